//! Bundle throughput on every bundled scene at the peer's texel size (1.2 cm), 256
//! directions: effective rays per second per core (pixels with a fragment × directions ÷
//! bundle seconds ÷ cores; target 10× Embree's 2.3 M incoherent rays/s per core).

use anyhow::{Context, Result};
use serde_json::{Value, json};

use livebake::bake::{BakeConfig, bake};
use livebake::progress::NoProgress;
use livebake::scene::{LoadOptions, load_gltf};

use super::Bench;
use super::atlas::SCENES;
use super::{EMBREE_RAYS_PER_CORE, assets, median};

const TEXEL_SIZE: f32 = 0.012;

pub fn run(bench: &Bench) -> Result<Value> {
    let quick = bench.quick;
    let (runs, samples) = if quick { (1, 64) } else { (3, 256) };
    let cores = livebake::parallel::available_threads() as f64;
    let mut out = Vec::new();
    for name in SCENES {
        let scene = std::sync::Arc::new(load_gltf(&assets().join(name), &LoadOptions::default())?);
        let mut config = BakeConfig { samples, ..BakeConfig::default() };
        config.atlas.texel_size = Some(TEXEL_SIZE);
        let mut last = None;
        let rate = median(runs, || {
            let out = bake(&scene, &config, &NoProgress)?;
            let bundle = out.report.lods[0].bundle.clone().context("bundle report")?;
            let rate = bundle.effective_rays_per_second;
            last = Some((out.report.lods[0].texels, bundle));
            Ok(rate)
        })?;
        let (texels, bundle) = last.context("no bake ran")?;
        out.push(json!({
            "scene": name,
            "texel_size_m": TEXEL_SIZE,
            "texels": texels,
            "directions": samples,
            "tiles_per_direction": bundle.tiles_per_direction,
            "per_direction_ms": bundle.per_direction_ms,
            "median_effective_rays_per_second": rate,
            "effective_rays_per_second_per_core": rate / cores,
            "ratio_to_embree_per_core": rate / cores / EMBREE_RAYS_PER_CORE,
            "target_ratio_to_embree_per_core": 10.0,
        }));
    }
    Ok(Value::Array(out))
}
