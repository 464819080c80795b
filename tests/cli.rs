//! The `livebake` command, run as a process in temporary directories: output files and
//! their contents, the no-argument default, `probe`, error messages for bad input, and
//! identical results for identical options (and any thread count).

mod support;

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::{Value, json};
use support::{fails, ok, text};

const CORNELL: &str = "cornell_box/cornellBox-2.79-Cycles-gltf.gltf";

fn asset(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets").join(rel)
}

fn cornell() -> String {
    asset(CORNELL).display().to_string()
}

fn read_json(path: &Path) -> Value {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_slice(&bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Decodes an EXR (linear RGB f32) and checks every value is finite and non-negative.
fn read_exr(path: &Path) -> image::Rgb32FImage {
    let img = image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())).to_rgb32f();
    for (x, y, p) in img.enumerate_pixels() {
        assert!(p.0.iter().all(|v| v.is_finite() && *v >= 0.0), "{}: pixel ({x},{y}) = {:?}", path.display(), p.0);
    }
    img
}

fn dims(path: &Path) -> (u32, u32) {
    image::image_dimensions(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Checks the files of a bake in `dir` against its report; returns the report.
fn check_bake_dir(dir: &Path, lods: u32) -> Value {
    let report = read_json(&dir.join("report.json"));
    let (w, h) =
        (report["atlas"]["width"].as_u64().unwrap() as u32, report["atlas"]["height"].as_u64().unwrap() as u32);
    assert!(w > 0 && h > 0);
    let levels = report["lods"].as_array().unwrap();
    assert_eq!(levels.len(), lods as usize);
    for k in 0..lods {
        let l = &levels[k as usize];
        assert_eq!(l["lod"], k);
        assert!(l["texels"].as_u64().unwrap() > 0);
        let (lw, lh) = (w << k, h << k);
        assert_eq!((l["width"].as_u64().unwrap() as u32, l["height"].as_u64().unwrap() as u32), (lw, lh));
        let exr = read_exr(&dir.join(format!("lightmap_lod{k}.exr")));
        assert_eq!(exr.dimensions(), (lw, lh), "LOD {k} EXR size");
        assert_eq!(dims(&dir.join(format!("lightmap_lod{k}.png"))), (lw, lh), "LOD {k} PNG size");
        // The EXR holds the baked irradiance: some light, and at least as many non-empty
        // pixels as texels (gutters copy texels too).
        let lit = exr.pixels().filter(|p| p.0.iter().any(|&v| v > 0.0)).count();
        assert!(lit > 0, "LOD {k}: black EXR");
        let texels = l["texels"].as_u64().unwrap() as usize;
        assert!(lit <= (lw * lh) as usize && texels <= (lw * lh) as usize);
    }
    assert!(!dir.join(format!("lightmap_lod{lods}.exr")).exists(), "more LODs than asked for");
    // Nothing half-written left behind.
    for entry in std::fs::read_dir(dir).unwrap() {
        let name = entry.unwrap().file_name();
        assert!(!name.to_string_lossy().ends_with(".partial"), "{name:?} left behind");
    }
    // The CLI fills in the phases around the bake.
    assert!(report["phases"]["load"].as_f64().unwrap() > 0.0);
    assert!(report["phases"]["write"].as_f64().unwrap() > 0.0);
    assert!(report["total_seconds"].as_f64().unwrap() > 0.0);
    report
}

// ---------------------------------------------------------------------------------------------
// bake

#[test]
fn bake_writes_exr_png_and_report() {
    let tmp = tempfile::tempdir().unwrap();
    let out_dir = tmp.path().join("baked");
    let out = out_dir.display().to_string();
    let stdout = ok(tmp.path(), &["bake", &cornell(), "--out", &out, "--texel-size", "0.05", "--samples", "16"]);
    let report = check_bake_dir(&out_dir, 1);
    assert_eq!(report["backend"], "cpu", "cpu is the default backend");
    assert_eq!(report["config"]["samples"], 16);
    assert!((report["atlas"]["texel_size"].as_f64().unwrap() - 0.05).abs() < 1e-6);
    assert!(report["lods"][0]["texels"].as_u64().unwrap() > 10_000);
    assert_eq!(report["lods"][0]["non_finite_texels"], 0);
    assert_eq!(report["scene"]["triangles"], 4410);
    // The summary names what was written.
    for f in ["lightmap_lod0.exr", "lightmap_lod0.png", "report.json"] {
        assert!(stdout.contains(f), "summary does not mention {f}:\n{stdout}");
    }
}

/// A model that carries no light (no punctual light, no emitter: as most exports for a
/// walkthrough) is lit by a white sky of 1 W/(sr·m²) when the command line gives none, with
/// a warning that says so; `--sky 0,0,0` keeps it black, with a warning that it will be.
#[test]
fn a_scene_without_light_is_lit_by_a_white_sky_and_says_so() {
    let tmp = tempfile::tempdir().unwrap();
    let room = asset("living_room/living_room.glb").display().to_string();
    let bake = |dir: &str, extra: &[&str]| {
        let out = tmp.path().join(dir);
        let mut args = vec!["bake", &room, "--texel-size", "0.1", "--samples", "16"];
        let out_arg = out.display().to_string();
        args.extend(["--out", &out_arg]);
        args.extend(extra);
        let run = support::livebake(tmp.path(), &args);
        let stderr = text(&run.stderr);
        assert!(run.status.success(), "{stderr}");
        (read_json(&out.join("report.json")), read_exr(&out.join("lightmap_lod0.exr")), stderr)
    };
    let (report, exr, stderr) = bake("sky", &[]);
    assert!(stderr.contains("no light of its own") && stderr.contains("white sky"), "{stderr}");
    assert_eq!(report["scene"]["sky"], json!([1.0, 1.0, 1.0]));
    // A surface open to the whole sky sees radiance 1 on every line: its estimate is π·Σa/Σa,
    // exactly π whatever the directions (the grass around the house). Nothing can get more:
    // a surface of albedo below 1 under it sends back less than the sky.
    let most = exr.pixels().flat_map(|p| p.0).fold(0.0f32, f32::max);
    assert!((most - std::f32::consts::PI).abs() < 1e-4 * std::f32::consts::PI, "brightest texel {most}, not π");
    let (report, exr, stderr) = bake("black", &["--sky", "0,0,0"]);
    assert!(stderr.contains("every light map will be black"), "{stderr}");
    assert_eq!(report["scene"]["sky"], json!([0.0, 0.0, 0.0]));
    assert!(exr.pixels().all(|p| p.0 == [0.0; 3]));
}

#[test]
fn bake_with_two_lods_writes_both_levels() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("o");
    let d = dir.display().to_string();
    ok(tmp.path(), &["-q", "bake", &cornell(), "--out", &d, "--texel-size", "0.05", "--samples", "16", "--lods", "2"]);
    let report = check_bake_dir(&dir, 2);
    let (w0, h0) = dims(&dir.join("lightmap_lod0.exr"));
    assert_eq!(dims(&dir.join("lightmap_lod1.exr")), (2 * w0, 2 * h0));
    assert_eq!(dims(&dir.join("lightmap_lod1.png")), (2 * w0, 2 * h0));
    let t0 = report["lods"][0]["texels"].as_u64().unwrap() as f64;
    let t1 = report["lods"][1]["texels"].as_u64().unwrap() as f64;
    assert!(t1 > 3.0 * t0 && t1 <= 4.0 * t0, "LOD 1 has {t1} texels, LOD 0 {t0}");
}

#[test]
fn no_arguments_runs_the_runtime_on_the_cornell_box_into_out() {
    // Without a display: the headless runtime on the Cornell box for a few seconds after
    // first light, every default, into ./out.
    let tmp = tempfile::tempdir().unwrap();
    let stdout = ok(tmp.path(), &[]);
    let report = read_json(&tmp.path().join("out/report.json"));
    assert!(report["scene"].as_str().unwrap().ends_with("cornellBox-2.79-Cycles-gltf.gltf"));
    assert!(report["first_light_seconds"].as_f64().unwrap() > 0.0);
    assert_eq!(report["config"]["seconds"], 3.0);
    assert!(tmp.path().join("out/cells.json").exists());
    read_exr(&tmp.path().join("out/lightmap_lod0.exr"));
    assert!(stdout.contains("first light") && stdout.contains("report.json"), "{stdout}");
}

#[test]
fn no_arguments_with_an_unreachable_display_falls_back_to_headless() {
    // DISPLAY names an X server that is not there (no socket for display 65 530): the viewer
    // cannot open, one warning says so, and the headless run follows, exit 0.
    let tmp = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_livebake"))
        .current_dir(tmp.path())
        .env_remove("RUST_LOG")
        .env_remove("WAYLAND_DISPLAY")
        .env("DISPLAY", ":65530")
        .output()
        .expect("cannot run livebake");
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "livebake failed ({}):\n{stderr}", out.status);
    assert!(!stderr.contains("panicked") && !stderr.contains("internal error"), "{stderr}");
    let fallback: Vec<&str> = stderr.lines().filter(|l| l.contains("running headless instead")).collect();
    assert_eq!(fallback.len(), 1, "{stderr}");
    assert!(fallback[0].contains("display"), "{}", fallback[0]);
    let report = read_json(&tmp.path().join("out/report.json"));
    assert_eq!(report["config"]["seconds"], 3.0);
    read_exr(&tmp.path().join("out/lightmap_lod0.exr"));
}

