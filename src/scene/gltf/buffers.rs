//! Buffers (external files, `data:` URIs, the GLB BIN chunk) and bounds-checked bufferView
//! slices.

use std::borrow::Cow;
use std::path::Path;

use ::gltf::json;

use super::LoadError;
use super::files::{FileError, FileScope, read_regular};
use super::uri::{self, UriSource};

/// The bytes of every buffer, each exactly `byteLength` long.
pub(super) struct Buffers<'a> {
    data: Vec<Cow<'a, [u8]>>,
}

/// Loads every buffer of the document. `bin` is the GLB BIN chunk, if any; `scope`: where
/// buffer files may be.
pub(super) fn load<'a>(
    file: &Path,
    root: &json::Root,
    bin: Option<&'a [u8]>,
    scope: &FileScope,
) -> Result<Buffers<'a>, LoadError> {
    let base_dir = file.parent().unwrap_or(Path::new("."));
    let mut data = Vec::with_capacity(root.buffers.len());
    for (index, buffer) in root.buffers.iter().enumerate() {
        data.push(load_one(file, base_dir, scope, index, buffer, bin)?);
    }
    Ok(Buffers { data })
}

fn load_one<'a>(
    file: &Path,
    base_dir: &Path,
    scope: &FileScope,
    index: usize,
    buffer: &json::Buffer,
    bin: Option<&'a [u8]>,
) -> Result<Cow<'a, [u8]>, LoadError> {
    let expected = buffer.byte_length.0;
    let short = |origin: String, actual: usize| LoadError::ShortBuffer {
        file: file.into(),
        buffer: index,
        origin,
        expected,
        actual: actual as u64,
    };
    let Some(uri_text) = &buffer.uri else {
        // Only the first buffer of a GLB may leave out the uri: it is the BIN chunk.
        let bin = match (index, bin) {
            (0, Some(bin)) => bin,
            _ => {
                return Err(LoadError::Invalid {
                    file: file.into(),
                    message: format!(
                        "buffer {index} has no uri and is not the BIN chunk of a GLB (only buffer 0 of a .glb may omit it)"
                    ),
                });
            }
        };
        let bytes = prefix(bin, expected).ok_or_else(|| short("the GLB BIN chunk".into(), bin.len()))?;
        return Ok(Cow::Borrowed(bytes));
    };
    let refused = |reason: String| LoadError::FileRefused {
        file: file.into(),
        object: format!("buffer {index}"),
        uri: uri_text.clone(),
        reason,
    };
    let source = uri::resolve(base_dir, uri_text, scope).map_err(|e| match e {
        uri::UriError::Remote { .. } => {
            LoadError::Unsupported { file: file.into(), what: format!("buffer {index} uri '{uri_text}': {e}") }
        }
        uri::UriError::Refused(r) => refused(r.to_string()),
        _ => LoadError::Invalid { file: file.into(), message: format!("buffer {index}: {e}") },
    })?;
    match source {
        UriSource::Data { bytes, .. } => {
            let actual = bytes.len();
            let mut bytes = bytes;
            if (actual as u64) < expected {
                return Err(short("its data: URI".into(), actual));
            }
            bytes.truncate(expected as usize);
            Ok(Cow::Owned(bytes))
        }
        UriSource::File(path) => {
            let missing = |source| LoadError::MissingBuffer {
                file: file.into(),
                buffer: index,
                uri: uri_text.clone(),
                resolved: path.clone(),
                source,
            };
            // A longer file is fine (its first byteLength bytes are the buffer); the length
            // is known to be the file's real size before anything is allocated.
            match read_regular(&path, Some(scope), expected, u64::MAX, Some(expected)) {
                Ok(bytes) => Ok(Cow::Owned(bytes)),
                Err(FileError::Io(source)) => Err(missing(source)),
                Err(FileError::TooShort { len, .. }) => Err(short(format!("file '{}'", path.display()), len as usize)),
                Err(e) => Err(refused(e.to_string())),
            }
        }
    }
}

/// The first `len` bytes of `bytes`, if it has that many.
fn prefix(bytes: &[u8], len: u64) -> Option<&[u8]> {
    bytes.get(..usize::try_from(len).ok()?)
}

impl Buffers<'_> {
    /// The bytes of bufferView `view`, checked against its buffer.
    pub(super) fn view(&self, file: &Path, root: &json::Root, view: usize) -> Result<&[u8], LoadError> {
        let v = root.buffer_views.get(view).ok_or_else(|| LoadError::Invalid {
            file: file.into(),
            message: format!("bufferView {view} does not exist ({} bufferViews)", root.buffer_views.len()),
        })?;
        let buffer = v.buffer.value();
        let data = self.data.get(buffer).ok_or_else(|| LoadError::Invalid {
            file: file.into(),
            message: format!("bufferView {view} refers to buffer {buffer}, which does not exist"),
        })?;
        let offset = v.byte_offset.map_or(0, |o| o.0);
        let length = v.byte_length.0;
        let out_of_bounds = || LoadError::ViewOutOfBounds {
            file: file.into(),
            view,
            buffer,
            offset,
            length,
            buffer_length: data.len() as u64,
        };
        let start = usize::try_from(offset).map_err(|_| out_of_bounds())?;
        let len = usize::try_from(length).map_err(|_| out_of_bounds())?;
        let end = start.checked_add(len).ok_or_else(out_of_bounds)?;
        data.get(start..end).ok_or_else(out_of_bounds)
    }

    /// The `byteStride` of bufferView `view`, if it has one.
    pub(super) fn stride(root: &json::Root, view: usize) -> Option<usize> {
        root.buffer_views.get(view).and_then(|v| v.byte_stride).map(|s| s.0)
    }
}
