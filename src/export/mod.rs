//! glTF export for other engines: the loaded scene with the light map attached, in a form
//! three.js, Babylon.js and Bevy load (docs/EXPORT.md).
//!
//! `export_gltf(scene, atlas, map, "dir/room.gltf", options)` writes
//!
//! * `dir/room.gltf` + `dir/room.bin`: the source file's materials, textures, samplers,
//!   cameras and KHR_lights_punctual lights, its images embedded in the buffer, and new
//!   geometry: one mesh per instancing node, in world space (positions and normals as the
//!   loader computed them), with the atlas layout as TEXCOORD_1 normalised to \[0, 1\]. A
//!   vertex is split where the faces around it sit in different charts. The node hierarchy is
//!   kept for cameras and lights (with its transforms, without meshes, skins or animations);
//!   the geometry nodes sit at the root with identity transforms.
//! * **Double-sided faces**: one TEXCOORD_1 per vertex cannot address a triangle's front and
//!   back charts, so a primitive with a double-sided material becomes two: its front faces,
//!   and its back faces with reversed winding and negated normals (the back made an ordinary
//!   front-facing surface). Materials are written single-sided; the back primitive shows
//!   exactly where the double-sided one showed its back.
//! * Every material gets `"MOZ_lightmap": {"index": T, "texCoord": 1, "intensity": s}` (in
//!   `extensionsUsed`), T being the PNG light map, s its scale (see [`lightmap`]).
//!   `asset.extras.livebake.lightmap` records what the maps hold and their file names.
//! * `dir/room.lightmap.exr`: irradiance E (W/m², linear RGB, f32, gutters filled) over the
//!   atlas at the LOD of the given map; `dir/room.lightmap.png`: sRGB-encoded E / s.
//!
//! The file's own TEXCOORD_1 moves to TEXCOORD_2 where a material texture reads it. Every file
//! is written under a temporary name first and renamed only when all are complete, so a
//! failed export leaves nothing half-written and no earlier export half-replaced.
//!
//! This module depends on the scene, atlas and nothing above them, so the baker and the live
//! runtime share it (the runtime with a map resampled to one LOD).

mod document;
mod geometry;
pub mod lightmap;

use std::io::{Cursor, Write};
use std::path::{Path, PathBuf};

use image::{ImageFormat, Rgb32FImage};

use crate::atlas::Atlas;
use crate::scene::{LoadError, LoadOptions, Scene, read_source};

/// How to export.
#[derive(Clone, Debug, Default)]
pub struct ExportOptions {
    /// The options the scene was loaded with (which glTF scene), so the exporter reads the
    /// same nodes from the source file.
    pub load: LoadOptions,
}

/// What an export wrote.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ExportReport {
    pub gltf: PathBuf,
    pub bin: PathBuf,
    /// Linear irradiance, f32 EXR.
    pub hdr: PathBuf,
    /// sRGB-encoded irradiance / `png_intensity`.
    pub png: PathBuf,
    /// `MOZ_lightmap.intensity`: E = png_intensity × (sRGB-decoded PNG texel).
    pub png_intensity: f32,
    /// LOD of the exported map (its size is the atlas's × 2^lod).
    pub lod: u32,
    pub width: u32,
    pub height: u32,
    /// Primitives written (a double-sided one counts twice: front and back).
    pub primitives: usize,
    /// What was not carried over, one line per kind (also logged).
    pub warnings: Vec<String>,
}

