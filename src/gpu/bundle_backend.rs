//! The GPU bundle backend: the 2013 paper's method on wgpu, behind [`BundleBackend`].
//!
//! Per batch of directions:
//! 1. one submission for every direction: analysis raster ([`super::bundle_analysis`]),
//!    mips ([`super::bundle_mips`]), Program 1 ([`super::bundle_tiles`]), each direction
//!    into plan buffers of its own; the plans are read back (a few KB each);
//! 2. all planned tiles of all the directions in one submission: per tile the linked-list
//!    build ([`super::bundle_lists`]), a copy of its node counter into its slot, and the
//!    resolve ([`super::bundle_resolve`]), which does nothing when the counter says the
//!    lists overflowed. The host reads the counts once; overflowed tiles are split, as on
//!    the CPU, and their parts redone in a further such round.
//!
//! No read-back happens inside a direction. (A batch whose plan buffers would exceed
//! `PLAN_BUFFER_BUDGET` is cut into parts that go through 1–2 each.)
//!
//! The per-texel sums stay on the GPU for the whole batch and are read back once.
//!
//! **Light pass: the CPU's.** Light bundles are small windows around small emitters (a
//! few tiles per direction), and their work is a small share of a bake; they run on the
//! CPU backend, on the same directions, while the host is otherwise idle waiting for the
//! GPU. **Foreign sides** (a runtime cell bake, whose bundles see surfaces outside the
//! target) show the runtime's `ShownSource`, which the resolve evaluates itself
//! ([`super::surface_radiance`]): the shown map's snapshot is mirrored on the GPU (pages
//! that changed since the last batch are uploaded) beside the scene's materials (uploaded
//! once, at the first such batch). A foreign source of another kind, or one the device
//! cannot hold, runs on the CPU backend (logged once).
//!
//! **Light through surfaces** (a scene with `BLEND`, transmission or `MASK` materials): the
//! resolve gives each fragment its transmittance and walks each line's layers with the
//! running product ([`super::bundle_resolve`], bundle_through.inc.wgsl), reading the
//! scene's materials (uploaded once, at the start, and shared with a foreign source) and
//! each target texel's triangle (with the target's buffers).
//!
//! Window culling (which triangles a cell's window draws) uses the CPU's bounds tree, as
//! the CPU backend does; a whole-scene window draws every triangle.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use super::GpuError;
use super::bundle_analysis::{AnalysisPass, Drawn, DrawnIds, GpuTriangles};
use super::bundle_lists::{ListBuffers, ListError, ListPass};
use super::bundle_mips::{AnalysisMaps, MipPass};
use super::bundle_resolve::{FixedPoint, Rectangle, ResolvePass, ResolveStatus, SceneSides, TargetBuffers};
use super::bundle_tiles::{TileBuffers, TilePass, read_plans};
use super::device::GpuContext;
use super::surface_radiance::{ForeignRadiance, SceneSurfaces};
use crate::bundle::progressive::BatchSums;
use crate::bundle::raster::{BundleFrame, Viewport};
use crate::bundle::stats::PassStats;
use crate::bundle::target::{BackendError, BackendProvider, BakeTarget, BundleScene, Cancelled, SourceRadiance};
use crate::bundle::tiles::TilingMode;
use crate::bundle::window::{WindowSource, split_overflowed, tile_viewport, unplanned};
use crate::bundle::{BundleBackend, DirectionJob};
use crate::cpu::{CpuBundleBackend, CpuProvider, CpuScene};
use crate::runtime::shown::ShownLightmap;
use crate::runtime::source::ShownSource;

/// Why a GPU batch failed (the batch then runs on the CPU backend).
#[derive(Debug, thiserror::Error)]
enum BatchError {
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error("cancelled")]
    Cancelled,
}

impl From<Cancelled> for BatchError {
    fn from(_: Cancelled) -> Self {
        BatchError::Cancelled
    }
}

/// What identifies a target's GPU buffers: its LOD, texel count and a hash of its tables
/// (charts, rectangles and every entry: a few ms for a whole LOD, against seconds a batch).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct TargetKey {
    lod: u32,
    texels: usize,
    tables: u64,
}

