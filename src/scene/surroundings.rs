//! Light from around the scene that the command line gives rather than the file: a uniform
//! sky, an environment map and a sun (docs/ARCHITECTURE.md "Light from around the scene"),
//! and how they are made ([`SurroundingsSpec`]) so that a front end can move the sun and
//! make them again.

use std::sync::Arc;

use super::daylight::{DaylightOptions, daylight};
use super::environment::Environment;
use super::environment::split::{SunSplit, split_sun};
use super::radiometry::TooBright;
use super::sun::{Instant, SunPosition, clear_sky_sun, solar_position};
use super::{LightKind, PunctualLight, Rgb, Scene};

/// What lights a scene from outside it. Rays that leave the scene see `sky +
/// environment(d)`; the sun is a directional light of the punctual layer.
#[derive(Clone, Debug, Default)]
pub struct Surroundings {
    /// Uniform radiance, W/(sr·m²).
    pub sky: Rgb,
    /// Radiance by direction, W/(sr·m²).
    pub environment: Option<Arc<Environment>>,
    /// A directional light (`--sun`, a sun study, the sky model's sun, an environment map's
    /// split-off sun).
    pub sun: Option<PunctualLight>,
}

impl Scene {
    /// Replaces the scene's surroundings (those set before are taken away, the file's lights
    /// kept), refusing light too bright for the scene's sums (see
    /// [`radiometry`](super::radiometry)).
    pub fn set_surroundings(&mut self, s: &Surroundings) -> Result<(), TooBright> {
        let c = self.light_ceiling();
        let brightest = s.sky.max_element() + s.environment.as_ref().map_or(0.0, |e| e.brightest());
        c.check(|| "the sky and environment radiance".into(), brightest as f64, c.radiance(), "W/(sr·m²)")?;
        let file_lights = self.lights.len() - self.surrounding_lights;
        if let Some(sun) = &s.sun {
            let most = c.light_intensity(true, file_lights + 1);
            c.check(|| format!("the sun '{}'", sun.name), sun.intensity.max_element() as f64, most, "W/m²")?;
        }
        self.lights.truncate(file_lights);
        self.lights.extend(s.sun.clone());
        self.surrounding_lights = s.sun.is_some() as usize;
        self.sky = s.sky;
        self.environment = s.environment.clone();
        Ok(())
    }

    /// The surroundings set with [`set_surroundings`](Self::set_surroundings) (or `sky`).
    pub fn surroundings(&self) -> Surroundings {
        let first = self.lights.len() - self.surrounding_lights;
        Surroundings { sky: self.sky, environment: self.environment.clone(), sun: self.lights.get(first).cloned() }
    }

    /// Whether rays leaving the scene see any light.
    pub fn has_sky(&self) -> bool {
        self.sky.max_element() > 0.0 || self.environment.as_ref().is_some_and(|e| e.brightest() > 0.0)
    }

    /// With an automatic sky ([`sky_automatic`](Scene::sky_automatic)), the white stand-in sky
    /// ([`STAND_IN_SKY`]) where nothing else lights the scene, and none where something does
    /// (a lamp added by a save): models exported for a walkthrough rarely carry
    /// their lighting, and a black result would only puzzle, but the stand-in must not add to
    /// light the scene has. Returns whether the stand-in is on. Without an automatic sky,
    /// nothing changes.
    pub fn stand_in_sky(&mut self) -> bool {
        if !self.sky_automatic {
            return false;
        }
        // An automatic sky is black but for the stand-in: judge the scene without it.
        self.sky = Rgb::ZERO;
        let unlit = !self.has_light();
        if unlit {
            self.sky = Rgb::splat(STAND_IN_SKY);
        }
        unlit
    }

    /// Whether anything lights the scene: a punctual light (the file's or the sun), a mesh
    /// whose material emits, or a sky. Without any, every light map is black.
    pub fn has_light(&self) -> bool {
        self.lights.iter().any(|l| l.intensity.max_element() > 0.0)
            || self.meshes.iter().any(|m| self.material_of(m).emission.max_element() > 0.0)
            || self.has_sky()
    }
}

/// Radiance (W/(sr·m²)) of the white sky that stands in for a scene's missing lighting
/// ([`Scene::stand_in_sky`]): a surface open to the whole sky gets π W/m².
pub const STAND_IN_SKY: f32 = 1.0;

/// The sky as a picture: radiance (W/(sr·m²)) toward every direction, `sky +
/// environment(d)`, over an equirectangular grid of `width × height` pixels (row 0 up, +Y;
/// u = ½ + atan2(x, −z)/2π, v = acos(y)/π, as an unrotated [`Environment`]), sampled at pixel
/// centres. What a viewer shows where no surface is.
#[derive(Clone, Debug, PartialEq)]
pub struct SkyPicture {
    pub width: u32,
    pub height: u32,
    /// Row-major, `width × height`.
    pub radiance: Vec<Rgb>,
}

