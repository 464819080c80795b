//! Serve: `livebake serve` on localhost with its page in headless Chromium (SwiftShader) in an
//! emulated headset (npm iwer, Quest 3 config, stereo; tests/web/xr_driver.mjs), while the
//! runtime refines. Figures, from the server's `--stats`:
//! - publish-to-texture latency: the hub seeing a publish → the page's acknowledgement that
//!   a fence placed after the update's upload calls is signalled, i.e. the GPU has written
//!   the pages (goal ≤ 100 ms median; it includes the ack's trip back); beside it, the hub
//!   seeing a publish → the page's acknowledgement that the upload calls returned;
//! - bytes per publish against the published pages' own bytes (goal: the pages plus a small
//!   header);
//! - the page's draw time (both eyes, `gl.finish()` included: software GL) and its frame
//!   interval, in the emulator and on the desktop page.
//!
//! Needs what scripts/test installs: Chromium, Node.js and the npm packages iwer and
//! playwright-core (in `$LIVEBAKE_NODE_TOOLS`, default `~/.cache/livebake-node`).

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};

use anyhow::{Context, Result, bail};
use serde_json::{Value, json};

use super::{Bench, assets};

const SCENE: &str = "cornell_2m/cornell_2m.gltf";
/// Fine texels and LODs enough for the runtime to publish all through the run (~100
/// publishes in 20 s on two cores).
const RUNTIME: [&str; 6] = ["--texel-size", "0.05", "--lods", "4", "--samples", "128"];
/// A real scene in the headset beside it, at the runtime's defaults: a game map (59k
/// triangles) under a sun and a sky, so both light-map layers are drawn, from its framing
/// start view. Its texels are many and its frames long under software GL: the latency there
/// is what a real building costs this machine, not what the room's does.
const REAL_SCENE: &str = "zdm2/zdm2_sun.gltf";

fn node_tools() -> PathBuf {
    match std::env::var_os("LIVEBAKE_NODE_TOOLS") {
        Some(dir) => PathBuf::from(dir),
        None => PathBuf::from(std::env::var_os("HOME").unwrap_or_default()).join(".cache/livebake-node"),
    }
}

fn quantile(v: &[f64], q: f64) -> Option<f64> {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    (!v.is_empty()).then(|| v[((v.len() - 1) as f64 * q).round() as usize])
}

pub fn run(bench: &Bench) -> Result<Value> {
    let tools = node_tools();
    for p in ["iwer", "playwright-core"] {
        if !tools.join("node_modules").join(p).join("package.json").exists() {
            bail!("npm package {p} missing from {} (scripts/test installs it)", tools.display());
        }
    }
    let (seconds, eye) = if bench.quick { (6.0, [480u32, 270u32]) } else { (20.0, [960, 540]) };
    let headset = session(bench, &tools, SCENE, &RUNTIME, seconds, eye, false)?;
    let desktop = session(bench, &tools, SCENE, &RUNTIME, seconds, eye, true)?;
    let real = if bench.quick { Value::Null } else { session(bench, &tools, REAL_SCENE, &[], seconds, eye, false)? };
    Ok(json!({
        "scene": SCENE,
        "runtime_options": RUNTIME.join(" "),
        "seconds": seconds,
        "eye_size": eye,
        "target_publish_to_texture_ms": 100.0,
        "page_renderer": "Chromium, SwiftShader (software GL)",
        "headset": headset,
        "desktop": desktop,
        "real_scene": { "scene": REAL_SCENE, "runtime_options": "(defaults)", "headset": real },
    }))
}

