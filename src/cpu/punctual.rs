//! Direct light of punctual lights (KHR_lights_punctual) at every texel: bundle rays never
//! hit a point, so each texel casts one shadow ray per light through the BVH. Deterministic
//! and noise-free; shadows are as sharp as the texels.

use crate::atlas::TexelMap;
use crate::parallel::par_map_indices;
use crate::reference::Bvh;
use crate::scene::{Rgb, Scene};

/// Irradiance (W/m²) from every punctual light of `scene` at every texel. Shadow rays leave
/// from `p + ε·n` and stop ε short of the light.
pub fn punctual_irradiance(scene: &Scene, bvh: &Bvh, texels: &TexelMap, epsilon: f32, threads: usize) -> Vec<Rgb> {
    let n = texels.len();
    if scene.lights.is_empty() || n == 0 {
        return vec![Rgb::ZERO; n];
    }
    par_map_indices(n, 1024, threads, |i| texel_irradiance(scene, bvh, texels, i, epsilon), &|_| {})
}

fn texel_irradiance(scene: &Scene, bvh: &Bvh, texels: &TexelMap, i: usize, epsilon: f32) -> Rgb {
    let (p, n) = (texels.position[i], texels.normal[i]);
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
