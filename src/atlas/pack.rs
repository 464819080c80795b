//! Chart rectangles, skyline packing with rotations, and the free-space search that keeps an
//! atlas stable under edits.
//!
//! **Placement.** A chart's local UVs span `[0, e]` on each axis (LOD-0 texels). Its
//! rectangle has `n = max(1, ⌈e − TOUCH_TOL/64⌉)` interior pixels on that axis plus a
//! [`BORDER`] of one empty texel on each side, so the side is `n + 2`, and the chart is
//! centred in the interior: local coordinate 0 goes to `rect_min + 1 + (n − e)/2`. Its
//! geometry then spans `[1 + d, 1 + n − d]` (relative to `rect_min`) with `d = (n − e)/2 ≥
//! −TOUCH_TOL/8`, so it reaches at most `TOUCH_TOL/8` into a border pixel: less than the
//! raster's touch tolerance, so every pixel the chart touches conservatively is an interior
//! pixel. (The `−TOUCH_TOL/64` lets an extent that is an integer up to float noise — a 4 m
//! wall at 0.1 m texels — use exactly `e` pixels, aligned to the pixel grid, instead of
//! `e + 1` half-covered ones.) TEXCOORD_1 blocks keep their validated pixel grid: their
//! interior is given and their offset is exactly one texel. A chart may be placed turned by
//! a quarter ([`Orient`]): `(x, y) ↦ (y, e.x − x)`, which keeps a block's pixel grid.
//!
//! **Gutters.** Rectangles never overlap, so between the coverage of two charts there are at
//! least the two border texels: bilinear sampling at LOD 0 (reading the 2×2 texels around a
//! point, all within one texel of a covered pixel) never mixes charts. At LOD k the same
//! layout scaled by 2^k leaves 2·2^k texels.
//!
//! **Packing** ([`pack`]). Skyline: rectangles by decreasing longer side, then shorter side,
//! then id; each goes, in whichever of its two orientations does better, where its top edge
//! is lowest, then where it leaves the least area under it unused, then leftmost. The atlas
//! width is `max(widest rectangle's shorter side, ⌈√(total area)⌉)`, aiming at a square.
//! Everything is integer arithmetic: deterministic.
//!
//! **Updates** ([`FreeMap`], [`pack_into_free`]). An existing atlas keeps its rectangles; new
//! ones go first into given free rectangles (the space a changed mesh's old charts left,
//! best short-side fit), then into the first free place of the atlas (top to bottom, left
//! to right), found on a bitmap of occupied texels.

use glam::DVec2;

use super::raster::{PixelRect, TOUCH_TOL, conservative};

/// Empty texels on each side of a chart's interior.
pub const BORDER: u32 = 1;

/// How a chart sits in its rectangle: interior pixels and the offset from the rectangle's
/// top-left corner to the chart's local origin, in LOD-0 texels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    pub interior: (u32, u32),
    pub offset: DVec2,
}

impl Placement {
    /// Rectangle size including the border.
    pub fn rect_size(&self) -> (u32, u32) {
        (self.interior.0 + 2 * BORDER, self.interior.1 + 2 * BORDER)
    }

    /// The same chart turned by a quarter ([`Orient::Turned`]).
    pub fn turned(&self, fixed: bool) -> Placement {
        let interior = (self.interior.1, self.interior.0);
        if fixed {
            return place_fixed(interior);
        }
        Placement { interior, offset: DVec2::new(self.offset.y, self.offset.x) }
    }
}

/// Interior pixels and offset on one axis for a chart extent `e` (see the module docs).
/// `None` when the extent is not finite or absurdly large.
pub fn axis_placement(e: f64) -> Option<(u32, f64)> {
    if !(e.is_finite() && e >= 0.0) || e > (u32::MAX / 4) as f64 {
        return None;
    }
    let n = (e - TOUCH_TOL / 64.0).ceil().max(1.0);
    Some((n as u32, BORDER as f64 + (n - e) * 0.5))
}

/// Placement of a chart whose local UVs span `[0, extent]`.
pub fn place_free(extent: DVec2) -> Option<Placement> {
    let (nx, ox) = axis_placement(extent.x)?;
    let (ny, oy) = axis_placement(extent.y)?;
    Some(Placement { interior: (nx, ny), offset: DVec2::new(ox, oy) })
}

