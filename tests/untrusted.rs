//! Scenes from strangers (issue 29): files outside the scene's folder, special files,
//! decompression bombs, light too bright for f32 sums, coordinates whose areas overflow. Each
//! case is a small file made here and goes through the real loader (and, where exit codes
//! and `error:` lines are the point, `tests/cli.rs`'s way of running the command); none may
//! panic or hang.

mod support;

use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::Duration;

use livebake::scene::{LoadError, LoadOptions, Scene, load_gltf};
use serde_json::{Value, json};
use support::{Doc, png};

const TRI: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
const UP_Z: [[f32; 3]; 3] = [[0.0, 0.0, 1.0]; 3];

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

fn write_json(dir: &Path, name: &str, j: &Value) -> PathBuf {
    write(dir, name, &serde_json::to_vec_pretty(j).unwrap())
}

/// Loads on a thread of its own, so that a load that blocks (a FIFO) fails the test instead
/// of hanging it.
fn load_within(path: &Path, options: &LoadOptions, seconds: u64) -> Result<Scene, LoadError> {
    let (tx, rx) = mpsc::channel();
    let (path, options) = (path.to_path_buf(), options.clone());
    std::thread::spawn(move || {
        let _ = tx.send(load_gltf(&path, &options));
    });
    rx.recv_timeout(Duration::from_secs(seconds)).unwrap_or_else(|_| panic!("the load blocked for {seconds} s"))
}

fn load(path: &Path) -> Result<Scene, LoadError> {
    load_within(path, &LoadOptions::default(), 60)
}

fn opted_in() -> LoadOptions {
    LoadOptions { allow_outside_files: true, ..LoadOptions::default() }
}

/// A refusal of `uri`: the message names the file, the object and the URI.
#[track_caller]
fn assert_refused(result: Result<Scene, LoadError>, uri: &str, because: &str) {
    let e = match result {
        Ok(_) => panic!("'{uri}' was read"),
        Err(e) => e,
    };
    let msg = e.to_string();
    assert!(matches!(e, LoadError::FileRefused { .. }), "{msg}");
    assert!(msg.contains(&format!("'{uri}'")) && msg.contains(because), "{msg}");
}

/// One triangle with a base-colour texture whose image has `uri`.
fn textured(uri: &str) -> Doc {
    let mut d = Doc::new();
    let mut p = d.prim(&TRI, Some(&UP_Z), None);
    p["material"] = json!(0);
    d.mesh_node(vec![p], json!({}));
    d.push("images", json!({ "uri": uri }));
    d.push("textures", json!({ "source": 0 }));
    d.push("materials", json!({ "pbrMetallicRoughness": { "baseColorTexture": { "index": 0 } } }));
    d
}

/// `scene.gltf` in `dir` whose buffer 0 is the file `uri` (the buffer's bytes are written to
/// `bin_at`, which may be outside `dir`).
fn buffer_at(dir: &Path, uri: &str, bin_at: &Path) -> PathBuf {
    let mut d = Doc::new();
    let p = d.prim(&TRI, Some(&UP_Z), None);
    d.mesh_node(vec![p], json!({}));
    std::fs::write(bin_at, &d.bin).unwrap();
    write_json(dir, "scene.gltf", &d.json_with_buffer(Some(uri.to_string())))
}

/// `root/scene/` (the scene's folder) and `root/elsewhere/` beside it.
fn two_folders() -> (tempfile::TempDir, PathBuf, PathBuf) {
    let root = tempfile::tempdir().unwrap();
    let scene = root.path().join("scene");
    let elsewhere = root.path().join("elsewhere");
    std::fs::create_dir_all(&scene).unwrap();
    std::fs::create_dir_all(&elsewhere).unwrap();
    (root, scene, elsewhere)
}

// ---------------------------------------------------------------------------------------------
// confinement

