//! Load, unwrap + pack and texel-map times on the bundled scenes, on a real game map (zdm2,
//! at LOD-0 budgets of 500k and 2 M texels, against the goal of fill ≥ 0.5) and, for
//! scale only, on large synthetic ones: the 312k-triangle "temple" as built (shared
//! vertices), the same as a triangle soup (no shared vertices, float noise, coincident
//! copies) and a 1.1 M-triangle instanced scene (three soup temples and eight rooms under
//! several transforms). Charts per triangle, fill and covered texels against the budget come
//! with the times.

use std::time::Instant;

use anyhow::Result;
use serde_json::{Value, json};

use livebake::atlas::{Atlas, AtlasConfig, TexelMap};
use livebake::reference::scenes::{temple, temple_instanced, temple_soup};
use livebake::scene::{LoadOptions, Scene, SceneGeometry, load_gltf};

use super::Bench;
use super::{assets, median, seconds};

pub const SCENES: [&str; 3] = [
    "cornell_box/cornellBox-2.79-Cycles-gltf.gltf",
    "van_gogh_room/van_gogh_room_lit.gltf",
    "cornell_2m/cornell_2m.gltf",
];

/// The real game map, at the two LOD-0 texel budgets.
const GAME_MAP: (&str, [u64; 2]) = ("zdm2/zdm2.gltf", [500_000, 2_000_000]);

/// Builds a synthetic scene.
type SceneMaker = fn() -> Scene;

pub fn run(bench: &Bench) -> Result<Value> {
    let (quick, ui) = (bench.quick, bench.ui);
    let runs = if quick { 3 } else { 7 };
    let mut out = Vec::new();
    let scenes = SCENES.map(|name| (name, 500_000)).into_iter().chain(GAME_MAP.1.map(|budget| (GAME_MAP.0, budget)));
    for (name, budget) in scenes {
        let path = assets().join(name);
        let scene = load_gltf(&path, &LoadOptions::default())?;
        let load = median(runs, || {
            let t = Instant::now();
            load_gltf(&path, &LoadOptions::default())?;
            Ok(seconds(t))
        })?;
        // The goal for real game assets.
        let goals = (name == GAME_MAP.0).then(|| json!({ "fill_ratio_at_least": 0.5 }));
        out.push(scene_times(name, &scene, budget, Some(load), runs, true, goals)?);
    }
    if !quick {
        let big: [(&str, SceneMaker); 3] = [
            ("synthetic temple", temple),
            ("synthetic temple, triangle soup", temple_soup),
            ("instanced temples and rooms", temple_instanced),
        ];
        // The goals for the temple class of asset (a game asset: a triangle soup).
        let goals = json!({ "triangles_per_chart_at_least": 8.0, "fill_ratio_at_least": 0.6, "atlas_build_seconds_at_most": 2.0 });
        for (k, (name, make)) in big.into_iter().enumerate() {
            ui.say(format!("  {name} ..."));
            let scene = make();
            out.push(scene_times(name, &scene, 500_000, None, 3, k < 2, (k == 1).then(|| goals.clone()))?);
        }
    }
    Ok(Value::Array(out))
}

/// Atlas figures of one scene at a LOD-0 texel budget; medians of `runs` builds (the unwrap
/// and pack times from the same builds). `texel_lod1`: also time the LOD-1 texel map;
/// `goals`: the goals for this scene, reported beside the figures.
fn scene_times(
    name: &str,
    scene: &Scene,
    budget: u64,
    load: Option<f64>,
    runs: usize,
    texel_lod1: bool,
    goals: Option<Value>,
) -> Result<Value> {
    let geom = SceneGeometry::new(scene);
    let config = AtlasConfig { texel_budget: budget, ..AtlasConfig::default() };
    let mut builds = Vec::with_capacity(runs);
    for _ in 0..runs.max(1) {
        let (t, cpu) = (Instant::now(), process_cpu_seconds());
        let atlas = Atlas::build(scene, &geom, &config)?;
        let cpu = process_cpu_seconds().zip(cpu).map_or(f64::NAN, |(b, a)| b - a);
        builds.push((seconds(t), atlas.stats.unwrap_seconds, atlas.stats.pack_seconds, cpu));
    }
    let mid = |f: fn(&(f64, f64, f64, f64)) -> f64| {
        let mut v: Vec<f64> = builds.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let atlas = Atlas::build(scene, &geom, &config)?;
    let texels = |lod| {
        median(runs, || {
            let t = Instant::now();
            TexelMap::build(scene, &geom, &atlas, lod);
            Ok(seconds(t))
        })
    };
    let texels_lod1 = if texel_lod1 { Some(texels(1)?) } else { None };
    let covered = atlas.stats.covered_texels_lod0;
    Ok(json!({
        "scene": name,
        "triangles": geom.len(),
        "faces": atlas.faces.len(),
        "texel_size_m": atlas.texel_size,
        "atlas": [atlas.width, atlas.height],
        "charts": atlas.stats.charts,
        "triangles_per_chart": geom.len() as f64 / atlas.stats.charts.max(1) as f64,
        "fill_ratio": atlas.stats.fill_ratio,
        "texels_lod0": covered,
        "texel_budget": config.texel_budget,
        "covered_over_budget": covered as f64 / config.texel_budget as f64,
        "median_seconds": {
            "load": load,
            "atlas_build": mid(|b| b.0),
            "unwrap": mid(|b| b.1),
            "pack": mid(|b| b.2),
            "atlas_build_cpu": (!mid(|b| b.3).is_nan()).then(|| mid(|b| b.3)),
            "texels_lod0": texels(0)?,
            "texels_lod1": texels_lod1,
        },
        "goals": goals,
    }))
}

/// CPU time (user + system, all threads) this process has used, from `/proc/self/stat`
/// (Linux; `None` elsewhere): next to wall time it shows how much a shared machine slowed a
/// measurement down.
fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name start at field 3 (state); utime and stime
    // are fields 14 and 15, in USER_HZ ticks (100 per second on Linux).
    let mut f = stat.rsplit_once(')')?.1.split_whitespace().skip(11);
    let (user, system): (f64, f64) = (f.next()?.parse().ok()?, f.next()?.parse().ok()?);
    Some((user + system) / 100.0)
}
