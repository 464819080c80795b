//! `livebake run`: the live runtime, headless. Refines around a camera (fixed, or moving
//! along a path) for a while, streams events as JSON lines, and at the end writes the light
//! maps as shown, the cell table, a report, and optionally irradiance at points read from
//! the shown light map.

use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use clap::Args;
use glam::{DVec3, Vec2, Vec3};
use serde::Deserialize;
use serde_json::{Value, json};

use livebake::cpu::CpuProvider;
use livebake::export::{ExportOptions, ExportReport, export_gltf};
use livebake::gpu::{GpuContext, GpuProvider};
use livebake::output::{write_json, write_rgb_exr};
use livebake::probe::{ProbeError, SurfaceLocator};
use livebake::runtime::shown::ShownLightmap;
use livebake::runtime::world::World;
use livebake::runtime::{CameraView, Runtime, RuntimeConfig, RuntimeEvent, RuntimeStats, TimedEvent, resample};
use livebake::scene::sun::{SunPosition, parse_time};
use livebake::scene::{Rgb, Scene, SunPlacement, SurroundingsSpec};
use livebake::watch::WatchConfig;

use super::SceneOptions;
use super::bake::load_scene_with;
use super::options::Backend;
use super::progress::Ui;
use livebake::points::{read_points, write_results};

/// Options of the runtime (with the scene options of `bake`).
#[derive(Args, Debug, Clone, Default)]
pub struct RuntimeOptions {
    /// Grid cell side, metres (default: from the scene, a few thousand non-empty cells).
    #[arg(long, value_name = "M")]
    pub cell_size: Option<f32>,
    /// Memory the shown pages and bakes in progress may use, bytes or with a K/M/G suffix
    /// (default: what the scene and the view need: the scene's fixed structures, LOD 0, and
    /// the pages of the texels a screen can tell apart all around the viewer; at most a
    /// quarter of the machine's memory).
    #[arg(long, value_name = "BYTES", value_parser = livebake::bake::memory::parse_bytes)]
    pub memory_budget: Option<u64>,
    /// Directions a cell needs at least before it may swap to the next LOD (it swaps early,
    /// before its error is below --error-bound, once it also has its shown LOD's directions).
    #[arg(long, value_name = "N")]
    pub min_directions: Option<u32>,
    /// Directions after which a cell's LOD is settled whatever its error (and it moves on).
    #[arg(long, value_name = "N")]
    pub max_directions: Option<u32>,
    /// Estimated relative error at which a cell's LOD is settled (and it moves on).
    #[arg(long, value_name = "E")]
    pub error_bound: Option<f32>,
    /// Directions of LOD 0 after which it is first shown (then again at twice as many, until
    /// --samples).
    #[arg(long, value_name = "N")]
    pub first_light_directions: Option<u32>,
    /// Texels a bake gathers from neighbouring cells wanting the same LOD (0: one cell a bake).
    #[arg(long, value_name = "N")]
    pub group_texels: Option<u32>,
    /// Directions of a hot reload's quick re-bake of the cells it invalidated (default 32);
    /// they are re-baked with --samples right after. At least --samples: one full re-bake.
    #[arg(long, value_name = "N")]
    pub reload_directions: Option<u32>,
}

