//! Which pixels of a light bundle matter: a light pass resolves only the pixels between its
//! emitter spans, row by row (see `TileFragments::window`), so a triangle whose projection
//! reaches no such pixel adds nothing to it. Gathering a light bundle's triangles against
//! its emitter group's silhouette rather than the window's square leaves out the prism's
//! corners: on ninety instanced Van Gogh rooms (0.14 m light pixels, 10-pixel windows) a
//! lamp's square gathered ~1 800 triangles, most of which never met a lamp pixel.

use glam::Vec2;

use crate::bundle::raster::{BundleFrame, ScreenTriangle, Viewport};
use crate::scene::SceneGeometry;

/// Per row of a light window's pixel grid, the columns its emitters cover (the hull of
/// their spans), widened by one pixel each way and across neighbouring rows: the window's
/// tiles are separate viewports whose pixel centres may differ from this grid's by float
/// rounding, and a triangle edge through a centre may fall either way.
#[derive(Default)]
pub struct EmitterRows {
    origin: Vec2,
    pixel: f32,
    /// First and last column per row (inclusive); `lo > hi` when the row has none.
    rows: Vec<(i32, i32)>,
    /// The rows' bounding rectangle (first and last column, first and last row): most
    /// triangles of a large scene miss it, and one test rejects them.
    bounds: [i32; 4],
    /// The unwidened hulls, while filling.
    covered: Vec<(i32, i32)>,
}

const NONE: (i32, i32) = (i32::MAX, i32::MIN);

impl EmitterRows {
    /// Rasterises `emitters` (triangle indices into `geom`) into `grid` along `frame`.
    pub fn fill(&mut self, geom: &SceneGeometry, emitters: &[u32], frame: &BundleFrame, grid: &Viewport) {
        self.origin = grid.origin;
        self.pixel = grid.pixel;
        let height = grid.height as usize;
        self.covered.clear();
        self.covered.resize(height, NONE);
        for &t in emitters {
            let i = t as usize;
            let Some(screen) = ScreenTriangle::setup(frame, grid, &geom.corners[i], geom.normals[i]) else { continue };
            screen.for_each_span(|y, x0, x1| {
                let row = &mut self.covered[y as usize];
                *row = (row.0.min(x0 as i32), row.1.max(x1 as i32 - 1));
            });
        }
        self.rows.clear();
        self.rows.extend((0..height).map(|y| {
            let near = &self.covered[y.saturating_sub(1)..(y + 2).min(height)];
            let (lo, hi) = near.iter().fold(NONE, |a, r| (a.0.min(r.0), a.1.max(r.1)));
            if lo > hi { NONE } else { (lo - 1, hi + 1) }
        }));
        self.bounds = [i32::MAX, i32::MIN, i32::MAX, i32::MIN];
        for (j, &(lo, hi)) in self.rows.iter().enumerate() {
            if lo <= hi {
                let b = &mut self.bounds;
                *b = [b[0].min(lo), b[1].max(hi), b[2].min(j as i32), b[3].max(j as i32)];
            }
        }
    }