impl SkyPicture {
    /// The radiance when every pixel has the same (a uniform sky, no map): a viewer clears to
    /// it rather than drawing the picture.
    pub fn uniform(&self) -> Option<Rgb> {
        let first = *self.radiance.first()?;
        self.radiance.iter().all(|&l| l == first).then_some(first)
    }
}

/// The widest sky picture: 1024 × 512 pixels (8 MB as RGBA f32), a third of a degree each.
const SKY_PICTURE_WIDTH: u32 = 1024;

impl Scene {
    /// The sky this scene's rays see on leaving it ([`SkyPicture`]), at the environment map's
    /// resolution up to 1024 × 512 (a uniform sky: 4 × 2); `None` when it is black.
    pub fn sky_picture(&self) -> Option<SkyPicture> {
        if !self.has_sky() {
            return None;
        }
        let width = self.environment.as_ref().map_or(4, |e| e.width().clamp(4, SKY_PICTURE_WIDTH));
        let height = width / 2;
        let mut radiance = Vec::with_capacity((width * height) as usize);
        for y in 0..height {
            let theta = std::f32::consts::PI * (y as f32 + 0.5) / height as f32;
            for x in 0..width {
                let phi = std::f32::consts::TAU * ((x as f32 + 0.5) / width as f32 - 0.5);
                let d = glam::Vec3::new(theta.sin() * phi.sin(), theta.cos(), -theta.sin() * phi.cos());
                radiance.push(self.sky + self.environment.as_ref().map_or(Rgb::ZERO, |e| e.radiance(d)));
            }
        }
        Some(SkyPicture { width, height, radiance })
    }
}

/// Where the sun is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SunPlacement {
    /// Elevation and azimuth (`--sun`).
    Fixed(SunPosition),
    /// A sun study (`--location`, `--time`): latitude, longitude (degrees) and an instant.
    Study { latitude: f64, longitude: f64, time: Instant },
}

impl SunPlacement {
    pub fn position(&self) -> SunPosition {
        match *self {
            SunPlacement::Fixed(p) => p,
            SunPlacement::Study { latitude, longitude, time } => solar_position(latitude, longitude, time),
        }
    }

    /// The sun moved by one step of a front end's key: `steps` × 15 minutes of a sun study,
    /// or × 5° of azimuth (`elevation_steps` × 5° of elevation, within ±90°).
    pub fn moved(&self, steps: i32, elevation_steps: i32) -> SunPlacement {
        match *self {
            SunPlacement::Fixed(p) => SunPlacement::Fixed(SunPosition {
                elevation: (p.elevation + 5.0 * elevation_steps as f64).clamp(-90.0, 90.0),
                azimuth: (p.azimuth + 5.0 * steps as f64).rem_euclid(360.0),
            }),
            SunPlacement::Study { latitude, longitude, time } => SunPlacement::Study {
                latitude,
                longitude,
                time: Instant(time.0 + 900.0 * steps as f64 + 86_400.0 * elevation_steps as f64),
            },
        }
    }

    /// For titles and events: `elevation 30.0°, azimuth 120.0°` (and the time of a study).
    pub fn describe(&self) -> String {
        let p = self.position();
        let at = format!("elevation {:.1}°, azimuth {:.1}°", p.elevation, p.azimuth);
        match self {
            SunPlacement::Fixed(_) => at,
            SunPlacement::Study { time, .. } => format!("{} UTC, {at}", super::sun::format_time(*time)),
        }
    }
}

/// How the surroundings are made from the command line's options.
#[derive(Clone, Debug)]
pub struct SurroundingsSpec {
    /// `--sky`.
    pub sky: Rgb,
    /// `--environment` as loaded (its sun already split off, see `environment_sun`).
    pub environment: Option<Arc<Environment>>,
    /// The directional light split off the environment map (the sun when no other is placed).
    pub environment_sun: Option<PunctualLight>,
    /// `--sun` or a sun study.
    pub sun: Option<SunPlacement>,
    /// The sun's irradiance when given (`--sun`'s third number); else the clear-sky sun's.
    pub sun_irradiance: Option<Rgb>,
    /// `--sky-model preetham`.
    pub daylight: Option<DaylightOptions>,
    /// The clear-sky sun's turbidity when there is no sky model (`--turbidity`).
    pub turbidity: f64,
}

