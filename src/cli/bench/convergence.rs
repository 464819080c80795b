//! Convergence against an independent reference on the 2 m Cornell-style room
//! (`assets/cornell_2m`), at 1.2 cm texels, error measured at 332 surface points against
//! Mitsuba 3 (`mitsuba_reference.json`, 65 536 spp, made with an independent Mitsuba 3 script, see assets/README.md):
//! normalised RMS error √(Σ(E−E_ref)²/ΣE_ref²) with Mitsuba's own variance removed.
//!
//! * `whole_command`: wall time of `livebake probe` (load, unwrap, bake, sample) as the
//!   directions grow, and the time to reach 10%, 5% and 2%, against Blender Cycles baking the
//!   same room's irradiance into a light map at the same texel size (goal: at most 1/50 of
//!   Cycles' time). Cycles is measured in the same run when `LIVEBAKE_CYCLES_PYTHON` names a
//!   Python that has `bpy` (`scripts/cycles_time_to_error.py`, which says what its seconds
//!   include); otherwise the report carries the figures that script recorded, with their date
//!   and machine, as `"cycles_source": "recorded"`.
//! * `efficiency`: bake time against error for the bundle bake and for the reference path
//!   tracer baking the same light map per texel; at equal time the bundle error must be at
//!   most half the reference's.

use std::path::Path;
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use livebake::glam::DVec3;
use serde_json::{Value, json};

use livebake::bake::{BackendKind, BakeConfig, bake};
use livebake::probe::{LightmapSampler, SurfaceLocator};
use livebake::progress::NoProgress;
use livebake::reference::Bvh;
use livebake::scene::{LoadOptions, Scene, SceneGeometry, load_gltf};

use super::Bench;
use super::{assets, seconds};
use livebake::points::{ReferencePoints, read_reference};

const TEXEL: f32 = 0.012;
/// The errors whose times are compared with Cycles'.
const TARGETS: [f64; 3] = [0.10, 0.05, 0.02];
/// Names the Python interpreter that has `bpy`, to measure Cycles in the run.
pub const CYCLES_PYTHON_ENV: &str = "LIVEBAKE_CYCLES_PYTHON";
const CYCLES_SCRIPT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/cycles_time_to_error.py");

/// Cycles' seconds to each error as `scripts/cycles_time_to_error.py` last measured them on
/// this machine, for runs without `bpy`.
struct RecordedCycles {
    date: &'static str,
    machine: &'static str,
    renderer: &'static str,
    command: &'static str,
    /// (error, seconds of Cycles' bake)
    seconds: &'static [(f64, f64)],
}

const RECORDED_CYCLES: RecordedCycles = RecordedCycles {
    date: "2026-12-07",
    machine: "the project's 2-core Intel Xeon VM",
    renderer: "Blender Cycles 5.0.1 (bpy from PyPI), CPU, 2 threads",
    command: "LIVEBAKE_CYCLES_PYTHON=/work/bpy-venv/bin/python livebake bench --only convergence",
    seconds: &[(0.10, 2.94), (0.05, 9.25), (0.02, 59.44)],
};

/// The reference's relative RMS error of per-point estimates (`None`: the point had none).
fn error_of(reference: &ReferencePoints, e: &[Option<[f64; 3]>]) -> Result<f64> {
    let got = e
        .iter()
        .enumerate()
        .map(|(k, got)| got.map(DVec3::from).with_context(|| format!("no estimate at point {k}")))
        .collect::<Result<Vec<DVec3>>>()?;
    if got.len() != reference.e.len() {
        bail!("{} estimates for {} reference points", got.len(), reference.e.len());
    }
    Ok(reference.relative_rms(|k| got[k]))
}

fn triple(v: &Value) -> Option<[f64; 3]> {
    let a = v.as_array()?;
    Some([a.first()?.as_f64()?, a.get(1)?.as_f64()?, a.get(2)?.as_f64()?])
}

/// Time at which a falling error curve crosses `target` (log-log interpolation).
fn time_to(curve: &[(f64, f64)], target: f64) -> Option<f64> {
    curve.windows(2).find(|w| w[0].1 >= target && w[1].1 <= target).map(|w| {
        let ((t0, e0), (t1, e1)) = (w[0], w[1]);
        if e0 == e1 {
            return t0;
        }
        let f = (target.ln() - e0.ln()) / (e1.ln() - e0.ln());
        (t0.ln() + f * (t1.ln() - t0.ln())).exp()
    })
}

