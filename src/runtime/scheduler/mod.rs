//! The runtime's shared state and its threads: first light, the workers that refine cells
//! (most urgent first, within the memory budget), publishing, eviction and the stats clock.
//!
//! Everything a decision reads is in one mutex ([`State`]: the world, the cell table, the
//! camera, memory accounting), held only to decide and to publish, never while tracing.
//! The shown light map is a separate snapshot pointer, swapped whole by each publish.
//!
//! Here: the state, the camera's views and targets, the stats clock. Beside it:
//! [`first_light`](mod@first_light) (LOD 0 of the whole scene), [`pick`] (choosing work),
//! [`worker`](mod@worker) (the worker loop), [`publish`] (the swap rule and publishing),
//! [`punctual_jobs`] and [`budget`] (memory accounting and eviction).

mod budget;
mod first_light;
mod pick;
mod publish;
mod punctual_jobs;
mod worker;

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, RwLock};
use std::time::{Duration, Instant};

use crossbeam_channel::Sender;

use super::cell_bake::CellBake;
use super::memory::{derived_budget, fixed_bytes};
use super::policy::{CameraView, CellView, LayerLight, cell_view, target_lod};
use super::shown::{Layer, ShownLightmap};
use super::world::World;
use super::{RuntimeConfig, RuntimeEvent, RuntimeStats, TimedEvent};
use crate::bundle::{BackendError, BundleBackend, BundleScene};
use crate::grid::CellId;

pub use first_light::{bake_first_light, empty_shown};
pub(super) use first_light::{bake_first_light_observed, first_light};
pub(super) use pick::next_lod;
pub use publish::publish_bake;
use punctual_jobs::punctual_work;
pub(super) use worker::worker;

/// Makes a bundle backend for a scene with a number of threads: the runtime's one handle on
/// its [`BackendProvider`](crate::bundle::BackendProvider), type-erased so that any thread
/// (workers, hot reload) can make one for the current world.
pub type MakeBackend =
    Arc<dyn Fn(&Arc<BundleScene>, usize) -> Result<Box<dyn BundleBackend>, BackendError> + Send + Sync>;

/// Per cell, in the state mutex.
#[derive(Default)]
pub(super) struct CellState {
    pub shown: u32,
    pub target: u32,
    pub view: Option<CellView>,
    /// A bake in progress, parked here between units: this cell's own, or its group's when
    /// this cell leads it.
    pub bake: Option<Box<CellBake>>,
    /// The leader of the group bake this cell is part of, when another cell leads it.
    pub member_of: Option<CellId>,
    /// A worker is tracing a unit of this cell's bake (or its group's).
    pub busy: bool,
    /// Directions traced by the bake in progress (also while a worker holds it).
    pub baking_directions: u64,
    /// Its light is older than the scene (hot reload): refresh it when nothing is more urgent.
    pub stale: bool,
    /// Its LOD 0 is a hot reload's quick re-bake (fewer directions than first light): re-bake
    /// LOD 0 with first light's directions before anything else.
    pub provisional: bool,
    /// Its shown level was published early (see [`publish_due`](publish::publish_due)): the
    /// bake that published it has not met the error bound nor `max_directions` yet and goes
    /// on at that LOD (parked as between any two units), republished as its directions
    /// double, before the cell moves on to a finer one. Only ever the finest shown level: a
    /// cell swaps to the next LOD only from a settled one.
    pub unsettled: bool,
    /// Directions and error of each shown level (index = LOD).
    pub history: Vec<(u64, f32)>,
    /// Pixels written at each LOD of the bundle layer (index = LOD), to withdraw or replace
    /// them.
    pub published: Vec<Vec<[u32; 2]>>,
    /// The cell's punctual layer (scenes with punctual lights).
    pub punctual: PunctualState,
    /// The light each layer shows at each LOD (indexed by [`Layer`], then LOD), as last
    /// published: what refining it is worth ([`urgency`](super::policy::urgency)).
    pub lights: [Vec<LayerLight>; 2],
}

impl CellState {
    /// The light `layer` showed at `lod` when last published there (none: dark, flat).
    pub fn light(&self, layer: Layer, lod: u32) -> LayerLight {
        self.lights[layer as usize].get(lod as usize).copied().unwrap_or_default()
    }

    /// Notes the light `layer` shows at `lod` (see [`ShownLightmap::layer_light`]).
    pub fn set_light(&mut self, layer: Layer, lod: u32, light: LayerLight) {
        let lights = &mut self.lights[layer as usize];
        if lights.len() <= lod as usize {
            lights.resize(lod as usize + 1, LayerLight::default());
        }
        lights[lod as usize] = light;
    }
}

