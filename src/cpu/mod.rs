//! The CPU bundle backend: the adaptive ray-bundle algorithm on worker threads, with the
//! same plan, node budget and estimator as the GPU backend.
//!
//! A batch of directions is split into a fixed number of lanes; each lane traces its
//! directions in order into its own hit sums, and the lanes are added in order. The sums
//! therefore do not depend on how many threads ran the lanes.

pub(crate) mod analysis;
mod bounds_tree;
pub(crate) mod direction;
mod emitter_rows;
pub(crate) mod fragments;
pub mod scene;

use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex, Weak};

use crate::bundle::progressive::BatchSums;
use crate::bundle::stats::PassStats;
use crate::bundle::target::{BackendError, BackendProvider, BakeTarget, BundleScene, Cancelled, SourceRadiance};
use crate::bundle::{BundleBackend, DirectionJob};
use crate::parallel::par_map;

use direction::{PassContext, Scratch, trace_direction};
pub use scene::CpuScene;

struct Lane {
    sums: BatchSums,
    scratch: Scratch,
}

pub struct CpuBundleBackend {
    scene: Arc<CpuScene>,
    lanes: Vec<Lane>,
    threads: usize,
    /// Per triangle: the current target's importance (rays per m²); zero outside it.
    importance: Vec<f32>,
}

impl CpuBundleBackend {
    pub fn new(scene: Arc<CpuScene>, threads: usize) -> Self {
        let lanes = (0..scene.bundle.config.lanes.max(1))
            .map(|_| Lane { sums: BatchSums::default(), scratch: Scratch::default() })
            .collect();
        let importance = vec![0.0; scene.bundle.geom.len()];
        CpuBundleBackend { scene, lanes, threads: threads.max(1), importance }
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
        for lane in &mut self.lanes {
            lane.sums = BatchSums::default();
        }
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
        // Lane 0 accumulates into `sums` itself (the caller is done with the last batch's),
        // the others into their own buffers, zeroed by the previous reduction.
        let light = !self.scene.bundle.emitters.small.is_empty();
        let n = target.len();
        if sums.fits(n, light) {
            sums.clear();
        } else {
            *sums = BatchSums::with_light(n, light);
        }
        self.lanes[0].sums = std::mem::take(sums);
        for lane in &mut self.lanes[1..] {
            if !lane.sums.fits(n, light) {
                lane.sums = BatchSums::with_light(n, light);
            }
        }
        let bundle = &self.scene.bundle;
        let ctx = PassContext {
            scene: &self.scene,
            config: &bundle.config,
            target,
            source,
            importance: &self.importance,
            sky: bundle.scene.sky,
            light_pixel: bundle.light_pixel(target.lod),
            cancel,
            global,
        };
        let n_lanes = self.lanes.len();
        // Lane l traces directions l, l + n_lanes, ... in order into its own sums; lanes are
        // independent, so which worker runs which lane does not change the result.
        let lanes: Vec<(usize, &mut Lane)> = self.lanes.iter_mut().enumerate().collect();
        let results = par_map(lanes, self.threads, |(l, lane)| {
            let mut stats = PassStats::default();
            for job in batch.iter().skip(l).step_by(n_lanes) {
                trace_direction(&ctx, job, &mut lane.sums, &mut lane.scratch, &mut stats)?;
            }
            Ok(stats)
        });
        self.set_importance(target, false);
        let mut total = PassStats::default();
        let mut cancelled = false;
        for r in results {
            match r {
                Ok(s) => total.add(&s),
                Err(Cancelled) => cancelled = true,
            }
        }
        // Reducing also zeroes lanes 1… for the next batch (a cancelled batch included).
        let (first, rest) = self.lanes.split_at_mut(1);
        *sums = std::mem::take(&mut first[0].sums);
        let mut others: Vec<BatchSums> = rest.iter_mut().map(|l| std::mem::take(&mut l.sums)).collect();
        sums.add_lanes(&mut others, self.threads);
        for (lane, s) in rest.iter_mut().zip(others) {
            lane.sums = s;
        }
        if cancelled { Err(Cancelled) } else { Ok(total) }
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
