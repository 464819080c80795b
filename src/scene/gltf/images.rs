//! Textures: images from a file URI, a `data:` URI or a bufferView, decoded with `image` into
//! RGBA8, with the sampler's wrap modes. Each glTF texture used by a material becomes one
//! [`Texture`]; an image shared by several textures is decoded once.

use std::collections::HashMap;
use std::path::Path;
use std::rc::Rc;

use ::gltf::json;
use json::texture::WrappingMode;
use json::validation::Checked;

use super::uri::{self, UriSource};
use super::{Ctx, LoadError};
use crate::scene::{Texture, WrapMode};

/// Decoded pixels of one glTF image.
struct Pixels {
    width: u32,
    height: u32,
    rgba8: Vec<[u8; 4]>,
}

/// glTF texture index → scene texture index, decoding on first use.
#[derive(Default)]
pub(super) struct TextureCache {
    by_texture: HashMap<usize, usize>,
    images: HashMap<usize, Rc<Pixels>>,
    pub textures: Vec<Texture>,
}

impl TextureCache {
    /// The scene texture for glTF texture `index` (a colour texture: sRGB).
    pub(super) fn get(&mut self, ctx: &Ctx, index: usize) -> Result<usize, LoadError> {
        if let Some(&t) = self.by_texture.get(&index) {
            return Ok(t);
        }
        let tex = ctx.root.textures.get(index).ok_or_else(|| {
            ctx.invalid(format!("texture {index} does not exist ({} textures)", ctx.root.textures.len()))
        })?;
        let image = tex.source.value();
        let pixels = match self.images.get(&image) {
            Some(p) => Rc::clone(p),
            None => {
                let p = Rc::new(decode(ctx, image)?);
                self.images.insert(image, Rc::clone(&p));
                p
            }
        };
        let (wrap_s, wrap_t) = wrap_modes(ctx, tex);
        self.textures.push(Texture {
            name: image_label(ctx, image),
            width: pixels.width,
            height: pixels.height,
            rgba8: pixels.rgba8.clone(),
            srgb: true,
            wrap_s,
            wrap_t,
        });
        let id = self.textures.len() - 1;
        self.by_texture.insert(index, id);
        Ok(id)
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

fn decode(ctx: &Ctx, index: usize) -> Result<Pixels, LoadError> {
    let error = |reason: String| LoadError::Image { file: ctx.file.into(), image: describe(ctx, index), reason };
    let bytes = encoded_bytes(ctx, index)?;
    let format = image::guess_format(&bytes)
        .map_err(|_| error("unrecognised image format (livebake decodes PNG and JPEG)".into()))?;
    let decoded = image::load_from_memory_with_format(&bytes, format)
        .map_err(|e| error(format!("cannot decode the {format:?} data: {e}")))?;
    let rgba = decoded.to_rgba8();
    let (width, height) = rgba.dimensions();
    let rgba8 = rgba.pixels().map(|p| p.0).collect();
    Ok(Pixels { width, height, rgba8 })
}

/// The encoded bytes (PNG, JPEG...) of image `index`, from its bufferView or its URI.
pub(super) fn encoded_bytes(ctx: &Ctx, index: usize) -> Result<Vec<u8>, LoadError> {
    let error = |reason: String| LoadError::Image { file: ctx.file.into(), image: describe(ctx, index), reason };
    let img = ctx.root.images.get(index).ok_or_else(|| error("does not exist".into()))?;
    match img.buffer_view {
        // A bad bufferView is reported as such (ViewOutOfBounds...).
        Some(view) => Ok(ctx.buffers.view(ctx.file, ctx.root, view.value())?.to_vec()),
        None => image_bytes(ctx, img).map_err(error),
    }
}

/// The encoded bytes of an image given by URI, or why they cannot be had.
fn image_bytes(ctx: &Ctx, img: &json::Image) -> Result<Vec<u8>, String> {
    let Some(uri_text) = &img.uri else {
        return Err("has neither a uri nor a bufferView".into());
    };
    let base_dir = ctx.file.parent().unwrap_or(Path::new("."));
    match uri::resolve(base_dir, uri_text).map_err(|e| e.to_string())? {
        UriSource::Data { bytes, .. } => Ok(bytes),
        UriSource::File(path) => std::fs::read(&path)
            .map_err(|e| format!("cannot read '{}' (looked for at {}): {e}", uri_text, path.display())),
    }
}
