//! The runtime's shared state and its threads: first light, the workers that refine cells
//! (most urgent first, within the memory budget), publishing, eviction and the stats clock.
//!
//! Everything a decision reads is in one mutex ([`State`]: the world, the cell table, the
//! camera, memory accounting), held only to decide and to publish, never while tracing.
//! The shown light map is a separate snapshot pointer, swapped whole by each publish.

use std::ops::ControlFlow;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, RwLock};
use std::time::{Duration, Instant};

use crossbeam_channel::Sender;

use super::cell_bake::CellBake;
use super::memory::{PAGE_BYTES_PER_TEXEL, bake_estimate, derived_budget, fixed_bytes, lod_texels};
use super::policy::{
    CameraView, CellView, LayerLight, Step, Tier, Work, cell_view, priority, screen_weight, target_lod, urgency,
};
use super::punctual::{PunctualBake, punctual_bake_bytes};
use super::shown::{Layer, Page, PageWriter, ShownLightmap};
use super::world::World;
use super::{RuntimeConfig, RuntimeEvent, RuntimeStats, TimedEvent};
use crate::atlas::chart_filter::filter_within_charts;
use crate::atlas::lookup::TexelTable;
use crate::bake::bundle::{BatchDone, BundleLodStats, bake_lod_observed};
use crate::bundle::{BackendError, BundleBackend, BundleScene};
use crate::grid::CellId;
use crate::progress::NoProgress;
use crate::scene::Rgb;

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
    /// Its shown level was published early (see [`publish_due`]): the bake that published it
    /// has not met the error bound nor `max_directions` yet and goes on at that LOD (parked
    /// as between any two units), republished as its directions double, before the cell
    /// moves on to a finer one. Only ever the finest shown level: a cell swaps to the next
    /// LOD only from a settled one.
    pub unsettled: bool,
    /// Directions and error of each shown level (index = LOD).
    pub history: Vec<(u64, f32)>,
    /// Pixels written at each LOD of the bundle layer (index = LOD), to withdraw or replace
    /// them.
    pub published: Vec<Vec<[u32; 2]>>,
    /// The cell's punctual layer (scenes with punctual lights).
    pub punctual: PunctualState,
    /// The light each layer shows at each LOD (indexed by [`Layer`], then LOD), as last
    /// published: what refining it is worth ([`urgency`]).
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
/// work beside everything else to do ([`urgency`]).
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
    /// Punctual jobs taken in a row while bundle work was waiting ([`pick`]).
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

/// Bakes LOD 0 of the whole scene with `backend` and returns `map` with it published
/// (filtered within charts, as every publish is), the pixels each cell owns there, and the
/// bake's figures.
pub fn bake_first_light(
    world: &World,
    backend: &mut dyn BundleBackend,
    threads: usize,
    map: ShownLightmap,
    cancel: &AtomicBool,
) -> Result<(ShownLightmap, PixelLists, BundleLodStats), String> {
    bake_first_light_observed(world, backend, threads, map, cancel, &[], &mut |_, _, _| {})
}

/// [`bake_first_light`], handing out early results on the way: after the first batch that
/// reaches each of `early` directions, `published(map, owned, directions)` gets `map` with
/// the running estimate published (the progressive bake goes on: later directions only add
/// to it).
pub fn bake_first_light_observed(
    world: &World,
    backend: &mut dyn BundleBackend,
    threads: usize,
    map: ShownLightmap,
    cancel: &AtomicBool,
    early: &[u64],
    published: &mut dyn FnMut(ShownLightmap, &PixelLists, u64),
) -> Result<(ShownLightmap, PixelLists, BundleLodStats), String> {
    let lod0 = &world.lod0;
    let w = lod0.width;
    let pixels: Vec<[u32; 2]> = lod0.pixel.iter().map(|&p| [p % w, p / w]).collect();
    let table = TexelTable::of_map(lod0);
    let cell_of: Vec<CellId> = lod0.position.iter().map(|&p| world.grid.cell_of(p)).collect();
    let mut owned = vec![Vec::new(); world.grid.len()];
    for (i, p) in pixels.iter().enumerate() {
        owned[cell_of[i] as usize].push(*p);
    }
    for &(g, t) in &lod0.gutter {
        owned[cell_of[t as usize] as usize].push([g % w, g / w]);
    }
    // The published values: the noisy part (bundles, light pass) filtered within charts in
    // the bundle layer, the exact punctual part in the punctual layer.
    let lights = !world.scene.lights.is_empty();
    let publish =
        |mut map: ShownLightmap, irradiance: &dyn Fn(usize) -> Rgb, direct: &[Rgb], sampled: &dyn Fn(usize) -> bool| {
            // No punctual part (a scene without punctual lights) reads as zero.
            let direct_of = |i: usize| direct.get(i).copied().unwrap_or(Rgb::ZERO);
            let noisy: Vec<Rgb> = (0..pixels.len()).map(|i| irradiance(i) - direct_of(i)).collect();
            let filtered = filter_within_charts(&pixels, |_| &table, &noisy, sampled);
            let layers = [(Layer::Bundles, filtered), (Layer::Punctual, (0..pixels.len()).map(direct_of).collect())];
            let mut writer = PageWriter::new(&mut map);
            for (layer, values) in layers.iter().take(if lights { 2 } else { 1 }) {
                for (i, p) in pixels.iter().enumerate() {
                    writer.write(*layer, 0, p[0], p[1], values[i]);
                }
                for &(g, t) in &lod0.gutter {
                    writer.write(*layer, 0, g % w, g / w, values[t as usize]);
                }
            }
            writer.finish();
            map
        };
    let mut next = early.iter().copied().filter(|&d| d > 0).min();
    let mut observe = |done: &BatchDone| {
        if let Some(at) = next
            && done.directions >= at
        {
            let e = done.estimate;
            published(
                publish(map.clone(), &|i| e.irradiance_of(i), e.punctual(), &|i| e.sampled(i)),
                &owned,
                done.directions,
            );
            next = early.iter().copied().filter(|&d| d > done.directions).min();
        }
        ControlFlow::Continue(())
    };
    let baked =
        bake_lod_observed(&world.bundle, &world.bvh, backend, lod0, None, threads, &NoProgress, cancel, &mut observe)
            .map_err(|e| e.to_string())?;
    if baked.stats.pass.unplanned_directions > 0 {
        return Err(format!("{} bundle directions could not be planned", baked.stats.pass.unplanned_directions));
    }
    let sampled = |i: usize| baked.unsampled.binary_search(&(i as u32)).is_err();
    let map = publish(map, &|i| baked.irradiance[i], &baked.punctual, &sampled);
    Ok((map, owned, baked.stats))
}