// ---------------------------------------------------------------------------------------------
// probe

/// Points in the Cornell box: on the floor, the ceiling (away from the lamp), the red wall
/// (x = −2), and one in mid-air.
fn probe_points(dir: &Path) -> PathBuf {
    let points = json!({ "points": [
        { "p": [-1.0, 0.0, 1.0], "n": [0.0, 1.0, 0.0], "name": "floor" },
        { "p": [1.0, 3.0, 1.0], "n": [0.0, -1.0, 0.0], "name": "ceiling" },
        { "p": [-2.0, 1.5, 0.5], "n": [1.0, 0.0, 0.0], "name": "red wall" },
        { "p": [0.0, 2.5, 1.0], "n": [0.0, 1.0, 0.0], "name": "mid-air" },
        { "p": [-2.0, 1.5, 0.5], "n": [-1.0, 0.0, 0.0], "name": "behind the single-sided red wall" },
    ]});
    let path = dir.join("points.json");
    std::fs::write(&path, serde_json::to_vec_pretty(&points).unwrap()).unwrap();
    path
}

/// The E of each point (None where the output has an error instead), checking the input
/// fields are kept.
fn probe_results(doc: &Value) -> Vec<Option<[f64; 3]>> {
    let list = doc["points"].as_array().expect("points");
    assert_eq!(list.len(), 5);
    list.iter()
        .map(|p| {
            assert!(p["name"].is_string() && p["p"].is_array() && p["n"].is_array(), "input fields kept: {p}");
            match (p.get("E"), p.get("error")) {
                (Some(e), None) => {
                    let e: Vec<f64> = e.as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
                    assert_eq!(e.len(), 3);
                    assert!(e.iter().all(|v| v.is_finite() && *v >= 0.0), "{p}");
                    Some([e[0], e[1], e[2]])
                }
                (None, Some(err)) => {
                    assert!(err.as_str().is_some_and(|s| !s.is_empty()), "{p}");
                    None
                }
                _ => panic!("a point needs exactly one of E and error: {p}"),
            }
        })
        .collect()
}

