//! Orthographic scan conversion for ray bundles, with the rules a GPU rasteriser uses:
//! vertices snapped to 1/256 pixel, coverage sampled at pixel centres, and a fill rule that
//! gives a pixel centre lying exactly on an edge shared by two triangles to exactly one of
//! them. That watertightness is what keeps bundle rays from slipping between the triangles
//! of a closed wall (a light leak) or hitting it twice.
//!
//! Coverage is produced as horizontal spans computed exactly in integer arithmetic, so
//! counting fragments (analysis pass, overflow checks) costs one step per row, not per pixel.

use glam::{Vec2, Vec3};

use crate::sampling::basis;

/// Sub-pixel precision of snapped vertex coordinates (8 bits, as on common GPUs).
const SUBPIXEL_BITS: u32 = 8;
const SUBPIXEL: i64 = 1 << SUBPIXEL_BITS;

/// A bundle direction ω with an orthonormal frame (t, b) spanning the projection plane.
/// Screen x runs along t, screen y along b, depth along ω.
#[derive(Clone, Copy, Debug)]
pub struct BundleFrame {
    pub dir: Vec3,
    pub t: Vec3,
    pub b: Vec3,
}

impl BundleFrame {
    pub fn new(dir: Vec3) -> Self {
        let dir = dir.normalize();
        let (t, b) = basis(dir);
        BundleFrame { dir, t, b }
    }

    /// Coordinates of `p` in the frame: (along t, along b, along ω).
    #[inline]
    pub fn coords(&self, p: Vec3) -> Vec3 {
        Vec3::new(p.dot(self.t), p.dot(self.b), p.dot(self.dir))
    }
}

/// A rectangle of `width × height` square pixels of a pixel grid on the projection plane.
/// The grid is anchored at `origin`; the rectangle starts `offset` pixels into it. Parts of
/// one grid snap vertices identically, so they cover exactly the pixels the whole would.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Viewport {
    /// Frame coordinates (along t, along b) of the grid's corner.
    pub origin: Vec2,
    /// Pixel side in metres.
    pub pixel: f32,
    /// First pixel (x, y) of the rectangle in the grid.
    pub offset: (u32, u32),
    pub width: u32,
    pub height: u32,
}

impl Viewport {
    pub fn square(origin: Vec2, pixel: f32, res: u32) -> Self {
        Viewport { origin, pixel, offset: (0, 0), width: res, height: res }
    }

    /// Frame coordinates of the rectangle's corner at its pixel (0, 0).
    pub fn corner(&self) -> Vec2 {
        self.origin + Vec2::new(self.offset.0 as f32, self.offset.1 as f32) * self.pixel
    }

    pub fn pixels(&self) -> u64 {
        self.width as u64 * self.height as u64
    }

    /// The viewport's pixel grid cut in two along each side longer than one pixel: the
    /// parts cover exactly the same pixels (same positions, same size), so redoing an
    /// overflowed tile as its parts samples the scene exactly as the whole would have.
    /// `None` for a single pixel, which cannot be split.
    pub fn split(&self) -> Option<Vec<Viewport>> {
        if self.width <= 1 && self.height <= 1 {
            return None;
        }
        let cuts = |n: u32| if n > 1 { vec![(0, n.div_ceil(2)), (n.div_ceil(2), n / 2)] } else { vec![(0, n)] };
        let mut parts = Vec::with_capacity(4);
        for &(y0, h) in &cuts(self.height) {
            for &(x0, w) in &cuts(self.width) {
                parts.push(Viewport {
                    origin: self.origin,
                    pixel: self.pixel,
                    offset: (self.offset.0 + x0, self.offset.1 + y0),
                    width: w,
                    height: h,
                });
            }
        }
        Some(parts)
    }

    /// World area of one pixel (m²): the weight `a_px` of every hit in this viewport.
    pub fn pixel_area(&self) -> f32 {
        self.pixel * self.pixel
    }

