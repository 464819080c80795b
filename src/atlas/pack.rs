//! Chart rectangles and skyline packing.
//!
//! **Placement.** A chart's local UVs span `[0, e]` on each axis (LOD-0 texels). Its
//! rectangle has `n = max(1, ⌈e − TOUCH_TOL/64⌉)` interior pixels on that axis plus a
//! [`BORDER`] of one empty texel on each side, so the side is `n + 2`, and the chart is
//! centred in the interior: local coordinate 0 goes to `rect_min + 1 + (n − e)/2`. Its
//! geometry then spans `[1 + d, 1 + n − d]` (relative to `rect_min`) with `d = (n − e)/2 ≥
//! −TOUCH_TOL/8`, so it reaches at most `TOUCH_TOL/8` into a border pixel: less than the
//! raster's touch tolerance, so every pixel the chart touches conservatively is an interior
//! pixel. (The `−TOUCH_TOL/4` lets an extent that is an integer up to float noise — a 4 m
//! wall at 0.1 m texels — use exactly `e` pixels, aligned to the pixel grid, instead of
//! `e + 1` half-covered ones.) TEXCOORD_1 blocks keep their validated pixel grid: their
//! interior is given and their offset is exactly one texel.
//!
//! **Gutters.** Rectangles never overlap, so between the coverage of two charts there are at
//! least the two border texels: bilinear sampling at LOD 0 (reading the 2×2 texels around a
//! point, all within one texel of a covered pixel) never mixes charts. At LOD k the same
//! layout scaled by 2^k leaves 2·2^k texels.
//!
//! **Packing.** Skyline bottom-left: rectangles sorted by height, then width (both
//! decreasing), then chart id; each goes where its top edge is lowest, leftmost on ties.
//! The atlas width is `max(widest rectangle, ⌈√(total area)⌉)`, aiming at a square.
//! Everything is integer arithmetic: deterministic.

use glam::DVec2;

use super::raster::TOUCH_TOL;

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

/// A packed atlas: its size and each rectangle's top-left corner (in input order).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Packing {
    pub width: u32,
    pub height: u32,
    pub positions: Vec<(u32, u32)>,
}

#[derive(Clone, Copy, Debug)]
struct Seg {
    x: u32,
    y: u32,
    w: u32,
}

/// Packs rectangles of the given sizes. `Err((width, height))` gives the size the atlas
/// would need when it exceeds `max_size` on either side (nothing of that size is allocated).
pub fn pack(sizes: &[(u32, u32)], max_size: u32) -> Result<Packing, (u32, u32)> {
    if sizes.is_empty() {
        return Ok(Packing { width: 0, height: 0, positions: Vec::new() });
    }
    let max_w = sizes.iter().map(|s| s.0).max().unwrap_or(0);
    let max_h = sizes.iter().map(|s| s.1).max().unwrap_or(0);
    let total: u64 = sizes.iter().map(|&(w, h)| w as u64 * h as u64).sum();
    let side = (total as f64).sqrt().ceil() as u64;
    let width = (max_w as u64).max(side);
    if max_w > max_size || max_h > max_size || total > max_size as u64 * max_size as u64 {
        let w = width.min(u32::MAX as u64) as u32;
        let h = total.div_ceil(width).max(max_h as u64).min(u32::MAX as u64) as u32;
        return Err((w, h));
    }
    let mut order: Vec<usize> = (0..sizes.len()).collect();
    order.sort_by(|&a, &b| sizes[b].1.cmp(&sizes[a].1).then(sizes[b].0.cmp(&sizes[a].0)).then(a.cmp(&b)));
    let p = skyline(sizes, &order, width as u32);
    if p.height <= max_size {
        return Ok(p);
    }
    // Too tall for the limit: use all the width we may.
    let p = skyline(sizes, &order, max_size);
    if p.height <= max_size { Ok(p) } else { Err((p.width, p.height)) }
}

fn skyline(sizes: &[(u32, u32)], order: &[usize], width: u32) -> Packing {
    let mut sky = vec![Seg { x: 0, y: 0, w: width }];
    let mut positions = vec![(0, 0); sizes.len()];
    let mut height = 0;
    for &id in order {
        let (w, h) = sizes[id];
        // Lowest position, leftmost on ties.
        let mut best: Option<(u32, usize)> = None;
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
            if best.is_none_or(|(by, _)| y < by) {
                best = Some((y, i));
            }
        }
        let (y, i) = best.expect("every rectangle fits the atlas width");
        let x = sky[i].x;
        positions[id] = (x, y);
        height = height.max(y + h);
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
        sky.splice(i..j, [Seg { x, y: y + h, w }]);
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
    Packing { width, height, positions }
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

    /// For random extents (integers up to float noise among them) and sub-pixel shapes,
    /// everything the chart touches conservatively at LOD 0..=6 lies in the rectangle's
    /// interior.
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
            let p = place_free(e).unwrap();
            let rect_min = DVec2::new((r.next_f64() * 100.0).floor(), (r.next_f64() * 100.0).floor());
            let o = rect_min + p.offset;
            // Two triangles spanning the chart's bounding box (the worst case for coverage).
            let q = [o, o + DVec2::new(e.x, 0.0), o + e, o + DVec2::new(0.0, e.y)];
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
                        assert!(interior.contains(x, y), "extent {e:?} lod {k}: ({x},{y}) outside {interior:?}");
                    }
                }
            }
        }
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
        let mut grid = vec![false; (p.width * p.height) as usize];
        let mut area = 0u64;
        for (i, &(x, y)) in p.positions.iter().enumerate() {
            let (w, h) = sizes[i];
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
        let fill = area as f64 / (p.width as f64 * p.height as f64);
        assert!(fill > 0.85, "fill {fill}");
        assert!((p.height as f64) < 1.3 * p.width as f64, "{}×{}", p.width, p.height);
    }

    #[test]
    fn too_large_is_reported_without_packing() {
        // Fits by area, not by shape: packed, found too tall, reported.
        assert_eq!(pack(&[(100, 100), (100, 100)], 150), Err((150, 200)));
        // Too large by area alone: reported before packing.
        assert_eq!(pack(&[(100, 100); 3], 150), Err((174, 173)));
        assert!(pack(&[(200, 10)], 150).is_err());
        assert!(pack(&[(100, 100)], 100).is_ok());
    }
}
