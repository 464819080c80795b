//! Whole-atlas tests: unwrap + pack + texel maps on synthetic scenes, checked by
//! independent rasterisation.

use glam::{DVec2, Vec3};

use super::copies::rigid_copy;
use super::lookup::{self, TexelTable};
use super::raster::{self, PixelRect};
use super::*;
use crate::reference::scenes::{icosphere, torus};
use crate::scene::builder::{diffuse, white};
use crate::scene::{SceneBuilder, SceneGeometry};

/// Thin triangles, 1e-4 of their length wide: alone, and inside a fan with big neighbours.
fn slivers(b: &mut SceneBuilder, m: u32) {
    for k in 0..6 {
        let a = k as f32 * 0.9;
        let d = Vec3::new(a.cos(), 0.3 * (k as f32 - 2.0), a.sin()).normalize() * (0.3 + 0.4 * k as f32);
        let w = d.cross(Vec3::Y).normalize() * d.length() * 1e-4;
        let o = Vec3::new(k as f32, 2.0, 0.0);
        b.mesh(&format!("sliver{k}"), vec![o, o + d, o + d * 0.5 + w], vec![[0, 1, 2]], m);
    }
    // A unit quad whose bottom edge carries a sliver and whose diagonal is split by one.
    let p = vec![
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(1.0, 0.0, -1.0),
        Vec3::new(0.0, 0.0, -1.0),
        Vec3::new(0.5, 0.0, -1e-4),
        Vec3::new(0.5, 0.0, -0.5 - 1e-4 * 0.7),
    ];
    b.mesh("fan", p, vec![[0, 1, 4], [4, 1, 2], [4, 2, 5], [0, 4, 5], [0, 5, 3], [5, 2, 3]], m);
}

pub(crate) fn config(texel: f32) -> AtlasConfig {
    AtlasConfig { texel_size: Some(texel), ..AtlasConfig::default() }
}

/// Barycentrics (u, v) of the projection of `p` onto the plane of a 3-D triangle, and the
/// distance from `p` to the triangle.
fn bary3(c: [Vec3; 3], p: Vec3) -> (f64, f64, f64) {
    let [a, b, cc] = c.map(|q| q.as_dvec3());
    let n = (b - a).cross(cc - a).normalize();
    let (t, s) = n.any_orthonormal_pair();
    let to2 = |q: glam::DVec3| DVec2::new((q - a).dot(t), (q - a).dot(s));
    let tri = [to2(a), to2(b), to2(cc)];
    let q = p.as_dvec3();
    let (_, _, d2) = raster::closest_barycentric(&tri, to2(q));
    let off = (q - a).dot(n);
    let (e1, e2, d) = (tri[1] - tri[0], tri[2] - tri[0], to2(q) - tri[0]);
    let det = e1.perp_dot(e2);
    ((d.perp_dot(e2)) / det, e1.perp_dot(d) / det, (d2 + off * off).sqrt())
}