#[test]
fn parent_escapes_are_refused_unless_opted_in() {
    let (_root, scene, elsewhere) = two_folders();
    // A texture beside the scene's folder, which would change the light if it were read.
    write(&elsewhere, "x.png", &png(2, 2, |_, _| [255, 0, 0, 255]));
    let path = textured("../elsewhere/x.png").write_gltf(&scene, "tex");
    assert_refused(load(&path), "../elsewhere/x.png", "leads out of the scene's folder");
    let s = load_within(&path, &opted_in(), 60).expect("opted in");
    assert_eq!(s.textures.len(), 1);
    assert_eq!(s.textures[0].rgba8[0], [255, 0, 0, 255]);

    // A buffer the same way, and with the dots percent-encoded.
    std::fs::create_dir_all(scene.join("sub")).unwrap();
    for uri in ["../elsewhere/b.bin", "%2E%2E/elsewhere/b.bin", "sub/../../elsewhere/b.bin"] {
        let path = buffer_at(&scene, uri, &elsewhere.join("b.bin"));
        assert_refused(load(&path), uri, "leads out of the scene's folder");
        assert!(load_within(&path, &opted_in(), 60).is_ok(), "{uri} opted in");
    }
    // `..` that stays inside is fine.
    let path = buffer_at(&scene, "sub/../b.bin", &scene.join("b.bin"));
    load(&path).expect("sub/../b.bin stays in the folder");
}

#[test]
fn absolute_paths_are_refused_unless_opted_in() {
    let (_root, scene, elsewhere) = two_folders();
    let png_path = write(&elsewhere, "x.png", &png(2, 2, |_, _| [0, 255, 0, 255]));
    let uri = png_path.display().to_string();
    let path = textured(&uri).write_gltf(&scene, "abs");
    assert_refused(load(&path), &uri, "is an absolute path");
    assert_eq!(load_within(&path, &opted_in(), 60).expect("opted in").textures[0].rgba8[0], [0, 255, 0, 255]);
    // Even a file inside the folder is refused by an absolute path: glTF URIs are relative.
    let inside = write(&scene, "in.png", &png(1, 1, |_, _| [1, 2, 3, 255])).display().to_string();
    assert_refused(load(&textured(&inside).write_gltf(&scene, "abs_in")), &inside, "is an absolute path");
    // The buffer of a scene given as /etc/passwd is refused before it is read.
    let path = buffer_at(&scene, "/etc/passwd", &scene.join("unused.bin"));
    assert_refused(load(&path), "/etc/passwd", "is an absolute path");
}

#[cfg(unix)]
#[test]
fn symbolic_links_out_of_the_folder_are_refused() {
    use std::os::unix::fs::symlink;
    let (_root, scene, elsewhere) = two_folders();
    write(&elsewhere, "x.png", &png(2, 2, |_, _| [255, 0, 0, 255]));
    symlink(elsewhere.join("x.png"), scene.join("link.png")).unwrap();
    let path = textured("link.png").write_gltf(&scene, "link");
    assert_refused(load(&path), "link.png", "is a symbolic link to");
    assert!(load_within(&path, &opted_in(), 60).is_ok());
    // A directory link on the way out is followed too.
    symlink(&elsewhere, scene.join("dir")).unwrap();
    let path = textured("dir/x.png").write_gltf(&scene, "dirlink");
    assert_refused(load(&path), "dir/x.png", "outside the scene's folder");
    // A buffer behind a link.
    let path = buffer_at(&scene, "b_link.bin", &elsewhere.join("b.bin"));
    symlink(elsewhere.join("b.bin"), scene.join("b_link.bin")).unwrap();
    assert_refused(load(&path), "b_link.bin", "is a symbolic link to");
    // A link that stays inside is fine.
    write(&scene, "real.png", &png(1, 1, |_, _| [9, 9, 9, 255]));
    symlink(scene.join("real.png"), scene.join("alias.png")).unwrap();
    let s = load(&textured("alias.png").write_gltf(&scene, "alias")).expect("a link inside the folder");
    assert_eq!(s.textures[0].rgba8[0], [9, 9, 9, 255]);
}

