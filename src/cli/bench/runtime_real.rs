//! The live runtime on real scenes, checked against an independent renderer: a viewer
//! standing at one spot and turning (36° a second, a full turn in 10 s: what every
//! walkthrough does), at the runtime's defaults, CPU backend, every core.
//!
//! * **zdm2** (a real game map: 58k triangles, thin, intersecting and degenerate pieces)
//!   under a directional sun and a uniform sky, the eye in its central courtyard;
//! * **the lit Van Gogh room** (a real interior: a ceiling panel and a bedside lamp), the eye
//!   in the middle of the room.
//!
//! The error is the relative RMS of the shown light map, read with the one sampling
//! function the viewer uses, at 96 surface points within 20 m of the eye that face it, seen
//! in all directions (`scripts/make_view_points.py`), against Mitsuba 3's irradiance there
//! (`../shared/tools/mitsuba_ref`, 0.4% relative standard error a point; its noise removed in
//! quadrature), every half second from the start. Beside it: the process's peak resident
//! memory over the run, the refinement throughput (texel-samples a second, the runtime's own
//! stats), and a whole-scene bake's at the texel size the runtime reached at the points, on
//! the same scene in the same run.

use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use livebake::glam::Vec3;
use serde_json::{Value, json};

use livebake::bake::memory::peak_resident_bytes;
use livebake::bake::{BakeConfig, bake};
use livebake::cpu::CpuProvider;
use livebake::progress::NoProgress;
use livebake::runtime::shown::Layer;
use livebake::runtime::{CameraView, Runtime, RuntimeConfig, RuntimeEvent, RuntimeStats};
use livebake::scene::{LoadOptions, Rgb, load_gltf};

use super::assets;
use super::runtime::{ShownReader, next_event, quantile, wait_first_light};
use super::runtime_large::reset_peak;
use super::{Bench, Narrator};
use livebake::plot::Series;
use livebake::points::read_reference;

/// A real scene, its eye and the reference irradiance at points seen from it.
struct RealScene {
    name: &'static str,
    /// The name in the plot's legend.
    short: &'static str,
    scene: &'static str,
    /// Uniform sky radiance (W/(sr·m²)) the reference was computed with.
    sky: Rgb,
    eye: Vec3,
    reference: &'static str,
}

const SCENES: [RealScene; 2] = [
    RealScene {
        name: "zdm2 (real game map) under a sun and a sky",
        short: "zdm2, sun and sky",
        scene: "zdm2/zdm2_sun.gltf",
        sky: Rgb::new(0.4, 0.45, 0.5),
        eye: Vec3::new(0.0, 10.9, 0.0),
        reference: "zdm2/mitsuba_sun_sky.json",
    },
    RealScene {
        name: "Van Gogh room, lit (ceiling panel and lamp)",
        short: "Van Gogh room, lit",
        scene: "van_gogh_room/van_gogh_room_lit.gltf",
        sky: Rgb::ZERO,
        eye: Vec3::new(-0.1, 1.6, 2.6),
        reference: "van_gogh_room/mitsuba_lit.json",
    },
];

/// Degrees a second the viewer turns.
const TURN: f32 = 36.0;
/// Seconds between the scored snapshots.
const SNAPSHOT_EVERY: f64 = 0.5;
/// The times the issue asks the error at (seconds from the start).
const MARKS: [f64; 2] = [10.0, 30.0];
/// Directions of the whole-scene bake whose throughput is compared.
const WHOLE_DIRECTIONS: u32 = 32;

/// The camera at `t` seconds: at the eye, turned `TURN`·t degrees about +Y, looking a little down.
fn turning(eye: Vec3, t: f64) -> CameraView {
    let a = (TURN as f64 * t).to_radians() as f32;
    CameraView::looking_at(eye, eye + Vec3::new(a.cos(), -0.15, a.sin()))
}

pub fn run(bench: &Bench) -> Result<Value> {
    let (quick, ui) = (bench.quick, bench.ui);
    let horizon = if quick { 12.0 } else { 30.0 };
    let measured = SCENES.iter().map(|s| scene(s, horizon, ui)).collect::<Result<Vec<_>>>()?;
    let curves: Vec<Vec<(f64, f64)>> =
        measured.iter().map(|(_, curve)| curve.iter().map(|c| (c.0, c.1)).collect()).collect();
    let series: Vec<Series> = SCENES.iter().zip(&curves).map(|(s, points)| Series { label: s.short, points }).collect();
    bench.plot_error("Near-camera error while turning at the eye (against Mitsuba 3)", &series, None)?;
    Ok(Value::Array(measured.into_iter().map(|(v, _)| v).collect()))
}

/// (seconds, error, median LOD of the bundle and punctual layers at the points).
type Score = (f64, f64, f64, f64);

