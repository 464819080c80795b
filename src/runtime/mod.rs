//! The live runtime (2017 thesis, 3.3.2): LOD 0 everywhere at first light, then the cells
//! near the camera refined in the background and swapped to the next LOD once converged.
//!
//! Threads and what each owns (docs/ARCHITECTURE.md has the picture):
//! * the caller's thread (a front end) owns the [`Runtime`]: it sets the camera, reads
//!   events, snapshots of the shown light map ([`Runtime::shown`]) and the cell table;
//! * a startup thread bakes LOD 0 of the whole scene on every core, publishes it (first
//!   light), then becomes one of the workers;
//! * worker threads (one per core) each own a bundle backend; they take the most urgent
//!   cell ([`policy::priority`]), trace one unit of its bake (a few directions, cancellable
//!   between tiles) and put it back; a bake that has converged is filtered and published
//!   whole (copy-on-write pages: readers see the cell before or after, never half);
//! * a clock thread emits a stats event once a second.
//!
//! Shared state is one mutex (the cell table, the camera, memory accounting) and one
//! snapshot pointer (the shown light map), never held during tracing.

pub mod cell_bake;
pub mod policy;
pub mod shown;
pub mod source;
pub mod world;

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, RwLock};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender};
use serde::Serialize;

use crate::atlas::lookup::TexelTable;
use crate::atlas::{Atlas, AtlasConfig, AtlasError};
use crate::bake::bundle::{BundleLodStats, bake_lod};
use crate::bundle::{BackendProvider, BundleConfig, BundleConfigError};
use crate::grid::{CellId, GridError};
use crate::progress::NoProgress;
use crate::scene::{Rgb, Scene, SceneGeometry};
use cell_bake::{CellBake, filter_within_charts};
use policy::{CellView, cell_view, priority, target_lod};
use shown::{PageWriter, ShownLightmap};
use world::World;

pub use policy::CameraView;

/// Most LOD levels (LOD 0 … 7: 128× the LOD-0 resolution).
pub const MAX_LODS: u32 = 8;

/// The runtime's settings. Defaults are the runtime's own: LOD 0 small enough for first
/// light within a second on the bundled rooms, and enough levels for ~2 cm texels near the
/// camera, memory allowing.
#[derive(Clone, Debug, Serialize)]
pub struct RuntimeConfig {
    /// LOD-0 layout (texel size or budget).
    pub atlas: AtlasConfig,
    /// Bundle parameters; `directions` is the LOD-0 (first light) bake's direction count.
    pub bundle: BundleConfig,
    /// LOD levels (LOD 0 … lods − 1); `None`: enough for [`FINEST_TEXEL`] texels.
    pub lods: Option<u32>,
    /// Grid cell side, metres; `None`: from the scene (a few thousand non-empty cells).
    pub cell_size: Option<f32>,
    /// Bytes the shown pages and the bakes in progress may hold; the finest pages of the
    /// cells farthest from the camera are evicted beyond it.
    pub memory_budget: u64,
    /// A cell swaps to the next LOD when it has at least `min_directions` and its estimated
    /// relative error is at most `error_bound`, or when it has `max_directions`.
    pub min_directions: u32,
    pub max_directions: u32,
    pub error_bound: f32,
    /// Directions per unit of work (one batch of a cell bake).
    pub unit_directions: u32,
    /// Screen pixels a texel may cover before the cell wants a finer LOD.
    pub texel_pixels: f32,
    /// Worker threads; `None`: every core.
    pub threads: Option<usize>,
    /// Start with refinement paused (first light still bakes); see [`Runtime::set_paused`].
    pub start_paused: bool,
}

/// Texel size the default LOD count aims at near the camera (metres).
pub const FINEST_TEXEL: f32 = 0.02;

impl Default for RuntimeConfig {
    fn default() -> Self {
        RuntimeConfig {
            atlas: AtlasConfig { texel_budget: 40_000, ..AtlasConfig::default() },
            bundle: BundleConfig { directions: 128, ..BundleConfig::default() },
            lods: None,
            cell_size: None,
            memory_budget: default_memory_budget(),
            min_directions: 32,
            max_directions: 512,
            error_bound: 0.03,
            unit_directions: 4,
            texel_pixels: 2.0,
            threads: None,
            start_paused: false,
        }
    }
}

