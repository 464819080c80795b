//! A physical sky (`--sky-model preetham`): Preetham, Shirley & Smits 1999, *A Practical
//! Analytic Model for Daylight* (SIGGRAPH '99), whose sun is the punctual layer's
//! directional light and whose sky is an environment map.
//!
//! * **Sky** (the paper's Sect. 3 and Appendix A.2): luminance Y and chromaticity x, y of a
//!   direction at zenith angle θ and angle γ from the sun follow Perez et al.'s distribution
//!   `F(θ, γ) = (1 + A·e^{B/cosθ})·(1 + C·e^{Dγ} + E·cos²γ)` relative to the zenith,
//!   `Y = Y_z·F(θ, γ)/F(0, θ_s)`, with A…E linear in the turbidity T (the paper's Table 2)
//!   and the zenith values `Y_z = (4.0453·T − 4.9710)·tan χ − 0.2155·T + 2.4192` kcd/m²,
//!   `χ = (4/9 − T/120)(π − 2θ_s)`, and x_z, y_z cubic in θ_s and quadratic in T (the
//!   matrices below). xyY goes to XYZ and to linear Rec. 709 RGB; luminance in cd/m² becomes
//!   W/(sr·m²) at 683 lm/W (the project's photometric watt, `scene::sun`).
//! * **Sun**: the clear-sky sun of `scene::sun::clear_sky_sun` at the same turbidity (the
//!   paper's Appendix A.2 attenuation), or the irradiance `--sun` gives.
//! * **Ground**: the model describes the upper hemisphere. Below the horizon the map holds the
//!   radiance of an endless Lambertian ground of albedo `--ground-albedo` lit by that sky and
//!   sun: `ρ·(E_sky + E_sun·sin e)/π` (its own shadows and the scene's ignored).
//! * **Twilight**: the model holds for a sun above the horizon. Below it there is no sun, and
//!   the sky of a sun on the horizon fades linearly to black at 6° below (civil twilight's
//!   end), a stand-in for a model of twilight.
//!
//! The map is 512×256 pixels (0.7°): Perez's circumsolar term `C·e^{Dγ}` has |D| ≤ 2.8 at
//! T ≤ 10, so it changes by a few per cent a pixel at most; the sun's disc is not in the map
//! (it is the directional light).

use std::sync::Arc;

use super::environment::Environment;
use super::sun::{SunPosition, clear_sky_sun};
use super::{PunctualLight, Rgb};

/// Turbidity range the paper fits (its Fig. 4 and Table 2).
pub const TURBIDITY_RANGE: (f64, f64) = (2.0, 10.0);
/// The map's size.
pub const MAP_WIDTH: u32 = 512;
pub const MAP_HEIGHT: u32 = 256;
/// Depth below the horizon at which the twilight sky is black, degrees.
pub const TWILIGHT_DEPTH: f64 = 6.0;

/// What a physical sky is made of.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DaylightOptions {
    pub turbidity: f64,
    pub ground_albedo: f64,
}

impl Default for DaylightOptions {
    /// A clear day (turbidity 3) over ground of albedo 0.2 (grass and soil).
    fn default() -> Self {
        DaylightOptions { turbidity: 3.0, ground_albedo: 0.2 }
    }
}

impl DaylightOptions {
    pub fn validate(&self) -> Result<(), String> {
        let (lo, hi) = TURBIDITY_RANGE;
        if !(self.turbidity >= lo && self.turbidity <= hi) {
            return Err(format!("--turbidity must be between {lo} and {hi} (the model's fit), got {}", self.turbidity));
        }
        if !(0.0..=1.0).contains(&self.ground_albedo) {
            return Err(format!("--ground-albedo must be between 0 and 1, got {}", self.ground_albedo));
        }
        Ok(())
    }
}

/// A physical sky and its sun.
#[derive(Clone, Debug)]
pub struct Daylight {
    pub sky: Arc<Environment>,
    /// `None` below the horizon.
    pub sun: Option<PunctualLight>,
}

/// Perez coefficients A…E of one quantity, linear in T: rows (slope, intercept).
type Linear5 = [(f64, f64); 5];

/// The paper's Table 2 (Appendix A.2): distribution coefficients of Y, x and y.
const PEREZ_Y: Linear5 =
    [(0.1787, -1.4630), (-0.3554, 0.4275), (-0.0227, 5.3251), (0.1206, -2.5771), (-0.0670, 0.3703)];
