//! Conservative rasterisation in atlas pixel space, and the small 2-D geometry helpers the
//! unwrapper, the TEXCOORD_1 validator and the texel maps share.
//!
//! Pixel `(x, y)` is the square `[x, x+1] × [y, y+1]`; its centre is `(x + ½, y + ½)`.
//! A triangle *touches* a pixel when it intersects the pixel square shrunk by [`TOUCH_TOL`]
//! on every side (an exact triangle–box test, computed per row by clipping the triangle to
//! the row's slab). The tolerance keeps a chart whose edge lies on a pixel boundary — an
//! axis-aligned wall whose size is a multiple of the texel size — from claiming the next
//! row or column for a sliver of float noise; what it leaves out is a strip thinner than
//! 1/256 pixel, whose bilinear footprint is still made of covered and gutter pixels.
//! A triangle that touches nothing under that rule (it lies inside the tolerance band
//! along pixel boundaries: only possible for slivers and near-points) gets the pixel
//! holding its centroid, so every triangle has at least one pixel.

use glam::DVec2;

/// How far (in pixels of the grid being rasterised) a triangle must reach into a pixel to
/// touch it.
pub const TOUCH_TOL: f64 = 1.0 / 256.0;

/// `⌊x⌋` as an integer (saturating), without a libm call (x86-64's baseline has no
/// `roundsd`).
#[inline]
pub fn floor_i64(x: f64) -> i64 {
    let i = x as i64;
    i - i64::from((i as f64) > x)
}

/// `⌈x⌉` as an integer (saturating).
#[inline]
pub fn ceil_i64(x: f64) -> i64 {
    let i = x as i64;
    i + i64::from((i as f64) < x)
}

/// Half-open pixel rectangle `[x0, x1) × [y0, y1)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PixelRect {
    pub x0: i64,
    pub y0: i64,
    pub x1: i64,
    pub y1: i64,
}

impl PixelRect {
    pub fn new(x0: i64, y0: i64, x1: i64, y1: i64) -> Self {
        PixelRect { x0, y0, x1, y1 }
    }

    pub fn is_empty(&self) -> bool {
        self.x0 >= self.x1 || self.y0 >= self.y1
    }

    pub fn contains(&self, x: i64, y: i64) -> bool {
        x >= self.x0 && x < self.x1 && y >= self.y0 && y < self.y1
    }

    pub fn width(&self) -> i64 {
        (self.x1 - self.x0).max(0)
    }

    pub fn height(&self) -> i64 {
        (self.y1 - self.y0).max(0)
    }
}

/// x-extent of the part of triangle `t` inside the horizontal slab `ya ≤ y ≤ yb`.
#[inline]
fn slab_span(t: &[DVec2; 3], ya: f64, yb: f64) -> Option<(f64, f64)> {
    let mut lo = f64::INFINITY;
    let mut hi = f64::NEG_INFINITY;
    for i in 0..3 {
        let a = t[i];
        let b = t[(i + 1) % 3];
        if a.y >= ya && a.y <= yb {
            lo = lo.min(a.x);
            hi = hi.max(a.x);
        }
        for yl in [ya, yb] {
            if (a.y - yl) * (b.y - yl) < 0.0 {
                let x = a.x + (yl - a.y) * (b.x - a.x) / (b.y - a.y);
                lo = lo.min(x);
                hi = hi.max(x);
            }
        }
    }
    (lo <= hi).then_some((lo, hi))
}

/// Visits the pixels of `bounds` that `t` touches (see the module docs), restricted to rows
/// `rows_from..rows_to`, row by row, left to right. `f` returns `false` to stop early.
/// Returns whether any pixel was visited.
fn scan(t: &[DVec2; 3], bounds: PixelRect, rows_from: i64, rows_to: i64, f: impl FnMut(i64, i64) -> bool) -> bool {
    scan_with(t, bounds, TOUCH_TOL, rows_from, rows_to, f)
}