/// A cell's punctual layer ([`super::punctual`]): LOD 0 comes with first light; each bake
/// then makes the next finer LOD, up to the cell's target, as long as that is worth its
/// work beside everything else to do ([`urgency`](super::policy::urgency)).
#[derive(Default)]
pub(super) struct PunctualState {
    /// The LOD shown.
    pub shown: u32,
    /// The LOD wanted: the cell's target.
    pub target: u32,
    /// Pixels written at each LOD (index = LOD; empty where skipped).
    pub published: Vec<Vec<[u32; 2]>>,
    /// A worker is baking it.
    pub busy: bool,
    /// A hot reload changed the scene after it was baked: re-bake LOD 0 and the two
    /// finest levels shown (the others are withdrawn), whatever the LOD.
    pub stale: bool,
}

impl PunctualState {
    /// The LODs its next bake makes (ascending), if it has one to make: the next finer LOD
    /// when the target is finer than shown; when stale, LOD 0 and the two finest shown.
    pub fn next_levels(&self) -> Option<Vec<u32>> {
        if self.busy {
            return None;
        }
        if self.stale {
            let mut levels = vec![0, self.shown.saturating_sub(1), self.shown];
            levels.dedup();
            return Some(levels);
        }
        (self.target > self.shown).then(|| vec![self.shown + 1])
    }
}

pub(super) struct State {
    pub world: Arc<World>,
    /// Incremented by every hot reload: bakes made for an older world are dropped.
    pub generation: u64,
    pub cells: Vec<CellState>,
    /// The camera the views and targets were computed for, and its version in
    /// [`Shared::camera`].
    pub camera: Option<CameraView>,
    pub camera_version: u64,
    pub paused: bool,
    /// A hot reload is re-baking LOD 0 of the cells it invalidated: workers wait.
    pub relighting: bool,
    /// Provisional cells still to re-bake at full quality, since the last reload.
    pub refining: Option<Refining>,
    /// LOD 0 is shown (first light) ...
    pub first_light: bool,
    /// ... and has all its directions: refinement may start.
    pub lod0_done: bool,
    /// Punctual jobs taken in a row while bundle work was waiting ([`pick`](pick::pick)).
    pub punctual_streak: u32,
    /// Directions of the LOD 0 shown.
    pub lod0_directions: u64,
    pub failed: Option<String>,
    /// The memory budget in force: the given one, or derived from the scene and the view
    /// (recomputed when the camera changes, [`update_views`]).
    pub budget: u64,
    /// Most pages the shown map may hold (see [`RuntimeConfig::page_limit`]).
    pub page_limit: Option<u64>,
    pub bake_bytes: u64,
    /// Texel-samples traced since the last stats event.
    pub window_samples: u64,
    pub stats: RuntimeStats,
}

impl State {
    pub fn new(world: Arc<World>, paused: bool, budget: u64, page_limit: Option<u64>) -> State {
        State {
            budget,
            page_limit,
            cells: (0..world.grid.len()).map(|_| CellState::default()).collect(),
            world,
            generation: 0,
            camera: None,
            camera_version: 0,
            paused,
            relighting: false,
            refining: None,
            first_light: false,
            lod0_done: false,
            punctual_streak: 0,
            lod0_directions: 0,
            failed: None,
            bake_bytes: 0,
            window_samples: 0,
            stats: RuntimeStats::default(),
        }
    }
}

/// A hot reload that published cells provisionally (see [`CellState::provisional`]):
/// `left` counts the provisional cells (this reload's and any an earlier one left);
/// `reload_refined` is sent when none is.
pub(super) struct Refining {
    pub seen_at: Instant,
    pub left: usize,
}

pub(super) struct Shared {
    pub config: RuntimeConfig,
    pub state: Mutex<State>,
    pub wake: Condvar,
    pub shown: RwLock<Arc<ShownLightmap>>,
    pub events: Sender<TimedEvent>,
    /// Held while an event is stamped and sent.
    pub emitting: Mutex<()>,
    pub dropped: AtomicU64,
    pub shutdown: AtomicBool,
    pub started: Instant,
    pub make_backend: MakeBackend,
    /// The camera the front end set last, with a version counting the sets: a front end
    /// sets it without waiting for the state mutex (which a publish holds while it writes a
    /// cell's pages, milliseconds for a large one); whoever next holds the state applies it
    /// ([`sync_camera`]).
    pub camera: Mutex<(u64, Option<CameraView>)>,
}

