//! The runtime's shared state and its threads: first light, the workers that refine cells
//! (most urgent first, within the memory budget), publishing, eviction and the stats clock.
//!
//! Everything a decision reads is in one mutex ([`State`]: the world, the cell table, the
//! camera, memory accounting), held only to decide and to publish, never while tracing.
//! The shown light map is a separate snapshot pointer, swapped whole by each publish.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, RwLock};
use std::time::{Duration, Instant};

use crossbeam_channel::Sender;

use super::cell_bake::{CellBake, filter_within_charts};
use super::policy::{CameraView, CellView, cell_view, priority, target_lod};
use super::shown::{PageWriter, ShownLightmap};
use super::world::World;
use super::{RuntimeConfig, RuntimeEvent, RuntimeStats, TimedEvent};
use crate::atlas::lookup::TexelTable;
use crate::bake::bundle::{BundleLodStats, bake_lod};
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
    pub bake: Option<Box<CellBake>>,
    pub busy: bool,
    /// Directions traced by the bake in progress (also while a worker holds it).
    pub baking_directions: u64,
    /// Its light is older than the scene (hot reload): refresh it when nothing is more urgent.
    pub stale: bool,
    /// Its LOD 0 is a hot reload's quick re-bake (fewer directions than first light): re-bake
    /// LOD 0 with first light's directions before anything else.
    pub provisional: bool,
    /// Directions and error of each shown level (index = LOD).
    pub history: Vec<(u64, f32)>,
    /// Pixels written at each LOD (index = LOD), to withdraw or replace them.
    pub published: Vec<Vec<[u32; 2]>>,
}

pub(super) struct State {
    pub world: Arc<World>,
    /// Incremented by every hot reload: bakes made for an older world are dropped.
    pub generation: u64,
    pub cells: Vec<CellState>,
    pub camera: Option<CameraView>,
    pub paused: bool,
    /// A hot reload is re-baking LOD 0 of the cells it invalidated: workers wait.
    pub relighting: bool,
    /// Provisional cells still to re-bake at full quality, since the last reload.
    pub refining: Option<Refining>,
    pub first_light: bool,
    pub failed: Option<String>,
    pub bake_bytes: u64,
    /// Texel-samples traced since the last stats event.
    pub window_samples: u64,
    pub stats: RuntimeStats,
}