/// [`scan`] with the pixel squares shrunk by `tol` instead of [`TOUCH_TOL`].
fn scan_with(
    t: &[DVec2; 3],
    bounds: PixelRect,
    tol: f64,
    rows_from: i64,
    rows_to: i64,
    mut f: impl FnMut(i64, i64) -> bool,
) -> bool {
    let ymin = t[0].y.min(t[1].y).min(t[2].y);
    let ymax = t[0].y.max(t[1].y).max(t[2].y);
    if !(ymin.is_finite() && ymax.is_finite()) {
        return false;
    }
    let y0 = ceil_i64(ymin - 1.0 + tol).max(bounds.y0).max(rows_from);
    let y1 = floor_i64(ymax - tol).min(bounds.y1 - 1).min(rows_to - 1);
    let mut any = false;
    for y in y0..=y1 {
        let Some((lo, hi)) = slab_span(t, y as f64 + tol, y as f64 + 1.0 - tol) else {
            continue;
        };
        let x0 = ceil_i64(lo - 1.0 + tol).max(bounds.x0);
        let x1 = floor_i64(hi - tol).min(bounds.x1 - 1);
        for x in x0..=x1 {
            any = true;
            if !f(x, y) {
                return true;
            }
        }
    }
    any
}

/// The pixel a triangle that touches nothing falls back to: the one holding its centroid,
/// clamped into `bounds`.
fn fallback_pixel(t: &[DVec2; 3], bounds: PixelRect) -> (i64, i64) {
    let c = (t[0] + t[1] + t[2]) / 3.0;
    let x = floor_i64(c.x).clamp(bounds.x0, bounds.x1 - 1);
    let y = floor_i64(c.y).clamp(bounds.y0, bounds.y1 - 1);
    (x, y)
}

/// Calls `f(x, y)` for every pixel of `bounds` that triangle `t` touches, in rows
/// `rows.0..rows.1` only (a band of a larger raster; the result does not depend on the band).
/// A triangle that touches no pixel of `bounds` anywhere gets its centroid's pixel.
pub fn conservative(t: &[DVec2; 3], bounds: PixelRect, rows: (i64, i64), mut f: impl FnMut(i64, i64)) {
    if bounds.is_empty() {
        return;
    }
    let any = scan(t, bounds, rows.0, rows.1, |x, y| {
        f(x, y);
        true
    });
    if !any && !scan(t, bounds, i64::MIN, i64::MAX, |_, _| false) {
        let (x, y) = fallback_pixel(t, bounds);
        if y >= rows.0 && y < rows.1 {
            f(x, y);
        }
    }
}

/// [`conservative`] restricted to the pixels of `clip` (a window of a larger raster): the
/// pixels visited are exactly those of the unrestricted raster that lie in `clip`, the
/// centroid fallback included (it is decided over the whole of `bounds`).
pub fn conservative_in(t: &[DVec2; 3], bounds: PixelRect, clip: PixelRect, mut f: impl FnMut(i64, i64)) {
    let window =
        PixelRect::new(bounds.x0.max(clip.x0), bounds.y0.max(clip.y0), bounds.x1.min(clip.x1), bounds.y1.min(clip.y1));
    let any = !window.is_empty()
        && scan(t, window, i64::MIN, i64::MAX, |x, y| {
            f(x, y);
            true
        });
    if !any && !bounds.is_empty() && !scan(t, bounds, i64::MIN, i64::MAX, |_, _| false) {
        let (x, y) = fallback_pixel(t, bounds);
        if clip.contains(x, y) {
            f(x, y);
        }
    }
}

/// The pixels of `bounds` that triangle `t` reaches into by more than `tol` (pixels of this
/// grid) and the pixel holding its centroid: with `tol` at most [`TOUCH_TOL`] / 2^k, a
/// superset of the LOD-0 parents of every pixel [`conservative`] gives the triangle at LOD
/// k (a touched LOD-k pixel's shrunk square lies in its parent's square shrunk by
/// `TOUCH_TOL / 2^k`, and the centroid's LOD-k pixel lies in the centroid's LOD-0 pixel).
pub fn reached(t: &[DVec2; 3], bounds: PixelRect, tol: f64, mut f: impl FnMut(i64, i64)) {
    if bounds.is_empty() {
        return;
    }
    scan_with(t, bounds, tol, i64::MIN, i64::MAX, |x, y| {
        f(x, y);
        true
    });
    let (x, y) = fallback_pixel(t, bounds);
    f(x, y);
}

/// Every pixel of `bounds` that `t` touches (convenience for tests and small rasters).
pub fn conservative_pixels(t: &[DVec2; 3], bounds: PixelRect) -> Vec<(i64, i64)> {
    let mut v = Vec::new();
    conservative(t, bounds, (i64::MIN, i64::MAX), |x, y| v.push((x, y)));
    v
}