fn scene(s: &RealScene, horizon: f64, ui: &dyn Narrator) -> Result<(Value, Vec<Score>)> {
    let path = assets().join(s.scene);
    let mut loaded = load_gltf(&path, &LoadOptions::default()).with_context(|| format!("{}", path.display()))?;
    loaded.sky = s.sky;
    let scene = Arc::new(loaded);
    let reference = read_reference(&assets().join(s.reference))?.in_frame(scene.origin);
    let config = RuntimeConfig::default();

    ui.say(format!("  {}: {} triangles, turning at the eye for {horizon} s ...", s.name, scene.triangle_count()));
    let rss_start = reset_peak();
    let runtime =
        Runtime::start(scene.clone(), config.clone(), Arc::new(CpuProvider::new())).context("Runtime::start")?;
    runtime.set_camera(turning(s.eye, 0.0));
    let (t_light, texels, _) = wait_first_light(&runtime)?;
    let world = runtime.world();
    let reader = ShownReader::new(&world, &reference.queries)?;
    let score = |t: f64| -> Score {
        let shown = runtime.shown();
        let median = |layer: Layer| {
            let lods: Vec<f64> =
                reader.at.iter().map(|&(p, _)| shown.cell_lod(layer, world.grid.cell_of(p)) as f64).collect();
            quantile(&lods, 0.5).unwrap_or(0.0)
        };
        (t, reader.error(&reference, &shown), median(Layer::Bundles), median(Layer::Punctual))
    };
    let mut curve = vec![score(t_light)];
    let mut stats: Vec<(f64, RuntimeStats)> = Vec::new();
    let mut next = t_light + SNAPSHOT_EVERY;
    while runtime.elapsed() < horizon {
        let now = runtime.elapsed();
        runtime.set_camera(turning(s.eye, now));
        if now >= next {
            curve.push(score(now));
            next += SNAPSHOT_EVERY;
        }
        if let Some(e) = next_event(&runtime, Duration::from_millis(20))? {
            match e.event {
                RuntimeEvent::Stats(st) => stats.push((e.t, st)),
                RuntimeEvent::Failed { error } => bail!("the runtime failed: {error}"),
                _ => {}
            }
        }
    }
    curve.push(score(runtime.elapsed()));
    let peak = peak_resident_bytes().zip(rss_start).map(|(p, start)| p.saturating_sub(start));
    let end = runtime.stats();
    runtime.shutdown()?;
    // None past the curve's end (a quick run stops before the last mark).
    let reached = curve.last().map_or(0.0, |c| c.0);
    let at = |mark: f64| curve.iter().rev().find(|c| c.0 <= mark && mark <= reached).map(|c| c.1);
    let refining: Vec<f64> = stats
        .iter()
        .filter(|(_, st)| st.texel_samples_per_second > 0.0)
        .map(|(_, st)| st.texel_samples_per_second)
        .collect();
    let runtime_rate = if refining.is_empty() { None } else { quantile(&refining, 0.5) };

    // The whole-scene bake at the texel size of the bundle layer's median LOD at the points.
    let lod = curve.last().map_or(0.0, |c| c.2) as u32;
    let texel = world.texel_size(lod);
    ui.say(format!("  {}: whole-scene bake at {texel:.3} m texels ({WHOLE_DIRECTIONS} directions) ...", s.name));
    let bake_config = BakeConfig {
        atlas: livebake::atlas::AtlasConfig { texel_size: Some(texel), ..config.atlas.clone() },
        samples: WHOLE_DIRECTIONS,
        ..BakeConfig::default()
    };
    let whole = bake(&scene, &bake_config, &NoProgress)?;
    let lod0 = &whole.report.lods[0];
    let bundle_seconds = lod0.bundle.as_ref().map_or(lod0.bake_seconds, |b| b.stats.bundle_seconds);
    let whole_rate = lod0.texels as f64 * WHOLE_DIRECTIONS as f64 / bundle_seconds.max(1e-9);

    let value = json!({
        "scene": s.name,
        "file": s.scene,
        "triangles": scene.triangle_count(),
        "points": reference.queries.len(),
        "eye": s.eye.to_array(),
        "turn_degrees_per_second": TURN,
        "lods": world.lods,
        "texel_size_per_lod_m": (0..world.lods).map(|k| world.texel_size(k)).collect::<Vec<_>>(),
        "first_light": { "seconds": t_light, "texels": texels },
        "error_at": MARKS.iter().map(|&m| json!({"seconds": m, "rel_rms": at(m)})).collect::<Vec<_>>(),
        "curve": curve.iter().map(|c| json!({"seconds": c.0, "rel_rms": c.1, "median_lod_bundles": c.2,
            "median_lod_punctual": c.3})).collect::<Vec<_>>(),
        "memory": {
            "peak_resident_growth_bytes": peak,
            "budget_bytes": end.memory_budget,
            "page_bytes": end.page_bytes,
            "page_fill": end.page_fill,
            "bake_bytes": end.bake_bytes,
            "fixed_bytes": end.fixed_bytes,
        },
        "cells_per_lod": end.cells_per_lod,
        "punctual_cells_per_lod": end.punctual_cells_per_lod,
        "throughput": {
            "runtime_texel_samples_per_second_median": runtime_rate,
            "whole_bake_texel_size_m": texel,
            "whole_bake_texels": lod0.texels,
            "whole_bake_texel_samples_per_second": whole_rate,
            "ratio_runtime_over_whole_bake": runtime_rate.map(|r| r / whole_rate),
        },
    });
    Ok((value, curve))
}
