//! Bundle backends in the bake driver: directions in batches, light jobs per emitter group,
//! the punctual pass, and the progressive estimate of one LOD.

use std::time::Instant;

use glam::Vec2;
use serde::Serialize;

use crate::atlas::{Atlas, TexelMap};
use crate::bundle::directions::BundleDirections;
use crate::bundle::emitters::{EmitterPlan, plan_emitters};
use crate::bundle::progressive::{BatchSums, ProgressiveEstimate, SourceKind};
use crate::bundle::stats::PassStats;
use crate::bundle::{BundleBackend, BundleConfig, DirectionJob, LightJob};
use crate::cpu::prepared::NO_GROUP;
use crate::cpu::punctual::punctual_irradiance;
use crate::cpu::{CpuBundleBackend, PreparedScene};
use crate::progress::Progress;
use crate::reference::{Bvh, ray_epsilon};
use crate::sampling::mix64;
use crate::scene::{Rgb, Scene, SceneGeometry};

/// What one LOD's bundle bake did.
#[derive(Clone, Debug, Default, Serialize)]
pub struct BundleLodStats {
    pub directions: u64,
    pub batches: u64,
    pub light_directions_per_group: u64,
    pub light_pass_groups: usize,
    pub emitter_triangles_in_global_bundles: usize,
    pub punctual_seconds: f64,
    pub bundle_seconds: f64,
    /// Texels no global bundle hit (their indirect light is missing).
    pub unsampled_texels: usize,
    pub pass: PassStats,
}

/// The scene-wide inputs of bundle bakes, shared by all LODs.
pub struct BundleInputs<'s> {
    pub scene: &'s Scene,
    pub geom: &'s SceneGeometry,
    pub bvh: &'s Bvh,
    pub atlas: &'s Atlas,
    pub emitters: EmitterPlan,
    /// Per triangle: its light-pass group or `NO_GROUP`.
    pub group_of: Vec<u32>,
}

impl<'s> BundleInputs<'s> {
    pub fn new(
        scene: &'s Scene,
        geom: &'s SceneGeometry,
        bvh: &'s Bvh,
        atlas: &'s Atlas,
        config: &BundleConfig,
    ) -> Self {
        let emitters = plan_emitters(scene, geom, atlas.stats.lit_area, config.small_emitter_fraction);
        let mut group_of = vec![NO_GROUP; geom.len()];
        for (g, group) in emitters.small.iter().enumerate() {
            for &t in &group.triangles {
                group_of[t as usize] = g as u32;
            }
        }
        BundleInputs { scene, geom, bvh, atlas, emitters, group_of }
    }
}

/// A coarser LOD's converged irradiance, read as the source radiance of a finer bake.
pub struct CoarserLod<'a> {
    pub texels: &'a TexelMap,
    pub irradiance: &'a [Rgb],
}

