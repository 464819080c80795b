//! Textures: images from a file URI, a `data:` URI or a bufferView, decoded with `image` into
//! RGBA8, with the sampler's wrap modes. Each glTF texture used by a material becomes one
//! [`Texture`]; an image shared by several textures is decoded once and its pixels shared.
//!
//! Before an image is decoded its header's size is checked against
//! [`LoadOptions::max_texture_pixels`](super::LoadOptions) and what decoding it would take (its
//! native pixels, their RGBA8 conversion and the texture kept) against what the textures
//! decoded so far leave of [`LoadOptions::texture_memory_limit`](super::LoadOptions): a few
//! kB of PNG that declare 16384² pixels are refused, not decoded into a gigabyte.

use std::collections::HashMap;
use std::io::Cursor;
use std::path::Path;
use std::sync::Arc;

use ::gltf::json;
use image::ImageDecoder;
use json::texture::WrappingMode;
use json::validation::Checked;

use super::diag::{Diagnostics, Kind};
use super::files::{FileError, read_regular};
use super::uri::{self, UriSource};
use super::{Ctx, LoadError};
use crate::scene::{Texture, WrapMode};

/// Decoded pixels of one glTF image (shared by every texture that uses it).
#[derive(Clone)]
struct Pixels {
    width: u32,
    height: u32,
    rgba8: Arc<[[u8; 4]]>,
}

/// Bytes a decoder's output may take per pixel: RGBA of f32 (EXR, HDR), the widest format.
const MOST_NATIVE_BYTES_PER_PIXEL: u64 = 16;

/// (glTF texture index, sRGB-encoded) → scene texture index, decoding on first use.
#[derive(Default)]
pub(super) struct TextureCache {
    by_texture: HashMap<(usize, bool), usize>,
    images: HashMap<usize, Pixels>,
    /// Bytes of the decoded pixels kept (each image once).
    decoded_bytes: u64,
    pub textures: Vec<Texture>,
}

impl TextureCache {
    /// The scene texture for glTF texture `index`: a colour texture (`srgb`: base colour,
    /// emission) or a linear one (transmission). Both share the image's pixels. `None` for a
    /// texture without a core `source` (glTF allows it: only an extension's image, KTX2,
    /// WebP or DDS, none of which livebake decodes), noted in `diag`: its material shows its
    /// factors alone.
    pub(super) fn get(
        &mut self,
        ctx: &Ctx,
        diag: &mut Diagnostics,
        index: usize,
        srgb: bool,
    ) -> Result<Option<usize>, LoadError> {
        if let Some(&t) = self.by_texture.get(&(index, srgb)) {
            return Ok(Some(t));
        }
        let tex = ctx.root.textures.get(index).ok_or_else(|| {
            ctx.invalid(format!("texture {index} does not exist ({} textures)", ctx.root.textures.len()))
        })?;
        // gltf-json's placeholder for an absent `source` (its `allow_empty_texture`).
        if tex.source.value() == u32::MAX as usize {
            let extensions = tex.extensions.as_ref().map(|e| e.others.keys().cloned().collect::<Vec<_>>().join(", "));
            diag.note(Kind::TextureWithoutSource, 1, || match extensions.filter(|e| !e.is_empty()) {
                Some(e) => format!("texture {index} ({e})"),
                None => format!("texture {index}"),
            });
            return Ok(None);
        }
        let image = tex.source.value();
        let pixels = match self.images.get(&image) {
            Some(p) => p.clone(),
            None => {
                let p = decode(ctx, image, self.decoded_bytes)?;
                self.decoded_bytes += p.rgba8.len() as u64 * 4;
                self.images.insert(image, p.clone());
                p
            }
        };
        let (wrap_s, wrap_t) = wrap_modes(ctx, tex);
        self.textures.push(Texture {
            name: image_label(ctx, image),
            width: pixels.width,
            height: pixels.height,
            rgba8: pixels.rgba8,
            srgb,
            wrap_s,
            wrap_t,
        });
        let id = self.textures.len() - 1;
        self.by_texture.insert((index, srgb), id);
        Ok(Some(id))
    }
}