impl Default for SurroundingsSpec {
    fn default() -> Self {
        SurroundingsSpec {
            sky: Rgb::ZERO,
            environment: None,
            environment_sun: None,
            sun: None,
            sun_irradiance: None,
            daylight: None,
            turbidity: DaylightOptions::default().turbidity,
        }
    }
}

impl SurroundingsSpec {
    /// Splits the sun off an environment map (see [`split_sun`]); logs what it did.
    pub fn take_sun_from(map: Environment) -> (Arc<Environment>, Option<PunctualLight>, Option<SunSplit>) {
        match split_sun(&map) {
            Some(split) => {
                let toward = split.toward;
                let elevation = toward.y.asin().to_degrees();
                let azimuth = toward.x.atan2(-toward.z).to_degrees().rem_euclid(360.0);
                tracing::info!(
                    "{}: its sun ({} pixels, {:.2e} sr above {:.3e} W/(sr·m²), the sky around it at {:.3e}; {:.0}% of the \
                     map's light) is a directional light at elevation {elevation:.2}°, azimuth {azimuth:.2}°, {} W/m²",
                    map.name,
                    split.pixels,
                    split.solid_angle,
                    split.threshold,
                    split.sky_level,
                    split.share * 100.0,
                    split.sun.intensity,
                );
                (Arc::new(split.sky.clone()), Some(split.sun.clone()), Some(split))
            }
            None => (Arc::new(map), None, None),
        }
    }

    /// The surroundings this makes.
    pub fn build(&self) -> Result<Surroundings, String> {
        let position = self.sun.map(|s| s.position());
        let mut out = Surroundings { sky: self.sky, environment: self.environment.clone(), sun: None };
        match (self.daylight, position) {
            (Some(options), Some(p)) => {
                let day = daylight(p, &options, self.sun_irradiance)?;
                out.environment = Some(day.sky);
                out.sun = day.sun;
            }
            (Some(_), None) => return Err("--sky-model needs the sun: --sun or --location with --time".into()),
            (None, Some(p)) => {
                let e = self.sun_irradiance.unwrap_or_else(|| clear_sky_sun(p.elevation, self.turbidity));
                out.sun = (p.elevation > 0.0 || self.sun_irradiance.is_some()).then(|| p.light("sun", e));
            }
            (None, None) => out.sun = self.environment_sun.clone(),
        }
        if out.sun.as_ref().is_some_and(|s| s.kind != LightKind::Directional) {
            return Err("the sun must be a directional light".into());
        }
        Ok(out)
    }

