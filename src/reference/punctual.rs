//! Direct light of punctual lights (KHR_lights_punctual) at every texel: bundle rays never
//! hit a point, so each texel casts one shadow ray per light through the BVH. Deterministic
//! and noise-free; shadows are as sharp as the texels.

use glam::{DVec2, Vec3};

use super::Bvh;
use crate::atlas::chart_filter::{fill_within_charts, for_each_neighbour};
use crate::atlas::lookup::TexelTable;
use crate::atlas::raster::{barycentric, closest_barycentric};
use crate::atlas::{Atlas, FaceId};
use crate::parallel::par_map;
use crate::scene::{Rgb, Scene, SceneGeometry, Side};

/// Irradiance (W/m²) from every punctual light of `scene` at every texel (surface points
/// `positions` with unit normals `normals`). Shadow rays leave from `p + ε·n` and stop ε
/// short of the light.
pub fn punctual_irradiance(
    scene: &Scene,
    bvh: &Bvh,
    positions: &[Vec3],
    normals: &[Vec3],
    epsilon: f32,
    threads: usize,
) -> Vec<Rgb> {
    let n = positions.len();
    if scene.lights.is_empty() || n == 0 {
        return vec![Rgb::ZERO; n];
    }
    let mut out = vec![Rgb::ZERO; n];
    in_spatial_order(
        &spatial_order(positions.len(), |i| positions[i], bounds(positions.iter().copied())),
        threads,
        scene.lights.len(),
        |i, cache| point_irradiance(scene, bvh, positions[i], normals[i], epsilon, cache),
        |i, e| out[i] = e,
    );
    out
}