/// Checks an atlas and its texel maps at LOD 0..=`max_lod` against independent rasters.
/// `strict`: every face must also own at least one texel (true when faces are large
/// compared with a texel, or alone in their chart).
fn check(scene: &Scene, atlas: &Atlas, max_lod: u32, strict: bool) -> Vec<TexelMap> {
    let g = SceneGeometry::new(scene);
    // Faces and charts agree.
    for t in 0..g.len() {
        for side in Side::BOTH {
            if let Some(f) = atlas.face(t as u32, side) {
                let face = &atlas.faces[f as usize];
                assert_eq!((face.tri, face.side), (t as u32, side));
                assert!(atlas.charts[face.chart as usize].faces.contains(&f));
                assert_eq!(atlas.charts[face.chart as usize].side, side);
                assert_eq!(atlas.charts[face.chart as usize].mesh, g.mesh[t]);
            }
        }
    }
    // Rectangles inside the atlas (they may overlap); covered LOD-0 pixels of two charts at
    // least three pixels apart, as footprints keep them (the pixels they claim are computed
    // from f64 UVs before placement; the faces store f32, so a footprint recomputed here may
    // differ by a pixel reached within float noise of FOOTPRINT_TOL, never by a covered one).
    let (w0, h0) = (atlas.width as i64, atlas.height as i64);
    let mut owner = vec![u32::MAX; (w0 * h0) as usize];
    let all = PixelRect::new(0, 0, w0, h0);
    for (ci, c) in atlas.charts.iter().enumerate() {
        let r = c.rect(0);
        assert!(r.x1 <= w0 && r.y1 <= h0, "chart {ci} outside the atlas");
        for &f in &c.faces {
            raster::conservative(&atlas.faces[f as usize].uv_lod(0), all, (i64::MIN, i64::MAX), |x, y| {
                owner[(y * w0 + x) as usize] = ci as u32;
            });
        }
    }
    for y in 0..h0 {
        for x in 0..w0 {
            let o = owner[(y * w0 + x) as usize];
            if o == u32::MAX {
                continue;
            }
            for yy in (y - 2).max(0)..(y + 3).min(h0) {
                for xx in (x - 2).max(0)..(x + 3).min(w0) {
                    let p = owner[(yy * w0 + xx) as usize];
                    assert!(p == u32::MAX || p == o, "charts {o} and {p} closer than 3 pixels at ({x},{y})");
                }
            }
        }
    }
    let mut maps = Vec::new();
    for lod in 0..=max_lod {
        let tm = TexelMap::build(scene, &g, atlas, lod);
        let slot = tm.slots();
        let s = (1u32 << lod) as f64;
        let w = tm.width as i64;
        assert_eq!((tm.width, tm.height), (atlas.width << lod, atlas.height << lod));
        assert_eq!(tm.len() as u64, atlas.covered_texels(lod));
        if lod == 0 {
            assert_eq!(tm.len() as u64, atlas.stats.covered_texels_lod0);
        }
        // Texels in block order over the whole map (bands hold whole blocks), slot consistent.
        let covered = texels::block_order(tm.width as usize, tm.height as usize)
            .filter(|&p| slot[p] != texels::NO_TEXEL)
            .map(|p| p as u32);
        assert!(covered.eq(tm.pixel.iter().copied()));
        for (t, &p) in tm.pixel.iter().enumerate() {
            assert_eq!(slot[p as usize], t as u32);
        }
        // The lookup table ranks the blocks' texels: it reads every texel and gutter pixel
        // as the map lists them, and gives back the map's lists as they are.
        let table = TexelTable::of_map(&tm);
        assert!(table.holds_map_pixels());
        let mut expected = slot.clone();
        for &(p, t) in &tm.gutter {
            expected[p as usize] = t;
        }
        for (p, &e) in expected.iter().enumerate() {
            assert_eq!(table.get(p as i64 % w, p as i64 / w), e, "LOD {lod} pixel {p}");
        }
        assert_eq!(table.map_pixels(), Some(lookup::MapPixels { pixel: tm.pixel.clone(), gutter: tm.gutter.clone() }));
        // A map built without positions and normals gets build's back.
        let mut lean = TexelMap::build_with(scene, &g, atlas, lod, texels::Restore::Albedo);
        assert!(lean.position.is_empty() && lean.normal.is_empty());
        assert_eq!((&lean.pixel, &lean.face, &lean.albedo, &lean.area), (&tm.pixel, &tm.face, &tm.albedo, &tm.area));
        lean.restore_geometry(scene, &g, atlas, 2, texels::Restore::All);
        assert_eq!((&lean.position, &lean.normal), (&tm.position, &tm.normal));
        // A lookup map places the same texels, with no attributes; asked, a texel's are
        // build's, bit for bit.
        let lookup = TexelMap::build_lookup(scene, &g, atlas, lod);
        assert!(lookup.albedo.is_empty() && lookup.emission.is_empty() && lookup.position.is_empty());
        assert_eq!(
            (&lookup.pixel, &lookup.face, &lookup.area, &lookup.gutter),
            (&tm.pixel, &tm.face, &tm.area, &tm.gutter)
        );
        for i in 0..tm.len() {
            let a = lookup.attributes_of(scene, &g, atlas, i);
            let got = (a.position, a.normal, a.albedo, a.emission);
            assert_eq!(got, (tm.position[i], tm.normal[i], tm.albedo[i], tm.emission[i]), "texel {i} at LOD {lod}");
        }
        assert_eq!(slot.iter().filter(|&&s| s != texels::NO_TEXEL).count(), tm.len());
        // Independent conservative raster over the whole atlas (no clipping to the chart):
        // no pixel is touched by two charts, every touched pixel holds a texel of the
        // face's chart, and at LOD 0 nothing reaches a chart's border.
        let window = PixelRect::new(0, 0, tm.width as i64, tm.height as i64);
        let mut chart_at: Vec<u32> = vec![u32::MAX; slot.len()];
        let mut owned = vec![0u32; atlas.faces.len()];
        for &f in &tm.face {
            owned[f as usize] += 1;
        }
        for (fi, face) in atlas.faces.iter().enumerate() {
            let chart = &atlas.charts[face.chart as usize];
            let interior = chart.interior(lod);
            let px = raster::conservative_pixels(&face.uv_lod(lod), window);
            assert!(!px.is_empty(), "face {fi} touches no pixel at LOD {lod}");
            for (x, y) in px {
                let i = (y * w + x) as usize;
                if lod == 0 {
                    assert!(interior.contains(x, y), "face {fi} reaches its chart's border at ({x},{y})");
                } else {
                    assert!(chart.rect(lod).contains(x, y), "face {fi} leaves its chart's rectangle at LOD {lod}");
                }
                assert!(
                    chart_at[i] == u32::MAX || chart_at[i] == face.chart,
                    "pixel ({x},{y}) LOD {lod} in two charts"
                );
                chart_at[i] = face.chart;
                if interior.contains(x, y) {
                    let t = slot[i];
                    assert_ne!(t, texels::NO_TEXEL, "face {fi} lost pixel ({x},{y}) at LOD {lod}");
                    assert_eq!(atlas.faces[tm.face[t as usize] as usize].chart, face.chart);
                }
            }
            if strict {
                assert!(owned[fi] > 0, "face {fi} owns no texel at LOD {lod}");
            }
        }
        // No two faces of a chart overlap: every pixel centre lies in at most one face of
        // each chart (top-left rule: a centre on a shared edge belongs to one side). The
        // unwrapper lets faces overlap by up to OVERLAP_TOL texel, so slivers at most that
        // thick (real meshes have them) may lie inside a neighbour and are left out.
        let mut centre_of: Vec<u32> = vec![u32::MAX; slot.len()];
        for (fi, face) in atlas.faces.iter().enumerate() {
            let t = face.uv_lod(lod);
            let longest = (t[1] - t[0]).length().max((t[2] - t[1]).length()).max((t[0] - t[2]).length());
            if raster::area2(&t).abs() <= longest * charts::OVERLAP_TOL * s {
                continue;
            }
            raster::centres_inside(&t, window, |x, y| {
                let c = &mut centre_of[(y * w + x) as usize];
                assert!(
                    *c == u32::MAX,
                    "faces {} and {fi} overlap at ({x},{y}) LOD {lod}: charts {} {}, uv {:?} {:?}",
                    *c,
                    atlas.faces[*c as usize].chart,
                    face.chart,
                    atlas.faces[*c as usize].uv,
                    face.uv
                );
                *c = fi as u32;
            });
        }
        // Texels lie on their face, have its side's normal, and map back to their pixel.
        for t in 0..tm.len() {
            let f = &atlas.faces[tm.face[t] as usize];
            let corners = g.corners[f.tri as usize];
            let (u, v, dist) = bary3(corners, tm.position[t]);
            let size = (corners[1] - corners[0]).length().max((corners[2] - corners[0]).length()) as f64;
            // Positions are f32: a few ulps of the coordinates on top (4 µm at 60 m).
            let ulps = 4.0 * f32::EPSILON as f64 * tm.position[t].abs().max_element() as f64;
            assert!(dist < 1e-6 * size.max(1.0) + ulps, "texel {t} is {dist} m off its face");
            assert!((tm.normal[t] - g.normals[f.tri as usize] * f.side.sign()).length() < 1e-6);
            let (px, py) = ((tm.pixel[t] as i64) % w, (tm.pixel[t] as i64) / w);
            let centre = DVec2::new(px as f64 + 0.5, py as f64 + 0.5);
            let (_, _, d2) = raster::closest_barycentric(&f.uv_lod(lod), centre);
            if d2 == 0.0 {
                let uv = f.uv_at(u as f32, v as f32).as_dvec2() * s;
                assert!((uv - centre).length() < 1e-2, "texel {t}: UV {uv} vs centre {centre}");
                assert_eq!((uv.x.floor() as i64, uv.y.floor() as i64), (px, py));
            }
        }
        // Gutters: empty pixels next to a texel, copying a neighbouring texel of the only
        // chart around; every empty 8-neighbour of a texel is a gutter pixel.
        let chart_of_texel = |t: u32| atlas.faces[tm.face[t as usize] as usize].chart;
        let mut is_gutter = vec![false; slot.len()];
        for &(p, t) in &tm.gutter {
            assert_eq!(slot[p as usize], texels::NO_TEXEL);
            is_gutter[p as usize] = true;
            let (x, y) = ((p as i64) % w, (p as i64) / w);
            let (tx, ty) = ((tm.pixel[t as usize] as i64) % w, (tm.pixel[t as usize] as i64) / w);
            assert!((x - tx).abs() <= 1 && (y - ty).abs() <= 1);
            let c = chart_of_texel(t);
            assert!(atlas.charts[c as usize].rect(lod).contains(x, y), "gutter pixel outside its chart's rectangle");
            for yy in (y - 1).max(0)..=(y + 1).min(tm.height as i64 - 1) {
                for xx in (x - 1).max(0)..=(x + 1).min(w - 1) {
                    let n = slot[(yy * w + xx) as usize];
                    assert!(
                        n == texels::NO_TEXEL || chart_of_texel(n) == c,
                        "gutter ({x},{y}) LOD {lod} next to two charts"
                    );
                }
            }
        }
        for &p in &tm.pixel {
            let (x, y) = ((p as i64) % w, (p as i64) / w);
            for yy in (y - 1).max(0)..=(y + 1).min(tm.height as i64 - 1) {
                for xx in (x - 1).max(0)..=(x + 1).min(w - 1) {
                    let i = (yy * w + xx) as usize;
                    assert!(slot[i] != texels::NO_TEXEL || is_gutter[i]);
                }
            }
        }
        // Texel areas partition the lit surface: every face's area lands in some texel once,
        // except slivers of a face reaching less than TOUCH_TOL pixel into a pixel (not
        // "touched" by the coverage rule): at most perimeter × TOUCH_TOL pixel per face.
        let lit: f64 = atlas.faces.iter().map(|f| g.areas[f.tri as usize] as f64).sum();
        let pixel = atlas.texel_size as f64 / (1u64 << lod) as f64;
        let untouched: f64 = atlas
            .faces
            .iter()
            .map(|f| {
                let c = g.corners[f.tri as usize];
                let perimeter = (c[1] - c[0]).length() + (c[2] - c[1]).length() + (c[0] - c[2]).length();
                perimeter as f64 * raster::TOUCH_TOL * pixel
            })
            .sum();
        let texel_area: f64 = tm.area.iter().map(|&a| a as f64).sum();
        assert!(
            texel_area <= lit * (1.0 + 1e-5) && texel_area >= lit * (1.0 - 1e-5) - untouched,
            "LOD {lod}: texel areas {texel_area} vs lit area {lit} (untouched bound {untouched})"
        );
        maps.push(tm);
    }
    maps
}