/// Barycentric weights `(u, v)` (of corners 1 and 2) of the point of triangle `t` closest to
/// `p`, and the squared distance from `p` to it (0 inside). Robust for degenerate triangles
/// (segments, points): the closest point is then found on the edges.
#[inline]
pub fn closest_barycentric(t: &[DVec2; 3], p: DVec2) -> (f64, f64, f64) {
    let [a, b, c] = *t;
    let (e1, e2, d) = (b - a, c - a, p - a);
    let det = e1.perp_dot(e2);
    let scale = e1.length_squared().max(e2.length_squared());
    if det.abs() > 1e-12 * scale {
        let u = d.perp_dot(e2) / det;
        let v = e1.perp_dot(d) / det;
        if u >= 0.0 && v >= 0.0 && u + v <= 1.0 {
            return (u, v, 0.0);
        }
    }
    // Outside (or degenerate): nearest point on the three edges.
    let seg = |p0: DVec2, p1: DVec2| {
        let e = p1 - p0;
        let l2 = e.length_squared();
        let s = if l2 > 0.0 { ((p - p0).dot(e) / l2).clamp(0.0, 1.0) } else { 0.0 };
        (s, (p0 + e * s - p).length_squared())
    };
    let (s_ab, d_ab) = seg(a, b);
    let (s_bc, d_bc) = seg(b, c);
    let (s_ca, d_ca) = seg(c, a);
    let mut best = (s_ab, 0.0, d_ab);
    if d_bc < best.2 {
        best = (1.0 - s_bc, s_bc, d_bc);
    }
    if d_ca < best.2 {
        best = (0.0, 1.0 - s_ca, d_ca);
    }
    best
}

/// Barycentric weights `(u, v)` (of corners 1 and 2) of `p` in the plane of triangle `t`,
/// outside it too (negative weights); `None` for a degenerate triangle.
#[inline]
pub fn barycentric(t: &[DVec2; 3], p: DVec2) -> Option<(f64, f64)> {
    let [a, b, c] = *t;
    let (e1, e2, d) = (b - a, c - a, p - a);
    let det = e1.perp_dot(e2);
    let scale = e1.length_squared().max(e2.length_squared());
    (det.abs() > 1e-12 * scale).then(|| (d.perp_dot(e2) / det, e1.perp_dot(d) / det))
}

/// Edge function `(b − a) × (p − a)`, evaluated with the endpoints in a canonical order so
/// that the two triangles sharing an edge get exactly opposite values.
#[inline]
fn edge_fn(a: DVec2, b: DVec2, p: DVec2) -> f64 {
    if (a.x, a.y) <= (b.x, b.y) { (b - a).perp_dot(p - a) } else { -(a - b).perp_dot(p - b) }
}

/// Calls `f(x, y)` for every pixel of `bounds` whose centre lies in triangle `t`, with a
/// top-left fill rule so that a centre on an edge shared by two triangles belongs to
/// exactly one of them. Degenerate (zero-area) triangles contain no centre.
pub fn centres_inside(t: &[DVec2; 3], bounds: PixelRect, mut f: impl FnMut(i64, i64)) {
    let mut t = *t;
    let area = (t[1] - t[0]).perp_dot(t[2] - t[0]);
    if area == 0.0 || !area.is_finite() {
        return;
    }
    if area < 0.0 {
        t.swap(1, 2);
    }
    let lo = t[0].min(t[1]).min(t[2]);
    let hi = t[0].max(t[1]).max(t[2]);
    let x0 = ((lo.x - 0.5).ceil() as i64).max(bounds.x0);
    let x1 = ((hi.x - 0.5).floor() as i64).min(bounds.x1 - 1);
    let y0 = ((lo.y - 0.5).ceil() as i64).max(bounds.y0);
    let y1 = ((hi.y - 0.5).floor() as i64).min(bounds.y1 - 1);
    // Top-left rule for a positively oriented triangle: a centre on edge a→b is inside when
    // the edge points "up" (dy > 0) or is horizontal pointing left.
    let top_left = |a: DVec2, b: DVec2| {
        let d = b - a;
        d.y > 0.0 || (d.y == 0.0 && d.x < 0.0)
    };
    let tl = [top_left(t[0], t[1]), top_left(t[1], t[2]), top_left(t[2], t[0])];
    for y in y0..=y1 {
        for x in x0..=x1 {
            let p = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
            let inside = (0..3).all(|i| {
                let e = edge_fn(t[i], t[(i + 1) % 3], p);
                e > 0.0 || (e == 0.0 && tl[i])
            });
            if inside {
                f(x, y);
            }
        }
    }
}