/// Irradiance (W/m²) from every punctual light over each texel's visible part: texel `i` is
/// LOD `lod` pixel `pixel(i)` of atlas face `faces[i]` in the chart table `table(i)`, sampled
/// at the 2×2 points of its pixel (each moved to the nearest point of its face's UV triangle)
/// that do not lie inside closed geometry ([`is_buried`]) or in a cut-out, and their mean
/// taken. A point sample at the texel's centre is wrong wherever a texel straddles other
/// geometry: a floor texel whose centre is under a wall shows the wall's shadow over its
/// whole visible part, and real assets (a slab through a floor, a prop sunk into a wall) are
/// full of such texels, most of all at coarse LODs. A texel whose every point is buried or
/// cut out is never seen: it shows its chart neighbours' mean ([`fill_within_charts`]), so
/// that bilinear sampling beside it reads the light of what is seen.
///
/// A texel that faces away from every light (at its four points and its centre) is 0
/// whether or not it is buried, so its points are not tested at first: the half of a sunlit
/// scene's texels that face away from the sun cast no ray. Whether it is buried is then
/// found only where the fill reads it (`settle_unlit`), so the values are those of testing
/// every texel.
#[allow(clippy::too_many_arguments)]
pub fn punctual_irradiance_of_texels<'t>(
    scene: &Scene,
    geom: &SceneGeometry,
    atlas: &Atlas,
    bvh: &Bvh,
    lod: u32,
    faces: &[FaceId],
    pixel: &(dyn Fn(usize) -> [u32; 2] + Sync),
    table: impl Fn(usize) -> &'t TexelTable,
    epsilon: f32,
    threads: usize,
) -> Vec<Rgb> {
    let n = faces.len();
    if scene.lights.is_empty() || n == 0 {
        return vec![Rgb::ZERO; n];
    }
    // A sub-point in the plane of the texel's face: beyond the face's edge it lands on the
    // neighbouring face of a flat chart, as the texel's area does (moved onto the face
    // instead, points near a diagonal between two triangles would crowd onto it). A texel
    // whose centre lies outside its face (a thin triangle's conservative texel) keeps its
    // points on the face.
    let texel = |i: usize| {
        let f = &atlas.faces[faces[i] as usize];
        let [x, y] = pixel(i);
        let uv = f.uv_lod(lod);
        let (cu, cv, outside) = closest_barycentric(&uv, DVec2::new(x as f64 + 0.5, y as f64 + 0.5));
        TexelOnFace {
            tri: f.tri,
            normal: geom.normals[f.tri as usize] * f.side.sign(),
            uv,
            corner: DVec2::new(x as f64, y as f64),
            centre: (cu, cv),
            outside,
        }
    };
    let point = |t: &TexelOnFace, dx: f64, dy: f64| {
        let at = t.corner + DVec2::new(dx, dy);
        let (u, v) = match barycentric(&t.uv, at) {
            Some(b) if t.outside == 0.0 => b,
            _ if t.outside == 0.0 => t.centre,
            _ => {
                let (u, v, _) = closest_barycentric(&t.uv, at);
                (u, v)
            }
        };
        let (u, v) = (u as f32, v as f32);
        (u, v, geom.point(t.tri, u, v))
    };
    // A point in a cut-out is no surface: nothing is lit there (as the bundles drop the
    // fragments there).
    let seen = |t: &TexelOnFace, (u, v, p): (f32, f32, Vec3)| {
        bvh.alpha().opaque_at(t.tri, u, v) && !is_buried(scene, geom, bvh, t.tri, p, t.normal, epsilon)
    };
    let unlit = |t: &TexelOnFace, p: Vec3| {
        scene.lights.iter().all(|l| l.unoccluded_irradiance(p, t.normal).0.max_element() <= 0.0)
    };
    let irradiance = |i: usize, cache: &mut [u32]| {
        let t = texel(i);
        let points = SUBPIXELS.map(|(dx, dy)| point(&t, dx, dy));
        let centre = point(&t, 0.5, 0.5).2;
        if unlit(&t, centre) && points.iter().all(|at| unlit(&t, at.2)) {
            return (Rgb::ZERO, Found::Unlit);
        }
        let (mut sum, mut count) = (Rgb::ZERO, 0u32);
        for at in points {
            if seen(&t, at) {
                sum += point_irradiance(scene, bvh, at.2, t.normal, epsilon, cache);
                count += 1;
            }
        }
        if count > 0 {
            (sum / count as f32, Found::Seen)
        } else {
            (point_irradiance(scene, bvh, centre, t.normal, epsilon, cache), Found::Buried)
        }
    };
    let (mut out, mut buried, mut unlit_texels) = (vec![Rgb::ZERO; n], Vec::new(), Vec::new());
    let store = |i: usize, (e, found): (Rgb, Found)| {
        out[i] = e;
        match found {
            Found::Seen => {}
            Found::Buried => buried.push(i as u32),
            Found::Unlit => unlit_texels.push(i as u32),
        }
    };
    // Over the box of the texels' faces, which holds their centres: the centres are made
    // once, as their keys are (held, they were 12 B a texel at the pass's peak).
    let corners = faces.iter().flat_map(|&f| geom.corners[atlas.faces[f as usize].tri as usize]);
    let order = spatial_order(n, |i| point(&texel(i), 0.5, 0.5).2, bounds(corners));
    in_spatial_order(&order, threads, scene.lights.len(), irradiance, store);
    let buried_of = |list: &[u32]| -> Vec<u32> {
        let chunks: Vec<&[u32]> = list.chunks(CHUNK).collect();
        let found = par_map(chunks, threads, |chunk| {
            let buried = |i: usize| {
                let t = texel(i);
                !SUBPIXELS.iter().any(|&(dx, dy)| seen(&t, point(&t, dx, dy)))
            };
            chunk.iter().copied().filter(|&i| buried(i as usize)).collect::<Vec<_>>()
        });
        found.into_iter().flatten().collect()
    };
    unlit_texels.sort_unstable();
    settle_unlit(pixel, &table, &out, &mut buried, &unlit_texels, buried_of);
    fill_within_charts(pixel, table, &mut out, &buried);
    out
}

/// What the first pass found at a texel.
enum Found {
    /// Some of its points are seen.
    Seen,
    /// None of its points is seen.
    Buried,
    /// It faces away from every light; its points were not tested.
    Unlit,
}

