//! A million triangles the way users' scenes have them: instancing nodes. Ninety copies of the
//! bundled Van Gogh room (its lit variant: a ceiling lamp and a bedside point light each) as
//! 90 parent nodes in a 10 × 9 grid of translations, written as a glTF beside a copy of the
//! room's buffer in a temp dir: 1 014 480 triangles, 90 small emitters, 90 point lights.
//!
//! Timed from nothing, as a user starting `livebake` on it: the load, then `Runtime::start`
//! (atlas, world, LOD-0 texels) to the `first_light` event; with the atlas's figures (charts,
//! fill, covered texels against the budget, seconds) and the process's peak resident bytes up
//! to first light (Linux's `clear_refs` resets the peak first); then, once the LOD-0 bake has
//! all its directions, its time and pass counters (light pass included). Goal (issue 8):
//! first light ≤ 15 s from the start of the load, under 2 GB.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result};
use serde_json::{Value, json};

use livebake::bake::memory::{peak_resident_bytes, resident_bytes};
use livebake::cpu::CpuProvider;
use livebake::runtime::{Runtime, RuntimeConfig};
use livebake::scene::{LoadOptions, load_gltf};

use super::runtime::{PATIENCE, wait_first_light};
use super::{Bench, Narrator};
use super::{assets, seconds};

/// Copies of the room, and the grid they stand in (columns along x).
const COPIES: usize = 90;
const COLUMNS: usize = 10;
/// Gap between neighbouring rooms (metres): they do not touch, each is closed.
const GAP: f64 = 1.0;
/// The goals.
const GOAL_SECONDS: f64 = 15.0;
const GOAL_BYTES: u64 = 2_000_000_000;

pub fn run(bench: &Bench) -> Result<Value> {
    let ui = bench.ui;
    let dir = std::env::temp_dir().join(format!("livebake-bench-instanced-{}", std::process::id()));
    let path = write_scene(&dir).context("writing the instanced scene")?;
    let result = measure(&path, ui);
    let _ = std::fs::remove_dir_all(&dir);
    result
}

/// Writes the instanced scene into `dir`; returns its path.
fn write_scene(dir: &Path) -> Result<PathBuf> {
    let room_dir = assets().join("van_gogh_room");
    let text = std::fs::read_to_string(room_dir.join("van_gogh_room_lit.gltf"))?;
    let mut gltf: Value = serde_json::from_str(&text)?;
    let room_nodes = gltf["nodes"].as_array().context("the room has no nodes")?.clone();
    // The room's extent along x and z, from its meshes' POSITION bounds.
    let (mut lo, mut hi) = ([f64::MAX; 3], [f64::MIN; 3]);
    for mesh in gltf["meshes"].as_array().context("the room has no meshes")? {
        for prim in mesh["primitives"].as_array().into_iter().flatten() {
            let accessor = &gltf["accessors"][prim["attributes"]["POSITION"].as_u64().context("no POSITION")? as usize];
            for k in 0..3 {
                lo[k] = lo[k].min(accessor["min"][k].as_f64().context("POSITION without min")?);
                hi[k] = hi[k].max(accessor["max"][k].as_f64().context("POSITION without max")?);
            }
        }
    }
    let step = [hi[0] - lo[0] + GAP, hi[2] - lo[2] + GAP];
    let mut nodes = Vec::new();
    let mut roots = Vec::new();
    for i in 0..COPIES {
        let first = nodes.len();
        nodes.extend(room_nodes.iter().cloned());
        let children: Vec<usize> = (first..nodes.len()).collect();
        let (x, z) = ((i % COLUMNS) as f64 * step[0], (i / COLUMNS) as f64 * step[1]);
        roots.push(nodes.len());
        nodes.push(json!({ "name": format!("room {i}"), "translation": [x, 0.0, z], "children": children }));
    }
    gltf["nodes"] = Value::Array(nodes);
    gltf["scenes"] = json!([{ "nodes": roots }]);
    gltf["scene"] = json!(0);
    std::fs::create_dir_all(dir)?;
    std::fs::copy(room_dir.join("van_gogh_room.bin"), dir.join("van_gogh_room.bin"))?;
    let path = dir.join("van_gogh_rooms_90.gltf");
    std::fs::write(&path, serde_json::to_vec(&gltf)?)?;
    Ok(path)
}

fn measure(path: &Path, ui: &dyn Narrator) -> Result<Value> {
    // Peak resident bytes from here (Linux ≥ 4.0: "5" resets VmHWM to VmRSS).
    let _ = std::fs::write("/proc/self/clear_refs", "5");
    let before = resident_bytes();
    let started = Instant::now();
    let scene = Arc::new(load_gltf(path, &LoadOptions::default())?);
    let load_seconds = seconds(started);
    ui.say(format!("  {} triangles loaded in {load_seconds:.2} s", scene.triangle_count()));
    let config = RuntimeConfig::default();
    let budget = config.atlas.texel_budget;
    let runtime = Runtime::start(scene.clone(), config, Arc::new(CpuProvider::new())).context("Runtime::start")?;
    let (t_light, texels, _) = wait_first_light(&runtime)?;
    let first_light_seconds = seconds(started);
    let peak = peak_resident_bytes();
    // First light shows LOD 0 after its first directions; its pass counters come with the
    // whole LOD-0 bake, which goes on to all of them.
    let lod0_seconds = wait_lod0_complete(&runtime).then(|| seconds(started));
    let stats = runtime.stats();
    let world = runtime.world();
    let atlas = &world.atlas;
    let out = json!({
        "scene": format!("{COPIES} copies of van_gogh_room_lit.gltf as instancing nodes"),
        "triangles": scene.triangle_count(),
        "punctual_lights": scene.lights.len(),
        "small_emitters": world.bundle.emitters.small.len(),
        "load_seconds": load_seconds,
        "atlas": {
            "charts": atlas.stats.charts,
            "fill_ratio": atlas.stats.fill_ratio,
            "covered_texels_lod0": atlas.stats.covered_texels_lod0,
            "texel_budget": budget,
            "budget_used": atlas.stats.budget_used,
            "texel_size_m": atlas.texel_size,
            "unwrap_seconds": atlas.stats.unwrap_seconds,
            "pack_seconds": atlas.stats.pack_seconds,
        },
        "first_light_seconds_from_start": t_light,
        "first_light_seconds_from_load": first_light_seconds,
        "first_light_texels": texels,
        "lod0_complete_seconds_from_load": lod0_seconds,
        "lod0_pass": stats.first_light_pass,
        "cell_setup_seconds": stats.cell_setup_seconds,
        "resident_bytes_before": before,
        "peak_resident_bytes": peak,
        "goal": { "first_light_seconds_at_most": GOAL_SECONDS, "peak_bytes_below": GOAL_BYTES },
        "goal_met": first_light_seconds <= GOAL_SECONDS && peak.is_some_and(|p| p < GOAL_BYTES),
    });
    runtime.shutdown()?;
    Ok(out)
}

/// Waits for the LOD-0 bake to have all its directions (its pass counters set); false when
/// the runtime does not get there within the bench's patience.
fn wait_lod0_complete(runtime: &Runtime) -> bool {
    let deadline = Instant::now() + PATIENCE;
    while Instant::now() < deadline {
        if runtime.stats().first_light_pass.directions > 0 {
            return true;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    false
}
