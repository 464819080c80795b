//! A bake's memory (issue 8): the estimate the guard checks before any texel map is built,
//! against what the bake then held, measured by the `livebake` binary itself (the growth of
//! its resident set from before the texel maps to its peak, `VmHWM`, after the light maps
//! are written) and written to `report.json`. A process of its own, so the peak is this
//! bake's and nothing else's.
//!
//! Two checks. The estimate is the guard's: it must not fall short of what the bake held
//! (at most 10% under). And the model behind it must match what was held, once its one
//! input that a bake only knows at the end is given: the threads' fragment buffers and the
//! hits kept for their turn grow to the largest tile, which the estimate, made before
//! any tile is planned, takes at the full node budget (2 × 18 MB and 25 MB here, where a
//! light pass gives the bake one lane for two threads; this bake's largest tile holds about
//! a third of it). So the measured growth is held to the estimate's per-texel part plus
//! `cpu_thread_bytes` at the largest tile the report gives, within ±10%: the per-texel
//! structures are counted by their types' sizes (exact), the gutter pixels are assumed a
//! quarter of the texels (8 B each: ±1 B a texel of ~100), and the allocator keeps some
//! freed temporaries (the texel map's per-band build buffers, a few % of the atlas).
//! Resident sizes do not depend on timing, so the figure is stable run to run; a per-texel
//! buffer added or dropped without the model being told (12 B or more of ~100) moves it by
//! 12% and more.

use std::path::Path;
use std::process::Command;

use serde_json::Value;

fn livebake_bake(dir: &Path, scene: &Path, args: &[&str]) -> Value {
    let out = dir.join("out");
    let status = Command::new(env!("CARGO_BIN_EXE_livebake"))
        .arg("bake")
        .arg(scene)
        .arg("--out")
        .arg(&out)
        .args(["-q", "--threads", "2"])
        .args(args)
        .env_remove("RUST_LOG")
        .output()
        .expect("cannot run livebake");
    assert!(status.status.success(), "bake failed: {}", String::from_utf8_lossy(&status.stderr));
    let bytes = std::fs::read(out.join("report.json")).expect("report.json");
    serde_json::from_slice(&bytes).expect("report.json is JSON")
}

#[test]
fn the_estimate_matches_the_measured_peak_of_a_mid_size_bake() {
    if !Path::new("/proc/self/status").exists() {
        eprintln!("no /proc: resident sizes cannot be read here");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/van_gogh_room/van_gogh_room_lit.gltf");
    // ~1.7 M texels: their ~300 MB dwarf what does not grow with them.
    let report = livebake_bake(tmp.path(), &scene, &["--texel-size", "0.01", "--samples", "8"]);
    let memory = &report["memory"];
    let estimate = memory["estimate"]["bytes"].as_f64().expect("estimate");
    let texels = memory["estimate"]["texels"].as_u64().expect("texels");
    let growth = memory["peak_growth"].as_f64().expect("measured peak growth");
    assert_eq!(texels, report["lods"][0]["texels"].as_u64().unwrap(), "LOD 0's count is exact");
    assert!(texels > 1_000_000, "{texels} texels: too few for per-texel memory to dominate");
    let ratio = growth / estimate;
    // The model at the largest tile this bake traced (see the module's notes).
    let pass = &report["lods"][0]["bundle"]["pass"];
    let largest_tile = pass["peak_tile_fragments"].as_u64().expect("peak_tile_fragments");
    let lanes = memory["estimate"]["lanes"].as_u64().expect("lanes");
    let at_largest = livebake::bundle::BundleConfig { node_capacity: largest_tile, ..Default::default() };
    let threads = livebake::bake::memory::cpu_thread_bytes(&at_largest, 2, lanes);
    let model = memory["estimate"]["texel_bytes"].as_f64().expect("texel_bytes") + threads as f64;
    let against_model = growth / model;
    eprintln!(
        "{texels} texels: estimate {:.0} MB ({:.1} B/texel), measured {:.0} MB ({:.1} B/texel), ratio {ratio:.3}; \
         model at the largest tile ({largest_tile} fragments) {:.0} MB, ratio {against_model:.3}",
        estimate / 1e6,
        estimate / texels as f64,
        growth / 1e6,
        growth / texels as f64,
        model / 1e6,
    );
    assert!(ratio <= 1.1, "measured {growth} B against an estimate of {estimate} B ({ratio:.3})");
    assert!(
        (0.9..=1.1).contains(&against_model),
        "measured {growth} B against the model's {model} B at the largest tile ({against_model:.3})"
    );
    let per_texel = report["bytes_per_texel"].as_f64().expect("bytes_per_texel");
    assert!((per_texel - growth / texels as f64).abs() < 1e-6 * per_texel, "bytes_per_texel is the growth per texel");
}
