//! Where a bundle direction looks, the same for every backend: the analysis window of a
//! direction (the target's box or the scene's bounding sphere, projected), the viewport of
//! a planned tile, and the split of a rectangle that overflowed the node buffer.

use glam::{Vec2, Vec3};

use super::BundleConfig;
use super::raster::{BundleFrame, Viewport, grid_centre};
use super::stats::PassStats;
use super::tiles::Tile;

/// What a direction's window is made from.
#[derive(Clone, Copy, Debug)]
pub struct WindowSource {
    /// The target's world box (`BakeTarget::window`); `None`: the whole scene.
    pub target: Option<(Vec3, Vec3)>,
    /// The scene's bounding sphere.
    pub centre: Vec3,
    pub radius: f32,
    /// Bundle pixel side at the target's LOD (texel size / oversampling), metres.
    pub bundle_pixel: f32,
}

/// Bundle pixels per analysis pixel a cell's window aims at (see [`analysis_viewport`]).
const BUNDLE_PIXELS_PER_ANALYSIS_PIXEL: f32 = 8.0;

impl WindowSource {
    /// The window's square along `frame`: the target's box projected (or the scene's
    /// bounding sphere for a whole-scene target), as (lower corner, side).
    pub fn square(&self, frame: &BundleFrame) -> (Vec2, f32) {
        match self.target {
            None => {
                let (r, c) = (self.radius, frame.coords(self.centre));
                (Vec2::new(c.x - r, c.y - r), 2.0 * r)
            }
            Some((lo, hi)) => {
                let corners = WindowOutline::new(frame, (lo, hi)).corners;
                let a = corners.iter().fold(Vec2::splat(f32::MAX), |m, c| m.min(*c));
                let b = corners.iter().fold(Vec2::splat(f32::MIN), |m, c| m.max(*c));
                let side = (b - a).max_element().max(1e-6);
                let centre = (a + b) * 0.5;
                (centre - Vec2::splat(side * 0.5), side)
            }
        }
    }

    /// The analysis window of a direction: the square, R pixels, with one spare pixel so
    /// the per-direction jitter never shifts geometry out of it. A small window (a cell's)
    /// needs fewer analysis pixels: R is cut to the power of two giving about
    /// `BUNDLE_PIXELS_PER_ANALYSIS_PIXEL` bundle pixels per analysis pixel at the target's
    /// resolution, at least 8.
    pub fn analysis_viewport(&self, config: &BundleConfig, frame: &BundleFrame, jitter: Vec2) -> Viewport {
        let (corner, side) = self.square(frame);
        let mut res = config.analysis_res;
        if self.target.is_some() {
            let wanted = (side / self.bundle_pixel / BUNDLE_PIXELS_PER_ANALYSIS_PIXEL).ceil().max(8.0) as u32;
            res = res.min(wanted.next_power_of_two());
        }
        let pixel = side / (res - 1) as f32;
        Viewport::square(corner - jitter * pixel, pixel, res)
    }
}

/// A target's window seen along a direction: the outline of the box's eight corners on the
/// projection plane. Every line crediting a target texel crosses its surface inside the box
/// (`BakeTarget::window`), so no line outside the outline credits one: a windowed pass builds
/// fragments only inside it. The square around it ([`WindowSource::square`]) has up to
/// several times its pixels (a slab of floor seen at a grazing angle), each with the whole
/// prism's depth of occluders.
#[derive(Clone, Copy, Debug)]
pub struct WindowOutline {
    /// The box's corners in frame coordinates (along t, along b).
    corners: [Vec2; 8],
    /// The box itself.
    window: (Vec3, Vec3),
}

/// Pixels the outline is widened by on every side: far more than the 1/256-pixel vertex snap
/// or the rounding of the projection can move a pixel centre.
const OUTLINE_MARGIN: f32 = 1.0;

