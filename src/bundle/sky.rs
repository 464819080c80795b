//! What a bundle line sees when it leaves the scene: the uniform sky plus the environment
//! map, **filtered to the solid angle one direction stands for**.
//!
//! A bake's D directions are uniform on the sphere and each serves ω and −ω, so a texel's
//! hemisphere gets D of the 2D samples: each stands for Ω = 2π/D sr. A line escaping along ω
//! reads the map averaged over the spherical cap of that solid angle around ω (radius r with
//! `2π(1 − cos r) = Ω`), not the map at ω: the bundles' estimate of `∫ L cosθ dω` is then a
//! quadrature of a function smooth at the scale of the samples, where point samples of a map
//! with a bright feature smaller than Ω would hit or miss it. The average is over the map's
//! pixels, each constant over its solid angle, weighted by solid angle (an exact box filter on
//! the sphere up to the pixel rows' quadrature), into a map of pixels about r/2 wide, read
//! bilinearly. A uniform map stays exactly uniform; where r is below one pixel of the map the
//! map is read as it is.

use std::f64::consts::PI;
use std::sync::Arc;

use glam::{DVec3, Vec3};

use crate::scene::{Environment, Rgb, Scene};

/// The radiance rays leaving the scene see, as the bundles read it.
#[derive(Clone, Debug)]
pub struct BundleSky {
    uniform: Rgb,
    /// The environment filtered for the bake's directions (or as it is).
    map: Option<Arc<Environment>>,
}

/// What the two ends of a bundle line see: the side looking along +ω sees `ahead` (the sky in
/// direction ω), the side looking along −ω sees `behind` (the sky in direction −ω).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SkySeen {
    pub ahead: Rgb,
    pub behind: Rgb,
}

impl SkySeen {
    /// The same radiance both ways (a uniform sky).
    pub fn uniform(l: Rgb) -> SkySeen {
        SkySeen { ahead: l, behind: l }
    }
}

/// The solid angle one of `directions` bundle directions stands for, sr.
pub fn direction_solid_angle(directions: u32) -> f64 {
    2.0 * PI / directions.max(1) as f64
}

impl BundleSky {
    /// The sky of `scene` for a bake of `directions` directions.
    pub fn new(scene: &Scene, directions: u32) -> BundleSky {
        let map = scene.environment.as_ref().map(|m| filtered(m, direction_solid_angle(directions)));
        BundleSky { uniform: scene.sky, map }
    }

    /// Radiance arriving from direction `d` (unit).
    #[inline]
    pub fn toward(&self, d: Vec3) -> Rgb {
        match &self.map {
            Some(m) => self.uniform + m.radiance(d),
            None => self.uniform,
        }
    }

    /// What the two ends of a line along `dir` see.
    #[inline]
    pub fn seen(&self, dir: Vec3) -> SkySeen {
        match &self.map {
            Some(_) => SkySeen { ahead: self.toward(dir), behind: self.toward(-dir) },
            None => SkySeen::uniform(self.uniform),
        }
    }

    /// The brightest channel a line can see.
    pub fn brightest(&self) -> f32 {
        self.uniform.max_element() + self.map.as_ref().map_or(0.0, |m| m.brightest())
    }

    /// The filtered map, if the scene has one.
    pub fn map(&self) -> Option<&Environment> {
        self.map.as_deref()
    }
}

/// `map` averaged over caps of solid angle `omega` (module docs); the map itself when the cap
/// is narrower than its pixels.
pub fn filtered(map: &Arc<Environment>, omega: f64) -> Arc<Environment> {
    let radius = (1.0 - omega / (2.0 * PI)).clamp(-1.0, 1.0).acos();
    let pixel = PI / map.height() as f64;
    if radius <= pixel {
        return map.clone();
    }
    let height = ((2.0 * PI / radius).ceil() as u32).clamp(2, map.height());
    let width = 2 * height;
    let out = cap_average(map, radius, width, height);
    Arc::new(map.resized(format!("{} filtered to {omega:.3e} sr", map.name), width, height, out))
}

