//! Environment maps: radiance from every direction around the scene, as an equirectangular
//! image (docs/ARCHITECTURE.md "Light from around the scene").
//!
//! **Convention** (the Mitsuba cross-check tool's, `shared/tools/mitsuba_ref/README.md`): a
//! world direction d (glTF, +Y up) reads the map at `u = 0.5 + (φ + ρ)/2π`, `v = θ/π` with
//! `φ = atan2(d.x, −d.z)`, `θ = acos(d.y)` and ρ the rotation; row 0 is the top of the image
//! (straight up), the image centre is −Z, u = 0.75 is +X. A positive rotation turns the sky
//! counter-clockwise seen from above: a feature the unrotated map shows at azimuth φ appears
//! at φ − ρ. The lookup is bilinear with texel centres at `((i+½)/W, (j+½)/H)`, periodic in u
//! and clamped in v (the first and last rows hold over the polar caps).
//!
//! [`load`] reads `.hdr` and `.exr` files; [`split`] takes a sun out of a map.

mod load;
pub mod split;

use std::f64::consts::PI;

use glam::{DVec3, Vec3};

pub use load::{EnvironmentError, EnvironmentOptions, load_environment};

use super::{Rgb, luminance};

/// An equirectangular radiance map, W/(sr·m²), with its rotation about +Y.
#[derive(Clone, Debug)]
pub struct Environment {
    /// What it is (the file, or the sky model), for messages and reports.
    pub name: String,
    width: u32,
    height: u32,
    /// Row-major, row 0 at the top (straight up).
    texels: Vec<Rgb>,
    /// ρ, radians.
    rotation: f32,
}

/// Why pixels do not make an environment map.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum PixelsError {
    #[error(
        "an environment map needs at least 1×1 pixels and width × height of them, got {width}×{height} and {pixels}"
    )]
    Size { width: u32, height: u32, pixels: usize },
    #[error("pixel ({x}, {y}) has radiance {value:?}: an environment map's radiance must be finite")]
    NonFinite { x: u32, y: u32, value: [f32; 3] },
    #[error("the rotation must be a finite angle, got {0}")]
    Rotation(f32),
}

impl Environment {
    /// A map of `width × height` pixels (row 0 at the top), radiance in W/(sr·m²), turned by
    /// `rotation` radians (see the module docs). Negative values are taken as 0 (an EXR's
    /// processing can leave tiny ones); non-finite ones are refused.
    pub fn new(
        name: impl Into<String>,
        width: u32,
        height: u32,
        mut texels: Vec<Rgb>,
        rotation: f32,
    ) -> Result<Environment, PixelsError> {
        if width == 0 || height == 0 || texels.len() as u64 != width as u64 * height as u64 {
            return Err(PixelsError::Size { width, height, pixels: texels.len() });
        }
        if !rotation.is_finite() {
            return Err(PixelsError::Rotation(rotation));
        }
        for (i, t) in texels.iter_mut().enumerate() {
            if !t.is_finite() {
                let (x, y) = ((i as u64 % width as u64) as u32, (i as u64 / width as u64) as u32);
                return Err(PixelsError::NonFinite { x, y, value: t.to_array() });
            }
            *t = t.max(Rgb::ZERO);
        }
        Ok(Environment { name: name.into(), width, height, texels, rotation })
    }

