//! The adaptive ray-bundle baker's pure-Rust building blocks (Tokuyoshi et al. 2013): the
//! unit-testable specification that the GPU passes are later held equal to.
//!
//! Per bundle direction ω the baker
//! 1. takes ω and the pixel-grid jitter from [`directions::BundleDirections`]: a progressive,
//!    stratified sequence of lines (ω and −ω are one bundle, pdf 1/(2π) per hemisphere);
//! 2. rasterises an R×R analysis pass along ω into an importance map (rays needed per unit
//!    area, reduced by max) and a fragment-count map (depth complexity, reduced by average),
//!    whose chains down to 1×1 are [`mips::MipChain`]s;
//! 3. plans the tiles of that direction with [`tiles::TilePlanner`] (Eq. 1–3, Program 1):
//!    each tile gets a bundle resolution that meets its importance while its predicted
//!    per-pixel linked-list nodes fit the node buffer.
//!
//! Nothing here touches the GPU.

pub mod directions;
pub mod emitters;
pub mod estimator;
pub mod mips;
pub mod progressive;
pub mod raster;
pub mod sky;
pub mod stats;
pub mod target;
pub mod through;
pub mod tiles;
pub mod window;

use glam::{Vec2, Vec3};
use serde::Serialize;

use tiles::TilingMode;

pub use target::{
    BackendError, BackendProvider, BakeTarget, BundleBackend, BundleScene, Cancelled, SourceRadiance, SurfaceRadiance,
};

/// Parameters of a ray-bundle bake. Same config and scene ⇒ same light map, whatever the
/// thread count.
#[derive(Clone, Debug, Serialize)]
pub struct BundleConfig {
    /// Global bundle directions (each serves ω and −ω).
    pub directions: u32,
    /// Side R of the analysis maps (power of two).
    pub analysis_res: u32,
    /// Side W of the head-pointer buffer: at most W×W bundle pixels per tile.
    pub head_side: u32,
    /// Node-buffer capacity N: at most N fragments per tile.
    pub node_capacity: u64,
    /// α of Eq. 2–3.
    pub alpha: f32,
    #[serde(serialize_with = "serialize_tiling")]
    pub tiling: TilingMode,
    /// Bundle pixels per texel side at the importance the texel density asks for. At 2 a
    /// texel is hit from every direction (≈4·|cosθ| pixels), so its estimate averages all D
    /// stratified directions instead of the ~D/2 that happen to land a pixel in it: on a
    /// Cornell-style room 256 directions gave 2.9% error at 2 against 5.7% at 1, for ~2.3×
    /// the time (error²·time 2.1e-4 against 3.6e-4).
    pub oversampling: f32,
    /// Light-pass directions per global direction, per small emitter group.
    pub light_directions: u32,
    /// Emitter groups smaller than this fraction of the lit area get the light pass.
    pub small_emitter_fraction: f64,
    /// Most directions per batch: the radiance later directions read is refreshed after
    /// each batch. Fewer are used when that gives fewer than [`MIN_BATCHES`] batches.
    pub directions_per_batch: u32,
    /// Independent accumulation lanes a batch is split into ([`Lanes`]). Results depend on
    /// this (float sums in another order) but not on the thread count.
    pub lanes: Lanes,
    /// Re-count memory splits to report the false-alarm ratio (one extra count pass each;
    /// off but for the tiling bench).
    pub measure_false_alarms: bool,
    pub seed: u64,
}

fn serialize_tiling<S: serde::Serializer>(t: &TilingMode, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(&match t {
        TilingMode::None => "none".to_string(),
        TilingMode::Uniform { k } => format!("uniform:{k}"),
        TilingMode::Adaptive => "adaptive".to_string(),
    })
}

impl Default for BundleConfig {
    fn default() -> Self {
        BundleConfig {
            directions: 256,
            analysis_res: 128,
            head_side: 512,
            node_capacity: 1 << 20,
            alpha: tiles::DEFAULT_ALPHA,
            tiling: TilingMode::Adaptive,
            oversampling: 2.0,
            light_directions: 16,
            small_emitter_fraction: 0.05,
            directions_per_batch: 8,
            lanes: Lanes::Auto,
            measure_false_alarms: false,
            seed: 0,
        }
    }
}