pub(crate) fn check_pub(scene: &Scene, atlas: &Atlas, max_lod: u32, strict: bool) -> Vec<TexelMap> {
    check(scene, atlas, max_lod, strict)
}

fn build(scene: &Scene, cfg: &AtlasConfig) -> Atlas {
    Atlas::build(scene, &SceneGeometry::new(scene), cfg).expect("atlas")
}

#[test]
fn room() {
    let mut b = SceneBuilder::new();
    let m = b.material(white());
    b.cuboid("room", Vec3::ZERO, Vec3::new(4.0, 2.5, 3.0), true, m);
    let s = b.build();
    let a = build(&s, &config(0.05));
    assert_eq!(a.charts.len(), 6);
    assert_eq!(a.faces.len(), 12);
    let area = 2.0 * (4.0 * 2.5 + 4.0 * 3.0 + 2.5 * 3.0);
    assert_eq!(a.stats.covered_texels_lod0, (area / 0.0025f64).round() as u64, "walls aligned to the pixel grid");
    check(&s, &a, 2, true);
}

#[test]
fn double_sided_quad_has_two_separate_faces() {
    let mut b = SceneBuilder::new();
    let m = b.material(diffuse(Vec3::splat(0.5), Vec3::new(1.0, 2.0, 3.0), true));
    b.quad("q", [Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y], m);
    let s = b.build();
    let a = build(&s, &config(0.1));
    assert_eq!(a.faces.len(), 4);
    assert_eq!(a.charts.len(), 2);
    assert_eq!((a.charts[0].side, a.charts[1].side), (Side::Front, Side::Back));
    let maps = check(&s, &a, 2, true);
    for tm in &maps {
        let mut sides = [0usize; 2];
        for t in 0..tm.len() {
            let f = &a.faces[tm.face[t] as usize];
            sides[f.side.index()] += 1;
            let want = Vec3::Z * f.side.sign();
            assert!((tm.normal[t] - want).length() < 1e-6);
            assert_eq!(tm.emission[t], Vec3::new(1.0, 2.0, 3.0), "a double-sided emitter emits from both faces");
            assert_eq!(tm.albedo[t], Vec3::splat(0.5));
        }
        assert_eq!(sides[0], sides[1]);
        assert_eq!(sides[0] * 2, tm.len());
    }
    // Single-sided emitter: back faces neither exist nor emit.
    let mut b = SceneBuilder::new();
    let m = b.material(diffuse(Vec3::splat(0.5), Vec3::ONE, false));
    b.quad("q", [Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y], m);
    let s = b.build();
    let a = build(&s, &config(0.1));
    assert_eq!(a.faces.len(), 2);
    assert!(a.face_of.iter().all(|f| f[1] == NO_FACE));
}