/// Placement of a pixel-aligned block (TEXCOORD_1) with the given interior.
pub fn place_fixed(interior: (u32, u32)) -> Placement {
    Placement { interior, offset: DVec2::splat(BORDER as f64) }
}

/// How a chart is turned in its rectangle.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Orient {
    #[default]
    AsIs,
    /// A quarter turn: local `(x, y) ↦ (y, e.x − x)` for a chart of extent `e`.
    Turned,
}

impl Orient {
    /// A local UV of a chart of extent `extent`, in the chart's turned frame.
    #[inline]
    pub fn apply(self, p: DVec2, extent: DVec2) -> DVec2 {
        match self {
            Orient::AsIs => p,
            Orient::Turned => DVec2::new(p.y, extent.x - p.x),
        }
    }

    /// Extent of the chart in its turned frame.
    pub fn extent(self, extent: DVec2) -> DVec2 {
        match self {
            Orient::AsIs => extent,
            Orient::Turned => DVec2::new(extent.y, extent.x),
        }
    }
}

/// LOD-0 pixels covered (conservatively) by triangles given relative to their rectangle's
/// top-left corner, all inside the placement's interior: what the texel map will make of
/// the chart.
pub fn coverage(tris: impl Iterator<Item = [DVec2; 3]>, placement: &Placement, mask: &mut Vec<bool>) -> u64 {
    let (w, h) = (placement.interior.0 as i64, placement.interior.1 as i64);
    let b = BORDER as i64;
    let bounds = PixelRect::new(b, b, b + w, b + h);
    mask.clear();
    mask.resize((w * h) as usize, false);
    for t in tris {
        conservative(&t, bounds, (i64::MIN, i64::MAX), |x, y| mask[((y - b) * w + (x - b)) as usize] = true);
    }
    mask.iter().filter(|&&m| m).count() as u64
}

/// A packed atlas: its size, each rectangle's top-left corner and orientation (in input
/// order). Sizes are given as placed unturned; a turned rectangle occupies `(h, w)`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Packing {
    pub width: u32,
    pub height: u32,
    pub positions: Vec<(u32, u32)>,
    pub orient: Vec<Orient>,
}

#[derive(Clone, Copy, Debug)]
struct Seg {
    x: u32,
    y: u32,
    w: u32,
}

/// Size of a rectangle in an orientation.
pub fn oriented((w, h): (u32, u32), o: Orient) -> (u32, u32) {
    if o == Orient::Turned { (h, w) } else { (w, h) }
}

/// Packs rectangles of the given sizes. `Err((width, height))` gives the size the atlas
/// would need when it exceeds `max_size` on either side (nothing of that size is allocated).
pub fn pack(sizes: &[(u32, u32)], max_size: u32) -> Result<Packing, (u32, u32)> {
    if sizes.is_empty() {
        return Ok(Packing { width: 0, height: 0, positions: Vec::new(), orient: Vec::new() });
    }
    let short = sizes.iter().map(|s| s.0.min(s.1)).max().unwrap_or(0);
    let long = sizes.iter().map(|s| s.0.max(s.1)).max().unwrap_or(0);
    let total: u64 = sizes.iter().map(|&(w, h)| w as u64 * h as u64).sum();
    let side = (total as f64).sqrt().ceil() as u64;
    let width = (short as u64).max(side);
    if short > max_size || total > max_size as u64 * max_size as u64 {
        let w = width.min(u32::MAX as u64) as u32;
        let h = total.div_ceil(width).max(long.min(w) as u64).min(u32::MAX as u64) as u32;
        return Err((w, h));
    }
    let too_large = (width as u32, long);
    let p = pack_strip(sizes, width as u32).ok_or(too_large)?;
    if p.height <= max_size {
        return Ok(p);
    }
    // Too tall for the limit: use all the width we may.
    let p = pack_strip(sizes, max_size).ok_or(too_large)?;
    if p.height <= max_size { Ok(p) } else { Err((p.width, p.height)) }
}

