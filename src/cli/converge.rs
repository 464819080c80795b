//! `livebake converge`: bakes LOD 0 progressively (directions keep accumulating, nothing
//! restarts) and measures the relative RMS error of the running light map against a
//! reference as it goes, for pipelines that must know a bake has converged.
//!
//! The error is measured at the reference's points, read as `probe` reads a finished bake:
//! the surface under each point ([`SurfaceLocator`]) and the bilinear taps of its side's
//! chart ([`LightmapLookup`]), here read from the running estimate. It is checked against
//! `--until` after every batch and recorded at doubling direction counts and at the end.
//!
//! The clock: wall seconds since the command started, loading the scene and building the
//! atlas, texel map and BVHs included; tracing an in-crate reference (`--reference-spp`) is
//! left out (it is the yardstick, not the bake) and reported on its own.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use clap::Args;
use glam::{DVec3, Vec3};
use serde::Serialize;
use serde_json::{Value, json};

use livebake::atlas::{Atlas, TexelMap};
use livebake::bake::bundle::{BatchDone, bake_lod_observed};
use livebake::bake::{BakeConfig, BakeError, MAX_SAMPLES, check_lod_sizes, check_memory, check_node_capacity};
use livebake::bundle::progressive::ProgressiveEstimate;
use livebake::bundle::{BackendProvider, BundleScene};
use livebake::cpu::CpuProvider;
use livebake::output::{write_json, write_rgb8_png, write_text};
use livebake::probe::{BilinearTaps, LightmapLookup, SurfaceLocator};
use livebake::progress::NoProgress;
use livebake::reference::punctual::is_buried;
use livebake::reference::{Bvh, ReferenceTracer};
use livebake::sampling::Rng;
use livebake::scene::{Scene, SceneGeometry};

use super::SceneOptions;
use super::bake::load_scene;
use super::options::Backend;
use super::progress::Ui;
use livebake::plot;
use livebake::points::{Query, ReferencePoints, read_points, read_reference};

/// LOD-0 texels the in-crate reference is traced at when no `--points` are given: the
/// error figure then averages 768 channel values, a few per cent noise on the figure itself.
const SAMPLED_TEXELS: usize = 256;
/// Paths per point of the in-crate reference by default (probe's default: ~1% noise per
/// point on a lit interior, and what is left is removed in quadrature).
const DEFAULT_REFERENCE_SPP: u32 = 1024;
/// Random stream of the texel sample (the seed is `--seed`).
const TEXEL_SAMPLE_STREAM: u64 = 0xC0_4E26_E5A3;
/// How far a `--points` point may be from the `--reference` point it stands for.
const SAME_POINT: f32 = 1e-5;

const CLOCK: &str = "wall seconds since the command started: loading the scene and building the atlas, \
                     texel map and BVHs included; tracing an in-crate reference excluded";

/// Options of `converge` (with the scene options of `bake`).
#[derive(Args, Debug, Clone)]
pub struct ConvergeOptions {
    /// Reference irradiance at points, in probe's output format
    /// ({"points":[{"p":..,"n":..,"E":[r,g,b],"E_stderr":[r,g,b]}, ...]}; E_stderr optional),
    /// e.g. from the Mitsuba tool. Default: the in-crate path tracer (--reference-spp).
    #[arg(long, value_name = "REF.json", conflicts_with = "reference_spp")]
    pub reference: Option<PathBuf>,
    /// Trace the reference with the in-crate path tracer, N paths per point: at --points, or
    /// at 256 LOD-0 texels sampled with --seed [default: 1024].
    #[arg(long, value_name = "N")]
    pub reference_spp: Option<u32>,
    /// Points to measure at (probe's input format). With --reference they must be its points.
    #[arg(long, value_name = "IN.json")]
    pub points: Option<PathBuf>,
    /// Relative RMS error to reach: exit 0 when reached within the budget, 3 when the budget
    /// (or --samples, the most directions) ran out first.
    // Negative numbers are values, refused with a message about them (not as unknown flags).
    #[arg(long, value_name = "REL_RMS", allow_negative_numbers = true)]
    pub until: Option<f64>,
    /// Seconds on the command's clock (load included) after which no new batch starts.
    #[arg(long, value_name = "SECONDS", allow_negative_numbers = true)]
    pub budget: Option<f64>,
    /// Output directory: convergence.json, convergence.csv, convergence.png (and
    /// reference.json when the reference was traced here).
    #[arg(long, default_value = "out")]
    pub out: PathBuf,
}

