//! The CPU bundle backend: the adaptive ray-bundle algorithm on worker threads, with the
//! same plan, node budget and estimator as the GPU backend.
//!
//! A batch of directions is split into a fixed number of lanes ([`crate::bundle::Lanes`]):
//! lane l traces directions l, l + L, … into its own sums, and the lanes are added in order.
//! The threads are shared out among the lanes; the threads of one lane add their hits in
//! the order one thread would (see `batch.rs`). The sums therefore depend on the lanes, not
//! on how many threads ran them.

pub(crate) mod analysis;
mod batch;
mod bounds_tree;
pub(crate) mod direction;
mod emitter_rows;
pub(crate) mod fragments;
mod prefetch;
pub mod scene;
mod through;

pub use batch::{SPARE_RECORD_BYTES, WAITING_HITS_PER_THREAD};

use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex, Weak};

use crate::bundle::progressive::BatchSums;
use crate::bundle::stats::PassStats;
use crate::bundle::target::{BackendError, BackendProvider, BakeTarget, BundleScene, Cancelled, SourceRadiance};
use crate::bundle::{BundleBackend, DirectionJob};

use direction::{PassContext, Worker};
pub use scene::CpuScene;

pub struct CpuBundleBackend {
    scene: Arc<CpuScene>,
    /// One per thread.
    workers: Vec<Worker>,
    /// The sums of lanes 1, 2, … (lane 0 accumulates into the caller's), zeroed between
    /// batches.
    lane_sums: Vec<BatchSums>,
    /// Per triangle: the current target's importance (rays per m²); zero outside it.
    importance: Vec<f32>,
    /// Whether a windowed target's fragments are built only inside its outline
    /// ([`crate::bundle::window::WindowOutline`]).
    outline_clip: bool,
    /// The share of N × [`WAITING_HITS_PER_THREAD`] that may wait ([`BundleBackend::scale_waiting_hits`]).
    waiting_share: f64,
}

impl CpuBundleBackend {
    pub fn new(scene: Arc<CpuScene>, threads: usize) -> Self {
        let workers = (0..threads.max(1)).map(|_| Worker::default()).collect();
        let importance = vec![0.0; scene.bundle.geom.len()];
        CpuBundleBackend { scene, workers, lane_sums: Vec::new(), importance, outline_clip: true, waiting_share: 1.0 }
    }

    /// With `false`, a windowed target's fragments fill the window's whole square, as the
    /// GPU backend's do: what the outline must not change (tests/runtime.rs).
    pub fn with_outline_clip(mut self, on: bool) -> Self {
        self.outline_clip = on;
        self
    }

    /// Sets the importance of `target`'s triangles (LOD-k texel density × oversampling²).
    fn set_importance(&mut self, target: &BakeTarget, on: bool) {
        let os = self.scene.bundle.config.oversampling;
        let scale = (1u64 << (2 * target.lod)) as f32 * os * os;
        for &t in target.triangles {
            self.importance[t as usize] = if on { self.scene.density[t as usize] * scale } else { 0.0 };
        }
    }
}

impl BundleBackend for CpuBundleBackend {
    fn name(&self) -> &'static str {
        "cpu"
    }

    fn trace_batch(
        &mut self,
        target: &BakeTarget,
        batch: &[DirectionJob],
        source: &SourceRadiance,
        sums: &mut BatchSums,
        cancel: &AtomicBool,
    ) -> Result<PassStats, Cancelled> {
        self.run(target, batch, source, sums, cancel, true)
    }

    fn release_texel_buffers(&mut self) {
        self.lane_sums = Vec::new();
    }

    fn scale_waiting_hits(&mut self, share: f64) {
        self.waiting_share = share.clamp(f64::MIN_POSITIVE, 1.0);
    }
}

impl CpuBundleBackend {
    /// [`BundleBackend::trace_batch`] for the light bundles only: `sums.light` gets the
    /// batch's light pass, `sums.bundle` is zeroed (the GPU backend fills it).
    pub fn trace_light_batch(
        &mut self,
        target: &BakeTarget,
        batch: &[DirectionJob],
        source: &SourceRadiance,
        sums: &mut BatchSums,
        cancel: &AtomicBool,
    ) -> Result<PassStats, Cancelled> {
        self.run(target, batch, source, sums, cancel, false)
    }