impl WindowOutline {
    pub fn new(frame: &BundleFrame, (lo, hi): (Vec3, Vec3)) -> Self {
        let corners = std::array::from_fn(|i| {
            let p = Vec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            );
            let c = frame.coords(p);
            Vec2::new(c.x, c.y)
        });
        WindowOutline { corners, window: (lo, hi) }
    }

    /// The box whose outline this is.
    pub fn window(&self) -> (Vec3, Vec3) {
        self.window
    }

    /// Per row of `viewport`, the pixels `x0..x1` of the rectangle (`x0 == x1` when none)
    /// whose centres lie within the outline widened by [`OUTLINE_MARGIN`] pixels.
    ///
    /// The outline is the convex hull of the corners, and a hull's extent over a band of rows
    /// is that of the segments between its points (every hull edge is one): each of the 28
    /// segments (and 8 points) is cut to the band of the row's centre ± the margin.
    pub fn rows(&self, viewport: &Viewport, out: &mut Vec<(u32, u32)>) {
        let p = self.corners.map(|c| viewport.grid_position(c));
        out.clear();
        hull_rows(&p, Points::Unordered, viewport, 0..viewport.height, out);
    }
}

/// How the points given to [`hull_rows`] are laid out.
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum Points {
    /// In any order: every segment between two of them is looked at.
    Unordered,
    /// A convex polygon's corners in order around it: its edges alone are.
    Polygon,
}

/// Appends, per row of `rows` of `viewport`, the pixels `x0..x1` (`x0 == x1` when none) whose
/// centres lie within [`OUTLINE_MARGIN`] pixels of the convex hull of `p` (grid positions).
///
/// A hull's extent over a band of rows is that of the segments between its points (every
/// hull edge is one; of a polygon in order, its edges): each segment (and point) is cut to
/// the band of the row's centre ± the margin.
pub fn hull_rows(
    p: &[Vec2],
    layout: Points,
    viewport: &Viewport,
    rows: std::ops::Range<u32>,
    out: &mut Vec<(u32, u32)>,
) {
    let n = p.len();
    for row in rows {
        let cy = grid_centre(viewport.offset.1, row);
        let (y0, y1) = (cy - OUTLINE_MARGIN, cy + OUTLINE_MARGIN);
        let (mut a, mut b) = (f32::INFINITY, f32::NEG_INFINITY);
        for i in 0..n {
            let others = match layout {
                Points::Unordered => i..n,
                Points::Polygon => (i + 1) % n..(i + 1) % n + 1,
            };
            for j in others {
                let (u, v) = if p[i].y <= p[j].y { (p[i], p[j]) } else { (p[j], p[i]) };
                if v.y < y0 || u.y > y1 {
                    continue;
                }
                // The segment's x at the band's clamped ends (a point when i == j).
                let at = |y: f32| if v.y > u.y { u.x + (v.x - u.x) * ((y - u.y) / (v.y - u.y)) } else { u.x };
                let (xa, xb) = (at(y0.max(u.y)), at(y1.min(v.y)));
                a = a.min(xa.min(xb));
                b = b.max(xa.max(xb));
            }
        }
        // Columns whose centre (grid x + 0.5) is in [a − margin, b + margin].
        let first = (a - OUTLINE_MARGIN - 0.5 - viewport.offset.0 as f32).ceil();
        let last = (b + OUTLINE_MARGIN - 0.5 - viewport.offset.0 as f32).floor();
        let clamp = |v: f32| if v.is_nan() { 0 } else { v.clamp(0.0, viewport.width as f32) as u32 };
        let (x0, x1) = (clamp(first), clamp(last + 1.0));
        out.push(if x0 < x1 { (x0, x1) } else { (0, 0) });
    }
}