/// `converge` stopped before reaching `--until`: not a failure of the command, so it is
/// told apart from one by its exit status.
#[derive(Debug, thiserror::Error)]
#[error(
    "not converged: relative RMS error {last:.5} is above the target {target} after {directions} directions and {seconds:.2} s ({why})"
)]
pub struct NotConverged {
    pub last: f64,
    pub target: f64,
    pub directions: u64,
    pub seconds: f64,
    pub why: String,
}

impl NotConverged {
    pub const EXIT_STATUS: u8 = 3;
}

#[derive(Clone, Copy, Debug, Serialize)]
struct Step {
    seconds: f64,
    directions: u64,
    rel_rms: f64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
enum Stop {
    /// `--until` reached.
    Target,
    /// `--budget` ran out.
    Budget,
    /// `--samples` directions done.
    MaxDirections,
}

/// The command's clock: since it started, less the time spent tracing a reference.
struct Clock {
    started: Instant,
    excluded: Duration,
}

impl Clock {
    fn seconds(&self) -> f64 {
        self.started.elapsed().saturating_sub(self.excluded).as_secs_f64()
    }
}

pub fn run(scene_path: &Path, options: &SceneOptions, converge: &ConvergeOptions, ui: &Ui) -> Result<()> {
    let mut clock = Clock { started: Instant::now(), excluded: Duration::ZERO };
    let config = bake_config(options, converge)?;
    let limits = Limits { until: converge.until, budget: converge.budget, max_directions: config.samples as u64 };
    // Files first: a bad one fails before any work.
    let file_reference = converge.reference.as_deref().map(read_reference).transpose()?;
    let points_file = converge.points.as_deref().map(read_points).transpose()?;
    if let (Some(reference), Some(points)) = (&file_reference, &points_file) {
        // In the files' own coordinates: a scene's origin moves both alike.
        let (reference, points) = (reference.in_frame(DVec3::ZERO), points.queries(DVec3::ZERO));
        same_points(&reference, converge.reference.as_deref(), &points, converge.points.as_deref())?;
    }

    let (scene, _) = load_scene(scene_path, options, None)?;
    let file_reference = file_reference.map(|r| r.in_frame(scene.origin));
    let points = points_file.map(|p| p.queries(scene.origin));
    let geom = Arc::new(SceneGeometry::new(&scene));
    let atlas = Arc::new(Atlas::build(&scene, &geom, &config.atlas).map_err(BakeError::from)?);
    check_lod_sizes(&atlas, 1)?;
    // As `bake` does (one LOD; a light pass assumed: the estimate bounds the bake's part).
    let traits = livebake::bake::memory::SceneTraits::MOST.with_masks(&scene);
    check_memory(&atlas, &BakeConfig { lods: 1, ..config.clone() }, traits)?;
    let texels = TexelMap::build(&scene, &geom, &atlas, 0);
    let bvh = Bvh::for_scene(&scene, &geom);
    check_node_capacity(&bvh, &config.bundle_config())?;

    // Located as probe locates (on the geometry without alpha cut-outs).
    let locate_bvh = Bvh::new(&geom);
    let locator = SurfaceLocator::new(&geom, &locate_bvh);
    let lookup = LightmapLookup::new(&atlas, &texels);
    let taps_at = |q: &Query| locator.locate(q.p, q.n).and_then(|at| lookup.taps(&at));
    let sampled;
    let (queries, taps): (&[Query], Vec<BilinearTaps>) = match (&file_reference, &points) {
        (Some(ReferencePoints { queries, .. }), _) | (None, Some(queries)) => {
            let taps = queries
                .iter()
                .enumerate()
                .map(|(k, q)| {
                    taps_at(q).with_context(|| {
                        format!("point {k} (p {:?}, n {:?}) has no light map under it", q.p.to_array(), q.n.to_array())
                    })
                })
                .collect::<Result<Vec<BilinearTaps>>>()
                .context("mismatched points: not every point is on a light-mapped surface of the scene")?;
            (queries, taps)
        }
        (None, None) => {
            // A texel whose centre lies in a cut-out (`MASK` below its cutoff), or inside
            // closed geometry (a face running through a solid: `is_buried`), has no surface
            // there to measure: a reference sees nothing or the solid's inside (E = 0), while
            // the bundles light the texel from its visible part. On AlphaBlendModeTest one
            // such centre (the bed's top, 2 mm inside its back panel: 1.2 against Mitsuba's
            // 0) takes the relative RMS error at 256 points from 1.2 % to 3.1 %.
            let epsilon = livebake::reference::ray_epsilon(&scene);
            let exists = |q: &Query| {
                locator.locate(q.p, q.n).is_ok_and(|at| {
                    bvh.alpha().opaque_at(at.tri, at.u, at.v)
                        && !is_buried(&scene, &geom, &bvh, at.tri, q.p, q.n.normalize(), epsilon)
                })
            };
            let (q, taps) =
                sample_texels(&texels, SAMPLED_TEXELS, config.seed, |q| exists(q).then(|| taps_at(q).ok()).flatten());
            sampled = q;
            (&sampled, taps)
        }
    };
    if queries.is_empty() {
        bail!("there are no points to measure the error at");
    }

    let traced = file_reference.is_none();
    let (reference, reference_info) = match file_reference {
        Some(reference) => {
            let path = converge.reference.as_deref().unwrap_or(Path::new(""));
            let info = json!({ "kind": "file", "path": path.display().to_string(), "points": reference.e.len() });
            (reference, info)
        }
        None => {
            let spp = converge.reference_spp.unwrap_or(DEFAULT_REFERENCE_SPP);
            let t = Instant::now();
            let reference = trace_reference(&scene, queries, spp, &config, ui);
            clock.excluded += t.elapsed();
            let at = match &converge.points {
                Some(p) => json!({ "points_file": p.display().to_string() }),
                None => json!({ "sampled_lod0_texels": SAMPLED_TEXELS, "seed": config.seed }),
            };
            let info = json!({
                "kind": "path_tracer",
                "paths_per_point": spp,
                "points": reference.e.len(),
                "at": at,
                "seconds": t.elapsed().as_secs_f64(),
                "file": "reference.json",
            });
            (reference, info)
        }
    };
    if reference.e.iter().all(|e| *e == DVec3::ZERO) {
        bail!("the reference's E is zero at every point: there is no relative error to measure");
    }

    let bundle = Arc::new(BundleScene::new(scene.clone(), geom.clone(), atlas.clone(), config.bundle_config()));
    let threads = config.threads();
    let mut backend =
        CpuProvider::new().backend(&bundle, threads).map_err(|e| anyhow!("the bundle backend is unavailable: {e}"))?;
    let error_of = |estimate: &ProgressiveEstimate| {
        reference.relative_rms(|k| taps[k].read(|t| estimate.irradiance_of(t)).as_dvec3())
    };
    ui.begin_phase("converge", if options.samples.is_some() { limits.max_directions } else { 0 });
    let mut run = ProgressiveRun::new(&limits, &clock, &error_of, ui);
    let never = AtomicBool::new(false);
    let baked =
        bake_lod_observed(&bundle, &bvh, &mut backend, &texels, None, threads, &NoProgress, &never, &mut |done| {
            run.batch_done(done)
        });
    ui.end_phase();
    let Ok(baked) = baked else { unreachable!("converge never raises the cancel flag") };
    if baked.stats.pass.unplanned_directions > 0 {
        let (count, directions) = (baked.stats.pass.unplanned_directions, baked.stats.directions);
        return Err(BakeError::UnplannedDirections { lod: 0, count, directions }.into());
    }
    let (steps, stop) = (run.steps, run.stop);
    let last = *steps.last().context("the bake ran no batch")?;
    if let Some(s) = steps.iter().find(|s| !s.rel_rms.is_finite()) {
        bail!(
            "the error after {} directions is {} (the light overflowed f32); nothing was written",
            s.directions,
            s.rel_rms
        );
    }
    if reference.e.iter().any(|e| !e.is_finite()) {
        bail!("the reference has non-finite irradiance (the light overflowed f32); nothing was written");
    }

    std::fs::create_dir_all(&converge.out)
        .with_context(|| format!("cannot create output directory {}", converge.out.display()))?;
    let mut files = Vec::new();
    if traced {
        let path = converge.out.join("reference.json");
        write_json(&path, &reference_json(&reference, &scene, scene_path, &reference_info, config.seed))?;
        files.push(path);
    }
    let doc = json!({
        "scene": scene_path.display().to_string(),
        "clock": CLOCK,
        "options": {
            "bake": bake_options_json(&config)?,
            "max_directions": options.samples,
            "budget_seconds": limits.budget,
            "until": limits.until,
            "seed": config.seed,
        },
        "lod0": {
            "width": texels.width,
            "height": texels.height,
            "texel_size_m": atlas.texel_size,
            "texels": texels.len(),
        },
        "reference": reference_info,
        "target": limits.until,
        "reached": limits.until.map(|_| stop == Stop::Target),
        "stopped_by": stop,
        "seconds": last.seconds,
        "directions": last.directions,
        "rel_rms": last.rel_rms,
        "steps": steps,
    });
    let name = scene_path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let title = format!("livebake converge: {name}, {} LOD-0 texels", texels.len());
    files.extend(write_curve(&converge.out, &doc, &steps, &title, limits.until)?);

    summarise(ui, scene_path, &texels, atlas.texel_size, &reference_info, &steps, &files);
    match limits.until {
        Some(target) if stop != Stop::Target => Err(NotConverged {
            last: last.rel_rms,
            target,
            directions: last.directions,
            seconds: last.seconds,
            why: match stop {
                Stop::Budget => format!("the {} s budget ran out", limits.budget.unwrap_or_default()),
                _ => format!("--samples {} directions done", limits.max_directions),
            },
        }
        .into()),
        Some(target) => {
            ui.say(format!("  reached {target} after {} directions, {:.2} s", last.directions, last.seconds));
            Ok(())
        }
        None => Ok(()),
    }
}

/// When a progressive run ends.
struct Limits {
    until: Option<f64>,
    budget: Option<f64>,
    max_directions: u64,
}

/// The observer of the progressive bake: measures after every batch, records the steps and
/// says when to stop.
struct ProgressiveRun<'a> {
    limits: &'a Limits,
    clock: &'a Clock,
    error_of: &'a dyn Fn(&ProgressiveEstimate) -> f64,
    ui: &'a Ui,
    steps: Vec<Step>,
    next_step: u64,
    stop: Stop,
}

