//! Direction and region shards against one machine (docs/SHARDS.md): a bake of `ROUNDS`
//! bounce rounds on a real scene, once as `livebake bake --bounce-rounds`, once as N = 4
//! direction shards and once as N = 4 region shards (`--shard-by regions`), run one after
//! another plus a merge per round, each a process of its own (all of a way given one layout
//! file, made by the first that needs it: docs/SHARDS.md). Per process the CPU time
//! (user + system) and peak resident memory come from `wait4`'s resource usage. The single
//! bake runs before, between and after the two ways, and each way is measured against the
//! mean of the two single bakes around it: this machine's speed drifts by 20–30% within
//! minutes, and one single bake before both ways moved the ratio by ±10% between repeats.
//! The figures are medians over the repeats: the ratio of the shards' CPU time (merges
//! included) to the single bake's, the merges' share of the single bake's CPU time, and
//! each shard's peak memory against the single bake's and against the goal for
//! region shards (the single bake's over N plus the geometry's: the same scene baked at
//! [`GEOMETRY_TEXELS`]). Region shards are for texels that outweigh the rest, so their
//! memory is measured again at 4× the texels ([`region_memory`]).

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, Result, bail};
use serde_json::{Value, json};

use super::{Bench, assets};

/// Shards a round is cut into.
const SHARDS: u32 = 4;
/// Bounce rounds baked: the direct light and one bounce.
const ROUNDS: u32 = 2;
/// The goals: CPU time of the shards over the single bake's, the merge's share.
const GOAL_CPU_RATIO: f64 = 1.15;
const GOAL_MERGE_SHARE: f64 = 0.05;

/// What one process used.
#[derive(Clone, Copy, Debug, Default)]
struct Usage {
    cpu_seconds: f64,
    wall_seconds: f64,
    peak_bytes: u64,
}

/// Runs `livebake ARGS` in `dir` and measures it (its own resource usage, from `wait4`).
///
/// The child is forked, not spawned: Linux records in a process's peak resident set, at its
/// `exec`, that of the memory it replaces, and a child spawned with `posix_spawn` (what
/// `Command` uses where it can) replaces this process's own memory, so it reported this
/// process's peak as its floor (the bench's peak: 31 MB after the first repeat, 1.1 GB
/// after the runtime sections). A forked child replaces a copy, whose size is this
/// process's resident set at the fork, kept small by giving freed heap back first.
fn measured(livebake: &Path, dir: &Path, args: &[String]) -> Result<Usage> {
    #[cfg(target_env = "gnu")]
    // SAFETY: malloc_trim only returns free heap memory to the system.
    unsafe {
        libc::malloc_trim(0);
    }
    let t = std::time::Instant::now();
    let mut command = Command::new(livebake);
    command
        .args(args)
        .current_dir(dir)
        .env_remove("RUST_LOG")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped());
    // SAFETY: the hook does nothing (it allocates nothing and takes no lock); its presence
    // makes the standard library fork instead of spawning.
    unsafe {
        use std::os::unix::process::CommandExt;
        command.pre_exec(|| Ok(()));
    }
    let child = command.spawn().context("cannot run livebake")?;
    let pid = child.id() as libc::pid_t;
    let mut status = 0;
    // SAFETY: `rusage` is plain old data that wait4 fills; `pid` is our child, waited for once.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let waited = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
    let wall_seconds = t.elapsed().as_secs_f64();
    if waited != pid {
        bail!("cannot wait for livebake: {}", std::io::Error::last_os_error());
    }
    if !(libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0) {
        let mut stderr = String::new();
        if let Some(mut e) = child.stderr {
            use std::io::Read;
            let _ = e.read_to_string(&mut stderr);
        }
        bail!("livebake {} failed: {}", args.join(" "), stderr.trim());
    }
    let secs = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    Ok(Usage {
        cpu_seconds: secs(usage.ru_utime) + secs(usage.ru_stime),
        wall_seconds,
        // Linux reports the peak in KiB.
        peak_bytes: usage.ru_maxrss as u64 * 1024,
    })
}

/// Shards and merges of one way of sharding: the shards' usage (each, per round) and the
/// merges' (per round).
#[derive(Default)]
struct Way {
    shards: Vec<Usage>,
    merges: Vec<Usage>,
    /// The bundle work of its rounds over the single bake's ([`WORK`]), from the merged
    /// reports.
    work: Vec<f64>,
}

/// The bundle work compared, from the reports' `pass` statistics (summed over the shards
/// by `merge`, over the rounds by `bake --bounce-rounds`): bundle lines resolved, fragments
/// built, and the seconds of the per-triangle phases (analysis, mips, tiling, triangle
/// set-up and count), the resolve and the light pass. A region shard resolves every line
/// that crosses one of its faces, so a line crossing faces of two shares is resolved twice:
/// the first ratio is what that costs, whatever the code does per line.
const WORK: [&str; 5] = ["lines_resolved", "fragments", "per_triangle_seconds", "resolve_seconds", "light_seconds"];

