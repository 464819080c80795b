//! Direct light of punctual lights (KHR_lights_punctual) at every texel: bundle rays never
//! hit a point, so each texel casts one shadow ray per light through the BVH. Deterministic
//! and noise-free; shadows are as sharp as the texels.

use glam::Vec3;

use super::Bvh;
use crate::parallel::par_map;
use crate::scene::{Rgb, Scene};

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
    // Texels in a worker's chunk are neighbours in space (texel order is atlas order, which
    // mixes rooms and instances): sorted along a Morton curve (the order changes no value,
    // only how often the cache hits).
    let order = spatial_order(positions);
    let chunks: Vec<&[u32]> = order.chunks(CHUNK).collect();
    let per_chunk = par_map(chunks, threads, |chunk| {
        let mut cache = vec![NO_OCCLUDER; scene.lights.len()];
        chunk
            .iter()
            .map(|&i| point_irradiance(scene, bvh, positions[i as usize], normals[i as usize], epsilon, &mut cache))
            .collect::<Vec<_>>()
    });
    let mut out = vec![Rgb::ZERO; n];
    for (&i, e) in order.iter().zip(per_chunk.into_iter().flatten()) {
        out[i as usize] = e;
    }
    out
}

/// Indices of `positions` sorted by the Morton code of their cell in a 1024³ grid over their
/// bounds.
fn spatial_order(positions: &[Vec3]) -> Vec<u32> {
    let (lo, hi) = positions.iter().fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), p| {
        if p.is_finite() { (lo.min(*p), hi.max(*p)) } else { (lo, hi) }
    });
    let scale = 1023.0 / (hi - lo).max_element().max(f32::MIN_POSITIVE);
    let spread = |x: u32| -> u64 {
        let mut v = x as u64 & 0x3ff;
        v = (v | (v << 16)) & 0x0300_00ff;
        v = (v | (v << 8)) & 0x0300_f00f;
        v = (v | (v << 4)) & 0x030c_30c3;
        (v | (v << 2)) & 0x0924_9249
    };
    let mut keyed: Vec<(u64, u32)> = positions
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let q = ((*p - lo) * scale).clamp(Vec3::ZERO, Vec3::splat(1023.0));
            let key =
                if p.is_finite() { spread(q.x as u32) | spread(q.y as u32) << 1 | spread(q.z as u32) << 2 } else { 0 };
            (key, i as u32)
        })
        .collect();
    keyed.sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}

/// Texels a worker takes at once: neighbours in a texel map, whose shadow rays toward a
/// light mostly meet the same occluder.
const CHUNK: usize = 1024;
const NO_OCCLUDER: u32 = u32::MAX;

/// `cache[l]`: the last triangle (BVH slot) found occluding light `l` (a shadow cache): the
/// wall between a texel and another room's light occludes its neighbours too, and testing
/// it alone is a fraction of a traversal. Exact: a hit on the cached triangle is a hit the
/// traversal would accept (the same test); a miss falls back to the traversal.
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