/// The part of triangle `corners` inside the box `(lo, hi)`: its corners (up to 9) in `out`,
/// empty when they do not meet (Sutherland–Hodgman against the box's six planes).
pub fn clip_to_box(corners: &[Vec3; 3], (lo, hi): (Vec3, Vec3), out: &mut Vec<Vec3>, scratch: &mut Vec<Vec3>) {
    out.clear();
    out.extend_from_slice(corners);
    for axis in 0..3 {
        for (bound, keep_below) in [(lo[axis], false), (hi[axis], true)] {
            let inside = |p: &Vec3| if keep_below { p[axis] <= bound } else { p[axis] >= bound };
            scratch.clear();
            for i in 0..out.len() {
                let (a, b) = (out[i], out[(i + 1) % out.len()]);
                if inside(&a) {
                    scratch.push(a);
                }
                if inside(&a) != inside(&b) {
                    let t = (bound - a[axis]) / (b[axis] - a[axis]);
                    let mut p = a + (b - a) * t;
                    p[axis] = bound;
                    scratch.push(p);
                }
            }
            std::mem::swap(out, scratch);
            if out.is_empty() {
                return;
            }
        }
    }
}

/// The bundle viewport of planned tile `tile` of the analysis window `global`.
pub fn tile_viewport(global: &Viewport, tile: &Tile) -> Viewport {
    let w = tile.window();
    let side = w.side as f32 * global.pixel;
    Viewport::square(global.origin + Vec2::new(w.x as f32, w.y as f32) * global.pixel, side / tile.res as f32, tile.res)
}

/// A rectangle counted more fragments than the node buffer holds: record it and queue its
/// parts (its pixel grid cut in four: the paper's "split and redo", sampling exactly the
/// same pixels), so no sample is lost. Returns false when the rectangle is a single pixel
/// deeper than the whole node buffer (N too small for the scene); the caller then builds it
/// anyway rather than drop samples.
pub fn split_overflowed(
    vp: &Viewport,
    count: u64,
    capacity: u64,
    queue: &mut Vec<Viewport>,
    stats: &mut PassStats,
) -> bool {
    stats.overflowed_tiles += 1;
    stats.overflow_fragments += count - capacity;
    match vp.split() {
        Some(parts) => {
            stats.resplits += 1;
            queue.extend(parts.iter().rev());
            true
        }
        None => {
            stats.unsplittable_tiles += 1;
            false
        }
    }
}

