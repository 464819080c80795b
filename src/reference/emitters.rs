//! Emissive triangles for next-event estimation: chosen in proportion to their power
//! (area × luminance of the emission × number of emitting sides, with an emissive texture's
//! mean standing in for the texture) through an alias table, then a uniform point on the
//! triangle. [`EmitterTable::area_pdf`] is the density of that point per m², which MIS needs
//! for the same point reached by a BSDF-sampled ray.

use glam::Vec2;

use crate::sampling::uniform_triangle;
use crate::scene::{Rgb, Scene, SceneGeometry, TriangleId, luminance};

/// Walker/Vose alias table: O(1) sampling of an index with given weights.
#[derive(Clone, Debug, Default)]
pub struct AliasTable {
    /// Probability of keeping bucket i (else take `alias[i]`).
    keep: Vec<f32>,
    alias: Vec<u32>,
}

impl AliasTable {
    /// Table for non-negative weights with a positive sum.
    pub fn new(weights: &[f64]) -> AliasTable {
        let n = weights.len();
        let total: f64 = weights.iter().sum();
        let mut scaled: Vec<f64> = weights.iter().map(|w| w * n as f64 / total).collect();
        let mut keep = vec![1.0f32; n];
        let mut alias: Vec<u32> = (0..n as u32).collect();
        let (mut small, mut large): (Vec<usize>, Vec<usize>) = (0..n).partition(|&i| scaled[i] < 1.0);
        while let (Some(s), Some(&l)) = (small.pop(), large.last()) {
            keep[s] = scaled[s] as f32;
            alias[s] = l as u32;
            scaled[l] -= 1.0 - scaled[s];
            if scaled[l] < 1.0 {
                large.pop();
                small.push(l);
            }
        }
        // Leftovers are 1 up to rounding: they keep themselves (already set).
        AliasTable { keep, alias }
    }

    pub fn len(&self) -> usize {
        self.keep.len()
    }

    pub fn is_empty(&self) -> bool {
        self.keep.is_empty()
    }

    /// An index from 32 random bits (bucket) and a uniform `coin` in [0, 1).
    #[inline]
    pub fn sample(&self, bits: u32, coin: f32) -> usize {
        let i = ((bits as u64 * self.keep.len() as u64) >> 32) as usize;
        if coin < self.keep[i] { i } else { self.alias[i] as usize }
    }
}

/// A point on an emitter chosen by [`EmitterTable::sample`].
#[derive(Clone, Copy, Debug)]
pub struct EmitterSample {
    pub tri: TriangleId,
    /// Barycentric weights of corners 1 and 2.
    pub u: f32,
    pub v: f32,
    /// Density of the point per m² of emitter area: P(triangle) / area.
    pub area_pdf: f32,
}

/// See the [module docs](self).
#[derive(Clone, Debug, Default)]
pub struct EmitterTable {
    tris: Vec<TriangleId>,
    table: AliasTable,
    /// Per [`TriangleId`]: P(triangle) / area, 0 for triangles that are never sampled.
    area_pdf: Vec<f32>,
    /// Σ area × luminance × sides, W/sr·… (a relative power, for reports).
    total_power: f64,
}

impl EmitterTable {
    pub fn new(scene: &Scene, geom: &SceneGeometry) -> EmitterTable {
        let mean_emission: Vec<Rgb> = scene
            .materials
            .iter()
            .map(|m| match &m.emissive_texture {
                Some(t) => m.emission * scene.textures[t.texture].mean().truncate(),
                None => m.emission,
            })
            .collect();
        let mut tris = Vec::new();
        let mut weights = Vec::new();
        for t in 0..geom.len() {
            let mid = geom.material[t] as usize;
            let sides = if scene.materials[mid].double_sided { 2.0 } else { 1.0 };
            let w = geom.areas[t] as f64 * luminance(mean_emission[mid].max(Rgb::ZERO)) as f64 * sides;
            if w > 0.0 && w.is_finite() {
                tris.push(t as TriangleId);
                weights.push(w);
            }
        }
        let total_power: f64 = weights.iter().sum();
        let mut area_pdf = vec![0.0f32; if tris.is_empty() { 0 } else { geom.len() }];
        for (&t, &w) in tris.iter().zip(&weights) {
            area_pdf[t as usize] = (w / total_power / geom.areas[t as usize] as f64) as f32;
        }
        let table = if tris.is_empty() { AliasTable::default() } else { AliasTable::new(&weights) };
        EmitterTable { tris, table, area_pdf, total_power }
    }

    /// Number of emitting triangles.
    pub fn len(&self) -> usize {
        self.tris.len()
    }

    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    pub fn total_power(&self) -> f64 {
        self.total_power
    }

    /// An emitter point from 32 random bits, a coin and a 2D uniform sample.
    #[inline]
    pub fn sample(&self, bits: u32, coin: f32, uv: Vec2) -> Option<EmitterSample> {
        if self.tris.is_empty() {
            return None;
        }
        let tri = self.tris[self.table.sample(bits, coin)];
        let (u, v) = uniform_triangle(uv);
        Some(EmitterSample { tri, u, v, area_pdf: self.area_pdf[tri as usize] })
    }

    /// Density per m² with which [`sample`](Self::sample) picks points of `tri`
    /// (0 if it never does).
    #[inline]
    pub fn area_pdf(&self, tri: TriangleId) -> f32 {
        self.area_pdf.get(tri as usize).copied().unwrap_or(0.0)
    }

    /// Solid-angle density, seen from a point at distance² `dist2` where the emitter's
    /// normal makes cosine `cos_emitter` with the direction back to that point.
    #[inline]
    pub fn solid_angle_pdf(area_pdf: f32, dist2: f32, cos_emitter: f32) -> f32 {
        area_pdf * dist2 / cos_emitter.abs()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Rng;

    #[test]
    fn alias_table_reproduces_its_weights() {
        // 4e5 draws; each frequency f has σ = √(p(1−p)/n) ≤ 7.9e-4, so 5σ < 4e-3.
        let w = [1.0, 0.0, 3.0, 0.5, 5.5];
        let table = AliasTable::new(&w);
        let mut counts = [0u32; 5];
        let mut r = Rng::new(3, 1);
        let n = 400_000;
        for _ in 0..n {
            counts[table.sample(r.next_u32(), r.next_f32())] += 1;
        }
        let total: f64 = w.iter().sum();
        for i in 0..5 {
            let f = counts[i] as f64 / n as f64;
            assert!((f - w[i] / total).abs() < 4e-3, "{i}: {f}");
        }
        assert_eq!(counts[1], 0);
    }
}