impl Shared {
    pub fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Sends an event stamped with the time since start. Stamping and sending happen under
    /// one lock, so events arrive in the order of their times whichever thread sends them.
    pub fn emit(&self, event: RuntimeEvent) {
        let _order = self.emitting.lock().unwrap_or_else(|e| e.into_inner());
        let e = TimedEvent { t: self.started.elapsed().as_secs_f64(), event };
        if self.events.try_send(e).is_err() {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    pub fn shown(&self) -> Arc<ShownLightmap> {
        self.shown.read().unwrap_or_else(|e| e.into_inner()).clone()
    }

    pub fn set_shown(&self, map: ShownLightmap) {
        let map = Arc::new(map);
        let old = std::mem::replace(&mut *self.shown.write().unwrap_or_else(|e| e.into_inner()), map);
        // Freed (when no reader holds it) after the lock is released: a map's pages are
        // hundreds of megabytes, and `shown` must not wait for that.
        drop(old);
    }

    pub fn seed(&self) -> u64 {
        self.config.bundle.seed
    }
}

/// Applies the camera the front end set last, if it is not applied yet.
pub(super) fn sync_camera(shared: &Shared, st: &mut State) {
    if take_camera(shared, st) {
        update_views(shared, st);
    }
}

/// Takes the camera the front end set last into `st` without recomputing the views (for
/// callers that recompute them anyway); returns whether it changed.
pub(super) fn take_camera(shared: &Shared, st: &mut State) -> bool {
    let (version, camera) = *shared.camera.lock().unwrap_or_else(|e| e.into_inner());
    let changed = version != st.camera_version;
    st.camera_version = version;
    st.camera = camera;
    changed
}

/// Recomputes every non-empty cell's view and target LOD (both layers') for the current
/// camera.
pub(super) fn update_views(shared: &Shared, st: &mut State) {
    let Some(camera) = st.camera else { return };
    let world = st.world.clone();
    if shared.config.memory_budget.is_none() {
        st.budget = derived_budget(&shared.config, &world, &shared.shown(), &camera, super::memory_ceiling());
    }
    for c in world.non_empty_cells() {
        let view = cell_view(&camera, &world.grid, c);
        let cell = &mut st.cells[c as usize];
        cell.view = Some(view);
        cell.target = target_lod(&camera, view, world.atlas.texel_size, shared.config.texel_pixels, world.lods);
        cell.punctual.target = cell.target;
    }
}

pub(super) fn current_stats(shared: &Shared, st: &mut State) -> RuntimeStats {
    let world = &st.world;
    let shown = shared.shown();
    let mut s = st.stats.clone();
    s.cells_per_lod = vec![0; world.lods as usize];
    s.queue = 0;
    s.baking = 0;
    s.punctual_cells_per_lod = vec![0; if world.scene.lights.is_empty() { 0 } else { world.lods as usize }];
    for c in world.non_empty_cells() {
        let cell = &st.cells[c as usize];
        s.cells_per_lod[(cell.shown as usize).min(world.lods as usize - 1)] += 1;
        if let Some(n) = s.punctual_cells_per_lod.get_mut(cell.punctual.shown as usize) {
            *n += 1;
        }
        s.queue += usize::from(next_lod(cell).is_some() || punctual_work(world, cell).is_some());
        s.baking += usize::from(cell.bake.is_some() || cell.busy || cell.punctual.busy);
    }
    s.page_bytes = shown.page_bytes() as u64;
    s.page_fill = shown.page_fill();
    s.bake_bytes = st.bake_bytes;
    s.fixed_bytes = fixed_bytes(world);
    s.memory_budget = st.budget;
    s.resident_bytes = s.page_bytes + s.bake_bytes + s.fixed_bytes;
    s.dropped_events = shared.dropped.load(Ordering::Relaxed);
    s
}

/// Light-map pixels (x, y) in lists: per cell, or per LOD.
pub(super) type PixelLists = Vec<Vec<[u32; 2]>>;

pub(super) fn clock_thread(shared: &Shared) {
    let mut last = Instant::now();
    loop {
        {
            let st = shared.lock();
            let wait = Duration::from_secs(1).saturating_sub(last.elapsed());
            let st = shared
                .wake
                .wait_timeout_while(st, wait, |_| !shared.shutdown.load(Ordering::SeqCst))
                .unwrap_or_else(|e| e.into_inner())
                .0;
            drop(st);
        }
        if shared.shutdown.load(Ordering::SeqCst) {
            return;
        }
        if last.elapsed() < Duration::from_secs(1) {
            continue;
        }
        let seconds = last.elapsed().as_secs_f64();
        last = Instant::now();
        let mut st = shared.lock();
        sync_camera(shared, &mut st);
        st.stats.texel_samples_per_second = st.window_samples as f64 / seconds;
        st.window_samples = 0;
        let stats = current_stats(shared, &mut st);
        drop(st);
        shared.emit(RuntimeEvent::Stats(stats));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A punctual bake makes the next finer LOD; a stale layer is made again at LOD 0 and
    /// its two finest levels; nothing while one is in flight or when shown at its target.
    #[test]
    fn a_punctual_bake_makes_the_next_finer_lod() {
        let state = |shown, target, stale| PunctualState { shown, target, stale, ..PunctualState::default() };
        assert_eq!(state(0, 5, false).next_levels(), Some(vec![1]));
        assert_eq!(state(4, 6, false).next_levels(), Some(vec![5]));
        assert_eq!(state(5, 5, true).next_levels(), Some(vec![0, 4, 5]));
        assert_eq!(state(1, 3, true).next_levels(), Some(vec![0, 1]));
        assert_eq!(state(0, 0, true).next_levels(), Some(vec![0]));
        assert_eq!(state(5, 5, false).next_levels(), None);
        assert_eq!(state(6, 5, false).next_levels(), None);
        let busy = PunctualState { busy: true, ..state(0, 5, false) };
        assert_eq!(busy.next_levels(), None);
    }
}