/// A quarter of the machine's memory, at most 4 GiB (1 GiB where it cannot be read).
pub fn default_memory_budget() -> u64 {
    let total = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|m| m.lines().find(|l| l.starts_with("MemTotal:"))?.split_whitespace().nth(1)?.parse::<u64>().ok());
    match total {
        Some(kib) => (kib * 1024 / 4).min(4 << 30),
        None => 1 << 30,
    }
}

impl RuntimeConfig {
    /// LOD levels for an LOD-0 texel of `texel0` metres.
    pub fn levels_for(&self, texel0: f32) -> u32 {
        match self.lods {
            Some(k) => k.clamp(1, MAX_LODS),
            None => {
                let k = (texel0 / FINEST_TEXEL).log2().ceil();
                (if k.is_finite() { k.max(0.0) as u32 } else { 0 } + 1).min(MAX_LODS)
            }
        }
    }

    pub fn threads(&self) -> usize {
        self.threads.unwrap_or_else(crate::parallel::available_threads).max(1)
    }

    pub fn validate(&self) -> Result<(), RuntimeError> {
        self.bundle.validate()?;
        let bad = |what: &str, why: String| Err(RuntimeError::BadOption(format!("{what} {why}")));
        if let Some(k) = self.lods
            && !(1..=MAX_LODS).contains(&k)
        {
            return bad("--lods", format!("must be between 1 and {MAX_LODS}, got {k}"));
        }
        if self.bundle.directions == 0 || self.min_directions == 0 || self.unit_directions == 0 {
            return bad("--samples, --min-directions and the unit size", "must be at least 1".into());
        }
        if self.max_directions < self.min_directions {
            return bad("--max-directions", format!("must be at least --min-directions ({})", self.min_directions));
        }
        if !(self.error_bound.is_finite() && self.error_bound > 0.0) {
            return bad("--error-bound", format!("must be a positive number, got {}", self.error_bound));
        }
        if !(self.texel_pixels.is_finite() && self.texel_pixels > 0.0) {
            return bad("the texel size on screen", format!("must be positive, got {}", self.texel_pixels));
        }
        if self.memory_budget < 1 << 20 {
            return bad("--memory-budget", format!("must be at least 1 MiB, got {} bytes", self.memory_budget));
        }
        if self.threads == Some(0) {
            return bad("--threads", "must be at least 1".into());
        }
        Ok(())
    }
}