fn wrap_modes(ctx: &Ctx, tex: &json::Texture) -> (WrapMode, WrapMode) {
    let convert = |m: &Checked<WrappingMode>| match m {
        Checked::Valid(WrappingMode::ClampToEdge) => WrapMode::ClampToEdge,
        Checked::Valid(WrappingMode::MirroredRepeat) => WrapMode::MirroredRepeat,
        _ => WrapMode::Repeat,
    };
    match tex.sampler.and_then(|s| ctx.root.samplers.get(s.value())) {
        Some(s) => (convert(&s.wrap_s), convert(&s.wrap_t)),
        None => (WrapMode::Repeat, WrapMode::Repeat),
    }
}

/// The image's name, else its file name, else `image<index>`.
fn image_label(ctx: &Ctx, index: usize) -> String {
    let img = ctx.root.images.get(index);
    let name = img.and_then(|i| i.name.clone());
    let uri = img.and_then(|i| i.uri.as_ref()).filter(|u| !u.starts_with("data:")).cloned();
    name.or(uri).unwrap_or_else(|| format!("image{index}"))
}

/// `image 3 'wood' (textures/wood.png)` for messages.
fn describe(ctx: &Ctx, index: usize) -> String {
    let img = ctx.root.images.get(index);
    let mut s = format!("image {index}");
    if let Some(name) = img.and_then(|i| i.name.as_ref()) {
        s.push_str(&format!(" '{name}'"));
    }
    match img.and_then(|i| i.uri.as_ref()) {
        Some(u) if u.starts_with("data:") => s.push_str(" (data: URI)"),
        Some(u) => s.push_str(&format!(" ({u})")),
        None => {
            if let Some(v) = img.and_then(|i| i.buffer_view) {
                s.push_str(&format!(" (bufferView {})", v.value()));
            }
        }
    }
    s
}

/// `image 3 'wood'`: the image without its source, for messages that name the URI apart.
fn describe_object(ctx: &Ctx, index: usize) -> String {
    match ctx.root.images.get(index).and_then(|i| i.name.as_ref()) {
        Some(name) => format!("image {index} '{name}'"),
        None => format!("image {index}"),
    }
}

/// Decodes image `index` after checking its header's size against the options; `kept`:
/// bytes of the textures decoded before it.
fn decode(ctx: &Ctx, index: usize, kept: u64) -> Result<Pixels, LoadError> {
    let error = |reason: String| LoadError::Image { file: ctx.file.into(), image: describe(ctx, index), reason };
    let bytes = encoded_bytes(ctx, index)?;
    let max_pixels = ctx.options.max_texture_pixels;
    // At its peak: the native pixels, their RGBA8 conversion and the texture's copy.
    let decoded =
        decode_bounded(&bytes, max_pixels, kept, 8, ctx.options.texture_memory_limit).map_err(|e| match e {
            DecodeError::Format => error("unrecognised image format (livebake decodes PNG and JPEG)".into()),
            DecodeError::TooLarge { width, height } => LoadError::TextureTooLarge {
                file: ctx.file.into(),
                image: describe(ctx, index),
                width,
                height,
                limit: max_pixels,
            },
            DecodeError::OverMemory { need, limit } => {
                LoadError::TexturesOverMemory { file: ctx.file.into(), image: describe(ctx, index), need, limit }
            }
            DecodeError::Decode { format, reason } => error(format!("cannot decode the {format:?} data: {reason}")),
        })?;
    drop(bytes);
    let rgba = decoded.into_rgba8();
    let (width, height) = rgba.dimensions();
    let rgba8 = rgba.as_raw().chunks_exact(4).map(|p| [p[0], p[1], p[2], p[3]]).collect();
    Ok(Pixels { width, height, rgba8 })
}

/// Why [`decode_bounded`] decoded nothing.
#[derive(Debug)]
pub(crate) enum DecodeError {
    /// Not an image format livebake decodes.
    Format,
    /// The header declares more pixels than allowed.
    TooLarge {
        width: u32,
        height: u32,
    },
    /// Decoding would take what is held past the memory limit.
    OverMemory {
        need: u64,
        limit: u64,
    },
    Decode {
        format: image::ImageFormat,
        reason: String,
    },
}