/// Smallest head-pointer side W: every tile pays a set-up (gathering and setting up each
/// triangle that meets it); below 16×16 pixels that costs more than the tile's rays, and a
/// direction is cut into tens of thousands of tiles.
pub const MIN_HEAD_SIDE: u32 = 16;
/// Largest head-pointer side W: the buffer holds W² entries per lane (1 GiB at 16384).
pub const MAX_HEAD_SIDE: u32 = 16384;
/// Most bundle pixels per texel side: a direction costs its square (256 bundle pixels per
/// texel at 16); beyond, more directions lower the error more than more pixels per direction.
pub const MAX_OVERSAMPLING: f32 = 16.0;
/// Most light-pass directions per global direction and small emitter group: each is a full
/// light bundle, so the light pass alone would take over a thousand times the global pass.
pub const MAX_LIGHT_DIRECTIONS: u32 = 1024;

/// Most accumulation lanes: each lane keeps its own per-texel sums (28 B a texel); more lanes
/// than cores only cost memory.
pub const MAX_LANES: u32 = 64;

/// Texels from which [`Lanes::Auto`] gives a target one lane. A lane is a set of hit sums for
/// its share of the batch's directions (16 B a texel, 28 B with a light pass), traced in
/// order; the threads share the lanes, and a thread working ahead of its lane's next unit
/// keeps that unit's hits as records until its turn (`cpu::batch`). Two lanes on two threads
/// never record but hold a second set of sums and add it to the first after every batch; one
/// lane holds one set, records about half the hits and shares its sums' cache lines between
/// the cores. Measured side by side with one build on this project's 2-core machine (Van
/// Gogh room, 4 M texels, 32 directions, medians of 6): one lane took 8% longer (16% more CPU
/// time) and peaked 12% lower (345 against 394 MB); with a light pass and a point light 7%
/// longer and 16% lower (475 against 566 MB). On the Cornell box (0.5 M texels, where the
/// sums are small beside what does not grow with them) one lane was 9–20% slower.
pub const AUTO_ONE_LANE_TEXELS: u64 = 1 << 20;

/// How many accumulation lanes a batch is split into.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Lanes {
    /// One lane for a target of [`AUTO_ONE_LANE_TEXELS`] texels or more, else two.
    #[default]
    Auto,
    /// This many for every target (1 ..= [`MAX_LANES`]).
    Fixed(u32),
}

impl Lanes {
    /// The lanes of a target of `texels` texels.
    pub fn for_texels(self, texels: u64) -> u32 {
        match self {
            Lanes::Auto if texels >= AUTO_ONE_LANE_TEXELS => 1,
            Lanes::Auto => 2,
            Lanes::Fixed(n) => n.max(1),
        }
    }

    /// The most lanes any target gets.
    pub fn most(self) -> u32 {
        match self {
            Lanes::Auto => 2,
            Lanes::Fixed(n) => n.max(1),
        }
    }
}

impl std::fmt::Display for Lanes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Lanes::Auto => f.write_str("auto"),
            Lanes::Fixed(n) => write!(f, "{n}"),
        }
    }
}

impl std::str::FromStr for Lanes {
    type Err = String;

    /// `auto` or a count (its range is checked by [`BundleConfig::validate`], which names the
    /// limit).
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim() {
            "auto" => Ok(Lanes::Auto),
            n => n.parse().map(Lanes::Fixed).map_err(|_| format!("expected `auto` or a lane count, got `{s}`")),
        }
    }
}

impl Serialize for Lanes {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Lanes::Auto => s.serialize_str("auto"),
            Lanes::Fixed(n) => s.serialize_u32(*n),
        }
    }
}