/// Error of a falling curve at time `t` (log-log interpolation; `None` outside it).
fn error_at(curve: &[(f64, f64)], t: f64) -> Option<f64> {
    curve.windows(2).find(|w| w[0].0 <= t && t <= w[1].0).map(|w| {
        let ((t0, e0), (t1, e1)) = (w[0], w[1]);
        let f = (t.ln() - t0.ln()) / (t1.ln() - t0.ln());
        (e0.ln() + f * (e1.ln() - e0.ln())).exp()
    })
}

/// Cycles' time to 5% is to be at least this many times livebake's (the goal).
const GOAL_SPEEDUP: f64 = 50.0;

/// Cycles' seconds to the errors of [`TARGETS`] (`None` where its run stopped short).
struct CyclesTimes {
    source: &'static str,
    seconds: Vec<(f64, Option<f64>)>,
    detail: Value,
}

/// Measures Cycles with the Python `LIVEBAKE_CYCLES_PYTHON` names, or reads the recorded
/// figures.
fn cycles_times(bench: &Bench, scene: &Path, points: &Path, reference: &Path) -> Result<CyclesTimes> {
    let Some(python) = std::env::var_os(CYCLES_PYTHON_ENV) else {
        let r = &RECORDED_CYCLES;
        return Ok(CyclesTimes {
            source: "recorded",
            seconds: r.seconds.iter().map(|&(e, t)| (e, Some(t))).collect(),
            detail: json!({ "date": r.date, "machine": r.machine, "renderer": r.renderer, "command": r.command }),
        });
    };
    // Quick runs stop at 5%: 2% takes Cycles minutes.
    let targets: &[f64] = if bench.quick { &TARGETS[..2] } else { &TARGETS };
    let list: Vec<String> = targets.iter().map(f64::to_string).collect();
    bench.ui.say(format!("  Blender Cycles ({}) ...", Path::new(&python).display()));
    let out = std::env::temp_dir().join(format!("livebake-bench-cycles-{}.json", std::process::id()));
    let status = Command::new(&python)
        .arg(CYCLES_SCRIPT)
        .args([scene, points, reference])
        .args(["--texel-size", &TEXEL.to_string(), "--targets", &list.join(","), "--out"])
        .arg(&out)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .status()
        .with_context(|| format!("cannot run {} (from {CYCLES_PYTHON_ENV})", Path::new(&python).display()))?;
    if !status.success() {
        bail!("{CYCLES_SCRIPT} exited with {status} (run it by hand to see why)");
    }
    let text = std::fs::read_to_string(&out).with_context(|| format!("cannot read {}", out.display()))?;
    let _ = std::fs::remove_file(&out);
    let detail: Value = serde_json::from_str(&text).context("Cycles' report")?;
    let times = detail["time_to_error"].as_array().context("Cycles' report has no time_to_error")?;
    let seconds = TARGETS
        .iter()
        .map(|&e| (e, times.iter().find(|t| t["error"].as_f64() == Some(e)).and_then(|t| t["seconds"].as_f64())))
        .collect();
    Ok(CyclesTimes { source: "measured", seconds, detail })
}

fn whole_command(
    livebake: &Path,
    scene: &Path,
    points: &Path,
    reference: &ReferencePoints,
    directions: &[u32],
) -> Result<Vec<(u32, f64, f64)>> {
    let out = std::env::temp_dir().join(format!("livebake-bench-probe-{}.json", std::process::id()));
    let mut curve = Vec::new();
    for &d in directions {
        let t = Instant::now();
        let status = Command::new(livebake)
            .args(["-q", "probe"])
            .arg(scene)
            .arg("--points")
            .arg(points)
            .args(["--texel-size", &TEXEL.to_string(), "--samples", &d.to_string(), "--out"])
            .arg(&out)
            .status()?;
        let secs = seconds(t);
        if !status.success() {
            bail!("livebake probe exited with {status}");
        }
        let doc: Value = serde_json::from_str(&std::fs::read_to_string(&out)?)?;
        let e: Vec<Option<[f64; 3]>> =
            doc["points"].as_array().context("points")?.iter().map(|p| triple(&p["E"])).collect();
        curve.push((d, secs, error_of(reference, &e)?));
    }
    let _ = std::fs::remove_file(&out);
    Ok(curve)
}

/// Bakes the light map with `config` and reads it at the reference points.
fn bake_and_probe(
    scene: &std::sync::Arc<Scene>,
    config: &BakeConfig,
    reference: &ReferencePoints,
) -> Result<(f64, f64)> {
    let t = Instant::now();
    let baked = bake(scene, config, &NoProgress)?;
    let secs = seconds(t);
    let geom = SceneGeometry::new(scene);
    let bvh = Bvh::new(&geom);
    let locator = SurfaceLocator::new(&geom, &bvh);
    let lod = baked.lods.last().context("no LOD")?;
    let sampler = LightmapSampler::new(&baked.atlas, lod);
    let e: Vec<Option<[f64; 3]>> = reference
        .queries
        .iter()
        .map(|q| locator.locate(q.p, q.n).and_then(|at| sampler.irradiance(&at)).ok().map(|e| e.as_dvec3().to_array()))
        .collect();
    Ok((secs, error_of(reference, &e)?))
}

