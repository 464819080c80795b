//! Buffers (external files, `data:` URIs, the GLB BIN chunk) and bounds-checked bufferView
//! slices.

use std::borrow::Cow;
use std::fs::File;
use std::io::Read;
use std::path::Path;

use ::gltf::json;

use super::LoadError;
use super::uri::{self, UriSource};

/// The bytes of every buffer, each exactly `byteLength` long.
pub(super) struct Buffers<'a> {
    data: Vec<Cow<'a, [u8]>>,
}

/// Loads every buffer of the document. `bin` is the GLB BIN chunk, if any.
pub(super) fn load<'a>(file: &Path, root: &json::Root, bin: Option<&'a [u8]>) -> Result<Buffers<'a>, LoadError> {
    let base_dir = file.parent().unwrap_or(Path::new("."));
    let mut data = Vec::with_capacity(root.buffers.len());
    for (index, buffer) in root.buffers.iter().enumerate() {
        data.push(load_one(file, base_dir, index, buffer, bin)?);
    }
    Ok(Buffers { data })
}

fn load_one<'a>(
    file: &Path,
    base_dir: &Path,
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
    let source = uri::resolve(base_dir, uri_text).map_err(|e| match e {
        uri::UriError::Remote { .. } => {
            LoadError::Unsupported { file: file.into(), what: format!("buffer {index} uri '{uri_text}': {e}") }
        }
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
            let f = File::open(&path).map_err(missing)?;
            let actual = f.metadata().map_err(missing)?.len();
            if actual < expected {
                return Err(short(format!("file '{}'", path.display()), actual as usize));
            }
            // `expected` is now known to be a real file size, so the allocation is honest.
            let mut bytes = Vec::with_capacity(usize::try_from(expected).unwrap_or(0));
            f.take(expected).read_to_end(&mut bytes).map_err(missing)?;
            if (bytes.len() as u64) < expected {
                return Err(short(format!("file '{}' (shrank while reading)", path.display()), bytes.len()));
            }
            Ok(Cow::Owned(bytes))
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