const PEREZ_X: Linear5 =
    [(-0.0193, -0.2592), (-0.0665, 0.0008), (-0.0004, 0.2125), (-0.0641, -0.8989), (-0.0033, 0.0452)];
const PEREZ_LITTLE_Y: Linear5 =
    [(-0.0167, -0.2608), (-0.0950, 0.0092), (-0.0079, 0.2102), (-0.0441, -1.6537), (-0.0109, 0.0529)];

/// Zenith chromaticity: `[T², T, 1] · M · [θ_s³, θ_s², θ_s, 1]` (Appendix A.2).
const ZENITH_X: [[f64; 4]; 3] =
    [[0.00166, -0.00375, 0.00209, 0.0], [-0.02903, 0.06377, -0.03202, 0.00394], [0.11693, -0.21196, 0.06052, 0.25886]];
const ZENITH_Y: [[f64; 4]; 3] =
    [[0.00275, -0.00610, 0.00317, 0.0], [-0.04214, 0.08970, -0.04153, 0.00516], [0.15346, -0.26756, 0.06670, 0.26688]];

/// The model at one turbidity and sun zenith angle.
#[derive(Clone, Copy, Debug)]
pub struct Preetham {
    coefficients: [[f64; 5]; 3],
    /// Zenith Y (kcd/m²), x, y.
    zenith: [f64; 3],
    theta_sun: f64,
}

impl Preetham {
    /// The sky of turbidity `t` with the sun at zenith angle `theta_sun` (radians, ≤ π/2).
    pub fn new(t: f64, theta_sun: f64) -> Preetham {
        let theta_sun = theta_sun.clamp(0.0, std::f64::consts::FRAC_PI_2);
        let linear = |c: &Linear5| c.map(|(slope, intercept)| slope * t + intercept);
        let chi = (4.0 / 9.0 - t / 120.0) * (std::f64::consts::PI - 2.0 * theta_sun);
        let zenith_luminance = (4.0453 * t - 4.9710) * chi.tan() - 0.2155 * t + 2.4192;
        let powers = [theta_sun.powi(3), theta_sun.powi(2), theta_sun, 1.0];
        let chroma = |m: &[[f64; 4]; 3]| {
            let row = |r: &[f64; 4]| r.iter().zip(&powers).map(|(a, b)| a * b).sum::<f64>();
            t * t * row(&m[0]) + t * row(&m[1]) + row(&m[2])
        };
        Preetham {
            coefficients: [linear(&PEREZ_Y), linear(&PEREZ_X), linear(&PEREZ_LITTLE_Y)],
            zenith: [zenith_luminance.max(0.0), chroma(&ZENITH_X), chroma(&ZENITH_Y)],
            theta_sun,
        }
    }

    /// Zenith luminance, kcd/m², and chromaticity.
    pub fn zenith(&self) -> [f64; 3] {
        self.zenith
    }

    fn perez(c: &[f64; 5], cos_theta: f64, gamma: f64) -> f64 {
        let [a, b, cc, d, e] = *c;
        (1.0 + a * (b / cos_theta).exp()) * (1.0 + cc * (d * gamma).exp() + e * gamma.cos().powi(2))
    }

    /// Y (kcd/m²), x, y of a direction at zenith angle θ (cosθ > 0) and γ from the sun.
    pub fn xy_luminance(&self, cos_theta: f64, gamma: f64) -> [f64; 3] {
        let mut out = [0.0; 3];
        for (k, c) in self.coefficients.iter().enumerate() {
            out[k] = self.zenith[k] * Self::perez(c, cos_theta, gamma) / Self::perez(c, 1.0, self.theta_sun);
        }
        out
    }

    /// Linear Rec. 709 radiance, W/(sr·m²) (photometric watts), of a direction at zenith angle
    /// θ (cosθ > 0) and γ from the sun.
    pub fn radiance(&self, cos_theta: f64, gamma: f64) -> Rgb {
        let [lum, x, y] = self.xy_luminance(cos_theta, gamma);
        let big_y = lum * 1000.0 / super::sun::LUMENS_PER_WATT;
        if y <= 0.0 {
            return Rgb::ZERO;
        }
        let (big_x, big_z) = (x * big_y / y, (1.0 - x - y) * big_y / y);
        let r = 3.2404542 * big_x - 1.5371385 * big_y - 0.4985314 * big_z;
        let g = -0.9692660 * big_x + 1.8760108 * big_y + 0.0415560 * big_z;
        let b = 0.0556434 * big_x - 0.2040259 * big_y + 1.0572252 * big_z;
        Rgb::new(r as f32, g as f32, b as f32).max(Rgb::ZERO)
    }
}

