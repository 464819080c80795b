//! Chart rectangles and footprints, and first-fit packing of footprints.
//!
//! **Placement.** A chart's local UVs span `[0, e]` on each axis (LOD-0 texels). Its
//! rectangle has `n = max(1, ⌈e − TOUCH_TOL/64⌉)` interior pixels on that axis plus a
//! [`BORDER`] of one texel on each side, so the side is `n + 2`, and the chart is centred in
//! the interior: local coordinate 0 goes to `rect_min + 1 + (n − e)/2`. Its geometry then
//! spans `[1 + d, 1 + n − d]` (relative to `rect_min`) with `d = (n − e)/2 ≥ −TOUCH_TOL/128`,
//! so it reaches at most `TOUCH_TOL/128` into a border pixel. (The `−TOUCH_TOL/64` lets an
//! extent that is an integer up to float noise — a 4 m wall at 0.1 m texels — use exactly
//! `e` pixels, aligned to the pixel grid, instead of `e + 1` half-covered ones.) Faces are
//! rasterised clipped to their chart's interior at every LOD. TEXCOORD_1 blocks keep their
//! validated pixel grid: their interior is given and their offset is exactly one texel. A
//! chart may be placed turned by quarter turns ([`Orient`]), which keep a block's pixel grid.
//!
//! **Footprints and gutters.** A chart claims, in its rectangle, the LOD-0 pixels its faces
//! reach by more than [`FOOTPRINT_TOL`] (every pixel they touch at LOD 0, and the LOD-0
//! parent of every pixel they touch at LOD 1..=6, see [`super::raster::reached`]) and the ring of
//! pixels around those: its [`Footprint`]. Footprints never overlap, so the covered pixels
//! of two charts are at least three pixels apart (two empty pixels between them): bilinear
//! sampling at LOD 0 (the 2×2 texels around a point, all within one texel of a covered
//! pixel) reads only texels and gutter pixels of its own chart, and a gutter pixel is next to
//! one chart only. At LOD k the same layout scaled by 2^k leaves 2·2^k texels, less what a
//! face reaches beyond its claimed pixels at finer LODs (far less than a pixel: float
//! rounding of the stored UVs, slivers thinner than `FOOTPRINT_TOL` along a pixel edge).
//! Rectangles may overlap: a thin diagonal chart leaves room in its rectangle's corners,
//! a triangle half its rectangle, and other charts take it.
//!
//! **Packing** ([`pack`]). Footprints by decreasing longer side, then shorter side, then id;
//! each goes to the first place, rows top to bottom and columns left to right, where it
//! meets no footprint placed before (found on the free runs of every row), as it is or
//! turned by a half (whichever reaches less low, then leftmost): a large chart's holes and
//! concave sides, a thin diagonal chart's corners and a triangle's empty half take smaller
//! charts. A footprint wider than the atlas is turned by a quarter. The atlas width is
//! `max(widest footprint's shorter side, ⌈√(total footprint area)⌉)`, aiming at a square;
//! an atlas more than 1.2 times taller than wide is packed again at the width of the square
//! of its area and at one widest footprint wider, and the smallest kept. Integer
//! arithmetic: deterministic.
//!
//! Updates of an existing atlas place footprints on a bitmap of the texels the kept charts
//! claim ([`super::free`]).

use glam::DVec2;

use super::raster::{PixelRect, TOUCH_TOL, conservative};

/// Empty texels on each side of a chart's interior.
pub const BORDER: u32 = 1;