impl<'a> ProgressiveRun<'a> {
    fn new(
        limits: &'a Limits,
        clock: &'a Clock,
        error_of: &'a dyn Fn(&ProgressiveEstimate) -> f64,
        ui: &'a Ui,
    ) -> Self {
        ProgressiveRun { limits, clock, error_of, ui, steps: Vec::new(), next_step: 1, stop: Stop::MaxDirections }
    }

    fn batch_done(&mut self, done: &BatchDone) -> ControlFlow<()> {
        let seconds = self.clock.seconds();
        let rel_rms = (self.error_of)(done.estimate);
        let limits = self.limits;
        let within_budget = limits.budget.is_none_or(|b| seconds < b);
        let ended = if limits.until.is_some_and(|u| rel_rms <= u) && within_budget {
            Some(Stop::Target)
        } else if !within_budget {
            Some(Stop::Budget)
        } else {
            (done.directions >= limits.max_directions).then_some(Stop::MaxDirections)
        };
        if ended.is_some() || done.directions >= self.next_step {
            self.steps.push(Step { seconds, directions: done.directions, rel_rms });
            self.next_step = 2 * done.directions;
        }
        self.ui.reached_at(done.directions);
        self.ui.status(&format!("{} directions, {seconds:.1} s, rel. RMS {:.2}%", done.directions, 100.0 * rel_rms));
        match ended {
            Some(why) => {
                self.stop = why;
                ControlFlow::Break(())
            }
            None => ControlFlow::Continue(()),
        }
    }
}