/// An empty shown map for `world` (nothing published yet).
pub fn empty_shown(world: &World) -> ShownLightmap {
    let blend_band = (2.0 * world.atlas.texel_size).min(world.grid.cell_size * 0.25);
    ShownLightmap::new(world.grid, world.atlas.width, world.atlas.height, world.lods, blend_band)
}

/// Bakes LOD 0 of the whole scene on every core and publishes it: first light after
/// `first_light_directions` (progressive: the bake goes on), then again at twice as many
/// directions and so on, and when the bake has all its directions; refinement starts then.
pub(super) fn first_light(shared: &Shared) {
    let world = shared.lock().world.clone();
    let threads = shared.config.threads();
    let total = shared.config.bundle.directions as u64;
    let mut early = Vec::new();
    let mut d = (shared.config.first_light_directions as u64).max(1);
    while d < total {
        early.push(d);
        d *= 2;
    }
    let generation = shared.lock().generation;
    let mut show = |map: ShownLightmap, owned: &PixelLists, directions: u64| {
        let mut st = shared.lock();
        if st.generation != generation {
            // A hot reload replaced the world meanwhile: it published its own light.
            return;
        }
        // LOD 0 only: punctual bakes may have published finer levels meanwhile.
        let mut shown = (*shared.shown()).clone();
        shown.adopt_level(&map, 0);
        let first = !st.first_light;
        let lights = !world.scene.lights.is_empty();
        for (c, pixels) in owned.iter().enumerate() {
            let cell = &mut st.cells[c];
            cell.history = vec![(directions, f32::NAN)];
            if first {
                cell.published = vec![pixels.clone()];
                if lights {
                    cell.punctual.published = vec![pixels.clone()];
                }
            }
            if !pixels.is_empty() {
                cell.set_light(Layer::Bundles, 0, shown.layer_light(Layer::Bundles, 0, pixels));
                if lights {
                    cell.set_light(Layer::Punctual, 0, shown.layer_light(Layer::Punctual, 0, pixels));
                }
            }
        }
        shared.set_shown(shown);
        st.lod0_directions = directions;
        if first {
            st.first_light = true;
            st.stats.first_light_seconds = Some(shared.started.elapsed().as_secs_f64());
            take_camera(shared, &mut st);
            update_views(shared, &mut st);
        }
        drop(st);
        shared.wake.notify_all();
        shared.emit(if first {
            RuntimeEvent::FirstLight { texels: world.lod0.len(), directions: directions as u32 }
        } else {
            RuntimeEvent::Lod0Published { directions }
        });
    };
    let result = (shared.make_backend)(&world.bundle, threads).map_err(|e| e.to_string()).and_then(|mut backend| {
        bake_first_light_observed(
            &world,
            backend.as_mut(),
            threads,
            empty_shown(&world),
            &shared.shutdown,
            &early,
            &mut show,
        )
    });
    let (map, owned, stats) = match result {
        Ok(r) => r,
        Err(_) if shared.shutdown.load(Ordering::SeqCst) => return,
        Err(error) => {
            tracing::error!("first light failed: {error}");
            shared.lock().failed = Some(error.clone());
            shared.wake.notify_all();
            shared.emit(RuntimeEvent::Failed { error });
            return;
        }
    };
    // The LOD-0 bake's counters before its map is shown: whoever wakes on the event that
    // shows it (first light, or LOD 0 published) reads them.
    {
        let mut st = shared.lock();
        st.stats.directions_traced += stats.directions;
        st.stats.first_light_pass = stats.pass.clone();
    }
    show(map, &owned, stats.directions);
    let mut st = shared.lock();
    st.lod0_done = true;
    st.first_light = true;
    drop(st);
    shared.wake.notify_all();
}

/// What a worker takes.
enum Job {
    /// Bundles: cells (the first leads), the LOD to bake them at, and their bake if one is
    /// parked.
    Bundles { world: Arc<World>, generation: u64, cells: Vec<CellId>, lod: u32, bake: Option<Box<CellBake>> },
    /// A cell's punctual layer at these LODs (ascending; the finest the cell then has is shown).
    Punctual { world: Arc<World>, generation: u64, cell: CellId, levels: Vec<u32> },
}

/// The LODs a cell's punctual layer is to be baked at next, if the scene has punctual lights
/// and the cell has such work waiting (see [`PunctualState::next_levels`]).
pub(super) fn punctual_work(world: &World, s: &CellState) -> Option<Vec<u32>> {
    if world.scene.lights.is_empty() || s.view.is_none() {
        return None;
    }
    s.punctual.next_levels()
}

/// The LOD a cell's next bake is at: LOD 0 again for a provisional cell (its quick re-bake
/// is replaced before it is refined on), its shown LOD for an unsettled cell still wanted at
/// least that fine (its level is finished before the next, see [`CellState::unsettled`]),
/// the next finer one below its target, else (a stale cell at its target) its shown LOD
/// again, to refresh it.
pub(super) fn next_lod(s: &CellState) -> Option<u32> {
    if s.provisional {
        Some(0)
    } else if s.unsettled && s.target >= s.shown {
        Some(s.shown)
    } else if s.target > s.shown {
        Some(s.shown + 1)
    } else if s.stale {
        Some(s.shown)
    } else {
        None
    }
}

