//! What a whole-LOD bake holds per texel (issue 8's goal: 64 B): `livebake bake` run as a
//! process of its own at two texel budgets, with and without a light pass, each reporting
//! its peak resident growth in `report.json`. The growth between the two budgets over the
//! texels between them is the marginal cost of a texel, free of what does not grow with the
//! texels (the fragment buffers, the scene); each run's own figure includes those. A third
//! pair bakes two LODs of the plain room, LOD 1 reading LOD 0 (no albedo held while its
//! bundles run): its marginal cost is per texel of LOD 1, LOD 0's share (a quarter as many
//! texels, kept as output) included.

use std::path::Path;
use std::process::Command;

use anyhow::{Context, Result, bail};
use serde_json::{Value, json};

use super::Bench;
use super::assets;

/// The goal.
const GOAL_BYTES_PER_TEXEL: f64 = 64.0;

pub fn run(bench: &Bench) -> Result<Value> {
    let (quick, ui) = (bench.quick, bench.ui);
    // Few directions: memory does not depend on them, and the bake's peak is reached in the
    // first batch.
    let (budgets, samples) = if quick { ([500_000u64, 1_000_000], 16) } else { ([2_000_000, 4_000_000], 32) };
    let room = assets().join("van_gogh_room");
    let mut out = json!({ "goal_bytes_per_texel": GOAL_BYTES_PER_TEXEL, "samples": samples });
    // The lit room has a small ceiling lamp (light pass); the plain one has no emitter. The
    // two-LOD pair aims LOD 1 (4× LOD 0's texels) at the same budgets.
    for (name, file, lods) in [
        ("light_pass", "van_gogh_room_lit.gltf", 1),
        ("no_light_pass", "van_gogh_room.gltf", 1),
        ("no_light_pass_lod1", "van_gogh_room.gltf", 2),
    ] {
        let runs: Vec<Value> = budgets
            .iter()
            .map(|&budget| {
                let budget = budget >> (2 * (lods - 1));
                ui.say(format!("  {name}: {budget} texels at LOD 0, {lods} LODs"));
                bake(bench.livebake, &room.join(file), budget, samples, lods)
            })
            .collect::<Result<_>>()?;
        let figure = |r: &Value, key: &str| r[key].as_f64().unwrap_or(f64::NAN);
        let (a, b) = (&runs[0], &runs[1]);
        let marginal = (figure(b, "peak_growth") - figure(a, "peak_growth"))
            / (figure(b, "finest_texels") - figure(a, "finest_texels"));
        out[name] = json!({ "scene": file, "lods": lods, "runs": runs, "marginal_bytes_per_texel": marginal });
    }
    Ok(out)
}

/// One `livebake bake` of `lods` LODs of `scene` at a texel budget (LOD 0's); its memory
/// figures and bake time.
fn bake(livebake: &Path, scene: &Path, budget: u64, samples: u32, lods: u32) -> Result<Value> {
    let dir = std::env::temp_dir().join(format!("livebake-bench-bake-memory-{}", std::process::id()));
    let status = Command::new(livebake)
        .arg("bake")
        .arg(scene)
        .args(["--texel-budget", &budget.to_string(), "--samples", &samples.to_string()])
        .args(["--lods", &lods.to_string(), "-q", "--out"])
        .arg(&dir)
        .env_remove("RUST_LOG")
        .output()
        .context("cannot run livebake bake")?;
    if !status.status.success() {
        bail!("livebake bake failed: {}", String::from_utf8_lossy(&status.stderr).trim());
    }
    let report: Value = serde_json::from_slice(&std::fs::read(dir.join("report.json")).context("report.json")?)?;
    let _ = std::fs::remove_dir_all(&dir);
    let memory = &report["memory"];
    let lods = report["lods"].as_array().map(Vec::as_slice).unwrap_or_default();
    let texels: u64 = lods.iter().filter_map(|l| l["texels"].as_u64()).sum();
    Ok(json!({
        "texel_budget": budget,
        "texels": texels,
        "finest_texels": lods.last().map_or(Value::Null, |l| l["texels"].clone()),
        "peak_growth": memory["peak_growth"],
        "bytes_per_texel": memory["measured_bytes_per_texel"],
        "estimated_bytes_per_texel": memory["estimate"]["bytes_per_texel"],
        "bake_seconds": lods.iter().filter_map(|l| l["bake_seconds"].as_f64()).sum::<f64>(),
    }))
}