#[test]
fn curved_surfaces_get_many_charts_and_lose_no_face() {
    let mut b = SceneBuilder::new();
    let m = b.material(white());
    let (p, f) = icosphere(Vec3::ZERO, 1.0, 3);
    b.mesh("sphere", p, f, m);
    let (p, f) = torus(Vec3::new(4.0, 0.0, 0.0), 1.0, 0.35, 48, 24);
    b.mesh("torus", p, f, m);
    let s = b.build();
    let a = build(&s, &config(0.015));
    let per_mesh = |mi: u32| a.charts.iter().filter(|c| c.mesh == mi).count();
    assert!(per_mesh(0) >= 8 && per_mesh(1) >= 8, "{} and {} charts", per_mesh(0), per_mesh(1));
    // Every face of a chart is within the angle of some common direction: no chart wraps
    // around the sphere.
    let g = SceneGeometry::new(&s);
    for c in &a.charts {
        let n: Vec3 = c.faces.iter().map(|&f| g.normals[a.faces[f as usize].tri as usize]).sum::<Vec3>().normalize();
        for &f in &c.faces {
            assert!(g.normals[a.faces[f as usize].tri as usize].dot(n) > (80f32).to_radians().cos());
        }
    }
    check(&s, &a, 2, true);
    // At a coarse texel size many faces share a texel: still none is lost (each face's
    // pixels hold texels of its own chart), but not every face can own one.
    let a = build(&s, &config(0.2));
    check(&s, &a, 1, false);
}

#[test]
fn coplanar_duplicate_faces_get_their_own_texels() {
    let mut b = SceneBuilder::new();
    let m = b.material(white());
    // Duplicated quad sharing vertices, and a copy with its own vertices, in one mesh.
    let q = [Vec3::ZERO, Vec3::new(2.0, 0.0, 0.0), Vec3::new(2.0, 0.0, -1.0), Vec3::new(0.0, 0.0, -1.0)];
    let mut p = q.to_vec();
    p.extend(q);
    b.mesh("dup", p, vec![[0, 1, 2], [0, 2, 3], [0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]], m);
    let s = b.build();
    let a = build(&s, &config(0.1));
    assert_eq!(a.charts.len(), 3);
    let maps = check(&s, &a, 2, true);
    assert_eq!(maps[0].len(), 3 * 200);
}

#[test]
fn slivers_keep_their_texels() {
    let mut b = SceneBuilder::new();
    let m = b.material(white());
    slivers(&mut b, m);
    let s = b.build();
    let a = build(&s, &config(0.05));
    // Alone in their chart, slivers own their pixels.
    let maps = check(&s, &a, 3, false);
    let lone = 6;
    for tm in &maps {
        for f in 0..lone {
            assert!(tm.face.contains(&(f as u32)), "sliver {f} owns no texel at LOD {}", tm.lod);
        }
    }
}