/// The mean radiance (by solid angle) over the cap of `radius` around the centre of every
/// pixel of a `width × height` grid in `map`'s own coordinates (the rotation is a shift of u,
/// which an average over caps commutes with).
fn cap_average(map: &Environment, radius: f64, width: u32, height: u32) -> Vec<Rgb> {
    let (w, h) = (map.width() as usize, map.height() as usize);
    let mut sum = vec![DVec3::ZERO; (width * height) as usize];
    let mut weight = vec![0.0f64; (width * height) as usize];
    let cos_r = radius.cos();
    let mut prefix = vec![DVec3::ZERO; w + 1];
    for j in 0..h {
        let theta = PI * (j as f64 + 0.5) / h as f64;
        let (top, bottom) = (PI * j as f64 / h as f64, PI * (j + 1) as f64 / h as f64);
        // Solid angle of the row per pixel width.
        let omega = (top.cos() - bottom.cos()) * 2.0 * PI / w as f64;
        let first = ((theta - radius) / PI * height as f64 - 0.5).floor().max(0.0) as u32;
        let last = (((theta + radius) / PI * height as f64 - 0.5).ceil().max(0.0) as u32).min(height - 1);
        if first > last {
            continue;
        }
        for (i, t) in map.texels()[j * w..(j + 1) * w].iter().enumerate() {
            prefix[i + 1] = prefix[i] + t.as_dvec3();
        }
        let total = prefix[w];
        // The row's integral from pixel 0 to `x` pixels (periodic).
        let integral = |x: f64| {
            let turns = (x / w as f64).floor();
            let x = x - turns * w as f64;
            let i = (x.floor() as usize).min(w - 1);
            total * turns + prefix[i] + map.texels()[j * w + i].as_dvec3() * (x - i as f64)
        };
        let (st, ct) = (theta.sin(), theta.cos());
        for y in first..=last {
            let tc = PI * (y as f64 + 0.5) / height as f64;
            let (sc, cc) = (tc.sin(), tc.cos());
            // The cap's half-width in azimuth at this row: cos Δφ ≥ (cos r − cosθc·cosθ)/(sinθc·sinθ).
            let half = if sc * st < 1e-12 {
                if cc * ct >= cos_r { PI } else { continue }
            } else {
                let x = (cos_r - cc * ct) / (sc * st);
                if x <= -1.0 {
                    PI
                } else if x >= 1.0 {
                    continue;
                } else {
                    x.acos()
                }
            };
            let span = half / (2.0 * PI) * w as f64; // half the row's pixels inside the cap
            for x in 0..width {
                let centre = (x as f64 + 0.5) / width as f64 * w as f64;
                let s = integral(centre + span) - integral(centre - span);
                let k = (y * width + x) as usize;
                sum[k] += s * omega;
                weight[k] += 2.0 * span * omega;
            }
        }
    }
    sum.iter().zip(&weight).map(|(s, w)| if *w > 0.0 { (*s / *w).as_vec3() } else { Rgb::ZERO }).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A map turned by 0.4 rad whose pixel (x, y) holds `f` of the world direction through it.
    fn map(width: u32, height: u32, f: impl Fn(DVec3) -> f32) -> Arc<Environment> {
        let probe = Environment::new("probe", 1, 1, vec![Rgb::ZERO], 0.4).expect("a map");
        let texels = (0..height)
            .flat_map(|y| (0..width).map(move |x| (x, y)))
            .map(|(x, y)| {
                let d = probe.direction((x as f64 + 0.5) / width as f64, (y as f64 + 0.5) / height as f64);
                Rgb::splat(f(d))
            })
            .collect();
        Arc::new(Environment::new("test", width, height, texels, 0.4).expect("a map"))
    }

    /// A uniform map stays the same value everywhere, to rounding.
    #[test]
    fn a_uniform_map_stays_uniform() {
        let m = map(256, 128, |_| 3.0);
        for d in [16, 256, 4096] {
            let f = filtered(&m, direction_solid_angle(d));
            for t in f.texels() {
                assert!((t.x - 3.0).abs() < 3.0 * 1e-6, "{d}: {t}");
            }
        }
    }

    /// A bright spot of radiance L and solid angle s (much smaller than the cap) reads as
    /// about L·s/Ω at the cap's centre and 0 farther than the cap's radius from it; the
    /// filter keeps the map's power (its mean over the sphere).
    #[test]
    fn a_small_bright_spot_spreads_over_one_directions_cap() {
        let spot = DVec3::new(0.3, 0.5, -0.8).normalize();
        let spot_radius = 0.02f64;
        let m = map(1024, 512, |d| if d.dot(spot) >= spot_radius.cos() { 1000.0 } else { 0.0 });
        let spot_omega: f64 = (0..m.height())
            .map(|y| (0..m.width()).filter(|&x| m.texel(x, y).x > 0.0).count() as f64 * m.pixel_solid_angle(y))
            .sum();
        let directions = 256;
        let omega = direction_solid_angle(directions);
        let f = filtered(&m, omega);
        let radius = (1.0 - omega / (2.0 * PI)).acos();
        let at_centre = f.radiance(spot.as_vec3()).x as f64;
        // The cap's mean: the spot's power over the cap's solid angle; the bilinear read of a
        // grid of r/2 pixels lowers the peak by up to ~15 % (the filtered map is a cone).
        let expected = 1000.0 * spot_omega / omega;
        assert!(at_centre > 0.8 * expected && at_centre < 1.02 * expected, "{at_centre} vs {expected}");
        let far = glam::DQuat::from_axis_angle(DVec3::Y.cross(spot).normalize(), 2.2 * radius) * spot;
        assert_eq!(f.radiance(far.as_vec3()).x, 0.0);
        let power = |e: &Environment| {
            (0..e.height())
                .map(|y| (0..e.width()).map(|x| e.texel(x, y).x as f64).sum::<f64>() * e.pixel_solid_angle(y))
                .sum::<f64>()
        };
        assert!((power(&f) / power(&m) - 1.0).abs() < 0.03, "{} vs {}", power(&f), power(&m));
    }

    /// Caps narrower than a pixel read the map itself.
    #[test]
    fn fine_caps_keep_the_map() {
        let m = map(64, 32, |d| d.y as f32);
        assert!(Arc::ptr_eq(&filtered(&m, direction_solid_angle(1 << 20)), &m));
        let sky = BundleSky::new(&Scene { sky: Rgb::splat(0.5), ..Scene::default() }, 256);
        assert_eq!(sky.seen(Vec3::Y), SkySeen::uniform(Rgb::splat(0.5)));
        assert_eq!(sky.brightest(), 0.5);
    }
}
