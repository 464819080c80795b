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
/// every turn, everything a chart touches conservatively at LOD 0..=6 lies in its
/// rectangle's interior, and the LOD-0 parent of every such pixel is claimed by its
/// footprint with the whole ring around it (the gutter). The footprint of a turned chart
/// is the turned footprint. Charts: the two triangles spanning the bounding box (the
/// worst case for coverage), or one of them (half the rectangle left to others).
#[test]
fn footprints_hold_what_charts_touch_at_every_lod() {
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
        let orient = Orient::ALL[i % 4];
        let unturned = place_free(e).unwrap();
        let p = unturned.oriented(orient, false);
        let corners = [DVec2::ZERO, DVec2::new(e.x, 0.0), e, DVec2::new(0.0, e.y)];
        let tris: Vec<[DVec2; 3]> = if i % 3 == 0 {
            vec![[corners[0], corners[1], corners[2]]]
        } else {
            vec![[corners[0], corners[1], corners[2]], [corners[0], corners[2], corners[3]]]
        };
        let footprint =
            Footprint::of_triangles(tris.iter().map(|t| t.map(|c| c + unturned.offset)), unturned.rect_size())
                .oriented(orient);
        assert_eq!(footprint.size, p.rect_size());
        let rect_min = DVec2::new((r.next_f64() * 100.0).floor(), (r.next_f64() * 100.0).floor());
        let o = rect_min + p.offset;
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
            for t in &tris {
                let t = t.map(|v| (o + orient.apply(v, e)) * s);
                for (x, y) in conservative_pixels(&t, window) {
                    assert!(interior.contains(x, y), "extent {e:?} {orient:?} lod {k}: ({x},{y}) outside {interior:?}");
                    let (px, py) = ((x >> k) - rect_min.x as i64, (y >> k) - rect_min.y as i64);
                    for (dx, dy) in (-1..=1).flat_map(|dx| (-1..=1).map(move |dy| (dx, dy))) {
                        assert!(
                            footprint.get((px + dx) as u32, (py + dy) as u32),
                            "extent {e:?} {orient:?} lod {k}: ({x},{y}) not claimed with its ring"
                        );
                    }
                }
            }
        }
    }
}

/// The half turn a word at a time is the half turn pixel by pixel, across word
/// boundaries and whatever the padding of the last word.
#[test]
fn half_turn_by_words_is_the_turn_by_pixels() {
    let mut r = crate::sampling::Rng::new(5, 0);
    for w in [1, 2, 63, 64, 65, 127, 128, 130, 200] {
        let mut f = Footprint::empty((w, 7));
        for y in 0..7 {
            for x in 0..w {
                if r.next_f64() < 0.3 {
                    f.set(x, y);
                }
            }
        }
        assert_eq!(f.half_turned(), f.turned_by_pixels(Orient::Half), "width {w}");
    }
}

/// Footprints placed by a packing lie inside the atlas and never overlap; returns the
/// claimed share of the atlas.
fn assert_disjoint_inside(p: &Packing, footprints: &[Footprint]) -> f64 {
    let mut grid = vec![false; (p.width * p.height) as usize];
    let mut area = 0u64;
    for (i, &(x, y)) in p.positions.iter().enumerate() {
        let f = footprints[i].oriented(p.orient[i]);
        assert!(x + f.size.0 <= p.width && y + f.size.1 <= p.height);
        for yy in 0..f.size.1 {
            for xx in 0..f.size.0 {
                if f.get(xx, yy) {
                    let c = &mut grid[((y + yy) * p.width + x + xx) as usize];
                    assert!(!*c, "footprints overlap at ({},{})", x + xx, y + yy);
                    *c = true;
                    area += 1;
                }
            }
        }
    }
    area as f64 / (p.width as f64 * p.height as f64)
}

/// A right triangle's footprint in a `w × h` rectangle (legs along the top and left).
pub(crate) fn triangle(w: u32, h: u32) -> Footprint {
    let e = DVec2::new(w as f64 - 2.0, h as f64 - 2.0);
    let t = [DVec2::ZERO, DVec2::new(e.x, 0.0), DVec2::new(0.0, e.y)].map(|c| c + DVec2::ONE);
    Footprint::of_triangles(std::iter::once(t), (w, h))
}