/// Packs rectangles into a strip of the given width (as [`pack`] orders them), as tall as it
/// needs; `None` when a rectangle is wider than the strip both ways.
pub fn pack_strip(sizes: &[(u32, u32)], width: u32) -> Option<Packing> {
    if sizes.iter().any(|s| s.0.min(s.1) > width) {
        return None;
    }
    let mut order: Vec<usize> = (0..sizes.len()).collect();
    let key = |s: (u32, u32)| (s.0.max(s.1), s.0.min(s.1));
    order.sort_by(|&a, &b| key(sizes[b]).cmp(&key(sizes[a])).then(a.cmp(&b)));
    Some(skyline(sizes, &order, width))
}

fn skyline(sizes: &[(u32, u32)], order: &[usize], width: u32) -> Packing {
    let mut sky = vec![Seg { x: 0, y: 0, w: width }];
    let mut positions = vec![(0, 0); sizes.len()];
    let mut orient = vec![Orient::AsIs; sizes.len()];
    let mut height = 0;
    for &id in order {
        // Best (top edge, unused area under it, x) over segments and orientations.
        let mut best: Option<((u32, u64, u32), usize, Orient)> = None;
        for o in [Orient::AsIs, Orient::Turned] {
            let (w, h) = oriented(sizes[id], o);
            if o == Orient::Turned && w == h {
                break;
            }
            if w > width {
                continue;
            }
            for i in 0..sky.len() {
                let x = sky[i].x;
                if x + w > width {
                    break;
                }
                let mut y = 0;
                let mut covered = 0;
                let mut j = i;
                while covered < w {
                    y = y.max(sky[j].y);
                    covered += sky[j].w;
                    j += 1;
                }
                let mut waste = 0u64;
                let mut left = w;
                for s in &sky[i..j] {
                    let part = s.w.min(left);
                    waste += (y - s.y) as u64 * part as u64;
                    left -= part;
                }
                let score = (y + h, waste, x);
                if best.is_none_or(|(b, _, _)| score < b) {
                    best = Some((score, i, o));
                }
            }
        }
        let ((top, _, x), i, o) = best.expect("every rectangle fits the atlas width in some orientation");
        let (w, h) = oriented(sizes[id], o);
        let y = top - h;
        positions[id] = (x, y);
        orient[id] = o;
        height = height.max(top);
        // Replace the skyline over [x, x + w) by one segment at y + h.
        let end = x + w;
        let mut j = i;
        while j < sky.len() && sky[j].x < end {
            let seg_end = sky[j].x + sky[j].w;
            if seg_end <= end {
                j += 1;
            } else {
                sky[j].w = seg_end - end;
                sky[j].x = end;
                break;
            }
        }
        sky.splice(i..j, [Seg { x, y: top, w }]);
        // Merge with equal-height neighbours.
        if i + 1 < sky.len() && sky[i + 1].y == sky[i].y {
            sky[i].w += sky[i + 1].w;
            sky.remove(i + 1);
        }
        if i > 0 && sky[i - 1].y == sky[i].y {
            sky[i - 1].w += sky[i].w;
            sky.remove(i);
        }
    }
    Packing { width, height, positions, orient }
}

/// A rectangle of texels: top-left corner and size.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rect {
    pub x: u32,
    pub y: u32,
    pub w: u32,
    pub h: u32,
}

impl Rect {
    pub fn contains(&self, o: &Rect) -> bool {
        o.x >= self.x && o.y >= self.y && o.x + o.w <= self.x + self.w && o.y + o.h <= self.y + self.h
    }

    pub fn intersects(&self, o: &Rect) -> bool {
        o.x < self.x + self.w && self.x < o.x + o.w && o.y < self.y + self.h && self.y < o.y + o.h
    }
}