#[cfg(unix)]
#[test]
fn fifos_and_devices_are_refused_without_blocking() {
    let (_root, scene, _) = two_folders();
    let fifo = scene.join("pipe.png");
    let c = std::ffi::CString::new(fifo.display().to_string()).unwrap();
    // SAFETY: a valid NUL-terminated path; mkfifo only creates a file.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0, "mkfifo");
    // A FIFO with no writer: opening it for reading would block forever.
    let path = textured("pipe.png").write_gltf(&scene, "fifo");
    assert_refused(load_within(&path, &LoadOptions::default(), 20), "pipe.png", "not a regular file but a FIFO");
    let path = buffer_at(&scene, "pipe.bin", &scene.join("unused.bin"));
    std::fs::rename(&fifo, scene.join("pipe.bin")).unwrap();
    assert_refused(load_within(&path, &LoadOptions::default(), 20), "pipe.bin", "a FIFO");
    // /dev/zero never ends: refused as a device, even where files outside are allowed.
    let path = textured("/dev/zero").write_gltf(&scene, "zero");
    assert_refused(load_within(&path, &opted_in(), 20), "/dev/zero", "not a regular file but a character device");
    let path = buffer_at(&scene, "/dev/zero", &scene.join("unused.bin"));
    assert_refused(load_within(&path, &opted_in(), 20), "/dev/zero", "a character device");
    // A scene file that is a FIFO is refused too.
    let c = std::ffi::CString::new(scene.join("scene_pipe.gltf").display().to_string()).unwrap();
    // SAFETY: as above.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0, "mkfifo");
    let e = load_within(&scene.join("scene_pipe.gltf"), &LoadOptions::default(), 20).expect_err("a FIFO scene");
    assert!(e.to_string().contains("not a regular file"), "{e}");
}

#[test]
fn the_hot_reload_list_refuses_what_the_loader_refuses() {
    let (_root, scene, elsewhere) = two_folders();
    write(&elsewhere, "x.png", &png(1, 1, |_, _| [0; 4]));
    let path = textured("../elsewhere/x.png").write_gltf(&scene, "watched");
    let bytes = std::fs::read(&path).unwrap();
    let e = livebake::scene::external_files(&path, &bytes, &LoadOptions::default()).expect_err("outside");
    assert!(matches!(e, LoadError::FileRefused { .. }), "{e}");
    let listed = livebake::scene::external_files(&path, &bytes, &opted_in()).expect("opted in");
    assert!(listed.iter().any(|f| f.uri == "../elsewhere/x.png"));
}

/// The watcher asks the loader's rule: a save that names a file outside fails, the next good
/// one loads; a watcher whose loads are opted in follows the file outside.
#[test]
fn hot_reload_refuses_a_save_that_reaches_outside() {
    use livebake::watch::{SceneWatcher, WatchConfig, WatchEvent};
    let (_root, scene, elsewhere) = two_folders();
    write(&elsewhere, "x.png", &png(1, 1, |_, _| [255, 0, 0, 255]));
    write(&scene, "in.png", &png(1, 1, |_, _| [0, 0, 255, 255]));
    let gltf = textured("in.png").write_gltf(&scene, "scene");
    let outcome = |allow_outside_files: bool| {
        let load = LoadOptions { allow_outside_files, ..LoadOptions::default() };
        let watcher = SceneWatcher::start(&gltf, WatchConfig { load, ..WatchConfig::default() }).unwrap();
        std::thread::sleep(Duration::from_millis(300));
        textured("../elsewhere/x.png").write_gltf(&scene, "scene");
        let outcome = loop {
            match watcher.events().recv_timeout(Duration::from_secs(30)).expect("a report from the watcher") {
                WatchEvent::Started { .. } => continue,
                e => break e,
            }
        };
        textured("in.png").write_gltf(&scene, "scene");
        std::thread::sleep(Duration::from_millis(300));
        outcome
    };
    match outcome(false) {
        WatchEvent::Failed { error, .. } => {
            assert!(error.contains("'../elsewhere/x.png'") && error.contains("leads out"), "{error}")
        }
        WatchEvent::Loaded { .. } => panic!("the save reaching outside loaded"),
        WatchEvent::Started { .. } => unreachable!(),
    }
    match outcome(true) {
        WatchEvent::Loaded { scene, .. } => assert_eq!(scene.textures[0].rgba8[0], [255, 0, 0, 255]),
        WatchEvent::Failed { error, .. } => panic!("opted in, the save failed: {error}"),
        WatchEvent::Started { .. } => unreachable!(),
    }
}

