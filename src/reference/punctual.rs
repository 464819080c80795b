//! Direct light of punctual lights (KHR_lights_punctual) at every texel: bundle rays never
//! hit a point, so each texel casts one shadow ray per light through the BVH. Deterministic
//! and noise-free; shadows are as sharp as the texels.

use glam::Vec3;

use super::Bvh;
use crate::parallel::par_map_indices;
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
    par_map_indices(n, 1024, threads, |i| point_irradiance(scene, bvh, positions[i], normals[i], epsilon), &|_| {})
}

fn point_irradiance(scene: &Scene, bvh: &Bvh, p: Vec3, n: Vec3, epsilon: f32) -> Rgb {
    let origin = p + n * epsilon;
    let mut e = Rgb::ZERO;
    for light in &scene.lights {
        let (irradiance, wi, dist) = light.unoccluded_irradiance(p, n);
        if irradiance.max_element() <= 0.0 {
            continue;
        }
        let tmax = if dist.is_finite() { dist - 2.0 * epsilon } else { f32::INFINITY };
        if tmax > 0.0 && !bvh.occluded(origin, wi, tmax) {
            e += irradiance;
        }
    }
    e
}
