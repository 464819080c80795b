//! The bake driver: scene → atlas → texel maps per LOD → irradiance per texel, with timings
//! and counts for the report. Backends compute the irradiance; this module owns everything
//! around them.

mod backend;
pub mod bundle;
pub mod half_source;
pub mod memory;
mod reference;
pub mod region_shard;
pub mod report;
pub mod rounds;

use std::time::Instant;

use serde::Serialize;

use std::sync::Arc;

use crate::atlas::lookup::TexelTable;
use crate::atlas::texels::Restore;
use crate::atlas::{Atlas, AtlasConfig, AtlasError, TexelMap};
use crate::bundle::{BundleConfig, BundleConfigError, BundleScene};
use crate::progress::Progress;
use crate::reference::Bvh;
use crate::scene::{Rgb, Scene, SceneGeometry};
use crate::shard::layout::{Layout, LayoutPlace, keep_layout, open_layout};

pub use report::{BakeReport, LodReport};

/// Which estimator computes texel irradiance.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum BackendKind {
    /// Per-texel path tracing (`reference` module): slow, unbiased ground truth.
    Reference,
    /// Adaptive ray bundles on CPU worker threads (`cpu` module).
    #[default]
    Cpu,
    /// Adaptive ray bundles on the GPU (`gpu::bundle_backend`; Vulkan, lavapipe without a GPU).
    Gpu,
    /// The GPU backend on a hardware adapter; on a software one the faster of the two,
    /// measured once (`gpu::choice`).
    Auto,
}

impl BackendKind {
    pub fn name(self) -> &'static str {
        match self {
            BackendKind::Reference => "reference",
            BackendKind::Cpu => "cpu",
            BackendKind::Gpu => "gpu",
            BackendKind::Auto => "auto",
        }
    }
}

/// Everything that determines a bake's result. Same config and scene ⇒ same light maps,
/// whatever the thread count.
#[derive(Clone, Debug, Serialize)]
pub struct BakeConfig {
    pub atlas: AtlasConfig,
    /// Number of LOD levels to bake (LOD 0 … lods−1).
    pub lods: u32,
    /// Samples: paths per texel for the reference backend, global bundle directions for
    /// bundle backends (overrides `bundle.directions`).
    pub samples: u32,
    pub backend: BackendKind,
    pub seed: u64,
    /// Bundle-backend parameters (its `directions` and `seed` come from `samples`/`seed`).
    pub bundle: BundleConfig,
    /// Worker threads; `None` uses every core.
    pub threads: Option<usize>,
    /// Most bytes the bake may hold (checked against an estimate before any texel map is
    /// built); `None`: three quarters of the machine's memory.
    pub memory_limit: Option<u64>,
    /// Whether the output's texel maps hold their positions and normals (24 B a texel,
    /// recomputed after the bundles of a bundle backend); without them they hold what
    /// light maps and their previews read. Not part of the result.
    #[serde(skip)]
    pub keep_texel_positions: bool,
    /// Bake LOD 0 in this many bounce rounds ([`rounds`]) instead of one progressive pass:
    /// what direction shards merged round by round equal. `None`: the progressive bake.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bounce_rounds: Option<u32>,
}

impl Default for BakeConfig {
    fn default() -> Self {
        BakeConfig {
            atlas: AtlasConfig::default(),
            lods: 1,
            samples: 256,
            backend: BackendKind::default(),
            seed: 0,
            bundle: BundleConfig::default(),
            threads: None,
            memory_limit: None,
            keep_texel_positions: true,
            bounce_rounds: None,
        }
    }
}

/// A shard's round in its report: refused when some directions found no tile plan;
/// otherwise the LOD's figures, the time so far and the measured memory.
fn report_shard_round(
    report: &mut BakeReport,
    texels: &TexelMap,
    texel_seconds: f64,
    config: &BakeConfig,
    stats: bundle::BundleLodStats,
    irradiance: &[Rgb],
    started: Instant,
) -> Result<(), BakeError> {
    if stats.pass.unplanned_directions > 0 {
        let (count, directions) = (stats.pass.unplanned_directions, stats.directions);
        return Err(BakeError::UnplannedDirections { lod: 0, count, directions });
    }
    let backend_stats = BackendStats {
        samples_per_texel: config.samples,
        rays: stats.pass.covered_pixels,
        seconds: stats.bundle_seconds + stats.punctual_seconds,
    };
    report.lods.push(LodReport::new(texels, texel_seconds, &backend_stats, irradiance, Some(stats)));
    report.total_seconds = started.elapsed().as_secs_f64();
    report.memory.measure();
    report.bytes_per_texel = report.memory.measured_bytes_per_texel;
    Ok(())
}