/// [`WORK`]'s figures of one report.
fn work_of(report: &Path) -> Result<[f64; 5]> {
    let text = std::fs::read_to_string(report).with_context(|| format!("cannot read {}", report.display()))?;
    let v: Value = serde_json::from_str(&text).with_context(|| format!("{} is not JSON", report.display()))?;
    let pass = &v["lods"][0]["bundle"]["pass"];
    let f = |k: &str| pass[k].as_f64().with_context(|| format!("{}: no pass.{k}", report.display()));
    Ok([
        f("covered_pixels")?,
        f("fragments")?,
        f("analysis_seconds")? + f("mip_seconds")? + f("subdivision_seconds")? + f("build_seconds")?,
        f("resolve_seconds")?,
        f("light_seconds")?,
    ])
}

/// One bake every way: the single bake's usage (before, between and after the two ways),
/// the direction shards' and the region shards', and the region shards' merged light map's
/// worst relative difference per texel from the single bake's.
struct Pair {
    singles: [Usage; 3],
    directions: Way,
    regions: Way,
    regions_worst: f64,
}

impl Pair {
    /// The single bake's CPU time a way is measured against: the mean of the two runs
    /// around it (way `k` of [`WAYS`] ran between single bakes `k` and `k + 1`).
    fn single_cpu_around(&self, way: usize) -> f64 {
        (self.singles[way].cpu_seconds + self.singles[way + 1].cpu_seconds) / 2.0
    }
}

/// The ways of sharding measured (`--shard-by`).
const WAYS: [&str; 2] = ["directions", "regions"];

/// The arguments of `livebake bake SCENE ...EXTRA`, quiet.
fn bake_args(scene_args: &[String], extra: &[&str]) -> Vec<String> {
    let mut a = vec!["-q".to_string(), "bake".into()];
    a.extend(scene_args.iter().cloned());
    a.extend(extra.iter().map(|s| s.to_string()));
    a
}

/// The scene's arguments at a texel budget and a number of directions.
fn scene_args(scene: &Path, budget: u64, samples: u32) -> Vec<String> {
    let scene = scene.to_string_lossy().into_owned();
    vec![scene, "--texel-budget".into(), budget.to_string(), "--samples".into(), samples.to_string()]
}

/// The shards of every round sharded `by` (`--shard-by`), one after another, each round
/// merged before the next reads it (into `{by}-m{round}`). Every process is given the way's
/// layout file (docs/SHARDS.md "The layout file"), made anew by the first that needs it.
fn shard_rounds(lb: &Path, dir: &Path, scene_args: &[String], by: &str) -> Result<Way> {
    let mut way = Way::default();
    let layout = format!("{by}-layout.lblayout");
    match std::fs::remove_file(dir.join(&layout)) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            return Err(e).with_context(|| format!("cannot remove {layout}"));
        }
        _ => {}
    }
    for round in 1..=ROUNDS {
        let out = format!("{by}-r{round}");
        let previous = format!("{by}-m{}/merged.lbshard", round - 1);
        for i in 0..SHARDS {
            let share = format!("{i}/{SHARDS}");
            let mut extra =
                vec!["--shard", share.as_str(), "--shard-by", by, "--out", out.as_str(), "--layout", layout.as_str()];
            if round > 1 {
                extra.extend(["--previous", previous.as_str()]);
            }
            way.shards.push(measured(lb, dir, &bake_args(scene_args, &extra))?);
        }
        let mut merge = vec!["-q".to_string(), "merge".into()];
        merge.extend((0..SHARDS).map(|i| format!("{out}/{}", livebake::shard::shard_file_name(i, SHARDS))));
        merge.extend(["--out".into(), format!("{by}-m{round}"), "--layout".into(), layout.clone()]);
        way.merges.push(measured(lb, dir, &merge)?);
    }
    Ok(way)
}