#[test]
fn texel_density_of_a_planar_quad() {
    for (angle, texel) in [(0.0f32, 0.1f32), (0.5, 0.1), (0.0, 0.07)] {
        let mut b = SceneBuilder::new();
        let m = b.material(white());
        let (c, s) = (angle.cos(), angle.sin());
        let x = Vec3::new(c, 0.0, -s) * 4.0;
        let z = Vec3::new(s, 0.0, c) * -2.0;
        b.quad("q", [Vec3::ZERO, x, x + z, z], m);
        let sc = b.build();
        let a = build(&sc, &config(texel));
        let g = SceneGeometry::new(&sc);
        let maps = check(&sc, &a, 1, true);
        let ideal = 8.0 / (texel as f64 * texel as f64);
        let (ex, ey) = (4.0 / texel as f64, 2.0 / texel as f64);
        let (n0, n1) = (maps[0].len() as f64, maps[1].len() as f64);
        if (ex - ex.round()).abs() < 1e-3 {
            // A 4 m × 2 m wall at 0.1 m is aligned to the pixel grid: exactly 40 × 20 texels,
            // and 80 × 40 at LOD 1.
            assert_eq!(n0, ideal.round(), "angle {angle}");
            assert_eq!(n1, 4.0 * ideal.round());
        } else {
            // Otherwise the chart is centred in ⌈e⌉ pixels: at most one partly covered
            // column and row more than the surface.
            assert!(n0 >= ideal && n0 <= ex.ceil() * ey.ceil(), "{n0} vs {ideal}");
            assert!(n1 >= 4.0 * ideal && n1 <= ((2.0 * ex).ceil() + 1.0) * ((2.0 * ey).ceil() + 1.0));
        }
        for f in 0..a.faces.len() as u32 {
            let d0 = a.texel_density(&g, f, 0) as f64;
            assert!((d0 * texel as f64 * texel as f64 - 1.0).abs() < 1e-4, "density {d0}");
            assert!((a.texel_density(&g, f, 2) as f64 / d0 - 16.0).abs() < 1e-3);
        }
        assert_eq!(a.triangle_texel_densities(&g, 1).len(), 2);
    }
}

/// Covered LOD-0 texels against the budget they were sized for (the texel map's count).
fn budget_miss(scene: &Scene, budget: u64) -> (f64, Atlas) {
    let a = build(scene, &AtlasConfig { texel_budget: budget, ..AtlasConfig::default() });
    (a.stats.covered_texels_lod0 as f64 / budget as f64, a)
}

#[test]
fn budget_sets_the_texel_size() {
    let mut b = SceneBuilder::new();
    let m = b.material(white());
    b.cuboid("house", Vec3::ZERO, Vec3::new(12.0, 3.0, 8.0), true, m);
    let dm = b.material(diffuse(Vec3::ONE, Vec3::ZERO, true));
    b.grid_quad(
        "partition",
        [Vec3::new(1.0, 0.0, 4.0), Vec3::new(11.0, 0.0, 4.0), Vec3::new(11.0, 3.0, 4.0), Vec3::new(1.0, 3.0, 4.0)],
        5,
        dm,
    );
    let s = b.build();
    let budget = 20_000u64;
    let (ratio, a) = budget_miss(&s, budget);
    let area = 2.0 * (12.0 * 3.0 + 12.0 * 8.0 + 3.0 * 8.0) + 2.0 * 30.0;
    assert!((a.stats.lit_area - area).abs() < 1e-3);
    // Big walls: covered ≈ area / texel², within the search's 2 % stop (a wall's partly
    // covered column and row are a few per cent of it at this size).
    assert!((ratio - 1.0).abs() < 0.02, "covered {} for a budget of {budget}", a.stats.covered_texels_lod0);
    assert!(a.stats.fill_ratio > 0.6, "fill {}", a.stats.fill_ratio);
    check(&s, &a, 1, true);
}

/// The budget search on counts shaped like an atlas's (area / t² + border and partly covered
/// pixels ∝ 1/t + one texel per small chart whatever t): from a start that covers 40 % too
/// many, within the 2 % stop in its four tries; with that floor above the budget it returns
/// a finite size, its closest try, instead of running off.
#[test]
fn budget_search_converges_or_returns_its_closest_try() {
    let count = |t: f64| -> Result<u64, AtlasError> { Ok((50.0 / (t * t) + 300.0 / t + 2000.0) as u64) };
    let mut tries = 0;
    let t = solve_texel_size(20_000, (50.0f64 / 20_000.0).sqrt(), |t| {
        tries += 1;
        count(t)
    })
    .unwrap();
    let c = count(t).unwrap() as f64;
    assert!((c / 20_000.0 - 1.0).abs() < 0.02, "{c} texels at {t} m after {tries} tries");
    assert!(tries <= BUDGET_STEPS);
    let t = solve_texel_size(1_000, 0.1, count).unwrap();
    assert!(t.is_finite() && t > 0.1, "{t}");
}

/// Many small objects (1000 boxes of 3–8 cm at texels of their size): conservative coverage (every
/// face touches whole pixels, every chart its partly covered border pixels) puts far more
/// texels on them than area / texel²: sized by area alone (the old rule) the atlas misses
/// the budget by more than 20 %; the search lands within 20 %.
#[test]
fn budget_holds_on_small_objects() {
    let mut b = SceneBuilder::new();
    let m = b.material(white());
    let mut r = crate::sampling::Rng::new(9, 0);
    for i in 0..1000 {
        let o = Vec3::new((i % 40) as f32 * 0.3, (i / 40) as f32 * 0.3, 0.0);
        let size = Vec3::new(r.next_f32(), r.next_f32(), r.next_f32()) * 0.05 + Vec3::splat(0.03);
        b.cuboid("box", o, o + size, false, m);
    }
    let s = b.build();
    let budget = 10_000u64;
    let (ratio, a) = budget_miss(&s, budget);
    assert!((ratio - 1.0).abs() <= 0.2, "covered {} texels for a budget of {budget}", a.stats.covered_texels_lod0);
    let by_area = (a.stats.lit_area / budget as f64).sqrt() as f32;
    let naive = build(&s, &config(by_area));
    let naive_ratio = naive.stats.covered_texels_lod0 as f64 / budget as f64;
    assert!(naive_ratio > 1.2, "the area rule would cover {naive_ratio} × the budget: the scene tests nothing");
    check(&s, &a, 0, false);
}