/// One `serve` process of `scene` (under the bundled assets) with `runtime` options, and one
/// page: in the emulated headset (both eyes of `eye` pixels), or (`desktop`) the desktop
/// page on a canvas of both eyes' size.
fn session(
    bench: &Bench,
    tools: &std::path::Path,
    scene: &str,
    runtime: &[&str],
    seconds: f64,
    eye: [u32; 2],
    desktop: bool,
) -> Result<Value> {
    let dir = std::env::temp_dir().join(format!("livebake-bench-serve-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let stats_path = dir.join("serve.json");
    let mut child = Command::new(bench.livebake)
        .args(["-q", "serve"])
        .arg(assets().join(scene))
        .args(["--port", "0", "--no-watch", "--seconds", &(seconds + 30.0).to_string()])
        .args(runtime)
        .arg("--stats")
        .arg(&stats_path)
        .stdout(Stdio::piped())
        .spawn()
        .context("cannot start livebake serve")?;
    let mut url = String::new();
    BufReader::new(child.stdout.take().context("serve's stdout")?).read_line(&mut url)?;
    let url = url.trim().to_string();
    if !url.starts_with("http://") {
        let _ = child.kill();
        bail!("livebake serve printed {url:?}");
    }
    let config = json!({
        "tools": tools, "url": format!("{url}?finish"), "out": dir, "eye_size": eye, "frames": 3, "no_vr": desktop,
        "timeout_s": 300, "steps": ["status", format!("sleep:{}", (seconds * 1000.0) as u64), "status"],
    });
    let config_path = dir.join("config.json");
    std::fs::write(&config_path, config.to_string())?;
    let driver = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/web/xr_driver.mjs"));
    let out = Command::new("node").arg(driver).arg(&config_path).output().context("cannot run node")?;
    // SIGINT ends serve cleanly (its --stats written).
    // SAFETY: kill(2) on our own child's pid.
    unsafe {
        libc::kill(child.id() as i32, libc::SIGINT);
    }
    let status = child.wait()?;
    let page: Value = serde_json::from_slice(&out.stdout).context("the driver's output")?;
    if let Some(e) = page.get("error") {
        bail!("the page failed: {e}");
    }
    if !status.success() {
        bail!("livebake serve exited with {status}");
    }
    // Frames the page drew during the sleep (the emulated headset's frame loop, or the
    // desktop page's, both the browser's animation frames), and what its uploads handed to
    // the GL.
    let statuses: Vec<&Value> =
        page["steps"].as_array().map(|a| a.iter().filter(|s| s["step"] == "status").collect()).unwrap_or_default();
    let frames_key = if desktop { "frames" } else { "xr_frames" };
    let (frame_interval_ms, uploaded_per_update, calls_per_update) = match statuses.as_slice() {
        [a, b] => {
            let delta = |k: &str| b["after"][k].as_f64().unwrap_or(0.0) - a["after"][k].as_f64().unwrap_or(0.0);
            let (frames, ms, updates) = (delta(frames_key), delta("now"), delta("updates"));
            let per = |k: &str| (updates > 0.0).then(|| delta(k) / updates);
            ((frames > 0.0).then(|| ms / frames), per("bytes_uploaded"), per("upload_calls"))
        }
        _ => (None, None, None),
    };
    let s: Value = serde_json::from_slice(&std::fs::read(&stats_path)?).context("serve's stats")?;
    let _ = std::fs::remove_dir_all(&dir);
    let series = |k: &str| -> Vec<f64> {
        s[k].as_array().map(|a| a.iter().filter_map(Value::as_f64).collect()).unwrap_or_default()
    };
    let (latencies, uploads) = (series("ack_latency_ms"), series("upload_latency_ms"));
    let updates = s["updates"].as_f64().unwrap_or(0.0);
    let per = |k: &str| (updates > 0.0).then(|| s[k].as_f64().unwrap_or(0.0) / updates);
    let (bytes, page_bytes) = (per("update_bytes"), per("update_page_bytes"));
    Ok(json!({
        "updates": s["updates"],
        // Of those, the ones that waited for the page's acknowledgements (flow control).
        "updates_held": s["updates_held"],
        "pages_per_update": per("update_pages"),
        // Confirmed by a fence the page polls (between tasks and at each frame's start).
        "publish_to_texture_ms": { "median": quantile(&latencies, 0.5), "p90": quantile(&latencies, 0.9), "samples": latencies.len() },
        // Only the upload calls returned (the GPU may still be busy with earlier frames).
        "publish_to_upload_call_ms": { "median": quantile(&uploads, 0.5), "p90": quantile(&uploads, 0.9), "samples": uploads.len() },
        "bytes_per_update": bytes,
        "page_bytes_per_update": page_bytes,
        "header_bytes_per_update": bytes.zip(page_bytes).map(|(b, p)| b - p),
        // What the page's texSubImage2D calls carried (one a run of adjacent pages of a pool
        // row), and how many calls, per update it applied.
        "uploaded_bytes_per_update": uploaded_per_update,
        "upload_calls_per_update": calls_per_update,
        // The draw (both eyes in the headset), gl.finish() included, as the page times it.
        "page_frame_ms": s["page_frame_ms"],
        // Between the page's frames (the browser's animation frames: the emulator's pacing in
        // the headset; on the desktop page at most one frame in flight).
        "page_frame_interval_ms": frame_interval_ms,
    }))
}