/// Whether two triangles' interiors overlap by more than `tol` along every separating axis
/// candidate (their edge normals). Triangles that share an edge or a vertex, or that are
/// degenerate (a segment has no interior), do not overlap.
pub fn triangles_overlap(a: &[DVec2; 3], b: &[DVec2; 3], tol: f64) -> bool {
    // Bounding boxes first (the axes x and y are separating axes too).
    let (alo, ahi) = (a[0].min(a[1]).min(a[2]), a[0].max(a[1]).max(a[2]));
    let (blo, bhi) = (b[0].min(b[1]).min(b[2]), b[0].max(b[1]).max(b[2]));
    if ahi.x <= blo.x + tol || bhi.x <= alo.x + tol || ahi.y <= blo.y + tol || bhi.y <= alo.y + tol {
        return false;
    }
    for tri in [a, b] {
        for i in 0..3 {
            // Unnormalised edge normal; the tolerance is scaled instead.
            let n = (tri[(i + 1) % 3] - tri[i]).perp();
            let len2 = n.length_squared();
            if len2 == 0.0 {
                continue;
            }
            let t = tol * len2.sqrt();
            let (amin, amax) = project(a, n);
            let (bmin, bmax) = project(b, n);
            if amax <= bmin + t || bmax <= amin + t {
                return false;
            }
        }
    }
    true
}

#[inline]
fn project(t: &[DVec2; 3], n: DVec2) -> (f64, f64) {
    let (p0, p1, p2) = (t[0].dot(n), t[1].dot(n), t[2].dot(n));
    (p0.min(p1).min(p2), p0.max(p1).max(p2))
}

