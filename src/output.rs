//! Writers for bake results: `lightmap_lodK.exr` (linear irradiance), `lightmap_lodK.png`
//! (tone-mapped outgoing radiance preview) and `report.json`.
//!
//! Every file is written to a temporary name in the output directory and renamed into place,
//! so an interrupted run never leaves a half-written light map behind an old good one.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use image::{ImageFormat, Rgb32FImage, RgbImage};
use serde::Serialize;

use crate::bake::{BakeOutput, BakedLod};
use crate::scene::Rgb;

#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    #[error("cannot create output directory {path}: {source}")]
    CreateDir { path: PathBuf, source: std::io::Error },
    #[error("cannot write {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("cannot encode {path}: {source}")]
    Encode { path: PathBuf, source: image::ImageError },
    #[error("cannot serialise {path}: {source}")]
    Json { path: PathBuf, source: serde_json::Error },
}

/// Writes `path` through a temporary sibling file and an atomic rename.
fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> Result<(), OutputError>,
) -> Result<(), OutputError> {
    let io_err = |source| OutputError::Io { path: path.to_path_buf(), source };
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".partial");
    let tmp = PathBuf::from(tmp);
    let file = File::create(&tmp).map_err(io_err)?;
    let mut w = BufWriter::new(file);
    let result = write(&mut w).and_then(|_| w.flush().map_err(io_err));
    match result {
        Ok(()) => std::fs::rename(&tmp, path).map_err(io_err),
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            Err(e)
        }
    }
}

/// Linear RGB irradiance of every pixel of `lod` (gutters filled, empty pixels 0), written
/// straight into the image (no full-size copy of the map beside it).
pub fn irradiance_image(lod: &BakedLod) -> Rgb32FImage {
    spread(lod, &lod.irradiance, image::Rgb([0.0; 3]), |e| image::Rgb(e.to_array()))
}

/// An image of `lod`'s size with each texel's `value` mapped by `pixel` at its pixel and
/// at the gutter pixels copying it; other pixels are `empty`.
fn spread<P: image::Pixel, T: Copy>(
    lod: &BakedLod,
    values: &[T],
    empty: P,
    pixel: impl Fn(T) -> P,
) -> image::ImageBuffer<P, Vec<P::Subpixel>> {
    let t = &lod.texels;
    let mut img = image::ImageBuffer::from_pixel(t.width, t.height, empty);
    let mut put = |p: u32, v: T| img.put_pixel(p % t.width, p / t.width, pixel(v));
    for (i, &p) in t.pixel.iter().enumerate() {
        put(p, values[i]);
    }
    for &(p, i) in &t.gutter {
        put(p, values[i as usize]);
    }
    img
}

/// Tone-mapped sRGB preview of outgoing radiance `L = Le + albedo/π·E`. Exposure is set from
/// the 99th-percentile luminance so dim and bright scenes both show; empty pixels are dark grey.
pub fn radiance_preview(lod: &BakedLod) -> RgbImage {
    let radiance = lod.radiance();
    let mut lum: Vec<f32> = radiance.iter().map(|c| luminance(*c)).filter(|l| l.is_finite()).collect();
    lum.sort_by(f32::total_cmp);
    let p99 = lum.get(lum.len() * 99 / 100).copied().unwrap_or(1.0);
    drop(lum);
    let exposure = if p99 > 0.0 { 1.5 / p99 } else { 1.0 };
    const EMPTY: [u8; 3] = [24, 24, 28];
    // A texel whose radiance is NaN shows as empty, as pixels without a texel do.
    spread(lod, &radiance, image::Rgb(EMPTY), |c: Rgb| {
        image::Rgb(if c.x.is_nan() { EMPTY } else { tone_map(c * exposure) })
    })
}

fn luminance(c: Rgb) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

fn tone_map(c: Rgb) -> [u8; 3] {
    c.to_array().map(|v| {
        let v = 1.0 - (-v.max(0.0)).exp();
        let s = if v <= 0.0031308 { 12.92 * v } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 };
        (s.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
    })
}

fn encode(
    path: &Path,
    w: &mut BufWriter<File>,
    img: impl Into<image::DynamicImage>,
    fmt: ImageFormat,
) -> Result<(), OutputError> {
    img.into().write_to(w, fmt).map_err(|source| OutputError::Encode { path: path.to_path_buf(), source })
}

pub fn write_exr(path: &Path, lod: &BakedLod) -> Result<(), OutputError> {
    let img = irradiance_image(lod);
    write_atomically(path, |w| encode(path, w, img, ImageFormat::OpenExr))
}

/// Writes a linear RGB image (row-major `width × height` pixels) as EXR.
pub fn write_rgb_exr(path: &Path, width: u32, height: u32, pixels: &[Rgb]) -> Result<(), OutputError> {
    let img = Rgb32FImage::from_fn(width, height, |x, y| image::Rgb(pixels[(y * width + x) as usize].to_array()));
    write_atomically(path, |w| encode(path, w, img, ImageFormat::OpenExr))
}

pub fn write_png(path: &Path, lod: &BakedLod) -> Result<(), OutputError> {
    let img = radiance_preview(lod);
    write_atomically(path, |w| encode(path, w, img, ImageFormat::Png))
}

/// Writes an 8-bit RGB image as PNG.
pub fn write_rgb8_png(path: &Path, img: RgbImage) -> Result<(), OutputError> {
    write_atomically(path, |w| encode(path, w, img, ImageFormat::Png))
}

/// Writes a text file (CSV and the like).
pub fn write_text(path: &Path, text: &str) -> Result<(), OutputError> {
    write_atomically(path, |w| {
        w.write_all(text.as_bytes()).map_err(|source| OutputError::Io { path: path.to_path_buf(), source })
    })
}

pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<(), OutputError> {
    write_atomically(path, |w| {
        serde_json::to_writer_pretty(&mut *w, value)
            .map_err(|source| OutputError::Json { path: path.to_path_buf(), source })?;
        w.write_all(b"\n").map_err(|source| OutputError::Io { path: path.to_path_buf(), source })
    })
}

/// Writes every baked LOD (EXR + PNG) into `dir`, creating it if needed. The report is
/// written separately (by the caller, once its timings are complete).
pub fn write_lightmaps(dir: &Path, baked: &BakeOutput) -> Result<Vec<PathBuf>, OutputError> {
    std::fs::create_dir_all(dir).map_err(|source| OutputError::CreateDir { path: dir.to_path_buf(), source })?;
    let mut written = Vec::new();
    for lod in &baked.lods {
        let exr = dir.join(format!("lightmap_lod{}.exr", lod.texels.lod));
        write_exr(&exr, lod)?;
        let png = dir.join(format!("lightmap_lod{}.png", lod.texels.lod));
        write_png(&png, lod)?;
        written.extend([exr, png]);
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tone_map_is_monotone_and_bounded() {
        let a = tone_map(Rgb::splat(0.1));
        let b = tone_map(Rgb::splat(1.0));
        let c = tone_map(Rgb::splat(100.0));
        assert!(a[0] < b[0] && b[0] < c[0]);
        assert_eq!(tone_map(Rgb::ZERO), [0, 0, 0]);
        assert_eq!(c, [255, 255, 255]);
    }

    #[test]
    fn atomic_write_leaves_no_partial_file_on_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.json");
        std::fs::write(&path, "old").unwrap();
        let r = write_atomically(&path, |_| {
            Err(OutputError::Io { path: path.clone(), source: std::io::Error::other("boom") })
        });
        assert!(r.is_err());
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "old");
        assert!(!dir.path().join("x.json.partial").exists());
    }
}