/// A budget below [`MIN_TEXELS_PER_CHART`] texels a chart is raised to that (and said so in
/// the stats): 3 000 separate small triangles (one chart each: nothing to grow or merge
/// across) at a budget of 1 000 texels would otherwise get texels larger than the scene,
/// one each, covering 3× the budget anyway. Raised, the covered texels land within ±20 % of
/// the raised budget and the texels stay smaller than the triangles' spacing.
#[test]
fn a_budget_below_the_charts_is_raised() {
    let mut b = SceneBuilder::new();
    let m = b.material(white());
    let (mut pos, mut tris) = (Vec::new(), Vec::new());
    // Sizes vary (0.1–0.4 m): identical charts would all cover the same count, a step
    // function of the texel size no search can land within 20 % of an arbitrary budget.
    let mut r = crate::sampling::Rng::new(5, 0);
    for i in 0..3000u32 {
        let o = Vec3::new((i % 60) as f32, (i / 60) as f32, 0.0);
        let (u, v) = (0.1 + 0.3 * r.next_f32(), 0.1 + 0.3 * r.next_f32());
        pos.extend([o, o + Vec3::new(u, 0.0, 0.0), o + Vec3::new(0.0, v, 0.0)]);
        tris.push([3 * i, 3 * i + 1, 3 * i + 2]);
    }
    b.mesh("scattered", pos, tris, m);
    let s = b.build();
    let a = build(&s, &AtlasConfig { texel_budget: 1_000, ..AtlasConfig::default() });
    assert_eq!(a.stats.charts, 3000);
    let raised = super::MIN_TEXELS_PER_CHART * 3000;
    assert_eq!(a.stats.budget_used, Some(raised));
    let ratio = a.stats.covered_texels_lod0 as f64 / raised as f64;
    assert!((ratio - 1.0).abs() <= 0.2, "covered {} for a raised budget of {raised}", a.stats.covered_texels_lod0);
    assert!(a.texel_size < 1.0, "texel {} m", a.texel_size);
    check(&s, &a, 0, false);
    // A budget the charts allow is kept.
    let a = build(&s, &AtlasConfig { texel_budget: 50_000, ..AtlasConfig::default() });
    assert_eq!(a.stats.budget_used, Some(50_000));
    assert_eq!(build(&s, &config(0.05)).stats.budget_used, None);
}

/// `--texel-budget` on the bundled scenes: covered LOD-0 texels within ±20 % of the budget
/// (the bound) at the default budget and at a tenth of it.
#[test]
fn budget_holds_on_the_bundled_scenes() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets");
    for rel in [
        "cornell_box/cornellBox-2.79-Cycles-gltf.gltf",
        "van_gogh_room/van_gogh_room_lit.gltf",
        "cornell_2m/cornell_2m.gltf",
    ] {
        let s = crate::scene::load_gltf(&dir.join(rel), &crate::scene::LoadOptions::default()).expect("bundled scene");
        for budget in [500_000, 50_000] {
            let (ratio, _) = budget_miss(&s, budget);
            assert!((ratio - 1.0).abs() <= 0.2, "{rel}: covered {ratio} × a budget of {budget}");
        }
    }
}

/// A triangle soup (no shared vertices, float-noise jitter, every third wall doubled by a
/// coincident copy) of a room of grid-tessellated walls welds back: each wall and each copy
/// is one chart (its welded form is planar and connected), so 8 charts for 6 walls, 2 of
/// them doubled, whatever the tessellation — far fewer than one chart per 8 triangles.
#[test]
fn soup_of_planar_walls_welds_back_to_one_chart_per_wall() {
    let mut b = SceneBuilder::new();
    let m = b.material(white());
    crate::reference::scenes::grid_room(&mut b, Vec3::ZERO, Vec3::new(6.0, 3.0, 5.0), (12, 8, 8), m, m, m);
    let room = b.build();
    let soup = crate::reference::scenes::triangle_soup(&room, 1e-5, 3, 4);
    let g = SceneGeometry::new(&soup);
    assert_eq!(soup.meshes.iter().map(|m| m.positions.len()).sum::<usize>(), 3 * g.len(), "a soup shares nothing");
    let a = build(&soup, &config(0.05));
    assert_eq!(a.charts.len(), 8);
    assert!(a.charts.len() * 8 <= g.len());
    // The welded walls are laid out as the clean walls are: the same rectangles, up to one
    // more column or row where the 10 µm jitter (2·10⁻⁴ texel) pushes a wall whose size is a
    // whole number of texels over a pixel boundary.
    let clean = build(&room, &config(0.05));
    let sizes = |a: &Atlas| {
        let mut v: Vec<(u32, u32)> =
            a.charts.iter().map(|c| (c.rect_size.0.max(c.rect_size.1), c.rect_size.0.min(c.rect_size.1))).collect();
        v.sort_unstable();
        v.dedup();
        v
    };
    let (got, want) = (sizes(&a), sizes(&clean));
    assert_eq!(got.len(), want.len(), "{got:?} vs {want:?}");
    for (g, w) in got.iter().zip(&want) {
        assert!(g.0 >= w.0 && g.0 <= w.0 + 1 && g.1 >= w.1 && g.1 <= w.1 + 1, "{got:?} vs {want:?}");
    }
    check(&soup, &a, 1, true);
}

