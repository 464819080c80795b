//! The paper's Fig. 6 / Table 2 comparison on the third-party room (the lit Van Gogh room):
//! no tiling (one W×W bundle), uniform K×K tiles at W×W each, and adaptive tiling (Eq. 1–3),
//! all with the same W, N and R, in one run: time, error against the reference path tracer
//! at light-map texels, overflow and false-alarm ratios, tiles per direction.

use anyhow::{Context, Result};
use livebake::glam::Vec3;
use serde_json::{Value, json};

use livebake::bake::{BakeConfig, bake};
use livebake::bundle::tiles::TilingMode;
use livebake::progress::NoProgress;
use livebake::reference::{ReferenceTracer, RelativeRmsError};
use livebake::scene::{LoadOptions, Rgb, load_gltf};

use super::Bench;
use super::assets;

const ROOM: &str = "van_gogh_room/van_gogh_room_lit.gltf";

pub fn run(bench: &Bench) -> Result<Value> {
    let quick = bench.quick;
    let scene = std::sync::Arc::new(load_gltf(&assets().join(ROOM), &LoadOptions::default())?);
    let (directions, ref_points, ref_spp) = if quick { (32, 100, 1024) } else { (128, 300, 8192) };
    let mut base = BakeConfig { samples: directions, ..BakeConfig::default() };
    base.atlas.texel_size = Some(0.02);
    base.bundle.head_side = 256;
    base.bundle.node_capacity = 1 << 17;
    base.bundle.measure_false_alarms = true;
    let modes =
        [("none", TilingMode::None), ("uniform:4", TilingMode::Uniform { k: 4 }), ("adaptive", TilingMode::Adaptive)];
    let mut bakes = Vec::new();
    for (name, mode) in modes {
        let mut config = base.clone();
        config.bundle.tiling = mode;
        let t = std::time::Instant::now();
        let out = bake(&scene, &config, &NoProgress)?;
        bakes.push((name, t.elapsed().as_secs_f64(), out));
    }
    // Reference at texels spread over the light map (the three bakes share the layout).
    let texels = &bakes[0].2.lods[0].texels;
    let picks: Vec<usize> = (0..texels.len())
        .step_by((texels.len() / ref_points).max(1))
        .filter(|&i| texels.emission[i] == Rgb::ZERO)
        .collect();
    let queries: Vec<(Vec3, Vec3)> = picks.iter().map(|&i| (texels.position[i], texels.normal[i])).collect();
    let tracer = ReferenceTracer::new(&scene);
    let (reference, _) = tracer.irradiance_batch_estimates(&queries, ref_spp, 11, &|_| {});
    let mut rows = Vec::new();
    for (name, secs, out) in &bakes {
        let e = &out.lods[0].irradiance;
        let mut error = RelativeRmsError::default();
        for (k, &i) in picks.iter().enumerate() {
            error.add(e[i].as_dvec3(), reference[k].e.as_dvec3(), reference[k].stderr.as_dvec3());
        }
        let b = out.report.lods[0].bundle.as_ref().context("bundle report")?;
        rows.push(json!({
            "tiling": name,
            "seconds": secs,
            "error": error.value(),
            "tiles_per_direction": b.tiles_per_direction,
            "overflow_ratio": b.overflow_ratio,
            "false_alarm_ratio": b.false_alarm_ratio,
            "overflowed_tiles": b.stats.pass.overflowed_tiles,
            "resplits": b.stats.pass.resplits,
            "effective_rays_per_second": b.effective_rays_per_second,
            "per_direction_ms": b.per_direction_ms,
        }));
    }
    Ok(json!({
        "scene": ROOM,
        "texel_size_m": 0.02,
        "directions": directions,
        "W": base.bundle.head_side,
        "N": base.bundle.node_capacity,
        "R": base.bundle.analysis_res,
        "alpha": base.bundle.alpha,
        "reference_points": picks.len(),
        "reference_paths": ref_spp,
        "modes": rows,
    }))
}