impl TargetKey {
    fn of(target: &BakeTarget) -> TargetKey {
        // FNV-1a over the tables' words.
        let mut h = 0xcbf2_9ce4_8422_2325u64;
        let mut add = |w: u64| {
            h ^= w;
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        };
        for t in target.tables {
            add(t.chart.map_or(u64::MAX, u64::from));
            for v in [t.rect.x0, t.rect.y0, t.rect.x1, t.rect.y1] {
                add(v as u64);
            }
            add(t.fingerprint());
        }
        TargetKey { lod: target.lod, texels: target.len(), tables: h }
    }
}

/// Most bytes of plan buffers a submission's directions may hold (see
/// `GpuBundleBackend::directions_per_submission`): at the default analysis resolution
/// (128) that is 157 directions, more than a batch.
const PLAN_BUFFER_BUDGET: u64 = 64 << 20;

/// Analysis maps and plan buffers of one analysis resolution, for the `slot`-th direction
/// of a submission.
struct PlanBuffers {
    res: u32,
    slot: usize,
    maps: AnalysisMaps,
    tiles: TileBuffers,
}

pub struct GpuBundleBackend {
    gpu: GpuContext,
    scene: Arc<CpuScene>,
    /// The light pass, and batches the GPU cannot resolve.
    cpu: CpuBundleBackend,
    triangles: GpuTriangles,
    sides: SceneSides,
    analysis: AnalysisPass,
    mips: MipPass,
    planner: TilePass,
    lists: ListPass,
    resolve: ResolvePass,
    list_buffers: ListBuffers,
    plans: Vec<PlanBuffers>,
    /// The last target's buffers (see [`TargetKey`]).
    target_buffers: Option<(TargetKey, TargetBuffers)>,
    importance: Vec<f32>,
    bounds_stack: Vec<u32>,
    window_triangles: Vec<u32>,
    tile_triangles: Vec<u32>,
    tile_counts: TileCounts,
    /// Waits for each phase so the stats time them apart (benches); otherwise build and
    /// resolve share one submission and `build_seconds` holds both.
    phase_timing: bool,
    /// The runtime's foreign source on the GPU, made at the first batch that has one.
    foreign: Option<ForeignRadiance>,
    /// The scene's materials on the GPU: made at the start when the scene lets light
    /// through surfaces (the resolve reads them for every fragment's transmittance), else
    /// with the foreign source.
    surfaces: Option<Arc<SceneSurfaces>>,
    warned_foreign: bool,
    /// Tests: fixed-point scales 2^this larger than chosen (to force a saturation).
    #[cfg(test)]
    scale_boost_bits: i32,
}

impl GpuBundleBackend {
    pub fn new(
        gpu: GpuContext,
        scene: Arc<CpuScene>,
        threads: usize,
        phase_timing: bool,
    ) -> Result<GpuBundleBackend, BackendError> {
        let config = &scene.bundle.config;
        if config.tiling != TilingMode::Adaptive {
            return Err(BackendError::Unavailable(format!(
                "the GPU backend plans adaptive tiles only (Program 1), not {:?}",
                config.tiling
            )));
        }
        let unavailable = |e: GpuError| BackendError::Unavailable(format!("GPU backend on {}: {e}", gpu.info.name));
        let geom = &scene.bundle.geom;
        let triangles = GpuTriangles::new(&gpu, &geom.corners);
        let sides = SceneSides::new(&gpu, &scene.bundle);
        let analysis = AnalysisPass::new(&gpu).map_err(unavailable)?;
        let mips = MipPass::new(&gpu).map_err(unavailable)?;
        let planner = TilePass::new(&gpu).map_err(unavailable)?;
        let lists = ListPass::new(&gpu).map_err(unavailable)?;
        let passing = scene.passing.is_some();
        let resolve = ResolvePass::new(&gpu, config.head_side, passing).map_err(unavailable)?;
        let surfaces = match passing {
            true => {
                let s =
                    SceneSurfaces::new(&gpu, &resolve.foreign.surfaces_layout, &scene.bundle).map_err(unavailable)?;
                tracing::debug!("GPU resolve: scene materials uploaded ({} bytes)", s.bytes);
                Some(Arc::new(s))
            }
            false => None,
        };
        let list_buffers = lists.buffers(&gpu, config.head_side, config.node_capacity).map_err(|e| match e {
            ListError::Capacity(n) => BackendError::Unavailable(format!(
                "--nodes {n} is more than this GPU's storage bindings hold ({} bytes); use a smaller --nodes",
                gpu.device.limits().max_storage_buffer_binding_size
            )),
            ListError::HeadSide(w) => BackendError::Unavailable(format!(
                "--head-side {w} exceeds this GPU's texture or storage limits; use a smaller --head-side"
            )),
            ListError::Gpu(e) => unavailable(e),
        })?;
        let cpu = CpuBundleBackend::new(scene.clone(), threads);
        let importance = vec![0.0; geom.len()];
        Ok(GpuBundleBackend {
            gpu,
            scene,
            cpu,
            triangles,
            sides,
            analysis,
            mips,
            planner,
            lists,
            resolve,
            list_buffers,
            plans: Vec::new(),
            target_buffers: None,
            importance,
            bounds_stack: Vec::new(),
            window_triangles: Vec::new(),
            tile_triangles: Vec::new(),
            tile_counts: TileCounts::default(),
            phase_timing,
            foreign: None,
            surfaces,
            warned_foreign: false,
            #[cfg(test)]
            scale_boost_bits: 0,
        })
    }