    /// A map of one radiance everywhere (1×1 pixel).
    pub fn uniform(radiance: Rgb) -> Environment {
        Environment {
            name: "uniform".into(),
            width: 1,
            height: 1,
            texels: vec![radiance.max(Rgb::ZERO)],
            rotation: 0.0,
        }
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    /// ρ, radians.
    pub fn rotation(&self) -> f32 {
        self.rotation
    }

    /// The pixels, row-major, row 0 at the top.
    pub fn texels(&self) -> &[Rgb] {
        &self.texels
    }

    /// Pixel (x, y).
    #[inline]
    pub fn texel(&self, x: u32, y: u32) -> Rgb {
        self.texels[y as usize * self.width as usize + x as usize]
    }

    /// The brightest channel of any pixel (what the bilinear lookup can return at most).
    pub fn brightest(&self) -> f32 {
        self.texels.iter().fold(0.0f32, |m, t| m.max(t.max_element()))
    }

    /// Map coordinates (u, v) of world direction `d` (unit length), u not wrapped.
    #[inline]
    pub fn uv(&self, d: Vec3) -> (f32, f32) {
        let phi = d.x.atan2(-d.z);
        let theta = d.y.clamp(-1.0, 1.0).acos();
        (0.5 + (phi + self.rotation) / std::f32::consts::TAU, theta / std::f32::consts::PI)
    }

    /// The world direction at map coordinates (u, v) (the inverse of [`uv`](Self::uv)).
    #[inline]
    pub fn direction(&self, u: f64, v: f64) -> DVec3 {
        let phi = 2.0 * PI * (u - 0.5) - self.rotation as f64;
        let theta = PI * v;
        DVec3::new(theta.sin() * phi.sin(), theta.cos(), -theta.sin() * phi.cos())
    }

    /// Radiance arriving from world direction `d` (unit length; toward the sky), W/(sr·m²):
    /// the bilinear lookup of the module docs.
    #[inline]
    pub fn radiance(&self, d: Vec3) -> Rgb {
        let (u, v) = self.uv(d);
        self.bilinear(u, v)
    }

    /// The bilinear lookup at map coordinates (u, v): periodic in u, clamped in v.
    #[inline]
    pub fn bilinear(&self, u: f32, v: f32) -> Rgb {
        let (w, h) = (self.width as i64, self.height as i64);
        let x = u as f64 * w as f64 - 0.5;
        let y = v as f64 * h as f64 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let col = |i: i64| i.rem_euclid(w) as u32;
        let row = |j: i64| j.clamp(0, h - 1) as u32;
        let (c0, c1, r0, r1) = (col(x0), col(x0 + 1), row(y0), row(y0 + 1));
        let top = self.texel(c0, r0) * (1.0 - fx) + self.texel(c1, r0) * fx;
        let bottom = self.texel(c0, r1) * (1.0 - fx) + self.texel(c1, r1) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// The solid angle of a pixel of row `y`, sr.
    pub fn pixel_solid_angle(&self, y: u32) -> f64 {
        let h = self.height as f64;
        let (top, bottom) = (PI * y as f64 / h, PI * (y + 1) as f64 / h);
        (top.cos() - bottom.cos()) * 2.0 * PI / self.width as f64
    }

    /// The world direction through the centre of pixel (x, y).
    pub fn pixel_direction(&self, x: u32, y: u32) -> DVec3 {
        self.direction((x as f64 + 0.5) / self.width as f64, (y as f64 + 0.5) / self.height as f64)
    }

    /// Irradiance on a surface facing `n` (unit) from the map with nothing in the way, W/m²,
    /// each pixel taken as constant over its solid angle (a quadrature of the bilinear map).
    pub fn irradiance(&self, n: Vec3) -> Rgb {
        let n = n.as_dvec3();
        let mut e = DVec3::ZERO;
        for y in 0..self.height {
            let omega = self.pixel_solid_angle(y);
            for x in 0..self.width {
                let cos = self.pixel_direction(x, y).dot(n);
                if cos > 0.0 {
                    e += self.texel(x, y).as_dvec3() * (cos * omega);
                }
            }
        }
        e.as_vec3()
    }

    /// The pixels' luminance weighted by solid angle, summed: the map's power per unit area
    /// of a sphere's cross-section, up to a constant (for shares of it).
    pub fn luminous_solid_angle(&self) -> f64 {
        (0..self.height)
            .map(|y| {
                let row = &self.texels[y as usize * self.width as usize..(y as usize + 1) * self.width as usize];
                row.iter().map(|t| luminance(*t) as f64).sum::<f64>() * self.pixel_solid_angle(y)
            })
            .sum()
    }

    /// The same map with `texels` replaced (same size and rotation).
    pub(crate) fn with_texels(&self, name: String, texels: Vec<Rgb>) -> Environment {
        debug_assert_eq!(texels.len(), self.texels.len());
        Environment { name, texels, ..self.clone_header() }
    }

    /// A map of `width × height` pixels with this one's rotation.
    pub(crate) fn resized(&self, name: String, width: u32, height: u32, texels: Vec<Rgb>) -> Environment {
        debug_assert_eq!(texels.len() as u64, width as u64 * height as u64);
        Environment { name, width, height, texels, rotation: self.rotation }
    }

    fn clone_header(&self) -> Environment {
        Environment {
            name: self.name.clone(),
            width: self.width,
            height: self.height,
            texels: Vec::new(),
            rotation: self.rotation,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(width: u32, height: u32, f: impl Fn(u32, u32) -> Rgb, rotation: f32) -> Environment {
        let texels = (0..height).flat_map(|y| (0..width).map(move |x| (x, y))).map(|(x, y)| f(x, y)).collect();
        Environment::new("test", width, height, texels, rotation).expect("a map")
    }

    /// docs/CLI.md's landmarks (`--environment`): straight up is v = 0, −Z the image centre, +X at u = 0.75,
    /// −X at u = 0.25; a rotation of +90° brings what was toward +X to −Z.
    #[test]
    fn directions_land_where_the_convention_puts_them() {
        let m = map(8, 4, |_, _| Rgb::ONE, 0.0);
        let close = |(u, v): (f32, f32), (eu, ev): (f32, f32)| (u - eu).abs() < 1e-6 && (v - ev).abs() < 1e-6;
        assert!(close(m.uv(Vec3::Y), (m.uv(Vec3::Y).0, 0.0)));
        assert!(close(m.uv(Vec3::NEG_Z), (0.5, 0.5)));
        assert!(close(m.uv(Vec3::X), (0.75, 0.5)));
        assert!(close(m.uv(Vec3::NEG_X), (0.25, 0.5)));
        assert!(close(m.uv(Vec3::NEG_Y), (m.uv(Vec3::NEG_Y).0, 1.0)));
        let turned = map(8, 4, |_, _| Rgb::ONE, 90f32.to_radians());
        // −Z now reads where +X did.
        assert!(close(turned.uv(Vec3::NEG_Z), (0.75, 0.5)), "{:?}", turned.uv(Vec3::NEG_Z));
        for (u, v) in [(0.1, 0.2), (0.5, 0.5), (0.93, 0.7)] {
            for m in [&m, &turned] {
                let d = m.direction(u, v).as_vec3();
                let (du, dv) = m.uv(d);
                assert!((du.rem_euclid(1.0) - u as f32).abs() < 1e-5 && (dv - v as f32).abs() < 1e-5);
            }
        }
    }

    /// Bilinear between texel centres, periodic across u = 0, clamped at the poles; exact
    /// at a centre.
    #[test]
    fn lookup_is_bilinear_periodic_in_u_and_clamped_in_v() {
        let m = map(4, 2, |x, y| Rgb::new(x as f32, y as f32, 1.0), 0.0);
        assert_eq!(m.bilinear(0.125, 0.25), Rgb::new(0.0, 0.0, 1.0));
        assert_eq!(m.bilinear(0.25, 0.25), Rgb::new(0.5, 0.0, 1.0));
        // Between the last column's centre (0.875) and the first's (1.125 ≡ 0.125).
        assert_eq!(m.bilinear(0.0, 0.25), Rgb::new(1.5, 0.0, 1.0));
        // Above the first row's centre and below the last's: that row.
        assert_eq!(m.bilinear(0.125, 0.0), Rgb::new(0.0, 0.0, 1.0));
        assert_eq!(m.bilinear(0.125, 1.0), Rgb::new(0.0, 1.0, 1.0));
        assert_eq!(m.bilinear(0.125, 0.5), Rgb::new(0.0, 0.5, 1.0));
    }

    /// A uniform map of radiance L gives πL on any surface (the quadrature is exact for a
    /// constant: the pixels' solid angles add up to 4π, their cosines to the disc's π).
    #[test]
    fn a_uniform_map_gives_pi_l() {
        let m = map(256, 128, |_, _| Rgb::splat(2.0), 0.3);
        let total: f64 = (0..m.height()).map(|y| m.pixel_solid_angle(y) * m.width() as f64).sum();
        assert!((total - 4.0 * PI).abs() < 1e-9);
        for n in [Vec3::Y, Vec3::X, Vec3::new(0.3, -0.8, 0.52).normalize()] {
            let e = m.irradiance(n);
            // Midpoint quadrature of cosθ over 128 rows: relative error ~ (π/128)²/24 < 1e-4.
            assert!((e / (2.0 * std::f32::consts::PI) - Rgb::ONE).abs().max_element() < 1e-3, "{n}: {e}");
        }
    }

    #[test]
    fn bad_pixels_are_refused_and_negatives_zeroed() {
        assert!(matches!(Environment::new("x", 2, 1, vec![Rgb::ONE], 0.0), Err(PixelsError::Size { .. })));
        assert!(matches!(
            Environment::new("x", 2, 1, vec![Rgb::ONE, Rgb::new(f32::NAN, 0.0, 0.0)], 0.0),
            Err(PixelsError::NonFinite { x: 1, y: 0, .. })
        ));
        let m = Environment::new("x", 1, 1, vec![Rgb::new(-1.0, 2.0, 0.0)], 0.0).expect("a map");
        assert_eq!(m.texel(0, 0), Rgb::new(0.0, 2.0, 0.0));
        assert!(Environment::new("x", 1, 1, vec![Rgb::ONE], f32::INFINITY).is_err());
    }
}