// ---------------------------------------------------------------------------------------------
// decompression bombs

#[test]
fn a_png_bomb_is_refused_from_its_header() {
    let dir = tempfile::tempdir().unwrap();
    // 16384² one-bit pixels: ~200 kB of PNG, 1 GiB of RGBA8 once decoded.
    let bomb = support::png_bomb(16384, 16384);
    assert!(bomb.len() < 400_000, "{} bytes", bomb.len());
    write(dir.path(), "bomb.png", &bomb);
    let path = textured("bomb.png").write_gltf(dir.path(), "bomb");
    let started = std::time::Instant::now();
    match load(&path) {
        Err(LoadError::TextureTooLarge { image, width, height, limit, .. }) => {
            assert_eq!((width, height, limit), (16384, 16384, 4096 * 4096));
            assert!(image.contains("bomb.png"), "{image}");
        }
        other => panic!("expected TextureTooLarge, got {:?}", other.map(|_| ())),
    }
    // Refused from the header, not after decoding a gigabyte (which takes seconds).
    assert!(started.elapsed() < Duration::from_secs(2), "{:?}", started.elapsed());
    let msg = load(&path).err().map(|e| e.to_string()).unwrap_or_default();
    assert!(msg.contains("--max-texture-pixels") && msg.contains("16384×16384"), "{msg}");

    // Within a raised pixel limit, the textures' memory limit still holds it back.
    let raised =
        LoadOptions { max_texture_pixels: 1 << 28, texture_memory_limit: Some(256 << 20), ..LoadOptions::default() };
    match load_within(&path, &raised, 60) {
        Err(LoadError::TexturesOverMemory { need, limit, .. }) => assert!(need > limit && limit == 256 << 20),
        other => panic!("expected TexturesOverMemory, got {:?}", other.map(|_| ())),
    }
}

#[test]
fn textures_of_one_image_share_its_pixels() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "x.png", &png(64, 64, |x, y| [x as u8, y as u8, 0, 255]));
    let mut d = Doc::new();
    let mut prims = Vec::new();
    for m in 0..3 {
        let mut p = d.prim(&TRI, Some(&UP_Z), None);
        p["material"] = json!(m);
        prims.push(p);
        d.push("textures", json!({ "source": 0, "sampler": m }));
        d.push("samplers", json!({ "wrapS": 33071 }));
        d.push("materials", json!({ "pbrMetallicRoughness": { "baseColorTexture": { "index": m } } }));
    }
    d.mesh_node(prims, json!({}));
    d.push("images", json!({ "uri": "x.png" }));
    let s = load(&d.write_gltf(dir.path(), "shared")).unwrap();
    assert_eq!(s.textures.len(), 3);
    assert!(s.textures.windows(2).all(|t| std::sync::Arc::ptr_eq(&t[0].rgba8, &t[1].rgba8)));
    // A limit that holds the image once holds the three textures.
    let once = LoadOptions { texture_memory_limit: Some(64 * 64 * 12 + 64 * 64 * 4), ..LoadOptions::default() };
    load_within(&dir.path().join("shared.gltf"), &once, 60).expect("one decode");
}

// ---------------------------------------------------------------------------------------------
// light and geometry beyond f32