/// Errors in a bundle configuration.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BundleConfigError {
    #[error("analysis resolution R (--analysis-res) must be a power of two between 2 and 4096, got {0}")]
    AnalysisRes(u32),
    #[error("head-pointer side W (--head-side) must be between {MIN_HEAD_SIDE} and {MAX_HEAD_SIDE}, got {0}")]
    HeadSide(u32),
    #[error("node capacity N (--nodes) must be at least 1")]
    NodeCapacity,
    #[error("alpha (--alpha) must be in (0, 1], got {0}")]
    Alpha(f32),
    #[error("oversampling (--oversampling) must be a positive number at most {MAX_OVERSAMPLING}, got {0}")]
    Oversampling(f32),
    #[error(
        "light-pass directions (--light-directions) must be between 1 and {MAX_LIGHT_DIRECTIONS}, got {0} (0 would drop the direct light of small emitters)"
    )]
    LightDirections(u32),
    #[error("accumulation lanes (--lanes) must be `auto` or between 1 and {MAX_LANES}, got {0}")]
    Lanes(u32),
    #[error("directions per batch must be at least 1")]
    Batching,
}

/// Multi-bounce needs source refreshes (one bounce each, see [`progressive`]): a bake is
/// split into at least this many batches when its directions allow.
pub const MIN_BATCHES: u32 = 32;

/// Batches of a progressive bake given the fewest directions a batch may have before the
/// batches grow to [`BundleConfig::batch_size`]: 32 Jacobi steps take an albedo-weighted
/// return of 0.9 (a bright, mostly enclosed space) to 3% of its first bounce, where the
/// (b+1)²-weighted mean of the batches then leaves ~1.5% of it (0.3% at 0.85).
pub const EARLY_BATCHES: u32 = 32;

/// Fewest directions a batch gets (fewer than [`MIN_BATCHES`] batches rather than fewer):
/// the CPU backend's threads run one direction's units while another's largest tile
/// finishes, so a batch of one direction leaves them idle behind its largest tile (a
/// quarter more time at 32 directions on the Van Gogh room).
pub const MIN_BATCH_SIZE: u32 = 2;

impl BundleConfig {
    /// Program 1's parameters for an analysis window of `pixel`-metre pixels (both backends
    /// plan with these).
    pub fn tile_params(&self, pixel: f32) -> tiles::TileParams {
        tiles::TileParams {
            w: self.head_side,
            n: self.node_capacity,
            alpha: self.alpha,
            pixel_area: (pixel as f64).powi(2),
        }
    }

    /// Directions per batch for this bake: at most `directions_per_batch`, fewer if that
    /// leaves under [`MIN_BATCHES`] batches, but at least [`MIN_BATCH_SIZE`] and one per lane.
    pub fn batch_size(&self) -> u32 {
        (self.directions / MIN_BATCHES).clamp(self.least_batch(), self.directions_per_batch.max(self.least_batch()))
    }

    /// The fewest directions a batch may have: [`MIN_BATCH_SIZE`], and one per lane.
    fn least_batch(&self) -> u32 {
        MIN_BATCH_SIZE.max(self.lanes.most())
    }

    /// Directions of batch `b` (from 0) of a bake whose source is its own running estimate
    /// (multi-bounce by Jacobi steps, [`progressive`]): the first [`EARLY_BATCHES`] have the
    /// fewest directions a batch may have, the rest [`batch_size`](Self::batch_size). Each
    /// batch adds one bounce to the source, so a bake of a few batches stays short of the
    /// bounces a bright, enclosed scene needs (its reflected light falls short by ~ρ^b after
    /// b batches, for an albedo-weighted return ρ): 16 batches of 8 directions left zdm2's
    /// points lit mostly by bounced light 9–13% too dark, where the same directions in
    /// smaller batches first converge the bounces before the batches grow.
    pub fn progressive_batch(&self, b: u64) -> u32 {
        if b < EARLY_BATCHES as u64 { self.least_batch().min(self.batch_size()) } else { self.batch_size() }
    }

