//! The GPU bundle backend against the CPU's, side by side in one run: the same batch of
//! directions over the same whole-LOD-0 target, on the bundled Cornell box and on the
//! synthetic 312k-triangle temple. Wall time per batch (median), the paper's Table 1 phases
//! per direction (a second GPU run waits after each phase to time it apart; the wall time
//! comes from the run without waits), and the pass structure per direction. Then the
//! runtime's cell bakes on both backends: a cell's bundles see the surfaces around it
//! through the shown light map (foreign sides), which the GPU resolve evaluates itself.

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
use livebake::runtime::cell_bake::CellBake;
use livebake::runtime::world::World;
use livebake::runtime::{RuntimeConfig, bake_first_light, empty_shown};
use livebake::scene::{LoadOptions, Rgb, Scene, SceneGeometry, load_gltf};

use super::{Bench, Narrator};
use super::{assets, median, seconds};

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

fn one(
    name: &str,
    scene: Arc<Scene>,
    directions: u64,
    runs: usize,
    gpu: &GpuContext,
    ui: &dyn Narrator,
) -> Result<Value> {
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
        "pass_structure_per_batch": {
            // One submission for every direction's analysis + mips + Program 1, then two
            // read-backs of the plans (all counters, then all tiles); then one submission of
            // the tiles and one read-back of their counts per round (the planned tiles; the
            // parts of overflowed ones); and the sums' read-back.
            "directions": gpu_stats.directions,
            "submissions": gpu_stats.plan_submissions + gpu_stats.tile_rounds,
            "read_backs": 2 * gpu_stats.plan_submissions + gpu_stats.tile_rounds + 1,
            "tiles_per_direction": per_direction(gpu_stats.tiles),
            "read_back_bytes_per_batch": 32 * texels.len() as u64 + 20,
        },
        "adapter": gpu.info.name,
        "software_adapter": gpu.is_software(),
    }))
}

/// The runtime's cell bakes at LOD 1 on both backends: the largest cells of `scene`, each
/// one unit of `directions` against first light (median wall time of `runs` units, each a
/// fresh bake of the same cell, so every run does the same work).
fn cells(
    name: &str,
    scene: Arc<Scene>,
    directions: u32,
    runs: usize,
    gpu: &GpuContext,
    ui: &dyn Narrator,
) -> Result<Value> {
    let config = RuntimeConfig::default();
    let geom = Arc::new(SceneGeometry::new(&scene));
    let atlas = Arc::new(Atlas::build(&scene, &geom, &config.atlas)?);
    let world = World::new(scene.clone(), geom, atlas, &config)?;
    let threads = livebake::parallel::available_threads();
    let never = AtomicBool::new(false);
    ui.say(format!("  {name}: first light for the cell bakes ..."));
    let mut cpu = CpuProvider::new().backend(&world.bundle, threads)?;
    let shown = Arc::new(
        bake_first_light(&world, &mut cpu, threads, empty_shown(&world), &never).map_err(anyhow::Error::msg)?.0,
    );
    let mut on_gpu = GpuProvider::new(gpu.clone()).backend(&world.bundle, threads)?;
    let mut phased = GpuProvider::new(gpu.clone()).with_phase_timing(true).backend(&world.bundle, threads)?;
    let mut cells: Vec<u32> = world.non_empty_cells().collect();
    cells.sort_by_key(|&c| (std::cmp::Reverse(world.lod0_texels[c as usize]), c));
    let mut out = Vec::new();
    for &cell in cells.iter().take(3) {
        ui.say(format!("  {name}: cell {cell} at LOD 1 on both backends ..."));
        let unit = |backend: &mut dyn BundleBackend| -> Result<(f64, PassStats, usize)> {
            let mut last = None;
            // One untimed unit first (pipelines, buffers, the map's mirror).
            let mut runs_left = runs + 1;
            let mut times = Vec::new();
            while runs_left > 0 {
                let mut bake = CellBake::new(&world, &[cell], 1, shown.clone(), 1);
                let t = Instant::now();
                let stats = bake.step(&world, backend, directions, &never).map_err(anyhow::Error::from)?;
                if runs_left <= runs {
                    times.push(seconds(t));
                }
                last = Some((stats.pass, bake.texels.len()));
                runs_left -= 1;
            }
            times.sort_by(f64::total_cmp);
            let (stats, texels) = last.expect("at least one unit");
            Ok((times[times.len() / 2], stats, texels))
        };
        let (cpu_wall, cpu_stats, texels) = unit(&mut cpu)?;
        let (gpu_wall, gpu_stats, _) = unit(&mut on_gpu)?;
        let (_, phased_stats, _) = unit(&mut phased)?;
        out.push(json!({
            "cell": cell,
            "texels": texels,
            "directions": directions,
            "cpu_median_unit_seconds": cpu_wall,
            "gpu_median_unit_seconds": gpu_wall,
            "gpu_over_cpu_wall": gpu_wall / cpu_wall,
            "cpu_phases_ms_per_direction": phases(&cpu_stats),
            "gpu_phases_ms_per_direction": phases(&phased_stats),
            "fragments_per_direction": gpu_stats.fragments as f64 / directions as f64,
            "foreign_lookups_per_direction": gpu_stats.foreign_lookups as f64 / directions as f64,
            "cpu_foreign_lookups_per_direction": cpu_stats.foreign_lookups as f64 / directions as f64,
            "gpu_cpu_fallback_batches": gpu_stats.cpu_fallback_batches,
            "gpu_tiles_per_direction": gpu_stats.tiles as f64 / directions as f64,
        }));
    }
    Ok(json!({ "scene": name, "triangles": scene.triangle_count(), "lod": 1, "runs": runs, "cells": out }))
}

pub fn run(bench: &Bench) -> Result<Value> {
    let (quick, ui) = (bench.quick, bench.ui);
    let (directions, runs) = if quick { (4, 1) } else { (8, 3) };
    let gpu = GpuContext::headless().context("the GPU backend bench needs a Vulkan adapter (lavapipe)")?;
    let cornell =
        Arc::new(load_gltf(&assets().join("cornell_box/cornellBox-2.79-Cycles-gltf.gltf"), &LoadOptions::default())?);
    let temple = Arc::new(temple_courtyard());
    Ok(json!({
        "whole_lod0": [
            one("cornell_box", cornell.clone(), directions, runs, &gpu, ui)?,
            one("temple_courtyard (synthetic)", temple, directions, runs, &gpu, ui)?,
        ],
        "runtime_cells": cells("cornell_box", cornell, directions as u32, runs, &gpu, ui)?,
    }))
}