    /// Continuous pixel coordinates in the grid (not the rectangle) of a point given by
    /// its frame coordinates along t and b.
    #[inline]
    pub fn grid_position(&self, c: Vec2) -> Vec2 {
        (c - self.origin) / self.pixel
    }
}

/// One triangle set up for scan conversion in a viewport.
#[derive(Clone, Copy, Debug)]
pub struct ScreenTriangle {
    /// Snapped vertices (1/256 pixel units), counter-clockwise in screen space (x right, y down
    /// as stored; orientation is only used consistently).
    v: [(i64, i64); 3],
    /// Per edge: whether a pixel centre exactly on it belongs to this triangle.
    include_edge: [bool; 3],
    /// Rows and columns of pixel centres the triangle can cover, clipped to the viewport.
    row_min: u32,
    row_max: u32,
    column_min: u32,
    column_max: u32,
    /// Viewport width: spans are clipped to `[0, width)`.
    width: u32,
    /// Snapped corners in grid pixel coordinates (original order) and their depths along ω:
    /// what [`planes`](Self::planes) interpolates.
    grid_corners: [Vec2; 3],
    corner_depths: [f32; 3],
    /// The triangle's front face looks along +ω (its geometric normal n has n·ω > 0).
    pub front_faces_dir: bool,
    /// All snapped coordinates fit the fast i64 span arithmetic.
    narrow: bool,
}

/// Integer arithmetic the span computation needs (i64 fast path, i128 for huge triangles).
trait SpanInt:
    Copy + Ord + From<i64> + std::ops::Add<Output = Self> + std::ops::Sub<Output = Self> + std::ops::Mul<Output = Self>
{
    fn floor_div(self, d: Self) -> Self;
    fn to_u32(self) -> u32;
}

macro_rules! span_int {
    ($($t:ty),*) => {$(
        impl SpanInt for $t {
            #[inline]
            fn floor_div(self, d: Self) -> Self {
                self.div_euclid(d)
            }
            #[inline]
            fn to_u32(self) -> u32 {
                self as u32
            }
        }
    )*};
}
span_int!(i64, i128);

/// Barycentric weights of the *original* corners 1 and 2 and the depth, as affine
/// functions of continuous *grid* pixel coordinates relative to the snapped corner 0 (the
/// anchor): f(x, y) = c\[0\]·(x − a.x) + c\[1\]·(y − a.y) + c\[2\], c\[2\] being the value at the
/// anchor. Grid, not rectangle, coordinates: a pixel gets bit-identical attributes
/// whichever part of a split viewport it is rasterised in.
///
/// Relative to the anchor, because that keeps the evaluation well conditioned: about the
/// grid's origin the constant term is a large sum that cancels (an atlas UV of thousands
/// of pixels minus gradient × hundreds of pixels), and its rounding (10⁻³ pixel) decided
/// which texel a line near a texel edge credited, differently on the GPU's arithmetic.
/// `x − a.x` is exact (both are multiples of 1/256 below 2^16), so what remains is the
/// rounding of terms the size of the triangle's extent in the tile.
#[derive(Clone, Copy, Debug)]
pub struct Planes {
    bary_u: [f32; 3],
    bary_v: [f32; 3],
    depth: [f32; 3],
    anchor: Vec2,
}

impl Planes {
    /// The depth along ω as an affine function (coefficients as in
    /// [`gradient`](Self::gradient); evaluate with [`at`](Self::at)).
    pub fn depth_coefficients(&self) -> [f32; 3] {
        self.depth
    }

    /// Grid coordinates (x, y) relative to the anchor, where coefficients are evaluated.
    #[inline]
    pub fn local(&self, x: f32, y: f32) -> (f32, f32) {
        (x - self.anchor.x, y - self.anchor.y)
    }

    /// Affine function `c` (of [`gradient`](Self::gradient)) at grid coordinates (x, y).
    #[inline]
    pub fn at(&self, c: &[f32; 3], x: f32, y: f32) -> f32 {
        let (dx, dy) = self.local(x, y);
        eval(c, dx, dy)
    }