/// The physical sky and sun for a sun at `sun` (see the module docs); `sun_irradiance`
/// overrides the clear-sky sun's.
pub fn daylight(sun: SunPosition, options: &DaylightOptions, sun_irradiance: Option<Rgb>) -> Result<Daylight, String> {
    options.validate()?;
    let above = sun.elevation > 0.0;
    let fade = if above { 1.0 } else { (1.0 + sun.elevation / TWILIGHT_DEPTH).max(0.0) };
    let model = Preetham::new(options.turbidity, (90.0 - sun.elevation.max(0.0)).to_radians());
    let toward = SunPosition { elevation: sun.elevation.max(0.0), azimuth: sun.azimuth }.toward();
    let probe = Environment::uniform(Rgb::ZERO);
    let (w, h) = (MAP_WIDTH, MAP_HEIGHT);
    let mut texels = vec![Rgb::ZERO; (w * h) as usize];
    // What the sky gives a horizontal surface (each pixel constant over its solid angle).
    let mut sky_irradiance = glam::DVec3::ZERO;
    for y in 0..h / 2 {
        let omega = {
            let pi = std::f64::consts::PI;
            let (top, bottom) = (pi * y as f64 / h as f64, pi * (y + 1) as f64 / h as f64);
            (top.cos() - bottom.cos()) * 2.0 * pi / w as f64
        };
        for x in 0..w {
            let d = probe.direction((x as f64 + 0.5) / w as f64, (y as f64 + 0.5) / h as f64);
            let gamma = d.dot(toward).clamp(-1.0, 1.0).acos();
            let l = model.radiance(d.y, gamma) * fade as f32;
            texels[(y * w + x) as usize] = l;
            sky_irradiance += l.as_dvec3() * (omega * d.y);
        }
    }
    let sun_light = if above {
        let e = sun_irradiance.unwrap_or_else(|| clear_sky_sun(sun.elevation, options.turbidity));
        Some(sun.light("sun", e))
    } else {
        None
    };
    let sun_irradiance = sun_light.as_ref().map_or(glam::DVec3::ZERO, |s| s.intensity.as_dvec3() * toward.y);
    let ground = ((sky_irradiance + sun_irradiance) * options.ground_albedo / std::f64::consts::PI).as_vec3();
    for texel in &mut texels[(w * (h / 2)) as usize..] {
        *texel = ground;
    }
    let name = format!(
        "Preetham sky (turbidity {}, ground albedo {}, sun at {:.2}° elevation, {:.2}° azimuth)",
        options.turbidity, options.ground_albedo, sun.elevation, sun.azimuth
    );
    let sky = Environment::new(name, w, h, texels, 0.0).map_err(|e| format!("the sky model: {e}"))?;
    Ok(Daylight { sky: Arc::new(sky), sun: sun_light })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The zenith values against the paper's formulas worked by hand at T = 3 and a sun 30°
    /// up (θ_s = 60° = 1.04720 rad, θ_s² = 1.09662, θ_s³ = 1.14838): χ = (4/9 − 3/120)·(π −
    /// 2.09440) = 0.43924, tan χ = 0.46985, Y_z = 7.1649·0.46985 − 0.6465 + 2.4192 = 5.1392
    /// kcd/m²; x_z = 9·(0.00166·1.14838 − 0.00375·1.09662 + 0.00209·1.04720) +
    /// 3·(−0.02903·1.14838 + 0.06377·1.09662 − 0.03202·1.04720 + 0.00394) +
    /// (0.11693·1.14838 − 0.21196·1.09662 + 0.06052·1.04720 + 0.25886) = 0.24493; y_z
    /// likewise 0.25257.
    #[test]
    fn zenith_values_match_the_papers_formulas_worked_by_hand() {
        let m = Preetham::new(3.0, 60f64.to_radians());
        let [y, x, yy] = m.zenith();
        assert!((y - 5.1392).abs() < 2e-4, "{y}");
        assert!((x - 0.24493).abs() < 2e-5, "{x}");
        assert!((yy - 0.25257).abs() < 2e-5, "{yy}");
    }

    /// What any clear sky does: brightest near the sun, darkest about 90° from it in the
    /// sun's vertical plane, the zenith's value at the zenith, bluer than the sun's aureole,
    /// symmetric about the sun's vertical plane.
    #[test]
    fn the_sky_is_bright_around_the_sun_and_blue_away_from_it() {
        let sun = SunPosition { elevation: 30.0, azimuth: 0.0 };
        let day = daylight(sun, &DaylightOptions::default(), None).expect("a sky");
        let at = |e: f64, a: f64| day.sky.radiance(SunPosition { elevation: e, azimuth: a }.toward().as_vec3());
        let near_sun = at(35.0, 0.0);
        let opposite = at(30.0, 180.0);
        let zenith = at(90.0, 0.0);
        assert!(near_sun.y > 2.0 * zenith.y && zenith.y > opposite.y * 0.5);
        assert!(zenith.z / zenith.x > near_sun.z / near_sun.x);
        let (left, right) = (at(20.0, -70.0), at(20.0, 70.0));
        assert!((left - right).abs().max_element() < 1e-3 * left.max_element(), "{left} {right}");
        // The zenith pixel holds the zenith luminance (converted at 683 lm/W).
        let model = Preetham::new(3.0, 60f64.to_radians());
        let expected = model.zenith()[0] * 1000.0 / 683.0;
        assert!((crate::scene::luminance(zenith) as f64 / expected - 1.0).abs() < 0.01, "{zenith}");
    }

    /// The ground reflects ρ/π of what reaches it; the sun is the clear-sky sun (or the one
    /// given); below the horizon there is no sun and the sky fades out by 6° below.
    #[test]
    fn ground_sun_and_twilight() {
        let options = DaylightOptions { turbidity: 3.0, ground_albedo: 0.5 };
        let up = SunPosition { elevation: 40.0, azimuth: 120.0 };
        let day = daylight(up, &options, None).expect("a sky");
        let sun = day.sun.as_ref().expect("a sun");
        assert_eq!(sun.intensity, clear_sky_sun(40.0, 3.0));
        let sky_e = crate::scene::luminance(
            Environment::new("upper", MAP_WIDTH, MAP_HEIGHT, day.sky.texels().to_vec(), 0.0)
                .map(|mut m| {
                    let half = (MAP_WIDTH * MAP_HEIGHT / 2) as usize;
                    let upper: Vec<Rgb> = m.texels()[..half].iter().copied().chain(vec![Rgb::ZERO; half]).collect();
                    m = m.with_texels("upper".into(), upper);
                    m.irradiance(glam::Vec3::Y)
                })
                .expect("a map"),
        ) as f64;
        let sun_e = crate::scene::luminance(sun.intensity) as f64 * 40f64.to_radians().sin();
        let ground = crate::scene::luminance(day.sky.radiance(-glam::Vec3::Y)) as f64;
        assert!((ground / (0.5 * (sky_e + sun_e) / std::f64::consts::PI) - 1.0).abs() < 0.01, "{ground}");
        let given = daylight(up, &options, Some(Rgb::splat(7.0))).expect("a sky");
        assert_eq!(given.sun.expect("a sun").intensity, Rgb::splat(7.0));
        let dusk = daylight(SunPosition { elevation: -3.0, azimuth: 120.0 }, &options, None).expect("a sky");
        let horizon = daylight(SunPosition { elevation: 0.0, azimuth: 120.0 }, &options, None).expect("a sky");
        assert!(dusk.sun.is_none());
        let zenith = |d: &Daylight| d.sky.radiance(glam::Vec3::Y).y;
        assert!((zenith(&dusk) / zenith(&horizon) - 0.5).abs() < 1e-3);
        let night = daylight(SunPosition { elevation: -10.0, azimuth: 0.0 }, &options, None).expect("a sky");
        assert_eq!(night.sky.brightest(), 0.0);
        assert!(daylight(up, &DaylightOptions { turbidity: 1.0, ..options }, None).is_err());
        assert!(daylight(up, &DaylightOptions { ground_albedo: 1.5, ..options }, None).is_err());
    }
}