/// Places rectangles (`sizes`, in order) into the free rectangles `free` (disjoint), best
/// short-side fit over both orientations (ties: long side, then the free list order), with
/// the free space kept as maximal rectangles. Returns each rectangle's corner and
/// orientation, `None` for those that did not fit.
pub fn pack_into_free(mut free: Vec<Rect>, sizes: &[(u32, u32)]) -> Vec<Option<((u32, u32), Orient)>> {
    let mut out = vec![None; sizes.len()];
    let mut order: Vec<usize> = (0..sizes.len()).collect();
    let area = |s: (u32, u32)| s.0 as u64 * s.1 as u64;
    order.sort_by(|&a, &b| area(sizes[b]).cmp(&area(sizes[a])).then(a.cmp(&b)));
    for id in order {
        let mut best: Option<((u32, u32), usize, Orient)> = None;
        for (k, f) in free.iter().enumerate() {
            for o in [Orient::AsIs, Orient::Turned] {
                let (w, h) = oriented(sizes[id], o);
                if w <= f.w && h <= f.h {
                    let (dw, dh) = (f.w - w, f.h - h);
                    let score = (dw.min(dh), dw.max(dh));
                    if best.is_none_or(|(b, _, _)| score < b) {
                        best = Some((score, k, o));
                    }
                }
            }
        }
        let Some((_, k, o)) = best else { continue };
        let (w, h) = oriented(sizes[id], o);
        let used = Rect { x: free[k].x, y: free[k].y, w, h };
        out[id] = Some(((used.x, used.y), o));
        // Split every free rectangle the new one meets into its maximal remainders.
        let mut next = Vec::with_capacity(free.len() + 4);
        for f in free {
            if !f.intersects(&used) {
                next.push(f);
                continue;
            }
            if used.x > f.x {
                next.push(Rect { w: used.x - f.x, ..f });
            }
            if used.x + used.w < f.x + f.w {
                next.push(Rect { x: used.x + used.w, w: f.x + f.w - used.x - used.w, ..f });
            }
            if used.y > f.y {
                next.push(Rect { h: used.y - f.y, ..f });
            }
            if used.y + used.h < f.y + f.h {
                next.push(Rect { y: used.y + used.h, h: f.y + f.h - used.y - used.h, ..f });
            }
        }
        // Drop rectangles inside others (the first of two equal ones stays).
        free = next
            .iter()
            .enumerate()
            .filter(|&(i, r)| !next.iter().enumerate().any(|(j, o)| j != i && o.contains(r) && (o != r || j < i)))
            .map(|(_, r)| *r)
            .collect();
    }
    out
}

/// Occupied texels of an atlas, one bit each, for finding free space.
#[derive(Clone, Debug)]
pub struct FreeMap {
    width: u32,
    height: u32,
    words: usize,
    /// Row-major, `words` u64 per row; bit set = occupied.
    bits: Vec<u64>,
}

impl FreeMap {
    pub fn new(width: u32, height: u32) -> Self {
        let words = (width as usize).div_ceil(64);
        FreeMap { width, height, words, bits: vec![0; words * height as usize] }
    }

    /// Marks `r` occupied (clipped to the map).
    pub fn occupy(&mut self, r: Rect) {
        let (x1, y1) = ((r.x + r.w).min(self.width), (r.y + r.h).min(self.height));
        for y in r.y..y1 {
            let row = &mut self.bits[y as usize * self.words..(y as usize + 1) * self.words];
            for x in r.x..x1 {
                row[x as usize / 64] |= 1 << (x % 64);
            }
        }
    }

    /// Whether every texel of `r` is inside the map and free.
    pub fn is_free(&self, r: Rect) -> bool {
        if r.x + r.w > self.width || r.y + r.h > self.height {
            return false;
        }
        (r.y..r.y + r.h).all(|y| {
            let row = &self.bits[y as usize * self.words..(y as usize + 1) * self.words];
            (r.x..r.x + r.w).all(|x| row[x as usize / 64] & (1 << (x % 64)) == 0)
        })
    }

