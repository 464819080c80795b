//! The files outside a glTF document that loading it reads: external buffers (with the
//! `byteLength` the document declares for them) and images given by a file URI. A hot-reload
//! watcher needs this list to know which files belong to the scene and to check a `.bin`
//! against its `.gltf` before loading the pair.

use std::path::{Path, PathBuf};

use super::{LoadError, document, uri};

/// One file a glTF document refers to by a relative URI.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ExternalFile {
    /// The URI as written in the document.
    pub uri: String,
    /// Where the loader reads it: the URI percent-decoded and joined to the document's directory.
    pub path: PathBuf,
    pub kind: ExternalKind,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExternalKind {
    /// `buffers[index]`, declared `byte_length` bytes long.
    Buffer { index: usize, byte_length: u64 },
    /// `images[index]`.
    Image { index: usize },
}

/// Parses and validates the document in `bytes` (a `.gltf` or `.glb` named `path`, the base
/// for relative URIs) as [`load_gltf_bytes`](super::load_gltf_bytes) does, and lists the
/// external files it refers to, buffers first, each in document order. `data:` URIs, the GLB
/// BIN chunk, images in bufferViews and remote URIs are not files here and are left out (the
/// loader reports a remote URI). Reads no file.
pub fn external_files(path: &Path, bytes: &[u8]) -> Result<Vec<ExternalFile>, LoadError> {
    let parsed = document::parse(path, bytes)?;
    let base_dir = path.parent().unwrap_or(Path::new("."));
    let buffers = parsed.root.buffers.iter().enumerate().filter_map(|(index, buffer)| {
        let uri = buffer.uri.as_ref()?;
        let kind = ExternalKind::Buffer { index, byte_length: buffer.byte_length.0 };
        Some(ExternalFile { uri: uri.clone(), path: uri::file_path(base_dir, uri)?, kind })
    });
    let images = parsed.root.images.iter().enumerate().filter_map(|(index, image)| {
        let uri = image.uri.as_ref()?;
        Some(ExternalFile {
            uri: uri.clone(),
            path: uri::file_path(base_dir, uri)?,
            kind: ExternalKind::Image { index },
        })
    });
    Ok(buffers.chain(images).collect())
}