/// Twice the signed area of a 2-D triangle.
#[inline]
pub fn area2(t: &[DVec2; 3]) -> f64 {
    (t[1] - t[0]).perp_dot(t[2] - t[0])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute_touch(t: &[DVec2; 3], x: i64, y: i64) -> bool {
        // Exact SAT test of the triangle against the shrunk pixel square (independent oracle).
        let lo = DVec2::new(x as f64 + TOUCH_TOL, y as f64 + TOUCH_TOL);
        let hi = DVec2::new(x as f64 + 1.0 - TOUCH_TOL, y as f64 + 1.0 - TOUCH_TOL);
        let tmin = t[0].min(t[1]).min(t[2]);
        let tmax = t[0].max(t[1]).max(t[2]);
        if tmax.x < lo.x || tmin.x > hi.x || tmax.y < lo.y || tmin.y > hi.y {
            return false;
        }
        let corners = [lo, DVec2::new(hi.x, lo.y), hi, DVec2::new(lo.x, hi.y)];
        for i in 0..3 {
            let n = (t[(i + 1) % 3] - t[i]).perp();
            if n == DVec2::ZERO {
                continue;
            }
            let (a0, a1) = project(t, n);
            let b: Vec<f64> = corners.iter().map(|c| c.dot(n)).collect();
            let (b0, b1) =
                (b.iter().cloned().fold(f64::INFINITY, f64::min), b.iter().cloned().fold(f64::NEG_INFINITY, f64::max));
            if a1 < b0 || b1 < a0 {
                return false;
            }
        }
        true
    }

    #[test]
    fn integer_floor_and_ceil() {
        for x in [-2.5, -2.0, -0.1, 0.0, 0.3, 1.0, 7.999, 1e12] {
            assert_eq!(floor_i64(x), x.floor() as i64, "{x}");
            assert_eq!(ceil_i64(x), x.ceil() as i64, "{x}");
        }
    }

    #[test]
    fn axis_aligned_rectangle_on_pixel_boundaries_covers_exactly_its_pixels() {
        let b = PixelRect::new(0, 0, 64, 64);
        let a = [DVec2::new(1.0, 1.0), DVec2::new(41.0, 1.0), DVec2::new(41.0, 21.0)];
        let c = [DVec2::new(1.0, 1.0), DVec2::new(41.0, 21.0), DVec2::new(1.0, 21.0)];
        let mut px: Vec<_> = conservative_pixels(&a, b);
        px.extend(conservative_pixels(&c, b));
        px.sort();
        px.dedup();
        assert_eq!(px.len(), 800);
        assert!(px.iter().all(|&(x, y)| (1..41).contains(&x) && (1..21).contains(&y)));
        // Half a pixel off the grid: one more row and column.
        let s = DVec2::splat(0.5);
        let mut px: Vec<_> = conservative_pixels(&a.map(|p| p + s), b);
        px.extend(conservative_pixels(&c.map(|p| p + s), b));
        px.sort();
        px.dedup();
        assert_eq!(px.len(), 41 * 21);
    }

    #[test]
    fn matches_exact_triangle_box_test_on_random_triangles() {
        let mut r = crate::sampling::Rng::new(7, 0);
        let b = PixelRect::new(-2, -2, 40, 40);
        for i in 0..2000 {
            let scale = if i % 3 == 0 { 2.0 } else { 30.0 };
            let mut t = [0; 3].map(|_| DVec2::new(r.next_f64() * scale, r.next_f64() * scale));
            if i % 5 == 0 {
                // Sliver: third corner almost on the first edge.
                t[2] = t[0] + (t[1] - t[0]) * 0.37 + (t[1] - t[0]).perp() * 1e-5;
            }
            let got: std::collections::BTreeSet<_> = conservative_pixels(&t, b).into_iter().collect();
            let mut want = std::collections::BTreeSet::new();
            for y in b.y0..b.y1 {
                for x in b.x0..b.x1 {
                    if brute_touch(&t, x, y) {
                        want.insert((x, y));
                    }
                }
            }
            if want.is_empty() {
                assert_eq!(got.len(), 1, "fallback pixel for {t:?}");
            } else {
                assert_eq!(got, want, "triangle {t:?}");
            }
        }
    }

    #[test]
    fn band_split_gives_the_same_pixels() {
        let b = PixelRect::new(0, 0, 50, 50);
        let t = [DVec2::new(3.2, 1.1), DVec2::new(47.0, 20.5), DVec2::new(10.0, 44.9)];
        let all = conservative_pixels(&t, b);
        let mut banded = Vec::new();
        for y0 in (0..50).step_by(7) {
            conservative(&t, b, (y0, y0 + 7), |x, y| banded.push((x, y)));
        }
        assert_eq!(all, banded);
        // A point-like triangle in a tolerance band gets exactly one pixel, in whichever band.
        let p = [DVec2::new(5.0, 9.0), DVec2::new(5.0, 9.0), DVec2::new(5.0001, 9.0)];
        let mut n = 0;
        for y0 in (0..50).step_by(7) {
            conservative(&p, b, (y0, y0 + 7), |_, _| n += 1);
        }
        assert_eq!(n, 1);
    }

    #[test]
    fn thin_sliver_touches_every_pixel_along_it() {
        let b = PixelRect::new(0, 0, 200, 200);
        let (p0, p1) = (DVec2::new(2.3, 3.7), DVec2::new(180.6, 121.2));
        let w = (p1 - p0).perp().normalize() * (p1 - p0).length() * 1e-4;
        let t = [p0, p1, (p0 + p1) * 0.5 + w];
        let px: std::collections::HashSet<_> = conservative_pixels(&t, b).into_iter().collect();
        for i in 0..=10000 {
            let q = p0 + (p1 - p0) * (i as f64 / 10000.0);
            let (fx, fy) = (q.x - q.x.floor(), q.y - q.y.floor());
            if fx.min(1.0 - fx) < 0.01 || fy.min(1.0 - fy) < 0.01 {
                continue; // within the tolerance band of a pixel edge
            }
            assert!(px.contains(&(q.x.floor() as i64, q.y.floor() as i64)), "{q:?}");
        }
    }

    #[test]
    fn top_left_rule_counts_every_centre_once() {
        // A fan and a grid of triangles whose edges pass through pixel centres.
        let b = PixelRect::new(0, 0, 20, 20);
        let mut count = vec![0u32; 400];
        let c = DVec2::new(10.5, 10.5);
        let ring = [
            DVec2::new(0.5, 0.5),
            DVec2::new(10.5, 0.5),
            DVec2::new(19.5, 0.5),
            DVec2::new(19.5, 10.5),
            DVec2::new(19.5, 19.5),
            DVec2::new(10.5, 19.5),
            DVec2::new(0.5, 19.5),
            DVec2::new(0.5, 10.5),
        ];
        for i in 0..8 {
            let t = if i % 2 == 0 { [c, ring[i], ring[(i + 1) % 8]] } else { [c, ring[(i + 1) % 8], ring[i]] };
            centres_inside(&t, b, |x, y| count[(y * 20 + x) as usize] += 1);
        }
        for y in 0..20 {
            for x in 0..20 {
                let n = count[(y * 20 + x) as usize];
                if (1..19).contains(&x) && (1..19).contains(&y) {
                    assert_eq!(n, 1, "({x},{y})");
                } else {
                    assert!(n <= 1, "({x},{y}) on the outer boundary counted {n} times");
                }
            }
        }
    }

    #[test]
    fn closest_barycentric_handles_degenerate_triangles() {
        let t = [DVec2::new(0.0, 0.0), DVec2::new(2.0, 0.0), DVec2::new(1.0, 0.0)];
        let (u, v, d2) = closest_barycentric(&t, DVec2::new(1.5, 1.0));
        let q = t[0] + (t[1] - t[0]) * u + (t[2] - t[0]) * v;
        assert!((q - DVec2::new(1.5, 0.0)).length() < 1e-12 && (d2 - 1.0).abs() < 1e-12);
        let t = [DVec2::new(0.0, 0.0), DVec2::new(4.0, 0.0), DVec2::new(0.0, 4.0)];
        assert_eq!(closest_barycentric(&t, DVec2::new(1.0, 2.0)), (0.25, 0.5, 0.0));
        let (u, v, d2) = closest_barycentric(&t, DVec2::new(3.0, 3.0));
        assert!((u - 0.5).abs() < 1e-12 && (v - 0.5).abs() < 1e-12 && (d2 - 2.0).abs() < 1e-12);
    }

    #[test]
    fn overlap_test_ignores_shared_edges() {
        let a = [DVec2::new(0.0, 0.0), DVec2::new(1.0, 0.0), DVec2::new(1.0, 1.0)];
        let b = [DVec2::new(0.0, 0.0), DVec2::new(1.0, 1.0), DVec2::new(0.0, 1.0)];
        assert!(!triangles_overlap(&a, &b, 1e-6));
        assert!(triangles_overlap(&a, &a, 1e-6));
        let c = [DVec2::new(0.5, 0.1), DVec2::new(2.0, 0.1), DVec2::new(2.0, 2.0)];
        assert!(triangles_overlap(&a, &c, 1e-6));
    }
}