    /// Uploads the importance of `target`'s triangles (as the CPU backend sets it).
    fn set_importance(&mut self, target: &BakeTarget) {
        let os = self.scene.bundle.config.oversampling;
        let scale = (1u64 << (2 * target.lod)) as f32 * os * os;
        self.importance.fill(0.0);
        for &t in target.triangles {
            self.importance[t as usize] = self.scene.density[t as usize] * scale;
        }
        self.triangles.set_importance(&self.gpu, &self.importance);
    }

    /// The plan buffers at analysis resolution `res` of the `slot`-th direction of a
    /// submission (made on first use, then reused).
    fn plan_buffers(&mut self, res: u32, slot: usize) -> Result<usize, GpuError> {
        if let Some(i) = self.plans.iter().position(|p| p.res == res && p.slot == slot) {
            return Ok(i);
        }
        let maps = AnalysisMaps::new(&self.gpu, res)?;
        let tiles = self.planner.buffers(&self.gpu, res);
        self.plans.push(PlanBuffers { res, slot, maps, tiles });
        Ok(self.plans.len() - 1)
    }

    /// Directions planned in one submission: as many as keep their plan buffers (analysis
    /// maps and tile list, each direction its own) within [`PLAN_BUFFER_BUDGET`] at the
    /// largest analysis resolution.
    fn directions_per_submission(&self) -> usize {
        let res = self.scene.bundle.config.analysis_res as u64;
        // Maps: importance and fragment count with their mips (4/3 of the finest level);
        // the tile list: a `PlannedTile` (16 bytes) per finest pixel.
        let per_direction = res * res * (2 * 4 * 4 / 3 + 16);
        (PLAN_BUFFER_BUDGET / per_direction.max(1)).max(1) as usize
    }

    /// The global bundles of `batch` into `sums.bundle` (sized and zeroed by the caller);
    /// foreign sides show `self.foreign` when `foreign`.
    fn trace_global(
        &mut self,
        target: &BakeTarget,
        batch: &[DirectionJob],
        source: &SourceRadiance,
        foreign: bool,
        sums: &mut BatchSums,
        cancel: &AtomicBool,
    ) -> Result<PassStats, BatchError> {
        self.set_importance(target);
        // A bake's batches share one target: its tables are uploaded once, and its buffers
        // reused (made anew per batch, lavapipe's host memory grew by ~40 MB a batch before
        // wgpu reclaimed them).
        let key = TargetKey::of(target);
        let buffers = match self.target_buffers.take() {
            Some((k, b)) if k == key => b,
            _ => {
                let passing = self.scene.passing.as_ref().map(|_| &*self.scene.bundle.atlas);
                TargetBuffers::new(&self.gpu, target, passing)?
            }
        };
        let result = self.trace_global_into(target, batch, source, foreign, sums, cancel, &buffers);
        self.target_buffers = Some((key, buffers));
        result
    }

