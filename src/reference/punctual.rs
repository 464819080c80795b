//! Direct light of punctual lights (KHR_lights_punctual) at every texel: bundle rays never
//! hit a point, so each texel casts one shadow ray per light through the BVH. Deterministic
//! and noise-free; shadows are as sharp as the texels.

use glam::{DVec2, Vec3};

use super::Bvh;
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
/// LOD `lod` pixel `pixel(i)` of atlas face `faces[i]`, sampled at the 2×2 points of its
/// pixel (each moved to the nearest point of its face's UV triangle) that do not lie inside
/// closed geometry ([`is_buried`]) or in a cut-out, and their mean taken. A point sample at the texel's
/// centre is wrong wherever a texel straddles other geometry: a floor texel whose centre is
/// under a wall shows the wall's shadow over its whole visible part, and real assets (a
/// slab through a floor, a prop sunk into a wall) are full of such texels, most of all at
/// coarse LODs. A texel whose every point is buried or cut out is never seen: it keeps its
/// centre's value and is reported in the second list, for its neighbours to stand in for it.
#[allow(clippy::too_many_arguments)]
pub fn punctual_irradiance_of_texels(
    scene: &Scene,
    geom: &SceneGeometry,
    atlas: &Atlas,
    bvh: &Bvh,
    lod: u32,
    faces: &[FaceId],
    pixel: &(dyn Fn(usize) -> [u32; 2] + Sync),
    epsilon: f32,
    threads: usize,
) -> (Vec<Rgb>, Vec<u32>) {
    let n = faces.len();
    if scene.lights.is_empty() || n == 0 {
        return (vec![Rgb::ZERO; n], Vec::new());
    }
    // A sub-point in the plane of the texel's face: beyond the face's edge it lands on the
    // neighbouring face of a flat chart, as the texel's area does (moved onto the face
    // instead, points near a diagonal between two triangles would crowd onto it). A texel
    // whose centre lies outside its face (a thin triangle's conservative texel) keeps its
    // points on the face.
    let point = |i: usize, dx: f64, dy: f64| {
        let f = &atlas.faces[faces[i] as usize];
        let [x, y] = pixel(i);
        let uv = f.uv_lod(lod);
        let (cu, cv, outside) = closest_barycentric(&uv, DVec2::new(x as f64 + 0.5, y as f64 + 0.5));
        let at = DVec2::new(x as f64 + dx, y as f64 + dy);
        let (u, v) = match barycentric(&uv, at) {
            Some(b) if outside == 0.0 => b,
            _ if outside == 0.0 => (cu, cv),
            _ => {
                let (u, v, _) = closest_barycentric(&uv, at);
                (u, v)
            }
        };
        let (u, v) = (u as f32, v as f32);
        (f.tri, u, v, geom.point(f.tri, u, v), geom.normals[f.tri as usize] * f.side.sign())
    };
    let mut out = vec![Rgb::ZERO; n];
    let mut buried = Vec::new();
    let irradiance = |i: usize, cache: &mut [u32]| {
        let (mut sum, mut seen) = (Rgb::ZERO, 0u32);
        for (dx, dy) in SUBPIXELS {
            let (tri, u, v, p, nrm) = point(i, dx, dy);
            // A point in a cut-out is no surface: nothing is lit there (as the bundles drop
            // the fragments there).
            if bvh.alpha().opaque_at(tri, u, v) && !is_buried(scene, geom, bvh, tri, p, nrm, epsilon) {
                sum += point_irradiance(scene, bvh, p, nrm, epsilon, cache);
                seen += 1;
            }
        }
        if seen > 0 {
            (sum / seen as f32, false)
        } else {
            let (_, _, _, p, nrm) = point(i, 0.5, 0.5);
            (point_irradiance(scene, bvh, p, nrm, epsilon, cache), true)
        }
    };
    let store = |i: usize, (e, b): (Rgb, bool)| {
        out[i] = e;
        if b {
            buried.push(i as u32);
        }
    };
    // Over the box of the texels' faces, which holds their centres: the centres are made
    // once, as their keys are (held, they were 12 B a texel at the pass's peak).
    let corners = faces.iter().flat_map(|&f| geom.corners[atlas.faces[f as usize].tri as usize]);
    let order = spatial_order(n, |i| point(i, 0.5, 0.5).3, bounds(corners));
    in_spatial_order(&order, threads, scene.lights.len(), irradiance, store);
    buried.sort_unstable();
    (out, buried)
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
