//! `livebake serve`: the page in headless Chromium with an emulated headset (npm `iwer`,
//! driven by tests/web/xr_driver.mjs through playwright-core), the socket's messages as a
//! plain client reads them, and the HTTP side's refusals. Nothing is skipped for want of a
//! headset or a GPU: Chromium draws with SwiftShader, the viewer on lavapipe under Xvfb,
//! and scripts/test installs Chromium and the npm packages when missing.

mod viewer_support;

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use livebake::runtime::shown::{Layer, Page, ShownLightmap};
use livebake::serve::protocol::{
    AckStage, CELL_ENTRY, PAGE_ENTRY_HEADER, UPDATE_HEADER, Update, decode_update, encode_ack, encode_pose,
};
use serde_json::{Value, json};
use tungstenite::Message;
use viewer_support::{cornell_path, run_bounded, xvfb};

fn livebake() -> Command {
    Command::new(env!("CARGO_BIN_EXE_livebake"))
}

/// A `livebake serve` child, killed when dropped; `url` is the line it printed.
struct Served {
    child: Child,
    url: String,
}

impl Drop for Served {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Served {
    fn start(scene: &Path, args: &[&str]) -> Served {
        let mut child = livebake()
            .arg("-q")
            .arg("serve")
            .arg(scene)
            .args(["--port", "0", "--backend", "cpu", "--seconds", "600"])
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .unwrap();
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
        assert!(line.starts_with("http://"), "serve printed {line:?}");
        Served { child, url: line.trim().to_string() }
    }

    /// host:port
    fn addr(&self) -> String {
        self.url.trim_start_matches("http://").split('/').next().unwrap().to_string()
    }

    fn token(&self) -> Option<String> {
        self.url.split_once("?token=").map(|(_, t)| t.to_string())
    }

    fn status(&self) -> Value {
        let q = self.token().map(|t| format!("?token={t}")).unwrap_or_default();
        let (code, body) = http_get(&self.addr(), &format!("/status.json{q}"), "");
        assert_eq!(code, 200);
        serde_json::from_slice(&body).unwrap()
    }

    fn wait_first_light(&self) -> Value {
        let deadline = Instant::now() + Duration::from_secs(300);
        loop {
            let s = self.status();
            if s["first_light"] == true {
                return s;
            }
            assert!(Instant::now() < deadline, "no first light: {s}");
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    fn socket(&self) -> tungstenite::WebSocket<TcpStream> {
        let stream = TcpStream::connect(self.addr()).unwrap();
        stream.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
        let q = self.token().map(|t| format!("?token={t}")).unwrap_or_default();
        let (ws, _) = tungstenite::client(format!("ws://{}/socket{q}", self.addr()), stream).unwrap();
        ws
    }
}

/// A raw HTTP GET (the path sent exactly as given): status code and body.
fn http_get(addr: &str, path: &str, extra_headers: &str) -> (u16, Vec<u8>) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    write!(s, "GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n{extra_headers}\r\n").unwrap();
    let mut all = Vec::new();
    s.read_to_end(&mut all).unwrap();
    let head_end = all.windows(4).position(|w| w == b"\r\n\r\n").expect("a response head");
    let head = String::from_utf8_lossy(&all[..head_end]).to_string();
    let code = head.split_whitespace().nth(1).and_then(|c| c.parse().ok()).unwrap();
    (code, all[head_end + 4..].to_vec())
}

/// The scene description, then every message up to and including the first update.
fn read_welcome(ws: &mut tungstenite::WebSocket<TcpStream>) -> (Value, Update) {
    let mut scene = Value::Null;
    loop {
        match ws.read().unwrap() {
            Message::Text(t) => scene = serde_json::from_str(&t).unwrap(),
            Message::Binary(b) if b[0] == 3 => return (scene, decode_update(&b).expect("a well-formed update")),
            _ => {}
        }
    }
}

/// Where scripts/test installs the npm packages.
fn node_tools() -> PathBuf {
    match std::env::var_os("LIVEBAKE_NODE_TOOLS") {
        Some(dir) => PathBuf::from(dir),
        None => PathBuf::from(std::env::var_os("HOME").unwrap_or_default()).join(".cache/livebake-node"),
    }
}

/// Runs the page in Chromium with the emulated headset (tests/web/xr_driver.mjs); its JSON.
/// The driver's files (eye pixels) go to `out`.
fn drive(config: Value, out: &Path) -> Value {
    for p in ["iwer", "playwright-core"] {
        assert!(
            node_tools().join("node_modules").join(p).join("package.json").exists(),
            "npm package {p} missing from {}: run scripts/test, which installs it",
            node_tools().display()
        );
    }
    assert!(Path::new("/usr/bin/chromium").exists(), "Chromium missing: run scripts/test, which installs it");
    let mut config = config;
    config["tools"] = json!(node_tools());
    config["out"] = json!(out);
    let file = out.join("config.json");
    std::fs::write(&file, config.to_string()).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/web/xr_driver.mjs");
    let out = Command::new("node").arg(script).arg(&file).output().expect("cannot run node");
    let text = String::from_utf8_lossy(&out.stdout);
    let result: Value = serde_json::from_str(&text).unwrap_or_else(|e| {
        panic!("driver output is not JSON ({e}): {text}\n{}", String::from_utf8_lossy(&out.stderr))
    });
    assert!(result.get("error").is_none(), "the page failed: {result:#}");
    assert!(result["final"]["errors"].as_array().is_some_and(|e| e.is_empty()), "{result:#}");
    result
}

fn step<'a>(result: &'a Value, name: &str) -> &'a Value {
    result["steps"].as_array().unwrap().iter().find(|s| s["step"] == name).unwrap_or_else(|| panic!("{result:#}"))
}

