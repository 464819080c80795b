//! Startup: LOD 0 of the bundled room at 5 cm texels, 256 directions, multi-bounce (target:
//! bake under 2 s, whole `bake` command under 3 s), and bundle throughput in effective rays
//! per second per core (target: 10× Embree's 2.3 M incoherent rays/s per core).

use std::process::Command;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use serde_json::{Value, json};

use livebake::bake::{BakeConfig, bake};
use livebake::progress::NoProgress;
use livebake::scene::{LoadOptions, load_gltf};

use super::Bench;
use super::{EMBREE_RAYS_PER_CORE, assets, median, seconds};

const ROOM: &str = "van_gogh_room/van_gogh_room_lit.gltf";

pub fn run(bench: &Bench) -> Result<Value> {
    let quick = bench.quick;
    let runs = if quick { 1 } else { 3 };
    let path = assets().join(ROOM);
    let scene = std::sync::Arc::new(load_gltf(&path, &LoadOptions::default())?);
    let mut config = BakeConfig { samples: 256, ..BakeConfig::default() };
    config.atlas.texel_size = Some(0.05);
    let mut last = None;
    let bake_seconds = median(runs, || {
        let t = Instant::now();
        let out = bake(&scene, &config, &NoProgress)?;
        let s = seconds(t);
        last = Some(out);
        Ok(s)
    })?;
    let out = last.context("no bake ran")?;
    let dir = tempfile_dir()?;
    let exe = bench.livebake;
    let command_seconds = median(runs, || {
        let t = Instant::now();
        let status = Command::new(exe)
            .args(["-q", "bake"])
            .arg(&path)
            .args(["--texel-size", "0.05", "--samples", "256", "--out"])
            .arg(&dir)
            .status()?;
        if !status.success() {
            bail!("livebake bake exited with {status}");
        }
        Ok(seconds(t))
    })?;
    let _ = std::fs::remove_dir_all(&dir);
    let lod = &out.report.lods[0];
    let bundle = lod.bundle.as_ref().context("bundle report")?;
    let cores = livebake::parallel::available_threads() as f64;
    let per_core = bundle.effective_rays_per_second / cores;
    let with_light_pass_per_core = bundle.effective_rays_per_second_with_light_pass / cores;
    Ok(json!({
        "scene": ROOM,
        "texel_size_m": 0.05,
        "texels": lod.texels,
        "directions": 256,
        "median_seconds": { "bake": bake_seconds, "whole_command": command_seconds },
        "targets_seconds": { "bake": 2.0, "whole_command": 3.0 },
        "per_direction_ms": bundle.per_direction_ms,
        "effective_rays_per_second": bundle.effective_rays_per_second,
        "effective_rays_per_second_per_core": per_core,
        "effective_rays_per_second_per_core_with_light_pass": with_light_pass_per_core,
        "ratio_to_embree_per_core": per_core / EMBREE_RAYS_PER_CORE,
        "target_ratio_to_embree_per_core": 10.0,
    }))
}

fn tempfile_dir() -> Result<std::path::PathBuf> {
    let dir = std::env::temp_dir().join(format!("livebake-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    Ok(dir)
}