fn lit_doc(light: Value) -> Doc {
    let mut d = Doc::new();
    let p = d.prim(&TRI, Some(&UP_Z), None);
    d.mesh_node(vec![p], json!({}));
    d.json["extensionsUsed"] = json!(["KHR_lights_punctual"]);
    d.json["extensions"] = json!({ "KHR_lights_punctual": { "lights": [light] } });
    let n = d.push(
        "nodes",
        json!({ "translation": [0.2, 0.2, 1.0], "extensions": { "KHR_lights_punctual": { "light": 0 } } }),
    );
    d.add_root(n);
    d
}

#[test]
fn lights_too_bright_for_f32_sums_are_refused_with_their_value() {
    let dir = tempfile::tempdir().unwrap();
    let path = lit_doc(json!({ "type": "point", "name": "lamp", "intensity": 1e38 })).write_gltf(dir.path(), "bright");
    let e = load(&path).expect_err("a point light of 1e38 W/sr");
    let msg = e.to_string();
    assert!(matches!(e, LoadError::Invalid { .. }), "{msg}");
    assert!(msg.contains("light 0 'lamp'") && msg.contains("1e38") && msg.contains("W/sr"), "{msg}");
    // The scene's ceiling is what decides: half a square metre of surface allows a lamp of
    // 8.8e10 W/sr (radiometry.rs), a real lamp far below it.
    let ceiling = livebake::scene::radiometry::LightCeiling::for_area(0.5).light_intensity(false, 1);
    for (intensity, loads) in [(1000.0, true), (ceiling * 0.99, true), (ceiling * 1.01, false)] {
        let path = lit_doc(json!({ "type": "point", "intensity": intensity })).write_gltf(dir.path(), "lamp");
        assert_eq!(load(&path).is_ok(), loads, "intensity {intensity:e} (ceiling {ceiling:e})");
    }
    let sun = lit_doc(json!({ "type": "directional", "intensity": 3e37 })).write_gltf(dir.path(), "sun");
    assert!(load(&sun).err().is_some_and(|e| e.to_string().contains("W/m²")));

    // Emission the same way, with the material named.
    let mut d = Doc::new();
    let mut p = d.prim(&TRI, Some(&UP_Z), None);
    p["material"] = json!(0);
    d.mesh_node(vec![p], json!({}));
    d.push(
        "materials",
        json!({ "name": "glow", "emissiveFactor": [1.0, 1.0, 1.0],
        "extensions": { "KHR_materials_emissive_strength": { "emissiveStrength": 1e30 } } }),
    );
    d.json["extensionsUsed"] = json!(["KHR_materials_emissive_strength"]);
    let e = load(&d.write_gltf(dir.path(), "glow")).expect_err("emission of 1e30");
    assert!(e.to_string().contains("'glow'") && e.to_string().contains("1e30"), "{e}");
}

#[test]
fn base_colours_outside_zero_one_are_clamped_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let mut d = Doc::new();
    let mut prims = Vec::new();
    for (m, (name, c)) in [("hot", 5.0), ("negative", -1.0), ("fine", 0.5)].into_iter().enumerate() {
        let mut p = d.prim(&TRI, Some(&UP_Z), None);
        p["material"] = json!(m);
        prims.push(p);
        d.push("materials", json!({ "name": name, "pbrMetallicRoughness": { "baseColorFactor": [c, c, c, 1.0] } }));
    }
    d.mesh_node(prims, json!({}));
    let s = load(&d.write_gltf(dir.path(), "colours")).unwrap();
    let colours: Vec<f32> = s.materials.iter().map(|m| m.base_color.x).collect();
    assert_eq!(colours, [1.0, 0.0, 0.5]);
    let warning = s.stats.warnings.iter().find(|w| w.contains("base colour factor")).expect("a warning");
    assert!(warning.starts_with("2 base colour factor(s) outside [0, 1] clamped"), "{warning}");
    assert!(warning.contains("'hot' [5.0") && warning.contains("'negative' [-1.0"), "{warning}");
}