    /// Barycentric weights (of the original corners 1 and 2) at grid coordinates (x, y),
    /// clamped onto the triangle (a pixel centre it covers lies on it up to rounding).
    pub fn barycentrics(&self, x: f32, y: f32) -> (f32, f32) {
        let u = self.at(&self.bary_u, x, y).clamp(0.0, 1.0);
        let v = self.at(&self.bary_v, x, y).clamp(0.0, 1.0 - u);
        (u, v)
    }

    /// Affine coefficients (per +1 pixel in x, per +1 pixel in y, at the anchor) of a
    /// value interpolated from the three original corners.
    pub fn gradient(&self, values: [f32; 3]) -> [f32; 3] {
        let mut out = [0.0; 3];
        for (k, o) in out.iter_mut().enumerate() {
            *o = values[0] * (if k == 2 { 1.0 } else { 0.0 })
                + (values[1] - values[0]) * self.bary_u[k]
                + (values[2] - values[0]) * self.bary_v[k];
        }
        out
    }
}

/// How far apart (metres along ω, per unit of depth slope tanθ) the depths of two coplanar
/// triangles may be at one pixel of side `pixel`: each corner snaps by at most half a
/// subpixel in x and in y, which tilts a triangle's depth plane (interpolated over the
/// snapped corners) by at most (√2/2)/SUBPIXEL pixel times its slope, each triangle
/// differently. The depths stay consistent with the coverage, which is what keeps a closed
/// mesh closed; stacked copies must allow for it.
pub fn snapped_depth_slack(pixel: f32) -> f32 {
    std::f32::consts::SQRT_2 * pixel / SUBPIXEL as f32
}

/// An affine function f(x, y) = c\[0\]·x + c\[1\]·y + c\[2\] at (x, y) (coordinates relative to
/// the function's anchor, see [`Planes`]).
#[inline]
pub fn eval(c: &[f32; 3], x: f32, y: f32) -> f32 {
    c[0] * x + c[1] * y + c[2]
}

/// Grid coordinate of the centre of pixel `i` of a rectangle that starts `offset` pixels
/// into its grid: where attributes are evaluated.
#[inline]
pub fn grid_centre(offset: u32, i: u32) -> f32 {
    (i + offset) as f32 + 0.5
}

/// Twice the signed area of snapped corners `v`, in integer type `I` (i64 when every
/// coordinate is below 2^30).
#[inline]
fn orient<I: SpanInt>(v: &[(i64, i64); 3]) -> I {
    let d = |a: i64, b: i64| I::from(a) - I::from(b);
    d(v[1].0, v[0].0) * d(v[2].1, v[0].1) - d(v[2].0, v[0].0) * d(v[1].1, v[0].1)
}

/// The first and last of pixel centres `0..count` (pixel i has its centre at
/// (i + 0.5)·SUBPIXEL) between the smallest and largest of snapped coordinates `q`.
#[inline]
fn centres_between(q: [i64; 3], count: u32) -> Option<(u32, u32)> {
    let (lo, hi) = (q[0].min(q[1]).min(q[2]), q[0].max(q[1]).max(q[2]));
    // ⌈(lo − half) / SUBPIXEL⌉ and ⌊(hi − half) / SUBPIXEL⌋ (an arithmetic shift floors);
    // saturation only moves coordinates near ±2^63 further out of the viewport.
    let half = SUBPIXEL / 2;
    let first = (lo.saturating_sub(half).saturating_add(SUBPIXEL - 1) >> SUBPIXEL_BITS).max(0);
    let last = (hi.saturating_sub(half) >> SUBPIXEL_BITS).min(count as i64 - 1);
    (first <= last).then_some((first as u32, last as u32))
}