#[test]
fn probe_reports_irradiance_on_surfaces_and_errors_in_mid_air() {
    let tmp = tempfile::tempdir().unwrap();
    let points = probe_points(tmp.path());
    let pts = points.display().to_string();

    // Reference backend, no --out: JSON on stdout.
    let stdout =
        ok(tmp.path(), &["-q", "probe", &cornell(), "--points", &pts, "--backend", "reference", "--samples", "64"]);
    let doc: Value = serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("stdout is not JSON ({e}):\n{stdout}"));
    let reference = probe_results(&doc);
    assert!(doc["points"][3]["error"].as_str().unwrap().contains("no surface"), "{}", doc["points"][3]);
    assert!(doc["points"][4]["error"].as_str().unwrap().contains("single-sided"), "{}", doc["points"][4]);

    // Default backend (cpu bake, then light-map reads), written to a file.
    let out = tmp.path().join("probed.json");
    let stdout = ok(
        tmp.path(),
        &["probe", &cornell(), "--points", &pts, "--texel-size", "0.05", "--out", &out.display().to_string()],
    );
    assert!(serde_json::from_str::<Value>(&stdout).is_err(), "with --out, stdout is the summary, not the JSON");
    let doc = read_json(&out);
    let cpu = probe_results(&doc);
    assert!(doc["points"][3]["error"].as_str().unwrap().contains("no surface"), "{}", doc["points"][3]);
    assert!(doc["points"][4]["error"].as_str().unwrap().contains("single-sided"), "{}", doc["points"][4]);

    for (i, (r, c)) in reference.iter().zip(&cpu).enumerate().take(3) {
        let (r, c) = (r.expect("reference E"), c.expect("cpu E"));
        // Every surface point here sees the lamp or its light: lit.
        assert!(r.iter().all(|&v| v > 1e-3) && c.iter().all(|&v| v > 1e-3), "point {i}: {r:?} / {c:?}");
        // The two estimates agree loosely: 64 paths leave the reference ~10–15% noise at
        // these points and the light map is bilinear over 5 cm texels; a factor of 2 is
        // > 5σ away and still catches a lost π or a wrong side.
        let ratio = (r[0] + r[1] + r[2]) / (c[0] + c[1] + c[2]);
        assert!((0.5..2.0).contains(&ratio), "point {i}: reference {r:?}, cpu {c:?}");
    }
}