    /// Whether the rectangle `lo..=hi` (frame coordinates: a triangle's or a subtree's
    /// projected bounds) holds a pixel centre of a covered row's columns. Passes every
    /// rectangle that contains one it passes.
    pub fn reaches(&self, lo: Vec2, hi: Vec2) -> bool {
        // Pixel (i, j)'s centre is at grid position (i + ½, j + ½).
        let g0 = (lo - self.origin) / self.pixel - Vec2::splat(0.5);
        let g1 = (hi - self.origin) / self.pixel - Vec2::splat(0.5);
        if !(g0.is_finite() && g1.is_finite()) {
            return true;
        }
        let (i0, i1) = (g0.x.ceil() as i32, g1.x.floor() as i32);
        let (j0, j1) = (g0.y.ceil() as i32, g1.y.floor() as i32);
        let [bx0, bx1, by0, by1] = self.bounds;
        if i1 < bx0 || i0 > bx1 || j1 < by0 || j0 > by1 {
            return false;
        }
        (j0.max(by0)..=j1.min(by1)).any(|j| self.rows.get(j as usize).is_some_and(|&(lo, hi)| lo <= i1 && hi >= i0))
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;
    use crate::sampling::Rng;

    fn projected(frame: &BundleFrame, c: &[Vec3; 3]) -> (Vec2, Vec2) {
        let q = c.map(|p| Vec2::new(p.dot(frame.t), p.dot(frame.b)));
        (q[0].min(q[1]).min(q[2]), q[0].max(q[1]).max(q[2]))
    }

    fn geometry(triangles: &[[Vec3; 3]]) -> SceneGeometry {
        let mut geom = SceneGeometry::default();
        for c in triangles {
            geom.corners.push(*c);
            geom.normals.push((c[1] - c[0]).cross(c[2] - c[0]).normalize_or_zero());
        }
        geom
    }

    /// Every triangle covering a pixel centre between a row's emitter spans, in any tile of
    /// the window (tiles are separate viewports, as the light pass builds them), has
    /// projected bounds that `reaches` passes; and triangles far from the emitters are left
    /// out.
    #[test]
    fn every_triangle_a_light_tile_resolves_is_reached() {
        let mut rng = Rng::new(17, 2);
        let (mut checked, mut left_out) = (0, 0);
        for round in 0..100 {
            let dir = Vec3::new(rng.next_f32() - 0.5, rng.next_f32() - 0.5, rng.next_f32() - 0.5);
            let frame = BundleFrame::new(dir);
            // A lamp of a few small triangles near the origin.
            let mut point = |scale: f32| (Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5) * scale;
            let base = point(0.6);
            let lamp: Vec<[Vec3; 3]> =
                (0..4).map(|_| [base + point(0.5), base + point(0.5), base + point(0.5)]).collect();
            // Half of them around the lamp, half anywhere in a 4 m cube.
            let others: Vec<[Vec3; 3]> = (0..600)
                .map(|k| {
                    let size = if k % 10 == 0 { 1.5 } else { 0.08 };
                    let c = if k % 2 == 0 { base + point(1.0) } else { point(4.0) };
                    [c + point(size), c + point(size), c + point(size)]
                })
                .collect();
            let geom = geometry(&lamp.iter().chain(&others).copied().collect::<Vec<_>>());
            let emitters: Vec<u32> = (0..lamp.len() as u32).collect();
            let pixel = 0.03 + 0.05 * (round % 4) as f32;
            let (per_side, tile_res) = (1 + round % 3, 1 + 24 / (1 + round % 3));
            let origin = Vec2::splat(-1.2) + Vec2::new(rng.next_f32(), rng.next_f32()) * pixel;
            let grid = Viewport::square(origin, pixel, tile_res * per_side);
            let mut rows = EmitterRows::default();
            rows.fill(&geom, &emitters, &frame, &grid);
            for ty in 0..per_side {
                for tx in 0..per_side {
                    let corner = origin + Vec2::new(tx as f32, ty as f32) * (tile_res as f32 * pixel);
                    let tile = Viewport::square(corner, pixel, tile_res);
                    let mut hull = vec![NONE; tile_res as usize];
                    for &e in &emitters {
                        let e = e as usize;
                        if let Some(s) = ScreenTriangle::setup(&frame, &tile, &geom.corners[e], geom.normals[e]) {
                            s.for_each_span(|y, x0, x1| {
                                let h = &mut hull[y as usize];
                                *h = (h.0.min(x0 as i32), h.1.max(x1 as i32));
                            });
                        }
                    }
                    for k in 0..geom.corners.len() {
                        let Some(s) = ScreenTriangle::setup(&frame, &tile, &geom.corners[k], geom.normals[k]) else {
                            continue;
                        };
                        let mut resolved = false;
                        s.for_each_span(|y, x0, x1| {
                            let h = hull[y as usize];
                            resolved |= (x0 as i32) < h.1 && (x1 as i32) > h.0;
                        });
                        if resolved {
                            let (lo, hi) = projected(&frame, &geom.corners[k]);
                            assert!(rows.reaches(lo, hi), "round {round}: triangle {k} left out");
                            checked += 1;
                        }
                    }
                }
            }
            for c in &others {
                let (lo, hi) = projected(&frame, c);
                left_out += !rows.reaches(lo, hi) as u32;
            }
        }
        assert!(checked > 1000, "{checked} resolved triangles checked");
        assert!(left_out > 1000, "{left_out} triangles left out");
    }
}