/// Area of triangle `t` inside the unit pixel square with corner (x, y), in pixel units
/// (Sutherland–Hodgman clip against the four sides, then the shoelace formula; a square
/// inside the triangle, as most are, is 1 without clipping). No allocation: it runs for
/// every pixel a face touches, and on small faces most of those are on its edges.
pub fn clipped_area(t: &[DVec2; 3], x: i64, y: i64) -> f64 {
    let (x0, y0) = (x as f64, y as f64);
    let (x1, y1) = (x0 + 1.0, y0 + 1.0);
    let lo = t[0].min(t[1]).min(t[2]);
    let hi = t[0].max(t[1]).max(t[2]);
    if lo.x >= x0 && hi.x <= x1 && lo.y >= y0 && hi.y <= y1 {
        return 0.5 * area2(t).abs();
    }
    if square_inside(t, x0, y0) {
        return 1.0;
    }
    // A triangle clipped by four half-planes has at most 7 corners; the clip goes back and
    // forth between two buffers.
    let mut a = [DVec2::ZERO; 8];
    let mut b = [DVec2::ZERO; 8];
    a[..3].copy_from_slice(t);
    let mut n = 3;
    // Each plane keeps points p with sign·(p[axis] − bound) ≥ 0.
    n = clip_by_plane::<0>(&a, n, &mut b, x0, 1.0);
    if n < 3 {
        return 0.0;
    }
    n = clip_by_plane::<0>(&b, n, &mut a, x1, -1.0);
    if n < 3 {
        return 0.0;
    }
    n = clip_by_plane::<1>(&a, n, &mut b, y0, 1.0);
    if n < 3 {
        return 0.0;
    }
    n = clip_by_plane::<1>(&b, n, &mut a, y1, -1.0);
    if n < 3 {
        return 0.0;
    }
    let mut twice = 0.0;
    for i in 0..n {
        let (p, q) = (a[i], a[if i + 1 == n { 0 } else { i + 1 }]);
        twice += p.x * q.y - q.x * p.y;
    }
    0.5 * twice.abs()
}