/// Random rectangles and triangles: footprints disjoint and inside, the packing
/// deterministic, about square, using both turns. The claimed share is what a packer
/// leaves unused besides the footprints (a rectangle-only packer reaches ~0.9 on these
/// rectangles; triangles, half their rectangles, must nest).
#[test]
fn packed_footprints_are_disjoint_inside_and_deterministic() {
    let mut r = crate::sampling::Rng::new(11, 0);
    let footprints: Vec<Footprint> = (0..3000)
        .map(|i| {
            let (w, h) = if i % 10 == 0 {
                (3 + (r.next_f64() * 60.0) as u32, 3 + (r.next_f64() * 40.0) as u32)
            } else {
                (3 + (r.next_f64() * 6.0) as u32, 3 + (r.next_f64() * 6.0) as u32)
            };
            if i % 2 == 0 { Footprint::full((w, h)) } else { triangle(w, h) }
        })
        .collect();
    let p = pack(&footprints, 16384).unwrap();
    assert_eq!(p, pack(&footprints, 16384).unwrap());
    let claimed = assert_disjoint_inside(&p, &footprints);
    assert!(claimed > 0.85, "claimed {claimed}");
    assert!((p.height as f64) < 1.3 * p.width as f64, "{}×{}", p.width, p.height);
    assert!(p.orient.contains(&Orient::Half) && p.orient.contains(&Orient::AsIs));
}

/// A ring's hole takes the charts that fit in it: a 60 × 60 frame four pixels thick
/// and 169 squares of 4 × 4, which fill the hole exactly.
#[test]
fn holes_take_smaller_charts() {
    let mut frame = Footprint::empty((60, 60));
    for y in 0..60 {
        for x in 0..60 {
            if !(4..56).contains(&x) || !(4..56).contains(&y) {
                frame.set(x, y);
            }
        }
    }
    let mut footprints = vec![frame];
    footprints.extend(vec![Footprint::full((4, 4)); 169]);
    let p = pack(&footprints, 16384).unwrap();
    assert_disjoint_inside(&p, &footprints);
    let inside = p.positions[1..].iter().filter(|&&(x, y)| (4..56).contains(&x) && (4..56).contains(&y)).count();
    // 52 × 52 of hole holds 13 × 13 squares of 4.
    assert_eq!(inside, 169, "{:?}", p);
    assert_eq!((p.width, p.height), (60, 60));
}

/// Long thin rectangles longer than the square side are turned by a quarter in a strip
/// narrower than they are long: three 150 × 3 strips among 10 × 10 squares (square side
/// 86). The atlas packed is no larger than that strip's.
#[test]
fn quarter_turns_fit_long_strips() {
    let mut footprints = vec![Footprint::full((150, 3)); 3];
    footprints.extend(vec![Footprint::full((10, 10)); 60]);
    let narrow = pack_strip(&footprints, 86).unwrap();
    let claimed = assert_disjoint_inside(&narrow, &footprints);
    assert!(narrow.orient[..3].iter().all(|&o| o.swaps()), "{:?}", &narrow.orient[..3]);
    assert!(claimed > 0.5, "claimed {claimed}");
    let p = pack(&footprints, 16384).unwrap();
    assert_disjoint_inside(&p, &footprints);
    assert!(p.width * p.height <= narrow.width * narrow.height, "{}×{}", p.width, p.height);
}

#[test]
fn too_large_is_reported_without_packing() {
    let full = |w, h, n| vec![Footprint::full((w, h)); n];
    // Fits by area, not by shape: packed, found too tall, reported.
    assert_eq!(pack(&full(100, 100, 2), 150), Err((150, 200)));
    // Too large by area alone: reported before packing.
    assert_eq!(pack(&full(100, 100, 3), 150), Err((174, 173)));
    assert!(pack(&full(200, 160, 1), 150).is_err());
    assert!(pack(&full(100, 100, 1), 100).is_ok());
}
