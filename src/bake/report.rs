//! `report.json`: what was baked, how, how long each phase took and how many rays it cost.

use serde::Serialize;

use crate::atlas::{Atlas, AtlasStats, TexelMap};
use crate::scene::{LoadStats, Rgb, Scene};

use super::bundle::BundleLodStats;
use super::memory::MemoryReport;
use super::{BackendStats, BakeConfig};

#[derive(Clone, Debug, Serialize)]
pub struct SceneReport {
    pub source: Option<String>,
    pub meshes: usize,
    pub triangles: usize,
    pub materials: usize,
    pub emissive_materials: usize,
    pub punctual_lights: usize,
    pub cameras: usize,
    /// The geometry's box in the file's coordinates (metres).
    pub bounds_min: Option<[f64; 3]>,
    pub bounds_max: Option<[f64; 3]>,
    /// Where the scene's frame has its origin, in the file's coordinates: zero unless the
    /// scene lies far from the file's origin ([`crate::scene::Scene::origin`]).
    pub origin: [f64; 3],
    /// Uniform sky radiance used, W/(sr·m²).
    pub sky: [f32; 3],
    pub load: LoadStats,
}

#[derive(Clone, Debug, Serialize)]
pub struct AtlasReport {
    /// Metres per texel at LOD 0.
    pub texel_size: f32,
    pub width: u32,
    pub height: u32,
    #[serde(flatten)]
    pub stats: AtlasStats,
}

#[derive(Clone, Debug, Serialize)]
pub struct LodReport {
    pub lod: u32,
    pub width: u32,
    pub height: u32,
    /// Texels covered by a face (the ones baked).
    pub texels: usize,
    pub gutter_texels: usize,
    pub texel_map_seconds: f64,
    pub bake_seconds: f64,
    pub samples_per_texel: u32,
    pub rays: u64,
    pub rays_per_second: f64,
    /// Mean irradiance over texels, W/m² (a quick sanity figure).
    pub mean_irradiance: [f32; 3],
    /// Texels whose estimate is not finite (must be 0).
    pub non_finite_texels: usize,
    /// Bundle backends: Table 1 phases, tiles, overflow and false alarms (see `bundle`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bundle: Option<BundleReport>,
}

/// Bundle-bake figures of one LOD, including the paper's Table 1 (milliseconds per direction
/// per phase) and Table 2 (overflow and false-alarm ratios).
#[derive(Clone, Debug, Serialize)]
pub struct BundleReport {
    pub per_direction_ms: PhaseMs,
    pub tiles_per_direction: f64,
    pub overflow_ratio: f64,
    /// `None` unless measured ([`crate::bundle::BundleConfig::measure_false_alarms`]).
    pub false_alarm_ratio: Option<f64>,
    pub fragments_per_second: f64,
    /// Global-bundle pixels with at least one fragment per second of bundle time.
    pub effective_rays_per_second: f64,
    /// The same counting the light pass's rays too (light-bundle pixels that cross an
    /// emitter), per second of bundle time.
    pub effective_rays_per_second_with_light_pass: f64,
    #[serde(flatten)]
    pub stats: BundleLodStats,
}

#[derive(Clone, Debug, Serialize)]
pub struct PhaseMs {
    pub analysis: f64,
    pub mip: f64,
    pub subdivision: f64,
    pub build: f64,
    pub resolve: f64,
    pub light_pass: f64,
}

impl BundleReport {
    pub fn new(stats: BundleLodStats) -> Self {
        let p = &stats.pass;
        let d = p.directions.max(1) as f64;
        let ms = |s: f64| s * 1000.0 / d;
        let secs = stats.bundle_seconds.max(1e-9);
        BundleReport {
            per_direction_ms: PhaseMs {
                analysis: ms(p.analysis_seconds),
                mip: ms(p.mip_seconds),
                subdivision: ms(p.subdivision_seconds),
                build: ms(p.build_seconds),
                resolve: ms(p.resolve_seconds),
                light_pass: ms(p.light_seconds),
            },
            tiles_per_direction: p.tiles as f64 / d,
            overflow_ratio: p.overflow_ratio(),
            false_alarm_ratio: p.false_alarm_ratio(),
            fragments_per_second: (p.fragments + p.light_fragments) as f64 / secs,
            effective_rays_per_second: p.covered_pixels as f64 / secs,
            effective_rays_per_second_with_light_pass: (p.covered_pixels + p.light_covered_pixels) as f64 / secs,
            stats,
        }
    }
}