#[test]
fn positions_whose_area_overflows_say_so() {
    let dir = tempfile::tempdir().unwrap();
    let mut d = Doc::new();
    let far: Vec<[f32; 3]> = TRI.iter().map(|p| p.map(|c| c * 1e30)).collect();
    let p = d.prim(&far, Some(&UP_Z), None);
    d.mesh_node(vec![p], json!({ "name": "far" }));
    let e = load(&d.write_gltf(dir.path(), "far")).expect_err("1e30 m triangles");
    let msg = e.to_string();
    assert!(msg.contains("overflows f32") && msg.contains("1e30") && !msg.contains("degenerate"), "{msg}");
    // Large but within f32: a 1e6 m triangle loads.
    let mut d = Doc::new();
    let big: Vec<[f32; 3]> = TRI.iter().map(|p| p.map(|c| c * 1e6)).collect();
    let p = d.prim(&big, Some(&UP_Z), None);
    d.mesh_node(vec![p], json!({}));
    load(&d.write_gltf(dir.path(), "big")).expect("1e6 m");
}

// ---------------------------------------------------------------------------------------------
// the command: one `error:` line, exit 1, earlier results left alone

/// `out/` holding the light map of an earlier bake, to see that a failed one leaves it.
fn earlier_results(dir: &Path) -> (String, PathBuf) {
    let out = dir.join("out");
    std::fs::create_dir_all(&out).unwrap();
    let exr = write(&out, "lightmap_lod0.exr", b"an earlier light map");
    (out.display().to_string(), exr)
}

#[track_caller]
fn left_alone(exr: &Path) {
    assert_eq!(std::fs::read(exr).unwrap(), b"an earlier light map");
    assert!(!exr.with_file_name("report.json").exists());
}

#[test]
fn the_command_refuses_hostile_scenes_with_one_error_line() {
    let (root, scene, elsewhere) = two_folders();
    let dir = root.path();
    let (out, exr) = earlier_results(dir);
    let bake = |path: &Path, extra: &[&str], needles: &[&str]| {
        let p = path.display().to_string();
        let mut args = vec!["-q", "bake", p.as_str(), "--out", out.as_str(), "--texel-budget", "2000"];
        args.extend_from_slice(extra);
        assert_eq!(support::fails(dir, &args, needles), 1);
        left_alone(&exr);
    };
    write(&elsewhere, "x.png", &png(2, 2, |_, _| [255, 0, 0, 255]));
    bake(
        &textured("../elsewhere/x.png").write_gltf(&scene, "escape"),
        &[],
        &["'../elsewhere/x.png'", "--allow-outside-files"],
    );
    let zero = textured("/dev/zero").write_gltf(&scene, "zero");
    bake(&zero, &[], &["'/dev/zero'", "absolute path"]);
    bake(&zero, &["--allow-outside-files"], &["'/dev/zero'", "character device"]);
    write(&scene, "bomb.png", &support::png_bomb(16384, 16384));
    let bomb = textured("bomb.png").write_gltf(&scene, "bomb");
    bake(&bomb, &[], &["bomb.png", "16384×16384", "--max-texture-pixels"]);
    // A lower limit refuses smaller textures; the opt-in reads the file outside.
    write(&scene, "small.png", &png(64, 64, |_, _| [9; 4]));
    bake(&textured("small.png").write_gltf(&scene, "small"), &["--max-texture-pixels", "1000"], &["64×64", "1000"]);
    let lamp = lit_doc(json!({ "type": "point", "name": "lamp", "intensity": 1e38 })).write_gltf(&scene, "lamp");
    bake(&lamp, &[], &["light 0 'lamp'", "1e38 W/sr"]);
    let mut far = Doc::new();
    let corners: Vec<[f32; 3]> = TRI.iter().map(|p| p.map(|c| c * 1e30)).collect();
    let p = far.prim(&corners, Some(&UP_Z), None);
    far.mesh_node(vec![p], json!({}));
    bake(&far.write_gltf(&scene, "far"), &[], &["overflows f32"]);
    let plain = lit_doc(json!({ "type": "point", "intensity": 10.0 })).write_gltf(&scene, "plain");
    bake(&plain, &["--sky", "1e30"], &["--sky", "1e30"]);

    // The same scenes are refused by every command that loads one.
    let points = write_json(dir, "points.json", &json!({ "points": [{ "p": [0.2, 0.2, 0.0], "n": [0, 0, 1] }] }));
    let (escape, points) = (scene.join("escape.gltf").display().to_string(), points.display().to_string());
    support::fails(dir, &["probe", &escape, "--points", &points], &["'../elsewhere/x.png'"]);
    support::fails(dir, &["run", &escape, "--seconds", "0", "--out", &out], &["'../elsewhere/x.png'"]);
    left_alone(&exr);
    support::fails(dir, &["converge", &escape, "--samples", "8", "--out", &out], &["'../elsewhere/x.png'"]);
    // With the opt-in the scene bakes (and its texture is the one outside).
    support::ok(
        dir,
        &["-q", "bake", &escape, "--out", "opted", "--texel-budget", "2000", "--samples", "8", "--allow-outside-files"],
    );
}