/// The bake options as JSON, less what converge grows or sets apart: the direction count
/// (`max_directions`) and the bundle's copy of the seed (`seed`).
fn bake_options_json(config: &BakeConfig) -> Result<Value> {
    let mut value = serde_json::to_value(config)?;
    if let Some(o) = value.as_object_mut() {
        o.remove("samples");
    }
    if let Some(b) = value.get_mut("bundle").and_then(Value::as_object_mut) {
        b.remove("directions");
        b.remove("seed");
    }
    Ok(value)
}

/// DIR/convergence.json, .csv and .png.
fn write_curve(dir: &Path, doc: &Value, steps: &[Step], title: &str, until: Option<f64>) -> Result<[PathBuf; 3]> {
    let json_path = dir.join("convergence.json");
    write_json(&json_path, doc)?;
    let mut csv = String::from("seconds,directions,rel_rms\n");
    for s in steps {
        csv.push_str(&format!("{},{},{}\n", s.seconds, s.directions, s.rel_rms));
    }
    let csv_path = dir.join("convergence.csv");
    write_text(&csv_path, &csv)?;
    let curve: Vec<(f64, f64)> = steps.iter().map(|s| (s.seconds, s.rel_rms)).collect();
    let png_path = dir.join("convergence.png");
    let series = [plot::Series { label: "bundle bake", points: &curve }];
    let x_desc = "seconds since the command started (load included)";
    write_rgb8_png(&png_path, plot::error_curves(title, x_desc, &series, until)?)?;
    Ok([json_path, csv_path, png_path])
}