pub fn run(bench: &Bench) -> Result<Value> {
    let (quick, ui) = (bench.quick, bench.ui);
    let dir = assets().join("cornell_2m");
    let (scene_path, points_path) = (dir.join("cornell_2m.gltf"), dir.join("points.json"));
    let scene = std::sync::Arc::new(load_gltf(&scene_path, &LoadOptions::default())?);
    let reference = read_reference(&dir.join("mitsuba_reference.json"))?.in_frame(scene.origin);
    let directions: &[u32] = if quick { &[32, 128, 512] } else { &[16, 32, 64, 128, 256, 512, 1024, 2048] };
    let spps: &[u32] = if quick { &[1, 4] } else { &[1, 2, 4, 8, 16, 32] };

    ui.say("  whole command (livebake probe) ...");
    let cmd = whole_command(bench.livebake, &scene_path, &points_path, &reference, directions)?;
    let cmd_curve: Vec<(f64, f64)> = cmd.iter().map(|&(_, t, e)| (t, e)).collect();
    let cycles = cycles_times(bench, &scene_path, &points_path, &dir.join("mitsuba_reference.json"))?;
    let targets: Vec<Value> = TARGETS
        .iter()
        .map(|&err| {
            let ours = time_to(&cmd_curve, err);
            let theirs = cycles.seconds.iter().find(|&&(e, _)| e == err).and_then(|&(_, t)| t);
            let speedup = ours.zip(theirs).map(|(ours, theirs)| theirs / ours);
            json!({ "error": err, "seconds": ours, "cycles_seconds": theirs, "speedup_vs_cycles": speedup, "goal_speedup": GOAL_SPEEDUP })
        })
        .collect();

    ui.say("  bundle and reference bakes ...");
    let mut base = BakeConfig::default();
    base.atlas.texel_size = Some(TEXEL);
    let mut bundle = Vec::new();
    for &d in directions {
        let (t, e) = bake_and_probe(&scene, &BakeConfig { samples: d, ..base.clone() }, &reference)?;
        bundle.push((d, t, e));
    }
    let mut traced = Vec::new();
    for &spp in spps {
        let config = BakeConfig { samples: spp, backend: BackendKind::Reference, ..base.clone() };
        let (t, e) = bake_and_probe(&scene, &config, &reference)?;
        traced.push((spp, t, e));
    }
    let traced_curve: Vec<(f64, f64)> = traced.iter().map(|&(_, t, e)| (t, e)).collect();
    let equal_time: Vec<Value> = bundle
        .iter()
        .filter_map(|&(d, t, e)| {
            error_at(&traced_curve, t).map(
                |r| json!({ "directions": d, "seconds": t, "bundle_error": e, "reference_error": r, "ratio": r / e }),
            )
        })
        .collect();
    Ok(json!({
        "scene": "cornell_2m/cornell_2m.gltf",
        "texel_size_m": TEXEL,
        "points": reference.queries.len(),
        "whole_command": cmd.iter().map(|&(d, t, e)| json!({ "directions": d, "seconds": t, "error": e })).collect::<Vec<_>>(),
        "time_to_error": targets,
        "cycles_source": cycles.source,
        "cycles": cycles.detail,
        "efficiency": {
            "bundle_bake": bundle.iter().map(|&(d, t, e)| json!({ "directions": d, "seconds": t, "error": e })).collect::<Vec<_>>(),
            "reference_bake": traced.iter().map(|&(s, t, e)| json!({ "paths_per_texel": s, "seconds": t, "error": e })).collect::<Vec<_>>(),
            "at_equal_time": equal_time,
            "goal_ratio": 2.0,
        },
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolation_is_log_log() {
        let c = [(1.0, 0.1), (4.0, 0.05), (16.0, 0.025)];
        assert!((time_to(&c, 0.05).unwrap() - 4.0).abs() < 1e-9);
        // Halfway in log error between 0.1 and 0.05 is halfway in log time: 2 s.
        assert!((time_to(&c, (0.1f64 * 0.05).sqrt()).unwrap() - 2.0).abs() < 1e-9);
        assert_eq!(time_to(&c, 0.01), None);
        assert!((error_at(&c, 2.0).unwrap() - (0.1f64 * 0.05).sqrt()).abs() < 1e-12);
        assert_eq!(error_at(&c, 20.0), None);
    }
}