    #[allow(clippy::too_many_arguments)]
    fn trace_global_into(
        &mut self,
        target: &BakeTarget,
        batch: &[DirectionJob],
        source: &SourceRadiance,
        foreign: bool,
        sums: &mut BatchSums,
        cancel: &AtomicBool,
        buffers: &TargetBuffers,
    ) -> Result<PassStats, BatchError> {
        let bundle = &self.scene.bundle;
        let texel = bundle.atlas.texel_size / (1u64 << target.lod) as f32;
        let foreign_brightest = match (&self.foreign, foreign) {
            (Some(f), true) => f.brightest(),
            _ => 0.0,
        };
        let brightest =
            source.own.iter().fold(bundle.sky.brightest().max(foreign_brightest), |m, l| m.max(l.max_element()));
        let mut scales = FixedPoint::for_batch(batch.len(), texel * texel, brightest);
        #[cfg(test)]
        {
            scales = scales.reduced(-self.scale_boost_bits);
        }
        // A saturated batch is redone once with scales 2^24 smaller (16 M times the room;
        // quantisation stays below 10⁻⁵ of one hit).
        for attempt in 0..2u64 {
            buffers.start_batch(&self.gpu, source.own);
            let mut stats = PassStats::default();
            for jobs in batch.chunks(self.directions_per_submission()) {
                self.trace_directions(target, jobs, buffers, foreign, scales, &mut stats, cancel)?;
            }
            let status: ResolveStatus = buffers.read(&self.gpu, scales, &mut sums.bundle)?;
            self.gpu.take_error()?;
            if status.saturated == 0 || attempt == 1 {
                if status.saturated > 0 {
                    tracing::error!("GPU resolve: {} fixed-point sums saturated after the retry", status.saturated);
                }
                stats.saturated_sums += status.saturated as u64;
                stats.redone_batches += attempt;
                stats.lost_lookups += status.lost as u64;
                stats.foreign_lookups += status.foreign as u64;
                stats.covered_pixels += status.covered as u64;
                stats.unresolved_pixels += status.deep as u64;
                return Ok(stats);
            }
            tracing::warn!("GPU resolve: {} fixed-point sums saturated; redoing the batch", status.saturated);
            scales = scales.reduced(24);
        }
        unreachable!("the loop returns on its second attempt")
    }