impl BakeConfig {
    /// The bundle parameters with this config's sample count and seed.
    pub fn bundle_config(&self) -> BundleConfig {
        BundleConfig { directions: self.samples, seed: self.seed, ..self.bundle.clone() }
    }

    pub fn threads(&self) -> usize {
        self.threads.unwrap_or_else(crate::parallel::available_threads).max(1)
    }
}

/// One baked level: its texel map and the irradiance (W/m², linear RGB) of every texel.
pub struct BakedLod {
    pub texels: TexelMap,
    pub irradiance: Vec<Rgb>,
}

impl BakedLod {
    /// Outgoing radiance of texel `i` of a diffuse surface: `Le + albedo/π · E`.
    #[inline]
    pub fn radiance_of(&self, i: usize) -> Rgb {
        let t = &self.texels;
        t.emission[i] + t.albedo[i] * self.irradiance[i] * std::f32::consts::FRAC_1_PI
    }
}

pub struct BakeOutput {
    pub atlas: Atlas,
    pub lods: Vec<BakedLod>,
    pub report: BakeReport,
}

#[derive(Debug, thiserror::Error)]
pub enum BakeError {
    #[error(transparent)]
    Atlas(#[from] AtlasError),
    #[error("the bundle backend is unavailable: {0}")]
    Backend(String),
    #[error("--lods must be between 1 and {max}, got {got}")]
    BadLodCount { got: u32, max: u32 },
    #[error("--samples must be at least 1")]
    NoSamples,
    #[error("--bounce-rounds must be between 1 and {max}, got {got}")]
    BadRounds { got: u32, max: u32 },
    #[error("a shard bakes LOD 0 alone (--lods 1), got --lods {0}")]
    ShardLods(u32),
    #[error("a shard needs --backend cpu or gpu (the same on every machine), got {0}")]
    ShardBackend(&'static str),
    #[error("the previous round's state has {previous} texels, this bake's atlas {texels}: not the same bake")]
    PreviousRound { texels: usize, previous: usize },
    #[error("cannot read the previous round's state: {0}")]
    PreviousState(#[from] crate::shard::ShardError),
    #[error("bounce rounds need a bundle backend (--backend cpu or gpu), not the reference path tracer")]
    RoundsNeedBundles,
    #[error("--samples must be at most {max}, got {got}")]
    TooManySamples { got: u32, max: u32 },
    #[error(
        "--nodes {nodes} cannot hold one bundle pixel of this scene: a line through it crosses {depth} surfaces, a node each, and tiles plan for {alpha} of the nodes; use --nodes {need} or more"
    )]
    NodesBelowDepthComplexity { nodes: u64, depth: u64, alpha: f32, need: u64 },
    #[error(transparent)]
    Bundle(#[from] BundleConfigError),
    #[error(
        "{count} of {directions} bundle directions of LOD {lod} could not be planned (see the log); the light map would miss their samples"
    )]
    UnplannedDirections { lod: u32, count: u64, directions: u64 },
    #[error(
        "{count} of {texels} texels of LOD {lod} have non-finite irradiance (texel {first} is {value}): the light \
         overflowed f32, as a point light almost touching a surface makes it; nothing was written"
    )]
    NonFiniteIrradiance { lod: u32, count: usize, texels: usize, first: usize, value: String },
    #[error(
        "LOD {lod} would have {pixels} atlas pixels, more than texel ids can number ({max}); use fewer --lods or a larger --texel-size"
    )]
    LodTooLarge { lod: u32, pixels: u64, max: u64 },
    #[error(
        "this bake needs {about}{need} ({texels} texels × {per_texel:.0} B, with {resident} already in use); the limit is {limit} ({limit_source}); {advice}",
        need = memory::human_bytes(.need),
        resident = memory::human_bytes(.resident),
        limit = memory::human_bytes(.limit)
    )]
    OutOfMemory {
        /// "~" for an estimate, "at least " for a lower bound.
        about: &'static str,
        need: u64,
        texels: u64,
        per_texel: f64,
        resident: u64,
        limit: u64,
        limit_source: &'static str,
        advice: String,
    },
}