#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("the scene was not loaded from a file, so there are no materials and images to copy")]
    NoSource,
    #[error("cannot read the scene's source file again")]
    Source(#[source] LoadError),
    #[error("{}: the file changed since the scene was loaded: {detail}", file.display())]
    SourceChanged { file: PathBuf, detail: String },
    #[error("the atlas does not belong to this scene: {0}")]
    AtlasMismatch(String),
    #[error(
        "the light map is {width}×{height} pixels, which is no LOD of the {atlas_width}×{atlas_height} atlas (LOD k is the atlas size × 2^k)"
    )]
    LightmapSize { width: u32, height: u32, atlas_width: u32, atlas_height: u32 },
    #[error("the light map has a non-finite value at pixel ({x}, {y})")]
    NonFinite { x: u32, y: u32 },
    #[error("{}: the export must be a .gltf file name (its .bin, .lightmap.exr and .lightmap.png go beside it)", path.display())]
    OutputName { path: PathBuf },
    #[error("cannot create the output directory {}", path.display())]
    CreateDir {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot write {}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot encode {}", path.display())]
    Encode {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
}

/// Exports `scene` with `lightmap` (linear RGB irradiance E, W/m², over `atlas` at some LOD k:
/// `atlas.width · 2^k × atlas.height · 2^k` pixels, gutters filled, as
/// [`crate::output::irradiance_image`] gives) to `out` (`….gltf`) and its sibling files. See the
/// module documentation for what is written.
pub fn export_gltf(
    scene: &Scene,
    atlas: &Atlas,
    lightmap: &Rgb32FImage,
    out: &Path,
    options: &ExportOptions,
) -> Result<ExportReport, ExportError> {
    let files = OutputFiles::new(out)?;
    let lod = lod_of(atlas, lightmap)?;
    if let Some((x, y, _)) = lightmap.enumerate_pixels().find(|(_, _, p)| !p.0.iter().all(|v| v.is_finite())) {
        return Err(ExportError::NonFinite { x, y });
    }
    let triangles = scene.triangle_count();
    if atlas.face_of.len() != triangles {
        return Err(ExportError::AtlasMismatch(format!(
            "it has {} triangles, the scene {triangles}",
            atlas.face_of.len()
        )));
    }
    let source_path = scene.source.as_deref().ok_or(ExportError::NoSource)?;
    let source = read_source(source_path, &options.load).map_err(ExportError::Source)?;
    check_source(scene, source_path, &source)?;

    let png_intensity = lightmap::png_intensity(lightmap);
    let info = document::LightmapInfo {
        lod,
        width: lightmap.width(),
        height: lightmap.height(),
        texel_size: atlas.texel_size,
        png_intensity,
    };
    let names = document::Names { bin_uri: &files.bin.uri, png_uri: &files.png.uri, exr_uri: &files.hdr.uri };
    let built = document::build(scene, atlas, &source, &names, &info);
    for w in &built.warnings {
        tracing::warn!("glTF export {}: {w}", out.display());
    }

    let mut gltf = serde_json::to_vec_pretty(&built.json).expect("a serde_json::Value always serialises");
    gltf.push(b'\n');
    let png = encode(&files.png.path, lightmap::png_image(lightmap, png_intensity), ImageFormat::Png)?;
    // Encoded from the borrowed image: no copy of it (12 B a pixel) beside the original.
    let exr = encode_buffer(&files.hdr.path, lightmap, ImageFormat::OpenExr)?;
    // The .gltf goes last: until it is renamed, an older export stays whole.
    write_all(
        &files.dir,
        &[(&files.bin.path, &built.bin), (&files.hdr.path, &exr), (&files.png.path, &png), (&files.gltf, &gltf)]
            .map(|(p, b)| (p.as_path(), b.as_slice())),
    )?;
    Ok(ExportReport {
        gltf: files.gltf,
        bin: files.bin.path,
        hdr: files.hdr.path,
        png: files.png.path,
        png_intensity,
        lod,
        width: lightmap.width(),
        height: lightmap.height(),
        primitives: built.primitives,
        warnings: built.warnings,
    })
}

/// The LOD k with `atlas size · 2^k = map size`.
fn lod_of(atlas: &Atlas, map: &Rgb32FImage) -> Result<u32, ExportError> {
    (0..16)
        .find(|&k| {
            atlas.width.checked_shl(k).filter(|w| w >> k == atlas.width) == Some(map.width())
                && atlas.height.checked_shl(k).filter(|h| h >> k == atlas.height) == Some(map.height())
        })
        .ok_or(ExportError::LightmapSize {
            width: map.width(),
            height: map.height(),
            atlas_width: atlas.width,
            atlas_height: atlas.height,
        })
}

/// The source must still be the file the scene came from: same materials, and every mesh
/// instance's node still instancing a mesh.
fn check_source(scene: &Scene, file: &Path, source: &crate::scene::SourceDocument) -> Result<(), ExportError> {
    let changed = |detail: String| ExportError::SourceChanged { file: file.to_path_buf(), detail };
    let count = |key: &str| source.json.get(key).and_then(|v| v.as_array()).map_or(0, Vec::len);
    // The loader appends glTF's default material once when a loaded primitive has none.
    let uses_default = source.nodes.iter().any(|&n| {
        let mesh = source.json.pointer(&format!("/nodes/{n}/mesh")).and_then(|m| m.as_u64());
        let primitives = mesh.and_then(|m| source.json.pointer(&format!("/meshes/{m}/primitives")));
        primitives.and_then(|p| p.as_array()).is_some_and(|p| p.iter().any(|p| p.get("material").is_none()))
    });
    let expected = count("materials") + usize::from(uses_default);
    if scene.materials.len() != expected {
        return Err(changed(format!("it has {expected} materials, the loaded scene {}", scene.materials.len())));
    }
    if count("images") != source.images.len() {
        return Err(changed("its images could not all be read".into()));
    }
    for mesh in &scene.meshes {
        let Some(node) = mesh.node else { continue };
        let has_mesh = source.nodes.contains(&node)
            && source.json.pointer(&format!("/nodes/{node}/mesh")).is_some_and(|m| m.is_u64());
        if !has_mesh {
            return Err(changed(format!("node {node} (mesh instance '{}') no longer instances a mesh", mesh.name)));
        }
    }
    Ok(())
}

fn encode(path: &Path, img: impl Into<image::DynamicImage>, format: ImageFormat) -> Result<Vec<u8>, ExportError> {
    let mut bytes = Cursor::new(Vec::new());
    img.into()
        .write_to(&mut bytes, format)
        .map_err(|source| ExportError::Encode { path: path.to_path_buf(), source })?;
    Ok(bytes.into_inner())
}

/// [`encode`] of a borrowed image buffer, the same bytes.
fn encode_buffer<P>(
    path: &Path,
    img: &image::ImageBuffer<P, Vec<P::Subpixel>>,
    format: ImageFormat,
) -> Result<Vec<u8>, ExportError>
where
    P: image::PixelWithColorType,
    [P::Subpixel]: image::EncodableLayout,
{
    let mut bytes = Cursor::new(Vec::new());
    img.write_to(&mut bytes, format).map_err(|source| ExportError::Encode { path: path.to_path_buf(), source })?;
    Ok(bytes.into_inner())
}

/// A sibling output file: its path and the relative URI the document uses for it.
struct Sibling {
    path: PathBuf,
    uri: String,
}

/// `dir/name.gltf` and its siblings `name.bin`, `name.lightmap.exr`, `name.lightmap.png`.
struct OutputFiles {
    dir: PathBuf,
    gltf: PathBuf,
    bin: Sibling,
    hdr: Sibling,
    png: Sibling,
}

impl OutputFiles {
    fn new(out: &Path) -> Result<Self, ExportError> {
        let bad = || ExportError::OutputName { path: out.to_path_buf() };
        let is_gltf = out.extension().is_some_and(|e| e.eq_ignore_ascii_case("gltf"));
        let stem = out.file_stem().and_then(|s| s.to_str()).filter(|s| !s.is_empty() && is_gltf).ok_or_else(bad)?;
        let dir = match out.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let sibling = |suffix: &str| {
            let name = format!("{stem}{suffix}");
            Sibling { path: dir.join(&name), uri: uri_encode(&name) }
        };
        Ok(OutputFiles {
            gltf: out.to_path_buf(),
            bin: sibling(".bin"),
            hdr: sibling(".lightmap.exr"),
            png: sibling(".lightmap.png"),
            dir,
        })
    }
}

/// Percent-encodes a file name for a relative URI (RFC 3986 unreserved characters stay).
fn uri_encode(name: &str) -> String {
    let mut out = String::with_capacity(name.len());
    for b in name.bytes() {
        if b.is_ascii_alphanumeric() || b"-._~".contains(&b) {
            out.push(b as char);
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    out
}

/// Writes every `(path, bytes)` to `path.partial` in `dir` (created if missing), then, once all
/// are complete, renames them into place in order. A failure while writing (a full disk, an
/// unwritable directory) removes the temporary files and replaces nothing; a target that is a
/// directory is refused before anything is written, which leaves renames within one directory
/// nothing ordinary to fail on.
fn write_all(dir: &Path, files: &[(&Path, &[u8])]) -> Result<(), ExportError> {
    std::fs::create_dir_all(dir).map_err(|source| ExportError::CreateDir { path: dir.to_path_buf(), source })?;
    if let Some((path, _)) = files.iter().find(|(p, _)| p.is_dir()) {
        let source = std::io::Error::other("a directory is in the way");
        return Err(ExportError::Io { path: path.to_path_buf(), source });
    }
    let temp = |p: &Path| {
        let mut t = p.as_os_str().to_owned();
        t.push(".partial");
        PathBuf::from(t)
    };
    let temps: Vec<PathBuf> = files.iter().map(|(p, _)| temp(p)).collect();
    let cleanup = || {
        for t in &temps {
            let _ = std::fs::remove_file(t);
        }
    };
    for ((path, bytes), tmp) in files.iter().zip(&temps) {
        let written = std::fs::File::create(tmp).and_then(|mut f| f.write_all(bytes).and_then(|_| f.sync_all()));
        if let Err(source) = written {
            cleanup();
            return Err(ExportError::Io { path: path.to_path_buf(), source });
        }
    }
    for ((path, _), tmp) in files.iter().zip(&temps) {
        if let Err(source) = std::fs::rename(tmp, path) {
            cleanup();
            return Err(ExportError::Io { path: path.to_path_buf(), source });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sibling_names_and_uris() {
        let f = OutputFiles::new(Path::new("out/my room.gltf")).unwrap();
        assert_eq!(f.bin.path, Path::new("out/my room.bin"));
        assert_eq!(f.bin.uri, "my%20room.bin");
        assert_eq!(f.png.uri, "my%20room.lightmap.png");
        assert_eq!(f.hdr.path, Path::new("out/my room.lightmap.exr"));
        assert_eq!(OutputFiles::new(Path::new("room.gltf")).unwrap().dir, Path::new("."));
        for bad in ["room.glb", "room", ".gltf", "dir/"] {
            assert!(matches!(OutputFiles::new(Path::new(bad)), Err(ExportError::OutputName { .. })), "{bad}");
        }
    }

    #[test]
    fn a_failed_write_leaves_no_temporary_and_replaces_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let first = dir.path().join("a.bin");
        std::fs::write(&first, b"old").unwrap();
        // The second target is a directory.
        let second = dir.path().join("b.gltf");
        std::fs::create_dir(&second).unwrap();
        std::fs::write(second.join("keep"), b"x").unwrap();
        let r = write_all(dir.path(), &[(&first, b"new"), (&second, b"{}")]);
        assert!(matches!(r, Err(ExportError::Io { .. })), "{r:?}");
        let leftovers: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().ends_with(".partial"))
            .collect();
        assert!(leftovers.is_empty(), "{leftovers:?}");
        assert_eq!(std::fs::read(&first).unwrap(), b"old");
    }
}