fn v3(v: &Value) -> [f32; 3] {
    let a = v.as_array().unwrap();
    [0, 1, 2].map(|i| a[i].as_f64().unwrap() as f32)
}

/// The light map stays as first light made it: one LOD, every direction in first light.
const FROZEN: [&str; 10] =
    ["--lods", "1", "--samples", "64", "--first-light-directions", "64", "--exposure", "1.5", "--texel-size", "0.05"];

/// Each eye the page draws in the emulated headset matches livebake's own render of that
/// eye's pose (`view --stereo`, lavapipe, under Xvfb).
///
/// Tolerance. Both draw albedo × E/π from the same light map (the same f32 texels, from the
/// same seeded bake) through the same sampling formulas (the page's GLSL computes what
/// shaders/lightmap.inc.wgsl does), the same tone curve and sRGB encoding. What differs:
/// (1) rounding to 8 bits (the viewer's target encodes sRGB in hardware, the page in its
/// shader) and the two software rasterisers' exp/pow: ±1 level, so 4 levels (of 255) per
/// channel is a match; (2) the rasterisers place triangle edges differently by a fraction of
/// a pixel (different projection conventions, GL's [-1, 1] depth against Vulkan's [0, 1],
/// different f32 arithmetic): a pixel whose centre lies within that fraction of an edge may
/// show the other side's colour. The room's visible edges are ~1 000 pixels long in a
/// 160×120 eye (19 200 pixels), and a sub-pixel shift flips only the pixels whose centres
/// lie within it: a few tenths of those. Hence at most 1 % of the pixels may differ by more
/// than 4 levels, and the mean difference over all pixels must stay under 0.5 level (1 %
/// of pixels at full contrast, ~50 levels here, is 0.5); an error in exposure, tone curve,
/// light-map sampling or pose moves every lit pixel and fails it. (Measured: 0.01 % of the
/// pixels, mean 0.07 level.)
#[test]
fn each_eye_in_the_emulated_headset_matches_the_viewers_stereo_render() {
    eyes_match_the_viewer(&cornell_path(), false, &[]);
}

/// The same with a point light added to the Cornell room: the page draws with its two-layer
/// program once the punctual layer holds pages (web/shaders.js), the test above with the
/// one-layer program. Tolerance as above (same room, same view).
#[test]
fn with_a_punctual_light_each_eye_matches_the_viewers_stereo_render() {
    let dir = tempfile::tempdir().unwrap();
    let mut gltf: Value = serde_json::from_slice(&std::fs::read(cornell_path()).unwrap()).unwrap();
    gltf["extensionsUsed"].as_array_mut().unwrap().push(json!("KHR_lights_punctual"));
    gltf["extensions"] = json!({"KHR_lights_punctual": {"lights": [{"type": "point", "intensity": 2.0}]}});
    let lamp = gltf["nodes"].as_array().unwrap().len();
    gltf["nodes"].as_array_mut().unwrap().push(json!({"translation": [0.6, 1.4, 1.2],
        "extensions": {"KHR_lights_punctual": {"light": 0}}}));
    gltf["scenes"][0]["nodes"].as_array_mut().unwrap().push(json!(lamp));
    let scene = dir.path().join("cornell_lamp.gltf");
    std::fs::write(&scene, gltf.to_string()).unwrap();
    eyes_match_the_viewer(&scene, true, &[]);
}

/// The same with the room's block made a `MASK` surface whose alpha is below its cutoff
/// (0.5): the viewer cuts it out (tests/viewer.rs holds that), so the page matches it only if
/// it cuts it out too. The alpha is its texture's (2 × 1: opaque, then clear; clamped), read
/// where `KHR_texture_transform` puts it: offset (0.75, 0.5), the clear texel (the block has
/// no TEXCOORD_0, so untransformed it would read (0, 0), the opaque one), so the page matches
/// only if it reads textures through the transform too. The block is in view: `view --stereo`
/// of the room with the block whole and cut out differ by more than 4 levels in 3 435 of an
/// eye's 19 200 pixels (18 %; the block, its shadow and its bounce), against the 1 % allowed.
/// Tolerance as above.
#[test]
fn with_a_cut_out_block_each_eye_matches_the_viewers_stereo_render() {
    let dir = tempfile::tempdir().unwrap();
    let mut gltf: Value = serde_json::from_slice(&std::fs::read(cornell_path()).unwrap()).unwrap();
    let half = image::RgbaImage::from_fn(2, 1, |x, _| image::Rgba([255, 255, 255, if x == 0 { 255 } else { 0 }]));
    half.save(dir.path().join("half.png")).unwrap();
    gltf["images"] = json!([{"uri": "half.png"}]);
    gltf["samplers"] = json!([{"wrapS": 33071, "wrapT": 33071}]);
    gltf["textures"] = json!([{"source": 0, "sampler": 0}]);
    gltf["extensionsUsed"].as_array_mut().unwrap().push(json!("KHR_texture_transform"));
    let cut = gltf["materials"].as_array().unwrap().len();
    gltf["materials"].as_array_mut().unwrap().push(json!({"name": "cut out",
        "pbrMetallicRoughness": {"baseColorFactor": [0.7, 0.7, 0.7, 1.0], "baseColorTexture": {"index": 0,
            "extensions": {"KHR_texture_transform": {"offset": [0.75, 0.5]}}}},
        "alphaMode": "MASK", "alphaCutoff": 0.5}));
    let block = gltf["meshes"].as_array().unwrap().iter().position(|m| m["name"] == "block").unwrap();
    gltf["meshes"][block]["primitives"][0]["material"] = json!(cut);
    let scene = dir.path().join("cornell_cut_out.gltf");
    std::fs::write(&scene, gltf.to_string()).unwrap();
    eyes_match_the_viewer(&scene, false, &[]);
}

