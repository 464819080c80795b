//! Reading an environment map from a `.hdr` (Radiance RGBE) or `.exr` file.
//!
//! The path comes from the user's command line, so it is not confined to a scene's folder;
//! but it must be a regular file (a FIFO or `/dev/zero` is refused without blocking), its
//! length bounded by what an image within the pixel limit can need, and its header's size
//! is checked against `max_pixels` (the `--max-texture-pixels` of material textures) and
//! the memory it would take before anything is decoded: the same rules and the same decoder
//! limits as textures (`scene::gltf::images`).

use std::path::{Path, PathBuf};

use super::{Environment, PixelsError};
use crate::scene::Rgb;
use crate::scene::gltf::{DecodeError, FileError, decode_bounded, most_encoded_bytes, read_regular};

/// How an environment map is read and scaled.
#[derive(Clone, Debug)]
pub struct EnvironmentOptions {
    /// Multiplies every pixel (`--environment-scale`).
    pub scale: f32,
    /// ρ in degrees (`--environment-rotation`; see the module docs of [`super`]).
    pub rotation_degrees: f32,
    /// Most pixels the map may have (the texture limit, `--max-texture-pixels`).
    pub max_pixels: u64,
    /// Most bytes decoding it may hold (`None`: no limit besides `max_pixels`).
    pub memory_limit: Option<u64>,
}

/// Why an environment map could not be read. Every message starts with the file.
#[derive(Debug, thiserror::Error)]
pub enum EnvironmentError {
    #[error("{}: {reason}", file.display())]
    File { file: PathBuf, reason: String },
    #[error("{}: not a Radiance HDR (.hdr) or OpenEXR (.exr) image{}", file.display(), found.as_ref().map(|f| format!(" but {f}")).unwrap_or_default())]
    Format { file: PathBuf, found: Option<String> },
    #[error("{}: {width}×{height} pixels, more than the {limit} an environment map may have (--max-texture-pixels)", file.display())]
    TooLarge { file: PathBuf, width: u32, height: u32, limit: u64 },
    #[error("{}: decoding it would hold {need} bytes, more than the {limit} allowed (--memory-limit)", file.display())]
    OverMemory { file: PathBuf, need: u64, limit: u64 },
    #[error("{}: cannot decode: {reason}", file.display())]
    Decode { file: PathBuf, reason: String },
    #[error("{}: {source}", file.display())]
    Pixels {
        file: PathBuf,
        #[source]
        source: PixelsError,
    },
    #[error("--environment-scale must be a finite number ≥ 0, got {0}")]
    Scale(f32),
}

/// Bytes a pixel takes beside the decoder's output: the RGB f32 conversion and the map's
/// own copy.
const KEPT_PER_PIXEL: u64 = 24;

/// Reads the equirectangular map at `path` (see the module docs for what is checked).
pub fn load_environment(path: &Path, options: &EnvironmentOptions) -> Result<Environment, EnvironmentError> {
    let file = || path.to_path_buf();
    if !(options.scale.is_finite() && options.scale >= 0.0) {
        return Err(EnvironmentError::Scale(options.scale));
    }
    let rotation = options.rotation_degrees.to_radians();
    let bytes = read_regular(path, None, 0, most_encoded_bytes(options.max_pixels), None).map_err(|e| {
        EnvironmentError::File {
            file: file(),
            reason: match e {
                FileError::Io(e) => format!("cannot read the file: {e}"),
                e => format!("the file {e}"),
            },
        }
    })?;
    let bytes = radiance_signature(bytes);
    match image::guess_format(&bytes) {
        Ok(image::ImageFormat::Hdr | image::ImageFormat::OpenExr) => {}
        Ok(other) => return Err(EnvironmentError::Format { file: file(), found: Some(format!("{other:?}")) }),
        Err(_) => return Err(EnvironmentError::Format { file: file(), found: None }),
    }
    let decoded =
        decode_bounded(&bytes, options.max_pixels, 0, KEPT_PER_PIXEL, options.memory_limit).map_err(|e| match e {
            DecodeError::Format => EnvironmentError::Format { file: file(), found: None },
            DecodeError::TooLarge { width, height } => {
                EnvironmentError::TooLarge { file: file(), width, height, limit: options.max_pixels }
            }
            DecodeError::OverMemory { need, limit } => EnvironmentError::OverMemory { file: file(), need, limit },
            DecodeError::Decode { reason, .. } => EnvironmentError::Decode { file: file(), reason },
        })?;
    drop(bytes);
    let rgb = decoded.into_rgb32f();
    let (width, height) = rgb.dimensions();
    let texels: Vec<Rgb> = rgb.as_raw().chunks_exact(3).map(|p| Rgb::new(p[0], p[1], p[2]) * options.scale).collect();
    drop(rgb);
    let name = path.display().to_string();
    let negatives = texels.iter().filter(|t| t.min_element() < 0.0).count();
    let map = Environment::new(name, width, height, texels, rotation)
        .map_err(|source| EnvironmentError::Pixels { file: file(), source })?;
    if negatives > 0 {
        tracing::warn!("{}: {negatives} pixel(s) with negative values taken as 0", path.display());
    }
    Ok(map)
}

