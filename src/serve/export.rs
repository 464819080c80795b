//! `--export-web DIR` (`bake`, `run`): the page and the socket's messages as files, so that
//! a static file server (or a headset's browser on one) shows the light map as it was:
//! `DIR/index.html?static` reads `scene.json`, `geometry.bin`, `texture-N.bin`, `sky.bin`
//! (unless the sky is black) and `lightmap.bin` (one full update) instead of a socket.

use std::path::{Path, PathBuf};

use glam::Vec3;

use super::http::PAGE_FILES;
use super::protocol::{changed_cells, encode_update};
use super::scene::{scene_messages, start_pose};
use crate::atlas::Atlas;
use crate::runtime::shown::ShownLightmap;
use crate::scene::Scene;

#[derive(Debug, thiserror::Error)]
pub enum ExportWebError {
    #[error("cannot write {path}: {source}")]
    Write { path: PathBuf, source: std::io::Error },
}

/// Writes the page and the scene lit by `shown` into `dir` (created if missing); returns the
/// files written. `exposure`: `None` for `view`'s automatic one; `pose`: the start pose
/// (`None`: `view`'s).
pub fn export_web(
    dir: &Path,
    scene: &Scene,
    atlas: &Atlas,
    shown: &ShownLightmap,
    exposure: Option<f32>,
    pose: Option<(Vec3, Vec3)>,
) -> Result<Vec<PathBuf>, ExportWebError> {
    let write = |name: &str, bytes: &[u8]| {
        let path = dir.join(name);
        std::fs::write(&path, bytes).map_err(|source| ExportWebError::Write { path: path.clone(), source })?;
        Ok::<PathBuf, ExportWebError>(path)
    };
    std::fs::create_dir_all(dir).map_err(|source| ExportWebError::Write { path: dir.to_path_buf(), source })?;
    let exposure = exposure.unwrap_or_else(|| crate::viewer::render::auto_exposure(shown));
    let msgs = scene_messages(scene, atlas, shown, 1, exposure, start_pose(scene, pose));
    let mut files = Vec::new();
    for (path, _, body) in PAGE_FILES.iter().filter(|(p, _, _)| *p != "/") {
        files.push(write(path.trim_start_matches('/'), body)?);
    }
    let json = serde_json::to_vec(&msgs.description).unwrap_or_default();
    files.push(write("scene.json", &json)?);
    files.push(write("geometry.bin", &msgs.geometry)?);
    for (i, t) in msgs.textures.iter().enumerate() {
        files.push(write(&format!("texture-{i}.bin"), t)?);
    }
    if let Some(sky) = &msgs.sky {
        files.push(write("sky.bin", sky)?);
    }
    let update = encode_update(0, 1, 0.0, true, &changed_cells(shown, None), &shown.changed_pages(None));
    files.push(write("lightmap.bin", &update)?);
    Ok(files)
}
