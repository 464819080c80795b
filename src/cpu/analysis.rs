//! Scene analysis of one bundle direction on the CPU (paper Sect. 4.1–4.2): an R×R
//! importance map (max over fragments of the triangle's texel density) and fragment-count
//! map, plus a coarse grid of the triangles under each part of the window so tiles only
//! scan the triangles that can touch them.

use glam::Vec2;

use super::scene::CpuScene;
use crate::bundle::raster::{BundleFrame, ScreenTriangle, Viewport};

/// Bins per side of the triangle grid over the analysis window.
const BINS: u32 = 16;

/// Analysis results of one direction.
#[derive(Default)]
pub struct Analysis {
    pub res: u32,
    /// Rays needed per m² of bundle at each analysis pixel (max over its fragments).
    pub importance: Vec<f32>,
    /// Fragments per analysis pixel (the depth complexity there).
    pub fragments: Vec<f32>,
    /// Triangles whose projection touches each bin (row-major, BINS×BINS).
    bins: Vec<Vec<u32>>,
    /// Triangles of the scene (the bit set [`candidates`](Self::candidates) needs).
    triangles: usize,
}

impl Analysis {
    /// Rasterises triangles `candidates` of `scene` (all of them when `None`) into the
    /// `viewport` (R×R) along `frame`. Importance is `importance[t]` (rays per m² of bundle:
    /// the target's texel density × oversampling², 0 for triangles holding no target texel).
    ///
    /// A triangle too small to cover any analysis pixel centre still marks the pixel under
    /// its centroid (a conservative touch): otherwise small objects would get no tile at all.
    pub fn run(
        &mut self,
        scene: &CpuScene,
        frame: &BundleFrame,
        viewport: &Viewport,
        candidates: Option<&[u32]>,
        importance: &[f32],
    ) {
        let res = viewport.width;
        let n = (res * res) as usize;
        let geom = &scene.bundle.geom;
        self.res = res;
        self.importance.clear();
        self.importance.resize(n, 0.0);
        self.fragments.clear();
        self.fragments.resize(n, 0.0);
        self.bins.resize_with((BINS * BINS) as usize, Vec::new);
        self.bins.iter_mut().for_each(Vec::clear);
        self.triangles = geom.len();
        match candidates {
            Some(c) => c.iter().for_each(|&t| self.add(scene, frame, viewport, t, importance[t as usize])),
            None => (0..geom.len() as u32).for_each(|t| self.add(scene, frame, viewport, t, importance[t as usize])),
        }
    }