/// Options of `run` itself.
#[derive(Args, Debug, Clone)]
pub struct RunOptions {
    /// Camera pose: eye and target.
    #[arg(long, value_name = "EX,EY,EZ,TX,TY,TZ", value_parser = livebake::viewer::camera::parse_pose, allow_hyphen_values = true, conflicts_with = "camera_path")]
    pub camera: Option<(Vec3, Vec3)>,
    /// Camera path: [{"t":s,"eye":[x,y,z],"target":[x,y,z]},...], interpolated, held after
    /// its last key.
    #[arg(long, value_name = "PATH.json")]
    pub camera_path: Option<PathBuf>,
    /// Sun moves: [{"t":s,"sun":[elevation,azimuth]} or {"t":s,"time":"ISO-8601"} (a sun
    /// study's, with --location)...]; each applied once, t seconds after first light, as a
    /// light change (reload_* events).
    #[arg(long, value_name = "PATH.json")]
    pub sun_path: Option<PathBuf>,
    /// How long to run, seconds after first light.
    #[arg(long, value_name = "S", default_value_t = 10.0, allow_negative_numbers = true)]
    pub seconds: f64,
    /// Event stream, one JSON object per line.
    #[arg(long, value_name = "OUT.jsonl")]
    pub events: Option<PathBuf>,
    /// Output directory for the light maps as shown, cells.json and report.json.
    #[arg(long, default_value = "out")]
    pub out: PathBuf,
    /// Points to read from the shown light map at the end (probe's format).
    #[arg(long, value_name = "IN.json", requires = "points_out")]
    pub points: Option<PathBuf>,
    #[arg(long, value_name = "OUT.json", requires = "points")]
    pub points_out: Option<PathBuf>,
    /// Hot reload: watch the scene's files and follow every good save (reload_* events).
    #[arg(long)]
    pub watch: bool,
    /// At the end, also write the scene with the light map as shown attached, for other
    /// engines (as `bake --export-gltf`: TEXCOORD_1 + MOZ_lightmap; OUT.bin,
    /// OUT.lightmap.exr and OUT.lightmap.png beside it). The map is resampled at the finest
    /// LOD any cell shows (at most 4 M pixels; see report.json "export").
    #[arg(long, value_name = "OUT.gltf")]
    pub export_gltf: Option<PathBuf>,
    /// At the end, also write a static web page showing the light map as shown (open
    /// DIR/index.html?static from any file server or a headset's browser; docs/SERVE.md),
    /// with the scene exported as --export-gltf does (DIR/scene.gltf).
    #[arg(long, value_name = "DIR")]
    pub export_web: Option<PathBuf>,
    #[command(flatten)]
    pub runtime: RuntimeOptions,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            camera: None,
            camera_path: None,
            sun_path: None,
            seconds: 10.0,
            events: None,
            out: PathBuf::from("out"),
            points: None,
            points_out: None,
            watch: false,
            export_gltf: None,
            export_web: None,
            runtime: RuntimeOptions::default(),
        }
    }
}

/// One key of a camera path.
#[derive(Deserialize)]
struct PathKey {
    t: f64,
    eye: [f64; 3],
    target: [f64; 3],
}

/// A camera path: keys in time order, linearly interpolated, held after the last; its poses
/// in the file's coordinates, read in a scene's frame with [`CameraPath::in_frame`].
pub struct CameraPath {
    keys: Vec<(f64, DVec3, DVec3)>,
}

impl CameraPath {
    pub fn read(path: &Path) -> Result<CameraPath> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("cannot read camera path {}", path.display()))?;
        let keys: Vec<PathKey> = serde_json::from_str(&text).with_context(|| {
            format!("{}: expected [{{\"t\":s,\"eye\":[x,y,z],\"target\":[x,y,z]}},...]", path.display())
        })?;
        if keys.is_empty() {
            bail!("{}: the camera path has no keys", path.display());
        }
        let mut out: Vec<(f64, DVec3, DVec3)> = Vec::with_capacity(keys.len());
        for (i, k) in keys.iter().enumerate() {
            let (eye, target) = (DVec3::from(k.eye), DVec3::from(k.target));
            if !(k.t.is_finite() && eye.is_finite() && target.is_finite()) || eye == target {
                bail!("{}: key {i} is not a finite pose with distinct eye and target", path.display());
            }
            if out.last().is_some_and(|l| l.0 > k.t) {
                bail!("{}: key {i} goes back in time (t = {})", path.display(), k.t);
            }
            out.push((k.t, eye, target));
        }
        Ok(CameraPath { keys: out })
    }

    /// The path with its poses in the frame of a scene whose origin is `origin`
    /// ([`livebake::scene::Scene::origin`]).
    pub fn in_frame(mut self, origin: DVec3) -> CameraPath {
        for key in &mut self.keys {
            (key.1, key.2) = (key.1 - origin, key.2 - origin);
        }
        self
    }

    /// The pose at time `t` (seconds).
    pub fn at(&self, t: f64) -> (Vec3, Vec3) {
        let k = &self.keys;
        let pose = |a: DVec3, b: DVec3| (a.as_vec3(), b.as_vec3());
        let Some(next) = k.iter().position(|key| key.0 > t) else {
            let last = k[k.len() - 1];
            return pose(last.1, last.2);
        };
        if next == 0 {
            return pose(k[0].1, k[0].2);
        }
        let (a, b) = (k[next - 1], k[next]);
        let s = (t - a.0) / (b.0 - a.0).max(1e-9);
        pose(a.1.lerp(b.1, s), a.2.lerp(b.2, s))
    }
}