/// The synthetic temple as a triangle soup (343k triangles, every tenth mesh doubled): the
/// issue's goals for this class of asset hold — at most one chart per 8 triangles, fill at
/// least 60 %, covered texels within ±20 % of the budget — with no face overlapping another
/// and every texel on its face ([`check`] at LOD 0).
#[test]
fn temple_soup_meets_the_chart_and_fill_goals() {
    let s = crate::reference::scenes::temple_soup();
    let g = SceneGeometry::new(&s);
    let a = Atlas::build(&s, &g, &AtlasConfig::default()).expect("atlas");
    eprintln!(
        "temple soup: {} triangles, {} charts, fill {:.3}, {} covered texels, {:.3} m texels, {}×{}",
        g.len(),
        a.charts.len(),
        a.stats.fill_ratio,
        a.stats.covered_texels_lod0,
        a.texel_size,
        a.width,
        a.height
    );
    assert!(a.charts.len() * 8 <= g.len(), "{} charts for {} triangles", a.charts.len(), g.len());
    assert!(a.stats.fill_ratio >= 0.6, "fill {}", a.stats.fill_ratio);
    let ratio = a.stats.covered_texels_lod0 as f64 / 500_000.0;
    assert!((ratio - 1.0).abs() <= 0.2, "covered {ratio} × the budget");
    check(&s, &a, 0, false);
}

#[test]
fn builds_are_deterministic() {
    let mut b = SceneBuilder::new();
    let m = b.material(white());
    let d = b.material(diffuse(Vec3::ONE, Vec3::ZERO, true));
    let (p, f) = icosphere(Vec3::ZERO, 1.0, 2);
    b.mesh("sphere", p, f, d);
    let (p, f) = torus(Vec3::new(4.0, 0.0, 0.0), 1.0, 0.35, 24, 12);
    b.mesh("torus", p, f, m);
    b.cuboid("room", Vec3::splat(-6.0), Vec3::splat(6.0), true, m);
    slivers(&mut b, m);
    let s = b.build();
    let g = SceneGeometry::new(&s);
    let cfg = AtlasConfig { texel_budget: 30_000, ..AtlasConfig::default() };
    let (a1, a2) = (Atlas::build(&s, &g, &cfg).unwrap(), Atlas::build(&s, &g, &cfg).unwrap());
    assert_eq!((a1.width, a1.height, a1.texel_size.to_bits()), (a2.width, a2.height, a2.texel_size.to_bits()));
    assert_eq!(a1.face_of, a2.face_of);
    for (f1, f2) in a1.faces.iter().zip(&a2.faces) {
        assert_eq!((f1.tri, f1.side, f1.chart), (f2.tri, f2.side, f2.chart));
        assert_eq!(f1.uv.map(|p| (p.x.to_bits(), p.y.to_bits())), f2.uv.map(|p| (p.x.to_bits(), p.y.to_bits())));
    }
    for (c1, c2) in a1.charts.iter().zip(&a2.charts) {
        assert_eq!((c1.rect_min, c1.rect_size, &c1.faces), (c2.rect_min, c2.rect_size, &c2.faces));
    }
    let (t1, t2) = (TexelMap::build(&s, &g, &a1, 1), TexelMap::build(&s, &g, &a2, 1));
    assert_eq!((&t1.pixel, &t1.face, &t1.gutter), (&t2.pixel, &t2.face, &t2.gutter));
    assert!(
        t1.position
            .iter()
            .zip(&t2.position)
            .all(|(p, q)| p.to_array().map(f32::to_bits) == q.to_array().map(f32::to_bits))
    );
}

#[test]
fn errors() {
    let mut b = SceneBuilder::new();
    let m = b.material(white());
    b.cuboid("room", Vec3::ZERO, Vec3::new(4.0, 2.5, 3.0), true, m);
    let s = b.build();
    let g = SceneGeometry::new(&s);
    for bad in [0.0, -0.1, f32::NAN, f32::INFINITY] {
        assert!(matches!(Atlas::build(&s, &g, &config(bad)), Err(AtlasError::BadTexelSize(_))), "{bad}");
    }
    // 1 mm texels over 59 m²: ~7.7k × 7.7k, above a 4096 limit (reported before any work).
    let cfg = AtlasConfig { texel_size: Some(0.001), max_size: 4096, ..AtlasConfig::default() };
    match Atlas::build(&s, &g, &cfg) {
        Err(AtlasError::TooLarge { width, height, max: 4096 }) => assert!(width > 4096 && height > 4096),
        other => panic!("{other:?}"),
    }
    // Fits by area but one wall alone is wider than the limit (found while packing).
    let cfg = AtlasConfig { texel_size: Some(0.01), max_size: 390, ..AtlasConfig::default() };
    assert!(matches!(Atlas::build(&s, &g, &cfg), Err(AtlasError::TooLarge { max: 390, .. })));
    assert!(matches!(Atlas::build(&Scene::default(), &SceneGeometry::default(), &config(0.1)), Err(AtlasError::Empty)));
    // Zero budget: no texel size can be derived; a budget beyond the largest atlas cannot be
    // met; nor can a zero or u32-overflowing atlas side.
    let cfg = AtlasConfig { texel_budget: 0, ..AtlasConfig::default() };
    assert!(matches!(Atlas::build(&s, &g, &cfg), Err(AtlasError::BadBudget { budget: 0, .. })));
    let cfg = AtlasConfig { texel_budget: 4097 * 4097, max_size: 4096, ..AtlasConfig::default() };
    assert!(matches!(Atlas::build(&s, &g, &cfg), Err(AtlasError::BadBudget { most: 16_777_216, .. })));
    for max_size in [0, MAX_ATLAS_SIDE + 1] {
        let cfg = AtlasConfig { max_size, ..AtlasConfig::default() };
        assert!(matches!(Atlas::build(&s, &g, &cfg), Err(AtlasError::BadMaxSize(_))));
    }
}

