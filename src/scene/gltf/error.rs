//! [`LoadError`]: what can go wrong loading a glTF file. Every message starts with the file.

use std::path::{Path, PathBuf};

/// Why a glTF file could not be loaded. Every variant carries the file it is about (the
/// `.gltf`/`.glb` the user asked for) and its message starts with that path, then names the
/// glTF object (buffer, bufferView, accessor, mesh instance, image...) and the problem.
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    /// The glTF file itself could not be read.
    #[error("{}: cannot read the file", file.display())]
    Io {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// Neither glTF JSON nor GLB (empty, or starts with something else).
    #[error("{}: not a glTF file: {reason}", file.display())]
    NotGltf { file: PathBuf, reason: String },

    /// The JSON is malformed or truncated, or a required property is missing or has the
    /// wrong type. `line`/`column` are 1-based positions in the JSON text (of the JSON chunk
    /// for a GLB).
    #[error("{}: malformed glTF JSON at line {line}, column {column}: {message}", file.display())]
    Json { file: PathBuf, line: usize, column: usize, message: String },

    /// The GLB container (header or chunk layout) is malformed.
    #[error("{}: malformed GLB: {message}", file.display())]
    Glb { file: PathBuf, message: String },

    /// The document parses but breaks a glTF rule (validation failures, wrong accessor types,
    /// a node hierarchy that is not a tree, non-finite transforms...).
    #[error("{}: invalid glTF: {message}", file.display())]
    Invalid { file: PathBuf, message: String },

    /// An external buffer file could not be read.
    #[error("{}: buffer {buffer} ('{uri}', looked for at {}) cannot be read", file.display(), resolved.display())]
    MissingBuffer {
        file: PathBuf,
        buffer: usize,
        uri: String,
        resolved: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// A buffer or image file that the scene may not read: its URI leaves the scene's folder
    /// (`..`, an absolute path, a symbolic link out of it) without the user's opt-in, or it
    /// is not a regular file (a device, FIFO, socket, directory).
    #[error("{}: {object} ('{uri}') {reason}", file.display())]
    FileRefused { file: PathBuf, object: String, uri: String, reason: String },

    /// An image declares more pixels than one texture may have (checked from its header,
    /// before it is decoded).
    #[error(
        "{}: {image} is {width}×{height} pixels, more than the {limit} a texture may have (--max-texture-pixels)",
        file.display()
    )]
    TextureTooLarge { file: PathBuf, image: String, width: u32, height: u32, limit: u64 },

    /// Decoding an image would take the scene's textures past the memory they may hold.
    #[error(
        "{}: {image} would take the decoded textures to {need} bytes, more than the {limit} they may hold (--memory-limit)",
        file.display()
    )]
    TexturesOverMemory { file: PathBuf, image: String, need: u64, limit: u64 },

    /// A buffer has fewer bytes than its `byteLength` says.
    #[error("{}: buffer {buffer} ({origin}) has {actual} bytes but its byteLength is {expected}", file.display())]
    ShortBuffer { file: PathBuf, buffer: usize, origin: String, expected: u64, actual: u64 },

    /// A bufferView reaches past the end of its buffer.
    #[error(
        "{}: bufferView {view} (byteOffset {offset}, byteLength {length}) reaches past the end of buffer {buffer} ({buffer_length} bytes)",
        file.display()
    )]
    ViewOutOfBounds { file: PathBuf, view: usize, buffer: usize, offset: u64, length: u64, buffer_length: u64 },

    /// An accessor (or its sparse part) reads outside its bufferView, or is absurdly large.
    #[error("{}: accessor {accessor}: {detail}", file.display())]
    AccessorOutOfBounds { file: PathBuf, accessor: usize, detail: String },

    /// A vertex index refers to a vertex that does not exist.
    #[error(
        "{}: mesh instance '{mesh}': index {index} (at position {position} of the index list) is out of range: the primitive has {vertex_count} vertices",
        file.display()
    )]
    IndexOutOfRange { file: PathBuf, mesh: String, position: usize, index: u32, vertex_count: usize },

    /// A NaN or infinite value where only finite numbers make sense (positions).
    #[error("{}: mesh instance '{mesh}': {attribute} of vertex {vertex} is not finite ({value})", file.display())]
    NonFinite { file: PathBuf, mesh: String, attribute: String, vertex: usize, value: String },

    /// An image is missing, unreadable or cannot be decoded.
    #[error("{}: {image}: {reason}", file.display())]
    Image { file: PathBuf, image: String, reason: String },

    /// The file needs something livebake does not support (a required extension, glTF 1.0,
    /// remote URIs...).
    #[error("{}: unsupported: {what}", file.display())]
    Unsupported { file: PathBuf, what: String },

    /// Nothing to light-map: the scene has no triangles.
    #[error("{}: the scene has no triangles: {detail}", file.display())]
    NoTriangles { file: PathBuf, detail: String },
}

impl LoadError {
    /// The glTF file the error is about.
    pub fn file(&self) -> &Path {
        match self {
            LoadError::Io { file, .. }
            | LoadError::NotGltf { file, .. }
            | LoadError::Json { file, .. }
            | LoadError::Glb { file, .. }
            | LoadError::Invalid { file, .. }
            | LoadError::MissingBuffer { file, .. }
            | LoadError::FileRefused { file, .. }
            | LoadError::TextureTooLarge { file, .. }
            | LoadError::TexturesOverMemory { file, .. }
            | LoadError::ShortBuffer { file, .. }
            | LoadError::ViewOutOfBounds { file, .. }
            | LoadError::AccessorOutOfBounds { file, .. }
            | LoadError::IndexOutOfRange { file, .. }
            | LoadError::NonFinite { file, .. }
            | LoadError::Image { file, .. }
            | LoadError::Unsupported { file, .. }
            | LoadError::NoTriangles { file, .. } => file,
        }
    }
}
