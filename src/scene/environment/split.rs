//! Taking the sun out of an outdoor environment map.
//!
//! A photographed sky with the sun in it holds most of its light in a disc of ~7·10⁻⁵ sr,
//! 10⁴–10⁵ times brighter than the sky around it. Bundles sample the sky with one radiance
//! per direction (each direction stands for 2π/D sr), so a sun that small would be hit or
//! missed: noise that takes thousands of directions to average out. So its brightest compact
//! region becomes a directional light (the punctual layer: one exact shadow ray per texel) and
//! the rest stays the sky:
//!
//! 1. the sky level S is the median luminance of the upper hemisphere (by solid angle), the
//!    peak P the brightest pixel;
//! 2. there is a sun when P ≥ [`SUN_CONTRAST`]·S (a clear sun is 10⁴–10⁵ times its sky, a
//!    bright cloud a few times);
//! 3. the region is the pixels connected to the peak (8-neighbours, periodic in u) with
//!    luminance ≥ T = √(P·S), halfway between sky and peak in stops, within
//!    [`MAX_SUN_RADIUS`] of the peak (compact: a glare-filled sky is not a sun);
//! 4. those pixels are set to the mean radiance of the pixels bordering the region (the sky
//!    around it, by solid angle), and what they held above it — Σ (L − L_fill)·Ω per channel —
//!    is the directional light's irradiance (on a surface facing it: the region is small
//!    enough that its cosines are 1 within 0.14 %), its colour that sum's, its direction
//!    the luminance-weighted mean direction of the removed light.

use std::collections::VecDeque;

use glam::DVec3;

use super::Environment;
#[cfg(test)]
use crate::scene::Rgb;
use crate::scene::{LightKind, PunctualLight, luminance};

/// Peak over sky luminance from which a map has a sun to split off.
pub const SUN_CONTRAST: f64 = 100.0;
/// Radius around the peak within which the region may grow, radians (3°: six times the sun's
/// disc; its bright aureole lies within).
pub const MAX_SUN_RADIUS: f64 = 0.052;

/// What [`split_sun`] found and did.
#[derive(Clone, Debug)]
pub struct SunSplit {
    /// The map without the sun.
    pub sky: Environment,
    /// The directional light made of the removed light.
    pub sun: PunctualLight,
    /// Unit direction toward the sun.
    pub toward: DVec3,
    /// Pixels taken out and their solid angle, sr.
    pub pixels: usize,
    pub solid_angle: f64,
    /// The luminance threshold T and the sky level S (W/(sr·m²)).
    pub threshold: f64,
    pub sky_level: f64,
    /// The removed share of the map's luminous power (Σ luminance·Ω).
    pub share: f64,
}

/// Splits the sun off `map` (see the module docs); `None` when the map has no sun.
pub fn split_sun(map: &Environment) -> Option<SunSplit> {
    let (w, h) = (map.width(), map.height());
    let lum = |x: u32, y: u32| luminance(map.texel(x, y)) as f64;
    // 1. Sky level and peak.
    let mut upper: Vec<(f64, f64)> = Vec::new();
    for y in 0..h {
        if (y as f64 + 0.5) / h as f64 >= 0.5 {
            break;
        }
        let omega = map.pixel_solid_angle(y);
        upper.extend((0..w).map(|x| (lum(x, y), omega)));
    }
    let sky_level = weighted_median(&mut upper)?;
    let (mut peak, mut at) = (f64::NEG_INFINITY, (0, 0));
    for y in 0..h {
        for x in 0..w {
            if lum(x, y) > peak {
                (peak, at) = (lum(x, y), (x, y));
            }
        }
    }
    // 2. Is there a sun?
    if !(peak > 0.0 && peak >= SUN_CONTRAST * sky_level) {
        return None;
    }
    // 3. The region.
    let threshold = (peak * sky_level).sqrt();
    let centre = map.pixel_direction(at.0, at.1);
    let near = |x: u32, y: u32| map.pixel_direction(x, y).dot(centre) >= MAX_SUN_RADIUS.cos();
    let index = |x: u32, y: u32| y as usize * w as usize + x as usize;
    let mut inside = vec![false; (w * h) as usize];
    let mut region = Vec::new();
    let mut queue = VecDeque::from([at]);
    inside[index(at.0, at.1)] = true;
    let neighbours = |x: u32, y: u32| {
        let mut n = Vec::with_capacity(8);
        for dy in -1i64..=1 {
            let yy = y as i64 + dy;
            if yy < 0 || yy >= h as i64 {
                continue;
            }
            for dx in -1i64..=1 {
                if (dx, dy) != (0, 0) {
                    n.push(((x as i64 + dx).rem_euclid(w as i64) as u32, yy as u32));
                }
            }
        }
        n
    };
    while let Some((x, y)) = queue.pop_front() {
        region.push((x, y));
        for (nx, ny) in neighbours(x, y) {
            let i = index(nx, ny);
            if !inside[i] && lum(nx, ny) >= threshold && near(nx, ny) {
                inside[i] = true;
                queue.push_back((nx, ny));
            }
        }
    }
    // 4. The fill: the sky bordering the region.
    let (mut fill, mut fill_omega) = (DVec3::ZERO, 0.0);
    let mut border = vec![false; inside.len()];
    for &(x, y) in &region {
        for (nx, ny) in neighbours(x, y) {
            let i = index(nx, ny);
            if !inside[i] && !border[i] {
                border[i] = true;
                let omega = map.pixel_solid_angle(ny);
                fill += map.texel(nx, ny).as_dvec3() * omega;
                fill_omega += omega;
            }
        }
    }
    // A region covering every pixel has no border: it is all sky, no sun.
    let fill = if fill_omega > 0.0 { fill / fill_omega } else { return None };
    let mut texels = map.texels().to_vec();
    let (mut removed, mut toward, mut solid_angle) = (DVec3::ZERO, DVec3::ZERO, 0.0);
    for &(x, y) in &region {
        let omega = map.pixel_solid_angle(y);
        let l = map.texel(x, y).as_dvec3();
        let excess = (l - fill).max(DVec3::ZERO);
        removed += excess * omega;
        toward += map.pixel_direction(x, y) * (luminance(excess.as_vec3()) as f64 * omega);
        solid_angle += omega;
        texels[index(x, y)] = l.min(fill).as_vec3();
    }
    let toward = toward.try_normalize()?;
    let share = luminance(removed.as_vec3()) as f64 / map.luminous_solid_angle().max(f64::MIN_POSITIVE);
    let sun = PunctualLight {
        name: format!("sun of {}", map.name),
        kind: LightKind::Directional,
        intensity: removed.as_vec3(),
        position: glam::Vec3::ZERO,
        direction: (-toward).as_vec3(),
        range: None,
    };
    let sky = map.with_texels(format!("{} without its sun", map.name), texels);
    Some(SunSplit { sky, sun, toward, pixels: region.len(), solid_angle, threshold, sky_level, share })
}