/// Most samples a bake may take, a time bound: at the few milliseconds a bundle direction
/// (or a path per texel) costs on a room, 2²⁰ of them already take hours, at an error 64×
/// below that of the default 256.
pub const MAX_SAMPLES: u32 = 1 << 20;

/// Lines through the scene sampled to find its depth complexity (surfaces crossed by one
/// line, hence nodes taken by one bundle pixel).
const DEPTH_LINES: u32 = 1024;

/// Surfaces counted along a line before the count stops (beyond the node budget too).
const DEPTH_COUNT_CAP: u64 = 1024;

/// The most surfaces any of [`DEPTH_LINES`] lines through the scene's bounds (random
/// directions and offsets, fixed seed) crosses, counted up to `cap`: a lower bound of the
/// fragments one bundle pixel can hold.
fn depth_complexity(bvh: &Bvh, cap: u64) -> u64 {
    let Some((lo, hi)) = bvh.bounds() else { return 0 };
    let diag = (hi - lo).length().max(1e-6);
    let step = diag * 1e-5;
    let mut rng = crate::sampling::Rng::new(0xdeb7, 0);
    let mut most = 0u64;
    for _ in 0..DEPTH_LINES {
        let dir = crate::sampling::uniform_sphere(rng.next_vec2());
        let through = lo + (hi - lo) * glam::Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
        let origin = through - dir * diag;
        let (mut t, mut crossed) = (0.0f32, 0u64);
        while crossed < cap {
            match bvh.intersect(origin, dir, t, 2.0 * diag) {
                Some(hit) => {
                    crossed += 1;
                    t = hit.t + step;
                }
                None => break,
            }
        }
        most = most.max(crossed);
    }
    most
}

/// Refuses a node buffer that cannot hold one bundle pixel of the scene: such a pixel never
/// fits a tile, and every one would be built alone, over budget (minutes per bake at
/// `--nodes 1`).
pub fn check_node_capacity(bvh: &Bvh, config: &BundleConfig) -> Result<(), BakeError> {
    let budget = (config.alpha as f64 * config.node_capacity as f64).floor() as u64;
    let depth = depth_complexity(bvh, (budget + 1).max(DEPTH_COUNT_CAP));
    if depth > budget {
        let (nodes, alpha) = (config.node_capacity, config.alpha);
        let need = (depth as f64 / alpha as f64).ceil() as u64;
        return Err(BakeError::NodesBelowDepthComplexity { nodes, depth, alpha, need });
    }
    Ok(())
}

/// Most atlas pixels a LOD may have: pixel and texel ids are `u32`, [`crate::atlas::texels::NO_TEXEL`]
/// excluded. Memory is the tighter bound in practice ([`check_memory`]).
const MAX_LOD_PIXELS: u64 = u32::MAX as u64 - 1;
const MAX_LODS: u32 = 8;