/// Adds to `buried` (sorted on return) the unlit texels (`unlit`, sorted, their points not
/// tested; `buried_of` tests them) whose being buried changes what [`fill_within_charts`]
/// makes of `values`. An unlit texel is 0 buried or not, and it reads as 0 in the fill;
/// whether it is buried counts (1) for itself, where a neighbour is lit: buried, it would show
/// their mean, and (2) for a buried texel's mean it is part of, when that texel or one of its
/// neighbours is lit (it is left out of the mean when buried). Where none of them is lit,
/// every mean is 0 either way.
fn settle_unlit<'t>(
    pixel: &dyn Fn(usize) -> [u32; 2],
    table: &impl Fn(usize) -> &'t TexelTable,
    values: &[Rgb],
    buried: &mut Vec<u32>,
    unlit: &[u32],
    buried_of: impl Fn(&[u32]) -> Vec<u32>,
) {
    let lit_near = |i: usize| {
        let mut lit = false;
        for_each_neighbour(&pixel, table, i, |j, _| lit |= values[j] != Rgb::ZERO);
        lit
    };
    let beside_light: Vec<u32> = unlit.iter().copied().filter(|&u| lit_near(u as usize)).collect();
    buried.extend(buried_of(&beside_light));
    let mut in_lit_means = Vec::new();
    for &b in buried.iter() {
        if values[b as usize] != Rgb::ZERO || lit_near(b as usize) {
            for_each_neighbour(&pixel, table, b as usize, |j, _| {
                let j = j as u32;
                if unlit.binary_search(&j).is_ok() && beside_light.binary_search(&j).is_err() {
                    in_lit_means.push(j);
                }
            });
        }
    }
    in_lit_means.sort_unstable();
    in_lit_means.dedup();
    buried.extend(buried_of(&in_lit_means));
    buried.sort_unstable();
}

/// A texel's pixel on its face: its triangle, the normal of its side, the face's UV at the
/// LOD, the pixel's corner and the weights of the face's point nearest the pixel's centre,
/// `outside` its distance from the face (0 inside).
struct TexelOnFace {
    tri: u32,
    normal: Vec3,
    uv: [DVec2; 3],
    corner: DVec2,
    centre: (f64, f64),
    outside: f64,
}

/// The points of a texel's pixel [`punctual_irradiance_of_texels`] samples (2×2, pixel units).
const SUBPIXELS: [(f64, f64); 4] = [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)];

/// Whether the surface point `p` of triangle `tri` (on the side of unit normal `n`) lies
/// inside closed geometry: the first surface straight out along `n` shows it its back, and
/// that back is no lit face (the inside of a single-sided surface: closed geometry, as the
/// bundles take it, `bundle::estimator`). A point on a floor under a resting box (whose
/// bottom lies on the floor), under a wall's solid, or on the part of a face that runs
/// through a box, sees the solid's inside straight above it; a point in open space sees the
/// front of what faces it, or the sky.
///
/// See-through surfaces ([`crate::scene::Material::is_see_through`]) are looked past: light
/// reaches what lies behind them, so the inside of a glass box is open space, and a point
/// inside a solid stays buried when a pane lies between it and the solid's back.
pub fn is_buried(scene: &Scene, geom: &SceneGeometry, bvh: &Bvh, tri: u32, p: Vec3, n: Vec3, epsilon: f32) -> bool {
    let origin = p + n * epsilon;
    let mut tmin = 0.0;
    for _ in 0..super::bvh::MAX_CROSSINGS {
        match bvh.intersect(origin, n, tmin, f32::INFINITY) {
            Some(hit) if hit.tri != tri => {
                if bvh.alpha().sheet_at(hit.tri, hit.u, hit.v).is_some() {
                    tmin = hit.t + epsilon;
                    continue;
                }
                let facing_away = geom.normals[hit.tri as usize].dot(n) > 0.0;
                return facing_away && !scene.materials[geom.material[hit.tri as usize] as usize].has_side(Side::Back);
            }
            _ => return false,
        }
    }
    false
}