/// What a bake's cells show, as the swap rule reads it.
#[derive(Clone, Copy, Debug)]
pub(super) struct ShownNow {
    /// Their shown LOD (a group's cells share it: they are gathered from one shown LOD and
    /// are neither evicted nor re-baked apart while the group is).
    pub lod: u32,
    /// The most directions any of them shows that level with.
    pub directions: u64,
    /// Every one of them shows an early publish still being refined ([`CellState::unsettled`]).
    pub unsettled: bool,
    /// One of them is stale (hot reload): its refresh publishes only settled, as before.
    pub stale: bool,
    /// One of them is provisional and the bake is at LOD 0: it replaces a reload's quick LOD 0.
    pub provisional: bool,
}

/// Whether a bake may be published after its latest unit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Due {
    /// Not yet.
    Wait,
    /// Published, and the bake goes on at this LOD into the same sums (no restart).
    Early,
    /// Published, and the bake is done: its error is below the bound or it has the most
    /// directions it may have.
    Settled,
}

/// The swap rule for a bake at `lod` with `directions` traced and an estimated `error`:
/// * settled when it has `min_directions` and its error is at most `error_bound`, or
///   `max_directions` (a reload's LOD-0 replacement: first light's directions);
/// * early, at a finer LOD than shown, once it has at least the directions of the shown level
///   (and `min_directions`): per-texel noise at equal directions is about the same at every
///   LOD (each texel gets ~oversampling² bundle lines per direction), so the finer level is
///   no noisier and is sharper. The error estimate is an upper bound (1.9–3.2× the measured
///   error, `tests/runtime.rs`), so waiting for it would keep most cells at the coarser
///   level until `max_directions`;
/// * early again, at the LOD an unsettled cell shows, each time its directions double (a
///   refresh of stale cells waits until settled, as it always has).
pub(super) fn publish_due(config: &RuntimeConfig, lod: u32, shown: ShownNow, directions: u64, error: f32) -> Due {
    let d = directions;
    let min = config.min_directions as u64;
    if shown.provisional {
        // Replacing a reload's quick LOD 0: with first light's directions, as LOD 0 is
        // everywhere else.
        return if d >= config.bundle.directions as u64 { Due::Settled } else { Due::Wait };
    }
    if d >= config.max_directions as u64 || (d >= min && error <= config.error_bound) {
        return Due::Settled;
    }
    let early = if lod > shown.lod {
        d >= min.max(shown.directions)
    } else {
        lod == shown.lod && shown.unsettled && !shown.stale && d >= min.max(2 * shown.directions)
    };
    if early { Due::Early } else { Due::Wait }
}

/// What the cells of `bake` show now (see [`ShownNow`]).
fn shown_now(st: &State, bake: &CellBake) -> ShownNow {
    let leader = &st.cells[bake.leader() as usize];
    let lod = leader.shown;
    let cells = || bake.cells.iter().map(|&m| &st.cells[m as usize]);
    ShownNow {
        lod,
        directions: cells().map(|s| s.history.get(lod as usize).map_or(0, |h| h.0)).max().unwrap_or(0),
        unsettled: cells().all(|s| s.unsettled && s.shown == lod),
        stale: cells().any(|s| s.stale),
        provisional: bake.lod == 0 && cells().any(|s| s.provisional),
    }
}

/// The next job (from first light on: punctual bakes; once LOD 0 has all its directions,
/// bundle bakes too), the most urgent of both layers' work ([`priority`]: a reload's
/// provisional cells first, then the on-screen error a job removes per unit of work,
/// [`urgency`], one scale for both layers), not being worked on, with room within the
/// memory budget (made by evicting what matters less, [`make_room`]); `None` when nothing
/// is to be done or nothing fits. A
/// cell whose group bake is parked (it is a member) brings its leader's bake back; a new
/// bake gathers neighbours that want the same LOD ([`gather_group`]).
fn pick(shared: &Shared, st: &mut State) -> Option<Job> {
    let punctual = best_punctual(st);
    // Bundle bakes see the shown map as converged light: they wait for all of LOD 0's
    // directions (punctual bakes, exact, need not).
    let bundles = if st.lod0_done { best_bundles(&shared.config, st) } else { None };
    // The more urgent first; when it does not fit the memory budget, the other. Bundle work
    // waiting gets every few jobs whatever the order says: a camera turning faster than
    // punctual bakes finish keeps raising in-view cells' punctual targets, and the
    // millisecond punctual bakes (evicting each other under a tight budget) took every job
    // (0 bundle publishes in 30 s, 26 943 punctual ones, 183 camera moves a second).
    let starved = st.punctual_streak >= PUNCTUAL_STREAK;
    let job = match (punctual, bundles) {
        (Some(p), Some(b)) if b.0 < p.0 || starved => {
            take_bundles(shared, st, b.1).or_else(|| take_punctual(shared, st, p.1))
        }
        (Some(p), b) => take_punctual(shared, st, p.1).or_else(|| b.and_then(|b| take_bundles(shared, st, b.1))),
        (None, Some((_, c))) => take_bundles(shared, st, c),
        (None, None) => None,
    };
    match &job {
        Some(Job::Punctual { .. }) if bundles.is_some() => st.punctual_streak += 1,
        Some(_) => st.punctual_streak = 0,
        None => {}
    }
    job
}

/// Punctual jobs in a row after which waiting bundle work goes first ([`pick`]): bundle work
/// gets at least a third of the jobs, and most of the time (a punctual bake is one shadow
/// ray a texel, a bundle unit many directions). With 8, the stress test's spinning camera
/// saw 3 bundle publishes in 30 s.
const PUNCTUAL_STREAK: u32 = 2;