/// Bakes `config.lods` levels of `scene`'s light map (lit by `scene.sky` as well as its emitters).
pub fn bake(scene: &Arc<Scene>, config: &BakeConfig, progress: &dyn Progress) -> Result<BakeOutput, BakeError> {
    config.validate()?;
    let started = Instant::now();
    let geom = SceneGeometry::new(scene);
    // The atlas options' own errors first (they say more than a memory figure would).
    config.atlas.validate()?;
    check_memory_early(scene, &geom, config)?;
    let atlas = Atlas::build(scene, &geom, &config.atlas)?;
    check_lod_sizes(&atlas, config.lods)?;
    let mut report = BakeReport::new(scene, &atlas, config);
    let mut lods: Vec<BakedLod> = Vec::new();
    match config.backend {
        BackendKind::Reference => {
            report.memory = check_memory(&atlas, config, memory::SceneTraits::LEAST.with_masks(scene))?;
            let backend = reference::ReferenceBackend::new(scene, config);
            report.memory.resident_at_start = memory::resident_bytes();
            for lod in 0..config.lods {
                let t0 = Instant::now();
                let texels = TexelMap::build(scene, &geom, &atlas, lod);
                let texel_seconds = t0.elapsed().as_secs_f64();
                let (irradiance, stats) = backend.bake_lod(&texels, progress);
                check_finite(lod, &irradiance)?;
                report.lods.push(LodReport::new(&texels, texel_seconds, &stats, &irradiance, None));
                lods.push(BakedLod { texels, irradiance });
            }
        }
        BackendKind::Cpu | BackendKind::Gpu | BackendKind::Auto => {
            let (bundle, bvh, mut backend) = bundle_setup(scene, &geom, &atlas, config, &mut report)?;
            for lod in 0..config.lods {
                let t0 = Instant::now();
                // Positions and normals only for a caller that keeps them: nothing the bake
                // runs reads them (the punctual pass places its points from each texel's
                // face and pixel; rounds read the albedo and emission).
                let restore = if config.keep_texel_positions { Restore::All } else { Restore::Albedo };
                let rounds = config.bounce_rounds.filter(|_| lod == 0);
                let mut texels = TexelMap::build_with(scene, &geom, &atlas, lod, restore);
                let texel_seconds = t0.elapsed().as_secs_f64();
                let coarser = lods.last().map(|l| bundle::CoarserLod { texels: &l.texels, irradiance: &l.irradiance });
                let never = std::sync::atomic::AtomicBool::new(false);
                let threads = config.threads();
                let baked = match rounds {
                    Some(r) => rounds::bake_lod_rounds(&bundle, &bvh, &mut *backend, &texels, r, threads, progress),
                    None => bundle::bake_lod_lean(
                        &bundle,
                        &bvh,
                        &mut *backend,
                        &mut texels,
                        coarser,
                        restore,
                        threads,
                        progress,
                        &never,
                    ),
                };
                let Ok(bundle::LodIrradiance { irradiance, stats: bstats, .. }) = baked else {
                    unreachable!("an offline bake is never cancelled")
                };
                check_finite(lod, &irradiance)?;
                if bstats.pass.unplanned_directions > 0 {
                    let (count, directions) = (bstats.pass.unplanned_directions, bstats.directions);
                    return Err(BakeError::UnplannedDirections { lod, count, directions });
                }
                let stats = BackendStats {
                    samples_per_texel: config.samples,
                    rays: bstats.pass.covered_pixels,
                    seconds: bstats.bundle_seconds + bstats.punctual_seconds,
                };
                report.lods.push(LodReport::new(&texels, texel_seconds, &stats, &irradiance, Some(bstats)));
                lods.push(BakedLod { texels, irradiance });
            }
        }
    }
    report.total_seconds = started.elapsed().as_secs_f64();
    report.memory.measure();
    report.bytes_per_texel = report.memory.measured_bytes_per_texel;
    Ok(BakeOutput { atlas, lods, report })
}

type BundleSetup = (Arc<BundleScene>, Bvh, Box<dyn crate::bundle::BundleBackend>);

/// What a bundle bake needs beside its texels: the bundle scene, the BVH and the backend,
/// after the memory and node-buffer checks (their figures into `report`).
fn bundle_setup(
    scene: &Arc<Scene>,
    geom: &SceneGeometry,
    atlas: &Atlas,
    config: &BakeConfig,
    report: &mut BakeReport,
) -> Result<BundleSetup, BakeError> {
    let bundle = Arc::new(BundleScene::new(
        scene.clone(),
        Arc::new(geom.clone()),
        Arc::new(atlas.clone()),
        config.bundle_config(),
    ));
    let traits = memory::SceneTraits::of(scene, geom, atlas, !bundle.emitters.small.is_empty());
    report.memory = check_memory(atlas, config, traits)?;
    let bvh = Bvh::for_scene(scene, geom);
    check_node_capacity(&bvh, &config.bundle_config())?;
    let backend = backend::bundle_backend(config.backend, &bundle, config.threads())?;
    report.backend = backend.name();
    // Measured from here: what grows with the texels (the scene, its BVH and the
    // per-triangle tables are resident already).
    report.memory.resident_at_start = memory::resident_bytes();
    Ok((bundle, bvh, backend))
}

/// What both kinds of shard ask of their options: valid, LOD 0 alone, one of `backends`.
fn check_shard_config(config: &BakeConfig, backends: &[BackendKind]) -> Result<(), BakeError> {
    config.validate()?;
    if config.lods != 1 {
        return Err(BakeError::ShardLods(config.lods));
    }
    if !backends.contains(&config.backend) {
        return Err(BakeError::ShardBackend(config.backend.name()));
    }
    Ok(())
}