impl LodReport {
    pub fn new(
        texels: &TexelMap,
        texel_seconds: f64,
        stats: &BackendStats,
        irradiance: &[Rgb],
        bundle: Option<BundleLodStats>,
    ) -> Self {
        let finite: Vec<&Rgb> = irradiance.iter().filter(|e| e.is_finite()).collect();
        let mean = finite.iter().fold(glam::DVec3::ZERO, |a, e| a + e.as_dvec3()) / finite.len().max(1) as f64;
        LodReport {
            lod: texels.lod,
            width: texels.width,
            height: texels.height,
            texels: texels.len(),
            gutter_texels: texels.gutter.len(),
            texel_map_seconds: texel_seconds,
            bake_seconds: stats.seconds,
            samples_per_texel: stats.samples_per_texel,
            rays: stats.rays,
            rays_per_second: if stats.seconds > 0.0 { stats.rays as f64 / stats.seconds } else { 0.0 },
            mean_irradiance: mean.as_vec3().to_array(),
            non_finite_texels: irradiance.len() - finite.len(),
            bundle: bundle.map(BundleReport::new),
        }
    }
}

/// Wall-clock seconds of each phase the CLI runs around the bake.
#[derive(Clone, Debug, Default, Serialize)]
pub struct PhaseTimings {
    pub load: f64,
    pub write: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct BakeReport {
    pub livebake_version: &'static str,
    pub backend: &'static str,
    pub config: BakeConfig,
    pub threads: usize,
    pub scene: SceneReport,
    pub atlas: AtlasReport,
    pub lods: Vec<LodReport>,
    pub phases: PhaseTimings,
    /// Atlas + texel maps + baking, seconds (excludes load and write; see `phases`).
    pub total_seconds: f64,
    /// Measured bytes per texel: the peak growth of the resident set over the bake (and, for
    /// `livebake bake`, the writing of its light maps) per texel baked (all LODs); `null`
    /// where /proc cannot be read. `memory` has the estimate beside it.
    pub bytes_per_texel: Option<f64>,
    pub memory: MemoryReport,
}

impl BakeReport {
    pub fn new(scene: &Scene, atlas: &Atlas, config: &BakeConfig) -> Self {
        let bounds = scene.bounds();
        BakeReport {
            livebake_version: env!("CARGO_PKG_VERSION"),
            backend: config.backend.name(),
            config: config.clone(),
            threads: config.threads(),
            scene: SceneReport {
                source: scene.source.as_ref().map(|p| p.display().to_string()),
                meshes: scene.meshes.len(),
                triangles: scene.triangle_count(),
                materials: scene.materials.len(),
                emissive_materials: scene.materials.iter().filter(|m| m.is_emissive()).count(),
                punctual_lights: scene.lights.len(),
                cameras: scene.cameras.len(),
                bounds_min: bounds.map(|b| scene.to_file(b.0).to_array()),
                bounds_max: bounds.map(|b| scene.to_file(b.1).to_array()),
                origin: scene.origin.to_array(),
                sky: scene.sky.to_array(),
                load: scene.stats.clone(),
            },
            atlas: AtlasReport {
                texel_size: atlas.texel_size,
                width: atlas.width,
                height: atlas.height,
                stats: atlas.stats.clone(),
            },
            lods: Vec::new(),
            phases: PhaseTimings::default(),
            total_seconds: 0.0,
            bytes_per_texel: None,
            memory: MemoryReport::default(),
        }
    }
}
