//! Direct light of punctual lights (KHR_lights_punctual) at every texel: bundle rays never
//! hit a point, so each texel casts one shadow ray per light through the BVH. Deterministic
//! and noise-free; shadows are as sharp as the texels.

use std::sync::atomic::{AtomicUsize, Ordering};

use crate::atlas::TexelMap;
use crate::reference::Bvh;
use crate::scene::{Rgb, Scene};

/// Irradiance (W/m²) from every punctual light of `scene` at every texel. Shadow rays leave
/// from `p + ε·n` and stop ε short of the light.
pub fn punctual_irradiance(scene: &Scene, bvh: &Bvh, texels: &TexelMap, epsilon: f32, threads: usize) -> Vec<Rgb> {
    let n = texels.len();
    let mut out = vec![Rgb::ZERO; n];
    if scene.lights.is_empty() || n == 0 {
        return out;
    }
    const CHUNK: usize = 1024;
    let next = AtomicUsize::new(0);
    let chunks: Vec<(usize, Vec<Rgb>)> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads.max(1))
            .map(|_| {
                s.spawn(|| {
                    let mut done = Vec::new();
                    loop {
                        let start = next.fetch_add(CHUNK, Ordering::Relaxed);
                        if start >= n {
                            break;
                        }
                        let end = (start + CHUNK).min(n);
                        let values = (start..end).map(|i| texel_irradiance(scene, bvh, texels, i, epsilon)).collect();
                        done.push((start, values));
                    }
                    done
                })
            })
            .collect();
        // A worker's panic is a bug: pass it on rather than leave its texels unlit.
        handles.into_iter().flat_map(|h| h.join().unwrap_or_else(|p| std::panic::resume_unwind(p))).collect()
    });
    for (start, values) in chunks {
        out[start..start + values.len()].copy_from_slice(&values);
    }
    out
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