impl ScreenTriangle {
    /// Sets up `corners` (world space, original winding) for `viewport` of `frame`.
    /// `None` when the triangle is edge-on to ω (covers no pixel centre), lies outside the
    /// viewport's rows or columns, or its coordinates are not finite.
    pub fn setup(frame: &BundleFrame, viewport: &Viewport, corners: &[Vec3; 3], normal: Vec3) -> Option<Self> {
        let c = corners.map(|p| frame.coords(p));
        let grid = c.map(|c| viewport.grid_position(Vec2::new(c.x, c.y)));
        Self::setup_in_grid(viewport, grid, c.map(|c| c.z), normal.dot(frame.dir) > 0.0)
    }

    /// [`setup`](Self::setup) from the corners' positions in the viewport's grid (see
    /// [`Viewport::grid_position`]) and depths along ω, for callers that need the positions
    /// too.
    pub fn setup_in_grid(
        viewport: &Viewport,
        grid: [Vec2; 3],
        depths: [f32; 3],
        front_faces_dir: bool,
    ) -> Option<Self> {
        if grid.iter().any(|q| !q.is_finite()) {
            return None;
        }
        // Snap in grid coordinates, then move to the rectangle by whole pixels: exact. (Scaling
        // by SUBPIXEL and rounding are exact in f32.)
        let (ox, oy) = (viewport.offset.0 as i64 * SUBPIXEL, viewport.offset.1 as i64 * SUBPIXEL);
        let snap = |q: Vec2| {
            let s = (q * SUBPIXEL as f32).round();
            (s.x as i64 - ox, s.y as i64 - oy)
        };
        let mut v = grid.map(snap);
        let grid_corners = v.map(|(x, y)| Vec2::new((x + ox) as f32, (y + oy) as f32) / SUBPIXEL as f32);
        let narrow = v.iter().all(|q| q.0.abs() < 1 << 30 && q.1.abs() < 1 << 30);
        let area2 = if narrow { orient::<i64>(&v) as i128 } else { orient::<i128>(&v) };
        if area2 == 0 {
            return None;
        }
        if area2 < 0 {
            v.swap(1, 2);
        }
        let (row_min, row_max) = centres_between(v.map(|q| q.1), viewport.height)?;
        let (column_min, column_max) = centres_between(v.map(|q| q.0), viewport.width)?;
        let include_edge = std::array::from_fn(|e| {
            let (a, b) = (v[e], v[(e + 1) % 3]);
            // Gradient of the edge function is (−dy, dx); include the edge when it points
            // right, or straight down. The neighbour across a shared edge sees it reversed,
            // so exactly one of the two includes a centre lying on it.
            let (gx, gy) = (-(b.1 - a.1), b.0 - a.0);
            gx > 0 || (gx == 0 && gy > 0)
        });
        Some(ScreenTriangle {
            v,
            include_edge,
            row_min,
            row_max,
            column_min,
            column_max,
            grid_corners,
            corner_depths: depths,
            front_faces_dir,
            width: viewport.width,
            narrow,
        })
    }

    /// First and last row of the viewport the triangle may cover.
    #[inline]
    pub fn rows(&self) -> (u32, u32) {
        (self.row_min, self.row_max)
    }

    /// First and last column of the viewport the triangle may cover.
    #[inline]
    pub fn columns(&self) -> (u32, u32) {
        (self.column_min, self.column_max)
    }

    /// Calls `f(row, x_begin, x_end)` for every row of the viewport with covered pixel
    /// centres, pixels `x_begin..x_end`.
    #[inline]
    pub fn for_each_span(&self, mut f: impl FnMut(u32, u32, u32)) {
        for row in self.row_min..=self.row_max {
            if let Some((x0, x1)) = self.span(row) {
                f(row, x0, x1);
            }
        }
    }

    /// Covered pixels of one row, clipped to the viewport.
    #[inline]
    pub fn span(&self, row: u32) -> Option<(u32, u32)> {
        if self.narrow { self.span_in::<i64>(row, self.width) } else { self.span_in::<i128>(row, self.width) }
    }