    /// Rasterises triangle `t` into the maps and files it into its bins.
    fn add(&mut self, scene: &CpuScene, frame: &BundleFrame, viewport: &Viewport, t: u32, importance: f32) {
        let geom = &scene.bundle.geom;
        let res = viewport.width;
        let bin_side = res as f32 / BINS as f32;
        let c = geom.corners[t as usize].map(|p| frame.coords(p));
        // The window's grid starts at its pixel (0, 0): grid and window positions agree.
        let p = c.map(|c| viewport.grid_position(Vec2::new(c.x, c.y)));
        let (lo, hi) = (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
        self.bin(t, lo / bin_side, hi / bin_side);
        let mut covered = false;
        let front_faces_dir = geom.normals[t as usize].dot(frame.dir) > 0.0;
        if let Some(screen) = ScreenTriangle::setup_in_grid(viewport, p, c.map(|c| c.z), front_faces_dir) {
            screen.for_each_span(|y, x0, x1| {
                let row = (y * res) as usize;
                for x in x0 as usize..x1 as usize {
                    let i = row + x;
                    self.fragments[i] += 1.0;
                    self.importance[i] = self.importance[i].max(importance);
                }
                covered = true;
            });
        }
        if !covered {
            let c = (p[0] + p[1] + p[2]) / 3.0;
            if c.x >= 0.0 && c.y >= 0.0 && (c.x as u32) < res && (c.y as u32) < res {
                let i = (c.y as u32 * res + c.x as u32) as usize;
                self.importance[i] = self.importance[i].max(importance);
            }
        }
    }

    fn bin(&mut self, t: u32, lo: Vec2, hi: Vec2) {
        let clamp = |v: f32| (v.max(0.0) as u32).min(BINS - 1);
        if !(lo.is_finite() && hi.is_finite()) || hi.x < 0.0 || hi.y < 0.0 || lo.x >= BINS as f32 || lo.y >= BINS as f32
        {
            return;
        }
        for by in clamp(lo.y)..=clamp(hi.y) {
            for bx in clamp(lo.x)..=clamp(hi.x) {
                self.bins[(by * BINS + bx) as usize].push(t);
            }
        }
    }

    /// Triangles that may touch the window `[x0, x1) × [y0, y1)` (analysis pixels), each once,
    /// in ascending order (so fragment build order, and with it the result, is deterministic).
    /// `collected`: the caller's bit set, one bit per triangle, all clear between calls (it
    /// dedupes bins; one per thread, so threads gather tiles of one analysis side by side).
    pub fn candidates(&self, x0: f64, y0: f64, x1: f64, y1: f64, collected: &mut Vec<u64>, out: &mut Vec<u32>) {
        out.clear();
        if collected.len() < self.triangles.div_ceil(64) {
            collected.resize(self.triangles.div_ceil(64), 0);
        }
        let bin_side = self.res as f64 / BINS as f64;
        let clamp = |v: f64| ((v / bin_side).max(0.0) as u32).min(BINS - 1);
        let (mut first_word, mut last_word) = (usize::MAX, 0);
        for by in clamp(y0)..=clamp(y1 - 1e-9) {
            for bx in clamp(x0)..=clamp(x1 - 1e-9) {
                for &t in &self.bins[(by * BINS + bx) as usize] {
                    let (word, bit) = ((t / 64) as usize, 1u64 << (t % 64));
                    if collected[word] & bit == 0 {
                        collected[word] |= bit;
                        out.push(t);
                        first_word = first_word.min(word);
                        last_word = last_word.max(word);
                    }
                }
            }
        }
        if out.is_empty() {
            return;
        }
        // Ascending order: read back the bit set when it is dense, else sort the few
        // collected; either way the set is left empty for the next window.
        let words = last_word - first_word + 1;
        if out.len() * 8 >= words {
            out.clear();
            for (word, set) in collected.iter_mut().enumerate().take(last_word + 1).skip(first_word) {
                let mut bits = std::mem::take(set);
                while bits != 0 {
                    out.push(word as u32 * 64 + bits.trailing_zeros());
                    bits &= bits - 1;
                }
            }
        } else {
            out.sort_unstable();
            for &t in out.iter() {
                collected[(t / 64) as usize] = 0;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Rng;

    /// Windows collect the union of their bins' triangles, once each and ascending, whether
    /// the triangles are dense in index (read back from the bit set) or sparse (sorted),
    /// and leave nothing collected behind.
    #[test]
    fn candidates_are_the_union_of_the_bins_in_ascending_order() {
        let mut rng = Rng::new(29, 1);
        let triangles = 20_000u32;
        let mut analysis = Analysis { res: 64, triangles: triangles as usize, ..Analysis::default() };
        let mut collected = Vec::new();
        analysis.bins = (0..BINS * BINS)
            .map(|b| {
                // Dense runs in some bins, a few scattered indices in others.
                let mut bin: Vec<u32> = if b % 3 == 0 {
                    let start = (rng.next_f32() * 19_000.0) as u32;
                    (start..start + 300).collect()
                } else {
                    (0..4).map(|_| (rng.next_f32() * triangles as f32) as u32).collect()
                };
                bin.sort_unstable();
                bin
            })
            .collect();
        let mut out = Vec::new();
        for _ in 0..300 {
            let (x0, y0) = (rng.next_f32() as f64 * 64.0, rng.next_f32() as f64 * 64.0);
            let (x1, y1) = (x0 + rng.next_f32() as f64 * 20.0 + 0.1, y0 + rng.next_f32() as f64 * 20.0 + 0.1);
            analysis.candidates(x0, y0, x1, y1, &mut collected, &mut out);
            let side = 64.0 / BINS as f64;
            let clamp = |v: f64| ((v / side).max(0.0) as u32).min(BINS - 1);
            let mut expected: Vec<u32> = (clamp(y0)..=clamp(y1 - 1e-9))
                .flat_map(|by| (clamp(x0)..=clamp(x1 - 1e-9)).map(move |bx| by * BINS + bx))
                .flat_map(|b| analysis.bins[b as usize].clone())
                .collect();
            expected.sort_unstable();
            expected.dedup();
            assert_eq!(out, expected);
            assert!(collected.iter().all(|&w| w == 0));
        }
    }
}