    /// Per row, the bit mask of the columns `x` where `w` free texels start (`x..x + w`).
    fn starts(&self, w: u32) -> Vec<u64> {
        let words = self.words;
        let mut out = vec![0u64; self.bits.len()];
        let mut run = vec![0u64; words];
        let mut tmp = vec![0u64; words];
        for y in 0..self.height as usize {
            let row = &self.bits[y * words..(y + 1) * words];
            // Free bits, columns past the width cleared.
            for (k, r) in run.iter_mut().enumerate() {
                *r = !row[k];
                let lo = k as u32 * 64;
                if lo + 64 > self.width {
                    let valid = self.width.saturating_sub(lo);
                    *r &= if valid == 0 { 0 } else { u64::MAX >> (64 - valid) };
                }
            }
            // run[x] = free at x..x+len; double len until it reaches w, then top up.
            let mut len = 1u32;
            while len < w {
                let step = len.min(w - len);
                shift_down(&run, step, &mut tmp);
                for (r, t) in run.iter_mut().zip(&tmp) {
                    *r &= t;
                }
                len += step;
            }
            out[y * words..(y + 1) * words].copy_from_slice(&run);
        }
        out
    }

    /// The first free place for a `w × h` rectangle, scanning rows top to bottom and columns
    /// left to right.
    pub fn first_fit(&self, w: u32, h: u32) -> Option<(u32, u32)> {
        if w == 0 || h == 0 || w > self.width || h > self.height {
            return None;
        }
        let starts = self.starts(w);
        let words = self.words;
        let row = |y: u32| &starts[y as usize * words..(y as usize + 1) * words];
        let mut acc = vec![0u64; words];
        let mut y0 = 0;
        'scan: while y0 + h <= self.height {
            acc.copy_from_slice(row(y0));
            for k in 0..h {
                let r = row(y0 + k);
                if r.iter().all(|&b| b == 0) {
                    // No window containing this row fits.
                    y0 += k + 1;
                    continue 'scan;
                }
                let mut any = 0;
                for (a, b) in acc.iter_mut().zip(r) {
                    *a &= b;
                    any |= *a;
                }
                if any == 0 {
                    y0 += 1;
                    continue 'scan;
                }
            }
            let k = acc.iter().position(|&b| b != 0)?;
            return Some((k as u32 * 64 + acc[k].trailing_zeros(), y0));
        }
        None
    }
}

