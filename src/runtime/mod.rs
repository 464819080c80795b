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
//!   between tiles) and put it back; a bake that meets the swap rule is filtered and
//!   published whole (copy-on-write pages: readers see the cell before or after, never
//!   half): early, once a finer level has the directions of the shown one (it then goes on
//!   at that level and is published again as its directions double), or settled, once its
//!   error is below the bound or it has the most directions;
//! * a clock thread emits a stats event once a second.
//!
//! The shown map has two layers ([`shown::Layer`]): the bundles' light (above) and the
//! direct light of punctual lights, exact per texel, which the workers bake first, straight
//! at each cell's target LOD ([`punctual`]): sharp shadows near the camera within a fraction
//! of a second, the smoother rest refined by bundles behind them.
//!
//! Shared state is one mutex (the cell table, the camera, memory accounting) and one
//! snapshot pointer (the shown light map), never held during tracing.

pub mod cell_bake;
pub mod memory;
pub mod policy;
pub mod punctual;
mod reload;
pub mod resample;
mod scheduler;
pub mod shown;
pub mod source;
pub mod world;

use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, RwLock};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crossbeam_channel::Receiver;
use serde::Serialize;

use crate::atlas::{Atlas, AtlasConfig, AtlasError};
use crate::bundle::{BackendProvider, BundleBackend, BundleConfig, BundleConfigError};
use crate::grid::{CellId, GridError};
use crate::scene::{Scene, SceneGeometry, Surroundings};
use crate::watch::{WatchConfig, WatchError};
use scheduler::{Shared, State, clock_thread, current_stats, first_light, next_lod, sync_camera, worker};
use shown::ShownLightmap;
use world::World;

pub use policy::CameraView;
pub use reload::{MIN_MARGIN_TEXELS, invalidation_margin};
pub use scheduler::{MakeBackend, bake_first_light, empty_shown, publish_bake};

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
    /// LOD 0 is first shown after this many of its directions (first light), then again at
    /// twice as many and so on until `bundle.directions`: light within a second that keeps
    /// getting better.
    pub first_light_directions: u32,
    /// LOD levels (LOD 0 … lods − 1); `None`: enough for [`FINEST_TEXEL`] texels.
    pub lods: Option<u32>,
    /// Grid cell side, metres; `None`: from the scene (a few thousand non-empty cells).
    pub cell_size: Option<f32>,
    /// Bytes the shown pages and the bakes in progress may hold; the finest pages of the
    /// cells farthest from the camera are evicted beyond it. `None`: derived from the scene
    /// and the view ([`memory::derived_budget`]), at most a quarter of the machine's memory.
    pub memory_budget: Option<u64>,
    /// Most pages (of either layer, [`shown::PAGE_SIDE`]² pixels each) the shown map may hold: what the
    /// front end can show (the viewer's GPU pool holds as many as its device's largest
    /// texture). `None`: no limit beyond the budget.
    pub page_limit: Option<u64>,
    /// A cell's bake at a finer LOD is published (settled) when it has at least
    /// `min_directions` and its estimated relative error is at most `error_bound`, or when it
    /// has `max_directions`; then the cell moves on to the next LOD. Before that it is
    /// published early, once it has at least `min_directions` and the directions of the level
    /// the cell shows (no noisier, and sharper), and again each time its directions double,
    /// the bake going on at that LOD meanwhile.
    pub min_directions: u32,
    pub max_directions: u32,
    pub error_bound: f32,
    /// Directions per unit of work (one batch of a cell bake).
    pub unit_directions: u32,
    /// Texels a bake gathers from neighbouring cells that want the same LOD, at least (when
    /// there are such cells), at most twice that: a bundle direction costs about as much for
    /// a few texels as for thousands, so small cells are baked in groups. 0: one cell a bake.
    pub group_texels: u32,
    /// Directions of a hot reload's first re-bake of the cells it invalidated (published at
    /// once: `reload_relit`); those cells are then re-baked at LOD 0 with `bundle.directions`
    /// (first light's count) before any other work (`reload_refined`). When it is at least
    /// `bundle.directions`, the first re-bake is the final one.
    pub reload_directions: u32,
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
            first_light_directions: 32,
            lods: None,
            cell_size: None,
            memory_budget: None,
            page_limit: None,
            min_directions: 32,
            max_directions: 512,
            error_bound: 0.03,
            unit_directions: 4,
            group_texels: 4096,
            // A quarter of first light's: the re-bake's cost is about proportional to its
            // directions, and 32 is the least a refinement publishes with (min_directions).
            reload_directions: 32,
            texel_pixels: 2.0,
            threads: None,
            start_paused: false,
        }
    }
}