/// The same with the room's block made a see-through sheet: `BLEND` with alpha 0.6 and
/// `KHR_materials_transmission` 0.8, tinted green and by its vertex colours (COLOR_0, which
/// the page must multiply in as the viewer does), so both of a sheet's draws matter (it lets
/// through 0.4 + 0.48·albedo of what lies behind and reflects 0.12·albedo of its light). The
/// viewer composites it in linear radiance before the tone curve (tests/viewer.rs holds that);
/// the page matches it only if it does the same. `view --stereo` of the room with the block
/// opaque and see-through differ by more than 4 levels (in a channel) in 3 014 of the left
/// eye's 19 200 pixels (16 %), against the 1 % allowed. Tolerance as above.
#[test]
fn with_a_see_through_block_each_eye_matches_the_viewers_stereo_render() {
    let dir = tempfile::tempdir().unwrap();
    let mut gltf: Value = serde_json::from_slice(&std::fs::read(cornell_path()).unwrap()).unwrap();
    let glass = gltf["materials"].as_array().unwrap().len();
    gltf["materials"].as_array_mut().unwrap().push(json!({"name": "glass",
        "pbrMetallicRoughness": {"baseColorFactor": [0.3, 0.9, 0.4, 0.6]}, "alphaMode": "BLEND",
        "extensions": {"KHR_materials_transmission": {"transmissionFactor": 0.8}}}));
    let used = gltf.as_object_mut().unwrap().entry("extensionsUsed").or_insert(json!([]));
    used.as_array_mut().unwrap().push(json!("KHR_materials_transmission"));
    let block = gltf["meshes"].as_array().unwrap().iter().position(|m| m["name"] == "block").unwrap();
    gltf["meshes"][block]["primitives"][0]["material"] = json!(glass);
    // Vertex colours (COLOR_0, normalised bytes in a buffer file of their own) tint it further.
    let position = gltf["meshes"][block]["primitives"][0]["attributes"]["POSITION"].as_u64().unwrap() as usize;
    let count = gltf["accessors"][position]["count"].as_u64().unwrap() as usize;
    let colors: Vec<u8> =
        (0..count).flat_map(|k| [(40 + 97 * k % 216) as u8, 255, (40 + 151 * k % 216) as u8, 255]).collect();
    let buffers = gltf["buffers"].as_array_mut().unwrap();
    std::fs::write(dir.path().join("colors.bin"), &colors).unwrap();
    buffers.push(json!({"byteLength": colors.len(), "uri": "colors.bin"}));
    let buffer = buffers.len() - 1;
    let views = gltf["bufferViews"].as_array_mut().unwrap();
    views.push(json!({"buffer": buffer, "byteLength": colors.len()}));
    let view = views.len() - 1;
    let accessors = gltf["accessors"].as_array_mut().unwrap();
    accessors
        .push(json!({"bufferView": view, "componentType": 5121, "normalized": true, "type": "VEC4", "count": count}));
    gltf["meshes"][block]["primitives"][0]["attributes"]["COLOR_0"] = json!(accessors.len() - 1);
    let scene = dir.path().join("cornell_glass.gltf");
    std::fs::write(&scene, gltf.to_string()).unwrap();
    eyes_match_the_viewer(&scene, false, &[]);
}

/// The same under an outdoor HDRI (`assets/outdoor_sky`, its sun split off as a light): the
/// viewer shows the sky picture where no surface is, all around the open room, so the page
/// matches it only if it draws the same sky the same way round. `view --stereo` with the
/// sky drawn and with the backdrop in its place differ by more than 4 levels (in a channel)
/// in 13 980 of the left eye's 19 200 pixels (73 %), against the 1 % allowed. Tolerance as
/// above.
#[test]
fn under_an_outdoor_sky_each_eye_matches_the_viewers_stereo_render() {
    let sky = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/outdoor_sky/sky.exr");
    eyes_match_the_viewer(&cornell_path(), true, &["--environment", sky]);
}

/// The same under a uniform sky, which the viewer and the page draw by clearing the frame to
/// it: the room stands against it all around. Tolerance as above.
#[test]
fn under_a_uniform_sky_each_eye_matches_the_viewers_stereo_render() {
    eyes_match_the_viewer(&cornell_path(), false, &["--sky", "0.3,0.5,0.8"]);
}