    /// Whether a front end can move the sun.
    pub fn movable(&self) -> bool {
        self.sun.is_some()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::SceneBuilder;

    /// Setting surroundings twice replaces the first sun, keeps the file's lights, and a sun
    /// or sky beyond the ceiling is refused with the scene unchanged.
    #[test]
    fn surroundings_replace_each_other_and_keep_the_files_lights() {
        let mut b = SceneBuilder::new();
        let m = b.material(crate::scene::Material::default());
        b.floor("floor", glam::Vec3::ZERO, 1.0, m);
        b.point_light(glam::Vec3::Y, Rgb::ONE);
        let mut scene = b.build();
        let sun = |e| SunPosition { elevation: e, azimuth: 0.0 }.light("sun", Rgb::splat(3.0));
        let first = Surroundings { sky: Rgb::splat(0.5), environment: None, sun: Some(sun(30.0)) };
        scene.set_surroundings(&first).expect("fits");
        scene.set_surroundings(&Surroundings { sun: Some(sun(60.0)), ..first.clone() }).expect("fits");
        assert_eq!(scene.lights.len(), 2);
        assert_eq!(scene.lights[0].name, "point");
        assert!((scene.lights[1].direction.y + 60f32.to_radians().sin()).abs() < 1e-6);
        let blinding = Surroundings {
            sun: Some(SunPosition { elevation: 30.0, azimuth: 0.0 }.light("sun", Rgb::splat(1e30))),
            ..first
        };
        assert!(scene.set_surroundings(&blinding).is_err());
        assert_eq!(scene.lights.len(), 2);
        scene.set_surroundings(&Surroundings::default()).expect("nothing");
        assert_eq!(scene.lights.len(), 1);
        assert!(!scene.has_sky());
    }

    /// The sky picture is the sky and environment seen toward each pixel's direction: a
    /// black sky has none; a uniform sky is that radiance everywhere; a map bright only above
    /// the horizon and toward +X (u ≥ ½: sin φ > 0) adds its radiance to the picture's upper
    /// rows' right half and nothing elsewhere.
    #[test]
    fn the_sky_picture_is_the_sky_seen_in_each_direction() {
        let mut b = SceneBuilder::new();
        let m = b.material(crate::scene::Material::default());
        b.floor("floor", glam::Vec3::ZERO, 1.0, m);
        let scene = b.build();
        assert_eq!(scene.sky_picture(), None);
        let sky = |s: &Surroundings| {
            let mut scene = scene.clone();
            scene.set_surroundings(s).expect("fits");
            scene.sky_picture().expect("a sky")
        };
        let uniform = sky(&Surroundings { sky: Rgb::splat(0.5), ..Surroundings::default() });
        assert!(uniform.radiance.iter().all(|&l| l == Rgb::splat(0.5)));
        // 64 × 32 pixels: rows 0–15 above the horizon, columns 32–63 toward +X.
        let bright = |x: u32, y: u32| y < 16 && x >= 32;
        let texels =
            (0..32).flat_map(|y| (0..64).map(move |x| Rgb::splat(if bright(x, y) { 4.0 } else { 0.0 }))).collect();
        let map = Environment::new("upper east", 64, 32, texels, 0.0).expect("a map");
        let picture = sky(&Surroundings { sky: Rgb::splat(0.5), environment: Some(Arc::new(map)), sun: None });
        assert_eq!((picture.width, picture.height), (64, 32));
        for y in 0..32 {
            for x in 0..64 {
                // Pixels next to an edge of the bright quarter blend across it (bilinear lookup).
                let near_edge = (15..=16).contains(&y) || [0, 31, 32, 63].contains(&x);
                if near_edge {
                    continue;
                }
                let want = if bright(x, y) { 4.5 } else { 0.5 };
                let l = picture.radiance[(y * 64 + x) as usize];
                assert!((l - Rgb::splat(want)).abs().max_element() < 1e-5, "pixel ({x}, {y}): {l}");
            }
        }
    }

    /// A scene is lit by a punctual light, an emitting material a mesh uses, or a sky; by
    /// nothing else (an unused emitting material, a light of zero intensity, a black sky).
    #[test]
    fn a_scene_has_light_from_a_lamp_an_emitter_or_the_sky() {
        let dark = |extra: &dyn Fn(&mut SceneBuilder)| {
            let mut b = SceneBuilder::new();
            let m = b.material(crate::scene::Material::default());
            b.floor("floor", glam::Vec3::ZERO, 1.0, m);
            extra(&mut b);
            b.build()
        };
        let glowing = crate::scene::Material { emission: Rgb::new(0.0, 0.0, 2.0), ..Default::default() };
        assert!(!dark(&|_| {}).has_light());
        assert!(
            !dark(&|b| {
                let _unused = b.material(glowing.clone());
            })
            .has_light(),
            "an emitter no mesh uses"
        );
        assert!(
            !dark(&|b| {
                b.point_light(glam::Vec3::Y, Rgb::ZERO);
            })
            .has_light(),
            "a black lamp"
        );
        assert!(
            dark(&|b| {
                b.point_light(glam::Vec3::Y, Rgb::ONE);
            })
            .has_light()
        );
        assert!(
            dark(&|b| {
                let e = b.material(glowing.clone());
                b.floor("panel", glam::Vec3::Y, 0.5, e);
            })
            .has_light()
        );
        let mut sky = dark(&|_| {});
        sky.set_surroundings(&Surroundings { sky: Rgb::ZERO, ..Default::default() }).expect("black");
        assert!(!sky.has_light());
        sky.set_surroundings(&Surroundings { sky: Rgb::splat(0.1), ..Default::default() }).expect("fits");
        assert!(sky.has_light());
        let sun = SunPosition { elevation: 30.0, azimuth: 0.0 }.light("sun", Rgb::splat(3.0));
        sky.set_surroundings(&Surroundings { sun: Some(sun), ..Default::default() }).expect("fits");
        assert!(sky.has_light() && !sky.has_sky());
    }

    #[test]
    fn a_sky_model_needs_a_sun_and_a_set_sun_needs_no_model() {
        let model = SurroundingsSpec { daylight: Some(DaylightOptions::default()), ..Default::default() };
        assert!(model.build().is_err());
        let placed = SunPlacement::Fixed(SunPosition { elevation: 45.0, azimuth: 90.0 });
        let sun_only = SurroundingsSpec { sun: Some(placed), ..Default::default() };
        let s = sun_only.build().expect("a sun");
        assert!(s.environment.is_none());
        assert_eq!(s.sun.expect("a sun").intensity, clear_sky_sun(45.0, 3.0));
        let with_sky = SurroundingsSpec { daylight: Some(DaylightOptions::default()), ..sun_only };
        assert!(with_sky.build().expect("a sky").environment.is_some());
        let moved = placed.moved(2, -1).position();
        assert_eq!((moved.elevation, moved.azimuth), (40.0, 100.0));
    }
}