/// A quarter of the machine's memory, at most 4 GiB (1 GiB where it cannot be read): the
/// most a derived budget may be.
pub fn memory_ceiling() -> u64 {
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
        if self.bundle.directions == 0
            || self.min_directions == 0
            || self.unit_directions == 0
            || self.first_light_directions == 0
            || self.reload_directions == 0
        {
            return bad(
                "--samples, --first-light-directions, --min-directions, --reload-directions and the unit size",
                "must be at least 1".into(),
            );
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
        if let Some(b) = self.memory_budget
            && b < 1 << 20
        {
            return bad("--memory-budget", format!("must be at least 1 MiB, got {b} bytes"));
        }
        if self.page_limit == Some(0) {
            return bad("the page limit", "must be at least 1".into());
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
    #[error(transparent)]
    Watch(#[from] WatchError),
}

/// What the runtime tells its front ends.
#[derive(Clone, Debug, Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
// `Stats` is the large variant; a few events a second, boxing it would only add noise.
#[allow(clippy::large_enum_variant)]
pub enum RuntimeEvent {
    /// LOD 0 is published everywhere (first light), at `directions` directions: the first
    /// `first_light_directions` of its progressive bake.
    FirstLight {
        texels: usize,
        directions: u32,
    },
    /// LOD 0 published again, its progressive bake having reached `directions` (twice as
    /// many each time, then all of `--samples`); refinement starts after the last.
    Lod0Published {
        directions: u64,
    },
    /// A cell swapped to a finer LOD, or was published again at its LOD (an unsettled level
    /// with twice the directions, or a refresh). Cells baked together are published at once,
    /// one event each; `group` lists them, its leader first (`[cell]` for a bake of one
    /// cell). `settled`: the bake met the error bound or `max_directions` and is done; false
    /// for an early publish, whose bake goes on at this LOD (the cell will be published
    /// again at it before moving on to a finer one).
    CellPublished {
        cell: CellId,
        lod: u32,
        directions: u64,
        error: f32,
        settled: bool,
        group: Vec<CellId>,
    },
    /// A cell's punctual layer (the direct light of punctual lights, exact, see
    /// [`shown::Layer`]) is shown at `lod`, baked in `ms` (`texels` at that LOD).
    PunctualPublished {
        cell: CellId,
        lod: u32,
        texels: usize,
        ms: f64,
    },
    /// A cell's finest LOD in `layer` was dropped to stay within the memory budget.
    CellEvicted {
        cell: CellId,
        lod: u32,
        layer: shown::Layer,
    },
    Stats(RuntimeStats),
    /// The runtime stopped working (first light failed, or a worker could not start).
    Failed {
        error: String,
    },
    /// Hot reload: a change to the scene's files was seen.
    ReloadStarted {
        paths: Vec<String>,
    },
    /// The new scene is served (`ms` from the change being seen): its changed meshes, the
    /// cells reset to LOD 0 around them, whether the atlas had to be packed anew, and where
    /// the time went.
    ReloadApplied {
        changed_meshes: usize,
        invalidated_cells: usize,
        repacked: bool,
        ms: f64,
        steps_ms: ReloadSteps,
    },
    /// Every invalidated cell is published again at LOD 0 (`ms` from the change being seen),
    /// baked with `directions` ([`RuntimeConfig::reload_directions`], or first light's count
    /// when that is no more).
    ReloadRelit {
        ms: f64,
        directions: u32,
    },
    /// No cell is provisional any more: every cell the last reload invalidated (and any an
    /// earlier reload left provisional) has been re-baked at LOD 0 with first light's
    /// `directions` (`ms` from the last change being seen). Not sent when the relight
    /// already had them; a reload superseded before it got there is covered by the next
    /// one's.
    ReloadRefined {
        ms: f64,
        directions: u32,
    },
    /// The change could not be loaded; the last good scene is still served.
    ReloadFailed {
        path: String,
        error: String,
    },
}

/// Where a reload's time went, milliseconds (each step in the order `reload::apply` runs
/// them; their sum is about `reload_applied.ms`).
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct ReloadSteps {
    /// From the change being seen to the new scene reaching the runtime (the watcher's quiet
    /// time, the load).
    pub load: f64,
    /// Diffing the scenes and the new scene's geometry.
    pub diff: f64,
    /// The atlas update.
    pub atlas: f64,
    /// The new world: BVH, the cells' triangle lists, the LOD-0 texels, the bundle scene.
    pub world: f64,
    /// The re-baked region's texels and their punctual light.
    pub region: f64,
    /// The LOD-0 re-bake itself (bundles).
    pub bake: f64,
    /// Filtering, publishing and swapping the new world in.
    pub publish: f64,
}

/// An event and when it happened (seconds since [`Runtime::start`]).
#[derive(Clone, Debug)]
pub struct TimedEvent {
    pub t: f64,
    pub event: RuntimeEvent,
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct RuntimeStats {
    /// Non-empty cells shown at each LOD (the bundle layer: the light bundles converge).
    pub cells_per_lod: Vec<usize>,
    /// Non-empty cells showing their punctual layer at each LOD (empty without punctual
    /// lights).
    pub punctual_cells_per_lod: Vec<usize>,
    /// Non-empty cells with work waiting: below their target LOD, stale or provisional.
    pub queue: usize,
    /// Cells with a bake in progress.
    pub baking: usize,
    /// Texels × directions traced per second, over the last stats interval.
    pub texel_samples_per_second: f64,
    /// The memory budget in force (given, or derived from the scene and the view).
    pub memory_budget: u64,
    /// Bytes: shown pages, bakes in progress, and what the scene's fixed structures hold.
    pub page_bytes: u64,
    /// Published pixels over the pixels of the pages held (see [`ShownLightmap::page_fill`]).
    pub page_fill: f64,
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
    /// Bundle-pass counters and phase times of the LOD-0 bake (all its directions).
    pub first_light_pass: crate::bundle::stats::PassStats,
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
    /// LOD shown in the bundle layer (the light bundles converge: sky, emitters, bounces).
    pub shown_lod: u32,
    /// LOD shown in the punctual layer (punctual lights' direct light); 0 without them.
    pub punctual_lod: u32,
    /// LOD being baked, if any, and the directions it has so far.
    pub baking_lod: Option<u32>,
    pub baking_directions: u64,
    /// A worker is tracing a unit of it now.
    pub working: bool,
    /// Its light predates the last hot reload (it will be refreshed).
    pub stale: bool,
    /// Its LOD 0 is a hot reload's quick re-bake (fewer directions than first light); it is
    /// re-baked at full quality before anything else.
    pub provisional: bool,
    /// Directions and estimated error of the shown LOD.
    pub directions: u64,
    pub error: f32,
    /// The shown LOD's bake met the error bound or `max_directions` (false: it was published
    /// early and is still being refined at that LOD).
    pub settled: bool,
    /// LOD-0 texels (0: an empty cell).
    pub texels: u32,
    pub target_lod: u32,
}

/// The live runtime over one scene, driving a bundle backend of the caller's choice.
pub struct Runtime {
    shared: Arc<Shared>,
    events: Receiver<TimedEvent>,
    threads: Vec<JoinHandle<()>>,
    /// Requests to the reload thread (hot reload's watcher, new surroundings).
    reload: crossbeam_channel::Sender<reload::ReloadRequest>,
    /// Raised to cut the reload thread's full re-bake short (a newer request, shutdown).
    reload_cancel: Arc<AtomicBool>,
}

/// Capacity of the event channel; events beyond it are dropped (and counted) rather than
/// letting a front end that never reads grow memory without bound.
const EVENT_CAPACITY: usize = 1 << 16;

impl Runtime {
    /// Builds the scene's atlas, grid and LOD-0 texels (errors are returned here), then bakes
    /// LOD 0 in the background ([`RuntimeEvent::FirstLight`] when it is shown) and refines
    /// from there with backends made by `provider`.
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
        let make_backend: MakeBackend = Arc::new(move |scene, threads| {
            provider.backend(scene, threads).map(|b| Box::new(b) as Box<dyn BundleBackend>)
        });
        // Until a camera is set, the scene's default view sets the derived budget.
        let budget = config.memory_budget.unwrap_or_else(|| {
            memory::derived_budget(&config, &world, &shown, &CameraView::for_scene(&world.scene), memory_ceiling())
        });
        let shared = Arc::new(Shared {
            state: Mutex::new(State::new(world, config.start_paused, budget, config.page_limit)),
            config,
            wake: Condvar::new(),
            shown: RwLock::new(Arc::new(shown)),
            events: tx,
            emitting: Mutex::new(()),
            dropped: AtomicU64::new(0),
            shutdown: AtomicBool::new(false),
            started,
            make_backend,
            camera: Mutex::new((0, None)),
        });
        let (reload, requests) = crossbeam_channel::unbounded();
        let reload_cancel = Arc::new(AtomicBool::new(false));
        let mut runtime = Runtime {
            shared: shared.clone(),
            events: rx,
            threads: Vec::new(),
            reload,
            reload_cancel: reload_cancel.clone(),
        };
        for w in 0..shared.config.threads() {
            let shared = shared.clone();
            runtime.spawn(&format!("livebake-worker-{w}"), move || {
                if w == 0 {
                    first_light(&shared);
                }
                worker(&shared);
            })?;
        }
        let clock = shared.clone();
        runtime.spawn("livebake-clock", move || clock_thread(&clock))?;
        let reloader = shared.clone();
        runtime.spawn("livebake-reload", move || reload::reload_thread(&reloader, requests, &reload_cancel))?;
        Ok(runtime)
    }

    fn spawn(&mut self, name: &str, f: impl FnOnce() + Send + 'static) -> Result<(), RuntimeError> {
        let handle = std::thread::Builder::new().name(name.to_string()).spawn(f).map_err(RuntimeError::Thread)?;
        self.threads.push(handle);
        Ok(())
    }

    /// Watches the scene's files and reloads on every good save (hot reload): the changed
    /// meshes' surroundings drop to LOD 0 and are re-baked first, the rest is refreshed at
    /// lower priority; a bad save keeps the current scene and reports
    /// [`RuntimeEvent::ReloadFailed`]. `path` is the file the scene was loaded from.
    pub fn watch(&mut self, path: &Path, mut config: WatchConfig) -> Result<(), RuntimeError> {
        // A reload is made in this world's frame, wherever its geometry now lies.
        config.load.origin = Some(self.world().scene.origin);
        let watcher = crate::watch::SceneWatcher::start(path, config)?;
        // The reload thread lives as long as the runtime.
        let _ = self.reload.send(reload::ReloadRequest::Watch(watcher));
        Ok(())
    }

    /// Lights the scene with `surroundings` (sky, environment map, sun) instead of its own:
    /// a light change, applied as hot reload applies one (LOD 0 re-baked everywhere, the grid
    /// kept, shown after first light's directions: `reload_applied`, `reload_relit`, then
    /// `reload_refined` at all of them). Returns at once. A newer call cuts the re-bake of an
    /// earlier one short; of several waiting, only the last is applied. A scene reloaded from
    /// its files keeps the surroundings set last.
    pub fn set_surroundings(&self, surroundings: Surroundings) {
        self.reload_cancel.store(true, Ordering::SeqCst);
        let _ = self.reload.send(reload::ReloadRequest::Surroundings(surroundings, Instant::now()));
    }

    /// The camera the runtime refines for. Accumulated work is kept when it moves; only the
    /// order of what comes next changes.
    pub fn set_camera(&self, camera: CameraView) {
        if !camera.is_valid() {
            tracing::warn!("ignoring an invalid camera: {camera:?}");
            return;
        }
        // Never waits for the state mutex (a front end's frame must not stall behind a
        // publish): the workers apply it before they choose their next job.
        {
            let mut c = self.shared.camera.lock().unwrap_or_else(|e| e.into_inner());
            c.0 += 1;
            c.1 = Some(camera);
        }
        self.shared.wake.notify_all();
    }

    /// Limits the shown map to `pages` pages (of either layer; `None`: no limit beyond the
    /// budget): what the front end can show, as the viewer's GPU pool. Levels beyond it are
    /// evicted before the next bake, the farthest first.
    pub fn set_page_limit(&self, pages: Option<u64>) {
        self.shared.lock().page_limit = pages.map(|p| p.max(1));
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

    /// The scene and everything derived from it, as served now (hot reload replaces it).
    pub fn world(&self) -> Arc<World> {
        self.shared.lock().world.clone()
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
        let mut st = self.shared.lock();
        sync_camera(&self.shared, &mut st);
        cell_table(&st)
    }

    /// The shown light map and the cell table as of one moment (every publish swaps the map
    /// under the state lock, which this holds while it reads both).
    pub fn snapshot(&self) -> (Arc<ShownLightmap>, Vec<CellInfo>) {
        let mut st = self.shared.lock();
        sync_camera(&self.shared, &mut st);
        (self.shared.shown(), cell_table(&st))
    }

    pub fn stats(&self) -> RuntimeStats {
        let mut st = self.shared.lock();
        sync_camera(&self.shared, &mut st);
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
        self.reload_cancel.store(true, Ordering::SeqCst);
        self.shared.wake.notify_all();
        // A panic is a bug; the panic hook reported it. Shutting down goes on for the others.
        self.threads.drain(..).map(|h| h.join()).filter(Result::is_err).count()
    }
}

/// The cell table of `st` (non-empty cells).
fn cell_table(st: &State) -> Vec<CellInfo> {
    let world = &st.world;
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
                punctual_lod: s.punctual.shown,
                baking_lod: s
                    .bake
                    .as_ref()
                    .or_else(|| s.member_of.and_then(|l| st.cells[l as usize].bake.as_ref()))
                    .map(|b| b.lod)
                    .or(if s.busy { next_lod(s) } else { None }),
                baking_directions: s.baking_directions,
                working: s.busy,
                stale: s.stale,
                provisional: s.provisional,
                directions,
                error,
                settled: !s.unsettled,
                texels: world.lod0_texels[c as usize],
                target_lod: s.target,
            }
        })
        .collect()
}

impl Drop for Runtime {
    fn drop(&mut self) {
        if self.stop() > 0 {
            tracing::error!("a runtime worker panicked");
        }
    }
}