/// One direction shard's bake: share `share` (index, count) of round `round` of LOD 0
/// ([`rounds`], docs/SHARDS.md), reading `previous`, round `round − 1`'s merged state.
pub struct ShardBake {
    pub atlas: Atlas,
    pub estimate: crate::bundle::progressive::ProgressiveEstimate,
    pub report: BakeReport,
}

/// The atlas and LOD 0's texel map (its albedo and emission, no positions or normals) of a
/// sharded bake: read from the layout file at `layout` when it holds this bake's, else
/// made and written there for the processes after this one (docs/SHARDS.md "The layout
/// file"). With the seconds of the texel map's making or of the layout's reading.
pub fn shard_layout(
    scene: &Scene,
    geom: &SceneGeometry,
    config: &BakeConfig,
    layout: Option<&LayoutPlace>,
) -> Result<(Layout, f64), BakeError> {
    let t0 = Instant::now();
    let limit = memory::described_limit(config.memory_limit);
    match layout.and_then(|p| open_layout(p, geom, true, limit)) {
        Some(read) => {
            check_lod_sizes(&read.atlas, 1)?;
            Ok((read, t0.elapsed().as_secs_f64()))
        }
        None => {
            let atlas = Atlas::build(scene, geom, &config.atlas)?;
            check_lod_sizes(&atlas, 1)?;
            let t0 = Instant::now();
            let texels = TexelMap::build_with(scene, geom, &atlas, 0, Restore::Albedo);
            let seconds = t0.elapsed().as_secs_f64();
            if let Some(place) = layout {
                keep_layout(place, &atlas, &texels);
            }
            Ok((Layout { atlas, texels }, seconds))
        }
    }
}

/// Bakes one direction shard (see [`ShardBake`]). Share 0 holds the punctual part (made in
/// round 1, taken from `previous` after), the other shares none, so that the merge counts
/// it once. The texel map has no positions and normals (the round and the punctual pass
/// read neither: 24 B a texel less), and the previous round is streamed from its file
/// (its irradiance, 12 B a texel, made into the round's source in place).
pub fn bake_shard(
    scene: &Arc<Scene>,
    config: &BakeConfig,
    round: u32,
    share: (u32, u32),
    previous: Option<&crate::shard::PreviousRound>,
    layout: Option<&LayoutPlace>,
    progress: &dyn Progress,
) -> Result<ShardBake, BakeError> {
    check_shard_config(config, &[BackendKind::Cpu, BackendKind::Gpu])?;
    let started = Instant::now();
    let geom = SceneGeometry::new(scene);
    config.atlas.validate()?;
    check_memory_early(scene, &geom, config)?;
    let (Layout { atlas, mut texels }, texel_seconds) = shard_layout(scene, &geom, config, layout)?;
    let mut report = BakeReport::new(scene, &atlas, config);
    let (bundle, bvh, mut backend) = bundle_setup(scene, &geom, &atlas, config, &mut report)?;
    if let Some(p) = previous
        && p.texels() != texels.len()
    {
        return Err(BakeError::PreviousRound { texels: texels.len(), previous: p.texels() });
    }
    let threads = config.threads();
    let mut punctual_seconds = 0.0;
    // Read by the punctual pass and the round's bundles.
    let table = TexelTable::of_map(&texels);
    let punctual = match (share.0, previous) {
        (0, Some(p)) => p.punctual(None)?,
        (0, None) => {
            let pass = bundle::PunctualPass::of_map(&bundle, &bvh, &texels, &table, threads);
            punctual_seconds = pass.seconds;
            pass.irradiance
        }
        _ => Vec::new(),
    };
    let irradiance = previous.map(|p| p.irradiance()).transpose()?;
    let source = rounds::round_source(&bundle, &texels, irradiance);
    // The round reads its source, not the albedo it was made from.
    texels.drop_albedo();
    let rounds::RoundSums { estimate, mut stats } = rounds::bake_round_from_source(
        &bundle,
        &mut *backend,
        &texels,
        &table,
        source,
        punctual,
        round,
        share,
        threads,
        progress,
    );
    stats.punctual_seconds = punctual_seconds;
    report_shard_round(&mut report, &texels, texel_seconds, config, stats, &estimate.irradiance(), started)?;
    Ok(ShardBake { atlas, estimate, report })
}

