//! Viewer: frame time on the machine's adapter (lavapipe here) for the bundled rooms while
//! the light arrives, and the time from launch to the first lit frame (goal: ≤ 1.5 s). Each
//! run is a fresh `livebake view` process in a window on a private Xvfb, so launch includes
//! process start, scene load, atlas, device, window and the LOD-0 light.
//!
//! The light is the live runtime with its defaults (what `livebake view SCENE` does): frame
//! times are taken while it refines the cells in view.

use std::process::Command;

use anyhow::{Context, Result, bail};
use serde_json::{Value, json};

use livebake::viewer::xvfb::Xvfb;

use super::Bench;
use super::assets;

const ROOMS: [&str; 3] = [
    "cornell_box/cornellBox-2.79-Cycles-gltf.gltf",
    "cornell_2m/cornell_2m.gltf",
    "van_gogh_room/van_gogh_room_lit.gltf",
];
const SIZE: &str = "1280x720";

fn median(mut v: Vec<f64>) -> Option<f64> {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied()
}

pub fn run(bench: &Bench) -> Result<Value> {
    let quick = bench.quick;
    let (runs, frames) = if quick { (1, 20) } else { (3, 120) };
    let xvfb = Xvfb::start()?;
    let exe = bench.livebake;
    let dir = std::env::temp_dir().join(format!("livebake-bench-viewer-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let mut scenes = Vec::new();
    let mut adapter = Value::Null;
    for room in ROOMS {
        let (mut medians, mut p99s, mut first) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..runs {
            let stats = dir.join("stats.json");
            let out = Command::new(exe)
                .env("DISPLAY", &xvfb.display)
                .args(["-q", "view"])
                .arg(assets().join(room))
                .args(["--frames", &frames.to_string(), "--size", SIZE])
                .arg("--stats")
                .arg(&stats)
                .output()?;
            if !out.status.success() {
                bail!("livebake view {room} failed: {}", String::from_utf8_lossy(&out.stderr));
            }
            let v: Value = serde_json::from_slice(&std::fs::read(&stats)?).context("viewer stats")?;
            adapter = v["adapter"].clone();
            medians.extend(v["lit_frame_ms"]["median"].as_f64());
            p99s.extend(v["lit_frame_ms"]["p99"].as_f64());
            first.extend(v["first_lit_frame_seconds"].as_f64());
        }
        scenes.push(json!({
            "scene": room,
            "lit_frame_ms": { "median": median(medians), "p99": median(p99s) },
            "first_lit_frame_seconds": median(first),
        }));
    }
    let _ = std::fs::remove_dir_all(&dir);
    Ok(json!({
        "adapter": adapter,
        "window": SIZE,
        "lit_frames_per_run": frames,
        "runs": runs,
        "light_source": "the live runtime, default options",
        "target_first_lit_frame_seconds": 1.5,
        "scenes": scenes,
    }))
}