#[derive(Debug, thiserror::Error)]
pub enum RuntimeError {
    #[error(transparent)]
    Atlas(#[from] AtlasError),
    #[error(transparent)]
    Grid(#[from] GridError),
    #[error(transparent)]
    Bundle(#[from] BundleConfigError),
    #[error("{0}")]
    BadOption(String),
    #[error("the bundle backend is unavailable: {0}")]
    Backend(String),
    #[error("the first-light bake failed: {0}")]
    FirstLight(String),
    #[error("no first light within {0:?}")]
    Timeout(Duration),
    #[error("cannot start a runtime thread: {0}")]
    Thread(std::io::Error),
    #[error("{0} runtime thread(s) panicked (a bug in livebake)")]
    WorkerPanicked(usize),
}

/// What the runtime tells its front ends.
#[derive(Clone, Debug, Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum RuntimeEvent {
    /// LOD 0 is published everywhere.
    FirstLight {
        texels: usize,
        directions: u32,
    },
    /// A cell swapped to a finer LOD.
    CellPublished {
        cell: CellId,
        lod: u32,
        directions: u64,
        error: f32,
    },
    /// A cell's finest LOD was dropped to stay within the memory budget.
    CellEvicted {
        cell: CellId,
        lod: u32,
    },
    Stats(RuntimeStats),
    /// The runtime stopped working (first light failed, or a worker could not start).
    Failed {
        error: String,
    },
}

/// An event and when it happened (seconds since [`Runtime::start`]).
#[derive(Clone, Debug)]
pub struct TimedEvent {
    pub t: f64,
    pub event: RuntimeEvent,
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct RuntimeStats {
    /// Non-empty cells shown at each LOD.
    pub cells_per_lod: Vec<usize>,
    /// Non-empty cells below their target LOD.
    pub queue: usize,
    /// Cells with a bake in progress.
    pub baking: usize,
    /// Texels × directions traced per second, over the last stats interval.
    pub texel_samples_per_second: f64,
    /// Bytes: shown pages, bakes in progress, and what the scene's fixed structures hold.
    pub page_bytes: u64,
    pub bake_bytes: u64,
    pub fixed_bytes: u64,
    pub resident_bytes: u64,
    pub directions_traced: u64,
    pub units: u64,
    pub publishes: u64,
    pub evictions: u64,
    /// Events dropped because nobody read the channel.
    pub dropped_events: u64,
    pub first_light_seconds: Option<f64>,
    /// Bundle-pass counters and phase times summed over every unit of refinement.
    pub pass: crate::bundle::stats::PassStats,
    /// Seconds spent making cell texel maps and their punctual light.
    pub cell_setup_seconds: f64,
}

/// A cell as front ends see it.
#[derive(Clone, Debug, Serialize)]
pub struct CellInfo {
    pub cell: CellId,
    pub min: [f32; 3],
    pub max: [f32; 3],
    pub shown_lod: u32,
    /// LOD being baked, if any, and the directions it has so far.
    pub baking_lod: Option<u32>,
    pub baking_directions: u64,
    /// A worker is tracing a unit of it now.
    pub working: bool,
    /// Directions and estimated error of the shown LOD.
    pub directions: u64,
    pub error: f32,
    /// LOD-0 texels (0: an empty cell).
    pub texels: u32,
    pub target_lod: u32,
}

/// Per cell, in the state mutex.
#[derive(Default)]
struct CellState {
    shown: u32,
    target: u32,
    view: Option<CellView>,
    bake: Option<Box<CellBake>>,
    busy: bool,
    /// Directions traced by the bake in progress (also while a worker holds it).
    baking_directions: u64,
    /// Directions and error of each shown level (index = LOD).
    history: Vec<(u64, f32)>,
    /// Pixels written at each LOD ≥ 1 (index = LOD), to withdraw them on eviction.
    published: Vec<Vec<[u32; 2]>>,
}

struct State {
    cells: Vec<CellState>,
    camera: Option<CameraView>,
    paused: bool,
    first_light: bool,
    failed: Option<String>,
    bake_bytes: u64,
    /// Texel-samples traced since the last stats event.
    window_samples: u64,
    stats: RuntimeStats,
}

struct Shared {
    world: Arc<World>,
    config: RuntimeConfig,
    state: Mutex<State>,
    wake: Condvar,
    shown: RwLock<Arc<ShownLightmap>>,
    events: Sender<TimedEvent>,
    dropped: AtomicU64,
    shutdown: AtomicBool,
    started: Instant,
    seed: u64,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn emit(&self, event: RuntimeEvent) {
        let e = TimedEvent { t: self.started.elapsed().as_secs_f64(), event };
        if self.events.try_send(e).is_err() {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    fn shown(&self) -> Arc<ShownLightmap> {
        self.shown.read().unwrap_or_else(|e| e.into_inner()).clone()
    }

    fn set_shown(&self, map: ShownLightmap) {
        *self.shown.write().unwrap_or_else(|e| e.into_inner()) = Arc::new(map);
    }
}

/// The live runtime over one scene, generic over how bundles are traced.
pub struct Runtime {
    shared: Arc<Shared>,
    events: Receiver<TimedEvent>,
    threads: Vec<JoinHandle<()>>,
}

/// Capacity of the event channel; events beyond it are dropped (and counted) rather than
/// letting a front end that never reads grow memory without bound.
const EVENT_CAPACITY: usize = 1 << 16;

impl Runtime {
    /// Builds the scene's atlas, grid and LOD-0 texels (errors are returned here), then bakes
    /// LOD 0 in the background ([`RuntimeEvent::FirstLight`] when it is shown) and refines
    /// from there.
    pub fn start<P: BackendProvider>(
        scene: Arc<Scene>,
        config: RuntimeConfig,
        provider: Arc<P>,
    ) -> Result<Runtime, RuntimeError> {
        config.validate()?;
        let started = Instant::now();
        let geom = Arc::new(SceneGeometry::new(&scene));
        let atlas = Arc::new(Atlas::build(&scene, &geom, &config.atlas)?);
        let world = Arc::new(World::new(scene, geom, atlas, &config)?);
        let (tx, rx) = crossbeam_channel::bounded(EVENT_CAPACITY);
        let shown = empty_shown(&world);
        let cells = (0..world.grid.len()).map(|_| CellState::default()).collect();
        let shared = Arc::new(Shared {
            seed: config.bundle.seed,
            state: Mutex::new(State {
                cells,
                camera: None,
                paused: config.start_paused,
                first_light: false,
                failed: None,
                bake_bytes: 0,
                window_samples: 0,
                stats: RuntimeStats::default(),
            }),
            config,
            world,
            wake: Condvar::new(),
            shown: RwLock::new(Arc::new(shown)),
            events: tx,
            dropped: AtomicU64::new(0),
            shutdown: AtomicBool::new(false),
            started,
        });
        let mut runtime = Runtime { shared: shared.clone(), events: rx, threads: Vec::new() };
        let workers = shared.config.threads();
        for w in 0..workers {
            let (shared, provider) = (shared.clone(), provider.clone());
            let handle = std::thread::Builder::new()
                .name(format!("livebake-worker-{w}"))
                .spawn(move || {
                    if w == 0 {
                        first_light(&shared, provider.as_ref());
                    }
                    worker(&shared, provider.as_ref());
                })
                .map_err(RuntimeError::Thread)?;
            runtime.threads.push(handle);
        }
        let clock = shared.clone();
        let handle = std::thread::Builder::new()
            .name("livebake-clock".into())
            .spawn(move || clock_thread(&clock))
            .map_err(RuntimeError::Thread)?;
        runtime.threads.push(handle);
        Ok(runtime)
    }

    /// The camera the runtime refines for. Accumulated work is kept when it moves; only the
    /// order of what comes next changes.
    pub fn set_camera(&self, camera: CameraView) {
        if !camera.is_valid() {
            tracing::warn!("ignoring an invalid camera: {camera:?}");
            return;
        }
        let mut st = self.shared.lock();
        st.camera = Some(camera);
        update_views(&self.shared, &mut st);
        drop(st);
        self.shared.wake.notify_all();
    }

    /// Pauses or resumes refinement (the first-light bake is not paused).
    pub fn set_paused(&self, paused: bool) {
        self.shared.lock().paused = paused;
        self.shared.wake.notify_all();
    }

    pub fn events(&self) -> &Receiver<TimedEvent> {
        &self.events
    }

    /// The shown light map now (an immutable snapshot).
    pub fn shown(&self) -> Arc<ShownLightmap> {
        self.shared.shown()
    }

    pub fn world(&self) -> &Arc<World> {
        &self.shared.world
    }

    pub fn config(&self) -> &RuntimeConfig {
        &self.shared.config
    }

    /// Seconds since [`Runtime::start`].
    pub fn elapsed(&self) -> f64 {
        self.shared.started.elapsed().as_secs_f64()
    }

    /// Whether LOD 0 has been published.
    pub fn has_first_light(&self) -> bool {
        self.shared.lock().first_light
    }

    /// Blocks until first light (or failure), at most `timeout`.
    pub fn wait_first_light(&self, timeout: Duration) -> Result<(), RuntimeError> {
        let deadline = Instant::now() + timeout;
        let mut st = self.shared.lock();
        loop {
            if let Some(e) = &st.failed {
                return Err(RuntimeError::FirstLight(e.clone()));
            }
            if st.first_light {
                return Ok(());
            }
            let now = Instant::now();
            if now >= deadline {
                return Err(RuntimeError::Timeout(timeout));
            }
            st = self.shared.wake.wait_timeout(st, deadline - now).unwrap_or_else(|e| e.into_inner()).0;
        }
    }

    /// The cell table (non-empty cells).
    pub fn cells(&self) -> Vec<CellInfo> {
        let st = self.shared.lock();
        let world = &self.shared.world;
        world
            .non_empty_cells()
            .map(|c| {
                let s = &st.cells[c as usize];
                let (lo, hi) = world.grid.bounds(c);
                let (directions, error) = s.history.get(s.shown as usize).copied().unwrap_or((0, f32::INFINITY));
                CellInfo {
                    cell: c,
                    min: lo.to_array(),
                    max: hi.to_array(),
                    shown_lod: s.shown,
                    baking_lod: s.bake.as_ref().map(|b| b.lod).or(if s.busy { Some(s.shown + 1) } else { None }),
                    baking_directions: s.baking_directions,
                    working: s.busy,
                    directions,
                    error,
                    texels: world.lod0_texels[c as usize],
                    target_lod: s.target,
                }
            })
            .collect()
    }

    pub fn stats(&self) -> RuntimeStats {
        let mut st = self.shared.lock();
        current_stats(&self.shared, &mut st)
    }

    /// Stops every thread; work in flight is cancelled at the next tile boundary (its partial
    /// sums are dropped). Reports a worker that panicked (a bug).
    pub fn shutdown(mut self) -> Result<(), RuntimeError> {
        match self.stop() {
            0 => Ok(()),
            n => Err(RuntimeError::WorkerPanicked(n)),
        }
    }

    /// Stops and joins every thread; returns how many had panicked.
    fn stop(&mut self) -> usize {
        self.shared.shutdown.store(true, Ordering::SeqCst);
        self.shared.wake.notify_all();
        // A panic is a bug; the panic hook reported it. Shutting down goes on for the others.
        self.threads.drain(..).map(|h| h.join()).filter(Result::is_err).count()
    }
}

impl Drop for Runtime {
    fn drop(&mut self) {
        if self.stop() > 0 {
            tracing::error!("a runtime worker panicked");
        }
    }
}

/// Recomputes every non-empty cell's view and target LOD for the current camera.
fn update_views(shared: &Shared, st: &mut State) {
    let Some(camera) = st.camera else { return };
    let world = &shared.world;
    let config = &shared.config;
    for c in world.non_empty_cells() {
        let view = cell_view(&camera, &world.grid, c);
        let cell = &mut st.cells[c as usize];
        cell.view = Some(view);
        cell.target = target_lod(&camera, view, world.atlas.texel_size, config.texel_pixels, world.lods);
    }
}

fn current_stats(shared: &Shared, st: &mut State) -> RuntimeStats {
    let world = &shared.world;
    let shown = shared.shown();
    let mut s = st.stats.clone();
    s.cells_per_lod = vec![0; world.lods as usize];
    s.queue = 0;
    s.baking = 0;
    for c in world.non_empty_cells() {
        let cell = &st.cells[c as usize];
        s.cells_per_lod[cell.shown as usize] += 1;
        s.queue += usize::from(cell.target > cell.shown);
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

/// Bakes LOD 0 of the whole scene with `backend` and returns `map` with it published
/// (filtered within charts, as every publish is), and the bake's figures.
pub fn bake_first_light(
    world: &World,
    backend: &mut dyn crate::bundle::BundleBackend,
    threads: usize,
    mut map: ShownLightmap,
    cancel: &AtomicBool,
) -> Result<(ShownLightmap, BundleLodStats), String> {
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
    let mut writer = PageWriter::new(&mut map);
    for (i, p) in pixels.iter().enumerate() {
        writer.write(0, p[0], p[1], values[i]);
    }
    for &(g, t) in &lod0.gutter {
        writer.write(0, g % w, g / w, values[t as usize]);
    }
    writer.finish();
    Ok((map, baked.stats))
}

/// An empty shown map for `world` (nothing published yet).
pub fn empty_shown(world: &World) -> ShownLightmap {
    let blend_band = (2.0 * world.atlas.texel_size).min(world.grid.cell_size * 0.25);
    ShownLightmap::new(world.grid, world.atlas.width, world.atlas.height, world.lods, blend_band)
}

/// Bakes LOD 0 of the whole scene on every core and publishes it.
fn first_light<P: BackendProvider>(shared: &Shared, provider: &P) {
    let world = &shared.world;
    let threads = shared.config.threads();
    let result = provider.backend(&world.bundle, threads).map_err(|e| e.to_string()).and_then(|mut backend| {
        bake_first_light(world, &mut backend, threads, (*shared.shown()).clone(), &shared.shutdown)
    });
    let (map, stats) = match result {
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
    for c in world.non_empty_cells() {
        st.cells[c as usize].history = vec![(stats.directions, f32::NAN)];
    }
    st.first_light = true;
    st.stats.first_light_seconds = Some(shared.started.elapsed().as_secs_f64());
    st.stats.directions_traced += stats.directions;
    update_views(shared, &mut st);
    drop(st);
    shared.wake.notify_all();
    shared.emit(RuntimeEvent::FirstLight { texels: world.lod0.len(), directions: shared.config.bundle.directions });
}

/// The next cell to refine: below its target, not being worked on, most urgent first, and
/// with room for its bake within the memory budget (made by evicting what matters less,
/// [`make_room`]); `None` when nothing is to be done or nothing fits.
fn pick(shared: &Shared, st: &mut State) -> Option<CellId> {
    let key = |st: &State, c: CellId| {
        let s = &st.cells[c as usize];
        (priority(s.view.unwrap_or(CellView { distance: f32::MAX, in_frustum: false }), s.shown, false), c)
    };
    let c = shared
        .world
        .non_empty_cells()
        .filter(|&c| {
            let s = &st.cells[c as usize];
            !s.busy && s.target > s.shown && s.view.is_some()
        })
        .min_by_key(|&c| key(st, c))?;
    if st.cells[c as usize].bake.is_some() {
        return Some(c); // its memory is already counted
    }
    let need = bake_estimate(&shared.world, c, st.cells[c as usize].shown + 1);
    make_room(shared, st, c, need).then_some(c)
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
    let distance = |st: &State, c: CellId| st.cells[c as usize].view.map_or(f32::MAX, |v| v.distance);
    let mine = distance(st, for_cell);
    while budgeted_bytes(shared, st) + need > budget {
        // The cell whose memory matters least: beyond its target first, then farthest.
        let victim = shared
            .world
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

fn worker<P: BackendProvider>(shared: &Shared, provider: &P) {
    let world = &shared.world;
    let mut backend = match provider.backend(&world.bundle, 1) {
        Ok(b) => b,
        Err(e) => {
            shared.emit(RuntimeEvent::Failed { error: e.to_string() });
            return;
        }
    };
    let cancel = &shared.shutdown;
    loop {
        // Take the most urgent cell and its bake.
        let (cell, bake) = {
            let mut st = shared.lock();
            loop {
                if shared.shutdown.load(Ordering::SeqCst) {
                    return;
                }
                if st.first_light && !st.paused && st.failed.is_none() {
                    if let Some(c) = pick(shared, &mut st) {
                        let s = &mut st.cells[c as usize];
                        s.busy = true;
                        break (c, s.bake.take());
                    }
                }
                st = shared.wake.wait_timeout(st, Duration::from_millis(200)).unwrap_or_else(|e| e.into_inner()).0;
            }
        };
        let mut bake = match bake {
            Some(b) => b,
            None => {
                let lod = shared.lock().cells[cell as usize].shown + 1;
                let t = Instant::now();
                let b = Box::new(CellBake::new(world, cell, lod, shared.shown(), shared.seed, 1));
                let mut st = shared.lock();
                st.bake_bytes += b.bytes() as u64;
                st.stats.cell_setup_seconds += t.elapsed().as_secs_f64();
                b
            }
        };
        let unit = bake.step(world, &mut backend, shared.config.unit_directions, cancel);
        let mut st = shared.lock();
        match unit {
            Err(_) => {
                // Cancelled: shutting down. The bake keeps what it had before the unit.
                let s = &mut st.cells[cell as usize];
                s.busy = false;
                s.bake = Some(bake);
                continue;
            }
            Ok(u) => {
                st.stats.pass.add(&u.pass);
                st.stats.units += 1;
                st.stats.directions_traced += u.directions;
                st.window_samples += u.texel_samples;
            }
        }
        let c = &shared.config;
        let error = bake.error();
        let d = bake.directions();
        let ready = d >= c.max_directions as u64 || (d >= c.min_directions as u64 && error <= c.error_bound);
        if ready {
            st.bake_bytes -= bake.bytes() as u64;
            publish(shared, &mut st, &bake, error);
            st.cells[cell as usize].busy = false;
            st.cells[cell as usize].baking_directions = 0;
            drop(st);
            shared.emit(RuntimeEvent::CellPublished { cell, lod: bake.lod, directions: d, error });
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
    let t = &bake.texels;
    let mut writer = PageWriter::new(map);
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

/// Publishes a converged bake in one new snapshot.
fn publish(shared: &Shared, st: &mut State, bake: &CellBake, error: f32) {
    let values = bake.result();
    let mut map = (*shared.shown()).clone();
    let pixels = publish_bake(&mut map, bake, &values);
    shared.set_shown(map);
    let cell = &mut st.cells[bake.cell as usize];
    cell.shown = bake.lod;
    let lod = bake.lod as usize;
    cell.history.resize(lod + 1, (0, f32::INFINITY));
    cell.history[lod] = (bake.directions(), error);
    cell.published.resize(lod + 1, Vec::new());
    cell.published[lod] = pixels;
    st.stats.publishes += 1;
}

fn clock_thread(shared: &Shared) {
    let mut last = Instant::now();
    loop {
        {
            let st = shared.lock();
            let st = shared
                .wake
                .wait_timeout_while(st, Duration::from_secs(1).saturating_sub(last.elapsed()), |_| {
                    !shared.shutdown.load(Ordering::SeqCst)
                })
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