    pub fn validate(&self) -> Result<(), BundleConfigError> {
        if !self.analysis_res.is_power_of_two() || !(2..=4096).contains(&self.analysis_res) {
            return Err(BundleConfigError::AnalysisRes(self.analysis_res));
        }
        if !(MIN_HEAD_SIDE..=MAX_HEAD_SIDE).contains(&self.head_side) {
            return Err(BundleConfigError::HeadSide(self.head_side));
        }
        if self.node_capacity == 0 {
            return Err(BundleConfigError::NodeCapacity);
        }
        if !(self.alpha > 0.0 && self.alpha <= 1.0) {
            return Err(BundleConfigError::Alpha(self.alpha));
        }
        if !(self.oversampling.is_finite() && self.oversampling > 0.0 && self.oversampling <= MAX_OVERSAMPLING) {
            return Err(BundleConfigError::Oversampling(self.oversampling));
        }
        if !(1..=MAX_LIGHT_DIRECTIONS).contains(&self.light_directions) {
            return Err(BundleConfigError::LightDirections(self.light_directions));
        }
        if let Lanes::Fixed(n) = self.lanes
            && !(1..=MAX_LANES).contains(&n)
        {
            return Err(BundleConfigError::Lanes(n));
        }
        if self.directions_per_batch == 0 {
            return Err(BundleConfigError::Batching);
        }
        Ok(())
    }
}

/// One global bundle direction and the light bundles traced with it.
#[derive(Clone, Debug)]
pub struct DirectionJob {
    pub index: u64,
    pub dir: Vec3,
    /// Sub-pixel shift of the bundle grid, in [0,1)² of an analysis pixel.
    pub jitter: Vec2,
    pub lights: Vec<LightJob>,
}

/// One light bundle: a direction through one emitter group's footprint.
#[derive(Clone, Debug)]
pub struct LightJob {
    pub group: u32,
    pub dir: Vec3,
    pub jitter: Vec2,
}

/// The direction sequences of a bake: one for global bundles, one per light-pass group,
/// each derived from the seed alone (direction i is the same whichever batch asks for it).
pub struct JobSequence {
    global: directions::BundleDirections,
    lights: Vec<directions::BundleDirections>,
    per_direction: u64,
}

impl JobSequence {
    pub fn new(seed: u64, groups: usize, light_directions: u32) -> Self {
        use crate::sampling::mix64;
        JobSequence {
            global: directions::BundleDirections::new(seed),
            lights: (0..groups).map(|g| directions::BundleDirections::new(mix64(seed ^ mix64(g as u64 + 1)))).collect(),
            per_direction: light_directions as u64,
        }
    }

    /// Global direction `i` and its light bundles.
    pub fn job(&self, i: u64) -> DirectionJob {
        let lights = self
            .lights
            .iter()
            .enumerate()
            .flat_map(|(g, dirs)| {
                (0..self.per_direction).map(move |j| {
                    let k = i * self.per_direction + j;
                    LightJob { group: g as u32, dir: dirs.direction(k), jitter: dirs.jitter(k) }
                })
            })
            .collect();
        DirectionJob { index: i, dir: self.global.direction(i), jitter: self.global.jitter(i), lights }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `auto` gives targets of 2²⁰ texels and more one lane and smaller ones two; a count
    /// is taken for every target; the option reads back as it was written, and counts out
    /// of range are refused by the validation.
    #[test]
    fn lanes_are_auto_or_a_count() {
        let auto: Lanes = "auto".parse().expect("auto");
        assert_eq!((auto.for_texels(AUTO_ONE_LANE_TEXELS - 1), auto.for_texels(AUTO_ONE_LANE_TEXELS)), (2, 1));
        let three: Lanes = "3".parse().expect("a count");
        assert_eq!((three.for_texels(10), three.for_texels(1 << 30), three.most()), (3, 3, 3));
        assert_eq!((auto.to_string(), three.to_string()), ("auto".to_string(), "3".to_string()));
        assert!("two".parse::<Lanes>().is_err());
        for bad in [0, MAX_LANES + 1] {
            let config = BundleConfig { lanes: Lanes::Fixed(bad), ..BundleConfig::default() };
            assert_eq!(config.validate(), Err(BundleConfigError::Lanes(bad)));
        }
    }
}