/// A Radiance file starts with `#?` and the name of the program that wrote it: `#?RADIANCE`
/// by convention, `#?RGBE` from Mitsuba and other renderers. The decoder knows only the
/// first, so any other such first line (a short run of letters) is read as it.
fn radiance_signature(mut bytes: Vec<u8>) -> Vec<u8> {
    const SIGNATURE: &[u8] = b"#?RADIANCE";
    let Some(name) = bytes.strip_prefix(b"#?") else { return bytes };
    let Some(end) = name.iter().take(32).position(|&b| b == b'\n') else { return bytes };
    if end == 0 || !name[..end].iter().all(u8::is_ascii_alphanumeric) || &bytes[..end + 2] == SIGNATURE {
        return bytes;
    }
    bytes.splice(..end + 2, SIGNATURE.iter().copied());
    bytes
}

#[cfg(test)]
mod tests {
    use super::*;

    fn options() -> EnvironmentOptions {
        EnvironmentOptions { scale: 2.0, rotation_degrees: 30.0, max_pixels: 1 << 20, memory_limit: None }
    }

    fn write_hdr(path: &Path, width: u32, height: u32, f: impl Fn(u32, u32) -> [f32; 3]) {
        let mut img = image::Rgb32FImage::new(width, height);
        for (x, y, p) in img.enumerate_pixels_mut() {
            *p = image::Rgb(f(x, y));
        }
        image::DynamicImage::ImageRgb32F(img).save(path).expect("write the test map");
    }

    /// An HDR and an EXR read back with their pixels scaled, row 0 at the top, rotated.
    #[test]
    fn hdr_and_exr_files_read_back_scaled() {
        let dir = tempfile::tempdir().expect("a temporary folder");
        for name in ["sky.hdr", "sky.exr"] {
            let path = dir.path().join(name);
            write_hdr(&path, 4, 2, |x, y| [x as f32, y as f32, 0.5]);
            let m = load_environment(&path, &options()).expect("the map loads");
            assert_eq!((m.width(), m.height()), (4, 2));
            // RGBE keeps 8 bits of mantissa: 0.5 and small integers are exact.
            assert_eq!(m.texel(3, 1), Rgb::new(6.0, 2.0, 1.0), "{name}");
            assert!((m.rotation() - 30f32.to_radians()).abs() < 1e-7);
        }
    }

    /// A Radiance file whose first line names another program (`#?RGBE`, as Mitsuba writes
    /// it) reads as one that says `#?RADIANCE`.
    #[test]
    fn radiance_files_of_any_program_read() {
        let dir = tempfile::tempdir().expect("a temporary folder");
        let path = dir.path().join("sky.hdr");
        write_hdr(&path, 4, 2, |x, y| [x as f32, y as f32, 0.5]);
        let bytes = std::fs::read(&path).expect("read the map");
        let rest = bytes.strip_prefix(b"#?RADIANCE").expect("the encoder's signature");
        std::fs::write(&path, [b"#?RGBE".as_slice(), rest].concat()).expect("write the map");
        let m = load_environment(&path, &options()).expect("the map loads");
        assert_eq!(m.texel(3, 1), Rgb::new(6.0, 2.0, 1.0));
    }

    /// Not a regular file, not an HDR image, too many pixels, a bad scale: each one error
    /// naming the file and the problem, nothing decoded.
    #[test]
    fn bad_files_get_clear_errors() {
        let dir = tempfile::tempdir().expect("a temporary folder");
        let err = |path: &Path, o: &EnvironmentOptions| load_environment(path, o).expect_err("refused").to_string();
        assert!(err(dir.path(), &options()).contains("not a regular file but a directory"));
        assert!(err(&dir.path().join("missing.exr"), &options()).contains("cannot read the file"));
        let png = dir.path().join("sky.png");
        image::RgbImage::new(2, 2).save(&png).expect("write a PNG");
        assert!(err(&png, &options()).contains("not a Radiance HDR (.hdr) or OpenEXR (.exr) image but Png"));
        let big = dir.path().join("big.hdr");
        write_hdr(&big, 64, 32, |_, _| [1.0; 3]);
        let small = EnvironmentOptions { max_pixels: 1000, ..options() };
        let e = err(&big, &small);
        assert!(e.contains("64×32 pixels, more than the 1000"), "{e}");
        let tight = EnvironmentOptions { memory_limit: Some(4096), ..options() };
        assert!(err(&big, &tight).contains("more than the 4096 allowed"));
        assert!(err(&big, &EnvironmentOptions { scale: -1.0, ..options() }).contains("--environment-scale"));
        #[cfg(unix)]
        assert!(err(Path::new("/dev/zero"), &options()).contains("not a regular file"));
    }
}