    /// [`span`](Self::span) in integer type `I`: i64 when every snapped coordinate is below
    /// 2^30 (products stay below 2^62), i128 for triangles reaching absurdly far outside.
    #[inline]
    fn span_in<I: SpanInt>(&self, row: u32, res: u32) -> Option<(u32, u32)> {
        let sub = I::from(SUBPIXEL);
        let half = I::from(SUBPIXEL / 2);
        let py = I::from(row as i64) * sub + half;
        let mut lo = I::from(0);
        let mut hi = I::from(res as i64 - 1);
        for e in 0..3 {
            let (a, b) = (self.v[e], self.v[(e + 1) % 3]);
            let (dx, dy) = (I::from(b.0 - a.0), I::from(b.1 - a.1));
            // E(px) = dx·(py − ya) − dy·(SUBPIXEL·px + SUBPIXEL/2 − xa) ≥ bias
            let c = dx * (py - I::from(a.1)) - dy * (half - I::from(a.0));
            let c = if self.include_edge[e] { c } else { c - I::from(1) };
            let k = dy * sub;
            // c − k·px ≥ 0
            if k == I::from(0) {
                if c < I::from(0) {
                    return None;
                }
            } else if k > I::from(0) {
                hi = hi.min(c.floor_div(k));
            } else {
                lo = lo.max(I::from(0) - c.floor_div(I::from(0) - k));
            }
        }
        (lo <= hi).then(|| (lo.to_u32(), hi.to_u32() + 1))
    }