    #[allow(clippy::too_many_arguments)]
    fn trace_directions(
        &mut self,
        target: &BakeTarget,
        jobs: &[DirectionJob],
        buffers: &TargetBuffers,
        foreign: bool,
        scales: FixedPoint,
        stats: &mut PassStats,
        cancel: &AtomicBool,
    ) -> Result<(), BatchError> {
        let scene = self.scene.clone();
        let bundle = &scene.bundle;
        let cfg = &bundle.config;
        let window = WindowSource {
            target: target.window,
            centre: scene.centre,
            radius: scene.radius,
            bundle_pixel: bundle.light_pixel(target.lod),
        };
        let gpu = self.gpu.clone();

        // The plans of all `jobs` in one submission (each direction its own maps and plan
        // buffers), read back after it.
        let t = Instant::now();
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        let mut directions = Vec::with_capacity(jobs.len());
        // Each window's triangle ids stay alive until the submission.
        let mut window_ids = Vec::with_capacity(jobs.len());
        for (slot, job) in jobs.iter().enumerate() {
            let t = Instant::now();
            let frame = BundleFrame::new(job.dir);
            let global = window.analysis_viewport(cfg, &frame, job.jitter);
            window_ids.push(match target.window {
                None => None,
                Some(_) => {
                    let side = global.pixel * global.width as f32;
                    let (stack, out) = (&mut self.bounds_stack, &mut self.window_triangles);
                    scene.bounds.overlapping(&frame, global.origin, side, stack, out);
                    Some(DrawnIds::new(&gpu, out))
                }
            });
            let drawn = window_ids[slot].as_ref().map_or(Drawn::All, Drawn::Uploaded);
            let p = self.plan_buffers(global.width, slot)?;
            let plan_buffers = &mut self.plans[p];
            self.analysis.encode(&gpu, &mut encoder, &self.triangles, drawn, &frame, &global, &plan_buffers.maps);
            if self.phase_timing {
                submit_and_wait(&gpu, encoder)?;
                stats.analysis_seconds += seconds(t);
                encoder = gpu.device.create_command_encoder(&Default::default());
            }
            let t = Instant::now();
            self.mips.encode(&gpu, &mut encoder, &mut plan_buffers.maps, true);
            if self.phase_timing {
                submit_and_wait(&gpu, encoder)?;
                stats.mip_seconds += seconds(t);
                encoder = gpu.device.create_command_encoder(&Default::default());
            }
            let t = Instant::now();
            let params = cfg.tile_params(global.pixel);
            self.planner.encode(&gpu, &mut encoder, &plan_buffers.maps, &params, &plan_buffers.tiles);
            if self.phase_timing {
                submit_and_wait(&gpu, encoder)?;
                stats.subdivision_seconds += seconds(t);
                encoder = gpu.device.create_command_encoder(&Default::default());
            }
            directions.push((frame, global, p));
        }
        gpu.queue.submit([encoder.finish()]);
        let plan_buffers: Vec<&TileBuffers> = directions.iter().map(|(_, _, p)| &self.plans[*p].tiles).collect();
        let plans = read_plans(&gpu, &plan_buffers)?;
        let mut round: Vec<(usize, Viewport)> = Vec::new();
        for (d, ((_, global, _), plan)) in directions.iter().zip(plans).enumerate() {
            match plan {
                Ok(plan) => {
                    stats.add_plan(&plan.stats);
                    round.extend(plan.tiles.iter().map(|tile| (d, tile_viewport(global, tile))));
                }
                Err(e) => unplanned(stats, &e),
            }
        }
        // Without phase timing, the one submission's time is the analysis's.
        if !self.phase_timing {
            stats.analysis_seconds += seconds(t);
        }
        stats.plan_submissions += 1;

        // The planned tiles of all the directions in one submission: per tile the list
        // build, a copy of its node count into its slot and the resolve (which does nothing
        // when the count says the lists overflowed); the counts are read back once.
        // Overflowed tiles are split, and their parts make the next round.
        let capacity = cfg.node_capacity;
        while !round.is_empty() {
            let counts = self.tile_counts.slots(&gpu, round.len());
            // Phase timing: the current tile's build; otherwise the whole round.
            let mut t = Instant::now();
            let mut encoder = gpu.device.create_command_encoder(&Default::default());
            // Each tile's triangle ids stay alive until the submission.
            let mut drawn_ids = Vec::with_capacity(round.len());
            for (slot, (d, vp)) in round.iter().enumerate() {
                let frame = &directions[*d].0;
                if cancel.load(Ordering::Relaxed) {
                    return Err(BatchError::Cancelled);
                }
                // The tile draws only the triangles whose projected bounds meet it (as the
                // CPU gathers a tile's candidates): a whole-scene window would draw them all.
                let side = vp.width.max(vp.height) as f32 * vp.pixel;
                let (stack, out) = (&mut self.bounds_stack, &mut self.tile_triangles);
                scene.bounds.overlapping(frame, vp.corner(), side, stack, out);
                drawn_ids.push(DrawnIds::new(&gpu, out));
                let tile_drawn = Drawn::Uploaded(&drawn_ids[slot]);
                self.lists.encode(&gpu, &mut encoder, &self.triangles, tile_drawn, frame, vp, &self.list_buffers);
                self.list_buffers.encode_count_copy(&mut encoder, counts, 4 * slot as u64);
                let rect = Rectangle {
                    frame,
                    viewport: vp,
                    coincidence: scene.coincidence_at(vp.pixel),
                    sky: bundle.sky.seen(frame.dir),
                    scales,
                };
                let foreign = self.foreign.as_ref().filter(|_| foreign);
                let surfaces = self.surfaces.as_deref();
                let (triangles, sides, lists) = (&self.triangles, &self.sides, &self.list_buffers);
                if self.phase_timing {
                    submit_and_wait(&gpu, encoder)?;
                    stats.build_seconds += seconds(t);
                    let resolve_start = Instant::now();
                    encoder = gpu.device.create_command_encoder(&Default::default());
                    self.resolve.encode(&gpu, &mut encoder, triangles, sides, lists, buffers, foreign, surfaces, &rect);
                    submit_and_wait(&gpu, encoder)?;
                    stats.resolve_seconds += seconds(resolve_start);
                    encoder = gpu.device.create_command_encoder(&Default::default());
                    t = Instant::now();
                } else {
                    self.resolve.encode(&gpu, &mut encoder, triangles, sides, lists, buffers, foreign, surfaces, &rect);
                }
            }
            gpu.queue.submit([encoder.finish()]);
            let counts = self.tile_counts.read(&gpu, round.len())?;
            if !self.phase_timing {
                // Without phase timing, build and resolve share the submission.
                stats.build_seconds += seconds(t);
            }
            let mut next = Vec::new();
            let mut parts = Vec::new();
            for (&(d, vp), &count) in round.iter().zip(&counts) {
                if count > capacity && split_overflowed(&vp, count, capacity, &mut parts, stats) {
                    next.extend(parts.drain(..).map(|part| (d, part)));
                    continue;
                }
                stats.tiles += 1;
                stats.fragments += count;
                stats.peak_tile_fragments = stats.peak_tile_fragments.max(count);
            }
            stats.tile_rounds += 1;
            round = next;
        }
        stats.directions += jobs.len() as u64;
        Ok(())
    }
}