/// One Sutherland–Hodgman step: the first `n` corners of `from` clipped to the half-plane
/// sign·(p[AXIS] − bound) ≥ 0, written to `to`; returns their count. A polygon no corner of
/// which is outside comes through as it is (the same corners in the same order, which is
/// what the clip would write), copied without the clip's work.
#[inline(always)]
fn clip_by_plane<const AXIS: usize>(from: &[DVec2; 8], n: usize, to: &mut [DVec2; 8], bound: f64, sign: f64) -> usize {
    let coord = |p: DVec2| if AXIS == 0 { p.x } else { p.y };
    let inside = |p: DVec2| sign * (coord(p) - bound) >= 0.0;
    if from[..n].iter().all(|&p| inside(p)) {
        to[..n].copy_from_slice(&from[..n]);
        return n;
    }
    let mut m = 0;
    for i in 0..n {
        let (a, b) = (from[i], from[if i + 1 == n { 0 } else { i + 1 }]);
        let (ia, ib) = (inside(a), inside(b));
        if ia {
            to[m] = a;
            m += 1;
        }
        if ia != ib {
            let s = (bound - coord(a)) / (coord(b) - coord(a));
            to[m] = a + (b - a) * s;
            m += 1;
        }
    }
    m
}

/// Whether the unit square with corner (x0, y0) lies inside triangle `t` (all four corners
/// on the inner side of every edge, or on it). Per edge only the corner farthest out is
/// tested: the edge function, rounded step by step, is monotonic in each coordinate (every
/// float operation rounds monotonically), so the corner the signs of the edge and of the
/// orientation pick has the least value of the four, exactly as computed.
fn square_inside(t: &[DVec2; 3], x0: f64, y0: f64) -> bool {
    let orient = area2(t);
    if orient == 0.0 {
        return false;
    }
    let positive = orient > 0.0;
    (0..3).all(|i| {
        let (a, b) = (t[i], t[if i == 2 { 0 } else { i + 1 }]);
        let e = b - a;
        // perp_dot(e, p − a) = e.x·(p.y − a.y) − e.y·(p.x − a.x), times `orient`.
        let dy = if (e.x >= 0.0) == positive { 0.0 } else { 1.0 };
        let dx = if (e.y <= 0.0) == positive { 0.0 } else { 1.0 };
        e.perp_dot(DVec2::new(x0 + dx, y0 + dy) - a) * orient >= 0.0
    })
}

#[cfg(test)]
mod clip_tests {
    use super::*;

    #[test]
    fn clipped_areas_of_a_triangle_sum_to_its_area() {
        let t = [DVec2::new(0.3, 0.2), DVec2::new(5.7, 1.1), DVec2::new(2.2, 4.9)];
        let mut sum = 0.0;
        for y in -1..7 {
            for x in -1..8 {
                sum += clipped_area(&t, x, y);
            }
        }
        assert!((sum - 0.5 * area2(&t).abs()).abs() < 1e-9, "{sum}");
        // A triangle covering the whole pixel contributes exactly 1, either way round.
        let big = [DVec2::new(-10.0, -10.0), DVec2::new(20.0, -10.0), DVec2::new(-10.0, 20.0)];
        assert_eq!(clipped_area(&big, 2, 2), 1.0);
        assert_eq!(clipped_area(&[big[0], big[2], big[1]], 2, 2), 1.0);
        assert_eq!(clipped_area(&t, 20, 20), 0.0);
        // A pixel the triangle's edge crosses: less than 1, the clip's area.
        let edge = clipped_area(&big, 4, 5);
        assert!(edge > 0.0 && edge < 1.0, "{edge}");
        assert!((edge - 0.5).abs() < 1e-12, "{edge}");
    }
}

/// The clip as first written, four planes in a loop with every corner tested against every
/// plane: what the faster [`clipped_area`] and [`square_inside`] must give, bit for bit (the
/// texel map's areas, and so every light map, must not move).
#[cfg(test)]
mod clip_as_written {
    use super::*;