/// The bake configuration of LOD 0 with `--samples` as the most directions (none: the most
/// any bake may take, hours of directions, so the budget ends the run), and the checks of
/// converge's own options.
fn bake_config(options: &SceneOptions, converge: &ConvergeOptions) -> Result<BakeConfig> {
    if options.backend != Backend::Cpu {
        bail!(
            "converge measures the CPU bundle bake (--backend cpu); the reference tracer is what --reference-spp uses"
        );
    }
    if options.lods.is_some_and(|k| k != 1) {
        bail!(
            "converge bakes LOD 0 only (finer levels are baked from a converged coarser one, not progressively); \
             choose its resolution with --texel-size or --texel-budget"
        );
    }
    if let Some(u) = converge.until
        && !(u.is_finite() && u > 0.0)
    {
        bail!("--until must be a positive relative error (e.g. 0.05 for 5%), got {u}");
    }
    if let Some(b) = converge.budget
        && !(b.is_finite() && b > 0.0)
    {
        bail!("--budget must be a positive number of seconds, got {b}");
    }
    if converge.reference_spp == Some(0) {
        bail!("--reference-spp must be at least 1");
    }
    if converge.budget.is_none() && options.samples.is_none() {
        bail!(
            "converge needs --budget SECONDS or --samples N (the most directions) to end: an unreachable --until would run forever"
        );
    }
    let config = options.bake_config(|_| MAX_SAMPLES)?;
    config.validate()?;
    Ok(config)
}

/// `--points` given with `--reference` must be the reference's points, in its order.
fn same_points(
    reference: &ReferencePoints,
    ref_path: Option<&Path>,
    points: &[Query],
    points_path: Option<&Path>,
) -> Result<()> {
    let (ref_path, points_path) = (ref_path.unwrap_or(Path::new("")), points_path.unwrap_or(Path::new("")));
    if points.len() != reference.queries.len() {
        bail!(
            "mismatched points: {} has {} points, the reference {} has {}",
            points_path.display(),
            points.len(),
            ref_path.display(),
            reference.queries.len()
        );
    }
    let close = |a: Vec3, b: Vec3| (a - b).abs().max_element() <= SAME_POINT;
    for (k, (p, r)) in points.iter().zip(&reference.queries).enumerate() {
        if !close(p.p, r.p) || !close(p.n.normalize_or_zero(), r.n.normalize_or_zero()) {
            bail!(
                "mismatched points: point {k} of {} (p {:?}, n {:?}) is not point {k} of the reference {} (p {:?}, n {:?})",
                points_path.display(),
                p.p.to_array(),
                p.n.to_array(),
                ref_path.display(),
                r.p.to_array(),
                r.n.to_array()
            );
        }
    }
    Ok(())
}