/// One key of a sun path.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SunKey {
    t: f64,
    sun: Option<[f64; 2]>,
    time: Option<String>,
}

/// Sun moves at times after first light, each applied once.
pub struct SunPath {
    keys: Vec<(f64, SunPlacement)>,
    next: usize,
}

impl SunPath {
    /// Reads `path`; `spec` is how the surroundings are made (a time key needs a sun study's
    /// place).
    pub fn read(path: &Path, spec: &SurroundingsSpec) -> Result<SunPath> {
        let text = std::fs::read_to_string(path).with_context(|| format!("cannot read sun path {}", path.display()))?;
        let expected = "expected [{\"t\":s,\"sun\":[elevation,azimuth]} or {\"t\":s,\"time\":\"ISO-8601\"},...]";
        let keys: Vec<SunKey> =
            serde_json::from_str(&text).with_context(|| format!("{}: {expected}", path.display()))?;
        let mut out: Vec<(f64, SunPlacement)> = Vec::with_capacity(keys.len());
        for (i, k) in keys.iter().enumerate() {
            let bad = |why: String| anyhow::anyhow!("{}: key {i}: {why}", path.display());
            if !k.t.is_finite() || out.last().is_some_and(|l| l.0 > k.t) {
                return Err(bad(format!("t = {} is not finite or goes back in time", k.t)));
            }
            let placement = match (&k.sun, &k.time, spec.sun) {
                (Some([elevation, azimuth]), None, _) => {
                    if !(elevation.is_finite() && azimuth.is_finite() && (-90.0..=90.0).contains(elevation)) {
                        return Err(bad(format!(
                            "sun [{elevation}, {azimuth}] is not an elevation in [-90, 90] and an azimuth"
                        )));
                    }
                    SunPlacement::Fixed(SunPosition { elevation: *elevation, azimuth: azimuth.rem_euclid(360.0) })
                }
                (None, Some(time), Some(SunPlacement::Study { latitude, longitude, .. })) => {
                    SunPlacement::Study { latitude, longitude, time: parse_time(time).map_err(bad)? }
                }
                (None, Some(_), _) => return Err(bad("a time key needs a sun study (--location and --time)".into())),
                _ => return Err(bad(format!("give either \"sun\" or \"time\"; {expected}"))),
            };
            out.push((k.t, placement));
        }
        Ok(SunPath { keys: out, next: 0 })
    }

    /// The placements due by `t` that were not handed out yet (the last of them).
    fn due(&mut self, t: f64) -> Option<SunPlacement> {
        let mut last = None;
        while let Some(&(at, p)) = self.keys.get(self.next)
            && at <= t
        {
            last = Some(p);
            self.next += 1;
        }
        last
    }
}

/// The runtime settings from the command line: the scene options of `bake` with the
/// runtime's own defaults where they were not given.
pub fn runtime_config(options: &SceneOptions, runtime: &RuntimeOptions) -> Result<RuntimeConfig> {
    if options.backend == Backend::Reference {
        bail!("--backend reference path-traces texels offline; the runtime needs a bundle backend (cpu, gpu or auto)");
    }
    let mut config = RuntimeConfig::default();
    let bake = options.bake_config(|_| config.bundle.directions)?;
    config.atlas = bake.atlas.clone();
    config.atlas.texel_budget = options.texel_budget.unwrap_or(RuntimeConfig::default().atlas.texel_budget);
    config.bundle = bake.bundle_config();
    config.lods = options.lods;
    config.threads = options.threads;
    config.cell_size = runtime.cell_size;
    if let Some(b) = runtime.memory_budget {
        config.memory_budget = Some(b);
    }
    if let Some(d) = runtime.min_directions {
        config.min_directions = d;
    }
    if let Some(d) = runtime.max_directions {
        config.max_directions = d;
    }
    if let Some(e) = runtime.error_bound {
        config.error_bound = e;
    }
    if let Some(n) = runtime.group_texels {
        config.group_texels = n;
    }
    if let Some(n) = runtime.first_light_directions {
        config.first_light_directions = n;
    }
    if let Some(d) = runtime.reload_directions {
        config.reload_directions = d;
    }
    config.validate()?;
    Ok(config)
}

