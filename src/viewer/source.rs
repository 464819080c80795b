//! Where the viewer's light comes from: the one place the live runtime plugs in.
//!
//! The viewer draws whatever a [`LightSource`] shows: the scene and atlas (replaced on a
//! reload, with a new generation), and the latest [`ShownLightmap`] snapshot.
//! [`RuntimeLight`] is the live runtime; [`shown_from_bake`] shows a finished bake.

use std::sync::Arc;

use glam::Vec3;

use super::camera::Camera;
use crate::atlas::Atlas;
use crate::atlas::texels::NO_TEXEL;
use crate::bake::BakeOutput;
use crate::grid::{Grid, GridError};
use crate::runtime::shown::{Layer, PageWriter, ShownLightmap};
use crate::runtime::{CameraView, Runtime, RuntimeEvent, TimedEvent};
use crate::scene::{Scene, SunPlacement, SurroundingsSpec};

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
    /// Where the sun is, when it can be moved.
    pub sun: Option<String>,
}

pub trait LightSource {
    fn scene(&self) -> SceneState;
    /// The light map to show; `None` before the first light.
    fn shown(&self) -> Option<Arc<ShownLightmap>>;
    /// Where the viewer looks (a runtime refines what is seen first).
    fn set_camera(&mut self, camera: &Camera, aspect: f32, height_px: u32);
    /// The most pages the viewer's GPU holds: a runtime keeps the shown map within it.
    fn set_page_limit(&mut self, _pages: u64) {}
    fn status(&self) -> SourceStatus;
    /// Takes the source's news (events); called once a frame.
    fn poll(&mut self) {}
    /// Moves the sun by key steps (see [`SunPlacement::moved`]), when the source has one to
    /// move.
    fn move_sun(&mut self, _steps: i32, _elevation_steps: i32) {}
    /// Stops background work; called once when the viewer closes. An error is what went
    /// wrong in the background (a worker that panicked).
    fn shutdown(&mut self) -> Result<(), String>;
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
            writer.write(Layer::Bundles, k as u32, x, y, lod.irradiance[i]);
        }
        for &(p, i) in &t.gutter {
            if i != NO_TEXEL {
                let (x, y) = pixel(p);
                writer.write(Layer::Bundles, k as u32, x, y, lod.irradiance[i as usize]);
            }
        }
    }
    let top = baked.lods.len().saturating_sub(1) as u32;
    for cell in 0..grid.len() as u32 {
        writer.set_cell_lod(Layer::Bundles, cell, top);
    }
    writer.finish();
    shown
}

/// A grid of cubic cells of side `cell_size` over the scene's bounds.
pub fn grid_over(scene: &Scene, cell_size: f32) -> Result<Grid, GridError> {
    let (lo, hi) = scene.bounds().ok_or(GridError::BadBounds)?;
    Grid::covering(lo, hi, cell_size)
}

/// The live runtime as the viewer's light: LOD 0 at first light, then the cells the
/// camera sees refined in the background and swapped in as they converge. With hot reload
/// ([`Runtime::watch`]) the scene is replaced when the runtime serves a new one, and the
/// status reports the last reload's time and the last error.
pub struct RuntimeLight {
    runtime: Option<Runtime>,
    state: SceneState,
    /// The runtime stopped working (it shows no new light).
    failed: Option<String>,
    /// The last hot reload that failed, until one succeeds.
    reload_error: Option<String>,
    last_reload_ms: Option<f64>,
    reloads: u64,
    /// How the scene's surroundings are made, when its sun can be moved.
    sun: Option<SurroundingsSpec>,
}

impl RuntimeLight {
    pub fn new(runtime: Runtime) -> RuntimeLight {
        let world = runtime.world();
        let state = SceneState { generation: 0, scene: world.scene.clone(), atlas: world.atlas.clone() };
        RuntimeLight {
            runtime: Some(runtime),
            state,
            failed: None,
            reload_error: None,
            last_reload_ms: None,
            reloads: 0,
            sun: None,
        }
    }