/// `punctual`: whether the page shows punctual pages; `lights`: options giving both the
/// server and `view` the same surroundings.
fn eyes_match_the_viewer(scene: &Path, punctual: bool, lights: &[&str]) {
    let served = Served::start(scene, &[&FROZEN[..], &["--no-watch"], lights].concat());
    let status = served.wait_first_light();
    let yfov = status["start"]["yfov"].as_f64().unwrap();
    let (w, h) = (160u32, 120u32);
    let ipd = 0.063f32;
    let dir = tempfile::tempdir().unwrap();
    let result = drive(
        json!({"url": served.url, "fovy": yfov, "ipd": ipd, "eye_size": [w, h], "frames": 3, "steps": ["capture", "status"]}),
        dir.path(),
    );
    let eyes = step(&result, "capture")["eyes"].as_array().unwrap().clone();
    assert_eq!(eyes.len(), 2);
    let punctual_pages = step(&result, "status")["after"]["layer_pages"][1].as_u64().unwrap();
    assert_eq!(punctual_pages > 0, punctual, "{punctual_pages} punctual pages in the page");
    let (left, right) = (v3(&eyes[0]["position"]), v3(&eyes[1]["position"]));
    let forward = v3(&eyes[0]["forward"]);
    let centre: [f32; 3] = [0, 1, 2].map(|i| 0.5 * (left[i] + right[i]));
    let dist = ((0..3).map(|i| (right[i] - left[i]).powi(2)).sum::<f32>()).sqrt();
    assert!((dist - ipd).abs() < 1e-4, "eyes {dist} m apart");
    let target: [f32; 3] = [0, 1, 2].map(|i| centre[i] + forward[i]);
    let camera = format!("{},{},{},{},{},{}", centre[0], centre[1], centre[2], target[0], target[1], target[2]);
    let x = xvfb();
    let shot = dir.path().join("view.png");
    let mut cmd = livebake();
    cmd.env("DISPLAY", &x.display)
        .arg("-q")
        .arg("view")
        .arg(scene)
        .args(FROZEN)
        .args(lights)
        .args(["--backend", "cpu", "--no-watch", "--stereo", "--ipd", &ipd.to_string(), "--camera", &camera])
        .args(["--size", &format!("{}x{h}", 2 * w)])
        .arg("--screenshot")
        .arg(&shot);
    let (code, stderr) = run_bounded(&mut cmd, 300);
    assert_eq!(code, Some(0), "{stderr}");
    let view = image::open(&shot).unwrap().to_rgba8();
    assert_eq!(view.dimensions(), (2 * w, h));
    for (i, eye) in eyes.iter().enumerate() {
        assert_eq!((eye["width"].as_u64(), eye["height"].as_u64()), (Some(w as u64), Some(h as u64)));
        let raw = std::fs::read(eye["file"].as_str().unwrap()).unwrap();
        let (mut over, mut sum, mut lit) = (0usize, 0f64, 0usize);
        for y in 0..h {
            for x in 0..w {
                // readPixels rows run bottom up.
                let p = &raw[(((h - 1 - y) * w + x) * 4) as usize..][..3];
                let q = view.get_pixel(i as u32 * w + x, y).0;
                let d = (0..3).map(|c| p[c].abs_diff(q[c])).max().unwrap();
                over += (d > 4) as usize;
                sum += d as f64;
                lit += (p.iter().map(|&v| v as u32).sum::<u32>() > 150) as usize;
            }
        }
        let n = (w * h) as f64;
        let (frac, mean) = (over as f64 / n, sum / n);
        eprintln!(
            "eye {i}: {:.2}% of pixels differ by more than 4 levels, mean difference {mean:.3}, {lit} lit pixels",
            100.0 * frac
        );
        assert!(lit as f64 > 0.2 * n, "eye {i}: the room is not in view ({lit} lit pixels)");
        assert!(frac <= 0.01, "eye {i}: {:.2}% of pixels differ by more than 4 levels", 100.0 * frac);
        assert!(mean <= 0.5, "eye {i}: mean difference {mean:.3} levels");
    }
}

/// The controllers in the emulated headset: the thumbstick turns the view 30° to the right
/// about the head (which stays where it is); the trigger, aimed at the floor, moves the head
/// over the floor to where the ray meets it (its height kept).
#[test]
fn snap_turn_and_teleport_on_the_emulated_controllers() {
    let served = Served::start(&cornell_path(), &[&FROZEN[..], &["--no-watch"]].concat());
    served.wait_first_light();
    let dir = tempfile::tempdir().unwrap();
    let result = drive(
        json!({"url": served.url, "eye_size": [96, 72], "frames": 2, "steps": ["snap_turn", "teleport"]}),
        dir.path(),
    );
    let centre = |views: &Value| -> [f32; 3] {
        let (a, b) = (v3(&views[0]["position"]), v3(&views[1]["position"]));
        [0, 1, 2].map(|i| 0.5 * (a[i] + b[i]))
    };
    let turn = step(&result, "snap_turn");
    assert_eq!(turn["snap_turns"], 1, "{turn}");
    let (f0, f1) = (v3(&turn["before"][0]["forward"]), v3(&turn["after"][0]["forward"]));
    let yaw = |f: [f32; 3]| f[0].atan2(-f[2]);
    let turned = (yaw(f1) - yaw(f0)).to_degrees();
    assert!((turned - 30.0).abs() < 0.01, "turned {turned}°: {turn}");
    let (h0, h1) = (centre(&turn["before"]), centre(&turn["after"]));
    assert!((0..3).all(|i| (h0[i] - h1[i]).abs() < 1e-4), "the head moved in a snap turn: {h0:?} → {h1:?}");
    let tele = step(&result, "teleport");
    assert_eq!(tele["teleports"], 1, "{tele}");
    let (t0, t1) = (centre(&tele["before"]), centre(&tele["after"]));
    let moved = ((t1[0] - t0[0]).powi(2) + (t1[2] - t0[2]).powi(2)).sqrt();
    eprintln!("teleported {moved:.2} m");
    assert!(moved > 0.5, "the teleport moved the head {moved} m: {tele}");
    assert!((t1[1] - t0[1]).abs() < 1e-4, "the head's height changed: {t0:?} → {t1:?}");
}

/// A copy of the Cornell room in a fresh folder (hot reload edits it).
fn cornell_copy(dir: &Path) -> PathBuf {
    let path = dir.join("cornell_2m.gltf");
    std::fs::copy(cornell_path(), &path).unwrap();
    path
}