/// Writes events as JSON lines with `"t"` (seconds since the runtime started).
struct EventLog {
    out: Option<BufWriter<std::fs::File>>,
}

impl EventLog {
    fn open(path: Option<&Path>) -> Result<EventLog> {
        let out = match path {
            Some(p) => Some(BufWriter::new(
                std::fs::File::create(p).with_context(|| format!("cannot create event file {}", p.display()))?,
            )),
            None => None,
        };
        Ok(EventLog { out })
    }

    fn write(&mut self, t: f64, event: &impl serde::Serialize) -> Result<()> {
        if let Some(out) = &mut self.out {
            let mut v = serde_json::to_value(event)?;
            if let Value::Object(m) = &mut v {
                m.insert("t".into(), json!(t));
            }
            serde_json::to_writer(&mut *out, &v)?;
            out.write_all(b"\n")?;
        }
        Ok(())
    }

    fn flush(&mut self) -> Result<()> {
        if let Some(out) = &mut self.out {
            out.flush()?;
        }
        Ok(())
    }
}

pub fn run(scene_path: &Path, options: &SceneOptions, run: &RunOptions, ui: &Ui) -> Result<()> {
    let config = runtime_config(options, &run.runtime)?;
    let path = run.camera_path.as_deref().map(CameraPath::read).transpose()?;
    let points = run.points.as_deref().map(read_points).transpose()?;
    if !(run.seconds.is_finite() && run.seconds >= 0.0) {
        bail!("--seconds must be a non-negative number, got {}", run.seconds);
    }
    if let Some(out) = &run.export_gltf
        && !out.extension().is_some_and(|e| e.eq_ignore_ascii_case("gltf"))
    {
        bail!("--export-gltf {}: the export must be a .gltf file name", out.display());
    }
    let (scene, load_seconds, mut spec) = load_scene_with(scene_path, options, None)?;
    let mut sun_path = run.sun_path.as_deref().map(|p| SunPath::read(p, &spec)).transpose()?;
    let path = path.map(|p| p.in_frame(scene.origin));
    // --camera is in the file's coordinates.
    let pose = run.camera.map(|p| scene.pose_to_scene(p));
    let interrupted = Arc::new(AtomicBool::new(false));
    // Ctrl-C ends the run early; the outputs are still written.
    let _ = signal_hook::flag::register(signal_hook::consts::SIGINT, interrupted.clone());

    let mut runtime = start_runtime(scene.clone(), config, options.backend)
        .with_context(|| format!("cannot start the runtime on {}", scene_path.display()))?;
    if run.watch {
        let watch = WatchConfig {
            surroundings: scene.surroundings(),
            load: options.load_options(None),
            ..WatchConfig::default()
        };
        runtime.watch(scene_path, watch).with_context(|| format!("cannot watch {}", scene_path.display()))?;
    }
    // Outputs are made once the scene and the options have proved good (events wait in the
    // runtime's channel meanwhile).
    std::fs::create_dir_all(&run.out)
        .with_context(|| format!("cannot create output directory {}", run.out.display()))?;
    let mut log = EventLog::open(run.events.as_deref())?;
    let base = CameraView::for_scene(&scene);
    let camera_at = |t: f64| match (&path, pose) {
        (Some(p), _) => {
            let (eye, target) = p.at(t);
            CameraView { eye, target, ..base }
        }
        (None, Some((eye, target))) => CameraView { eye, target, ..base },
        (None, None) => base,
    };
    runtime.set_camera(camera_at(0.0));
    ui.begin_phase("first light", 0);

    let mut first_light: Option<f64> = None;
    let mut last_stats: Option<RuntimeStats> = None;
    let mut failure = None;
    loop {
        let elapsed = runtime.elapsed();
        let since_light = first_light.map(|t| elapsed - t);
        if interrupted.load(Ordering::Relaxed) || since_light.is_some_and(|s| s >= run.seconds) {
            break;
        }
        // The path's clock starts at first light, when refinement starts.
        runtime.set_camera(camera_at(since_light.unwrap_or(0.0)));
        if let (Some(t), Some(path)) = (since_light, sun_path.as_mut())
            && let Some(placement) = path.due(t)
        {
            spec.sun = Some(placement);
            let surroundings = spec.build().map_err(anyhow::Error::msg).context("--sun-path")?;
            tracing::info!("the sun moves to {}", placement.describe());
            runtime.set_surroundings(surroundings);
        }
        match runtime.events().recv_timeout(Duration::from_millis(20)) {
            Ok(TimedEvent { t, event }) => {
                log.write(t, &event)?;
                match &event {
                    RuntimeEvent::FirstLight { .. } => {
                        first_light = Some(t);
                        ui.end_phase();
                        ui.begin_phase("refining", 0);
                    }
                    RuntimeEvent::Stats(s) => {
                        ui.status(&format!(
                            "cells per LOD {:?} | queue {} | {:.1} M texel-samples/s | {:.0} MB",
                            s.cells_per_lod,
                            s.queue,
                            s.texel_samples_per_second / 1e6,
                            s.resident_bytes as f64 / 1e6
                        ));
                        last_stats = Some(s.clone());
                    }
                    RuntimeEvent::Failed { error } => {
                        failure = Some(error.clone());
                        break;
                    }
                    RuntimeEvent::ReloadFailed { path, error } => {
                        tracing::warn!("reload of {path} failed (the last good scene stays): {error}")
                    }
                    RuntimeEvent::ReloadApplied { changed_meshes, invalidated_cells, ms, .. } => tracing::info!(
                        "reloaded: {changed_meshes} meshes changed, {invalidated_cells} cells re-baked, {ms:.0} ms"
                    ),
                    _ => {}
                }
            }
            Err(crossbeam_channel::RecvTimeoutError::Timeout) => {}
            Err(crossbeam_channel::RecvTimeoutError::Disconnected) => break,
        }
    }
    ui.end_phase();
    // The events already sent go into the log before the final snapshot, so that it names
    // what the snapshot shows (all but a publish landing at that very moment).
    while let Ok(TimedEvent { t, event }) = runtime.events().try_recv() {
        log.write(t, &event)?;
    }
    // One moment's map and cell table: a publish between two reads would make cells.json
    // name LODs the written map does not show.
    let (shown, cells) = runtime.snapshot();
    let stats = runtime.stats();
    let world = runtime.world();
    // On the runtime's clock, as every event's "t" is.
    let t_end = runtime.elapsed();
    runtime.shutdown()?;
    if let Some(error) = failure {
        bail!("the runtime failed on {}: {error}", scene_path.display());
    }

    // Outputs, none of them with a non-finite value: a sample is a blend of each layer's
    // published pixels, so finite pixels whose largest values sum to a finite one keep every
    // written map, export and point finite.
    let non_finite = shown.non_finite_pixels();
    if non_finite > 0 || !shown.max_irradiance().is_finite() {
        bail!(
            "the light map as shown has {non_finite} non-finite pixel(s) or sums beyond f32 (the light overflowed f32, \
             as a point light almost touching a surface makes it); nothing was written to {}",
            run.out.display()
        );
    }
    let mut written = Vec::new();
    for lod in 0..shown.lods() {
        let Some(rect) = shown.published_rect(lod) else { continue };
        let (w, h) = (rect.2 - rect.0, rect.3 - rect.1);
        if w * h > MAX_EXR_PIXELS {
            tracing::warn!("LOD {lod}'s published region is {w}×{h} pixels; not written (above {MAX_EXR_PIXELS})");
            continue;
        }
        let file = run.out.join(format!("lightmap_lod{lod}.exr"));
        write_rgb_exr(&file, w as u32, h as u32, &shown.level_pixels(lod, rect))?;
        written.push((lod, rect, file));
    }
    // Positions in the file's coordinates, as the scene's points are given.
    let in_file = |p: [f32; 3]| scene.to_file(Vec3::from(p)).to_array();
    let cells_json = json!({
        "grid": {
            "origin": in_file(world.grid.origin.to_array()),
            "cell_size": world.grid.cell_size,
            "dims": world.grid.dims,
        },
        "cells": cells.iter().map(|c| json!({
            "cell": c.cell,
            "bounds": {"min": in_file(c.min), "max": in_file(c.max)},
            "shown_lod": c.shown_lod,
            "punctual_lod": c.punctual_lod,
            "target_lod": c.target_lod,
            "directions": c.directions,
            "error": if c.error.is_finite() { json!(c.error) } else { Value::Null },
            "settled": c.settled,
            "texels_lod0": c.texels,
        })).collect::<Vec<_>>(),
    });
    write_json(&run.out.join("cells.json"), &cells_json)?;
    let export = match &run.export_gltf {
        Some(out) => Some(export_shown(&world, &shown, out, &ExportOptions { load: options.load_options(None) })?),
        None => None,
    };
    if let Some(dir) = &run.export_web {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        export_shown(&world, &shown, &dir.join("scene.gltf"), &ExportOptions { load: options.load_options(None) })?;
        livebake::serve::export::export_web(dir, &world.scene, &world.atlas, &shown, None, pose)
            .with_context(|| format!("cannot export the web page into {}", dir.display()))?;
        ui.say(format!("  web page in {} (open index.html?static from a file server)", dir.display()));
    }
    let report = json!({
        "scene": scene_path.display().to_string(),
        "triangles": scene.triangle_count(),
        "load_seconds": load_seconds,
        "atlas": {
            "texel_size": world.atlas.texel_size,
            "width": world.atlas.width,
            "height": world.atlas.height,
            "charts": world.atlas.stats.charts,
            "fill_ratio": world.atlas.stats.fill_ratio,
            "covered_texels_lod0": world.atlas.stats.covered_texels_lod0,
        },
        "grid": world.grid,
        "lods": world.lods,
        "texel_size_per_lod": (0..world.lods).map(|k| world.texel_size(k)).collect::<Vec<_>>(),
        "config": runtime_report_config(options, run),
        "first_light_seconds": stats.first_light_seconds,
        "run_seconds": t_end,
        "interrupted": interrupted.load(Ordering::Relaxed),
        "stats": stats,
        "last_stats_event": last_stats,
        "lightmaps": written.iter().map(|(lod, r, f)| json!({
            "lod": lod, "file": f.file_name().map(|n| n.to_string_lossy().to_string()),
            "origin": [r.0, r.1], "size": [r.2 - r.0, r.3 - r.1],
        })).collect::<Vec<_>>(),
        "export": export.as_ref().map(|e| json!({
            "gltf": e.gltf, "lod": e.lod, "width": e.width, "height": e.height,
            "finest_shown_lod": shown.finest_lod(),
            "png_intensity": e.png_intensity,
        })),
    });
    write_json(&run.out.join("report.json"), &report)?;
    if let (Some(points), Some(out)) = (points, run.points_out.as_deref()) {
        let locator = SurfaceLocator::new(&world.geom, &world.bvh);
        let results: Vec<Result<Rgb, ProbeError>> = points
            .queries(scene.origin)
            .iter()
            .map(|q| {
                let at = locator.locate(q.p, q.n)?;
                let face = world.atlas.face(at.tri, at.side).ok_or(ProbeError::BackOfSingleSided)?;
                let uv: Vec2 = world.atlas.faces[face as usize].uv_at(at.u, at.v);
                Ok(shown.irradiance(world.geom.point(at.tri, at.u, at.v), uv))
            })
            .collect();
        write_results(&points, &results, Some(out))?;
        ui.say(format!("wrote {} ({} points)", out.display(), results.len()));
    }
    log.write(t_end, &json!({"event": "finished", "stats": stats}))?;
    log.flush()?;
    summarise(ui, scene_path, &scene, &stats, &written, &run.out);
    if let Some(e) = &export {
        ui.say(format!("  exported {} (light map at LOD {}, {}×{})", e.gltf.display(), e.lod, e.width, e.height));
    }
    Ok(())
}