/// How far (LOD-0 pixels) a face must reach into a pixel for its chart's footprint to claim
/// it: below `TOUCH_TOL / 64`, so a pixel touched at any LOD up to 6 has its LOD-0 parent
/// claimed, and above the `TOUCH_TOL / 128` a chart of integer extent reaches into its border
/// (a wall aligned to the pixel grid claims no extra row).
pub const FOOTPRINT_TOL: f64 = TOUCH_TOL / 96.0;

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

    /// The same chart turned by `o`.
    pub fn oriented(&self, o: Orient, fixed: bool) -> Placement {
        let interior = oriented(self.interior, o);
        if fixed {
            return place_fixed(interior);
        }
        // Centred on both axes: a half turn keeps the offsets, a quarter swaps them.
        let offset = if o.swaps() { DVec2::new(self.offset.y, self.offset.x) } else { self.offset };
        Placement { interior, offset }
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

/// How a chart is turned in its rectangle: counter-clockwise quarter turns, which map the
/// pixel grid onto itself.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Orient {
    #[default]
    AsIs,
    /// Local `(x, y) ↦ (y, e.x − x)` for a chart of extent `e`.
    Quarter,
    /// `(x, y) ↦ (e.x − x, e.y − y)`.
    Half,
    /// `(x, y) ↦ (e.y − y, x)`.
    ThreeQuarters,
}

impl Orient {
    pub const ALL: [Orient; 4] = [Orient::AsIs, Orient::Quarter, Orient::Half, Orient::ThreeQuarters];

    /// Whether the turn swaps the axes.
    pub fn swaps(self) -> bool {
        matches!(self, Orient::Quarter | Orient::ThreeQuarters)
    }

    /// A local UV of a chart of extent `extent`, in the chart's turned frame.
    #[inline]
    pub fn apply(self, p: DVec2, extent: DVec2) -> DVec2 {
        match self {
            Orient::AsIs => p,
            Orient::Quarter => DVec2::new(p.y, extent.x - p.x),
            Orient::Half => extent - p,
            Orient::ThreeQuarters => DVec2::new(extent.y - p.y, p.x),
        }
    }

    /// Extent of the chart in its turned frame.
    pub fn extent(self, extent: DVec2) -> DVec2 {
        if self.swaps() { DVec2::new(extent.y, extent.x) } else { extent }
    }

