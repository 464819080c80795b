//! Where the viewer's light comes from: the one place the live runtime plugs in.
//!
//! The viewer draws whatever a [`LightSource`] shows: the scene and atlas (replaced on a
//! reload, with a new generation), and the latest [`ShownLightmap`] snapshot. [`BakedLight`]
//! is a finished bake shown as a light map (baked once in the background); the live
//! runtime's source refines while the viewer runs.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use glam::Vec3;

use super::camera::Camera;
use crate::atlas::Atlas;
use crate::atlas::texels::NO_TEXEL;
use crate::bake::{BakeConfig, BakeOutput, bake};
use crate::grid::Grid;
use crate::progress::NoProgress;
use crate::runtime::shown::{LodPages, PAGE_SIDE, Page, ShownLightmap};
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

/// A new page id, unique in the process (pages are copy-on-write: a changed page is a new id).
pub fn next_page_id() -> u64 {
    static NEXT: AtomicU64 = AtomicU64::new(1);
    NEXT.fetch_add(1, Ordering::Relaxed)
}

/// A finished bake as a shown light map: every LOD's texels (and gutter copies) in pages,
/// every cell of `grid` showing the finest LOD.
pub fn shown_from_bake(baked: &BakeOutput, grid: Grid, blend_band: f32) -> ShownLightmap {
    let levels = baked
        .lods
        .iter()
        .map(|lod| {
            let t = &lod.texels;
            let mut pixels = vec![[0.0f32; 4]; (t.width * t.height) as usize];
            for (i, &p) in t.pixel.iter().enumerate() {
                pixels[p as usize] = lod.irradiance[i].extend(1.0).to_array();
            }
            for &(p, i) in &t.gutter {
                if i != NO_TEXEL {
                    pixels[p as usize] = lod.irradiance[i as usize].extend(1.0).to_array();
                }
            }
            paginate(&pixels, t.width, t.height)
        })
        .collect();
    let cell_lod = vec![(baked.lods.len() - 1) as u8; grid.cell_count()];
    ShownLightmap {
        grid,
        cell_lod,
        atlas_width: baked.atlas.width,
        atlas_height: baked.atlas.height,
        blend_band,
        levels,
    }
}

/// Cuts a row-major `width × height` image into pages; pages without a valid pixel are absent.
pub fn paginate(pixels: &[[f32; 4]], width: u32, height: u32) -> LodPages {
    let side = PAGE_SIDE;
    let (pages_x, pages_y) = (width.div_ceil(side), height.div_ceil(side));
    let mut pages = Vec::with_capacity((pages_x * pages_y) as usize);
    for py in 0..pages_y {
        for px in 0..pages_x {
            let mut texels = vec![[0.0f32; 4]; (side * side) as usize];
            let mut any = false;
            for y in 0..side {
                for x in 0..side {
                    let (gx, gy) = (px * side + x, py * side + y);
                    if gx < width && gy < height {
                        let v = pixels[(gy * width + gx) as usize];
                        any |= v[3] > 0.0;
                        texels[(y * side + x) as usize] = v;
                    }
                }
            }
            pages.push(any.then(|| Arc::new(Page { id: next_page_id(), texels })));
        }
    }
    LodPages { pages_x, pages_y, pages }
}

/// A grid of cubic cells of side `cell_size` over the scene's bounds (at least one cell).
pub fn grid_over(scene: &Scene, cell_size: f32) -> Grid {
    let (lo, hi) = scene.bounds().unwrap_or((Vec3::ZERO, Vec3::ONE));
    let extent = (hi - lo).max(Vec3::splat(1e-6));
    let dims = (extent / cell_size).ceil().max(Vec3::ONE);
    Grid { origin: lo, cell_size, dims: [dims.x as u32, dims.y as u32, dims.z as u32] }
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
                Ok(out) => {
                    let grid = grid_over(&baked_scene, cell_size);
                    BakeState::Done(Arc::new(shown_from_bake(&out, grid, 0.0)), started.elapsed().as_secs_f64())
                }
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