/// Decodes an encoded image after checking its header: at most `max_pixels` pixels, and
/// `kept` bytes already held plus the decoder's output plus `kept_per_pixel` bytes a pixel
/// that the caller makes of it at most `limit`. The decoder's own allocations are held to
/// what an image within the pixel limit needs, so a header that lies about its size cannot
/// take more. One rule for material textures and environment maps.
pub(crate) fn decode_bounded(
    bytes: &[u8],
    max_pixels: u64,
    kept: u64,
    kept_per_pixel: u64,
    limit: Option<u64>,
) -> Result<image::DynamicImage, DecodeError> {
    let format = image::guess_format(bytes).map_err(|_| DecodeError::Format)?;
    let mut reader = image::ImageReader::with_format(Cursor::new(bytes), format);
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(max_pixels.saturating_mul(MOST_NATIVE_BYTES_PER_PIXEL).max(1 << 20));
    reader.limits(limits);
    let cannot = |e: image::ImageError| DecodeError::Decode { format, reason: e.to_string() };
    let decoder = reader.into_decoder().map_err(cannot)?;
    let (width, height) = decoder.dimensions();
    let pixels = width as u64 * height as u64;
    if pixels > max_pixels {
        return Err(DecodeError::TooLarge { width, height });
    }
    let need = kept.saturating_add(decoder.total_bytes()).saturating_add(pixels.saturating_mul(kept_per_pixel));
    if let Some(limit) = limit
        && need > limit
    {
        return Err(DecodeError::OverMemory { need, limit });
    }
    image::DynamicImage::from_decoder(decoder).map_err(cannot)
}

/// The most bytes an encoded image within `max_pixels` pixels may have: its raw pixels at
/// the widest format, and a header.
pub(crate) fn most_encoded_bytes(max_pixels: u64) -> u64 {
    max_pixels.saturating_mul(MOST_NATIVE_BYTES_PER_PIXEL).saturating_add(1 << 20)
}

/// The encoded bytes (PNG, JPEG...) of image `index`, from its bufferView or its URI.
pub(super) fn encoded_bytes(ctx: &Ctx, index: usize) -> Result<Vec<u8>, LoadError> {
    let error = |reason: String| LoadError::Image { file: ctx.file.into(), image: describe(ctx, index), reason };
    let img = ctx.root.images.get(index).ok_or_else(|| error("does not exist".into()))?;
    match img.buffer_view {
        // A bad bufferView is reported as such (ViewOutOfBounds...).
        Some(view) => Ok(ctx.buffers.view(ctx.file, ctx.root, view.value())?.to_vec()),
        None => image_bytes(ctx, index, img),
    }
}

/// The encoded bytes of an image given by URI, or why they cannot be had.
fn image_bytes(ctx: &Ctx, index: usize, img: &json::Image) -> Result<Vec<u8>, LoadError> {
    let error = |reason: String| LoadError::Image { file: ctx.file.into(), image: describe(ctx, index), reason };
    let Some(uri_text) = &img.uri else {
        return Err(error("has neither a uri nor a bufferView".into()));
    };
    let refused = |reason: String| LoadError::FileRefused {
        file: ctx.file.into(),
        object: describe_object(ctx, index),
        uri: uri_text.clone(),
        reason,
    };
    let base_dir = ctx.file.parent().unwrap_or(Path::new("."));
    let source = uri::resolve(base_dir, uri_text, &ctx.scope).map_err(|e| match e {
        uri::UriError::Refused(r) => refused(r.to_string()),
        e => error(e.to_string()),
    })?;
    match source {
        UriSource::Data { bytes, .. } => Ok(bytes),
        UriSource::File(path) => {
            // No encoding of an image within the pixel limit needs more than its raw pixels
            // at the widest format, and a header.
            let most = most_encoded_bytes(ctx.options.max_texture_pixels);
            read_regular(&path, Some(&ctx.scope), 0, most, None).map_err(|e| match e {
                FileError::Io(e) => {
                    error(format!("cannot read '{}' (looked for at {}): {e}", uri_text, path.display()))
                }
                e => refused(e.to_string()),
            })
        }
    }
}
