//! The GPU bundle backend against the CPU's, side by side in one run: the same batch of
//! directions over the same whole-LOD-0 target, on the bundled Cornell box and on the
//! synthetic 312k-triangle temple. Wall time per batch (median), the paper's Table 1 phases
//! per direction (a second GPU run waits after each phase to time it apart; the wall time
//! comes from the run without waits), and the pass structure per direction.

use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use anyhow::{Context, Result};
use serde_json::{Value, json};

use livebake::atlas::{Atlas, AtlasConfig, TexelMap};
use livebake::bundle::progressive::BatchSums;
use livebake::bundle::stats::PassStats;
use livebake::bundle::target::WholeLod;
use livebake::bundle::{
    BackendProvider, BundleBackend, BundleConfig, BundleScene, DirectionJob, JobSequence, SourceRadiance,
};
use livebake::cpu::CpuProvider;
use livebake::gpu::{GpuContext, GpuProvider};
use livebake::reference::scenes::temple_courtyard;
use livebake::scene::{LoadOptions, Rgb, Scene, SceneGeometry, load_gltf};

use super::{assets, median, seconds};
use crate::cli::progress::Ui;

/// Per direction, ms: (analysis, mips, subdivision, build, resolve, light).
fn phases(stats: &PassStats) -> Value {
    let per = |s: f64| 1e3 * s / stats.directions.max(1) as f64;
    json!({
        "analysis": per(stats.analysis_seconds),
        "mips": per(stats.mip_seconds),
        "subdivision": per(stats.subdivision_seconds),
        "build": per(stats.build_seconds),
        "resolve": per(stats.resolve_seconds),
        "light": per(stats.light_seconds),
    })
}

fn one(name: &str, scene: Arc<Scene>, directions: u64, runs: usize, gpu: &GpuContext, ui: &Ui) -> Result<Value> {
    let geom = Arc::new(SceneGeometry::new(&scene));
    let atlas = Arc::new(Atlas::build(&scene, &geom, &AtlasConfig::default())?);
    let bundle = Arc::new(BundleScene::new(scene.clone(), geom.clone(), atlas.clone(), BundleConfig::default()));
    let texels = TexelMap::build(&scene, &geom, &atlas, 0);
    let whole = WholeLod::new(&atlas, &texels);
    let target = whole.target(&texels);
    // A source as a bake's first batch has it: each texel's emission.
    let own: Vec<Rgb> = texels.emission.clone();
    let source = SourceRadiance { own: &own, foreign: None };
    let jobs = JobSequence::new(0, bundle.emitters.small.len(), bundle.config.light_directions);
    let batch: Vec<DirectionJob> = (0..directions).map(|i| jobs.job(i)).collect();
    let never = AtomicBool::new(false);
    let threads = livebake::parallel::available_threads();
    let timed = |backend: &mut dyn BundleBackend| -> Result<(f64, PassStats)> {
        let mut sums = BatchSums::default();
        // One untimed batch first: lavapipe compiles pipelines on first use, and both
        // backends size their buffers.
        let mut last = backend.trace_batch(&target, &batch, &source, &mut sums, &never).map_err(anyhow::Error::from)?;
        let wall = median(runs, || {
            let t = Instant::now();
            last = backend.trace_batch(&target, &batch, &source, &mut sums, &never).map_err(anyhow::Error::from)?;
            Ok(seconds(t))
        })?;
        Ok((wall, last))
    };
    ui.say(format!("  {name}: {} triangles, {} texels, CPU backend ...", scene.triangle_count(), texels.len()));
    let mut cpu = CpuProvider::new().backend(&bundle, threads)?;
    let (cpu_wall, cpu_stats) = timed(&mut cpu)?;
    drop(cpu);
    ui.say(format!("  {name}: GPU backend ..."));
    let mut on_gpu = GpuProvider::new(gpu.clone()).backend(&bundle, threads)?;
    let (gpu_wall, gpu_stats) = timed(&mut on_gpu)?;
    drop(on_gpu);
    let mut phased = GpuProvider::new(gpu.clone()).with_phase_timing(true).backend(&bundle, threads)?;
    let (phased_wall, phased_stats) = timed(&mut phased)?;
    let per_direction = |n: u64| n as f64 / gpu_stats.directions.max(1) as f64;
    Ok(json!({
        "scene": name,
        "triangles": scene.triangle_count(),
        "texels": texels.len(),
        "directions": directions,
        "runs": runs,
        "cpu": {
            "median_batch_seconds": cpu_wall,
            "per_direction_ms": 1e3 * cpu_wall / directions as f64,
            "phases_ms_per_direction": phases(&cpu_stats),
            "fragments_per_direction": per_direction(cpu_stats.fragments),
        },
        "gpu": {
            "median_batch_seconds": gpu_wall,
            "per_direction_ms": 1e3 * gpu_wall / directions as f64,
            "phases_ms_per_direction": phases(&phased_stats),
            "phase_timed_batch_seconds": phased_wall,
            "fragments_per_direction": per_direction(gpu_stats.fragments),
            "unresolved_pixels": gpu_stats.unresolved_pixels,
            "redone_batches": gpu_stats.redone_batches,
        },
        "gpu_over_cpu_wall": gpu_wall / cpu_wall,
        "target_gpu_over_cpu_wall": 3.0,
        "pass_structure_per_direction": {
            // One submission for analysis + mips + Program 1 and the plan's read-back, then one
            // submission and a 4-byte count read-back per built tile (overflow splits included).
            "submissions": 1.0 + per_direction(gpu_stats.tiles + gpu_stats.overflowed_tiles),
            "read_backs": 1.0 + per_direction(gpu_stats.tiles + gpu_stats.overflowed_tiles),
            "tiles": per_direction(gpu_stats.tiles),
            "read_back_bytes_per_batch": 32 * texels.len() as u64 + 16,
        },
        "adapter": gpu.info.name,
        "software_adapter": gpu.is_software(),
    }))
}

pub fn run(quick: bool, ui: &Ui) -> Result<Value> {
    let (directions, runs) = if quick { (4, 1) } else { (8, 3) };
    let gpu = GpuContext::headless().context("the GPU backend bench needs a Vulkan adapter (lavapipe)")?;
    let cornell =
        Arc::new(load_gltf(&assets().join("cornell_box/cornellBox-2.79-Cycles-gltf.gltf"), &LoadOptions::default())?);
    let temple = Arc::new(temple_courtyard());
    Ok(json!([
        one("cornell_box", cornell, directions, runs, &gpu, ui)?,
        one("temple_courtyard (synthetic)", temple, directions, runs, &gpu, ui)?,
    ]))
}