    fn square_inside_every_corner(t: &[DVec2; 3], x0: f64, y0: f64) -> bool {
        let orient = area2(t);
        if orient == 0.0 {
            return false;
        }
        (0..3).all(|i| {
            let (a, b) = (t[i], t[(i + 1) % 3]);
            [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]
                .into_iter()
                .all(|(dx, dy)| (b - a).perp_dot(DVec2::new(x0 + dx, y0 + dy) - a) * orient >= 0.0)
        })
    }

    fn clipped_area_every_plane(t: &[DVec2; 3], x: i64, y: i64) -> f64 {
        let (x0, y0) = (x as f64, y as f64);
        let (x1, y1) = (x0 + 1.0, y0 + 1.0);
        let lo = t[0].min(t[1]).min(t[2]);
        let hi = t[0].max(t[1]).max(t[2]);
        if lo.x >= x0 && hi.x <= x1 && lo.y >= y0 && hi.y <= y1 {
            return 0.5 * area2(t).abs();
        }
        if square_inside_every_corner(t, x0, y0) {
            return 1.0;
        }
        let mut poly = [DVec2::ZERO; 8];
        let mut next = [DVec2::ZERO; 8];
        poly[..3].copy_from_slice(t);
        let mut n = 3;
        for (axis, bound, sign) in [(0, x0, 1.0), (0, x1, -1.0), (1, y0, 1.0), (1, y1, -1.0)] {
            let inside = |p: DVec2| sign * (p[axis] - bound) >= 0.0;
            let mut m = 0;
            for i in 0..n {
                let (a, b) = (poly[i], poly[(i + 1) % n]);
                let (ia, ib) = (inside(a), inside(b));
                if ia {
                    next[m] = a;
                    m += 1;
                }
                if ia != ib {
                    let s = (bound - a[axis]) / (b[axis] - a[axis]);
                    next[m] = a + (b - a) * s;
                    m += 1;
                }
            }
            std::mem::swap(&mut poly, &mut next);
            n = m;
            if n < 3 {
                return 0.0;
            }
        }
        let mut twice = 0.0;
        for i in 0..n {
            let (a, b) = (poly[i], poly[(i + 1) % n]);
            twice += a.x * b.y - b.x * a.y;
        }
        0.5 * twice.abs()
    }

    /// Random triangles of every kind a chart holds (large and sub-pixel, thin, degenerate,
    /// both windings, corners on the pixel grid and on its half-steps, where ties between
    /// corners decide), every pixel around each: the same bits.
    #[test]
    fn the_faster_clip_gives_the_same_bits_as_the_clip_as_written() {
        let mut state = 0x5eed_u64;
        let mut unit = || {
            state = crate::sampling::mix64(state.wrapping_add(0x9e37_79b9_7f4a_7c15));
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut pixels = 0usize;
        let mut partial = 0usize;
        for k in 0..4000 {
            let scale = [0.3, 1.0, 2.5, 9.0][k % 4];
            let snap = |v: f64| match k % 5 {
                0 => v.round(),
                1 => (v * 2.0).round() / 2.0,
                _ => v,
            };
            let mut p = || DVec2::new(snap(10.0 + unit() * scale), snap(10.0 + unit() * scale));
            let mut t = [p(), p(), p()];
            match k % 7 {
                0 => t[2] = t[0] + (t[1] - t[0]) * 0.5, // a segment
                1 => t[1] = t[0],                       // two corners in one
                _ => {}
            }
            for y in 8..22 {
                for x in 8..22 {
                    let (fast, slow) = (clipped_area(&t, x, y), clipped_area_every_plane(&t, x, y));
                    assert_eq!(fast.to_bits(), slow.to_bits(), "{t:?} at ({x}, {y}): {fast} against {slow}");
                    let (x0, y0) = (x as f64, y as f64);
                    assert_eq!(
                        square_inside(&t, x0, y0),
                        square_inside_every_corner(&t, x0, y0),
                        "{t:?} at ({x}, {y})"
                    );
                    pixels += 1;
                    partial += usize::from(fast > 0.0 && fast < 1.0);
                }
            }
        }
        // The comparison went through the clip many times, not only the shortcuts (12 945
        // pixels of the 784 000 are partly covered).
        assert!(partial > 10_000, "{partial} of {pixels} pixels partly covered");
    }
}