    /// Pixel `(x, y)` of a `w × h` rectangle (as placed unturned) in the turned rectangle:
    /// the turn of the chart about its centred placement, pixel for pixel.
    #[inline]
    fn pixel(self, (x, y): (u32, u32), (w, h): (u32, u32)) -> (u32, u32) {
        match self {
            Orient::AsIs => (x, y),
            Orient::Quarter => (y, w - 1 - x),
            Orient::Half => (w - 1 - x, h - 1 - y),
            Orient::ThreeQuarters => (h - 1 - y, x),
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

/// The LOD-0 pixels a chart claims in its rectangle (see the module docs), one bit each.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Footprint {
    /// The rectangle's size.
    pub size: (u32, u32),
    words: usize,
    /// Row-major, `words` u64 per row; bit set = claimed.
    bits: Vec<u64>,
}

impl Footprint {
    fn empty(size: (u32, u32)) -> Footprint {
        let words = (size.0 as usize).div_ceil(64);
        Footprint { size, words, bits: vec![0; words * size.1 as usize] }
    }

    /// The whole rectangle (a TEXCOORD_1 block, which may cover any pixel of its interior).
    pub fn full(size: (u32, u32)) -> Footprint {
        let mut f = Footprint::empty(size);
        for y in 0..size.1 {
            for x in 0..size.0 {
                f.set(x, y);
            }
        }
        f
    }

    /// The footprint of triangles given relative to their rectangle's top-left corner (a
    /// rectangle of `size`, interior one [`BORDER`] in): the interior pixels they reach by
    /// more than [`FOOTPRINT_TOL`] and the ring around them.
    pub fn of_triangles(tris: impl Iterator<Item = [DVec2; 3]>, size: (u32, u32)) -> Footprint {
        let (w, h) = (size.0 as i64, size.1 as i64);
        let b = BORDER as i64;
        let interior = PixelRect::new(b, b, w - b, h - b);
        let mut reached = Footprint::empty(size);
        for t in tris {
            super::raster::reached(&t, interior, FOOTPRINT_TOL, |x, y| reached.set(x as u32, y as u32));
        }
        // The ring: each row grown by a pixel either way (bits carried across words), then
        // each row ORed with its neighbours. Reached pixels are interior ones, so the ring
        // stays inside the rectangle.
        let words = reached.words;
        let mut grown = vec![0u64; reached.bits.len()];
        for (src, dst) in reached.bits.chunks(words.max(1)).zip(grown.chunks_mut(words.max(1))) {
            for k in 0..words {
                let left = src[k] << 1 | if k > 0 { src[k - 1] >> 63 } else { 0 };
                let right = src[k] >> 1 | if k + 1 < words { src[k + 1] << 63 } else { 0 };
                dst[k] = src[k] | left | right;
            }
        }
        let mut f = Footprint::empty(size);
        let rows = size.1 as usize;
        for y in 0..rows {
            for k in 0..words {
                let mut v = grown[y * words + k];
                if y > 0 {
                    v |= grown[(y - 1) * words + k];
                }
                if y + 1 < rows {
                    v |= grown[(y + 1) * words + k];
                }
                f.bits[y * words + k] = v;
            }
        }
        f
    }

    /// [`Footprint::oriented`] by a half turn, a word at a time: rows in reverse order, each
    /// row's bits reversed (`x ↦ w − 1 − x`).
    fn half_turned(&self) -> Footprint {
        let mut f = Footprint::empty(self.size);
        let words = self.words;
        // Reversing a row of `words · 64` bits maps x to words·64 − 1 − x: shift down by the
        // unused bits at the end to get w − 1 − x.
        let pad = (words * 64) as u32 - self.size.0;
        let mut reversed = vec![0u64; words];
        for y in 0..self.size.1 as usize {
            let src = &self.bits[y * words..(y + 1) * words];
            for (k, r) in reversed.iter_mut().enumerate() {
                *r = src[words - 1 - k].reverse_bits();
            }
            let dst = &mut f.bits[(self.size.1 as usize - 1 - y) * words..(self.size.1 as usize - y) * words];
            for k in 0..words {
                let hi = if pad == 0 { 0 } else { reversed.get(k + 1).map_or(0, |&w| w << (64 - pad)) };
                dst[k] = reversed[k] >> pad | hi;
            }
        }
        f
    }

    /// Row `y`'s claimed columns as runs `[start, end)`, left to right.
    fn runs(&self, y: u32) -> impl Iterator<Item = (u32, u32)> + '_ {
        let row = &self.bits[y as usize * self.words..(y as usize + 1) * self.words];
        let mut x = 0u32;
        std::iter::from_fn(move || {
            // Next set bit at or after x, then the next clear one.
            let next = |x: u32, set: bool| -> u32 {
                let mut k = x as usize / 64;
                if k >= row.len() {
                    return x;
                }
                let flip = |w: u64| if set { w } else { !w };
                let mut w = flip(row[k]) & (u64::MAX << (x % 64));
                while w == 0 {
                    k += 1;
                    if k == row.len() {
                        return (k * 64) as u32;
                    }
                    w = flip(row[k]);
                }
                (k * 64) as u32 + w.trailing_zeros()
            };
            let start = next(x, true);
            if start >= self.size.0 {
                return None;
            }
            let end = next(start, false).min(self.size.0);
            x = end;
            Some((start, end))
        })
    }

    #[inline]
    fn set(&mut self, x: u32, y: u32) {
        self.bits[y as usize * self.words + x as usize / 64] |= 1 << (x % 64);
    }

    #[inline]
    pub fn get(&self, x: u32, y: u32) -> bool {
        self.bits[y as usize * self.words + x as usize / 64] & (1 << (x % 64)) != 0
    }

    /// Claimed pixels.
    pub fn area(&self) -> u64 {
        self.bits.iter().map(|b| b.count_ones() as u64).sum()
    }

    /// The footprint of the same chart turned by `o` (the footprint of the chart as placed
    /// unturned, pixel for pixel: turns are exact on the pixel grid).
    pub fn oriented(&self, o: Orient) -> Footprint {
        match o {
            Orient::AsIs => self.clone(),
            Orient::Half => self.half_turned(),
            _ => self.turned_by_pixels(o),
        }
    }

    /// [`Footprint::oriented`] pixel by pixel.
    fn turned_by_pixels(&self, o: Orient) -> Footprint {
        let mut f = Footprint::empty(oriented(self.size, o));
        for y in 0..self.size.1 {
            for x in 0..self.size.0 {
                if self.get(x, y) {
                    let (u, v) = o.pixel((x, y), self.size);
                    f.set(u, v);
                }
            }
        }
        f
    }
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

/// Size of a rectangle in an orientation.
pub fn oriented((w, h): (u32, u32), o: Orient) -> (u32, u32) {
    if o.swaps() { (h, w) } else { (w, h) }
}

/// Packs footprints (as placed unturned). `Err((width, height))` gives the size the atlas
/// would need when it exceeds `max_size` on either side (nothing of that size is allocated).
pub fn pack(footprints: &[Footprint], max_size: u32) -> Result<Packing, (u32, u32)> {
    if footprints.is_empty() {
        return Ok(Packing { width: 0, height: 0, positions: Vec::new(), orient: Vec::new() });
    }
    let short = footprints.iter().map(|f| f.size.0.min(f.size.1)).max().unwrap_or(0);
    let long = footprints.iter().map(|f| f.size.0.max(f.size.1)).max().unwrap_or(0);
    let total: u64 = footprints.iter().map(Footprint::area).sum();
    let side = (total as f64).sqrt().ceil() as u64;
    let width = (short as u64).max(side);
    if short > max_size || total > max_size as u64 * max_size as u64 {
        let w = width.min(u32::MAX as u64) as u32;
        let h = total.div_ceil(width).max(long.min(w) as u64).min(u32::MAX as u64) as u32;
        return Err((w, h));
    }
    let too_large = (width as u32, long);
    let mut p = pack_strip(footprints, width as u32).ok_or(too_large)?;
    // Far taller than wide (a few large charts that do not tile the width, as a room's
    // walls): packed again at the square's width and at room for one more of the widest
    // footprint in a row, the smallest atlas kept.
    if p.height as u64 * 5 > p.width as u64 * 6 {
        let square = (p.width as f64 * p.height as f64).sqrt().ceil() as u32;
        let widest = footprints.iter().map(|f| f.size.0.max(f.size.1)).max().unwrap_or(0);
        for w in [square, p.width.saturating_add(widest)] {
            if let Some(q) = pack_strip(footprints, w.min(max_size))
                && (q.width as u64 * q.height as u64) < p.width as u64 * p.height as u64
            {
                p = q;
            }
        }
    }
    if p.height <= max_size {
        return Ok(p);
    }
    // Too tall for the limit: use all the width we may.
    let p = pack_strip(footprints, max_size).ok_or(too_large)?;
    if p.height <= max_size { Ok(p) } else { Err((p.width, p.height)) }
}

/// Packs footprints into a strip of the given width (as [`pack`] orders them), as tall as it
/// needs; `None` when a footprint is wider than the strip both ways.
pub fn pack_strip(footprints: &[Footprint], width: u32) -> Option<Packing> {
    if footprints.iter().any(|f| f.size.0.min(f.size.1) > width) {
        return None;
    }
    let mut order: Vec<usize> = (0..footprints.len()).collect();
    let key = |s: (u32, u32)| (s.0.max(s.1), s.0.min(s.1));
    order.sort_by(|&a, &b| key(footprints[b].size).cmp(&key(footprints[a].size)).then(a.cmp(&b)));
    Some(first_fits(footprints, &order, width))
}

/// The free pixels of a strip of atlas rows, as runs per row, for first-fit placement of
/// footprints. Rows past the last one held are free.
struct FreeRuns {
    width: u32,
    /// Per row, its free runs `[start, end)`, increasing.
    rows: Vec<Vec<(u32, u32)>>,
    /// Per row, its longest free run.
    longest: Vec<u32>,
    /// Per run length, a row above which no row has a free run that long (rows only lose
    /// free pixels, so it only moves down).
    first_row: Vec<usize>,
    /// Per shape (its row spans) already placed, the row of its last fit: no later fit of
    /// the same shape is above it (many charts have the same small shape).
    last_fit: std::collections::HashMap<Vec<(u32, u32)>, usize>,
}

/// A footprint as [`FreeRuns::first_fit`] places it: per row, the span from its first to its
/// last claimed column (`(0, 0)` for a row with none).
struct Spans {
    size: (u32, u32),
    rows: Vec<(u32, u32)>,
    /// Rows with a span, longest span first: the most constraining rows are tried first.
    order: Vec<u32>,
}

impl Spans {
    fn of(f: &Footprint) -> Spans {
        let rows = (0..f.size.1)
            .map(|y| {
                let mut runs = f.runs(y);
                match runs.next() {
                    Some((a, b)) => (a, runs.last().map_or(b, |r| r.1)),
                    None => (0, 0),
                }
            })
            .collect::<Vec<(u32, u32)>>();
        let mut order: Vec<u32> = (0..f.size.1).filter(|&r| rows[r as usize].1 > rows[r as usize].0).collect();
        order.sort_by_key(|&r| (std::cmp::Reverse(rows[r as usize].1 - rows[r as usize].0), r));
        Spans { size: f.size, rows, order }
    }
}

impl FreeRuns {
    fn new(width: u32) -> FreeRuns {
        FreeRuns {
            width,
            rows: Vec::new(),
            longest: Vec::new(),
            first_row: vec![0; width as usize + 1],
            last_fit: Default::default(),
        }
    }

    /// The first row with a free run of `len` pixels.
    fn first_row(&mut self, len: u32) -> usize {
        let mut y = self.first_row[len as usize];
        while self.longest(y) < len {
            y += 1;
        }
        self.first_row[len as usize] = y;
        y
    }

    fn longest(&self, y: usize) -> u32 {
        self.longest.get(y).copied().unwrap_or(self.width)
    }

    /// The first place `(x, y)` (rows top to bottom, columns left to right) where every row
    /// span of `s` lies on free pixels, if its row is at most `last_row`.
    fn first_fit(&mut self, s: &Spans, last_row: usize) -> Option<(u32, u32)> {
        let mut allowed: Vec<(u32, u32)> = Vec::new();
        let mut next: Vec<(u32, u32)> = Vec::new();
        let mut fits: Vec<(u32, u32)> = Vec::new();
        let last = self.width - s.size.0;
        let mut start = self.last_fit.get(&s.rows).copied().unwrap_or(0);
        for &r in &s.order {
            let (a, b) = s.rows[r as usize];
            start = start.max(self.first_row(b - a).saturating_sub(r as usize));
        }
        for y in start..=last_row {
            // Cheap refusal first: every row needs a free run as long as its span.
            if s.order.iter().any(|&r| {
                let (a, b) = s.rows[r as usize];
                self.longest(y + r as usize) < b - a
            }) {
                continue;
            }
            // Columns allowed by every row: intervals of x, intersected row by row.
            allowed.clear();
            allowed.push((0, last + 1));
            for &r in &s.order {
                let r = r as usize;
                let (a, b) = s.rows[r];
                next.clear();
                let whole = [(0, self.width)];
                let runs: &[(u32, u32)] = self.rows.get(y + r).map_or(&whole, |v| v.as_slice());
                let (mut i, mut j) = (0, 0);
                // Row r allows x in [start − a, end − b] for each run long enough; only the
                // runs that can meet the columns still allowed are read.
                let (lo_x, hi_x) = (allowed[0].0, allowed[allowed.len() - 1].1);
                let first = runs.partition_point(|&(_, e0)| e0 < lo_x + b);
                fits.clear();
                fits.extend(
                    runs[first..]
                        .iter()
                        .take_while(|&&(s0, _)| s0 < hi_x + a)
                        .filter(|&&(s0, e0)| e0 >= b && e0 - s0 >= b - a)
                        .map(|&(s0, e0)| (s0.saturating_sub(a), (e0 - b + 1).min(last + 1)))
                        .filter(|&(lo, hi)| lo < hi),
                );
                while i < allowed.len() && j < fits.len() {
                    let lo = allowed[i].0.max(fits[j].0);
                    let hi = allowed[i].1.min(fits[j].1);
                    if lo < hi {
                        next.push((lo, hi));
                    }
                    if allowed[i].1 < fits[j].1 { i += 1 } else { j += 1 }
                }
                std::mem::swap(&mut allowed, &mut next);
                if allowed.is_empty() {
                    break;
                }
            }
            if let Some(&(x, _)) = allowed.first() {
                self.last_fit.insert(s.rows.clone(), y);
                return Some((x, y as u32));
            }
        }
        None
    }

    /// Marks the claimed pixels of footprint `f` at corner `(x, y)` used.
    fn occupy(&mut self, f: &Footprint, (x, y): (u32, u32)) {
        let end = y as usize + f.size.1 as usize;
        while self.rows.len() < end {
            self.rows.push(vec![(0, self.width)]);
            self.longest.push(self.width);
        }
        for r in 0..f.size.1 {
            let row = &mut self.rows[(y + r) as usize];
            for (start, end) in f.runs(r) {
                // Take [x + start, x + end) out of the free run holding it.
                let (a, b) = (x + start, x + end);
                let k = row.partition_point(|&(_, e0)| e0 < b);
                if row.get(k).is_some_and(|&(s0, e0)| s0 <= a && b <= e0) {
                    let (s0, e0) = row[k];
                    let mut parts = Vec::with_capacity(2);
                    if s0 < a {
                        parts.push((s0, a));
                    }
                    if b < e0 {
                        parts.push((b, e0));
                    }
                    row.splice(k..k + 1, parts);
                }
            }
            self.longest[(y + r) as usize] = row.iter().map(|&(s0, e0)| e0 - s0).max().unwrap_or(0);
        }
    }
}

/// One turn of a footprint at its first fit.
struct Fit {
    /// Its lowest row (one past) and its column: the smaller the better.
    score: (u32, u32),
    corner: (u32, u32),
    orient: Orient,
    footprint: Footprint,
}

/// Places footprints in `order` at their first fits in a strip of `width` (see the module docs).
fn first_fits(footprints: &[Footprint], order: &[usize], width: u32) -> Packing {
    let mut free = FreeRuns::new(width);
    let mut positions = vec![(0, 0); footprints.len()];
    let mut orient = vec![Orient::AsIs; footprints.len()];
    let mut height = 0;
    for &id in order {
        // Half turns (a triangle's empty half takes the next one's full half); quarter turns
        // only for a footprint wider than the strip: they cost a search of their own each
        // (shapes unlike the ones placed before) and gave no fill on real scenes.
        let turns: &[Orient] = if footprints[id].size.0 <= width {
            &[Orient::AsIs, Orient::Half]
        } else {
            &[Orient::Quarter, Orient::ThreeQuarters]
        };
        let mut best: Option<Fit> = None;
        let mut tried: Option<Vec<(u32, u32)>> = None;
        for &o in turns {
            let f = footprints[id].oriented(o);
            if f.size.0 > width {
                continue;
            }
            // A turn with the same row spans has the same first fit.
            let spans = Spans::of(&f);
            if tried.as_ref().is_some_and(|t| *t == spans.rows) {
                continue;
            }
            // Only a fit whose lowest row is no lower than the best one's can do better.
            let last_row = best.as_ref().map_or(usize::MAX, |b| b.score.0.saturating_sub(f.size.1) as usize);
            let fit = free.first_fit(&spans, last_row);
            tried = Some(spans.rows);
            let Some((x, y)) = fit else { continue };
            let score = (y + f.size.1, x);
            if best.as_ref().is_none_or(|b| score < b.score) {
                best = Some(Fit { score, corner: (x, y), orient: o, footprint: f });
            }
        }
        let fit = best.expect("every footprint fits the strip's width in some turn");
        free.occupy(&fit.footprint, fit.corner);
        positions[id] = fit.corner;
        orient[id] = fit.orient;
        height = height.max(fit.score.0);
    }
    Packing { width, height, positions, orient }
}

#[cfg(test)]
pub(crate) mod tests;