/// The glTF export of the light map as shown at the end of the run: resampled at the finest
/// LOD any cell shows, capped at [`resample::MAX_EXPORT_PIXELS`] (`runtime::resample`).
fn export_shown(world: &World, shown: &ShownLightmap, out: &Path, options: &ExportOptions) -> Result<ExportReport> {
    let lod = resample::export_lod(shown, resample::MAX_EXPORT_PIXELS);
    let finest = shown.finest_lod();
    if lod < finest {
        tracing::warn!(
            "the export holds LOD {lod}: LOD {finest}, the finest shown, would exceed {} pixels; cells shown finer lose detail",
            resample::MAX_EXPORT_PIXELS
        );
    }
    let image = resample::shown_image(world, shown, lod);
    export_gltf(&world.scene, &world.atlas, &image, out, options)
        .with_context(|| format!("cannot export {}", out.display()))
}

/// Largest LOD image `run` writes (16 M pixels: 200 MB of f32 RGB).
const MAX_EXR_PIXELS: u64 = 1 << 24;

fn runtime_report_config(options: &SceneOptions, run: &RunOptions) -> Value {
    json!({
        "texel_size": options.texel_size,
        "texel_budget": options.texel_budget,
        "lods": options.lods,
        "samples": options.samples,
        "seed": options.seed,
        "cell_size": run.runtime.cell_size,
        "memory_budget": run.runtime.memory_budget,
        "min_directions": run.runtime.min_directions,
        "max_directions": run.runtime.max_directions,
        "error_bound": run.runtime.error_bound,
        "group_texels": run.runtime.group_texels,
        "first_light_directions": run.runtime.first_light_directions,
        "reload_directions": run.runtime.reload_directions,
        "seconds": run.seconds,
    })
}