    fn run(
        &mut self,
        target: &BakeTarget,
        batch: &[DirectionJob],
        source: &SourceRadiance,
        sums: &mut BatchSums,
        cancel: &AtomicBool,
        global: bool,
    ) -> Result<PassStats, Cancelled> {
        self.set_importance(target, true);
        let light = !self.scene.bundle.emitters.small.is_empty();
        let n = target.len();
        if sums.fits(n, light) {
            sums.clear();
        } else {
            *sums = BatchSums::with_light(n, light);
        }
        let bundle = &self.scene.bundle;
        let lanes = bundle.config.lanes.for_texels(n as u64) as usize;
        let ctx = PassContext {
            scene: &self.scene,
            config: &bundle.config,
            target,
            source,
            importance: &self.importance,
            sky: &bundle.sky,
            light_pixel: bundle.light_pixel(target.lod),
            cancel,
            global,
            split_large_tiles: lanes == 1,
            outline_clip: self.outline_clip,
            waiting_hits: (bundle.config.node_capacity.saturating_mul(WAITING_HITS_PER_THREAD) as f64
                * self.waiting_share)
                .ceil() as u64,
        };
        // Lane 0 accumulates into `sums` itself (the caller is done with the last batch's),
        // the others into buffers of their own, zeroed when they were last added.
        self.lane_sums.truncate(lanes - 1);
        for lane in &mut self.lane_sums {
            if !lane.fits(n, light) {
                *lane = BatchSums::with_light(n, light);
            }
        }
        self.lane_sums.resize_with(lanes - 1, || BatchSums::with_light(n, light));
        let jobs: Vec<Vec<DirectionJob>> =
            (0..lanes).map(|l| batch.iter().skip(l).step_by(lanes).cloned().collect()).collect();
        let lane_work = jobs.iter().zip(std::iter::once(&mut *sums).chain(self.lane_sums.iter_mut())).collect();
        let result = trace_lanes(&ctx, lane_work, &mut self.workers);
        // Adding also zeroes lanes 1… for the next batch (a cancelled batch's included).
        sums.add_lanes(&mut self.lane_sums, self.workers.len());
        let mut total = PassStats::default();
        for w in &mut self.workers {
            total.add(&std::mem::take(&mut w.stats));
        }
        self.set_importance(target, false);
        result.map(|()| total)
    }
}

/// Traces each lane's directions into its sums, the threads (`workers`) shared out among the
/// lanes: all at once when there are as many threads as lanes or more, else in rounds of
/// one thread each.
fn trace_lanes(
    ctx: &PassContext,
    lanes: Vec<(&Vec<DirectionJob>, &mut BatchSums)>,
    workers: &mut [Worker],
) -> Result<(), Cancelled> {
    let (n_lanes, threads) = (lanes.len(), workers.len().max(1));
    let mut lanes = lanes.into_iter();
    if n_lanes == 1
        && let Some((jobs, sums)) = lanes.next()
    {
        return batch::trace_batch(ctx, jobs, sums, workers);
    }
    // Lane l's share of the threads: the first `threads % n_lanes` lanes get one more.
    let mut groups: Vec<&mut [Worker]> = Vec::with_capacity(n_lanes);
    let mut rest = workers;
    for l in 0..n_lanes.min(threads) {
        let take = (threads / n_lanes).max(1) + usize::from(threads > n_lanes && l < threads % n_lanes);
        let (group, tail) = rest.split_at_mut(take.min(rest.len()));
        groups.push(group);
        rest = tail;
    }
    let mut result = Ok(());
    loop {
        let round: Vec<_> = lanes.by_ref().take(groups.len()).collect();
        if round.is_empty() {
            return result;
        }
        std::thread::scope(|s| {
            let handles: Vec<_> = round
                .into_iter()
                .zip(groups.iter_mut())
                .map(|((jobs, sums), group)| s.spawn(move || batch::trace_batch(ctx, jobs, sums, group)))
                .collect();
            // Joined here, so that a worker's panic reaches the caller with its own payload.
            for h in handles {
                let traced = h.join().unwrap_or_else(|p| std::panic::resume_unwind(p));
                result = result.and(traced);
            }
        });
    }
}

/// Makes CPU backends; the per-scene data ([`CpuScene`]) is built once per scene and
/// shared by every backend made for it.
#[derive(Default)]
pub struct CpuProvider {
    cache: Mutex<Option<(Weak<BundleScene>, Arc<CpuScene>)>>,
}

impl CpuProvider {
    pub fn new() -> Self {
        CpuProvider::default()
    }

    /// The shared CPU data of `scene`.
    pub fn scene(&self, scene: &Arc<BundleScene>) -> Arc<CpuScene> {
        let mut cache = self.cache.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((weak, cpu)) = cache.as_ref()
            && weak.upgrade().is_some_and(|s| Arc::ptr_eq(&s, scene))
        {
            return cpu.clone();
        }
        let cpu = Arc::new(CpuScene::new(scene.clone()));
        *cache = Some((Arc::downgrade(scene), cpu.clone()));
        cpu
    }
}

impl BackendProvider for CpuProvider {
    type Backend = CpuBundleBackend;

    fn name(&self) -> &'static str {
        "cpu"
    }

    fn backend(&self, scene: &Arc<BundleScene>, threads: usize) -> Result<CpuBundleBackend, BackendError> {
        Ok(CpuBundleBackend::new(self.scene(scene), threads))
    }
}
