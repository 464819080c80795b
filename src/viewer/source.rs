//! Where the viewer's light comes from: the one place the live runtime plugs in.
//!
//! The viewer draws whatever a [`LightSource`] shows: the scene and atlas (replaced on a
//! reload, with a new generation), and the latest [`ShownLightmap`] snapshot. [`BakedLight`]
//! is a finished bake shown as a light map (baked once in the background); the live
//! runtime's source refines while the viewer runs.

use std::sync::{Arc, Mutex};
use std::time::Instant;

use super::camera::Camera;
use crate::atlas::Atlas;
use crate::atlas::texels::NO_TEXEL;
use crate::bake::{BakeConfig, BakeOutput, bake};
use crate::grid::{Grid, GridError};
use crate::progress::NoProgress;
use crate::runtime::shown::{PageWriter, ShownLightmap};
use crate::scene::{Scene, SceneGeometry};

/// The scene a source lights and its atlas; `generation` changes when either is replaced.
#[derive(Clone)]
pub struct SceneState {
    pub generation: u64,
    pub scene: Arc<Scene>,
    pub atlas: Arc<Atlas>,
}

/// What the viewer's title shows about the source.
#[derive(Clone, Debug, Default)]
pub struct SourceStatus {
    /// Work waiting (cells queued for baking), when the source has a queue.
    pub queued: Option<usize>,
    /// Milliseconds the last reload took.
    pub last_reload_ms: Option<f64>,
    pub last_error: Option<String>,
    /// A short state word ("baking", "refining", "done").
    pub state: String,
}

pub trait LightSource {
    fn scene(&self) -> SceneState;
    /// The light map to show; `None` before the first light.
    fn shown(&self) -> Option<Arc<ShownLightmap>>;
    /// Where the viewer looks (a runtime refines what is seen first).
    fn set_camera(&mut self, camera: &Camera, aspect: f32, height_px: u32);
    fn status(&self) -> SourceStatus;
    /// Stops background work; called once when the viewer closes.
    fn shutdown(&mut self);
}

/// A finished bake as a shown light map: every LOD's texels (and the gutter pixels copying
/// them) published, every cell of `grid` showing the finest LOD.
pub fn shown_from_bake(baked: &BakeOutput, grid: Grid, blend_band: f32) -> ShownLightmap {
    let (w, h) = (baked.atlas.width, baked.atlas.height);
    let mut shown = ShownLightmap::new(grid, w, h, baked.lods.len() as u32, blend_band);
    let mut writer = PageWriter::new(&mut shown);
    for (k, lod) in baked.lods.iter().enumerate() {
        let t = &lod.texels;
        let pixel = |p: u32| (p % t.width, p / t.width);
        for (i, &p) in t.pixel.iter().enumerate() {
            let (x, y) = pixel(p);
            writer.write(k as u32, x, y, lod.irradiance[i]);
        }
        for &(p, i) in &t.gutter {
            if i != NO_TEXEL {
                let (x, y) = pixel(p);
                writer.write(k as u32, x, y, lod.irradiance[i as usize]);
            }
        }
    }
    let top = baked.lods.len().saturating_sub(1) as u32;
    for cell in 0..grid.len() as u32 {
        writer.set_cell_lod(cell, top);
    }
    writer.finish();
    shown
}

/// A grid of cubic cells of side `cell_size` over the scene's bounds.
pub fn grid_over(scene: &Scene, cell_size: f32) -> Result<Grid, GridError> {
    let (lo, hi) = scene.bounds().ok_or(GridError::BadBounds)?;
    Grid::covering(lo, hi, cell_size)
}

enum BakeState {
    Baking,
    Done(Arc<ShownLightmap>, f64),
    Failed(String),
}

/// A scene baked once (in a background thread, so the window opens at once) and shown.
pub struct BakedLight {
    state: SceneState,
    result: Arc<Mutex<BakeState>>,
}

impl BakedLight {
    /// Starts baking `scene` with `config`; its atlas is built first (synchronously: the
    /// viewer needs it to draw). `cell_size` sets the display grid.
    pub fn start(scene: Arc<Scene>, config: BakeConfig, cell_size: f32) -> Result<BakedLight, crate::bake::BakeError> {
        let geom = SceneGeometry::new(&scene);
        let atlas = Arc::new(Atlas::build(&scene, &geom, &config.atlas)?);
        let result = Arc::new(Mutex::new(BakeState::Baking));
        let (sink, baked_scene) = (result.clone(), scene.clone());
        std::thread::spawn(move || {
            let started = Instant::now();
            let state = match bake(&baked_scene, &config, &NoProgress) {
                Ok(out) => match grid_over(&baked_scene, cell_size) {
                    Ok(grid) => {
                        BakeState::Done(Arc::new(shown_from_bake(&out, grid, 0.0)), started.elapsed().as_secs_f64())
                    }
                    Err(e) => BakeState::Failed(e.to_string()),
                },
                Err(e) => BakeState::Failed(e.to_string()),
            };
            if let Ok(mut s) = sink.lock() {
                *s = state;
            }
        });
        Ok(BakedLight { state: SceneState { generation: 0, scene, atlas }, result })
    }
}

impl LightSource for BakedLight {
    fn scene(&self) -> SceneState {
        self.state.clone()
    }

    fn shown(&self) -> Option<Arc<ShownLightmap>> {
        match &*self.result.lock().ok()? {
            BakeState::Done(shown, _) => Some(shown.clone()),
            _ => None,
        }
    }

    fn set_camera(&mut self, _camera: &Camera, _aspect: f32, _height_px: u32) {}

    fn status(&self) -> SourceStatus {
        let (state, last_error) = match self.result.lock().as_deref() {
            Ok(BakeState::Baking) => ("baking".to_string(), None),
            Ok(BakeState::Done(_, s)) => (format!("baked in {s:.1} s"), None),
            Ok(BakeState::Failed(e)) => ("bake failed".to_string(), Some(e.clone())),
            Err(_) => ("bake failed".to_string(), Some("bake thread panicked".to_string())),
        };
        SourceStatus { queued: None, last_reload_ms: None, last_error, state }
    }

    fn shutdown(&mut self) {}
}