/// A light map written at the end: its LOD, its pixel rectangle (x0, y0, x1, y1), its file.
type WrittenLod = (u32, (u64, u64, u64, u64), PathBuf);

fn summarise(ui: &Ui, path: &Path, scene: &Scene, stats: &RuntimeStats, written: &[WrittenLod], out: &Path) {
    ui.say(format!("livebake run: {} ({} triangles)", path.display(), scene.triangle_count()));
    if let Some(t) = stats.first_light_seconds {
        ui.say(format!("  first light after {t:.2} s"));
    }
    ui.say(format!(
        "  cells per LOD {:?}, {} publishes, {} directions traced, {:.0} MB resident",
        stats.cells_per_lod,
        stats.publishes,
        stats.directions_traced,
        stats.resident_bytes as f64 / 1e6
    ));
    for (_, _, f) in written {
        ui.say(format!("  wrote {}", f.display()));
    }
    ui.say(format!("  wrote {} and {}", out.join("cells.json").display(), out.join("report.json").display()));
}

/// The runtime on the bundle backend `backend` names. `auto` is the GPU backend on a
/// hardware adapter and the CPU's otherwise: a runtime's cell bakes see surfaces outside
/// their cell, which the GPU resolve cannot read yet, so on a software adapter only the
/// first light would run on it, slower than on the CPU.
pub fn start_runtime(scene: Arc<Scene>, config: RuntimeConfig, backend: Backend) -> Result<Runtime> {
    let gpu = match backend {
        Backend::Gpu => Some(GpuContext::headless().context("--backend gpu needs a Vulkan adapter")?),
        Backend::Auto => GpuContext::headless().ok().filter(|g| !g.is_software()),
        Backend::Cpu | Backend::Reference => None,
    };
    Ok(match gpu {
        Some(gpu) => Runtime::start(scene, config, Arc::new(GpuProvider::new(gpu)))?,
        None => Runtime::start(scene, config, Arc::new(CpuProvider::new()))?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_paths_interpolate_and_hold() {
        let keys = vec![(0.0, DVec3::ZERO, DVec3::Z), (2.0, DVec3::new(2.0, 0.0, 0.0), DVec3::Z)];
        let p = CameraPath { keys };
        assert_eq!(p.at(1.0).0, Vec3::new(1.0, 0.0, 0.0));
        assert_eq!(p.at(-1.0).0, Vec3::ZERO);
        assert_eq!(p.at(9.0).0, Vec3::new(2.0, 0.0, 0.0));
        assert!(livebake::viewer::camera::parse_pose("0,0,0,0,0,1").is_ok());
        assert!(livebake::viewer::camera::parse_pose("0,0,0,0,0,0").is_err());
        assert!(livebake::viewer::camera::parse_pose("0,0,0").is_err());
    }

    /// A path's poses are kept in f64 and moved into a scene's frame before they become f32:
    /// a quarter metre 4 194 304 m out survives (as f32 it is 4 194 304.0).
    #[test]
    fn camera_paths_are_read_in_the_scenes_frame() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("path.json");
        std::fs::write(&file, r#"[{"t": 0, "eye": [4194304.25, 1.5, 0], "target": [4194310.75, 1.5, -1]}]"#).unwrap();
        let origin = DVec3::new(4_194_304.0, 0.0, 0.0);
        let (eye, target) = CameraPath::read(&file).unwrap().in_frame(origin).at(0.0);
        assert_eq!(eye, Vec3::new(0.25, 1.5, 0.0));
        assert_eq!(target, Vec3::new(6.75, 1.5, -1.0));
    }
}
