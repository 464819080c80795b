//! The files outside a glTF document that loading it reads: external buffers (with the
//! `byteLength` the document declares for them) and images given by a file URI. A hot-reload
//! watcher needs this list to know which files belong to the scene and to check a `.bin`
//! against its `.gltf` before loading the pair.

use std::path::{Path, PathBuf};

use super::{LoadError, LoadOptions, document, file_scope, uri};

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
/// loader reports a remote URI). A file the loader would refuse to read under `options`
/// (outside the scene's folder) is an error here too, so that nothing outside is watched.
/// Reads no file (but follows symbolic links to see where they lead).
pub fn external_files(path: &Path, bytes: &[u8], options: &LoadOptions) -> Result<Vec<ExternalFile>, LoadError> {
    let parsed = document::parse(path, bytes)?;
    let base_dir = path.parent().unwrap_or(Path::new("."));
    let scope = file_scope(path, options);
    let refused = |object: String, uri: &str, reason: String| LoadError::FileRefused {
        file: path.to_path_buf(),
        object,
        uri: uri.to_string(),
        reason,
    };
    let mut out = Vec::new();
    let buffers = parsed.root.buffers.iter().enumerate().filter_map(|(index, b)| {
        let kind = ExternalKind::Buffer { index, byte_length: b.byte_length.0 };
        b.uri.as_ref().map(|u| (format!("buffer {index}"), u, kind))
    });
    let images = parsed.root.images.iter().enumerate().filter_map(|(index, image)| {
        image.uri.as_ref().map(|u| (format!("image {index}"), u, ExternalKind::Image { index }))
    });
    for (object, uri, kind) in buffers.chain(images) {
        match uri::file_path(base_dir, uri, &scope) {
            Ok(Some(path)) => out.push(ExternalFile { uri: uri.clone(), path, kind }),
            Ok(None) => {}
            Err(r) => return Err(refused(object, uri, r.to_string())),
        }
    }
    Ok(out)
}