fn bake_both(bench: &Bench, dir: &Path, scene_args: &[String]) -> Result<Pair> {
    let lb = bench.livebake;
    let rounds = ROUNDS.to_string();
    let single = |out: &str| measured(lb, dir, &bake_args(scene_args, &["--bounce-rounds", &rounds, "--out", out]));
    let mut singles = vec![single("single")?];
    let mut ways = Vec::new();
    for by in WAYS {
        let mut way = shard_rounds(lb, dir, scene_args, by)?;
        let mut work = [0.0; 5];
        for round in 1..=ROUNDS {
            for (w, x) in work.iter_mut().zip(work_of(&dir.join(format!("{by}-m{round}/report.json")))?) {
                *w += x;
            }
        }
        let one = work_of(&dir.join("single/report.json"))?;
        way.work = work.iter().zip(one).map(|(w, s)| w / s).collect();
        ways.push(way);
        singles.push(single(&format!("single-after-{by}"))?);
    }
    let map = |d: &str| -> Result<Vec<f32>> {
        let path = dir.join(d).join("lightmap_lod0.exr");
        let img = image::open(&path).with_context(|| format!("cannot read {}", path.display()))?.into_rgb32f();
        Ok(img.into_raw())
    };
    let regions_worst = worst_relative(&map("single")?, &map(&format!("regions-m{ROUNDS}"))?);
    let regions = ways.pop().unwrap_or_default();
    let directions = ways.pop().unwrap_or_default();
    let singles = singles.try_into().map_err(|_| anyhow::anyhow!("one single bake before and one after each way"))?;
    Ok(Pair { singles, directions, regions, regions_worst })
}

/// Largest relative difference of two maps' values (both zero: none).
fn worst_relative(a: &[f32], b: &[f32]) -> f64 {
    if a.len() != b.len() {
        return f64::INFINITY;
    }
    a.iter().zip(b).fold(0.0f64, |w, (&x, &y)| {
        let scale = x.abs().max(y.abs()) as f64;
        if scale > 0.0 { w.max((x as f64 - y as f64).abs() / scale) } else { w }
    })
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

pub fn run(bench: &Bench) -> Result<Value> {
    let (scene, budget, samples, repeats): (PathBuf, u64, u32, usize) = if bench.quick {
        (assets().join("cornell_box/cornellBox-2.79-Cycles-gltf.gltf"), 20_000, 32, 1)
    } else {
        // The default bake's texels and directions: the fixed costs every process pays
        // (load, atlas, BVH, texel map; the merge's write) weigh as they would in use.
        (assets().join("van_gogh_room/van_gogh_room_lit.gltf"), 500_000, 256, 3)
    };
    let args = scene_args(&scene, budget, samples);
    let dir = tempfile_dir()?;
    let mut pairs = Vec::new();
    let mut geometry = Vec::new();
    for r in 0..repeats {
        bench.ui.status(&format!("scale_out: repeat {} of {repeats}", r + 1));
        let pair = bake_both(bench, &dir, &args);
        let tiny = pair.as_ref().ok().map(|_| geometry_usage(bench.livebake, &dir, &scene, samples));
        // Every file of the repeat goes, whatever happened.
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir)?;
        pairs.push(pair?);
        geometry.extend(tiny.transpose()?);
    }
    let geometry_peak = median(geometry.iter().map(|u| u.peak_bytes as f64).collect());
    // Where the texels outweigh what every process holds: what region shards are for.
    bench.ui.status("scale_out: region shards' memory at 4× the texels");
    let memory = region_memory(bench.livebake, &dir, &scene, budget * 4, samples);
    let _ = std::fs::remove_dir_all(&dir);
    let memory = memory?;
    let cpu = |u: &[Usage]| u.iter().map(|u| u.cpu_seconds).sum::<f64>();
    let singles = || pairs.iter().flat_map(|p| &p.singles);
    let single_peak = median(singles().map(|u| u.peak_bytes as f64).collect());
    let single_cpu = median(singles().map(|u| u.cpu_seconds).collect());
    let summary = |k: usize, way: &dyn Fn(&Pair) -> &Way| {
        let ratio = median(
            pairs.iter().map(|p| (cpu(&way(p).shards) + cpu(&way(p).merges)) / p.single_cpu_around(k)).collect(),
        );
        let merge_share = median(pairs.iter().map(|p| cpu(&way(p).merges) / p.single_cpu_around(k)).collect());
        let peak = |u: &[Usage]| u.iter().map(|u| u.peak_bytes).max().unwrap_or(0) as f64;
        let shard_peak = median(pairs.iter().map(|p| peak(&way(p).shards)).collect());
        let merge_peak = median(pairs.iter().map(|p| peak(&way(p).merges)).collect());
        let work: serde_json::Map<String, Value> = WORK
            .iter()
            .enumerate()
            .map(|(i, k)| {
                (k.to_string(), json!(median(pairs.iter().filter_map(|p| way(p).work.get(i).copied()).collect())))
            })
            .collect();
        json!({
            "work_over_single": work,
            "shards_cpu_seconds": median(pairs.iter().map(|p| cpu(&way(p).shards)).collect()),
            "merge_cpu_seconds": median(pairs.iter().map(|p| cpu(&way(p).merges)).collect()),
            "cpu_ratio": ratio,
            "merge_share": merge_share,
            "shard_peak_bytes": shard_peak,
            "merge_peak_bytes": merge_peak,
            "shard_peak_over_single": shard_peak / single_peak,
            "shard_peak_over_goal": shard_peak / (single_peak / SHARDS as f64 + geometry_peak),
        })
    };
    let directions = summary(0, &|p: &Pair| &p.directions);
    let regions = summary(1, &|p: &Pair| &p.regions);
    let runs: Vec<Value> = pairs
        .iter()
        .map(|p| {
            let way = |w: &Way| {
                json!({
                    "shards": w.shards.iter().map(usage_json).collect::<Vec<_>>(),
                    "merges": w.merges.iter().map(usage_json).collect::<Vec<_>>(),
                })
            };
            json!({
                "singles": p.singles.iter().map(usage_json).collect::<Vec<_>>(),
                "directions": way(&p.directions),
                "regions": way(&p.regions),
                "regions_worst_relative_difference": p.regions_worst,
            })
        })
        .collect();
    let field = |v: &Value, k: &str| v.get(k).cloned().unwrap_or(Value::Null);
    Ok(json!({
        "scene": scene.file_name().map(|f| f.to_string_lossy().into_owned()),
        "texel_budget": budget,
        "samples": samples,
        "rounds": ROUNDS,
        "shards": SHARDS,
        "repeats": repeats,
        "single_cpu_seconds": single_cpu,
        "shards_cpu_seconds": field(&directions, "shards_cpu_seconds"),
        "merge_cpu_seconds": field(&directions, "merge_cpu_seconds"),
        "cpu_ratio": field(&directions, "cpu_ratio"),
        "goal_cpu_ratio": GOAL_CPU_RATIO,
        "merge_share": field(&directions, "merge_share"),
        "goal_merge_share": GOAL_MERGE_SHARE,
        "single_peak_bytes": single_peak,
        "shard_peak_bytes": field(&directions, "shard_peak_bytes"),
        "merge_peak_bytes": field(&directions, "merge_peak_bytes"),
        "shard_peak_over_single": field(&directions, "shard_peak_over_single"),
        "work_over_single": field(&directions, "work_over_single"),
        "regions": regions,
        "goal_region_peak_over_single": 1.0 / SHARDS as f64,
        "geometry_peak_bytes": geometry_peak,
        "region_peak_goal_bytes": single_peak / SHARDS as f64 + geometry_peak,
        "region_memory": memory,
        "regions_worst_relative_difference": median(pairs.iter().map(|p| p.regions_worst).collect()),
        "runs": runs,
    }))
}

