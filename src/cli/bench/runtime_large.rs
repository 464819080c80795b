//! The live runtime on a large scene: the synthetic 312k-triangle temple, with the runtime's
//! defaults (CPU bundle backend, every core), in two lights: `runtime_large` under a sun and
//! a sky ([`temple_courtyard_sunlit`]: sharp column shadows, which need fine texels near the
//! viewer, the case the LOD hierarchy is for) and `runtime_large_overcast` under the sky
//! alone ([`temple_courtyard`]: smooth light that 30 cm texels already render within 5 %,
//! where a whole-scene bake is cheap).
//!
//! * **First light**: seconds from `Runtime::start` (atlas, grid, LOD-0 texels included) to
//!   the `first_light` event.
//! * **Near-camera convergence**: a camera at eye height among the columns; the error at the
//!   surface points in view within [`NEAR`] metres (hits of a grid of view rays) against the
//!   in-crate reference tracer, from snapshots of the shown map taken every second, until it
//!   is at most [`GOAL`] (or the horizon passes). The reference is computed first, on no
//!   clock; each snapshot is scored when taken and let go (the memory measured is the
//!   runtime's own).
//! * **The whole-scene bake** at the texel size the runtime shows at those points (their
//!   median LOD) when it got there, with the same bundle settings, on the same points: its
//!   error after each batch, stopped at [`GOAL`] or at [`SPEEDUP`]× the runtime's time, so
//!   the goal "the runtime reaches it ≥ 8× sooner" is decided without running the slower
//!   one to the end. Memory of each: the process's peak resident bytes over the runtime's
//!   phase (Linux's `clear_refs` resets the peak), and the bake's estimate (what `livebake
//!   bake` checks before allocating) and resident bytes sampled between its batches.
//! * **Swap latency**: the camera jumps [`JUMP`] to another part of the courtyard; seconds
//!   until every cell within 2 m of the new eye shows its target LOD.
//! * **11 ms ticks**: a front end's 90 Hz loop (the camera walking at 1 m/s, `set_camera`
//!   and a snapshot of the shown map each tick) for a while: the time each tick spends in the
//!   runtime's calls, and the refinement throughput meanwhile beside that of the phase before
//!   (no ticks).

use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use livebake::glam::{DVec3, Vec3};
use livebake::reference::punctual::punctual_irradiance;
use serde_json::{Value, json};

use livebake::atlas::{Atlas, AtlasConfig};
use livebake::bake::memory::{peak_resident_bytes, resident_bytes};
use livebake::cpu::CpuProvider;
use livebake::reference::scenes::{temple_courtyard, temple_courtyard_sunlit};
use livebake::runtime::shown::{Layer, ShownLightmap};
use livebake::runtime::world::World;
use livebake::runtime::{CameraView, Runtime, RuntimeConfig, RuntimeEvent, RuntimeStats};
use livebake::scene::Scene;
use livebake::scene::SceneGeometry;

use super::runtime::{
    ShownLods, ShownReader, TooLarge, median_point_error, next_event, quantile, reference_at, view_hits,
    wait_first_light, whole_bake, worst_points,
};
use super::{Bench, curve_points};
use livebake::plot::Series;
use livebake::points::{Query, ReferencePoints};

/// The error goal near the camera (relative RMS).
const GOAL: f64 = 0.05;
/// Surface points count as near the camera within this distance (metres).
const NEAR: f32 = 20.0;
/// How much sooner than the whole-scene bake the runtime is to get there (the goal).
const SPEEDUP: f64 = 8.0;
/// The camera jump of the swap-latency phase (metres, along −x and −z).
const JUMP: f32 = 40.0;
/// Seconds between the snapshots of the shown map scored near the camera.
const SNAPSHOT_EVERY: f64 = 0.25;
/// Rays through the view (columns × rows) whose hits within [`NEAR`] are the error points.
const VIEW_RAYS: (u32, u32) = (24, 14);

/// Eye height among the columns (between four of them), looking along a diagonal row.
fn start_camera() -> CameraView {
    CameraView::looking_at(Vec3::new(0.4, 1.7, 0.4), Vec3::new(20.0, 1.0, 12.0))
}

/// Resets the process's peak resident size to its current size (Linux ≥ 4.0); returns the
/// resident bytes then.
pub(super) fn reset_peak() -> Option<u64> {
    std::fs::write("/proc/self/clear_refs", "5").ok()?;
    resident_bytes()
}