/// The live session in the emulated headset: cells published after the page joined reach
/// its texture as partial updates; the headset's pose moves the runtime's camera; a hot
/// reload replaces the page's scene; a second client that sends garbage and a third that
/// drops its connection change nothing for the page.
#[test]
fn live_updates_head_pose_and_hot_reload_reach_the_page() {
    let dir = tempfile::tempdir().unwrap();
    let scene = cornell_copy(dir.path());
    // Refinement long enough (20 s and more) for the steps to see it going on.
    let served = Served::start(&scene, &["--texel-size", "0.05", "--samples", "128", "--lods", "4"]);
    let status = served.wait_first_light();
    let yfov = status["start"]["yfov"].as_f64().unwrap();
    // The reload: the room's lamp dimmed to a third, saved.
    let text = std::fs::read_to_string(&scene).unwrap();
    let mut doc: Value = serde_json::from_str(&text).unwrap();
    let mut edited = false;
    for m in doc["materials"].as_array_mut().unwrap() {
        if let Some(e) = m.get_mut("emissiveFactor")
            && e.as_array().unwrap().iter().any(|v| v.as_f64().unwrap() > 0.0)
        {
            *e = json!(e.as_array().unwrap().iter().map(|v| v.as_f64().unwrap() / 3.0).collect::<Vec<_>>());
            edited = true;
        }
    }
    assert!(edited, "the room has an emissive material");
    let result = drive(
        json!({
            "url": served.url, "fovy": yfov, "eye_size": [320, 240], "frames": 2,
            "steps": ["wait_updates", "move_head", "garbage_clients", "wait_updates", "edit", "wait_scene:2", "status"],
            "edit": {"path": scene, "content": doc.to_string()},
        }),
        dir.path(),
    );
    // Incremental updates after the whole map: pages of single publishes, not the map.
    let w = step(&result, "wait_updates");
    let (before, after) = (&w["before"], &w["after"]);
    assert!(after["updates"].as_u64() > before["updates"].as_u64(), "{w}");
    assert!(after["pages"].as_u64() > before["pages"].as_u64(), "{w}");
    assert_eq!(after["full"], 1, "one whole map (on joining) before the reload: {w}");
    // The head moved 1 m along x in the tracking space; the page sent it, the runtime's
    // camera took it.
    let m = step(&result, "move_head");
    let (b, a) = (v3(&m["before"]["eye"]), v3(&m["after"]["eye"]));
    assert!((a[0] - b[0] - 1.0).abs() < 1e-3 && (a[1] - b[1]).abs() < 1e-3, "{m}");
    assert_eq!(v3(&m["server_pose"][0]), a, "the runtime's camera: {m}");
    // Garbage and a dropped client did not disturb the page: it kept its connection and
    // took updates after them (the second wait_updates).
    let g = step(&result, "garbage_clients");
    assert_eq!(g["garbage_closed"], true, "{g}");
    let fin = &step(&result, "status")["after"];
    assert_eq!(fin["connected"], true, "{fin}");
    // The reload reached the page: the new scene and its whole map.
    assert_eq!(fin["generation"], 2, "{fin}");
    assert_eq!(fin["scenes"], 2, "{fin}");
    assert!(fin["full"].as_u64() >= Some(2), "{fin}");
    let s = served.status();
    assert!(s["reloads"].as_u64() >= Some(1), "{s}");
}

/// Every update after the first carries exactly what the runtime published: replayed on a
/// mirror of the first (whole) map, they give the runtime's shown map page for page, bit
/// for bit (read after the runtime is paused, so nothing is in flight); and each is the
/// published pages plus its small header, never the whole map.
#[test]
fn updates_carry_exactly_the_published_pages() {
    let (stats, _) = replay_updates(&[Duration::ZERO], livebake::serve::hub::IN_FLIGHT_BYTES);
    eprintln!("{} updates, {} held", stats.updates, stats.updates_held);
}

/// A client slow to acknowledge (a headset on a slow link) is not sent every publish: with
/// a budget of one byte in flight, changes wait while it holds an unacknowledged update and
/// then go as one update against what it has. Replayed, they still give the runtime's shown
/// map bit for bit, and the server never had more than one of them out.
#[test]
fn a_client_slow_to_acknowledge_gets_the_changes_merged_and_still_the_whole_map() {
    // A second an update: the runtime below publishes several times a second (one thread,
    // the Cornell box's cells at 64 directions; 7 of the 8 updates waited when this was
    // written), so some must wait even on a slower machine. Below the hub's 2 s after which
    // an unacknowledged update stops counting, with room for a loaded one.
    let (stats, _) = replay_updates(&[Duration::from_millis(1000)], 1);
    eprintln!("{} updates, {} held", stats.updates, stats.updates_held);
    assert!(stats.updates_held > 0, "no update waited for the slow client: {stats:?}");
}

/// Flow control is per client: beside the slow client above, a prompt one (acknowledging
/// within ~0.1 s, the short read after each update) is not held back to its pace. Both end
/// with the runtime's shown map.
#[test]
fn a_slow_client_does_not_hold_back_a_prompt_one() {
    let (stats, counts) = replay_updates(&[Duration::ZERO, Duration::from_millis(1000)], 1);
    eprintln!("{} updates, {} held; per client {counts:?}", stats.updates, stats.updates_held);
    assert!(counts[0] > counts[1], "the prompt client got no more updates than the slow one: {counts:?}");
}