/// Calls `f(i, cache)` for every index of `order` ([`spatial_order`]) on `threads` threads,
/// [`CHUNK`] consecutive ones a worker (texel order is atlas order, which mixes rooms and
/// instances; neighbours in space meet the same occluders, so the shadow cache hits), and
/// `store(i, result)` for each, [`BATCH`] indices at a time: one batch's results are held,
/// not a result per index beside the caller's output. The order changes no value, only how
/// often the cache hits.
fn in_spatial_order<R: Send>(
    order: &[u64],
    threads: usize,
    lights: usize,
    f: impl Fn(usize, &mut [u32]) -> R + Sync,
    mut store: impl FnMut(usize, R),
) {
    for batch in order.chunks(BATCH) {
        let chunks: Vec<&[u64]> = batch.chunks(CHUNK).collect();
        let results = par_map(chunks, threads, |chunk| {
            let mut cache = vec![NO_OCCLUDER; lights];
            chunk.iter().map(|&k| f(k as u32 as usize, &mut cache)).collect::<Vec<_>>()
        });
        for (&k, r) in batch.iter().zip(results.into_iter().flatten()) {
            store(k as u32 as usize, r);
        }
    }
}

/// The box of the finite points of `points`.
fn bounds(points: impl Iterator<Item = Vec3>) -> (Vec3, Vec3) {
    points.fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), p| {
        if p.is_finite() { (lo.min(p), hi.max(p)) } else { (lo, hi) }
    })
}

/// `0..n` sorted by the Morton code of `position(i)`'s cell in a 1024³ grid over the box
/// `(lo, hi)` (positions outside it take the nearest cell), each as `code << 32 | index`
/// (8 B an index).
fn spatial_order(n: usize, position: impl Fn(usize) -> Vec3, (lo, hi): (Vec3, Vec3)) -> Vec<u64> {
    debug_assert!(n <= u32::MAX as usize + 1);
    let scale = 1023.0 / (hi - lo).max_element().max(f32::MIN_POSITIVE);
    let mut keyed: Vec<u64> = (0..n)
        .map(|i| {
            let p = position(i);
            let q = ((p - lo) * scale).clamp(Vec3::ZERO, Vec3::splat(1023.0));
            let key = if p.is_finite() { crate::morton::key3(q.x as u32, q.y as u32, q.z as u32) } else { 0 };
            key << 32 | i as u64
        })
        .collect();
    keyed.sort_unstable();
    keyed
}

/// Texels a worker takes at once: neighbours in a texel map, whose shadow rays toward a
/// light mostly meet the same occluder.
const CHUNK: usize = 1024;
/// Indices [`in_spatial_order`] hands out before it stores their results.
const BATCH: usize = 256 * CHUNK;
const NO_OCCLUDER: u32 = u32::MAX;