    /// Lets the viewer move the sun of `spec` (the surroundings the scene was lit with).
    pub fn with_sun(mut self, spec: SurroundingsSpec) -> RuntimeLight {
        self.sun = spec.movable().then_some(spec);
        self
    }

    /// Hot reloads applied so far.
    pub fn reloads(&self) -> u64 {
        self.reloads
    }

    /// Takes the runtime's world when it is not the one shown (a reload replaced it).
    fn follow_world(&mut self) {
        let Some(runtime) = &self.runtime else { return };
        let world = runtime.world();
        if !(Arc::ptr_eq(&world.scene, &self.state.scene) && Arc::ptr_eq(&world.atlas, &self.state.atlas)) {
            self.state = SceneState {
                generation: self.state.generation + 1,
                scene: world.scene.clone(),
                atlas: world.atlas.clone(),
            };
        }
    }
}

impl LightSource for RuntimeLight {
    fn scene(&self) -> SceneState {
        self.state.clone()
    }

    fn shown(&self) -> Option<Arc<ShownLightmap>> {
        let runtime = self.runtime.as_ref()?;
        runtime.has_first_light().then(|| runtime.shown())
    }

    fn set_page_limit(&mut self, pages: u64) {
        if let Some(runtime) = &self.runtime {
            runtime.set_page_limit(Some(pages));
        }
    }

    fn set_camera(&mut self, camera: &Camera, aspect: f32, height_px: u32) {
        if let Some(runtime) = &self.runtime {
            runtime.set_camera(CameraView {
                eye: camera.eye,
                target: camera.look_target(),
                up: Vec3::Y,
                yfov: camera.yfov,
                aspect,
                height_px,
            });
        }
    }

    fn poll(&mut self) {
        let Some(runtime) = &self.runtime else { return };
        let mut reloaded = false;
        while let Ok(TimedEvent { event, .. }) = runtime.events().try_recv() {
            match event {
                RuntimeEvent::Failed { error } => self.failed = Some(error),
                RuntimeEvent::ReloadApplied { changed_meshes, invalidated_cells, ms, .. } => {
                    tracing::info!(
                        "reloaded: {changed_meshes} meshes changed, {invalidated_cells} cells re-baked, {ms:.0} ms"
                    );
                    self.last_reload_ms = Some(ms);
                    self.reload_error = None;
                    self.reloads += 1;
                    reloaded = true;
                }
                // (The watcher has logged it.)
                RuntimeEvent::ReloadFailed { error, .. } => self.reload_error = Some(format!("reload failed: {error}")),
                _ => {}
            }
        }
        if reloaded {
            self.follow_world();
        }
    }

    fn status(&self) -> SourceStatus {
        let Some(runtime) = &self.runtime else { return SourceStatus::default() };
        let stats = runtime.stats();
        let state = if runtime.has_first_light() {
            format!("refining, {:.1} M texel-samples/s", stats.texel_samples_per_second / 1e6)
        } else {
            "first light...".to_string()
        };
        SourceStatus {
            queued: Some(stats.queue),
            last_reload_ms: self.last_reload_ms,
            last_error: self.failed.clone().or_else(|| self.reload_error.clone()),
            state,
            sun: self.sun.as_ref().and_then(|s| s.sun.map(|p| p.describe())),
        }
    }

    fn move_sun(&mut self, steps: i32, elevation_steps: i32) {
        let (Some(runtime), Some(spec)) = (&self.runtime, &mut self.sun) else { return };
        spec.sun = spec.sun.map(|p: SunPlacement| p.moved(steps, elevation_steps));
        match spec.build() {
            Ok(surroundings) => runtime.set_surroundings(surroundings),
            Err(e) => self.reload_error = Some(e),
        }
    }

    fn shutdown(&mut self) -> Result<(), String> {
        match self.runtime.take() {
            Some(runtime) => runtime.shutdown().map_err(|e| e.to_string()),
            None => Ok(()),
        }
    }
}