/// Bakes one LOD with the CPU bundle backend.
pub fn bake_lod(
    inputs: &BundleInputs,
    texels: &TexelMap,
    coarser: Option<CoarserLod>,
    config: &BundleConfig,
    threads: usize,
    progress: &dyn Progress,
) -> (Vec<Rgb>, BundleLodStats) {
    let mut stats = BundleLodStats::default();
    let t0 = Instant::now();
    let punctual = punctual_irradiance(inputs.scene, inputs.bvh, texels, ray_epsilon(inputs.scene), threads);
    stats.punctual_seconds = t0.elapsed().as_secs_f64();

    let prepared = PreparedScene::new(inputs.geom, inputs.atlas, texels, inputs.group_of.clone());
    let carried: Vec<bool> = (0..texels.len())
        .map(|i| inputs.emitters.carried_by_bundles[inputs.atlas.faces[texels.face[i] as usize].tri as usize])
        .collect();
    let light_pixel = inputs.atlas.texel_size / (1u32 << texels.lod) as f32 / config.oversampling;
    let mut backend =
        CpuBundleBackend::new(&prepared, config, &inputs.emitters.small, inputs.scene.sky, light_pixel, threads);

    let kind = if coarser.is_some() { SourceKind::Converged } else { SourceKind::Progressive };
    let mut estimate = ProgressiveEstimate::new(kind, punctual, texels.area.clone());
    let mut source = Vec::new();
    match &coarser {
        Some(c) => source_from_coarser(texels, c, &carried, &mut source),
        None => estimate.source_radiance(texels, &carried, None, threads, &mut source),
    }
    stats.light_pass_groups = inputs.emitters.small.len();
    stats.emitter_triangles_in_global_bundles = inputs.emitters.carried_by_bundles.iter().filter(|&&c| c).count();

    let t1 = Instant::now();
    let jobs = Jobs::new(config, inputs.emitters.small.len());
    let mut sums = BatchSums::new(texels.len());
    progress.begin(&format!("LOD {} bundles", texels.lod), config.directions as u64);
    let per_batch = config.batch_size() as u64;
    let mut first = 0u64;
    while first < config.directions as u64 {
        let count = per_batch.min(config.directions as u64 - first);
        let batch: Vec<DirectionJob> = (first..first + count).map(|i| jobs.job(i)).collect();
        let pass = backend.trace_batch(&batch, &source, &mut sums);
        stats.pass.add(&pass);
        estimate.add_batch(&sums, count * config.light_directions as u64, threads);
        if kind == SourceKind::Progressive {
            estimate.source_radiance(texels, &carried, Some(&sums), threads, &mut source);
        }
        first += count;
        progress.advance(count);
    }
    progress.end();
    stats.bundle_seconds = t1.elapsed().as_secs_f64();
    stats.directions = config.directions as u64;
    stats.batches = estimate.batches();
    stats.light_directions_per_group = estimate.light_directions();
    stats.unsampled_texels = estimate.unsampled();
    (estimate.irradiance(), stats)
}

/// The direction sequences of a bake: one for global bundles, one per light-pass group.
struct Jobs {
    global: BundleDirections,
    lights: Vec<BundleDirections>,
    per_direction: u64,
}

impl Jobs {
    fn new(config: &BundleConfig, groups: usize) -> Self {
        Jobs {
            global: BundleDirections::new(config.seed),
            lights: (0..groups).map(|g| BundleDirections::new(mix64(config.seed ^ mix64(g as u64 + 1)))).collect(),
            per_direction: config.light_directions as u64,
        }
    }

    fn job(&self, i: u64) -> DirectionJob {
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

/// Source radiance of a finer LOD's texels read from the converged coarser LOD: each texel
/// takes the coarser irradiance under its centre (bilinear, gutters make that chart-safe).
fn source_from_coarser(texels: &TexelMap, coarser: &CoarserLod, carried: &[bool], out: &mut Vec<Rgb>) {
    let c = coarser.texels;
    let image = c.to_image(coarser.irradiance, Rgb::ZERO);
    let scale = (1u32 << texels.lod) as f32 / (1u32 << c.lod) as f32;
    out.clear();
    out.extend((0..texels.len()).map(|i| {
        let p = texels.pixel[i];
        let centre = Vec2::new((p % texels.width) as f32 + 0.5, (p / texels.width) as f32 + 0.5) / scale;
        let e = bilinear(&image, c.width, c.height, centre);
        let reflected = texels.albedo[i] * e * std::f32::consts::FRAC_1_PI;
        if carried[i] { reflected + texels.emission[i] } else { reflected }
    }));
}

fn bilinear(image: &[Rgb], w: u32, h: u32, p: Vec2) -> Rgb {
    let q = p - Vec2::splat(0.5);
    let (x0, y0) = (q.x.floor(), q.y.floor());
    let (fx, fy) = (q.x - x0, q.y - y0);
    let at = |x: f32, y: f32| {
        let x = (x.max(0.0) as u32).min(w - 1);
        let y = (y.max(0.0) as u32).min(h - 1);
        image[(y * w + x) as usize]
    };
    let top = at(x0, y0) * (1.0 - fx) + at(x0 + 1.0, y0) * fx;
    let bottom = at(x0, y0 + 1.0) * (1.0 - fx) + at(x0 + 1.0, y0 + 1.0) * fx;
    top * (1.0 - fy) + bottom * fy
}