/// A job's place in the order of work ([`priority`]).
type JobKey = ((Tier, std::cmp::Reverse<u32>), CellId);

/// Where a cell stands for the camera, and how much of the screen its surfaces may cover
/// ([`screen_weight`]).
fn weight_of(world: &World, s: &CellState, c: CellId) -> f32 {
    let view = s.view.unwrap_or(CellView { distance: f32::MAX, in_frustum: false });
    let texel = world.atlas.texel_size;
    let area = world.lod0_texels[c as usize] as f32 * texel * texel;
    screen_weight(view, area, world.grid.cell_size)
}

/// The cell whose punctual layer is most urgent ([`urgency`] of its next level's bake), if
/// any has work waiting; a stale layer's re-bake after all refinement.
fn best_punctual(st: &State) -> Option<(JobKey, CellId)> {
    let world = &st.world;
    world
        .non_empty_cells()
        .filter_map(|c| {
            let s = &st.cells[c as usize];
            let levels = punctual_work(world, s)?;
            let p = &s.punctual;
            let texels = levels.iter().map(|&k| lod_texels(world, c, k)).sum();
            let u = urgency(weight_of(world, s, c), s.light(Layer::Punctual, p.shown), Step::Punctual { texels });
            let tier = if p.stale { Tier::Refresh } else { Tier::Refine };
            Some(((priority(tier, u), c), c))
        })
        .min()
}

/// Takes the punctual bake of `c` (see [`pick`]).
fn take_punctual(shared: &Shared, st: &mut State, c: CellId) -> Option<Job> {
    let world = st.world.clone();
    let levels = punctual_work(&world, &st.cells[c as usize])?;
    let texels: u64 = levels.iter().map(|&k| lod_texels(&world, c, k)).sum();
    let need = punctual_bake_bytes(texels);
    if !make_room(shared, st, &[c], need, texels, Work::Punctual) {
        return None;
    }
    st.cells[c as usize].punctual.busy = true;
    st.bake_bytes += need;
    Some(Job::Punctual { world, generation: st.generation, cell: c, levels })
}

/// The cell whose bundle layer is most urgent, if any has work waiting: a reload's
/// provisional cells first (the change is shown at full quality soonest), then refinement by
/// [`urgency`] (a finer level: the detail of the shown one, over the work until it swaps in;
/// an early-published level: its noise, over the work until it is published again), then
/// refreshing stale light.
fn best_bundles(config: &RuntimeConfig, st: &State) -> Option<(JobKey, CellId)> {
    let world = &st.world;
    let leader_of = |c: CellId| st.cells[c as usize].member_of.unwrap_or(c);
    world
        .non_empty_cells()
        .filter_map(|c| {
            let s = &st.cells[c as usize];
            if st.cells[leader_of(c) as usize].busy || s.view.is_none() {
                return None;
            }
            let lod = next_lod(s)?;
            let parked = st.cells[leader_of(c) as usize].bake.as_ref().filter(|b| b.lod == lod);
            let traced = parked.map_or(0, |b| b.directions());
            let (shown_directions, error) = s.history.get(s.shown as usize).copied().unwrap_or((0, f32::INFINITY));
            let texels = lod_texels(world, c, lod);
            let step = if lod > s.shown {
                let wanted = (config.min_directions as u64).max(shown_directions);
                Step::Refine { texels, directions: wanted.saturating_sub(traced).max(1), new: parked.is_none() }
            } else {
                Step::Continue { texels, directions: (2 * shown_directions).saturating_sub(traced).max(1), error }
            };
            let tier = if s.provisional {
                Tier::Provisional
            } else if lod > s.shown || s.unsettled {
                Tier::Refine
            } else {
                Tier::Refresh
            };
            let u = urgency(weight_of(world, s, c), s.light(Layer::Bundles, s.shown), step);
            Some(((priority(tier, u), c), c))
        })
        .min()
}

/// Takes the bundle bake of `c` (see [`pick`]): its group's parked bake, or a new one.
fn take_bundles(shared: &Shared, st: &mut State, c: CellId) -> Option<Job> {
    let world = st.world.clone();
    let leader = st.cells[c as usize].member_of.unwrap_or(c);
    if let Some(bake) = st.cells[leader as usize].bake.take() {
        // Resume the parked bake, unless it is of another level than its leader's next (the
        // cell was evicted or refreshed meanwhile): then it is dropped and made anew.
        let wanted = next_lod(&st.cells[leader as usize]);
        if bake.cells.len() > 1 || wanted == Some(bake.lod) {
            let (cells, lod) = (bake.cells.clone(), bake.lod);
            for &m in &cells {
                st.cells[m as usize].busy = true;
            }
            return Some(Job::Bundles { world, generation: st.generation, cells, lod, bake: Some(bake) });
        }
        st.bake_bytes -= bake.bytes() as u64;
        st.cells[leader as usize].baking_directions = 0;
    }
    let lod = next_lod(&st.cells[leader as usize])?;
    let cells = gather_group(shared, st, leader, lod);
    let need: u64 = cells.iter().map(|&m| bake_estimate(&world, m, lod)).sum();
    let texels: u64 = cells.iter().map(|&m| lod_texels(&world, m, lod)).sum();
    if !make_room(shared, st, &cells, need, texels, Work::Bundles) {
        return None;
    }
    for &m in &cells {
        st.cells[m as usize].busy = true;
    }
    Some(Job::Bundles { world, generation: st.generation, cells, lod, bake: None })
}

