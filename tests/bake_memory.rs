//! A bake's memory (issue 8): the estimate the guard checks before any texel map is built,
//! against what the bake then held, measured by the `livebake` binary itself (the growth of
//! its resident set from before the texel maps to its peak, `VmHWM`, after the light maps
//! are written) and written to `report.json`. A process of its own, so the peak is this
//! bake's and nothing else's.
//!
//! Tolerance ±25%: the estimate counts every per-texel and per-pixel structure by its type's
//! size (exact), and approximates three things: the gutter pixels (a quarter of the texels
//! assumed, 8 B each: ±1 B a texel), the threads' fragment buffers and the hits kept for
//! their turn (counted at the full node budget, 2 × 24 MB and 25 MB here, where a light
//! pass gives the bake one lane for two threads; they grow to the largest tile, which may be
//! less) and what the allocator keeps of freed temporaries (the texel map's
//! per-band build buffers, a few % of the atlas). Resident sizes do not depend on timing,
//! so the figure is stable run to run; a per-texel buffer added or dropped without the model
//! being told (12 B or more of ~150) moves it by 8% and more, stacking with the above.

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
    eprintln!(
        "{texels} texels: estimate {:.0} MB ({:.1} B/texel), measured {:.0} MB ({:.1} B/texel), ratio {ratio:.3}",
        estimate / 1e6,
        estimate / texels as f64,
        growth / 1e6,
        growth / texels as f64
    );
    assert!((0.75..=1.25).contains(&ratio), "measured {growth} B against an estimate of {estimate} B ({ratio:.3})");
    let per_texel = report["bytes_per_texel"].as_f64().expect("bytes_per_texel");
    assert!((per_texel - growth / texels as f64).abs() < 1e-6 * per_texel, "bytes_per_texel is the growth per texel");
}