/// `out[x] = bits[x + s]` over a row of bits (zeros shifted in at the end).
fn shift_down(bits: &[u64], s: u32, out: &mut [u64]) {
    let (wq, r) = ((s / 64) as usize, s % 64);
    for (k, o) in out.iter_mut().enumerate() {
        let lo = bits.get(k + wq).copied().unwrap_or(0);
        let hi = bits.get(k + wq + 1).copied().unwrap_or(0);
        *o = if r == 0 { lo } else { (lo >> r) | (hi << (64 - r)) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atlas::raster::{PixelRect, conservative_pixels};

    #[test]
    fn placement_offsets() {
        // Integer extent: aligned to the pixel grid, no extra column.
        assert_eq!(axis_placement(40.0), Some((40, 1.0)));
        let (n, o) = axis_placement(40.0 + 1e-5).unwrap();
        assert_eq!(n, 40);
        assert!((o - (1.0 - 0.5e-5)).abs() < 1e-12);
        assert_eq!(axis_placement(40.001).unwrap().0, 41);
        // Fractional extent: ⌈e⌉ pixels, centred.
        let (n, o) = axis_placement(2.4).unwrap();
        assert_eq!(n, 3);
        assert!((o - 1.3).abs() < 1e-12);
        // Zero extent (a point or a segment across the other axis): one pixel, centred.
        assert_eq!(axis_placement(0.0), Some((1, 1.5)));
        assert_eq!(axis_placement(f64::NAN), None);
        assert_eq!(place_fixed((7, 3)).rect_size(), (9, 5));
    }

    /// For random extents (integers up to float noise among them) and sub-pixel shapes, in
    /// both orientations, everything the chart touches conservatively at LOD 0..=6 lies in
    /// the rectangle's interior.
    #[test]
    fn placed_charts_touch_only_their_interior_at_every_lod() {
        let mut r = crate::sampling::Rng::new(3, 0);
        for i in 0..3000 {
            let e = match i % 4 {
                0 => {
                    DVec2::new((r.next_f64() * 50.0).round(), (r.next_f64() * 9.0).round())
                        + DVec2::splat(r.next_f64() * 2e-5 - 1e-5).max(DVec2::ZERO)
                }
                1 => DVec2::new(r.next_f64() * 0.8, r.next_f64() * 3.0),
                _ => DVec2::new(r.next_f64() * 40.0, r.next_f64() * 12.0),
            };
            let orient = if i % 2 == 0 { Orient::AsIs } else { Orient::Turned };
            let p = place_free(e).unwrap();
            let p = if orient == Orient::Turned { p.turned(false) } else { p };
            let rect_min = DVec2::new((r.next_f64() * 100.0).floor(), (r.next_f64() * 100.0).floor());
            let o = rect_min + p.offset;
            // Two triangles spanning the chart's bounding box (the worst case for coverage).
            let q = [DVec2::ZERO, DVec2::new(e.x, 0.0), e, DVec2::new(0.0, e.y)].map(|c| o + orient.apply(c, e));
            for k in 0..=6 {
                let s = (1u32 << k) as f64;
                let (rw, rh) = p.rect_size();
                let rect = PixelRect::new(
                    (rect_min.x * s) as i64,
                    (rect_min.y * s) as i64,
                    ((rect_min.x + rw as f64) * s) as i64,
                    ((rect_min.y + rh as f64) * s) as i64,
                );
                let interior =
                    PixelRect::new(rect.x0 + s as i64, rect.y0 + s as i64, rect.x1 - s as i64, rect.y1 - s as i64);
                // Rasterise against a big window so that nothing is clipped away.
                let window = PixelRect::new(-10, -10, 10_000, 10_000);
                for t in [[q[0], q[1], q[2]], [q[0], q[2], q[3]]] {
                    let t = t.map(|v| v * s);
                    for (x, y) in conservative_pixels(&t, window) {
                        assert!(
                            interior.contains(x, y),
                            "extent {e:?} {orient:?} lod {k}: ({x},{y}) outside {interior:?}"
                        );
                    }
                }
            }
        }
    }

    fn assert_disjoint_inside(p: &Packing, sizes: &[(u32, u32)]) -> f64 {
        let mut grid = vec![false; (p.width * p.height) as usize];
        let mut area = 0u64;
        for (i, &(x, y)) in p.positions.iter().enumerate() {
            let (w, h) = oriented(sizes[i], p.orient[i]);
            assert!(x + w <= p.width && y + h <= p.height);
            for yy in y..y + h {
                for xx in x..x + w {
                    let c = &mut grid[(yy * p.width + xx) as usize];
                    assert!(!*c, "rectangles overlap at ({xx},{yy})");
                    *c = true;
                }
            }
            area += (w * h) as u64;
        }
        area as f64 / (p.width as f64 * p.height as f64)
    }

    #[test]
    fn skyline_rectangles_are_disjoint_inside_and_deterministic() {
        let mut r = crate::sampling::Rng::new(11, 0);
        let sizes: Vec<(u32, u32)> = (0..3000)
            .map(|i| {
                if i % 10 == 0 {
                    (3 + (r.next_f64() * 60.0) as u32, 3 + (r.next_f64() * 40.0) as u32)
                } else {
                    (3 + (r.next_f64() * 6.0) as u32, 3 + (r.next_f64() * 6.0) as u32)
                }
            })
            .collect();
        let p = pack(&sizes, 16384).unwrap();
        assert_eq!(p, pack(&sizes, 16384).unwrap());
        let fill = assert_disjoint_inside(&p, &sizes);
        assert!(fill > 0.9, "fill {fill}");
        assert!((p.height as f64) < 1.3 * p.width as f64, "{}×{}", p.width, p.height);
        assert!(p.orient.contains(&Orient::Turned) && p.orient.contains(&Orient::AsIs));
    }

    /// Long thin rectangles longer than the square side are turned rather than widening the
    /// atlas: three 150 × 3 strips among 10 × 10 squares (square side 86).
    #[test]
    fn rotation_fits_long_strips() {
        let mut sizes = vec![(150u32, 3u32); 3];
        sizes.extend(vec![(10, 10); 60]);
        let p = pack(&sizes, 16384).unwrap();
        let fill = assert_disjoint_inside(&p, &sizes);
        assert_eq!(p.width, 86);
        assert!(p.orient[..3].iter().all(|&o| o == Orient::Turned), "{:?}", &p.orient[..3]);
        assert!(fill > 0.5, "fill {fill}");
    }

    #[test]
    fn too_large_is_reported_without_packing() {
        // Fits by area, not by shape: packed, found too tall, reported.
        assert_eq!(pack(&[(100, 100), (100, 100)], 150), Err((150, 200)));
        // Too large by area alone: reported before packing.
        assert_eq!(pack(&[(100, 100); 3], 150), Err((174, 173)));
        assert!(pack(&[(200, 160)], 150).is_err());
        assert!(pack(&[(100, 100)], 100).is_ok());
    }

    #[test]
    fn free_rectangles_take_exact_fits_first() {
        // Two freed slots, 4×3 and 6×5; rectangles 6×5, 3×4 (fits 4×3 turned), 2×2 (in the
        // remainder of nothing: both slots used exactly) → the last does not fit.
        let free = vec![Rect { x: 0, y: 0, w: 4, h: 3 }, Rect { x: 10, y: 10, w: 6, h: 5 }];
        let got = pack_into_free(free, &[(6, 5), (3, 4), (2, 2)]);
        assert_eq!(got[0], Some(((10, 10), Orient::AsIs)));
        assert_eq!(got[1], Some(((0, 0), Orient::Turned)));
        assert_eq!(got[2], None);
        // A smaller rectangle splits a slot; the rest of the slot stays usable.
        let got = pack_into_free(vec![Rect { x: 5, y: 5, w: 10, h: 4 }], &[(4, 4), (6, 4), (1, 1)]);
        assert_eq!(got[1], Some(((5, 5), Orient::AsIs)), "the larger first, into the corner");
        assert_eq!(got[0], Some(((11, 5), Orient::AsIs)), "then the exact fit left over");
        let placed: Vec<Rect> = got
            .iter()
            .zip([(4, 4), (6, 4)])
            .map(|(g, s)| {
                let ((x, y), o) = g.unwrap();
                let (w, h) = oriented(s, o);
                Rect { x, y, w, h }
            })
            .collect();
        assert!(!placed[0].intersects(&placed[1]));
        assert!(placed.iter().all(|r| Rect { x: 5, y: 5, w: 10, h: 4 }.contains(r)));
        assert_eq!(got[2], None);
    }

    #[test]
    fn free_map_finds_the_first_hole() {
        let mut m = FreeMap::new(130, 40);
        m.occupy(Rect { x: 0, y: 0, w: 130, h: 10 });
        m.occupy(Rect { x: 0, y: 10, w: 70, h: 30 });
        m.occupy(Rect { x: 75, y: 10, w: 55, h: 5 });
        // A 5-wide column free from row 10, a 60-wide region from row 15.
        assert_eq!(m.first_fit(5, 30), Some((70, 10)));
        assert_eq!(m.first_fit(6, 2), Some((70, 15)));
        assert_eq!(m.first_fit(60, 25), Some((70, 15)));
        assert_eq!(m.first_fit(61, 1), None);
        assert_eq!(m.first_fit(60, 26), None);
        assert!(m.is_free(Rect { x: 70, y: 15, w: 60, h: 25 }));
        assert!(!m.is_free(Rect { x: 69, y: 15, w: 2, h: 2 }));
        // Brute force agrees on random maps.
        let mut r = crate::sampling::Rng::new(5, 0);
        for _ in 0..40 {
            let mut m = FreeMap::new(150, 50);
            for _ in 0..30 {
                let (x, y) = ((r.next_f64() * 150.0) as u32, (r.next_f64() * 50.0) as u32);
                m.occupy(Rect { x, y, w: 1 + (r.next_f64() * 30.0) as u32, h: 1 + (r.next_f64() * 10.0) as u32 });
            }
            for (w, h) in [(1, 1), (3, 7), (20, 4), (70, 2), (9, 9)] {
                let brute =
                    (0..=50 - h).find_map(|y| (0..=150 - w).find(|&x| m.is_free(Rect { x, y, w, h })).map(|x| (x, y)));
                assert_eq!(m.first_fit(w, h), brute, "{w}×{h}");
            }
        }
    }
}