/// The cells a new bake of `leader` at `lod` takes: the leader, then its nearest neighbours
/// (within [`GROUP_REACH`] cells on each axis) that also want `lod` next from the same shown
/// LOD (and are as provisional and as unsettled, see [`CellState::provisional`] and
/// [`CellState::unsettled`]: a group follows one swap rule) and are free (no bake of
/// their own, not in a group), until the group has `config.group_texels` texels at `lod` (estimated from LOD 0's); never more than twice that,
/// nor more than the memory budget has free.
fn gather_group(shared: &Shared, st: &State, leader: CellId, lod: u32) -> Vec<CellId> {
    let world = &st.world;
    let want = shared.config.group_texels as u64;
    let texels = |c: CellId| (world.lod0_texels[c as usize] as u64) << (2 * lod);
    let mut cells = vec![leader];
    let mut total = texels(leader);
    if total >= want {
        return cells;
    }
    let free = st.budget.saturating_sub(budgeted_bytes(shared, st));
    let mut bytes = bake_estimate(world, leader, lod);
    let l = &st.cells[leader as usize];
    let (shown, provisional, unsettled) = (l.shown, l.provisional, l.unsettled);
    let [x, y, z] = world.grid.coords(leader);
    let dims = world.grid.dims;
    let range = |v: u32, n: u32| v.saturating_sub(GROUP_REACH)..=(v + GROUP_REACH).min(n - 1);
    let mut near: Vec<(u32, CellId)> = Vec::new();
    for k in range(z, dims[2]) {
        for j in range(y, dims[1]) {
            for i in range(x, dims[0]) {
                let c = world.grid.index([i, j, k]);
                let s = &st.cells[c as usize];
                let free = !s.busy && s.bake.is_none() && s.member_of.is_none();
                if c != leader
                    && world.lod0_texels[c as usize] > 0
                    && free
                    && s.shown == shown
                    && s.provisional == provisional
                    && s.unsettled == unsettled
                    && next_lod(s) == Some(lod)
                {
                    let d = i.abs_diff(x).max(j.abs_diff(y)).max(k.abs_diff(z));
                    near.push((d, c));
                }
            }
        }
    }
    near.sort_unstable();
    for (_, c) in near {
        if total >= want || cells.len() == super::cell_bake::MAX_GROUP {
            break;
        }
        // Never past twice the wanted size, and a group grows only into free memory: making
        // room for a larger one would drop other cells' parked work (under a tight budget and
        // a moving camera, again and again).
        if total + texels(c) > 2 * want || bytes + bake_estimate(world, c, lod) > free {
            continue;
        }
        bytes += bake_estimate(world, c, lod);
        total += texels(c);
        cells.push(c);
    }
    cells
}

/// How far (cells, per axis) a group reaches from its leader.
const GROUP_REACH: u32 = 3;

/// Bytes counted against the budget: shown pages and bakes in progress.
fn budgeted_bytes(shared: &Shared, st: &State) -> u64 {
    shared.shown().page_bytes() as u64 + st.bake_bytes
}

/// Frees memory until `need` more bytes fit the budget, taking from what matters less than
/// the work on `for_cells` (its leader first): first parked bakes and finest levels (of
/// either layer) of cells shown finer than they need, then bundle levels of cells farther
/// from the camera than the leader and punctual levels of cells out of view (when the
/// leader is in view, or farther), farthest first (at equal distance a punctual level, the
/// cheaper to make again). A punctual bake takes milliseconds: letting it evict in-view
/// cells' punctual levels by distance alone made cells in view evict each other as fast as
/// a turning camera reorders them, and no bundle work got through. A punctual bake takes
/// bundle work's room only from levels beyond their cell's target, never a parked bake: a
/// camera turning faster than a bundle bake's unit parked each bake at once, and the next
/// punctual bake dropped it (0 bundle publishes in 240 s, 183 camera moves a second).
/// Cells in a parked group bake are let alone (the group's leader stands for them: its
/// bake goes first). Returns whether it fits.
fn make_room(shared: &Shared, st: &mut State, for_cells: &[CellId], need: u64, texels: u64, work: Work) -> bool {
    let budget = st.budget;
    // The front end's page limit, and the pages the work's `texels` will take.
    let page_cap = st.page_limit.map_or(u64::MAX, |p| p.saturating_mul(Page::BYTES as u64));
    let need_pages = texels * PAGE_BYTES_PER_TEXEL;
    let over = |st: &State| {
        budgeted_bytes(shared, st) + need > budget || shared.shown().page_bytes() as u64 + need_pages > page_cap
    };
    let world = st.world.clone();
    let view = |st: &State, c: CellId| st.cells[c as usize].view;
    let distance = |st: &State, c: CellId| view(st, c).map_or(f32::MAX, |v| v.distance);
    let in_view = |st: &State, c: CellId| view(st, c).is_some_and(|v| v.in_frustum);
    let (mine, mine_in_view) = (distance(st, for_cells[0]), in_view(st, for_cells[0]));
    while over(st) {
        // What matters least: beyond its cell's target first, then farthest.
        let mut victim: Option<((bool, f32, bool), CellId, Layer)> = None;
        for c in world.non_empty_cells().filter(|c| !for_cells.contains(c)) {
            let s = &st.cells[c as usize];
            let d = distance(st, c);
            let out_of_view = !in_view(st, c) && (mine_in_view || d > mine);
            let mut consider = |over: bool, layer: Layer| {
                let less_urgent = if layer == Layer::Bundles { d > mine } else { out_of_view };
                if !(over || less_urgent) {
                    return;
                }
                let key = (over, d, layer == Layer::Punctual);
                if victim.as_ref().is_none_or(|(k, _, _)| key.partial_cmp(k) == Some(std::cmp::Ordering::Greater)) {
                    victim = Some((key, c, layer));
                }
            };
            let parked = s.bake.is_some();
            if !s.busy && s.member_of.is_none() && (s.shown > 0 || parked) {
                let over = s.shown > s.target;
                if work == Work::Bundles || (over && !parked) {
                    consider(over, Layer::Bundles);
                }
            }
            if !s.punctual.busy && s.punctual.shown > 0 {
                consider(s.punctual.shown > s.punctual.target, Layer::Punctual);
            }
        }
        let Some((_, victim, layer)) = victim else { return false };
        match layer {
            // A parked bake's work is lost; it would be the first thing rebuilt if needed.
            Layer::Bundles if st.cells[victim as usize].bake.is_some() => drop_parked(st, victim),
            Layer::Bundles => evict(shared, st, victim),
            Layer::Punctual => evict_punctual(shared, st, victim),
        }
    }
    true
}