/// The node counts of a round of tiles, copied on the GPU slot by slot and read back once.
#[derive(Default)]
struct TileCounts {
    buffer: Option<wgpu::Buffer>,
}

impl TileCounts {
    /// A buffer with room for `n` counts (grown by doubling).
    fn slots(&mut self, gpu: &GpuContext, n: usize) -> &wgpu::Buffer {
        let bytes = 4 * n.max(1) as u64;
        if self.buffer.as_ref().is_none_or(|b| b.size() < bytes) {
            self.buffer = Some(gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("bundle tile counts"),
                size: bytes.next_power_of_two(),
                usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
                mapped_at_creation: false,
            }));
        }
        self.buffer.as_ref().expect("made above")
    }

    /// The first `n` counts of the submission just made.
    fn read(&self, gpu: &GpuContext, n: usize) -> Result<Vec<u64>, GpuError> {
        let Some(buffer) = &self.buffer else { return Ok(Vec::new()) };
        let bytes = gpu.read_buffer(buffer, 4 * n as u64)?;
        gpu.take_error()?;
        Ok(bytes.chunks_exact(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]) as u64).collect())
    }
}

impl GpuBundleBackend {
    /// Mirrors `source`'s foreign radiance on the GPU for the batch; why not, when the
    /// resolve has no kernel for it or the device cannot hold it.
    fn prepare_foreign(&mut self, source: &SourceRadiance) -> Result<(), String> {
        let shown = source.foreign.and_then(|f| f.as_any()).and_then(|a| a.downcast_ref::<ShownSource>());
        let Some(shown) = shown.filter(|s| Arc::ptr_eq(&s.bundle, &self.scene.bundle)) else {
            return Err("the GPU resolve evaluates only the runtime's shown light map for this scene".into());
        };
        let snapshot: &Arc<ShownLightmap> = &shown.shown;
        let pipeline = self.resolve.prepare_foreign(&self.gpu);
        let (gpu, bindings, scene) = (&self.gpu, &self.resolve.foreign, &self.scene.bundle);
        let surfaces = &mut self.surfaces;
        let result = pipeline.and_then(|()| match &mut self.foreign {
            Some(f) => f.sync(gpu, bindings, scene, snapshot),
            None => {
                let surfaces = match surfaces {
                    Some(s) => s.clone(),
                    None => {
                        let s = SceneSurfaces::new(gpu, &bindings.surfaces_layout, scene)?;
                        tracing::debug!("GPU resolve: scene materials uploaded ({} bytes)", s.bytes);
                        surfaces.insert(Arc::new(s)).clone()
                    }
                };
                ForeignRadiance::new(gpu, bindings, scene, snapshot, surfaces).map(|f| self.foreign = Some(f))
            }
        });
        result.map_err(|e| {
            // A mirror left half-synced is dropped; the next batch starts it anew.
            self.foreign = None;
            format!("the GPU cannot hold the shown light map or the scene's materials ({e})")
        })
    }
}

