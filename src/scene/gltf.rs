//! glTF 2.0 import (.gltf and .glb) with typed, file-naming errors.

use std::path::{Path, PathBuf};

use super::Scene;

#[derive(Clone, Debug, Default)]
pub struct LoadOptions {}

#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
}

pub fn load_gltf(path: &Path, options: &LoadOptions) -> Result<Scene, LoadError> {
    let _ = options;
    Err(LoadError::Invalid { path: path.to_path_buf(), message: "not implemented".into() })
}