/// Drops the bake parked at `leader` (its group's with it): its work is lost.
fn drop_parked(st: &mut State, leader: CellId) {
    let Some(bake) = st.cells[leader as usize].bake.take() else { return };
    st.bake_bytes -= bake.bytes() as u64;
    for &m in &bake.cells {
        let s = &mut st.cells[m as usize];
        s.baking_directions = 0;
        s.member_of = None;
    }
}

/// Withdraws a cell's finest shown level of the bundle layer (its pixels at that LOD) and
/// shows the next coarser.
fn evict(shared: &Shared, st: &mut State, cell: CellId) {
    let s = &mut st.cells[cell as usize];
    let lod = s.shown;
    if lod == 0 {
        return;
    }
    let pixels = std::mem::take(&mut s.published[lod as usize]);
    s.shown = lod - 1;
    // Only the finest shown level may be unsettled: the coarser one was settled before the
    // cell swapped on from it.
    s.unsettled = false;
    s.history.truncate(lod as usize);
    withdraw(shared, Layer::Bundles, cell, lod, &pixels, lod - 1);
    st.stats.evictions += 1;
    shared.emit(RuntimeEvent::CellEvicted { cell, lod, layer: Layer::Bundles });
}

/// Withdraws a cell's finest punctual level and shows the next coarser one it has (LOD 0 at
/// least: levels in between are skipped, [`PunctualState`]).
fn evict_punctual(shared: &Shared, st: &mut State, cell: CellId) {
    let p = &mut st.cells[cell as usize].punctual;
    let lod = p.shown;
    if lod == 0 {
        return;
    }
    let pixels = p.published.get_mut(lod as usize).map(std::mem::take).unwrap_or_default();
    let below = (0..lod).rev().find(|&k| p.published.get(k as usize).is_some_and(|v| !v.is_empty())).unwrap_or(0);
    p.shown = below;
    withdraw(shared, Layer::Punctual, cell, lod, &pixels, below);
    st.stats.evictions += 1;
    shared.emit(RuntimeEvent::CellEvicted { cell, lod, layer: Layer::Punctual });
}

/// Clears `pixels` of `layer` at `lod` and shows `cell` at `shown` in that layer, in a new
/// snapshot.
fn withdraw(shared: &Shared, layer: Layer, cell: CellId, lod: u32, pixels: &[[u32; 2]], shown: u32) {
    let mut map = (*shared.shown()).clone();
    let mut writer = PageWriter::new(&mut map);
    for p in pixels {
        writer.clear(layer, lod, p[0], p[1]);
    }
    writer.set_cell_lod(layer, cell, shown);
    writer.finish();
    shared.set_shown(map);
}

pub(super) fn worker(shared: &Shared) {
    let mut backend: Option<(u64, Box<dyn BundleBackend>)> = None;
    let cancel = &shared.shutdown;
    loop {
        // Take the most urgent job.
        let job = {
            let mut st = shared.lock();
            loop {
                if shared.shutdown.load(Ordering::SeqCst) {
                    return;
                }
                sync_camera(shared, &mut st);
                if st.first_light && !st.paused && !st.relighting && st.failed.is_none() {
                    if let Some(job) = pick(shared, &mut st) {
                        break job;
                    }
                }
                st = shared.wake.wait_timeout(st, Duration::from_millis(200)).unwrap_or_else(|e| e.into_inner()).0;
            }
        };
        let (world, generation, cells, lod, bake) = match job {
            Job::Bundles { world, generation, cells, lod, bake } => (world, generation, cells, lod, bake),
            Job::Punctual { world, generation, cell, levels } => {
                bake_punctual(shared, &world, generation, cell, &levels);
                continue;
            }
        };
        if backend.as_ref().is_none_or(|(g, _)| *g != generation) {
            match (shared.make_backend)(&world.bundle, 1) {
                Ok(b) => backend = Some((generation, b)),
                Err(e) => {
                    shared.emit(RuntimeEvent::Failed { error: e.to_string() });
                    let mut st = shared.lock();
                    for &c in &cells {
                        st.cells[c as usize].busy = false;
                    }
                    return;
                }
            }
        }
        let Some((_, backend)) = backend.as_mut() else { return };
        let mut bake = match bake {
            Some(b) => b,
            None => {
                let t = Instant::now();
                let b = Box::new(CellBake::new(&world, &cells, lod, shared.shown(), shared.seed()));
                let mut st = shared.lock();
                st.bake_bytes += b.bytes() as u64;
                st.stats.cell_setup_seconds += t.elapsed().as_secs_f64();
                b
            }
        };
        let unit = bake.step(&world, backend.as_mut(), shared.config.unit_directions, cancel);
        let mut st = shared.lock();
        if st.generation != generation {
            // A hot reload replaced the world: this bake's texels are of the old scene (the
            // reload recounted the bytes of what it kept). The grid is kept across reloads.
            for &c in &cells {
                if let Some(s) = st.cells.get_mut(c as usize) {
                    s.busy = false;
                }
            }
            continue;
        }
        let u = match unit {
            Ok(u) => u,
            Err(_) => {
                // Cancelled (shutting down): the bake keeps what it had before the unit.
                park(&mut st, bake);
                continue;
            }
        };
        st.stats.pass.add(&u.pass);
        st.stats.units += 1;
        st.stats.directions_traced += u.directions;
        st.window_samples += u.texel_samples;
        let c = &shared.config;
        let error = bake.error();
        let d = bake.directions();
        let due = publish_due(c, bake.lod, shown_now(&st, &bake), d, error);
        if due == Due::Wait {
            park(&mut st, bake);
        } else {
            let settled = due == Due::Settled;
            let refined = publish(shared, &mut st, &bake, error, settled);
            let (cells, lod) = (bake.cells.clone(), bake.lod);
            if settled {
                st.bake_bytes -= bake.bytes() as u64;
                for &m in &bake.cells {
                    let s = &mut st.cells[m as usize];
                    s.busy = false;
                    s.member_of = None;
                    s.baking_directions = 0;
                }
            } else {
                // Published early: the bake goes on at this LOD into the same sums, parked as
                // between any two units (its memory stays reserved: the budget counted its
                // pages and its bake together).
                park(&mut st, bake);
            }
            drop(st);
            for &cell in &cells {
                shared.emit(RuntimeEvent::CellPublished {
                    cell,
                    lod,
                    directions: d,
                    error,
                    settled,
                    group: cells.clone(),
                });
            }
            if let Some(ms) = refined {
                shared.emit(RuntimeEvent::ReloadRefined { ms, directions: c.bundle.directions });
            }
        }
        shared.wake.notify_all();
    }
}

