//! The two encodings of the exported light map.
//!
//! * **EXR, 32-bit float, linear RGB irradiance E in W/m²**: lossless (the bake's own f32
//!   values), read by three.js (`EXRLoader`), Babylon and Bevy, and what pipelines should use.
//! * **PNG, 8-bit sRGB-encoded E / intensity**: what every engine samples natively. Values are
//!   divided by `intensity` (the largest channel value of the map, so nothing clips) and
//!   encoded with the sRGB transfer function; the GPU decodes sRGB textures before filtering,
//!   so `intensity × texel` is E again. The sRGB curve spends its 256 levels where the eye
//!   needs them: the step near black is 1/(255·12.92) of `intensity` instead of 1/255 for
//!   plain linear 8-bit, while RGBM (the other common choice) needs a decoding shader in every
//!   engine and Babylon's RGBD is Babylon's alone.

use image::{Rgb32FImage, RgbImage};

/// sRGB transfer function (linear → encoded), both in [0, 1].
pub fn srgb_encode(linear: f32) -> f32 {
    if linear <= 0.003_130_8 { 12.92 * linear } else { 1.055 * linear.powf(1.0 / 2.4) - 0.055 }
}

/// Inverse of [`srgb_encode`].
pub fn srgb_decode(encoded: f32) -> f32 {
    if encoded <= 0.040_45 { encoded / 12.92 } else { ((encoded + 0.055) / 1.055).powf(2.4) }
}

/// Largest error of the PNG, relative to `intensity`: half an 8-bit step through the steepest
/// part of the sRGB decoding curve (at 1, slope 2.4/1.055), plus f32 rounding.
/// `|intensity · decode(png) − E| ≤ PNG_ERROR · intensity` for E in [0, intensity].
pub const PNG_ERROR: f32 = 0.5 / 255.0 * 2.4 / 1.055 + 1e-6;

/// The same bound for values up to `fraction` of `intensity`: half an 8-bit step through the
/// sRGB decoding curve where it is steepest below that value's code (the curve steepens with
/// the value, so the code half a step above `encode(fraction)` bounds it).
pub fn png_error_below(fraction: f32) -> f32 {
    let y = (srgb_encode(fraction.clamp(0.0, 1.0)) + 0.5 / 255.0).min(1.0);
    let slope = if y <= 0.040_45 { 1.0 / 12.92 } else { 2.4 / 1.055 * ((y + 0.055) / 1.055).powf(1.4) };
    0.5 / 255.0 * slope + 1e-6
}

/// The scale of the PNG: the largest channel value of `map` (so nothing clips), or 1 for an
/// all-black map.
pub fn png_intensity(map: &Rgb32FImage) -> f32 {
    let max = map.as_raw().iter().copied().filter(|v| v.is_finite()).fold(0.0f32, f32::max);
    if max > 0.0 { max } else { 1.0 }
}

/// `map / intensity`, sRGB-encoded, 8 bits per channel; negative values become 0.
pub fn png_image(map: &Rgb32FImage, intensity: f32) -> RgbImage {
    RgbImage::from_fn(map.width(), map.height(), |x, y| {
        let p = map.get_pixel(x, y).0;
        image::Rgb(p.map(|v| (srgb_encode((v / intensity).clamp(0.0, 1.0)) * 255.0).round() as u8))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_curves_are_inverse_and_match_the_standard_points() {
        for i in 0..=1000 {
            let x = i as f32 / 1000.0;
            assert!((srgb_decode(srgb_encode(x)) - x).abs() < 2e-6, "{x}");
        }
        // IEC 61966-2-1: 0.5 encoded is 0.2140 linear; the linear segment ends at 0.04045.
        assert!((srgb_decode(0.5) - 0.214_041).abs() < 1e-5);
        assert!((srgb_decode(0.040_45) - 0.003_130_8).abs() < 1e-6);
    }

    #[test]
    fn png_round_trip_stays_within_its_stated_bound() {
        // Every value of [0, 1] in fine steps, through 8 bits and back.
        let n = 4096;
        let map = Rgb32FImage::from_fn(n, 1, |x, _| {
            let v = x as f32 / (n - 1) as f32 * 3.0;
            image::Rgb([v, v * 0.5, v * 0.25])
        });
        let s = png_intensity(&map);
        assert_eq!(s, 3.0);
        let png = png_image(&map, s);
        let mut worst = 0.0f32;
        for x in 0..n {
            let (e, q) = (map.get_pixel(x, 0).0, png.get_pixel(x, 0).0);
            for c in 0..3 {
                let back = s * srgb_decode(q[c] as f32 / 255.0);
                worst = worst.max((back - e[c]).abs() / s);
            }
        }
        assert!(worst <= PNG_ERROR, "worst {worst} > bound {PNG_ERROR}");
        assert!((png_error_below(1.0) - PNG_ERROR).abs() < 1e-7);
        // Below a tenth of the intensity, the finer bound holds too and is ~3× tighter.
        let mut worst_low = 0.0f32;
        for x in 0..n {
            let (e, q) = (map.get_pixel(x, 0).0, png.get_pixel(x, 0).0);
            for c in 0..3 {
                if e[c] <= 0.1 * s {
                    worst_low = worst_low.max((s * srgb_decode(q[c] as f32 / 255.0) - e[c]).abs() / s);
                }
            }
        }
        assert!(worst_low <= png_error_below(0.1), "{worst_low} > {}", png_error_below(0.1));
        assert!(png_error_below(0.1) < PNG_ERROR / 2.5);
        // The bound is not loose by more than a few times: the steep end uses most of it.
        assert!(worst > PNG_ERROR / 3.0, "worst {worst} vs bound {PNG_ERROR}");
    }

    #[test]
    fn an_all_black_map_gets_intensity_one() {
        let map = Rgb32FImage::new(4, 4);
        assert_eq!(png_intensity(&map), 1.0);
        assert!(png_image(&map, 1.0).as_raw().iter().all(|&v| v == 0));
    }
}