/// Runs a runtime on the Cornell box with a server (`in_flight_bytes`) and a raw client per
/// entry of `ack_delays`, each acknowledging each update that long after reading it, as the
/// page does once it uploaded it; pauses the runtime after 8 updates a client and checks
/// each client's replayed mirror against the shown map. A budget under one update's size
/// lets one out at a time. Returns the server's figures and each client's update count.
fn replay_updates(ack_delays: &[Duration], in_flight_bytes: usize) -> (livebake::serve::ServeStats, Vec<usize>) {
    use livebake::cpu::CpuProvider;
    use livebake::runtime::{Runtime, RuntimeConfig};
    use livebake::serve::{ServeConfig, Server};
    let scene = Arc::new(livebake::scene::load_gltf(&cornell_path(), &Default::default()).unwrap());
    // First light at every direction: no later re-publish of the whole of LOD 0 (which
    // legitimately rewrites every LOD-0 page); what follows are cell publishes.
    let config = RuntimeConfig {
        lods: Some(3),
        threads: Some(1),
        first_light_directions: 64,
        bundle: livebake::bundle::BundleConfig { seed: 3, directions: 64, ..RuntimeConfig::default().bundle },
        ..RuntimeConfig::default()
    };
    let runtime = Runtime::start(scene, config, Arc::new(CpuProvider::new())).unwrap();
    let server = Server::bind(
        &cornell_path(),
        ServeConfig {
            addr: "127.0.0.1:0".parse().unwrap(),
            token: None,
            exposure: Some(1.0),
            pose: None,
            in_flight_bytes,
        },
    )
    .unwrap();
    let addr = server.local_addr().to_string();
    // A client reads until the server lets it go (everything queued is delivered first).
    let client = |ack_delay: Duration| {
        let addr = addr.clone();
        std::thread::spawn(move || {
            let stream = TcpStream::connect(&addr).unwrap();
            stream.set_read_timeout(Some(Duration::from_secs(120))).unwrap();
            let (mut ws, _) = tungstenite::client(format!("ws://{addr}/socket"), stream).unwrap();
            let (scene, first) = read_welcome(&mut ws);
            assert!(first.full);
            let mut updates = vec![first];
            // Updates read and not yet acknowledged: one at most under a budget below an
            // update's size, if the server holds the rest (after the delay, a short read takes
            // whatever the server sent meanwhile).
            let mut most_unacknowledged = 0;
            let mut unacknowledged: Vec<Update> = Vec::new();
            loop {
                let timeout = if unacknowledged.is_empty() { 120_000 } else { 100 };
                ws.get_ref().set_read_timeout(Some(Duration::from_millis(timeout))).unwrap();
                match ws.read() {
                    Ok(Message::Binary(b)) if b[0] == 3 => {
                        unacknowledged.push(decode_update(&b).expect("a well-formed update"));
                        most_unacknowledged = most_unacknowledged.max(unacknowledged.len());
                        if unacknowledged.len() == 1 {
                            std::thread::sleep(ack_delay);
                        }
                    }
                    Ok(_) => {}
                    Err(tungstenite::Error::Io(e))
                        if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) =>
                    {
                        for u in unacknowledged.drain(..) {
                            let _ = ws.send(Message::binary(encode_ack(u.seq, AckStage::Uploaded, 0.0)));
                            updates.push(u);
                        }
                    }
                    Err(_) => break,
                }
            }
            updates.append(&mut unacknowledged);
            (scene, updates, most_unacknowledged)
        })
    };
    let clients: Vec<_> = ack_delays.iter().map(|&d| (d, client(d))).collect();
    let mut paused_at: Option<Instant> = None;
    let mut last_shown: Option<Arc<ShownLightmap>> = None;
    let stats = server
        .run(&runtime, |s| {
            if s.updates >= 8 * clients.len() as u64 && paused_at.is_none() {
                runtime.set_paused(true);
                paused_at = Some(Instant::now());
            }
            // Paused long enough for a bake in flight to have been published (and broadcast:
            // the hub publishes before it asks whether to stop).
            if paused_at.is_some_and(|t| t.elapsed() > Duration::from_secs(3)) {
                last_shown = Some(runtime.shown());
                return true;
            }
            false
        })
        .unwrap();
    let shown = last_shown.unwrap();
    runtime.shutdown().unwrap();
    let mut counts = Vec::new();
    for (ack_delay, client) in clients {
        let (scene, updates, most_unacknowledged) = client.join().unwrap();
        // Every update is at least its header: a budget below it lets one out at a time.
        if in_flight_bytes < UPDATE_HEADER {
            assert!(most_unacknowledged <= 1, "{most_unacknowledged} updates out at once");
        }
        check_replay(&scene, &updates, ack_delay, &shown);
        counts.push(updates.len() - 1);
    }
    assert_eq!(counts.iter().sum::<usize>() as u64, stats.updates, "every update sent reached its client");
    assert!(stats.update_bytes > stats.update_page_bytes);
    (stats, counts)
}