/// Bakes `cell`'s punctual layer at `levels` and publishes it (the finest level it then has
/// shown): each level's earlier pixels are replaced, and a stale cell's other levels
/// withdrawn (their shadows predate the change).
fn bake_punctual(shared: &Shared, world: &World, generation: u64, cell: CellId, levels: &[u32]) {
    let t = Instant::now();
    let bakes: Vec<PunctualBake> = levels.iter().map(|&k| PunctualBake::new(world, cell, k)).collect();
    let mut st = shared.lock();
    let need: u64 = levels.iter().map(|&k| punctual_bake_bytes(lod_texels(world, cell, k))).sum();
    st.bake_bytes = st.bake_bytes.saturating_sub(need);
    st.stats.cell_setup_seconds += t.elapsed().as_secs_f64();
    if st.generation != generation {
        // A hot reload replaced the world (and reset what it invalidated).
        st.cells[cell as usize].punctual.busy = false;
        return;
    }
    let p = &mut st.cells[cell as usize].punctual;
    p.busy = false;
    let stale = std::mem::take(&mut p.stale);
    let mut map = (*shared.shown()).clone();
    let mut writer = PageWriter::new(&mut map);
    let top = levels.iter().copied().max().unwrap_or(0);
    p.published.resize(p.published.len().max(top as usize + 1), Vec::new());
    for (k, pixels) in p.published.iter_mut().enumerate() {
        if levels.contains(&(k as u32)) || stale {
            for q in pixels.drain(..) {
                writer.clear(Layer::Punctual, k as u32, q[0], q[1]);
            }
        }
    }
    let mut texels = 0;
    for bake in &bakes {
        let pixels = &mut p.published[bake.lod as usize];
        for (q, e) in bake.pixels() {
            writer.write(Layer::Punctual, bake.lod, q[0], q[1], e);
            pixels.push(q);
        }
        texels = bake.texels.len();
    }
    // The finest level it has now.
    let shown = p.published.iter().rposition(|v| !v.is_empty()).unwrap_or(0) as u32;
    writer.set_cell_lod(Layer::Punctual, cell, shown);
    writer.finish();
    p.shown = shown;
    let s = &mut st.cells[cell as usize];
    for &k in levels {
        let light = map.layer_light(Layer::Punctual, k, &s.punctual.published[k as usize]);
        s.set_light(Layer::Punctual, k, light);
    }
    shared.set_shown(map);
    st.stats.publishes += 1;
    drop(st);
    shared.emit(RuntimeEvent::PunctualPublished { cell, lod: shown, texels, ms: t.elapsed().as_secs_f64() * 1e3 });
    shared.wake.notify_all();
}

/// Puts a bake back between units: in its leader's slot, its cells free for the next unit.
fn park(st: &mut State, bake: Box<CellBake>) {
    let leader = bake.leader();
    for &m in &bake.cells {
        let s = &mut st.cells[m as usize];
        s.busy = false;
        s.baking_directions = bake.directions();
        s.member_of = (m != leader).then_some(leader);
    }
    st.cells[leader as usize].bake = Some(bake);
}

/// Writes a bake's texels and gutter pixels (`values` per texel) into `map`'s bundle layer
/// at its LOD and swaps its cells to it. Returns the pixels written per cell of the bake.
pub fn publish_bake(map: &mut ShownLightmap, bake: &CellBake, values: &[Rgb]) -> Vec<Vec<[u32; 2]>> {
    publish_texels(map, bake, values, &[])
}

/// [`publish_bake`], withdrawing first the pixels `replaced` of the cells' previous bakes at
/// that LOD (a refresh).
fn publish_texels(
    map: &mut ShownLightmap,
    bake: &CellBake,
    values: &[Rgb],
    replaced: &[Vec<[u32; 2]>],
) -> Vec<Vec<[u32; 2]>> {
    let t = &bake.texels;
    let mut writer = PageWriter::new(map);
    for p in replaced.iter().flatten() {
        writer.clear(Layer::Bundles, bake.lod, p[0], p[1]);
    }
    for (i, p) in t.pixel.iter().enumerate() {
        writer.write(Layer::Bundles, bake.lod, p[0], p[1], values[i]);
    }
    for &(g, i) in &t.gutter {
        writer.write(Layer::Bundles, bake.lod, g[0], g[1], values[i as usize]);
    }
    for &c in &bake.cells {
        writer.set_cell_lod(Layer::Bundles, c, bake.lod);
    }
    writer.finish();
    bake.pixels_per_cell()
}