/// Texels of the bake that stands for "the geometry" of the memory goal (1/N of the
/// single bake's peak plus the geometry): what a process holds for the scene, its BVH and
/// atlas and the bundles' buffers of a tiny map.
const GEOMETRY_TEXELS: u64 = 2_000;

/// A one-round bake of `scene` at [`GEOMETRY_TEXELS`].
fn geometry_usage(lb: &Path, dir: &Path, scene: &Path, samples: u32) -> Result<Usage> {
    let args = scene_args(scene, GEOMETRY_TEXELS, samples);
    measured(lb, dir, &bake_args(&args, &["--bounce-rounds", "1", "--out", "geometry"]))
}

/// Region shards' peak memory, round by round, against the goal at `budget` texels:
/// the single bake's peak over N plus the geometry's ([`geometry_usage`]). One run each.
fn region_memory(lb: &Path, dir: &Path, scene: &Path, budget: u64, samples: u32) -> Result<Value> {
    let dir = dir.join("memory");
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let args = scene_args(scene, budget, samples);
    let rounds = ROUNDS.to_string();
    let single = measured(lb, &dir, &bake_args(&args, &["--bounce-rounds", &rounds, "--out", "single"]))?;
    let geometry = geometry_usage(lb, &dir, scene, samples)?;
    let way = shard_rounds(lb, &dir, &args, "regions")?;
    let per_round: Vec<u64> =
        way.shards.chunks(SHARDS as usize).map(|r| r.iter().map(|u| u.peak_bytes).max().unwrap_or(0)).collect();
    let goal = single.peak_bytes as f64 / SHARDS as f64 + geometry.peak_bytes as f64;
    let largest = per_round.iter().copied().max().unwrap_or(0) as f64;
    Ok(json!({
        "texel_budget": budget,
        "single_peak_bytes": single.peak_bytes,
        "geometry_peak_bytes": geometry.peak_bytes,
        "goal_bytes": goal,
        "shard_peak_bytes_per_round": per_round,
        "shard_peak_over_goal": largest / goal,
        "shard_peak_over_single": largest / single.peak_bytes as f64,
        "shards": way.shards.iter().map(usage_json).collect::<Vec<_>>(),
    }))
}

fn usage_json(u: &Usage) -> Value {
    json!({ "cpu_seconds": u.cpu_seconds, "wall_seconds": u.wall_seconds, "peak_bytes": u.peak_bytes })
}

fn tempfile_dir() -> Result<PathBuf> {
    let dir = std::env::temp_dir().join(format!("livebake-bench-scale-out-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    Ok(dir)
}