/// Records a direction whose tiles could not be planned (the driver refuses the result).
pub fn unplanned(stats: &mut PassStats, error: &dyn std::fmt::Display) {
    tracing::error!("bundle direction not planned: {error}");
    stats.unplanned_directions += 1;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Rng;

    /// A random box, direction and viewport grid (the box somewhere inside the grid or
    /// reaching out of it), for the outline tests.
    fn random_case(rng: &mut Rng) -> (BundleFrame, (Vec3, Vec3), Viewport) {
        let mut v = || Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
        let lo = (v() - 0.5) * 10.0;
        // Slabs as well as cubes: one side may be a hundredth of the others.
        let mut size = v() * 4.0 + 0.05;
        let thin = (v().x * 3.0) as usize;
        size[thin.min(2)] *= 0.01;
        let dir = (v() - 0.5).normalize_or(Vec3::Z);
        let frame = BundleFrame::new(dir);
        let square =
            WindowSource { target: Some((lo, lo + size)), centre: Vec3::ZERO, radius: 1.0, bundle_pixel: 0.01 }
                .square(&frame);
        let res = 32 + (v().x * 96.0) as u32;
        let pixel = square.1 / res as f32 * (0.8 + v().y * 0.4);
        let origin = square.0 - Vec2::splat(v().z * 4.0 * pixel);
        let grid = Viewport::square(origin, pixel, res);
        // A part of the grid, as overflowed tiles are.
        let (ox, oy) = ((v().x * res as f32 * 0.3) as u32, (v().y * res as f32 * 0.3) as u32);
        let vp = Viewport { offset: (ox, oy), width: res - ox, height: res - oy, ..grid };
        (frame, (lo, lo + size), vp)
    }

    /// No pixel whose centre is within half a pixel of a point of the box (where a line
    /// through the box crosses the pixel) is left out, whatever the box, direction and part
    /// of the grid.
    #[test]
    fn the_outline_holds_every_pixel_a_point_of_the_box_falls_in() {
        let mut rng = Rng::new(41, 3);
        let mut out = Vec::new();
        for _ in 0..300 {
            let (frame, (lo, hi), vp) = random_case(&mut rng);
            WindowOutline::new(&frame, (lo, hi)).rows(&vp, &mut out);
            assert_eq!(out.len(), vp.height as usize);
            for _ in 0..2000 {
                let t = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
                let c = frame.coords(lo + (hi - lo) * t);
                let g = vp.grid_position(Vec2::new(c.x, c.y));
                let (x, y) = (g.x.floor() - vp.offset.0 as f32, g.y.floor() - vp.offset.1 as f32);
                if x < 0.0 || y < 0.0 || x >= vp.width as f32 || y >= vp.height as f32 {
                    continue;
                }
                let (x0, x1) = out[y as usize];
                assert!((x0..x1).contains(&(x as u32)), "pixel ({x}, {y}) of a box point is outside {x0}..{x1}");
            }
        }
    }

    /// The part of a triangle inside a box: analytic areas where the box cuts off a corner
    /// region or nothing, empty when they miss; and on random triangles and boxes, corners
    /// all in the box and an area equal to the triangle's share inside it, as 20 000 random
    /// points of it count that share (binomial: four standard errors, √(p(1−p)/n) ≤ 0.0035).
    #[test]
    fn clipping_keeps_the_part_of_a_triangle_inside_the_box() {
        let area = |p: &[Vec3]| {
            (1..p.len().saturating_sub(1)).map(|i| (p[i] - p[0]).cross(p[i + 1] - p[0]).length() / 2.0).sum::<f32>()
        };
        let (mut out, mut scratch) = (Vec::new(), Vec::new());
        let tri = [Vec3::ZERO, Vec3::new(2.0, 0.0, 0.0), Vec3::new(0.0, 2.0, 0.0)];
        clip_to_box(&tri, (Vec3::splat(-1.0), Vec3::splat(3.0)), &mut out, &mut scratch);
        assert!((area(&out) - 2.0).abs() < 1e-6, "whole: {}", area(&out));
        clip_to_box(&tri, (Vec3::new(0.0, 0.0, -1.0), Vec3::new(1.0, 1.0, 1.0)), &mut out, &mut scratch);
        assert!((area(&out) - 1.0).abs() < 1e-6, "unit square: {}", area(&out));
        // x ≥ 0.5: ∫ from 0.5 to 2 of (2 − x) dx = 1.125.
        clip_to_box(&tri, (Vec3::new(0.5, -1.0, -1.0), Vec3::splat(3.0)), &mut out, &mut scratch);
        assert!((area(&out) - 1.125).abs() < 1e-6, "cut corner: {}", area(&out));
        clip_to_box(&tri, (Vec3::splat(5.0), Vec3::splat(6.0)), &mut out, &mut scratch);
        assert!(out.is_empty());

        let mut rng = Rng::new(47, 2);
        let mut v = || Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
        let mut cut = 0;
        for _ in 0..40 {
            let tri = [v() * 4.0, v() * 4.0, v() * 4.0];
            let lo = v() * 2.0;
            let b = (lo, lo + v() * 2.0 + Vec3::splat(0.5));
            clip_to_box(&tri, b, &mut out, &mut scratch);
            for p in &out {
                assert!(p.cmpge(b.0 - 1e-5).all() && p.cmple(b.1 + 1e-5).all(), "{p} outside {b:?}");
            }
            let n = 20_000;
            let inside = (0..n)
                .filter(|_| {
                    let (mut a, mut c) = (v().x, v().y);
                    if a + c > 1.0 {
                        (a, c) = (1.0 - a, 1.0 - c);
                    }
                    let p = tri[0] + (tri[1] - tri[0]) * a + (tri[2] - tri[0]) * c;
                    p.cmpge(b.0).all() && p.cmple(b.1).all()
                })
                .count();
            let share = inside as f32 / n as f32;
            let clipped = area(&out) / area(&tri);
            assert!((clipped - share).abs() <= 4.0 * 0.0036, "clipped {clipped}, sampled {share}");
            cut += usize::from(share > 0.05 && share < 0.95);
        }
        assert!(cut >= 10, "only {cut} triangles were cut by their box");
    }

    /// A convex polygon's rows from its edges in order are those from every pair of its
    /// corners (the outline's way), for the polygons clipping makes.
    #[test]
    fn a_polygon_s_rows_are_its_hull_s() {
        let mut rng = Rng::new(53, 4);
        let (mut out, mut scratch) = (Vec::new(), Vec::new());
        let (mut polygon, mut unordered) = (Vec::new(), Vec::new());
        let mut rows = 0;
        for _ in 0..300 {
            let (frame, (lo, hi), vp) = random_case(&mut rng);
            let mut v = || Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
            let span = hi - lo;
            let tri = [lo + (v() * 2.0 - 0.5) * span, lo + (v() * 2.0 - 0.5) * span, lo + (v() * 2.0 - 0.5) * span];
            clip_to_box(&tri, (lo, hi), &mut out, &mut scratch);
            let p: Vec<Vec2> = out
                .iter()
                .map(|&c| {
                    let f = frame.coords(c);
                    vp.grid_position(Vec2::new(f.x, f.y))
                })
                .collect();
            polygon.clear();
            unordered.clear();
            hull_rows(&p, Points::Polygon, &vp, 0..vp.height, &mut polygon);
            hull_rows(&p, Points::Unordered, &vp, 0..vp.height, &mut unordered);
            assert_eq!(polygon, unordered);
            rows += polygon.iter().filter(|(a, b)| a < b).count();
        }
        assert!(rows > 1000, "{rows} rows with pixels");
    }

    /// The outline keeps no more pixels than the box's projection grown by the margin and
    /// half a pixel: the projected area of a box along unit ω is |ω·x|·A_yz + |ω·y|·A_xz +
    /// |ω·z|·A_xy (its faces' shadows, each counted once from either side), and growing a
    /// convex shape of width w and height h by r on every side adds at most 2r(w + h) + 4r².
    #[test]
    fn the_outline_is_the_boxs_shadow_not_its_square() {
        let mut rng = Rng::new(43, 5);
        let (mut kept, mut square) = (0u64, 0u64);
        let mut out = Vec::new();
        for _ in 0..300 {
            let (frame, (lo, hi), vp) = random_case(&mut rng);
            let grid =
                Viewport { offset: (0, 0), width: vp.width + vp.offset.0, height: vp.height + vp.offset.1, ..vp };
            WindowOutline::new(&frame, (lo, hi)).rows(&grid, &mut out);
            let count: u64 = out.iter().map(|&(a, b)| (b - a) as u64).sum();
            let s = (hi - lo) / grid.pixel;
            let d = frame.dir.abs();
            let area = (d.x * s.y * s.z + d.y * s.x * s.z + d.z * s.x * s.y) as f64;
            let side = WindowSource { target: Some((lo, hi)), centre: Vec3::ZERO, radius: 1.0, bundle_pixel: 0.01 }
                .square(&frame)
                .1;
            let corners = WindowOutline::new(&frame, (lo, hi)).corners.map(|c| grid.grid_position(c));
            let ext = corners.iter().fold(Vec2::splat(f32::MIN), |m, c| m.max(*c))
                - corners.iter().fold(Vec2::splat(f32::MAX), |m, c| m.min(*c));
            let r = (OUTLINE_MARGIN + 0.5) as f64;
            let bound = area + 2.0 * r * (ext.x + ext.y) as f64 + 4.0 * r * r;
            assert!(count as f64 <= bound + 1e-3 * bound, "{count} pixels kept, the grown shadow holds {bound:.1}");
            // The whole box in the grid: the outline's share of its square.
            if corners
                .iter()
                .all(|c| c.min_element() > 2.0 && c.x < grid.width as f32 - 2.0 && c.y < grid.height as f32 - 2.0)
            {
                kept += count;
                square += ((side / grid.pixel) as f64).powi(2) as u64;
            }
        }
        assert!(
            square > 0 && (kept as f64) < 0.8 * square as f64,
            "the outlines kept {kept} of their squares' {square} pixels"
        );
    }
}