/// Publishes a bake in one new snapshot (every cell of a group at once); `settled`: by the
/// error bound or the most directions, else early (the bake goes on, [`publish_due`]).
/// Returns the milliseconds since the change was seen when this published the last
/// provisional cell of a reload (`reload_refined`).
fn publish(shared: &Shared, st: &mut State, bake: &CellBake, error: f32, settled: bool) -> Option<f64> {
    let values = bake.result();
    let lod = bake.lod as usize;
    let replaced: Vec<Vec<[u32; 2]>> = bake
        .cells
        .iter()
        .map(|&c| st.cells[c as usize].published.get_mut(lod).map(std::mem::take).unwrap_or_default())
        .collect();
    let mut map = (*shared.shown()).clone();
    let pixels = publish_texels(&mut map, bake, &values, &replaced);
    let mut refreshed = 0;
    for (&c, pixels) in bake.cells.iter().zip(pixels) {
        let cell = &mut st.cells[c as usize];
        cell.set_light(Layer::Bundles, bake.lod, map.layer_light(Layer::Bundles, bake.lod, &pixels));
        cell.shown = bake.lod;
        cell.stale = false;
        cell.unsettled = !settled;
        // (A provisional cell's next bake is at LOD 0: `next_lod`.)
        if cell.provisional && bake.lod == 0 {
            cell.provisional = false;
            refreshed += 1;
        }
        cell.history.resize(lod + 1, (0, f32::INFINITY));
        cell.history[lod] = (bake.directions(), error);
        cell.published.resize(lod + 1, Vec::new());
        cell.published[lod] = pixels;
    }
    shared.set_shown(map);
    st.stats.publishes += 1;
    if refreshed == 0 {
        return None;
    }
    let r = st.refining.as_mut()?;
    r.left = r.left.saturating_sub(refreshed);
    if r.left > 0 {
        return None;
    }
    let ms = r.seen_at.elapsed().as_secs_f64() * 1e3;
    st.refining = None;
    Some(ms)
}

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

    fn config() -> RuntimeConfig {
        RuntimeConfig { min_directions: 32, max_directions: 512, error_bound: 0.03, ..RuntimeConfig::default() }
    }

    fn shown(lod: u32, directions: u64) -> ShownNow {
        ShownNow { lod, directions, unsettled: false, stale: false, provisional: false }
    }

    /// A finer level is published early at exactly the shown level's directions, whatever
    /// its error; the error bound still settles it sooner, never before the minimum.
    #[test]
    fn a_finer_level_swaps_at_the_shown_levels_directions() {
        let c = config();
        let from = shown(0, 128);
        assert_eq!(publish_due(&c, 1, from, 124, 0.2), Due::Wait);
        assert_eq!(publish_due(&c, 1, from, 128, 0.2), Due::Early);
        assert_eq!(publish_due(&c, 1, from, 32, 0.02), Due::Settled);
        assert_eq!(publish_due(&c, 1, from, 28, 0.0), Due::Wait, "below the minimum");
        // A shown level with fewer directions than the minimum: the minimum holds.
        assert_eq!(publish_due(&c, 1, shown(0, 16), 28, 0.2), Due::Wait);
        assert_eq!(publish_due(&c, 1, shown(0, 16), 32, 0.2), Due::Early);
        // More than the maximum shown: the maximum settles first.
        assert_eq!(publish_due(&c, 2, shown(1, 1024), 512, 0.2), Due::Settled);
    }

    /// An unsettled level is published again each time its directions double and settled by
    /// the bound or the maximum; a settled level (a stale refresh) or a stale unsettled one
    /// only when settled.
    #[test]
    fn an_unsettled_level_is_republished_as_its_directions_double() {
        let c = config();
        let unsettled = ShownNow { unsettled: true, ..shown(1, 128) };
        assert_eq!(publish_due(&c, 1, unsettled, 252, 0.2), Due::Wait);
        assert_eq!(publish_due(&c, 1, unsettled, 256, 0.2), Due::Early);
        assert_eq!(publish_due(&c, 1, unsettled, 140, 0.02), Due::Settled);
        assert_eq!(publish_due(&c, 1, ShownNow { unsettled: true, ..shown(1, 256) }, 512, 0.2), Due::Settled);
        assert_eq!(publish_due(&c, 1, shown(1, 128), 256, 0.2), Due::Wait, "a refresh of a settled level");
        let stale = ShownNow { stale: true, ..unsettled };
        assert_eq!(publish_due(&c, 1, stale, 256, 0.2), Due::Wait, "a stale level");
        assert_eq!(publish_due(&c, 1, stale, 512, 0.2), Due::Settled);
    }

    /// Replacing a reload's quick LOD 0 takes first light's directions, as before: no early
    /// publish and no error bound.
    #[test]
    fn a_provisional_lod0_waits_for_first_lights_directions() {
        let c = config();
        let provisional = ShownNow { provisional: true, ..shown(0, 32) };
        let full = c.bundle.directions as u64;
        assert_eq!(publish_due(&c, 0, provisional, full - 4, 0.0), Due::Wait);
        assert_eq!(publish_due(&c, 0, provisional, full, 0.5), Due::Settled);
    }

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

    /// The LOD a cell bakes next: an unsettled level is finished before the next, unless the
    /// cell is now wanted coarser.
    #[test]
    fn an_unsettled_cell_bakes_its_shown_lod_next() {
        let cell = |shown, target, unsettled| CellState { shown, target, unsettled, ..CellState::default() };
        assert_eq!(next_lod(&cell(1, 3, true)), Some(1));
        assert_eq!(next_lod(&cell(1, 1, true)), Some(1));
        assert_eq!(next_lod(&cell(1, 0, true)), None);
        assert_eq!(next_lod(&cell(1, 3, false)), Some(2));
        assert_eq!(next_lod(&cell(1, 1, false)), None);
    }
}