/// Replays a client's `updates` (the first the whole map) on a mirror and checks it against
/// `shown`, page for page and cell LOD for cell LOD; a prompt client's (`ack_delay` zero)
/// updates are single publishes, never as large as the whole map.
fn check_replay(scene: &Value, updates: &[Update], ack_delay: Duration, shown: &ShownLightmap) {
    assert_eq!(scene["type"], "scene");
    assert_eq!(scene["lods"], 3);
    // The mirror: page key → texels.
    let mut mirror = std::collections::HashMap::new();
    let mut cells = [vec![0u8; shown.grid.len()], vec![0u8; shown.grid.len()]];
    for (i, u) in updates.iter().enumerate() {
        assert_eq!(u.full, i == 0);
        if i > 0 {
            let bytes = UPDATE_HEADER
                + u.cells.len() * CELL_ENTRY
                + u.pages.len() * (PAGE_ENTRY_HEADER + Page::BYTES)
                + u.dropped.len() * PAGE_ENTRY_HEADER;
            assert!(!u.pages.is_empty() || !u.cells.is_empty() || !u.dropped.is_empty(), "an empty update");
            // A prompt client's update is one publish's pages, fewer than the first light's
            // whole map; a merged one may hold several publishes' (finer LODs' pages
            // included), but each page once.
            if ack_delay.is_zero() {
                assert!(
                    u.pages.len() < updates[0].pages.len(),
                    "update {i} carries {} pages: the whole map?",
                    u.pages.len()
                );
            }
            let keys: std::collections::HashSet<_> = u.pages.iter().map(|(k, _)| *k).collect();
            assert_eq!(keys.len(), u.pages.len(), "update {i} carries a page twice");
            eprintln!("update {i}: {} pages, {} cell LODs, {bytes} bytes", u.pages.len(), u.cells.len());
        }
        for (k, t) in &u.pages {
            mirror.insert(*k, t.clone());
        }
        for k in &u.dropped {
            mirror.remove(k);
        }
        for c in &u.cells {
            cells[c.layer as usize][c.cell as usize] = c.lod;
        }
    }
    let mut live = 0;
    for layer in Layer::ALL {
        for (k, level) in shown.layer(layer).levels.iter().enumerate() {
            for py in 0..level.pages_y {
                for px in 0..level.pages_x {
                    if let Some(p) = level.page(px, py) {
                        live += 1;
                        let got = mirror.get(&(layer as u8, k as u8, px, py)).expect("a live page the client lacks");
                        assert_eq!(got.as_slice(), &p.texels[..], "page {layer:?} {k} ({px}, {py})");
                    }
                }
            }
        }
        assert_eq!(&cells[layer as usize][..], &shown.layer(layer).cell_lod[..]);
    }
    assert_eq!(live, mirror.len(), "pages the runtime freed are gone from the mirror too");
}

/// A page opened over plain http from a LAN address (not localhost) is not cross-origin
/// isolated, so it has no shared memory: its socket's worker posts each message to it
/// instead (web/livebake.js). It still gets the whole map, then updates, and acknowledges
/// them once the GPU has them. The LAN address is a name Chromium resolves to 127.0.0.1
/// (`lan_host` in the driver), so the test needs no network; the server runs with `--host`,
/// so the page also carries the token (URL, then cookie and socket) as on a LAN.
#[test]
fn over_plain_http_from_a_lan_address_the_page_works_without_shared_memory() {
    let served = Served::start(
        &cornell_path(),
        &["--host", "127.0.0.1", "--no-watch", "--texel-size", "0.05", "--samples", "128", "--lods", "4"],
    );
    assert!(served.token().is_some(), "--host prints a URL with a token");
    served.wait_first_light();
    let url = served.url.replacen("127.0.0.1", "lan.test", 1);
    let dir = tempfile::tempdir().unwrap();
    let result = drive(
        json!({"url": url, "lan_host": "lan.test", "no_vr": true, "eye_size": [320, 240], "steps": ["wait_updates", "status"]}),
        dir.path(),
    );
    let w = step(&result, "wait_updates");
    assert!(w["after"]["updates"].as_u64() > w["before"]["updates"].as_u64(), "{w}");
    let fin = &step(&result, "status")["after"];
    assert_eq!(fin["shared_ring"], false, "the page had shared memory: not the fallback: {fin}");
    assert_eq!(fin["full"], 1, "{fin}");
    assert_eq!(fin["connected"], true, "{fin}");
    assert!(fin["fenced"].as_u64() >= Some(1), "no update acknowledged as in the texture: {fin}");
}

/// With --host every request needs the token (page, files, status, socket); the scene's
/// folder is all that is served of the disk, and only its own files.
#[test]
fn without_the_token_or_outside_the_scene_requests_are_refused() {
    let served = Served::start(&cornell_path(), &["--host", "127.0.0.1", "--no-watch", "--texel-size", "0.1"]);
    let token = served.token().expect("--host prints a URL with a token");
    assert_eq!(token.len(), 32);
    let addr = served.addr();
    let q = format!("?token={token}");
    // The token with its first character changed (to '1' when it already was '0': a token
    // starting with '0', 1 in 16, made this the token itself).
    let wrong = format!("{}{}", if token.starts_with('0') { '1' } else { '0' }, &token[1..]);
    assert_ne!(wrong, token);
    for path in ["/", "/livebake.js", "/shaders.js", "/status.json", "/scene/cornell_2m.gltf"] {
        assert_eq!(http_get(&addr, path, "").0, 403, "{path} without the token");
        assert_eq!(http_get(&addr, &format!("{path}?token={wrong}"), "").0, 403, "{path} with a wrong token");
        assert_eq!(http_get(&addr, &format!("{path}{q}"), "").0, 200, "{path} with the token");
        let cookie = format!("Cookie: livebake_token={token}\r\n");
        assert_eq!(http_get(&addr, path, &cookie).0, 200, "{path} with the cookie");
    }
    // The socket too.
    let stream = TcpStream::connect(&addr).unwrap();
    assert!(tungstenite::client(format!("ws://{addr}/socket"), stream).is_err(), "a socket without the token");
    // Outside the folder, or in it but not the scene's.
    for (path, want) in [
        ("/scene/../serve.rs", 403),
        ("/scene/%2e%2e/%2e%2e/Cargo.toml", 403),
        ("/scene//etc/passwd", 403),
        ("/scene/mitsuba_reference.json", 404),
        ("/scene/points.json", 404),
        ("/../Cargo.toml", 404),
        ("/etc/passwd", 404),
        ("/scene/", 403),
    ] {
        assert_eq!(http_get(&addr, &format!("{path}{q}"), "").0, want, "{path}");
    }
    let (_, page) = http_get(&addr, &format!("/{q}"), "");
    assert!(String::from_utf8_lossy(&page).contains("livebake.js"));
}

