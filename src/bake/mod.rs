//! The bake driver: scene → atlas → texel maps per LOD → irradiance per texel, with timings
//! and counts for the report. Backends compute the irradiance; this module owns everything
//! around them.

mod reference;
pub mod report;

use std::time::Instant;

use serde::Serialize;

use crate::atlas::{Atlas, AtlasConfig, AtlasError, TexelMap};
use crate::progress::Progress;
use crate::scene::{Rgb, Scene, SceneGeometry};

pub use report::{BakeReport, LodReport};

/// Which estimator computes texel irradiance.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum BackendKind {
    /// Per-texel path tracing (`reference` module): slow, unbiased ground truth.
    #[default]
    Reference,
}

impl BackendKind {
    pub fn name(self) -> &'static str {
        match self {
            BackendKind::Reference => "reference",
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
    /// Samples: paths per texel for the reference backend.
    pub samples: u32,
    pub backend: BackendKind,
    pub seed: u64,
    /// Worker threads; `None` uses every core.
    pub threads: Option<usize>,
}

impl Default for BakeConfig {
    fn default() -> Self {
        BakeConfig {
            atlas: AtlasConfig::default(),
            lods: 1,
            samples: 16,
            backend: BackendKind::default(),
            seed: 0,
            threads: None,
        }
    }
}

impl BakeConfig {
    pub fn threads(&self) -> usize {
        self.threads
            .unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1))
            .max(1)
    }
}

/// One baked level: its texel map and the irradiance (W/m², linear RGB) of every texel.
pub struct BakedLod {
    pub texels: TexelMap,
    pub irradiance: Vec<Rgb>,
}

impl BakedLod {
    /// Outgoing radiance of each texel of a diffuse surface: `Le + albedo/π · E`.
    pub fn radiance(&self) -> Vec<Rgb> {
        let t = &self.texels;
        (0..t.len())
            .map(|i| t.emission[i] + t.albedo[i] * self.irradiance[i] * std::f32::consts::FRAC_1_PI)
            .collect()
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
    #[error("--lods must be between 1 and {max}, got {got}")]
    BadLodCount { got: u32, max: u32 },
    #[error("--samples must be at least 1")]
    NoSamples,
    #[error("LOD {lod} would have {texels} texels, above the limit of {max}; use fewer --lods or a larger --texel-size")]
    LodTooLarge { lod: u32, texels: u64, max: u64 },
}

/// Largest atlas (pixels) a single LOD may have: 2^28 pixels is ~8 GB of texel data.
const MAX_LOD_PIXELS: u64 = 1 << 28;
const MAX_LODS: u32 = 8;

/// Bakes `config.lods` levels of `scene`'s light map (lit by `scene.sky` as well as its emitters).
pub fn bake(scene: &Scene, config: &BakeConfig, progress: &dyn Progress) -> Result<BakeOutput, BakeError> {
    if config.lods == 0 || config.lods > MAX_LODS {
        return Err(BakeError::BadLodCount { got: config.lods, max: MAX_LODS });
    }
    if config.samples == 0 {
        return Err(BakeError::NoSamples);
    }
    let started = Instant::now();
    let geom = SceneGeometry::new(scene);
    let atlas = Atlas::build(scene, &geom, &config.atlas)?;
    let hierarchy = atlas.lods(config.lods);
    for lod in 0..config.lods {
        let texels = hierarchy.texel_count(lod);
        if texels > MAX_LOD_PIXELS {
            return Err(BakeError::LodTooLarge { lod, texels, max: MAX_LOD_PIXELS });
        }
    }
    let mut report = BakeReport::new(scene, &atlas, config);
    let mut lods = Vec::new();
    let backend = reference::ReferenceBackend::new(scene, config);
    for lod in 0..config.lods {
        let t0 = Instant::now();
        let texels = TexelMap::build(scene, &geom, &atlas, lod);
        let texel_seconds = t0.elapsed().as_secs_f64();
        let (irradiance, stats) = backend.bake_lod(&texels, progress);
        report.lods.push(LodReport::new(&texels, texel_seconds, &stats, &irradiance));
        lods.push(BakedLod { texels, irradiance });
    }
    report.total_seconds = started.elapsed().as_secs_f64();
    Ok(BakeOutput { atlas, lods, report })
}

/// What a backend measured while baking one LOD.
#[derive(Clone, Debug, Default, Serialize)]
pub struct BackendStats {
    /// Samples per texel (reference: paths).
    pub samples_per_texel: u32,
    pub rays: u64,
    pub seconds: f64,
}