#[test]
fn degenerate_triangles_get_no_face() {
    let mut b = SceneBuilder::new();
    let m = b.material(white());
    b.mesh("m", vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::X * 2.0], vec![[0, 1, 2], [0, 1, 3]], m);
    let s = b.build();
    let a = build(&s, &config(0.1));
    assert_eq!(a.face_of[1], [NO_FACE, NO_FACE]);
    assert_eq!(a.faces.len(), 1);
}

/// Rigid copies of a mesh (instancing nodes) share its unwrap: a torus, a copy turned and
/// moved, one also scaled 2×, are copies (with their scale); a mirrored copy, whose edge
/// lengths all agree, and a copy with one vertex moved by 1 mm are not. The atlas gives each
/// copy the original's number of charts, and its texels check out on every copy.
#[test]
fn rigid_copies_share_their_original_charts() {
    use glam::Quat;
    let mut b = SceneBuilder::new();
    let m = b.material(white());
    let (p, f) = torus(Vec3::ZERO, 1.0, 0.35, 24, 12);
    let turn = Quat::from_rotation_y(0.7) * Quat::from_rotation_x(0.3);
    let moved: Vec<Vec3> = p.iter().map(|&q| turn * q + Vec3::new(5.0, 1.0, -2.0)).collect();
    let scaled: Vec<Vec3> = p.iter().map(|&q| turn * q * 2.0 + Vec3::new(-6.0, 0.0, 0.0)).collect();
    let mirrored: Vec<Vec3> = p.iter().map(|&q| Vec3::new(-q.x, q.y, q.z) + Vec3::new(0.0, 0.0, 6.0)).collect();
    let mut nudged = moved.clone();
    nudged[7] += Vec3::new(0.001, 0.0, 0.0);
    let nudged: Vec<Vec3> = nudged.iter().map(|&q| q + Vec3::new(0.0, 5.0, 0.0)).collect();
    // Small (a 0.1 m torus: 2.5 cm edges) and 3 km away, where f32 positions are 2.4·10⁻⁴ m
    // apart: its edges round by ~1 %, far beyond the relative tolerance.
    let far: Vec<Vec3> = p.iter().map(|&q| turn * q * 0.1 + Vec3::new(3000.0, 0.0, 0.0)).collect();
    for (name, pos) in
        [("torus", p), ("moved", moved), ("scaled", scaled), ("mirrored", mirrored), ("nudged", nudged), ("far", far)]
    {
        b.mesh(name, pos, f.clone(), m);
    }
    let s = b.build();
    let g = SceneGeometry::new(&s);
    let cfg = AtlasConfig { texel_budget: 40_000, ..AtlasConfig::default() };
    let SceneFaces { face_of, .. } = SceneFaces::new(&s, &g);
    let meshes: Vec<MeshCharts> = (0..6).filter_map(|mi| MeshCharts::new(&s, &g, &face_of, mi, 0.05, &cfg)).collect();
    let scale = |k: usize| rigid_copy(&s, &g, &meshes[0], &meshes[k]).map(|c| c.scale);
    assert!((scale(1).expect("a turned and moved copy") - 1.0).abs() < 1e-5);
    assert!((scale(2).expect("a scaled copy") - 2.0).abs() < 1e-5);
    assert!(scale(3).is_none(), "a mirror image is not a rigid copy");
    assert!(scale(4).is_none(), "a vertex moved by 1 mm is not a copy");
    assert!((scale(5).expect("a small copy far away") - 0.1).abs() < 1e-3);

    let a = build(&s, &cfg);
    let per_mesh = |mi: u32| a.charts.iter().filter(|c| c.mesh == mi).count();
    assert_eq!(per_mesh(1), per_mesh(0));
    assert_eq!(per_mesh(2), per_mesh(0));
    assert_eq!(per_mesh(5), per_mesh(0));
    check(&s, &a, 1, false);
}

/// A real game map (zdm2, 57 612 lit triangles of thin, intersecting and degenerate pieces)
/// at the two LOD-0 budgets of the issue: fill (covered texels over the atlas) at least the
/// issue's goal of 0.5, charts no more than the 4 861 and 5 825 the rectangle packer's atlas
/// had (the unwrap is the same; the packing must not pay for fill with smaller charts), the
/// covered texels within the budget search's ±20 %, and the whole check at LOD 0 (and 1 at
/// 500k): every face touches texels of its chart, footprints disjoint, gutters next to one
/// chart only. The rectangle packer left 0.58 and 0.62 here; xatlas, given the same faces,
/// texel size and gutter, 0.56 and 0.73.
#[test]
fn zdm2_game_map_fills_half_its_atlas() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/zdm2/zdm2.gltf");
    let s = crate::scene::load_gltf(&path, &crate::scene::LoadOptions::default()).expect("zdm2 loads");
    let g = SceneGeometry::new(&s);
    for (budget, charts_before, lods) in [(500_000u64, 4861usize, 1u32), (2_000_000, 5825, 0)] {
        let a = Atlas::build(&s, &g, &AtlasConfig { texel_budget: budget, ..AtlasConfig::default() }).expect("atlas");
        eprintln!(
            "zdm2 at {budget}: {} charts, {:.2} triangles a chart, fill {:.3}, {}×{}",
            a.charts.len(),
            g.len() as f64 / a.charts.len() as f64,
            a.stats.fill_ratio,
            a.width,
            a.height
        );
        assert!(a.stats.fill_ratio >= 0.5, "fill {} at {budget}", a.stats.fill_ratio);
        assert!(a.charts.len() <= charts_before, "{} charts at {budget}", a.charts.len());
        let ratio = a.stats.covered_texels_lod0 as f64 / budget as f64;
        assert!((ratio - 1.0).abs() <= 0.2, "covered {ratio} × the budget");
        check(&s, &a, lods, false);
    }
}
