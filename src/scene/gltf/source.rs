//! The file a scene was loaded from, read again for writers that copy parts of it (the glTF
//! exporter): its JSON as written, the encoded bytes of every image, and which nodes the
//! loaded scene is made of. The same parsing, validation, buffer and URI code as loading, so
//! the writer sees exactly the document the scene came from.

use std::path::Path;

use super::diag::Diagnostics;
use super::{Ctx, LoadError, LoadOptions, buffers, document, images, nodes};

/// What [`read_source`] gives.
#[derive(Clone, Debug)]
pub struct SourceDocument {
    /// The glTF JSON as written (the JSON chunk of a GLB), unknown extensions and extras kept.
    pub json: serde_json::Value,
    /// Every image of `images`, in order: its encoded bytes and MIME type.
    pub images: Vec<SourceImage>,
    /// Index of the scene that [`load_gltf`](super::load_gltf) loads with the same options
    /// (`None`: the file has no scenes and all root nodes were loaded).
    pub scene: Option<usize>,
    /// Root nodes of the scene that [`load_gltf`](super::load_gltf) loads with the same options.
    pub roots: Vec<usize>,
    /// Every node of that scene, parents before children (the order the loader visits them).
    pub nodes: Vec<usize>,
}

/// One image's encoded bytes (PNG, JPEG, WebP, KTX2...) and MIME type: the file's `mimeType`,
/// else recognised from the bytes.
#[derive(Clone, Debug)]
pub struct SourceImage {
    pub bytes: Vec<u8>,
    pub mime_type: String,
}

/// Reads `path` again as the loader would with `options` (the file must still be valid glTF
/// that livebake loads); image bytes are read but not decoded.
pub fn read_source(path: &Path, options: &LoadOptions) -> Result<SourceDocument, LoadError> {
    let bytes = super::read_scene_file(path)?;
    let parsed = document::parse(path, &bytes)?;
    let json: serde_json::Value = serde_json::from_slice(parsed.json_text).map_err(|e| LoadError::Json {
        file: path.to_path_buf(),
        line: e.line(),
        column: e.column(),
        message: e.to_string(),
    })?;
    let scope = super::file_scope(path, options);
    let buffers = buffers::load(path, &parsed.root, parsed.bin, &scope)?;
    let ctx = Ctx { file: path, root: &parsed.root, buffers, scope, options };
    let roots = nodes::scene_roots(&ctx, options)?;
    let nodes = nodes::traverse(&ctx, &roots, &mut Diagnostics::default())?.into_iter().map(|n| n.node).collect();
    let mut out_images = Vec::with_capacity(parsed.root.images.len());
    for (index, image) in parsed.root.images.iter().enumerate() {
        let bytes = images::encoded_bytes(&ctx, index)?;
        let declared = image.mime_type.as_ref().map(|m| m.0.clone());
        let mime_type =
            declared.or_else(|| sniff_mime_type(&bytes).map(str::to_string)).ok_or_else(|| LoadError::Image {
                file: path.to_path_buf(),
                image: format!("image {index}"),
                reason: "has no mimeType and its bytes are not PNG, JPEG, WebP or KTX2".into(),
            })?;
        out_images.push(SourceImage { bytes, mime_type });
    }
    let scene = nodes::chosen_scene(&parsed.root, options);
    Ok(SourceDocument { json, images: out_images, scene, roots, nodes })
}

/// The MIME type of encoded image bytes, from their magic number.
fn sniff_mime_type(bytes: &[u8]) -> Option<&'static str> {
    const KTX2: &[u8] = b"\xABKTX 20\xBB\r\n\x1A\n";
    if bytes.starts_with(b"\x89PNG\r\n\x1A\n") {
        Some("image/png")
    } else if bytes.starts_with(b"\xFF\xD8\xFF") {
        Some("image/jpeg")
    } else if bytes.len() >= 12 && &bytes[..4] == b"RIFF" && &bytes[8..12] == b"WEBP" {
        Some("image/webp")
    } else if bytes.starts_with(KTX2) {
        Some("image/ktx2")
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mime_types_come_from_magic_numbers() {
        assert_eq!(sniff_mime_type(b"\x89PNG\r\n\x1A\n...."), Some("image/png"));
        assert_eq!(sniff_mime_type(b"\xFF\xD8\xFF\xE0"), Some("image/jpeg"));
        assert_eq!(sniff_mime_type(b"RIFF\0\0\0\0WEBPVP8 "), Some("image/webp"));
        assert_eq!(sniff_mime_type(b"\xABKTX 20\xBB\r\n\x1A\n"), Some("image/ktx2"));
        assert_eq!(sniff_mime_type(b"GIF89a"), None);
        assert_eq!(sniff_mime_type(b""), None);
    }
}