/// `count` distinct LOD-0 texels (all when there are fewer) drawn uniformly with `seed` (a
/// partial Fisher–Yates shuffle), as points on their faces with their sides' normals, and
/// their taps. Texels where `taps` finds no light map are passed over: the centre of a texel
/// under an object standing on its face (coplanar with the object's single-sided bottom) is
/// located on that bottom's back, as probe would locate it.
fn sample_texels(
    texels: &TexelMap,
    count: usize,
    seed: u64,
    taps: impl Fn(&Query) -> Option<BilinearTaps>,
) -> (Vec<Query>, Vec<BilinearTaps>) {
    let n = texels.len();
    let mut order: Vec<u32> = (0..n as u32).collect();
    let mut rng = Rng::new(seed, TEXEL_SAMPLE_STREAM);
    let mut chosen = Vec::new();
    for i in 0..n {
        if chosen.len() == count {
            break;
        }
        let j = i + ((rng.next_f64() * (n - i) as f64) as usize).min(n - i - 1);
        order.swap(i, j);
        let t = order[i] as usize;
        let q = Query { p: texels.position[t], n: texels.normal[t] };
        if let Some(taps) = taps(&q) {
            chosen.push((t, q, taps));
        }
    }
    chosen.sort_unstable_by_key(|c| c.0);
    chosen.into_iter().map(|(_, q, taps)| (q, taps)).unzip()
}

/// E and its standard error at every query, `spp` paths each, as `probe --backend
/// reference` traces them (at the point, over the hemisphere of its normal, seed `--seed`).
fn trace_reference(
    scene: &livebake::scene::Scene,
    queries: &[Query],
    spp: u32,
    config: &BakeConfig,
    ui: &Ui,
) -> ReferencePoints {
    let tracer = ReferenceTracer::new(scene).with_threads(config.threads);
    let at: Vec<(Vec3, Vec3)> = queries.iter().map(|q| (q.p, q.n.normalize())).collect();
    ui.begin_phase("reference", at.len() as u64);
    let (estimates, _) = tracer.irradiance_batch_estimates(&at, spp, config.seed, &|done| ui.reached_at(done as u64));
    ui.end_phase();
    ReferencePoints {
        queries: queries.to_vec(),
        e: estimates.iter().map(|e| e.e.as_dvec3()).collect(),
        stderr: estimates.iter().map(|e| e.stderr.as_dvec3()).collect(),
    }
}

/// The traced reference in probe's output format (points in the file's coordinates), to pass
/// back as `--reference`.
fn reference_json(reference: &ReferencePoints, scene: &Scene, path: &Path, info: &Value, seed: u64) -> Value {
    let points: Vec<Value> = reference
        .queries
        .iter()
        .zip(reference.e.iter().zip(&reference.stderr))
        .map(|(q, (e, s))| {
            json!({ "p": scene.to_file(q.p).to_array(), "n": q.n.to_array(), "E": e.to_array(), "E_stderr": s.to_array() })
        })
        .collect();
    json!({
        "scene": path.display().to_string(),
        "tracer": "livebake reference path tracer",
        "paths_per_point": info["paths_per_point"],
        "seed": seed,
        "points": points,
    })
}

fn summarise(
    ui: &Ui,
    scene: &Path,
    texels: &TexelMap,
    texel_size: f32,
    reference: &Value,
    steps: &[Step],
    files: &[PathBuf],
) {
    ui.say(format!(
        "livebake converge: {}, LOD 0 {}×{} at {:.2} cm/texel, {} texels; reference: {} at {} points",
        scene.display(),
        texels.width,
        texels.height,
        texel_size * 100.0,
        texels.len(),
        reference["kind"].as_str().unwrap_or_default(),
        reference["points"]
    ));
    ui.say(format!("  {:>10}  {:>9}  {:>9}", "directions", "seconds", "rel. RMS"));
    for s in steps {
        ui.say(format!("  {:>10}  {:>9.3}  {:>8.3}%", s.directions, s.seconds, 100.0 * s.rel_rms));
    }
    for f in files {
        ui.say(format!("  wrote {}", f.display()));
    }
}