// ---------------------------------------------------------------------------------------------
// bad input

#[test]
fn bad_input_exits_with_an_error_line_and_no_panic() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let scene = cornell();
    let out = dir.join("o").display().to_string();
    let write = |name: &str, bytes: &[u8]| {
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        p.display().to_string()
    };
    let empty = write("empty.gltf", b"");
    let full = std::fs::read(asset(CORNELL)).unwrap();
    let truncated = write("truncated.gltf", &full[..full.len() / 3]);
    let short_point = write("short.json", br#"{"points": [{"p": [0, 0], "n": [0, 1, 0]}]}"#);
    let not_json = write("broken.json", br#"{"points": [{"p": [0, 0, 0], "#);
    let no_list = write("nolist.json", br#"{"pts": []}"#);
    let good_points = probe_points(dir).display().to_string();
    let missing = dir.join("nowhere.gltf").display().to_string();

    fails(dir, &["bake", &missing, "--out", &out], &["nowhere.gltf"]);
    fails(dir, &["bake", &empty, "--out", &out], &["empty.gltf", "empty"]);
    fails(dir, &["bake", &truncated, "--out", &out], &["truncated.gltf", "truncated"]);
    fails(dir, &["probe", &scene, "--points", &short_point], &["short.json", "\"p\"", "three numbers"]);
    fails(dir, &["probe", &scene, "--points", &not_json], &["broken.json", "not valid JSON"]);
    fails(dir, &["probe", &scene, "--points", &no_list], &["nolist.json", "points"]);
    fails(dir, &["probe", &scene, "--points", &dir.join("none.json").display().to_string()], &["none.json"]);
    fails(dir, &["probe", &missing, "--points", &good_points], &["nowhere.gltf"]);
    fails(dir, &["bake", &scene, "--out", &out, "--sky", "1,2"], &["--sky", "R,G,B"]);
    fails(dir, &["bake", &scene, "--out", &out, "--sky", "-1,0,0"], &["--sky", "non-negative"]);
    fails(dir, &["bake", &scene, "--out", &out, "--texel-size", "-1"], &["--texel-size", "positive"]);
    fails(dir, &["bake", &scene, "--out", &out, "--texel-size=0"], &["--texel-size", "positive"]);
    fails(dir, &["bake", &scene, "--out", &out, "--texel-size", "0.05", "--lods", "0"], &["--lods"]);
    fails(dir, &["bake", &scene, "--out", &out, "--texel-size", "0.05", "--lods", "9"], &["--lods"]);
    fails(dir, &["bake", &scene, "--out", &out, "--texel-size", "0.05", "--samples", "0"], &["--samples"]);
    fails(dir, &["bake", &scene, "--out", &out, "--threads", "0"], &["--threads"]);
    fails(dir, &["bake", &scene, "--out", &out, "--texel-size", "0.0001"], &["--texel-size"]);
    fails(dir, &["bake", &scene, "--out", &out, "--backend", "quantum"], &["--backend", "quantum"]);
    // Absurd options (issue 8): each refused with exit code 1 before any work, the limit named.
    let absurd = |dir: &Path, args: &[&str], needles: &[&str]| assert_eq!(fails(dir, args, needles), 1, "{args:?}");
    absurd(dir, &["bake", &scene, "--out", &out, "--lanes", "100000"], &["--lanes", "64", "100000"]);
    absurd(dir, &["bake", &scene, "--out", &out, "--oversampling", "100000"], &["--oversampling", "16"]);
    absurd(dir, &["bake", &scene, "--out", &out, "--threads", "50000"], &["--threads", "1024", "50000"]);
    absurd(dir, &["bake", &scene, "--out", &out, "--light-directions", "0"], &["--light-directions", "small emitters"]);
    absurd(dir, &["bake", &scene, "--out", &out, "--head-side", "1"], &["--head-side", "16"]);
    absurd(dir, &["bake", &scene, "--out", &out, "--nodes", "1"], &["--nodes", "surfaces"]);
    absurd(dir, &["bake", &scene, "--out", &out, "--samples", "4000000000"], &["--samples", "1048576"]);
    absurd(dir, &["bake", &scene, "--out", &out, "--texel-budget", "0"], &["--texel-budget"]);
    absurd(dir, &["bake", &scene, "--out", &out, "--texel-budget", "1000000000000"], &["--texel-budget", "268435456"]);
    // Nothing was written by any of them.
    assert!(!dir.join("o").exists());
}

/// The memory guard (issue 8): a bake whose estimated peak exceeds the limit is refused before
/// any texel map is built, with exit code 1 and one `error:` line naming the limit and the
/// options that lower the need; a limit it fits in bakes.
#[test]
fn bakes_over_the_memory_limit_are_refused_naming_what_to_change() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let scene = cornell();
    let out = dir.join("o").display().to_string();
    let refused = |args: &[&str], needles: &[&str]| {
        let mut all = vec!["bake", scene.as_str(), "--out", out.as_str(), "-q"];
        all.extend_from_slice(args);
        assert_eq!(fails(dir, &all, needles), 1, "{all:?}");
    };
    // ~500k texels at the default budget need ~170 MB: 100 MB is too little.
    refused(&["--memory-limit", "100M"], &["needs ", "texels", "--memory-limit", "--texel-budget", "--lanes"]);
    refused(&["--memory-limit", "100M", "--texel-size", "0.01"], &["--texel-size", "--memory-limit"]);
    refused(&["--memory-limit", "300M", "--texel-size", "0.02", "--lods", "3"], &["--lods", "--texel-size"]);
    // Below what the process already holds: only a larger limit helps.
    refused(&["--memory-limit", "1k"], &["--memory-limit"]);
    // Texels so fine that the lit area alone rules the bake out, before the atlas is built
    // (or, on a machine with the memory, the atlas's own limit does).
    let room = asset("van_gogh_room/van_gogh_room_lit.gltf").display().to_string();
    let out_arg = out.as_str();
    let fine = ["bake", room.as_str(), "--out", out_arg, "-q", "--texel-size", "0.0005"];
    assert_eq!(fails(dir, &fine, &["--texel-size"]), 1);
    // Not a size: the argument parser refuses it (exit 2).
    assert_eq!(fails(dir, &["bake", &scene, "--out", &out, "--memory-limit", "lots"], &["--memory-limit"]), 2);
    assert!(!dir.join("o").exists(), "a refused bake wrote nothing");
    // The same bake within a limit that holds it runs, and reports its estimate.
    ok(dir, &["bake", &scene, "--out", &out, "-q", "--texel-size", "0.05", "--samples", "8", "--memory-limit", "1G"]);
    let report = read_json(&dir.join("o/report.json"));
    let estimate = &report["memory"]["estimate"];
    assert!(estimate["bytes"].as_u64().is_some_and(|b| b > 0 && b < 1 << 30), "{estimate}");
    assert_eq!(report["memory"]["limit_bytes"].as_u64(), Some(1 << 30));
    assert_eq!(report["memory"]["limit_source"], "option");
}

// ---------------------------------------------------------------------------------------------
// determinism

#[test]
fn same_options_give_identical_light_maps_whatever_the_thread_count() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = cornell();
    for (backend, samples) in [("cpu", "32"), ("reference", "4")] {
        // One bake with the shared options plus `extra`; returns its (EXR, PNG) bytes.
        let bake = |name: &str, extra: &[&str]| -> (Vec<u8>, Vec<u8>) {
            let dir = tmp.path().join(format!("{backend}-{name}"));
            let d = dir.display().to_string();
            let mut args = vec![
                "-q",
                "bake",
                &scene,
                "--out",
                &d,
                "--texel-size",
                "0.05",
                "--backend",
                backend,
                "--samples",
                samples,
            ];
            args.extend_from_slice(extra);
            ok(tmp.path(), &args);
            let exr = std::fs::read(dir.join("lightmap_lod0.exr")).unwrap();
            let png = std::fs::read(dir.join("lightmap_lod0.png")).unwrap();
            (exr, png)
        };
        let a = bake("a", &["--threads", "2"]);
        let b = bake("b", &["--threads", "2"]);
        let single = bake("single", &["--threads", "1"]);
        assert!(a.0 == b.0, "{backend}: two bakes with the same options differ (EXR)");
        assert!(a.1 == b.1, "{backend}: two bakes with the same options differ (PNG)");
        assert!(a.0 == single.0, "{backend}: --threads 1 and --threads 2 differ (EXR)");
        assert!(a.1 == single.1, "{backend}: --threads 1 and --threads 2 differ (PNG)");
        // And a different seed does change a Monte Carlo result (the comparison can fail).
        let seeded = bake("seed", &["--seed", "1"]);
        assert!(seeded.0 != a.0, "{backend}: the seed changes nothing");
    }
}