/// A socket that sends garbage is closed; the others go on (plain clients, no browser).
#[test]
fn a_malformed_message_closes_that_client_only() {
    let served = Served::start(&cornell_path(), &["--no-watch", "--texel-size", "0.1", "--lods", "3"]);
    served.wait_first_light();
    let mut first = served.socket();
    read_welcome(&mut first);
    let mut bad = served.socket();
    read_welcome(&mut bad);
    bad.send(Message::Binary(vec![42u8, 1, 2, 3].into())).unwrap();
    let closed = (0..1000).any(|_| match bad.read() {
        Ok(Message::Close(_)) | Err(_) => true,
        Ok(_) => false,
    });
    assert!(closed, "the garbage sender was not closed");
    let mut text = served.socket();
    read_welcome(&mut text);
    text.send(Message::text("hello")).unwrap();
    drop(text);
    // A client that vanishes without a close.
    drop(served.socket());
    // The first client still talks: its pose reaches the runtime.
    let pose = livebake::serve::protocol::Pose {
        eye: glam::Vec3::new(0.5, 1.0, 1.5),
        target: glam::Vec3::new(0.5, 1.0, 0.0),
        yfov: 1.0,
        aspect: 1.0,
        height_px: 100,
    };
    first.send(Message::Binary(encode_pose(&pose).into())).unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        // (Reading keeps its queue flowing.)
        first.get_mut().set_read_timeout(Some(Duration::from_millis(50))).unwrap();
        let _ = first.read();
        // The others' threads notice their ends on their own time: wait for both facts.
        let s = served.status();
        if s["last_pose"][0] == json!([0.5, 1.0, 1.5]) && s["clients_now"] == 1 {
            break;
        }
        assert!(Instant::now() < deadline, "the first client's pose never arrived, or the others stayed: {s}");
    }
}

/// A plain static file server over `dir` (what anyone would put a `--export-web` folder
/// behind); records each request's path and status.
/// Requests a test file server saw: path and status.
type RequestLog = Arc<std::sync::Mutex<Vec<(String, u16)>>>;

fn static_server(dir: PathBuf) -> (String, RequestLog) {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let log = Arc::new(std::sync::Mutex::new(Vec::new()));
    let seen = log.clone();
    std::thread::spawn(move || {
        for stream in listener.incoming() {
            let Ok(mut s) = stream else { continue };
            let mut head = Vec::new();
            let mut b = [0u8; 1];
            while !head.ends_with(b"\r\n\r\n") && s.read(&mut b).is_ok_and(|n| n == 1) {
                head.push(b[0]);
            }
            let line = String::from_utf8_lossy(&head).lines().next().unwrap_or("").to_string();
            let target = line.split_whitespace().nth(1).unwrap_or("/").to_string();
            let path = target.split('?').next().unwrap().trim_start_matches('/').to_string();
            let file = dir.join(&path);
            let body = (!path.contains("..") && !path.is_empty()).then(|| std::fs::read(&file).ok()).flatten();
            let code = if body.is_some() { 200 } else { 404 };
            seen.lock().unwrap().push((path.clone(), code));
            let ty = match file.extension().and_then(|e| e.to_str()) {
                Some("html") => "text/html",
                Some("js") => "text/javascript",
                Some("json") => "application/json",
                _ => "application/octet-stream",
            };
            let body = body.unwrap_or_default();
            let _ = write!(
                s,
                "HTTP/1.1 {code} X\r\nContent-Type: {ty}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
                body.len()
            );
            let _ = s.write_all(&body);
        }
    });
    (addr, log)
}

/// `bake --export-web DIR` is self-contained: a plain file server over DIR alone, and the
/// page in Chromium draws the lit room (not black) from DIR's files and nothing else.
#[test]
fn the_web_export_is_a_static_self_contained_page() {
    let dir = tempfile::tempdir().unwrap();
    let web = dir.path().join("web");
    let mut cmd = livebake();
    cmd.arg("-q")
        .arg("bake")
        .arg(cornell_path())
        .args(["--texel-size", "0.05", "--samples", "64", "--backend", "cpu", "--out"])
        .arg(dir.path().join("out"))
        .arg("--export-web")
        .arg(&web);
    let (code, stderr) = run_bounded(&mut cmd, 300);
    assert_eq!(code, Some(0), "{stderr}");
    for f in [
        "index.html",
        "livebake.js",
        "shaders.js",
        "lightmap.js",
        "scene.json",
        "geometry.bin",
        "lightmap.bin",
        "scene.gltf",
        "scene.bin",
    ] {
        assert!(web.join(f).is_file(), "{f} missing from the export");
    }
    let (addr, log) = static_server(web.clone());
    let out = dir.path().join("driver");
    std::fs::create_dir_all(&out).unwrap();
    let result = drive(
        json!({"url": format!("http://{addr}/index.html?static"), "no_vr": true, "eye_size": [160, 120],
               "steps": ["sleep:500", "mean_pixel"]}),
        &out,
    );
    let mean =
        step(&result, "mean_pixel")["mean"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect::<Vec<_>>();
    let lit = step(&result, "mean_pixel")["lit"].as_f64().unwrap();
    eprintln!("mean page colour {mean:?}, {:.0}% of the pixels lit", 100.0 * lit);
    // The background is (39, 39, 46), a sum of 124; the lit room's walls and floor sum to
    // well over 200 and fill about a sixth of this 320×120 canvas (measured 17 %).
    assert!(lit > 0.1, "the page is (nearly) black: mean {mean:?}, {lit} lit");
    let requests = log.lock().unwrap().clone();
    for (path, code) in &requests {
        assert!(*code == 200 || path == "favicon.ico", "{path}: {code} ({requests:?})");
    }
    assert!(requests.iter().any(|(p, _)| p == "lightmap.bin"), "{requests:?}");
}