fn seconds(t: Instant) -> f64 {
    t.elapsed().as_secs_f64()
}

fn submit_and_wait(gpu: &GpuContext, encoder: wgpu::CommandEncoder) -> Result<(), GpuError> {
    gpu.queue.submit([encoder.finish()]);
    gpu.wait_idle()
}

impl BundleBackend for GpuBundleBackend {
    fn name(&self) -> &'static str {
        "gpu"
    }

    /// The target's buffers (host memory on a software adapter: sources, fixed-point sums
    /// and their read-back copy), made again for the next target, and the lane sums of the
    /// CPU backend running the light pass.
    fn release_texel_buffers(&mut self) {
        self.target_buffers = None;
        self.cpu.release_texel_buffers();
    }

    fn trace_batch(
        &mut self,
        target: &BakeTarget,
        batch: &[DirectionJob],
        source: &SourceRadiance,
        sums: &mut BatchSums,
        cancel: &AtomicBool,
    ) -> Result<PassStats, Cancelled> {
        let foreign = source.foreign.is_some();
        if foreign && let Err(why) = self.prepare_foreign(source) {
            if !self.warned_foreign {
                tracing::warn!("{why}: bakes that see surfaces outside their target run on the CPU backend");
                self.warned_foreign = true;
            }
            let mut stats = self.cpu.trace_batch(target, batch, source, sums, cancel)?;
            stats.cpu_fallback_batches += 1;
            return Ok(stats);
        }
        // The light pass on the CPU sizes and zeroes the sums; without light bundles the
        // sums are sized here.
        let mut stats = if batch.iter().any(|j| !j.lights.is_empty()) {
            self.cpu.trace_light_batch(target, batch, source, sums, cancel)?
        } else {
            let light = !self.scene.bundle.emitters.small.is_empty();
            if sums.fits(target.len(), light) {
                sums.clear();
            } else {
                *sums = BatchSums::with_light(target.len(), light);
            }
            PassStats::default()
        };
        match self.trace_global(target, batch, source, foreign, sums, cancel) {
            Ok(global) => {
                stats.add(&global);
                Ok(stats)
            }
            Err(BatchError::Cancelled) => Err(Cancelled),
            Err(BatchError::Gpu(e)) => {
                tracing::error!("GPU bundle batch failed ({e}); tracing it on the CPU backend");
                let mut stats = self.cpu.trace_batch(target, batch, source, sums, cancel)?;
                stats.cpu_fallback_batches += 1;
                Ok(stats)
            }
        }
    }
}

/// Makes GPU backends on one device; the per-scene CPU data is shared as the CPU
/// provider shares it.
pub struct GpuProvider {
    gpu: GpuContext,
    cpu: CpuProvider,
    phase_timing: bool,
}

impl GpuProvider {
    pub fn new(gpu: GpuContext) -> GpuProvider {
        GpuProvider { gpu, cpu: CpuProvider::new(), phase_timing: false }
    }

    /// Backends that time each phase apart (one wait per phase; for benchmarks).
    pub fn with_phase_timing(mut self, on: bool) -> GpuProvider {
        self.phase_timing = on;
        self
    }

    pub fn context(&self) -> &GpuContext {
        &self.gpu
    }
}

impl BackendProvider for GpuProvider {
    type Backend = GpuBundleBackend;

    fn name(&self) -> &'static str {
        "gpu"
    }

    fn backend(&self, scene: &Arc<BundleScene>, threads: usize) -> Result<GpuBundleBackend, BackendError> {
        GpuBundleBackend::new(self.gpu.clone(), self.cpu.scene(scene), threads, self.phase_timing)
    }
}

#[cfg(test)]
mod tests;