// ---------------------------------------------------------------------------------------------
// run

/// `run` on the 2 m room for a second after first light: the event stream (one JSON object per
/// line, times increasing, first light before any publish, a stats event, a final
/// `finished`), the shown light maps, the cell table, the report, and irradiance at points
/// read from the shown map.
#[test]
fn run_streams_events_and_writes_what_it_showed() {
    let tmp = tempfile::tempdir().unwrap();
    let room = asset("cornell_2m/cornell_2m.gltf").display().to_string();
    let points = asset("cornell_2m/points.json").display().to_string();
    let out = tmp.path().join("o");
    let args = [
        "run",
        &room,
        "--seconds",
        "1.5",
        "--events",
        "e.jsonl",
        "--out",
        "o",
        "--camera",
        "0.3,1,1.7,1.7,0.6,0.3",
        "--points",
        &points,
        "--points-out",
        "p.json",
        "--threads",
        "2",
    ];
    ok(tmp.path(), &args);
    let lines = std::fs::read_to_string(tmp.path().join("e.jsonl")).unwrap();
    let events: Vec<Value> =
        lines.lines().map(|l| serde_json::from_str(l).expect("one JSON object per line")).collect();
    let kinds: Vec<&str> = events.iter().map(|e| e["event"].as_str().unwrap()).collect();
    let t: Vec<f64> = events.iter().map(|e| e["t"].as_f64().unwrap()).collect();
    assert!(t.windows(2).all(|w| w[0] <= w[1]), "times go back: {t:?}");
    let first_light = kinds.iter().position(|&k| k == "first_light").expect("first_light");
    assert!(kinds.iter().position(|&k| k == "cell_published").is_none_or(|p| p > first_light));
    assert!(kinds.contains(&"stats") && kinds.last() == Some(&"finished"), "{kinds:?}");
    for e in events.iter().filter(|e| e["event"] == "cell_published") {
        assert!(e["lod"].as_u64().unwrap() >= 1 && e["directions"].as_u64().unwrap() > 0, "{e}");
    }
    let cells = read_json(&out.join("cells.json"));
    let list = cells["cells"].as_array().unwrap();
    assert!(list.len() > 10);
    for c in list {
        assert!(c["bounds"]["min"].as_array().unwrap().len() == 3 && c["shown_lod"].as_u64().is_some(), "{c}");
    }
    // Cells published (a cell may be published more than once: early at a finer level, then
    // again as that level refines in place, see docs/CLI.md, `livebake run`). Every
    // one shows in the cell table (no eviction at this size). The table may show more: a
    // publish emits its event just after it changes the map, so one that lands as the run
    // takes its final snapshot is in the table while its event comes too late for the log.
    let published: std::collections::BTreeSet<u64> =
        events.iter().filter(|e| e["event"] == "cell_published").map(|e| e["cell"].as_u64().unwrap()).collect();
    let refined: std::collections::BTreeSet<u64> =
        list.iter().filter(|c| c["shown_lod"].as_u64().unwrap() > 0).map(|c| c["cell"].as_u64().unwrap()).collect();
    assert!(published.is_subset(&refined), "published cells not shown: {:?}", published.difference(&refined));
    let report = read_json(&out.join("report.json"));
    assert!(
        report["first_light_seconds"].as_f64().unwrap() > 0.0
            && report["stats"]["resident_bytes"].as_u64().unwrap() > 0
    );
    read_exr(&out.join("lightmap_lod0.exr"));
    let probed = read_json(&tmp.path().join("p.json"));
    let pts = probed["points"].as_array().unwrap();
    assert_eq!(pts.len(), 332);
    assert!(pts.iter().all(|p| p["E"].as_array().is_some_and(|e| e.iter().all(|v| v.as_f64().unwrap() >= 0.0))));
}