/// One region shard's round (see [`region_shard`]): its texels' sums, which charts and
/// texels of LOD 0 they are, and the report.
pub struct RegionShardBake {
    pub atlas: Atlas,
    pub estimate: crate::bundle::progressive::ProgressiveEstimate,
    /// The share's charts (ascending) and its texels' ids in the whole LOD (ascending).
    pub charts: Vec<u32>,
    pub texels: Vec<u32>,
    /// Texels of the whole LOD.
    pub whole_texels: usize,
    /// Bytes of what the share's bake held for its texels and the foreign lookup.
    pub held_bytes: usize,
    /// What it was expected to hold at its peak ([`region_shard::estimate`]).
    pub memory: memory::MemoryEstimate,
    pub report: BakeReport,
}

/// Bakes one region shard: share `share.0` of `share.1` of LOD 0's texels (whole charts,
/// [`region_shard::deal_charts`]), every batch of round `round`, the rest of the scene
/// seen through `previous` (round − 1's merged state, streamed: its irradiance and the
/// share's punctual part; the carried emission alone in round 1). Each share holds its own
/// texels' punctual part.
pub fn bake_region_shard(
    scene: &Arc<Scene>,
    config: &BakeConfig,
    round: u32,
    share: (u32, u32),
    previous: Option<&crate::shard::PreviousRound>,
    layout: Option<&LayoutPlace>,
    progress: &dyn Progress,
) -> Result<RegionShardBake, BakeError> {
    check_shard_config(config, &[BackendKind::Cpu])?;
    let started = Instant::now();
    let geom = SceneGeometry::new(scene);
    config.atlas.validate()?;
    // The single bake's early guard would count the whole LOD: a region shard is checked
    // against its own estimate once the atlas says how many texels the LOD has.

    region_shard::stage("geometry");
    // A layout made before (by a merge or a direction shard) read without the texels'
    // attributes: what `build_lookup` makes. A region shard makes none for the next: it
    // holds no attributes.
    let t0 = Instant::now();
    let limit = memory::described_limit(config.memory_limit);
    let (atlas, read) = match layout.and_then(|p| open_layout(p, &geom, false, limit)) {
        Some(Layout { atlas, texels }) => (atlas, Some((texels, t0.elapsed().as_secs_f64()))),
        None => (Atlas::build(scene, &geom, &config.atlas)?, None),
    };
    check_lod_sizes(&atlas, 1)?;
    region_shard::stage("atlas");
    let expected = region_shard::estimate(atlas.stats.covered_texels_lod0, share.1, previous.is_some(), config);
    tracing::info!(
        lod_texels = expected.texels,
        shares = share.1,
        texel_bytes = expected.texel_bytes,
        bytes = expected.bytes,
        "region shard memory estimate"
    );
    refuse_over_limit(&expected, config, false, config.atlas.texel_size, "")?;
    // Which texel is where, without its attributes: the shard asks them once, to make the
    // round's source, and holds them for its own texels alone.
    let (texels, texel_seconds) = match read {
        Some(read) => read,
        None => {
            let t0 = Instant::now();
            (TexelMap::build_lookup(scene, &geom, &atlas, 0), t0.elapsed().as_secs_f64())
        }
    };
    region_shard::stage("map");
    if let Some(p) = previous
        && p.texels() != texels.len()
    {
        return Err(BakeError::PreviousRound { texels: texels.len(), previous: p.texels() });
    }
    // The bundles are laid out as the whole LOD's: its lane count, not the share's.
    let mut whole = config.clone();
    whole.bundle.lanes = crate::bundle::Lanes::Fixed(config.bundle.lanes.for_texels(texels.len() as u64));
    let mut report = BakeReport::new(scene, &atlas, config);
    let (bundle, bvh, mut backend) = bundle_setup(scene, &geom, &atlas, &whole, &mut report)?;
    let threads = config.threads();
    let whole_texels = texels.len();
    region_shard::stage("setup");
    let r = region_shard::bake_region_round(
        &bundle,
        &bvh,
        &mut *backend,
        texels,
        previous,
        round,
        share,
        threads,
        progress,
    )?;
    let region_shard::RegionRound { estimate, stats, charts, texels: keep, map: sub, held_bytes } = r;
    report_shard_round(&mut report, &sub, texel_seconds, config, stats, &estimate.irradiance(), started)?;
    Ok(RegionShardBake { atlas, estimate, charts, texels: keep, whole_texels, held_bytes, memory: expected, report })
}