/// A lamp within the ceiling can still overflow f32 at a surface closer to it than the
/// ceiling assumes (`radiometry::NEAREST_LIGHT`): here a square of 0.1 µm (whose ceiling is
/// 4.4·10²⁴ W/sr) 0.5 nm under a lamp of 4·10²⁴ W/sr, its texels 1 nm apart, so the nearest
/// texel (< 0.9 nm away) gets `I·cos/d² > 3·10⁴²` W/m², beyond f32. The bake fails with
/// exit 1 and writes nothing.
#[test]
fn a_bake_with_non_finite_texels_fails_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let (out, exr) = earlier_results(dir.path());
    let mut d = Doc::new();
    let s = 1e-7;
    let quad = [[0.0, 0.0, 0.0], [s, 0.0, 0.0], [s, s, 0.0], [0.0, s, 0.0]];
    let p = d.prim(&quad, Some(&[[0.0, 0.0, 1.0]; 4]), Some(&[0, 1, 2, 0, 2, 3]));
    d.mesh_node(vec![p], json!({}));
    d.json["extensionsUsed"] = json!(["KHR_lights_punctual"]);
    d.json["extensions"] = json!({ "KHR_lights_punctual": { "lights": [{ "type": "point", "intensity": 4e24 }] } });
    let at = json!([s / 2.0, s / 2.0, 5e-10]);
    let n = d.push("nodes", json!({ "translation": at, "extensions": { "KHR_lights_punctual": { "light": 0 } } }));
    d.add_root(n);
    let path = d.write_gltf(dir.path(), "micro").display().to_string();
    let args = ["-q", "bake", &path, "--out", &out, "--texel-size", "1e-9", "--samples", "8"];
    assert_eq!(support::fails(dir.path(), &args, &["non-finite irradiance", "nothing was written"]), 1);
    left_alone(&exr);
}

#[test]
fn points_files_over_the_limit_are_refused_before_the_scene_loads() {
    let dir = tempfile::tempdir().unwrap();
    let max = 1 << 20;
    let point = r#"{"p":[0,0,0],"n":[0,0,1]}"#;
    let mut text = String::with_capacity((max + 1) * (point.len() + 1) + 16);
    text.push_str(r#"{"points":["#);
    for k in 0..=max {
        if k > 0 {
            text.push(',');
        }
        text.push_str(point);
    }
    text.push_str("]}");
    let big = write(dir.path(), "big.json", text.as_bytes()).display().to_string();
    // The scene does not exist: the points file is refused first.
    let scene = dir.path().join("absent.gltf").display().to_string();
    let needles = ["big.json", "more than 1048576 points"];
    support::fails(dir.path(), &["probe", &scene, "--points", &big], &needles);
    support::fails(dir.path(), &["run", &scene, "--points", &big, "--points-out", "o.json"], &needles);
    support::fails(dir.path(), &["converge", &scene, "--points", &big, "--samples", "8"], &needles);
}