/// `cache[l]`: the last triangle (BVH slot) found occluding light `l` (a shadow cache): the
/// wall between a texel and another room's light occludes its neighbours too, and testing
/// it alone is a fraction of a traversal. Exact: a hit on the cached triangle is a hit the
/// traversal would accept (the same test); a miss falls back to the traversal. In a scene
/// with see-through surfaces the shadow ray carries their transmittance
/// ([`Bvh::transmittance`]) and there is no cache (a pane found on the ray does not block).
fn point_irradiance(scene: &Scene, bvh: &Bvh, p: Vec3, n: Vec3, epsilon: f32, cache: &mut [u32]) -> Rgb {
    let origin = p + n * epsilon;
    let mut e = Rgb::ZERO;
    for (light, cached) in scene.lights.iter().zip(cache.iter_mut()) {
        let (irradiance, wi, dist) = light.unoccluded_irradiance(p, n);
        if irradiance.max_element() <= 0.0 {
            continue;
        }
        let tmax = if dist.is_finite() { dist - 2.0 * epsilon } else { f32::INFINITY };
        if tmax.is_nan() || tmax <= 0.0 {
            continue;
        }
        if bvh.alpha().has_see_through() {
            e += irradiance * bvh.transmittance(origin, wi, tmax, epsilon);
            continue;
        }
        if *cached != NO_OCCLUDER && bvh.occluded_by(*cached, origin, wi, tmax) {
            continue;
        }
        match bvh.occluder(origin, wi, tmax) {
            Some(slot) => *cached = slot,
            None => e += irradiance,
        }
    }
    e
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::punctual_irradiance_of_texels;
    use crate::atlas::lookup::TexelTable;
    use crate::atlas::{Atlas, AtlasConfig, TexelMap};
    use crate::reference::{Bvh, ray_epsilon};
    use crate::scene::builder::white;
    use crate::scene::{Rgb, SceneBuilder, SceneGeometry};

    /// A ridge along z: face A slopes down towards +x, where a sun low on the horizon lights it
    /// at cos 80°; face B slopes down towards −x and faces away. The two are 20° apart, one
    /// chart. A closed box sunk through the ridge buries the strip of B beside it (and 2 cm of
    /// A). B's texels are unlit, so the pass tests none of their points at first; those by the
    /// ridge are buried beside A's lit texels and show their light (the fill's mean of seen
    /// neighbours), as they do when every texel is tested: their buried neighbours on B are
    /// found buried and left out of the mean. A buried texel of B with no lit neighbour stays 0,
    /// and none shows more than A gets.
    #[test]
    fn buried_texels_facing_away_show_their_lit_neighbours_light() {
        let (s, c) = (10f32.to_radians().sin(), 10f32.to_radians().cos());
        let sun = Rgb::new(3.0, 2.0, 1.0);
        let mut b = SceneBuilder::new();
        let m = b.material(white());
        let ridge = |z: f32| Vec3::new(0.0, 0.0, z);
        let low = |x: f32, z: f32| Vec3::new(x * c, -s, z);
        let corners = vec![ridge(-1.0), ridge(1.0), low(1.0, 1.0), low(1.0, -1.0), low(-1.0, -1.0), low(-1.0, 1.0)];
        b.mesh("roof", corners, vec![[0, 1, 2], [0, 2, 3], [4, 5, 1], [4, 1, 0]], m);
        b.cuboid("box", Vec3::new(-0.3, -0.5, -0.3), Vec3::new(0.02, 0.3, 0.3), false, m);
        b.directional_light(Vec3::NEG_X, sun);
        let scene = b.build();
        let geom = SceneGeometry::new(&scene);
        let (na, nb) = (Vec3::new(s, c, 0.0), Vec3::new(-s, c, 0.0));
        assert!(geom.normals[0].distance(na) < 1e-5 && geom.normals[2].distance(nb) < 1e-5, "winding");
        let config = AtlasConfig { texel_size: Some(0.05), ..AtlasConfig::default() };
        let atlas = Atlas::build(&scene, &geom, &config).expect("atlas");
        let texels = TexelMap::build(&scene, &geom, &atlas, 0);
        let table = TexelTable::of_map(&texels);
        let bvh = Bvh::for_scene(&scene, &geom);
        let w = texels.width;
        let pixel = |i: usize| [texels.pixel[i] % w, texels.pixel[i] / w];
        let e = punctual_irradiance_of_texels(
            &scene,
            &geom,
            &atlas,
            &bvh,
            0,
            &texels.face,
            &pixel,
            |_| &table,
            ray_epsilon(&scene),
            1,
        );
        let lit = sun * s;
        let on = |i: usize, n: Vec3| texels.normal[i].distance(n) < 1e-4;
        let (mut shown, mut dark, mut open) = (0, 0, 0);
        for (i, &p) in texels.position.iter().enumerate() {
            if on(i, na) && p.x > 0.2 {
                let tol = 1e-5 * lit.max_element();
                assert!((e[i] - lit).abs().max_element() <= tol, "A in the open at {p}: {} vs {lit}", e[i]);
                open += 1;
            }
            if on(i, nb) {
                assert!(e[i].cmple(lit * (1.0 + 1e-5)).all(), "B at {p} shows more than A gets: {}", e[i]);
                // Within the box's span along z, every neighbour a buried texel of B by the ridge
                // counts is a lit texel of A (at `lit`: the box is on the sun's far side);
                // its buried neighbours on B are left out, unlit as they are.
                if e[i] != Rgb::ZERO && p.z.abs() < 0.2 {
                    let tol = 1e-5 * lit.max_element();
                    assert!((e[i] - lit).abs().max_element() <= tol, "B by the ridge at {p}: {} vs {lit}", e[i]);
                    shown += 1;
                }
                if p.x < -0.15 && p.z.abs() < 0.15 {
                    assert_eq!(e[i], Rgb::ZERO, "B deep in the box at {p}");
                    dark += 1;
                }
            }
        }
        assert!(open > 100 && dark > 4, "{open} {dark}");
        assert!(shown > 0, "no buried texel of B beside A shows A's light");
    }
}