impl BakeConfig {
    /// Refuses what [`bake`] cannot run: the LOD count, no samples, bundle parameters.
    pub fn validate(&self) -> Result<(), BakeError> {
        if self.lods == 0 || self.lods > MAX_LODS {
            return Err(BakeError::BadLodCount { got: self.lods, max: MAX_LODS });
        }
        if self.samples == 0 {
            return Err(BakeError::NoSamples);
        }
        if self.samples > MAX_SAMPLES {
            return Err(BakeError::TooManySamples { got: self.samples, max: MAX_SAMPLES });
        }
        if let Some(r) = self.bounce_rounds {
            if !(1..=rounds::MAX_ROUNDS).contains(&r) {
                return Err(BakeError::BadRounds { got: r, max: rounds::MAX_ROUNDS });
            }
            if self.backend == BackendKind::Reference {
                return Err(BakeError::RoundsNeedBundles);
            }
        }
        self.bundle_config().validate()?;
        Ok(())
    }
}

/// Refuses a baked LOD with a non-finite texel: written out, it would poison every
/// consumer of the map (a mean of infinity, NaN in an engine's shader).
pub fn check_finite(lod: u32, irradiance: &[Rgb]) -> Result<(), BakeError> {
    let mut bad = irradiance.iter().enumerate().filter(|(_, e)| !e.is_finite());
    let Some((first, e)) = bad.next() else { return Ok(()) };
    let count = 1 + bad.count();
    Err(BakeError::NonFiniteIrradiance { lod, count, texels: irradiance.len(), first, value: format!("{e:?}") })
}

/// Refuses an atlas whose LODs 0 … `lods`−1 have more pixels than `u32` ids can number.
pub fn check_lod_sizes(atlas: &Atlas, lods: u32) -> Result<(), BakeError> {
    let hierarchy = atlas.lods(lods);
    for lod in 0..lods {
        let pixels = hierarchy.texel_count(lod);
        if pixels > MAX_LOD_PIXELS {
            return Err(BakeError::LodTooLarge { lod, pixels, max: MAX_LOD_PIXELS });
        }
    }
    Ok(())
}

/// The memory guard: estimates the peak of baking `config` on `atlas` ([`memory::estimate`];
/// `traits`: what the scene's lights and textures add) before anything per texel is
/// allocated and refuses it when that, with what the process already holds, exceeds the
/// limit (`config.memory_limit`, else 3/4 of the machine's memory). The error names the
/// options that lower it. Returns the memory part of the report, measured figures to come.
pub fn check_memory(
    atlas: &Atlas,
    config: &BakeConfig,
    traits: memory::SceneTraits,
) -> Result<memory::MemoryReport, BakeError> {
    let estimate = memory::estimate(atlas, config, traits);
    let (limit, source) = memory::memory_limit(config.memory_limit);
    refuse_over_limit(&estimate, config, traits.light_pass, Some(atlas.texel_size), "~")?;
    Ok(memory::MemoryReport {
        estimate,
        limit_bytes: limit,
        limit_source: Some(source),
        ..memory::MemoryReport::default()
    })
}

/// Share of `--texel-budget` taken as the least the atlas covers: its texel-size search
/// aims at the budget, and lands within ±20% of it (or above, on atlases of tiny charts).
const EARLY_BUDGET_SHARE: f64 = 0.8;

/// The guard before the atlas is built (under a second however fine the texels): a lower
/// bound of the texels — from the lit area alone with `--texel-size`
/// ([`crate::atlas::min_texels`]), else [`EARLY_BUDGET_SHARE`] of the budget — and no
/// light pass nor lane buffers, so what it refuses the full check would refuse too.
fn check_memory_early(scene: &Scene, geom: &SceneGeometry, config: &BakeConfig) -> Result<(), BakeError> {
    let texels = match config.atlas.texel_size {
        Some(_) => crate::atlas::min_texels(scene, geom, &config.atlas).unwrap_or(0),
        None => (config.atlas.texel_budget as f64 * EARLY_BUDGET_SHARE) as u64,
    };
    // Counted with one lane: `auto` gives the bake one, should it have more texels than this
    // lower bound.
    let mut one_lane = config.clone();
    if one_lane.bundle.lanes == crate::bundle::Lanes::Auto {
        one_lane.bundle.lanes = crate::bundle::Lanes::Fixed(1);
    }
    let mut estimate = memory::estimate_from_lod0(texels, None, &one_lane, memory::SceneTraits::LEAST);
    // The threads' buffers are counted at their most: not part of a lower bound.
    estimate.bytes = estimate.texel_bytes;
    estimate.thread_bytes = 0;
    estimate.bytes_per_texel = estimate.bytes as f64 / estimate.texels.max(1) as f64;
    refuse_over_limit(&estimate, config, false, config.atlas.texel_size, "at least ")
}