/// The median of `(value, weight)` pairs by weight; `None` when they weigh nothing.
fn weighted_median(pairs: &mut [(f64, f64)]) -> Option<f64> {
    let total: f64 = pairs.iter().map(|p| p.1).sum();
    if total.is_nan() || total <= 0.0 {
        return None;
    }
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut acc = 0.0;
    for &(v, weight) in pairs.iter() {
        acc += weight;
        if acc >= total / 2.0 {
            return Some(v);
        }
    }
    pairs.last().map(|p| p.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sky of radiance 1 (ground 0.3) with a sun disc of 0.5° radius, radiance 4·10⁴,
    /// at elevation 30°, azimuth 60°, drawn by supersampling each pixel.
    fn sunny(width: u32) -> (Environment, DVec3, f64) {
        let height = width / 2;
        let probe = Environment::uniform(Rgb::ZERO);
        let (e, a) = (30f64.to_radians(), 60f64.to_radians());
        let sun = DVec3::new(e.cos() * a.sin(), e.sin(), -e.cos() * a.cos());
        let radius = 0.5f64.to_radians();
        let sun_radiance = 4e4;
        let mut texels = Vec::new();
        let s = 8;
        for y in 0..height {
            for x in 0..width {
                let mut inside = 0;
                for j in 0..s {
                    for i in 0..s {
                        let u = (x as f64 + (i as f64 + 0.5) / s as f64) / width as f64;
                        let v = (y as f64 + (j as f64 + 0.5) / s as f64) / height as f64;
                        inside += (probe.direction(u, v).dot(sun) >= radius.cos()) as u32;
                    }
                }
                let base = if (y as f64 + 0.5) / (height as f64) < 0.5 { 1.0 } else { 0.3 };
                texels.push(Rgb::splat(base + (sun_radiance * inside as f64 / (s * s) as f64) as f32));
            }
        }
        let disc = 2.0 * std::f64::consts::PI * (1.0 - radius.cos());
        (Environment::new("sunny", width, height, texels, 0.0).expect("a map"), sun, sun_radiance * disc)
    }

    /// The split light holds the disc's irradiance (its excess over the sky) to within the
    /// pixels' quadrature, points at the disc, and what is left is sky.
    #[test]
    fn a_drawn_sun_becomes_a_directional_light_of_its_irradiance() {
        for width in [512, 2048] {
            let (map, toward, irradiance) = sunny(width);
            let split = split_sun(&map).expect("a sun");
            let e = split.sun.intensity.x as f64;
            // The disc is drawn with 8×8 samples a pixel: its area within ~1/(8·pixels
            // across) × its rim; 2 % at 512 wide (the disc is 1.4 pixels across).
            assert!((e / irradiance - 1.0).abs() < 0.02, "{width}: {e} vs {irradiance}");
            assert!(split.toward.angle_between(toward) < 0.2f64.to_radians(), "{width}: {:?}", split.toward);
            assert!((split.sky_level - 1.0).abs() < 1e-6);
            assert!(split.sky.brightest() <= 1.0 + 1e-6, "{width}: {}", split.sky.brightest());
            // The disc's luminous power over the map's: sun + sky (2π·1) + ground (2π·0.3).
            let share = irradiance / (irradiance + 2.0 * std::f64::consts::PI * 1.3);
            assert!((split.share / share - 1.0).abs() < 0.02, "{} vs {share}", split.share);
        }
    }

    /// A cloudy sky (its brightest patch a few times the median) keeps its light.
    #[test]
    fn an_overcast_map_has_no_sun() {
        let texels = (0..64 * 32).map(|i| Rgb::splat(1.0 + (i % 7) as f32)).collect();
        let map = Environment::new("overcast", 64, 32, texels, 0.0).expect("a map");
        assert!(split_sun(&map).is_none());
        assert!(split_sun(&Environment::uniform(Rgb::ZERO)).is_none());
    }
}