impl State {
    pub fn new(world: Arc<World>, paused: bool) -> State {
        State {
            cells: (0..world.grid.len()).map(|_| CellState::default()).collect(),
            world,
            generation: 0,
            camera: None,
            paused,
            relighting: false,
            refining: None,
            first_light: false,
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
        *self.shown.write().unwrap_or_else(|e| e.into_inner()) = Arc::new(map);
    }

    pub fn seed(&self) -> u64 {
        self.config.bundle.seed
    }
}

/// Recomputes every non-empty cell's view and target LOD for the current camera.
pub(super) fn update_views(shared: &Shared, st: &mut State) {
    let Some(camera) = st.camera else { return };
    let world = st.world.clone();
    for c in world.non_empty_cells() {
        let view = cell_view(&camera, &world.grid, c);
        let cell = &mut st.cells[c as usize];
        cell.view = Some(view);
        cell.target = target_lod(&camera, view, world.atlas.texel_size, shared.config.texel_pixels, world.lods);
    }
}

pub(super) fn current_stats(shared: &Shared, st: &mut State) -> RuntimeStats {
    let world = &st.world;
    let shown = shared.shown();
    let mut s = st.stats.clone();
    s.cells_per_lod = vec![0; world.lods as usize];
    s.queue = 0;
    s.baking = 0;
    for c in world.non_empty_cells() {
        let cell = &st.cells[c as usize];
        s.cells_per_lod[(cell.shown as usize).min(world.lods as usize - 1)] += 1;
        s.queue += usize::from(cell.target > cell.shown || cell.stale || cell.provisional);
        s.baking += usize::from(cell.bake.is_some() || cell.busy);
    }
    s.page_bytes = shown.page_bytes() as u64;
    s.bake_bytes = st.bake_bytes;
    s.fixed_bytes = fixed_bytes(world);
    s.resident_bytes = s.page_bytes + s.bake_bytes + s.fixed_bytes;
    s.dropped_events = shared.dropped.load(Ordering::Relaxed);
    s
}

/// Bytes of what the runtime holds for the scene whatever the camera does: geometry, atlas,
/// BVH, the LOD-0 texels and the grid's triangle lists.
fn fixed_bytes(world: &World) -> u64 {
    let tris = world.geom.len() as u64;
    let lod0 = world.lod0.len() as u64 * (4 + 4 + 12 * 4 + 4) + world.lod0.slot.len() as u64 * 4;
    tris * (36 + 12 + 4 + 4 + 4 + 4) // geometry
        + world.atlas.faces.len() as u64 * 36
        + world.bvh.memory_bytes() as u64
        + lod0
        + world.cell_triangles.triangles.len() as u64 * 4
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
    mut map: ShownLightmap,
    cancel: &AtomicBool,
) -> Result<(ShownLightmap, PixelLists, BundleLodStats), String> {
    let baked = bake_lod(&world.bundle, &world.bvh, backend, &world.lod0, None, threads, &NoProgress, cancel)
        .map_err(|e| e.to_string())?;
    if baked.stats.pass.unplanned_directions > 0 {
        return Err(format!("{} bundle directions could not be planned", baked.stats.pass.unplanned_directions));
    }
    let lod0 = &world.lod0;
    let w = lod0.width;
    let pixels: Vec<[u32; 2]> = lod0.pixel.iter().map(|&p| [p % w, p / w]).collect();
    let table = TexelTable::of_map(lod0);
    let direct = &baked.punctual;
    let noisy: Vec<Rgb> = baked.irradiance.iter().zip(direct).map(|(e, d)| *e - *d).collect();
    let values: Vec<Rgb> =
        filter_within_charts(&pixels, |_| &table, &noisy).into_iter().zip(direct).map(|(n, d)| n + *d).collect();
    let cell_of: Vec<CellId> = lod0.position.iter().map(|&p| world.grid.cell_of(p)).collect();
    let mut owned = vec![Vec::new(); world.grid.len()];
    let mut writer = PageWriter::new(&mut map);
    for (i, p) in pixels.iter().enumerate() {
        writer.write(0, p[0], p[1], values[i]);
        owned[cell_of[i] as usize].push(*p);
    }
    for &(g, t) in &lod0.gutter {
        let p = [g % w, g / w];
        writer.write(0, p[0], p[1], values[t as usize]);
        owned[cell_of[t as usize] as usize].push(p);
    }
    writer.finish();
    Ok((map, owned, baked.stats))
}

/// An empty shown map for `world` (nothing published yet).
pub fn empty_shown(world: &World) -> ShownLightmap {
    let blend_band = (2.0 * world.atlas.texel_size).min(world.grid.cell_size * 0.25);
    ShownLightmap::new(world.grid, world.atlas.width, world.atlas.height, world.lods, blend_band)
}

/// Bakes LOD 0 of the whole scene on every core and publishes it (first light).
pub(super) fn first_light(shared: &Shared) {
    let world = shared.lock().world.clone();
    let threads = shared.config.threads();
    let result = (shared.make_backend)(&world.bundle, threads).map_err(|e| e.to_string()).and_then(|mut backend| {
        bake_first_light(&world, backend.as_mut(), threads, empty_shown(&world), &shared.shutdown)
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
    let mut st = shared.lock();
    shared.set_shown(map);
    for (c, pixels) in owned.into_iter().enumerate() {
        let cell = &mut st.cells[c];
        cell.history = vec![(stats.directions, f32::NAN)];
        cell.published = vec![pixels];
    }
    st.first_light = true;
    st.stats.first_light_seconds = Some(shared.started.elapsed().as_secs_f64());
    st.stats.directions_traced += stats.directions;
    update_views(shared, &mut st);
    drop(st);
    shared.wake.notify_all();
    shared.emit(RuntimeEvent::FirstLight { texels: world.lod0.len(), directions: shared.config.bundle.directions });
}

/// What a worker takes: a cell, the LOD to bake it at, and its bake if one is parked.
struct Job {
    world: Arc<World>,
    generation: u64,
    cell: CellId,
    lod: u32,
    bake: Option<Box<CellBake>>,
}

/// The LOD a cell's next bake is at: LOD 0 again for a provisional cell (its quick re-bake
/// is replaced before it is refined on), the next finer one below its target, else (a
/// stale cell at its target) its shown LOD again, to refresh it.
fn next_lod(s: &CellState) -> Option<u32> {
    if s.provisional {
        Some(0)
    } else if s.target > s.shown {
        Some(s.shown + 1)
    } else if s.stale {
        Some(s.shown)
    } else {
        None
    }
}

/// The next job: the most urgent cell below its target (or stale), not being worked on, with
/// room for its bake within the memory budget (made by evicting what matters less,
/// [`make_room`]); `None` when nothing is to be done or nothing fits.
fn pick(shared: &Shared, st: &mut State) -> Option<Job> {
    let world = st.world.clone();
    let key = |st: &State, c: CellId| {
        let s = &st.cells[c as usize];
        let view = s.view.unwrap_or(CellView { distance: f32::MAX, in_frustum: false });
        // A reload's provisional cells first (the change is shown at full quality soonest),
        // refinement before refreshing stale light, then the policy's order.
        (!s.provisional, s.target <= s.shown, priority(view, s.shown, false), c)
    };
    let c = world
        .non_empty_cells()
        .filter(|&c| {
            let s = &st.cells[c as usize];
            !s.busy && s.view.is_some() && next_lod(s).is_some()
        })
        .min_by_key(|&c| key(st, c))?;
    let lod = next_lod(&st.cells[c as usize])?;
    // A parked bake of another level (the cell was evicted or refreshed meanwhile) is dropped.
    if let Some(b) = &st.cells[c as usize].bake
        && b.lod != lod
    {
        let bytes = b.bytes() as u64;
        st.cells[c as usize].bake = None;
        st.cells[c as usize].baking_directions = 0;
        st.bake_bytes -= bytes;
    }
    if st.cells[c as usize].bake.is_none() && !make_room(shared, st, c, bake_estimate(&world, c, lod)) {
        return None;
    }
    let s = &mut st.cells[c as usize];
    s.busy = true;
    Some(Job { world, generation: st.generation, cell: c, lod, bake: s.bake.take() })
}

/// Bytes a bake of `cell` at `lod` will hold while it runs and its pages once published, from
/// the cell's LOD-0 texel count (4^lod times as many texels at LOD `lod`).
fn bake_estimate(world: &World, cell: CellId, lod: u32) -> u64 {
    let texels = world.lod0_texels[cell as usize] as u64 * (1u64 << (2 * lod));
    texels * (BAKE_BYTES_PER_TEXEL + PAGE_BYTES_PER_TEXEL)
}

/// A cell bake holds its texels (~68 B), sums per lane (28 B × lanes, 2 by default, plus the
/// reduced copy), the running totals (56 B), sources and variance (~40 B): ~250 B a texel.
const BAKE_BYTES_PER_TEXEL: u64 = 256;
/// A published texel is 16 B in a page; pages are partly filled (charts, other cells).
const PAGE_BYTES_PER_TEXEL: u64 = 32;

/// Bytes counted against the budget: shown pages and bakes in progress.
fn budgeted_bytes(shared: &Shared, st: &State) -> u64 {
    shared.shown().page_bytes() as u64 + st.bake_bytes
}

/// Frees memory until `need` more bytes fit the budget, taking from what matters less than
/// `for_cell`: first parked bakes and finest levels of cells shown finer than they need, then
/// those of cells farther from the camera than `for_cell`, farthest first. Returns whether
/// it fits.
fn make_room(shared: &Shared, st: &mut State, for_cell: CellId, need: u64) -> bool {
    let budget = shared.config.memory_budget;
    let world = st.world.clone();
    let distance = |st: &State, c: CellId| st.cells[c as usize].view.map_or(f32::MAX, |v| v.distance);
    let mine = distance(st, for_cell);
    while budgeted_bytes(shared, st) + need > budget {
        // The cell whose memory matters least: beyond its target first, then farthest.
        let victim = world
            .non_empty_cells()
            .filter(|&c| {
                let s = &st.cells[c as usize];
                c != for_cell
                    && !s.busy
                    && (s.shown > 0 || s.bake.is_some())
                    && (s.shown > s.target || distance(st, c) > mine)
            })
            .max_by(|&a, &b| {
                let over = |c: CellId| st.cells[c as usize].shown > st.cells[c as usize].target;
                (over(a), distance(st, a)).partial_cmp(&(over(b), distance(st, b))).unwrap_or(std::cmp::Ordering::Equal)
            });
        let Some(victim) = victim else { return false };
        let s = &mut st.cells[victim as usize];
        if let Some(bake) = s.bake.take() {
            // A parked bake's work is lost; it would be the first thing rebuilt if needed.
            s.baking_directions = 0;
            st.bake_bytes -= bake.bytes() as u64;
            continue;
        }
        evict(shared, st, victim);
    }
    true
}

/// Withdraws a cell's finest shown level (its pixels at that LOD) and shows the next coarser.
fn evict(shared: &Shared, st: &mut State, cell: CellId) {
    let s = &mut st.cells[cell as usize];
    let lod = s.shown;
    if lod == 0 {
        return;
    }
    let pixels = std::mem::take(&mut s.published[lod as usize]);
    s.shown = lod - 1;
    s.history.truncate(lod as usize);
    let mut map = (*shared.shown()).clone();
    let mut writer = PageWriter::new(&mut map);
    for p in &pixels {
        writer.clear(lod, p[0], p[1]);
    }
    writer.set_cell_lod(cell, lod - 1);
    writer.finish();
    shared.set_shown(map);
    st.stats.evictions += 1;
    shared.emit(RuntimeEvent::CellEvicted { cell, lod });
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
                if st.first_light && !st.paused && !st.relighting && st.failed.is_none() {
                    if let Some(job) = pick(shared, &mut st) {
                        break job;
                    }
                }
                st = shared.wake.wait_timeout(st, Duration::from_millis(200)).unwrap_or_else(|e| e.into_inner()).0;
            }
        };
        let Job { world, generation, cell, lod, bake } = job;
        if backend.as_ref().is_none_or(|(g, _)| *g != generation) {
            match (shared.make_backend)(&world.bundle, 1) {
                Ok(b) => backend = Some((generation, b)),
                Err(e) => {
                    shared.emit(RuntimeEvent::Failed { error: e.to_string() });
                    shared.lock().cells[cell as usize].busy = false;
                    return;
                }
            }
        }
        let Some((_, backend)) = backend.as_mut() else { return };
        let mut bake = match bake {
            Some(b) => b,
            None => {
                let t = Instant::now();
                let b = Box::new(CellBake::new(&world, cell, lod, shared.shown(), shared.seed(), 1));
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
            if let Some(s) = st.cells.get_mut(cell as usize) {
                s.busy = false;
            }
            continue;
        }
        let u = match unit {
            Ok(u) => u,
            Err(_) => {
                // Cancelled (shutting down): the bake keeps what it had before the unit.
                let s = &mut st.cells[cell as usize];
                s.busy = false;
                s.bake = Some(bake);
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
        let ready = if bake.lod == 0 && st.cells[cell as usize].provisional {
            // Replacing a reload's quick LOD 0: with first light's directions, as LOD 0 is
            // everywhere else.
            d >= c.bundle.directions as u64
        } else {
            d >= c.max_directions as u64 || (d >= c.min_directions as u64 && error <= c.error_bound)
        };
        if ready {
            st.bake_bytes -= bake.bytes() as u64;
            let refined = publish(shared, &mut st, &bake, error);
            let s = &mut st.cells[cell as usize];
            s.busy = false;
            s.baking_directions = 0;
            drop(st);
            shared.emit(RuntimeEvent::CellPublished { cell, lod: bake.lod, directions: d, error });
            if let Some(ms) = refined {
                shared.emit(RuntimeEvent::ReloadRefined { ms, directions: c.bundle.directions });
            }
        } else {
            let s = &mut st.cells[cell as usize];
            s.busy = false;
            s.baking_directions = bake.directions();
            s.bake = Some(bake);
        }
        shared.wake.notify_all();
    }
}

/// Writes a converged bake's texels and gutter pixels (`values` per texel) into `map` at
/// its LOD and swaps the cell to it. Returns the pixels written.
pub fn publish_bake(map: &mut ShownLightmap, bake: &CellBake, values: &[Rgb]) -> Vec<[u32; 2]> {
    publish_texels(map, bake, values, &[])
}

/// [`publish_bake`], withdrawing first the pixels `replaced` of the cell's previous bake at
/// that LOD (a refresh).
fn publish_texels(map: &mut ShownLightmap, bake: &CellBake, values: &[Rgb], replaced: &[[u32; 2]]) -> Vec<[u32; 2]> {
    let t = &bake.texels;
    let mut writer = PageWriter::new(map);
    for p in replaced {
        writer.clear(bake.lod, p[0], p[1]);
    }
    let mut pixels = Vec::with_capacity(t.len() + t.gutter.len());
    for (i, p) in t.pixel.iter().enumerate() {
        writer.write(bake.lod, p[0], p[1], values[i]);
        pixels.push(*p);
    }
    for &(g, i) in &t.gutter {
        writer.write(bake.lod, g[0], g[1], values[i as usize]);
        pixels.push(g);
    }
    writer.set_cell_lod(bake.cell, bake.lod);
    writer.finish();
    pixels
}

/// Publishes a converged bake in one new snapshot. Returns the milliseconds since the change
/// was seen when this was the last provisional cell of a reload (`reload_refined`).
fn publish(shared: &Shared, st: &mut State, bake: &CellBake, error: f32) -> Option<f64> {
    let values = bake.result();
    let lod = bake.lod as usize;
    let cell = &mut st.cells[bake.cell as usize];
    let replaced = cell.published.get_mut(lod).map(std::mem::take).unwrap_or_default();
    let mut map = (*shared.shown()).clone();
    let pixels = publish_texels(&mut map, bake, &values, &replaced);
    shared.set_shown(map);
    cell.shown = bake.lod;
    cell.stale = false;
    // (A provisional cell's next bake is at LOD 0: `next_lod`.)
    let was_provisional = cell.provisional && bake.lod == 0;
    if was_provisional {
        cell.provisional = false;
    }
    cell.history.resize(lod + 1, (0, f32::INFINITY));
    cell.history[lod] = (bake.directions(), error);
    cell.published.resize(lod + 1, Vec::new());
    cell.published[lod] = pixels;
    st.stats.publishes += 1;
    if !was_provisional {
        return None;
    }
    let r = st.refining.as_mut()?;
    r.left = r.left.saturating_sub(1);
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
        st.stats.texel_samples_per_second = st.window_samples as f64 / seconds;
        st.window_samples = 0;
        let stats = current_stats(shared, &mut st);
        drop(st);
        shared.emit(RuntimeEvent::Stats(stats));
    }
}