/// Refuses `estimate` (of a bake at `texel_size` m, when known) when it, with what the process holds
/// already, exceeds the limit; the error says which options bring it within.
fn refuse_over_limit(
    estimate: &memory::MemoryEstimate,
    config: &BakeConfig,
    light_pass: bool,
    texel_size: Option<f32>,
    about: &'static str,
) -> Result<(), BakeError> {
    let (limit, source) = memory::memory_limit(config.memory_limit);
    let resident = memory::resident_bytes().unwrap_or(0);
    let need = estimate.bytes.saturating_add(resident);
    if need > limit {
        // Texels scale as 1/texel size²: the size (or budget) that brings the texel part
        // within what is left, with 5% to spare.
        let fixed = estimate.thread_bytes.saturating_add(estimate.texture_bytes).saturating_add(estimate.passing_bytes);
        let room = limit.saturating_sub(resident).saturating_sub(fixed) as f64;
        let shrink = estimate.texel_bytes as f64 / room.max(1.0) * 1.05;
        let size = texel_size.map(|t| memory::metres(t as f64 * shrink.sqrt()));
        let mut advice = if room < 1.0 {
            "raise --memory-limit (what does not grow with the texels alone exceeds it), or lower --nodes".to_string()
        } else if let (Some(_), Some(size)) = (config.atlas.texel_size, &size) {
            format!("raise --texel-size to at least {size} m")
        } else {
            let budget = ((config.atlas.texel_budget as f64 / shrink) as u64).max(1);
            match &size {
                Some(size) => {
                    format!("lower --texel-budget to at most {budget} (or give --texel-size of at least {size} m)")
                }
                None => format!("lower --texel-budget to at most {budget}"),
            }
        };
        if config.lods > 1 {
            advice.push_str(&format!(
                ", or bake fewer --lods (each finer one has 4× the texels of the one before; {} now)",
                config.lods
            ));
        }
        if estimate.lanes > 1 {
            advice.push_str(&format!(
                ", or give --lanes 1 ({} now, {} B a texel each)",
                estimate.lanes,
                16 + 12 * u64::from(light_pass)
            ));
        }
        let limit_source = match source {
            memory::LimitSource::Option => "--memory-limit",
            memory::LimitSource::Machine => "3/4 of this machine's memory; --memory-limit sets it",
        };
        return Err(BakeError::OutOfMemory {
            about,
            need,
            texels: estimate.texels,
            per_texel: estimate.bytes_per_texel,
            resident,
            limit,
            limit_source,
            advice,
        });
    }
    Ok(())
}

/// What a backend measured while baking one LOD.
#[derive(Clone, Debug, Default, Serialize)]
pub struct BackendStats {
    /// Samples per texel (reference: paths; bundles: global directions).
    pub samples_per_texel: u32,
    /// Rays cast (reference) or effective bundle rays: bundle pixels with a fragment, summed
    /// over directions (bundles).
    pub rays: u64,
    pub seconds: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The light ceiling (`scene::radiometry`) is derived for the most directions and
    /// batches a bake can take.
    #[test]
    fn the_light_ceiling_covers_the_longest_bake() {
        use crate::scene::radiometry::{MOST_BATCHES, MOST_DIRECTIONS};
        assert_eq!(MAX_SAMPLES as f64, MOST_DIRECTIONS);
        assert_eq!((MAX_SAMPLES / crate::bundle::MIN_BATCH_SIZE) as f64, MOST_BATCHES);
    }

    #[test]
    fn non_finite_texels_are_counted_and_named() {
        let mut e = vec![Rgb::ONE; 10];
        assert!(check_finite(0, &e).is_ok());
        e[3].y = f32::NAN;
        e[7].x = f32::INFINITY;
        let Err(BakeError::NonFiniteIrradiance { lod, count, texels, first, .. }) = check_finite(2, &e) else {
            panic!("non-finite texels passed")
        };
        assert_eq!((lod, count, texels, first), (2, 2, 10, 3));
    }
}
