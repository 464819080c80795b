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

use crate::atlas::lookup::TexelTable;
use crate::atlas::texels::NO_TEXEL;
use crate::bake::{BakeOutput, BakedLod};
use crate::scene::{Rgb, luminance};

#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    #[error("cannot create output directory {path}: {source}")]
    CreateDir { path: PathBuf, source: std::io::Error },
    #[error("cannot write {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("cannot encode {path}: {source}")]
    Encode { path: PathBuf, source: image::ImageError },
    #[error("cannot encode {path}: {source}")]
    Exr { path: PathBuf, source: exr::error::Error },
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

/// Writes `path` as [`write_json`] does (through a temporary sibling and a rename), with
/// `write` streaming its bytes.
pub fn write_stream(path: &Path, write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>) -> Result<(), OutputError> {
    write_atomically(path, |w| write(w).map_err(|source| OutputError::Io { path: path.to_path_buf(), source }))
}

/// Linear RGB irradiance of every pixel of `lod` (gutters filled, empty pixels 0), written
/// straight into the image (no full-size copy of the map beside it).
pub fn irradiance_image(lod: &BakedLod) -> Rgb32FImage {
    spread(lod, |i| lod.irradiance[i], image::Rgb([0.0; 3]), |e| image::Rgb(e.to_array()))
}

/// An image of `lod`'s size with texel `i`'s `value(i)` mapped by `pixel` at its pixel and
/// at the gutter pixels copying it; other pixels are `empty`.
fn spread<P: image::Pixel, T: Copy>(
    lod: &BakedLod,
    value: impl Fn(usize) -> T,
    empty: P,
    pixel: impl Fn(T) -> P,
) -> image::ImageBuffer<P, Vec<P::Subpixel>> {
    let t = &lod.texels;
    let mut img = image::ImageBuffer::from_pixel(t.width, t.height, empty);
    let mut put = |p: u32, v: T| img.put_pixel(p % t.width, p / t.width, pixel(v));
    for (i, &p) in t.pixel.iter().enumerate() {
        put(p, value(i));
    }
    for &(p, i) in &t.gutter {
        put(p, value(i as usize));
    }
    img
}

/// Tone-mapped sRGB preview of outgoing radiance `L = Le + albedo/π·E`. Exposure is set from
/// the 99th-percentile luminance so dim and bright scenes both show; empty pixels are dark grey.
/// Each texel's radiance is computed where it is read, not held (12 B a texel).
pub fn radiance_preview(lod: &BakedLod) -> RgbImage {
    let radiance = |i: usize| lod.radiance_of(i);
    let mut lum: Vec<f32> = (0..lod.texels.len()).map(|i| luminance(radiance(i))).filter(|l| l.is_finite()).collect();
    // The element a sort would put there, without the sort.
    let k = lum.len() * 99 / 100;
    let p99 = if k < lum.len() { *lum.select_nth_unstable_by(k, f32::total_cmp).1 } else { 1.0 };
    drop(lum);
    let exposure = if p99 > 0.0 { 1.5 / p99 } else { 1.0 };
    const EMPTY: [u8; 3] = [24, 24, 28];
    // A texel whose radiance is NaN shows as empty, as pixels without a texel do.
    spread(lod, radiance, image::Rgb(EMPTY), |c: Rgb| {
        image::Rgb(if c.x.is_nan() { EMPTY } else { tone_map(c * exposure) })
    })
}

fn tone_map(c: Rgb) -> [u8; 3] {
    c.to_array().map(|v| (srgb_encode(tone_curve(v)).clamp(0.0, 1.0) * 255.0 + 0.5) as u8)
}

/// The display's tone curve, 1 − e^(−v) of exposed radiance v (the viewer's `tone_map`,
/// shaders/common.inc.wgsl).
pub fn tone_curve(v: f32) -> f32 {
    1.0 - (-v.max(0.0)).exp()
}

/// sRGB encoding of a linear value in [0, 1].
pub fn srgb_encode(v: f32) -> f32 {
    if v <= 0.0031308 { 12.92 * v } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 }
}

fn encode(
    path: &Path,
    w: &mut BufWriter<File>,
    img: impl Into<image::DynamicImage>,
    fmt: ImageFormat,
) -> Result<(), OutputError> {
    img.into().write_to(w, fmt).map_err(|source| OutputError::Encode { path: path.to_path_buf(), source })
}

/// Writes `lod`'s irradiance as [`irradiance_image`] holds it, in the EXR the `image` crate
/// would write of that image (the same call to `exr`), read pixel by pixel through the
/// map's lookup table rather than from a full-size image (12 B a pixel at the end of a bake,
/// where a ranked table holds ~0.5).
pub fn write_exr(path: &Path, lod: &BakedLod) -> Result<(), OutputError> {
    use exr::prelude::{Image, SpecificChannels, Vec2, WritableImage};
    let table = TexelTable::of_map(&lod.texels);
    let size = (lod.texels.width as usize, lod.texels.height as usize);
    let image = Image::from_channels(
        size,
        SpecificChannels::rgb(|p: Vec2<usize>| {
            let t = table.get(p.x() as i64, p.y() as i64);
            let e = if t == NO_TEXEL { Rgb::ZERO } else { lod.irradiance[t as usize] };
            (e.x, e.y, e.z)
        }),
    );
    write_atomically(path, |w| {
        image.write().to_buffered(w).map_err(|source| OutputError::Exr { path: path.to_path_buf(), source })
    })
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

    /// The EXR written through the lookup table is, byte for byte, the one the `image` crate
    /// writes of the full-size irradiance image, gutters and empty pixels included.
    #[test]
    fn exr_read_through_the_table_is_the_full_images() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/cornell_box/cornellBox-2.79-Cycles-gltf.gltf");
        let scene = crate::scene::load_gltf(&path, &crate::scene::LoadOptions::default()).expect("bundled scene");
        let geom = crate::scene::SceneGeometry::new(&scene);
        let config = crate::atlas::AtlasConfig { texel_budget: 5000, ..Default::default() };
        let atlas = crate::atlas::Atlas::build(&scene, &geom, &config).expect("atlas");
        let texels = crate::atlas::TexelMap::build(&scene, &geom, &atlas, 1);
        assert!(!texels.gutter.is_empty());
        let irradiance = (0..texels.len()).map(|i| Rgb::new(i as f32, 0.5, -(i as f32))).collect();
        let lod = BakedLod { texels, irradiance };
        let dir = std::env::temp_dir().join(format!("livebake-exr-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let (streamed, whole) = (dir.join("streamed.exr"), dir.join("whole.exr"));
        write_exr(&streamed, &lod).expect("streamed EXR");
        write_atomically(&whole, |w| encode(&whole, w, irradiance_image(&lod), ImageFormat::OpenExr)).expect("EXR");
        let (a, b) = (std::fs::read(&streamed).expect("read"), std::fs::read(&whole).expect("read"));
        std::fs::remove_dir_all(&dir).ok();
        assert!(a.len() > 1000 && a == b, "{} against {} bytes", a.len(), b.len());
    }

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
