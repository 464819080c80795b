//! Load, unwrap + pack and texel-map times on the bundled scenes and on a large synthetic
//! one (the 312k-triangle "temple", for scaling).

use std::time::Instant;

use anyhow::Result;
use serde_json::{Value, json};

use livebake::atlas::{Atlas, AtlasConfig, TexelMap};
use livebake::reference::scenes::temple;
use livebake::scene::{LoadOptions, Scene, SceneGeometry, load_gltf};

use super::{assets, median, seconds};
use crate::cli::progress::Ui;

pub const SCENES: [&str; 3] = [
    "cornell_box/cornellBox-2.79-Cycles-gltf.gltf",
    "van_gogh_room/van_gogh_room_lit.gltf",
    "cornell_2m/cornell_2m.gltf",
];

pub fn run(quick: bool, _ui: &Ui) -> Result<Value> {
    let runs = if quick { 3 } else { 7 };
    let mut out = Vec::new();
    for name in SCENES {
        let path = assets().join(name);
        let scene = load_gltf(&path, &LoadOptions::default())?;
        let load = median(runs, || {
            let t = Instant::now();
            load_gltf(&path, &LoadOptions::default())?;
            Ok(seconds(t))
        })?;
        out.push(scene_times(name, &scene, Some(load), runs)?);
    }
    if !quick {
        out.push(scene_times("synthetic temple", &temple(), None, 3)?);
    }
    Ok(Value::Array(out))
}

fn scene_times(name: &str, scene: &Scene, load: Option<f64>, runs: usize) -> Result<Value> {
    let geom = SceneGeometry::new(scene);
    let config = AtlasConfig::default();
    let atlas = Atlas::build(scene, &geom, &config)?;
    let build = median(runs, || {
        let t = Instant::now();
        Atlas::build(scene, &geom, &config)?;
        Ok(seconds(t))
    })?;
    let unwrap = median(runs, || Ok(Atlas::build(scene, &geom, &config)?.stats.unwrap_seconds))?;
    let pack = median(runs, || Ok(Atlas::build(scene, &geom, &config)?.stats.pack_seconds))?;
    let texels = |lod| {
        median(runs, || {
            let t = Instant::now();
            TexelMap::build(scene, &geom, &atlas, lod);
            Ok(seconds(t))
        })
    };
    Ok(json!({
        "scene": name,
        "triangles": geom.len(),
        "texel_size_m": atlas.texel_size,
        "atlas": [atlas.width, atlas.height],
        "charts": atlas.stats.charts,
        "fill_ratio": atlas.stats.fill_ratio,
        "texels_lod0": atlas.stats.covered_texels_lod0,
        "median_seconds": { "load": load, "atlas_build": build, "unwrap": unwrap, "pack": pack, "texels_lod0": texels(0)?, "texels_lod1": texels(1)? },
    }))
}