/// The sunlit temple.
pub fn run(bench: &Bench) -> Result<Value> {
    temple(
        "temple_courtyard_sunlit (synthetic temple, open to a sun and a uniform sky)",
        temple_courtyard_sunlit,
        bench,
    )
}

/// The overcast temple.
pub fn run_overcast(bench: &Bench) -> Result<Value> {
    temple("temple_courtyard (synthetic temple, open to a uniform sky)", temple_courtyard, bench)
}

fn temple(name: &str, make: fn() -> Scene, bench: &Bench) -> Result<Value> {
    let (quick, ui) = (bench.quick, bench.ui);
    let (horizon, spp, tick_seconds, swap_patience) =
        if quick { (30.0, 512, 4.0, 30.0) } else { (120.0, 2048, 10.0, 120.0) };
    let t_build = Instant::now();
    let scene = Arc::new(make());
    let scene_seconds = t_build.elapsed().as_secs_f64();
    let config = RuntimeConfig::default();
    let camera = start_camera();
    let provider = Arc::new(CpuProvider::new());

    // The error points and their reference first, on no clock, from the world the runtime
    // will build (the same atlas and grid: they are deterministic), so that the runtime's
    // snapshots can be scored as they are taken and none is kept (the memory measured is
    // the runtime's own).
    let world = Arc::new(World::new(
        scene.clone(),
        Arc::new(SceneGeometry::new(&scene)),
        Arc::new(Atlas::build(&scene, &SceneGeometry::new(&scene), &config.atlas)?),
        &config,
    )?);
    let points: Vec<Query> =
        view_hits(&world, &camera, VIEW_RAYS).into_iter().filter(|(t, _)| *t <= NEAR).map(|(_, q)| q).collect();
    if points.len() < 16 {
        bail!("only {} surface points within {NEAR} m in view", points.len());
    }
    ui.say(format!("  temple: reference at {} points, {spp} paths each ...", points.len()));
    let reference = reference_at(&scene, &points, spp);
    let reader = ShownReader::new(&world, &points)?;
    drop(world);
    // A snapshot's (seconds, error, median LOD at the points of the finer layer) and its
    // values at the points. The finer layer is the one whose texels the whole-scene bake
    // is to match: the punctual layer near the camera where the scene has punctual lights.
    let score = |world: &World, t: f64, shown: &ShownLightmap| {
        let median = |layer: Layer| {
            let lods: Vec<f64> =
                reader.at.iter().map(|&(p, _)| shown.cell_lod(layer, world.grid.cell_of(p)) as f64).collect();
            quantile(&lods, 0.5).unwrap_or(0.0)
        };
        let lod = median(Layer::Bundles).max(median(Layer::Punctual));
        ((t, reader.error(&reference, shown), lod), reader.values(shown))
    };

    ui.say(format!("  temple ({} triangles): first light ...", scene.triangle_count()));
    let rss_start = reset_peak();
    let runtime = Runtime::start(scene.clone(), config.clone(), provider).context("Runtime::start")?;
    runtime.set_camera(camera);
    let (t_light, texels, _) = wait_first_light(&runtime)?;
    let world = runtime.world();

    // Refinement with a fixed camera, a snapshot scored every quarter second until the horizon.
    ui.say(format!("  temple: refining near the camera for up to {horizon} s ..."));
    let (first, first_values) = score(&world, t_light, &runtime.shown());
    let mut values_goal = (first.1 <= GOAL).then_some(first_values);
    let mut curve: Vec<(f64, f64, f64)> = vec![first];
    let mut stats: Vec<(f64, RuntimeStats)> = Vec::new();
    // Swaps raise a cell's LOD; republishes are at its LOD (an unsettled level, refined).
    let (mut swaps, mut republishes) = (0usize, 0usize);
    let mut lods = ShownLods::default();
    let mut next = t_light + SNAPSHOT_EVERY;
    while runtime.elapsed() < t_light + horizon {
        let now = runtime.elapsed();
        if now >= next {
            let (c, values) = score(&world, now, &runtime.shown());
            if values_goal.is_none() && c.1 <= GOAL {
                values_goal = Some(values);
                ui.say(format!("  temple: {:.1} % near the camera at {:.2} s (median LOD {})", 100.0 * c.1, c.0, c.2));
            }
            if curve.len() % 16 == 0 {
                ui.say(format!("    {:.1} s: {:.1} % near the camera, median LOD {}", c.0, 100.0 * c.1, c.2));
            }
            curve.push(c);
            next += SNAPSHOT_EVERY;
        }
        if let Some(e) = next_event(&runtime, Duration::from_secs_f64((next - now).clamp(0.001, 0.1)))? {
            match e.event {
                RuntimeEvent::CellPublished { cell, lod, .. } => {
                    if lods.published(cell, lod) {
                        swaps += 1
                    } else {
                        republishes += 1
                    }
                }
                RuntimeEvent::CellEvicted { cell, lod, layer: Layer::Bundles } => lods.evicted(cell, lod),
                RuntimeEvent::Stats(s) => stats.push((e.t, s)),
                _ => {}
            }
        }
    }
    let runtime_peak = peak_resident_bytes().zip(rss_start).map(|(p, s)| p.saturating_sub(s));
    let refined = layer_errors(&world, &reader, &points, &reference, &runtime.shown());
    let accounted_peak = stats.iter().map(|(_, s)| s.resident_bytes).max();
    let steady_rates: Vec<f64> =
        stats.iter().filter(|(t, _)| *t > t_light + 1.0).map(|(_, s)| s.texel_samples_per_second).collect();

    // Swap latency: the camera jumps; every cell within 2 m of the new eye at its target.
    let jumped =
        CameraView::looking_at(camera.eye - Vec3::new(JUMP, 0.0, JUMP), camera.target - Vec3::new(JUMP, 0.0, JUMP));
    ui.say("  temple: camera jump ...");
    let jump_at = runtime.elapsed();
    runtime.set_camera(jumped);
    let near_jump = |c: &livebake::runtime::CellInfo| {
        let (lo, hi) = (Vec3::from(c.min), Vec3::from(c.max));
        (jumped.eye.clamp(lo, hi) - jumped.eye).length() <= 2.0
    };
    // Per layer: the seconds until every cell within 2 m shows it at its target.
    let (mut swap_latency, mut punctual_latency) = (None, None);
    let mut near_cells = Vec::new();
    while runtime.elapsed() < jump_at + swap_patience {
        while let Ok(e) = runtime.events().try_recv() {
            if let RuntimeEvent::Failed { error } = e.event {
                bail!("the runtime failed: {error}");
            }
        }
        near_cells = runtime.cells().into_iter().filter(|c| near_jump(c)).collect();
        let at_target = |lod: fn(&livebake::runtime::CellInfo) -> u32| {
            !near_cells.is_empty() && near_cells.iter().all(|c| lod(c) >= c.target_lod)
        };
        if punctual_latency.is_none() && !scene.lights.is_empty() && at_target(|c| c.punctual_lod) {
            punctual_latency = Some(runtime.elapsed() - jump_at);
        }
        if at_target(|c| c.shown_lod) {
            swap_latency = Some(runtime.elapsed() - jump_at);
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let near_json: Vec<Value> = near_cells
        .iter()
        .map(|c| {
            json!({"cell": c.cell, "shown_lod": c.shown_lod, "punctual_lod": c.punctual_lod, "target_lod": c.target_lod,
                "texels_lod0": c.texels})
        })
        .collect();

    // 11 ms ticks: the front end walks on at 1 m/s, sets the camera and reads a snapshot.
    ui.say(format!("  temple: {tick_seconds} s of 11 ms ticks ..."));
    let tick = Duration::from_micros(11_111);
    let mut tick_ms = Vec::new();
    let mut late = 0usize;
    let mut tick_stats = Vec::new();
    let ticks_start = Instant::now();
    let mut due = Instant::now();
    while ticks_start.elapsed().as_secs_f64() < tick_seconds {
        let walked = Vec3::X * ticks_start.elapsed().as_secs_f32();
        let work = Instant::now();
        runtime.set_camera(CameraView::looking_at(jumped.eye + walked, jumped.target + walked));
        let shown = runtime.shown();
        std::hint::black_box(shown.version);
        while let Ok(e) = runtime.events().try_recv() {
            match e.event {
                RuntimeEvent::Failed { error } => bail!("the runtime failed: {error}"),
                RuntimeEvent::Stats(s) => tick_stats.push(s),
                _ => {}
            }
        }
        tick_ms.push(work.elapsed().as_secs_f64() * 1e3);
        due += tick;
        match due.checked_duration_since(Instant::now()) {
            Some(wait) => std::thread::sleep(wait),
            None => late += 1,
        }
    }
    let tick_rates: Vec<f64> = tick_stats.iter().skip(1).map(|s| s.texel_samples_per_second).collect();
    let end_stats = runtime.stats();
    runtime.shutdown()?;

    let reached = curve.iter().position(|c| c.1 <= GOAL);
    let (t_goal, lod_goal) = match reached {
        Some(i) => (curve[i].0, curve[i].2 as u32),
        None => (curve.last().map_or(horizon, |c| c.0), curve.last().map_or(0.0, |c| c.2) as u32),
    };
    // The whole-scene bake at that texel size, for up to SPEEDUP× the runtime's time. Where
    // it would not fit the bench's memory, the finest texel size (halving the resolution)
    // at which it does: a bake at coarser texels takes no longer to get anywhere (a direction
    // costs about in proportion to the texels), so its time is a lower bound of the other's,
    // and the memory it would have held is reported.
    let budget = SPEEDUP * t_goal;
    let mut too_large = Vec::new();
    let mut lod = lod_goal;
    let (bake, texel_goal) = loop {
        let texel = world.texel_size(lod);
        ui.say(format!("  temple: whole-scene bake at {texel:.3} m texels for up to {budget:.0} s ..."));
        let atlas = AtlasConfig { texel_size: Some(texel), ..config.atlas.clone() };
        match whole_bake(&scene, &atlas, &points, &reference, budget, Some(GOAL)) {
            Err(e) if lod > 0 && e.downcast_ref::<TooLarge>().is_some() => {
                ui.say(format!("  temple: {e:#}"));
                too_large.push(e.downcast::<TooLarge>()?);
                lod -= 1;
            }
            r => break (r, texel),
        }
    };
    let whole = match bake {
        Ok(bake) => {
            let reached_at = bake.curve.iter().find(|c| c.2 <= GOAL).map(|c| c.0);
            json!({
                "texel_size_m": bake.texel_size,
                "texels": bake.texels,
                "stopped_at_seconds": bake.ended_seconds,
                "first_batch_seconds": bake.curve.first().map(|c| c.0),
                "seconds_to_goal": reached_at,
                "error_at_stop": bake.curve.last().map(|c| c.2),
                "directions_at_stop": bake.curve.last().map(|c| c.1),
                "time_ratio_bake_over_runtime": reached_at.map(|t| t / t_goal),
                "time_ratio_at_least": (reached_at.is_none() && reached.is_some()).then(|| bake.ended_seconds / t_goal),
                "estimated_peak_bytes": bake.estimated_bytes,
                "sampled_peak_bytes": bake.sampled_peak_bytes,
                "memory_ratio_runtime_over_bake_estimate": runtime_peak.map(|r| r as f64 / bake.estimated_bytes as f64),
                "curve": bake.curve.iter().map(|&(s, d, e)| json!({"seconds": s, "directions": d, "error": e})).collect::<Vec<_>>(),
            })
        }
        Err(e) => json!({ "texel_size_m": texel_goal, "refused": format!("{e:#}") }),
    };
    let finer_refused: Vec<Value> = too_large
        .iter()
        .map(|t| {
            json!({
                "texel_size_m": t.texel_size,
                "texels": t.texels,
                "estimated_peak_bytes": t.bytes,
                "bench_limit_bytes": t.limit,
                "memory_ratio_runtime_over_bake_estimate": runtime_peak.map(|r| r as f64 / t.bytes as f64),
            })
        })
        .collect();

    let mut series = vec![("runtime", curve.iter().map(|c| (c.0, c.1)).collect::<Vec<_>>())];
    if let Some(points) = whole.get("curve") {
        series.push(("whole-scene bake", curve_points(points)));
    }
    let series: Vec<Series> = series.iter().map(|(label, points)| Series { label, points }).collect();
    bench.plot_error(&format!("Error at the points: {name}"), &series, Some(GOAL))?;

    Ok(json!({
        "scene": name,
        "triangles": scene.triangle_count(),
        "scene_build_seconds": scene_seconds,
        "lods": world.lods,
        "texel_size_per_lod_m": (0..world.lods).map(|k| world.texel_size(k)).collect::<Vec<_>>(),
        "cell_size_m": world.grid.cell_size,
        "cells": world.non_empty_cells().count(),
        "first_light": { "seconds": t_light, "texels": texels },
        "near_camera": {
            "camera": {"eye": camera.eye.to_array(), "target": camera.target.to_array()},
            "points": points.len(),
            "within_m": NEAR,
            "reference": format!("in-crate path tracer, {spp} paths per point"),
            "measure": "relative RMS error of E, the reference's noise removed in quadrature",
            "goal": GOAL,
            "runtime_seconds_to_goal": reached.map(|_| t_goal),
            "runtime_median_point_error_at_goal": values_goal.as_ref().and_then(|v| median_point_error(&reference, v)),
            "median_lod_at_points_at_goal": lod_goal,
            "median_lod_means": "the median over the points of their cells' LOD in the finer layer (bundles or punctual)",
            "runtime_curve": curve.iter().map(|&(t, e, l)| json!({"seconds": t, "error": e, "median_lod_at_points": l})).collect::<Vec<_>>(),
            "at_the_horizon": refined,
            "swaps": swaps,
            "republishes": republishes,
            "runtime_peak_resident_bytes": runtime_peak,
            "runtime_peak_accounted_bytes": accounted_peak,
            "median_texel_samples_per_second": quantile(&steady_rates, 0.5),
            "whole_scene_bake": whole,
            "whole_scene_bakes_too_large_to_run": finer_refused,
        },
        "swap_latency": {
            "jump_m": [-JUMP, 0.0, -JUMP],
            "seconds": swap_latency,
            "punctual_layer_seconds": punctual_latency,
            "patience_seconds": swap_patience,
            "cells_within_2m": near_json,
        },
        "ticks_11ms": {
            "seconds": tick_seconds,
            "ticks": tick_ms.len(),
            "late_ticks": late,
            "runtime_calls_ms": { "median": quantile(&tick_ms, 0.5), "p99": quantile(&tick_ms, 0.99), "max": tick_ms.iter().cloned().fold(0.0, f64::max) },
            "median_texel_samples_per_second": quantile(&tick_rates, 0.5),
            "median_texel_samples_per_second_without_ticks": quantile(&steady_rates, 0.5),
        },
        "end_stats": end_stats,
    }))
}

/// Where the error near the camera is, in `shown`: per layer, against the exact direct light
/// of the punctual lights at each point (one shadow ray: what the punctual layer converges
/// to) and the reference minus that (what the bundle layer converges to), each as an RMS over
/// the points relative to the reference's RMS (so the two add in quadrature, about); and the
/// points that weigh most in the total.
fn layer_errors(
    world: &World,
    reader: &ShownReader,
    points: &[Query],
    reference: &ReferencePoints,
    shown: &ShownLightmap,
) -> Value {
    let normals: Vec<Vec3> = points.iter().map(|q| q.n).collect();
    let positions: Vec<Vec3> = reader.at.iter().map(|a| a.0).collect();
    let direct = punctual_irradiance(&world.scene, &world.bvh, &positions, &normals, world.epsilon, 1);
    let scale: f64 = reference.e.iter().map(|e| e.length_squared()).sum::<f64>().sqrt();
    let rms = |d: &dyn Fn(usize) -> DVec3| (0..points.len()).map(|k| d(k).length_squared()).sum::<f64>().sqrt() / scale;
    let layer = |layer: Layer, k: usize| {
        let (p, uv) = reader.at[k];
        shown.layer_irradiance(layer, world.grid.cell_of(p), p, uv).as_dvec3()
    };
    let values = reader.values(shown);
    json!({
        "error": reference.relative_rms(|k| values[k]),
        "punctual_layer_vs_exact_direct": rms(&|k| layer(Layer::Punctual, k) - direct[k].as_dvec3()),
        "bundle_layer_vs_reference_minus_direct": rms(&|k| layer(Layer::Bundles, k) - (reference.e[k] - direct[k].as_dvec3())),
        "direct_share_of_reference": (0..points.len()).map(|k| direct[k].as_dvec3().length_squared()).sum::<f64>().sqrt() / scale,
        "worst_points": worst_points(reference, &values, 8),
    })
}