    /// The attribute planes. They pass through the *snapped* corners, so they agree with the
    /// coverage: where two triangles of a closed surface meet, a line covered by both crosses
    /// them in the order the snapped (still closed) surface dictates; planes through the
    /// unsnapped corners can swap entry and exit near edges. Computed on demand: coverage
    /// alone (analysis, counting) does not need them.
    pub fn planes(&self) -> Planes {
        let p = self.grid_corners;
        let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
        // Non-zero: the snapped area was checked at setup (and is exact in f32 for sane sizes).
        let inv = 1.0 / (e1.x * e2.y - e1.y * e2.x);
        let plane = |v: [f32; 3]| {
            let (d1, d2) = (v[1] - v[0], v[2] - v[0]);
            let cx = (d1 * e2.y - d2 * e1.y) * inv;
            let cy = (d2 * e1.x - d1 * e2.x) * inv;
            [cx, cy, v[0]]
        };
        Planes {
            bary_u: plane([0.0, 1.0, 0.0]),
            bary_v: plane([0.0, 0.0, 1.0]),
            depth: plane(self.corner_depths),
            anchor: p[0],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Rng;

    fn frame_z() -> BundleFrame {
        BundleFrame { dir: Vec3::Z, t: Vec3::X, b: Vec3::Y }
    }

    fn vp(res: u32) -> Viewport {
        Viewport::square(Vec2::ZERO, 1.0, res)
    }

    /// Pixel-centre coverage of one triangle, brute force with the same snapping and rule.
    fn brute(tri: &ScreenTriangle, res: u32) -> Vec<(u32, u32)> {
        let mut out = Vec::new();
        for y in 0..res {
            for x in 0..res {
                let (px, py) = (x as i128 * 256 + 128, y as i128 * 256 + 128);
                let inside = (0..3).all(|e| {
                    let (a, b) = (tri.v[e], tri.v[(e + 1) % 3]);
                    let ev = (b.0 - a.0) as i128 * (py - a.1 as i128) - (b.1 - a.1) as i128 * (px - a.0 as i128);
                    ev > 0 || (ev == 0 && tri.include_edge[e])
                });
                if inside {
                    out.push((x, y));
                }
            }
        }
        out
    }

    fn spans_of(tri: &ScreenTriangle) -> Vec<(u32, u32)> {
        let mut out = Vec::new();
        tri.for_each_span(|y, x0, x1| out.extend((x0..x1).map(|x| (x, y))));
        out
    }

    fn setup(c: [Vec3; 3], res: u32) -> Option<ScreenTriangle> {
        let n = (c[1] - c[0]).cross(c[2] - c[0]).normalize_or_zero();
        ScreenTriangle::setup(&frame_z(), &vp(res), &c, n)
    }

    #[test]
    fn spans_match_brute_force_on_random_triangles() {
        let mut rng = Rng::new(5, 0);
        let res = 24;
        let mut nonempty = 0;
        for _ in 0..400 {
            let mut p = || Vec3::new(rng.next_f32() * 30.0 - 3.0, rng.next_f32() * 30.0 - 3.0, rng.next_f32());
            let c = [p(), p(), p()];
            if let Some(t) = setup(c, res) {
                let s = spans_of(&t);
                assert_eq!(s, brute(&t, res));
                nonempty += !s.is_empty() as u32;
            }
        }
        assert!(nonempty > 200);
    }

    /// Small and thin triangles (few rows, steep edges) and tall ones (hundreds of rows)
    /// against the rule at every pixel centre.
    #[test]
    fn spans_match_brute_force_on_small_thin_and_tall_triangles() {
        let mut rng = Rng::new(11, 3);
        for (res, size, count, min_nonempty) in [(24, 3.0, 400, 100), (24, 0.7, 2000, 20), (300, 900.0, 40, 10)] {
            let mut nonempty = 0;
            for _ in 0..count {
                let base = Vec3::new(rng.next_f32() * res as f32, rng.next_f32() * res as f32, 0.0);
                let mut p = || base + Vec3::new(rng.next_f32() - 0.5, rng.next_f32() - 0.5, rng.next_f32()) * size;
                let c = [p(), p(), p()];
                match setup(c, res) {
                    Some(t) => {
                        let s = spans_of(&t);
                        assert_eq!(s, brute(&t, res));
                        nonempty += !s.is_empty() as u32;
                    }
                    // Skipped: the same grid, extended far enough to hold the triangle,
                    // has no covered centre inside the viewport.
                    None => {
                        if let Some(t) = setup(c, 4 * res) {
                            assert!(spans_of(&t).iter().all(|&(x, y)| x >= res || y >= res));
                        }
                    }
                }
            }
            assert!(nonempty >= min_nonempty, "{nonempty} of {count} at size {size}");
        }
    }

    /// A fan of triangles around a centre and a grid of quads whose vertices sit exactly on
    /// pixel centres: every pixel centre inside the covered region is hit exactly once.
    #[test]
    fn shared_edges_are_watertight() {
        let res = 32;
        let mut hits = vec![0u32; (res * res) as usize];
        let centre = Vec3::new(16.5, 16.5, 0.0);
        let n = 37;
        for i in 0..n {
            let a = i as f32 / n as f32 * std::f32::consts::TAU;
            let b = (i + 1) as f32 / n as f32 * std::f32::consts::TAU;
            let pa = centre + Vec3::new(a.cos(), a.sin(), 0.0) * 40.0;
            let pb = centre + Vec3::new(b.cos(), b.sin(), 0.0) * 40.0;
            // Alternate winding: the fill rule must not depend on it.
            let tri = if i % 2 == 0 { [centre, pa, pb] } else { [centre, pb, pa] };
            if let Some(t) = setup(tri, res) {
                t.for_each_span(|y, x0, x1| (x0..x1).for_each(|x| hits[(y * res + x) as usize] += 1));
            }
        }
        assert!(hits.iter().all(|&h| h == 1), "fan: {:?}", hits.iter().filter(|&&h| h != 1).count());

        let mut hits = vec![0u32; (res * res) as usize];
        for gy in 0..8 {
            for gx in 0..8 {
                let p = |x: u32, y: u32| Vec3::new(x as f32 * 4.0 + 0.5, y as f32 * 4.0 + 0.5, 0.0);
                let (a, b, c, d) = (p(gx, gy), p(gx + 1, gy), p(gx + 1, gy + 1), p(gx, gy + 1));
                for tri in [[a, b, c], [a, c, d]] {
                    if let Some(t) = setup(tri, res) {
                        t.for_each_span(|y, x0, x1| (x0..x1).for_each(|x| hits[(y * res + x) as usize] += 1));
                    }
                }
            }
        }
        // The grid spans pixel centres 0.5 ..= 32.5: every pixel of the viewport, once.
        assert!(hits.iter().all(|&h| h == 1));
    }

    /// Triangles reaching millions of pixels outside the viewport take the i128 path and
    /// must agree with the brute-force rule.
    #[test]
    fn huge_triangles_use_wide_arithmetic_correctly() {
        let res = 16;
        let c = [Vec3::new(-3.0e6, -2.0e6, 0.0), Vec3::new(4.0e6, 7.5, 0.0), Vec3::new(8.3, 5.0e6, 0.0)];
        let t = setup(c, res).unwrap();
        assert!(!t.narrow);
        let s = spans_of(&t);
        assert_eq!(s, brute(&t, res));
        assert!(!s.is_empty());
    }

    /// The rows (or columns) a triangle may cover, against exact wide arithmetic, near pixel
    /// centres and at the ends of the i64 range.
    #[test]
    fn centre_ranges_match_wide_arithmetic() {
        let exact = |q: [i64; 3], count: u32| {
            let (lo, hi) = (*q.iter().min().unwrap() as i128, *q.iter().max().unwrap() as i128);
            let first = (lo - 128 + 255).div_euclid(256).max(0);
            let last = (hi - 128).div_euclid(256).min(count as i128 - 1);
            (first <= last).then_some((first as u32, last as u32))
        };
        let mut rng = Rng::new(23, 5);
        let mut cases =
            vec![[i64::MIN, 0, 5], [i64::MAX, i64::MAX - 3, 0], [i64::MIN, i64::MIN, i64::MAX], [-129, 127, 128]];
        for _ in 0..20_000 {
            let mut q = || (rng.next_f32() * 10_000.0) as i64 - 2_000 + [-1, 0, 1][(rng.next_f32() * 3.0) as usize];
            cases.push([q(), q(), q()]);
        }
        for q in cases {
            for count in [1, 7, 30] {
                assert_eq!(centres_between(q, count), exact(q, count), "{q:?} in {count}");
            }
        }
    }

    /// Splitting a viewport keeps every pixel centre where it was: the parts' coverage is
    /// exactly the whole's.
    #[test]
    fn split_viewports_cover_the_same_pixels() {
        let mut rng = Rng::new(9, 1);
        let whole = Viewport { origin: Vec2::new(-0.37, 1.21), pixel: 0.25, offset: (0, 0), width: 13, height: 6 };
        let parts = whole.split().unwrap();
        assert_eq!(parts.len(), 4);
        assert_eq!(parts.iter().map(|p| p.pixels()).sum::<u64>(), whole.pixels());
        for _ in 0..50 {
            let mut p = || Vec3::new(rng.next_f32() * 4.0 - 0.7, rng.next_f32() * 2.0 + 1.0, rng.next_f32());
            let c = [p(), p(), p()];
            let n = (c[1] - c[0]).cross(c[2] - c[0]).normalize_or_zero();
            let centres = |v: &Viewport| -> Vec<(i64, i64)> {
                let Some(t) = ScreenTriangle::setup(&frame_z(), v, &c, n) else { return Vec::new() };
                let (ox, oy) = (v.offset.0 as i64, v.offset.1 as i64);
                let mut out = Vec::new();
                t.for_each_span(|y, x0, x1| out.extend((x0..x1).map(|x| (x as i64 + ox, y as i64 + oy))));
                out
            };
            let mut from_parts: Vec<_> = parts.iter().flat_map(centres).collect();
            let mut from_whole = centres(&whole);
            from_parts.sort_unstable();
            from_whole.sort_unstable();
            assert_eq!(from_parts, from_whole);
        }
        let strip = Viewport { origin: Vec2::ZERO, pixel: 1.0, offset: (0, 0), width: 1, height: 5 };
        assert_eq!(strip.split().unwrap().len(), 2);
        assert!(Viewport::square(Vec2::ZERO, 1.0, 1).split().is_none());
    }

    /// Parts of a split viewport skip triangles outside their rows or columns: small
    /// triangles straddling the cuts must still cover exactly what they cover in the whole.
    #[test]
    fn parts_keep_triangles_straddling_their_borders() {
        let mut rng = Rng::new(13, 2);
        let whole = Viewport { origin: Vec2::new(0.3, -0.2), pixel: 1.0, offset: (0, 0), width: 17, height: 9 };
        let parts = whole.split().unwrap();
        let centres = |v: &Viewport, c: &[Vec3; 3]| -> Vec<(u32, u32)> {
            let n = (c[1] - c[0]).cross(c[2] - c[0]).normalize_or_zero();
            let Some(t) = ScreenTriangle::setup(&frame_z(), v, c, n) else { return Vec::new() };
            let mut out = Vec::new();
            t.for_each_span(|y, x0, x1| out.extend((x0..x1).map(|x| (x + v.offset.0, y + v.offset.1))));
            out
        };
        let mut covered = 0;
        for _ in 0..2000 {
            let base = Vec3::new(rng.next_f32() * 19.0 - 1.0, rng.next_f32() * 11.0 - 1.0, 0.0);
            let mut p = || base + Vec3::new(rng.next_f32() - 0.5, rng.next_f32() - 0.5, rng.next_f32()) * 2.5;
            let c = [p(), p(), p()];
            let mut from_parts: Vec<_> = parts.iter().flat_map(|v| centres(v, &c)).collect();
            let mut from_whole = centres(&whole, &c);
            from_parts.sort_unstable();
            from_whole.sort_unstable();
            assert_eq!(from_parts, from_whole);
            covered += from_whole.len();
        }
        assert!(covered > 500, "{covered}");
    }

    #[test]
    fn edge_on_and_offscreen_triangles_give_nothing() {
        // Edge-on to ω = +Z: all three corners project onto a line.
        assert!(setup([Vec3::ZERO, Vec3::new(5.0, 5.0, 1.0), Vec3::new(10.0, 10.0, -2.0)], 16).is_none());
        assert!(setup([Vec3::new(0.0, 40.0, 0.0), Vec3::new(5.0, 40.0, 0.0), Vec3::new(0.0, 45.0, 0.0)], 16).is_none());
    }

    #[test]
    fn attributes_interpolate_affinely() {
        let c = [Vec3::new(1.0, 1.0, 2.0), Vec3::new(9.0, 1.0, 4.0), Vec3::new(1.0, 9.0, 6.0)];
        let t = setup(c, 16).unwrap();
        let planes = t.planes();
        let (u, v) = (
            planes.at(&planes.gradient([0.0, 1.0, 0.0]), 5.0, 5.0),
            planes.at(&planes.gradient([0.0, 0.0, 1.0]), 5.0, 5.0),
        );
        assert!((u - 0.5).abs() < 1e-5 && (v - 0.5).abs() < 1e-5);
        assert!((planes.at(&planes.depth_coefficients(), 5.0, 5.0) - 5.0).abs() < 1e-5);
        let g = planes.gradient([10.0, 20.0, 30.0]);
        assert!((planes.at(&g, 1.0, 1.0) - 10.0).abs() < 1e-4);
        assert!((planes.at(&g, 9.0, 1.0) - 20.0).abs() < 1e-4);
        assert!(t.front_faces_dir);
    }

    #[test]
    fn covered_count_approximates_area() {
        // A large triangle of area 0.5·200·150 = 15000 pixel² in a 256² viewport: centre
        // sampling is exact up to the pixels along the perimeter (~ 610 pixels long).
        let c = [Vec3::new(10.3, 20.7, 0.0), Vec3::new(210.3, 20.7, 0.0), Vec3::new(10.3, 170.7, 0.0)];
        let t = setup(c, 256).unwrap();
        let n = spans_of(&t).len() as f32;
        assert!((n - 15000.0).abs() < 610.0 * 0.5 + 1.0, "{n}");
    }
}