#[test]
fn run_refuses_bad_options_with_one_line() {
    let tmp = tempfile::tempdir().unwrap();
    let c = cornell();
    fails(tmp.path(), &["run", &c, "--backend", "reference"], &["runtime", "cpu"]);
    fails(tmp.path(), &["run", &c, "--camera", "1,2,3"], &["six"]);
    fails(tmp.path(), &["run", &c, "--camera", "1,1,1,1,1,1"], &["differ"]);
    fails(tmp.path(), &["run", &c, "--seconds", "-1"], &["seconds"]);
    fails(tmp.path(), &["run", &c, "--camera-path", "missing.json"], &["camera path", "missing.json"]);
    std::fs::write(
        tmp.path().join("back.json"),
        r#"[{"t":1,"eye":[0,1,0],"target":[1,1,1]},{"t":0,"eye":[0,1,0],"target":[1,1,1]}]"#,
    )
    .unwrap();
    fails(tmp.path(), &["run", &c, "--camera-path", "back.json"], &["back in time"]);
    fails(tmp.path(), &["run", &c, "--memory-budget", "12Q"], &["unit"]);
    fails(tmp.path(), &["run", &c, "--memory-budget", "12"], &["memory-budget"]);
    fails(tmp.path(), &["run", &c, "--cell-size", "0"], &["cell-size"]);
    fails(tmp.path(), &["run", &c, "--lods", "20"], &["lods"]);
    fails(tmp.path(), &["run", &c, "--max-directions", "4", "--min-directions", "8"], &["max-directions"]);
    fails(tmp.path(), &["run", "missing.gltf"], &["missing.gltf"]);
    fails(tmp.path(), &["run", &c, "--export-gltf", "room.glb"], &["export", ".gltf"]);
    assert!(!tmp.path().join("out").exists(), "a refused run wrote outputs");
}
