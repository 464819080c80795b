//! The live runtime on the bundled rooms with its defaults (`RuntimeConfig::default()`, the
//! CPU bundle backend on every core):
//!
//! * first light: seconds from `Runtime::start` (atlas, grid and LOD-0 texels included; the
//!   scene load is not) to the `first_light` event, median over a few starts, and the cells
//!   and texels it lit;
//! * refinement for a fixed wall time with a fixed camera inside the room: cells per shown
//!   LOD, swaps (a `cell_published` that raises the cell's LOD) and their times, republishes
//!   (one at the cell's LOD: an unsettled level with more directions), throughput, the
//!   memory it reports, the time of one unit of work;
//! * the error of the shown light map near the camera (the nearer half of the surface points
//!   hit by a grid of rays through the view) against the in-crate reference path tracer,
//!   side by side with whole-scene progressive bakes given the same wall time: at the
//!   runtime's LOD-0 layout and at the texel size the runtime shows near the camera. The
//!   relative RMS error is led by the worst points (on the Van Gogh room: thin faces lit by
//!   the bedside point light, which only a finer texel resolves), so the median per-point
//!   error and the points weighing most are given too.
//!
//! Both clocks start before the atlas is built (the scene is loaded before either).

use std::collections::HashMap;
use std::ops::ControlFlow;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use livebake::glam::{DVec3, Vec3};
use serde_json::{Value, json};

use livebake::atlas::{Atlas, AtlasConfig, TexelMap};
use livebake::bake::bundle::{BatchDone, bake_lod_observed};
use livebake::bake::memory::{self, resident_bytes};
use livebake::bake::{BakeConfig, check_lod_sizes, check_node_capacity};
use livebake::bundle::{BackendProvider, BundleScene};
use livebake::cpu::CpuProvider;
use livebake::grid::CellId;
use livebake::probe::{LightmapLookup, SurfaceLocator};
use livebake::progress::NoProgress;
use livebake::reference::{Bvh, ReferenceTracer};
use livebake::runtime::shown::{Layer, ShownLightmap};
use livebake::runtime::world::World;
use livebake::runtime::{CameraView, Runtime, RuntimeConfig, RuntimeEvent, RuntimeStats, TimedEvent};
use livebake::scene::{LoadOptions, Scene, SceneGeometry, load_gltf};

use super::{Bench, Narrator, assets, curve_points, seconds};
use livebake::plot::Series;
use livebake::points::{Query, ReferencePoints};

pub const ROOMS: [&str; 3] = [
    "cornell_box/cornellBox-2.79-Cycles-gltf.gltf",
    "cornell_2m/cornell_2m.gltf",
    "van_gogh_room/van_gogh_room_lit.gltf",
];

/// However loaded the machine, first light comes well within this.
pub const PATIENCE: Duration = Duration::from_secs(180);
/// Rays through the view (columns × rows) whose nearer half of hits are the error points.
const VIEW_RAYS: (u32, u32) = (12, 8);

/// A camera inside a closed room, whatever cameras the file has (the bundled Cornell box's
/// looks in from outside its open front): the fallback of [`CameraView::for_scene`], at mid
/// height, 40% of the way from the centre toward +Z, looking at the centre.
pub fn inside_camera(scene: &Scene) -> CameraView {
    let (lo, hi) = scene.bounds().unwrap_or((Vec3::splat(-1.0), Vec3::splat(1.0)));
    let centre = (lo + hi) * 0.5;
    CameraView::looking_at(centre + Vec3::new(0.0, 0.05 * (hi.y - lo.y), 0.4 * (hi.z - lo.z)), centre)
}

/// The next event within `timeout`; a runtime failure is an error.
pub fn next_event(runtime: &Runtime, timeout: Duration) -> Result<Option<TimedEvent>> {
    match runtime.events().recv_timeout(timeout) {
        Ok(e) => match &e.event {
            RuntimeEvent::Failed { error } => bail!("the runtime failed: {error}"),
            _ => Ok(Some(e)),
        },
        Err(crossbeam_channel::RecvTimeoutError::Timeout) => Ok(None),
        Err(crossbeam_channel::RecvTimeoutError::Disconnected) => bail!("the runtime's event channel closed"),
    }
}

/// Each cell's shown LOD as the events tell it (LOD 0 until published): a `cell_published`
/// that raises it is a swap, one at the same LOD a republish (an unsettled level with more
/// directions, or a refresh).
#[derive(Default)]
pub(super) struct ShownLods(HashMap<CellId, u32>);

impl ShownLods {
    /// Notes a publish of `cell` at `lod`; returns whether it swapped the cell to a finer LOD.
    pub fn published(&mut self, cell: CellId, lod: u32) -> bool {
        let shown = self.0.entry(cell).or_insert(0);
        let swap = lod > *shown;
        *shown = lod;
        swap
    }

    /// Notes that `cell`'s `lod` was evicted (it shows the next coarser).
    pub fn evicted(&mut self, cell: CellId, lod: u32) {
        self.0.insert(cell, lod.saturating_sub(1));
    }
}

/// Waits for first light; returns its time (seconds since start) and texel count, and the
/// events seen before it.
pub fn wait_first_light(runtime: &Runtime) -> Result<(f64, usize, Vec<TimedEvent>)> {
    let deadline = Instant::now() + PATIENCE;
    let mut seen = Vec::new();
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            bail!("no first light within {PATIENCE:?}");
        }
        if let Some(e) = next_event(runtime, left)? {
            if let RuntimeEvent::FirstLight { texels, .. } = e.event {
                return Ok((e.t, texels, seen));
            }
            seen.push(e);
        }
    }
}

/// Surface points in view: the hits of a grid of rays through the camera on light-mapped
/// sides, the nearer half of them (the normal is the side facing the camera).
fn points_in_view(world: &World, camera: &CameraView) -> Vec<Query> {
    let mut hits = view_hits(world, camera, VIEW_RAYS);
    hits.truncate(hits.len().div_ceil(2));
    hits.into_iter().map(|(_, q)| q).collect()
}

/// The hits of a grid of `rays` (columns × rows) through the view on light-mapped sides, nearest
/// first, with their distances (the normal is the side facing the camera).
pub(super) fn view_hits(world: &World, camera: &CameraView, rays: (u32, u32)) -> Vec<(f32, Query)> {
    let (f, r, u) = camera.basis();
    let half_h = (camera.yfov * 0.5).tan();
    let half_w = half_h * camera.aspect;
    let (nx, ny) = rays;
    let mut hits: Vec<(f32, Query)> = Vec::new();
    for j in 0..ny {
        for i in 0..nx {
            let sx = ((i as f32 + 0.5) / nx as f32 * 2.0 - 1.0) * half_w;
            let sy = ((j as f32 + 0.5) / ny as f32 * 2.0 - 1.0) * half_h;
            let dir = (f + r * sx + u * sy).normalize();
            let Some(hit) = world.bvh.intersect(camera.eye, dir, 0.0, f32::MAX) else { continue };
            let n = world.geom.normals[hit.tri as usize];
            let n = if n.dot(dir) > 0.0 { -n } else { n };
            let p = world.geom.point(hit.tri, hit.u, hit.v);
            let side = livebake::scene::Side::facing(world.geom.normals[hit.tri as usize], n);
            if world.atlas.face(hit.tri, side).is_some() {
                hits.push((hit.t, Query { p, n }));
            }
        }
    }
    hits.sort_by(|a, b| a.0.total_cmp(&b.0));
    hits
}

/// The in-crate reference at `points` (`spp` paths each).
pub(super) fn reference_at(scene: &Scene, points: &[Query], spp: u32) -> ReferencePoints {
    let tracer = ReferenceTracer::new(scene);
    let at: Vec<(Vec3, Vec3)> = points.iter().map(|q| (q.p, q.n)).collect();
    let (estimates, _) = tracer.irradiance_batch_estimates(&at, spp, 0x5EED, &|_| {});
    ReferencePoints {
        queries: points.to_vec(),
        e: estimates.iter().map(|e| e.e.as_dvec3()).collect(),
        stderr: estimates.iter().map(|e| e.stderr.as_dvec3()).collect(),
    }
}

/// Where the error points read the shown light map: position and LOD-0 UV of each.
pub(super) struct ShownReader {
    pub at: Vec<(Vec3, livebake::glam::Vec2)>,
}

impl ShownReader {
    pub fn new(world: &World, points: &[Query]) -> Result<ShownReader> {
        let locator = SurfaceLocator::new(&world.geom, &world.bvh);
        let at = points
            .iter()
            .enumerate()
            .map(|(k, q)| {
                let at = locator.locate(q.p, q.n).with_context(|| format!("error point {k}"))?;
                let face =
                    world.atlas.face(at.tri, at.side).with_context(|| format!("error point {k}: no light map"))?;
                Ok((world.geom.point(at.tri, at.u, at.v), world.atlas.faces[face as usize].uv_at(at.u, at.v)))
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(ShownReader { at })
    }

    pub fn values(&self, shown: &ShownLightmap) -> Vec<DVec3> {
        self.at.iter().map(|&(p, uv)| shown.irradiance(p, uv).as_dvec3()).collect()
    }

    pub fn error(&self, reference: &ReferencePoints, shown: &ShownLightmap) -> f64 {
        let got = self.values(shown);
        reference.relative_rms(|k| got[k])
    }
}

/// Median over the points of |E − E_ref| / |E_ref| (RGB lengths): the typical point, where
/// the RMS is led by the worst.
pub(super) fn median_point_error(reference: &ReferencePoints, got: &[DVec3]) -> Option<f64> {
    let mut v: Vec<f64> = got
        .iter()
        .zip(&reference.e)
        .filter(|(_, e)| e.length() > 0.0)
        .map(|(g, e)| (*g - *e).length() / e.length())
        .collect();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied()
}

/// The points that weigh most in the error (squared difference of E's mean over RGB),
/// largest first, with the share of the sum of squares each takes.
pub(super) fn worst_points(reference: &ReferencePoints, got: &[DVec3], n: usize) -> Vec<Value> {
    let d2: Vec<f64> = got.iter().zip(&reference.e).map(|(g, e)| (*g - *e).length_squared()).collect();
    let total: f64 = d2.iter().sum();
    let mut order: Vec<usize> = (0..d2.len()).collect();
    order.sort_by(|&a, &b| d2[b].total_cmp(&d2[a]));
    order
        .into_iter()
        .take(n)
        .map(|k| {
            json!({
                "p": reference.queries[k].p.to_array(),
                "n": reference.queries[k].n.to_array(),
                "E_reference": reference.e[k].to_array(),
                "E_shown": got[k].to_array(),
                "share_of_squared_error": if total > 0.0 { d2[k] / total } else { 0.0 },
            })
        })
        .collect()
}

/// Texels published in a snapshot (pixels with a value, gutters included) at every LOD of
/// both layers.
fn published_pixels(shown: &ShownLightmap) -> u64 {
    shown
        .layers
        .iter()
        .flat_map(|l| l.levels.iter())
        .flat_map(|l| l.rows.iter())
        .flat_map(|row| row.iter().flatten())
        .map(|p| p.valid as u64)
        .sum()
}

pub(super) fn quantile(v: &[f64], q: f64) -> Option<f64> {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    (!v.is_empty()).then(|| v[((v.len() - 1) as f64 * q).round() as usize])
}

/// (seconds, directions, error) after each batch of a bake.
type Curve = Vec<(f64, u64, f64)>;

pub(super) struct WholeBake {
    pub texels: usize,
    pub texel_size: f32,
    pub curve: Curve,
    /// E at the points after the last batch done within the budget.
    pub values_at_t: Option<Vec<DVec3>>,
    /// The bake's peak bytes as `livebake bake` estimates them before allocating.
    pub estimated_bytes: u64,
    /// Seconds from the start (atlas included) to the end: its last batch, the goal, or the
    /// budget (then perhaps before its first batch).
    pub ended_seconds: f64,
    /// The most resident bytes seen after a batch, over those before the atlas (a lower bound
    /// of its peak: sampled between batches).
    pub sampled_peak_bytes: Option<u64>,
}

/// A whole-scene progressive bake of LOD 0 with `atlas_config` and the runtime's bundle
/// settings, stopped at the first batch that ends after `budget` seconds (or, with
/// `stop_below`, whose error is at most that): (seconds, directions, error) after every
/// batch, on a clock started before the atlas. Refused, like `livebake bake`, when its
/// estimated peak exceeds the machine's memory limit.
pub(super) fn whole_bake(
    scene: &Arc<Scene>,
    atlas_config: &AtlasConfig,
    points: &[Query],
    reference: &ReferencePoints,
    budget: f64,
    stop_below: Option<f64>,
) -> Result<WholeBake> {
    let t = Instant::now();
    let rss_before = resident_bytes();
    let runtime = RuntimeConfig::default();
    let geom = Arc::new(SceneGeometry::new(scene));
    let atlas = Arc::new(Atlas::build(scene, &geom, atlas_config)?);
    check_lod_sizes(&atlas, 1)?;
    let bundle_config = livebake::bundle::BundleConfig { directions: 1 << 16, ..runtime.bundle.clone() };
    let bundle = Arc::new(BundleScene::new(scene.clone(), geom.clone(), atlas.clone(), bundle_config.clone()));
    let estimated_bytes = whole_bake_estimate(&atlas, !bundle.emitters.small.is_empty())?;
    let texels = TexelMap::build(scene, &geom, &atlas, 0);
    let bvh = Bvh::for_scene(scene, &geom);
    check_node_capacity(&bvh, &bundle_config)?;
    let locate_bvh = Bvh::new(&geom);
    let locator = SurfaceLocator::new(&geom, &locate_bvh);
    let lookup = LightmapLookup::new(&atlas, &texels);
    let taps = points
        .iter()
        .enumerate()
        .map(|(k, q)| locator.locate(q.p, q.n).and_then(|at| lookup.taps(&at)).with_context(|| format!("point {k}")))
        .collect::<Result<Vec<_>>>()?;
    let threads = runtime.threads();
    let mut backend =
        CpuProvider::new().backend(&bundle, threads).map_err(|e| anyhow!("the bundle backend is unavailable: {e}"))?;
    let mut curve = Vec::new();
    // Stopped at the budget even before its first batch is done (at fine texels the texel
    // map and the punctual pass alone may take longer).
    let stop = AtomicBool::new(false);
    let done = AtomicBool::new(false);
    let mut values_at_t = None;
    let mut sampled_peak: Option<u64> = None;
    let mut observe = |done: &BatchDone| {
        let s = seconds(t);
        if let (Some(now), Some(before)) = (resident_bytes(), rss_before) {
            sampled_peak = Some(sampled_peak.unwrap_or(0).max(now.saturating_sub(before)));
        }
        let got: Vec<DVec3> = taps.iter().map(|tap| tap.read(|i| done.estimate.irradiance_of(i)).as_dvec3()).collect();
        let error = reference.relative_rms(|k| got[k]);
        curve.push((s, done.directions, error));
        if s <= budget {
            values_at_t = Some(got);
        }
        let converged = stop_below.is_some_and(|bound| error <= bound);
        if s >= budget || converged { ControlFlow::Break(()) } else { ControlFlow::Continue(()) }
    };
    let baked = std::thread::scope(|scope| {
        scope.spawn(|| {
            while !done.load(Ordering::Relaxed) && seconds(t) < budget {
                std::thread::sleep(Duration::from_millis(50));
            }
            stop.store(true, Ordering::Relaxed);
        });
        let r =
            bake_lod_observed(&bundle, &bvh, &mut backend, &texels, None, threads, &NoProgress, &stop, &mut observe);
        done.store(true, Ordering::Relaxed);
        r
    });
    // Cancelled at the budget (the only error it has): the curve so far is the result.
    let _: Result<_, livebake::bundle::Cancelled> = baked;
    Ok(WholeBake {
        texels: texels.len(),
        texel_size: atlas.texel_size,
        curve,
        values_at_t,
        estimated_bytes,
        ended_seconds: seconds(t),
        sampled_peak_bytes: sampled_peak,
    })
}

/// The peak bytes `livebake bake` estimates for one LOD of `atlas` with the runtime's bundle
/// settings (with or without the light pass); an error beyond half of the machine's memory
/// (the bench's own limit, below `livebake bake`'s three quarters: a bench must leave the
/// machine usable, and the runtime it is compared with stays far below).
pub(super) fn whole_bake_estimate(atlas: &Atlas, light_pass: bool) -> Result<u64> {
    let config = BakeConfig { lods: 1, bundle: RuntimeConfig::default().bundle, ..BakeConfig::default() };
    let estimate = memory::estimate(atlas, &config, memory::SceneTraits { light_pass, ..memory::SceneTraits::MOST });
    let (three_quarters, _) = memory::memory_limit(None);
    let limit = three_quarters / 3 * 2;
    if estimate.bytes > limit {
        return Err(TooLarge {
            texel_size: atlas.texel_size,
            texels: atlas.stats.covered_texels_lod0,
            bytes: estimate.bytes,
            limit,
        }
        .into());
    }
    Ok(estimate.bytes)
}

/// A whole-scene bake the bench does not run for its memory ([`whole_bake_estimate`]).
#[derive(Debug)]
pub(super) struct TooLarge {
    pub texel_size: f32,
    pub texels: u64,
    pub bytes: u64,
    pub limit: u64,
}

impl std::fmt::Display for TooLarge {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "a whole-scene bake at {} m texels ({} texels) would hold about {} (the bench runs them within {})",
            self.texel_size,
            self.texels,
            memory::human_bytes(&self.bytes),
            memory::human_bytes(&self.limit)
        )
    }
}

impl std::error::Error for TooLarge {}

/// The error a whole-scene bake shows at `t`: that of its last batch done by then.
fn bake_error_at(curve: &[(f64, u64, f64)], t: f64) -> Option<(u64, f64)> {
    curve.iter().rev().find(|c| c.0 <= t).map(|c| (c.1, c.2))
}

fn whole_bake_json(bake: &WholeBake, reference: &ReferencePoints, t: f64, runtime_error: f64) -> Value {
    let curve = &bake.curve;
    let at = bake_error_at(curve, t);
    json!({
        "texel_size_m": bake.texel_size,
        "texels": bake.texels,
        "estimated_peak_bytes": bake.estimated_bytes,
        "sampled_peak_bytes": bake.sampled_peak_bytes,
        "median_point_error_at_t": bake.values_at_t.as_ref().and_then(|v| median_point_error(reference, v)),
        "first_batch_seconds": curve.first().map(|c| c.0),
        "directions_at_t": at.map(|a| a.0),
        "error_at_t": at.map(|a| a.1),
        "error_ratio_bake_over_runtime": at.map(|a| a.1 / runtime_error),
        "curve": curve.iter().map(|&(s, d, e)| json!({"seconds": s, "directions": d, "error": e})).collect::<Vec<_>>(),
    })
}

fn room(name: &str, quick: bool, ui: &dyn Narrator) -> Result<Value> {
    let (runs, refine, spp) = if quick { (1, 4.0, 1024) } else { (3, 10.0, 4096) };
    let scene = Arc::new(load_gltf(&assets().join(name), &LoadOptions::default())?);
    let camera = inside_camera(&scene);
    let config = RuntimeConfig::default();
    let provider = Arc::new(CpuProvider::new());

    // First light, `runs` times; the last runtime goes on refining.
    let mut first = Vec::new();
    let mut last = None;
    for i in 0..runs {
        let runtime = Runtime::start(scene.clone(), config.clone(), provider.clone()).context("Runtime::start")?;
        runtime.set_camera(camera);
        let (t, texels, _) = wait_first_light(&runtime)?;
        first.push(t);
        if i + 1 < runs {
            runtime.shutdown()?;
        } else {
            last = Some((runtime, t, texels));
        }
    }
    let (runtime, t_light, texels) = last.context("no runtime ran")?;
    let world = runtime.world();
    let light_shown = runtime.shown();
    let stats_at_light = runtime.stats();

    // Refinement for `refine` seconds of wall time after first light.
    ui.say(format!("  {name}: refining for {refine} s ..."));
    let points = points_in_view(&world, &camera);
    if points.len() < 8 {
        bail!("only {} surface points in view", points.len());
    }
    let reader = ShownReader::new(&world, &points)?;
    // (time, LOD, directions, estimated error, settled) of each swap, and of each republish.
    let mut swaps: Vec<(f64, u32, u64, f32, bool)> = Vec::new();
    let mut republishes: Vec<(f64, u32, u64, f32, bool)> = Vec::new();
    let mut lods = ShownLods::default();
    let mut stats: Vec<(f64, RuntimeStats)> = Vec::new();
    let mut evictions = 0;
    // LOD 0 with all its directions (first light shows the first few of them).
    let mut lod0_complete: Option<(f64, Arc<ShownLightmap>)> = None;
    let mut snapshots = vec![(t_light, light_shown.clone())];
    let mut next_snapshot = t_light + 1.0;
    let end = t_light + refine;
    loop {
        let now = runtime.elapsed();
        if now >= next_snapshot {
            snapshots.push((now, runtime.shown()));
            next_snapshot += 1.0;
        }
        if now >= end {
            break;
        }
        let wait = Duration::from_secs_f64((end.min(next_snapshot) - now).clamp(0.001, 0.1));
        if let Some(e) = next_event(&runtime, wait)? {
            match e.event {
                RuntimeEvent::CellPublished { cell, lod, directions, error, settled, .. } => {
                    let p = (e.t, lod, directions, error, settled);
                    if lods.published(cell, lod) { swaps.push(p) } else { republishes.push(p) }
                }
                RuntimeEvent::CellEvicted { cell, lod, layer } => {
                    if layer == Layer::Bundles {
                        lods.evicted(cell, lod);
                    }
                    evictions += 1;
                }
                RuntimeEvent::Stats(s) => stats.push((e.t, s)),
                RuntimeEvent::Lod0Published { directions } if directions >= config.bundle.directions as u64 => {
                    lod0_complete = Some((e.t, runtime.shown()));
                }
                _ => {}
            }
        }
    }
    let t_end = runtime.elapsed();
    let (shown, cells) = runtime.snapshot();
    let end_stats = runtime.stats();
    runtime.shutdown()?;

    // The reference near the camera (not on either clock).
    ui.say(format!("  {name}: reference at {} points, {spp} paths each ...", points.len()));
    let reference = reference_at(&scene, &points, spp);
    let runtime_error = reader.error(&reference, &shown);
    let curve: Vec<Value> = snapshots
        .iter()
        .map(|(t, s)| json!({"seconds": t, "error": reader.error(&reference, s)}))
        .chain(std::iter::once(json!({"seconds": t_end, "error": runtime_error})))
        .collect();
    // The LOD shown where the points are, at the end.
    let point_lods: Vec<f64> =
        reader.at.iter().map(|&(p, _)| shown.cell_lod(Layer::Bundles, world.grid.cell_of(p)) as f64).collect();
    let finest_near = point_lods.iter().fold(0.0f64, |a, &b| a.max(b)) as u32;

    ui.say(format!("  {name}: whole-scene bakes for {t_end:.1} s each ..."));
    let lod0 = whole_bake(&scene, &config.atlas, &points, &reference, t_end, None)?;
    let fine_atlas = AtlasConfig { texel_size: Some(world.texel_size(finest_near)), ..config.atlas.clone() };
    let fine = if finest_near > 0 {
        let bake = whole_bake(&scene, &fine_atlas, &points, &reference, t_end, None)?;
        whole_bake_json(&bake, &reference, t_end, runtime_error)
    } else {
        Value::Null
    };

    let mut per_lod = vec![0usize; world.lods as usize];
    for c in &cells {
        per_lod[c.shown_lod as usize] += 1;
    }
    let swap_times: Vec<f64> = swaps.iter().map(|s| s.0).collect();
    let swap_directions: Vec<f64> = swaps.iter().map(|s| s.2 as f64).collect();
    let swap_errors: Vec<f64> = swaps.iter().map(|s| s.3 as f64).collect();
    let at_max = swaps.iter().filter(|s| s.2 >= config.max_directions as u64).count();
    let publishes = || swaps.iter().chain(&republishes);
    let settled = publishes().filter(|s| s.4).count();
    let settled_at_max = publishes().filter(|s| s.4 && s.2 >= config.max_directions as u64).count();
    let republish_directions: Vec<f64> = republishes.iter().map(|s| s.2 as f64).collect();
    let mut swaps_per_lod = vec![0usize; world.lods as usize];
    for &(_, lod, _, _, _) in &swaps {
        swaps_per_lod[lod as usize] += 1;
    }
    let refine_stats: Vec<&RuntimeStats> = stats.iter().filter(|(t, _)| *t > t_light + 1.0).map(|(_, s)| s).collect();
    let rates: Vec<f64> = refine_stats.iter().map(|s| s.texel_samples_per_second).collect();
    let peak_resident = stats.iter().map(|(_, s)| s.resident_bytes).chain([end_stats.resident_bytes]).max();
    let peak_budgeted = stats
        .iter()
        .map(|(_, s)| s.page_bytes + s.bake_bytes)
        .chain([end_stats.page_bytes + end_stats.bake_bytes])
        .max();
    let published = published_pixels(&shown);
    let refine_seconds = t_end - t_light;
    let directions = end_stats.directions_traced - stats_at_light.directions_traced;
    let units = end_stats.units - stats_at_light.units;
    let pass = &end_stats.pass;
    let traced = pass.analysis_seconds
        + pass.mip_seconds
        + pass.subdivision_seconds
        + pass.build_seconds
        + pass.resolve_seconds
        + pass.light_seconds;
    let threads = config.threads();
    Ok(json!({
        "scene": name,
        "triangles": scene.triangle_count(),
        "lods": world.lods,
        "texel_size_per_lod_m": (0..world.lods).map(|k| world.texel_size(k)).collect::<Vec<_>>(),
        "cell_size_m": world.grid.cell_size,
        "camera": {"eye": camera.eye.to_array(), "target": camera.target.to_array()},
        "first_light": {
            "runs": runs,
            "median_seconds": quantile(&first, 0.5),
            "seconds": first,
            "texels": texels,
            "cells": cells.len(),
            "directions": config.first_light_directions.min(config.bundle.directions),
            "lod0_complete_seconds": lod0_complete.as_ref().map(|l| l.0),
            "lod0_directions": config.bundle.directions,
            "first_light_pass": end_stats.first_light_pass,
        },
        "refinement": {
            "seconds": refine_seconds,
            "cells_per_shown_lod": per_lod,
            "swaps": swaps.len(),
            "swaps_per_lod": swaps_per_lod,
            "directions_per_swap": { "median": quantile(&swap_directions, 0.5), "p90": quantile(&swap_directions, 0.9) },
            "estimated_error_per_swap": { "median": quantile(&swap_errors, 0.5), "p90": quantile(&swap_errors, 0.9) },
            "swaps_at_max_directions": at_max,
            "swaps_settled": swaps.iter().filter(|s| s.4).count(),
            "republishes": republishes.len(),
            "directions_per_republish": { "median": quantile(&republish_directions, 0.5), "p90": quantile(&republish_directions, 0.9) },
            "settled_publishes": settled,
            "settled_at_max_directions": settled_at_max,
            "swap_rule": { "min_directions": config.min_directions, "max_directions": config.max_directions, "error_bound": config.error_bound },
            "swap_seconds_from_start": { "median": quantile(&swap_times, 0.5), "p90": quantile(&swap_times, 0.9), "first": swap_times.first(), "last": swap_times.last() },
            "evictions": evictions,
            "median_texel_samples_per_second": quantile(&rates, 0.5),
            "directions_per_second": directions as f64 / refine_seconds,
            "units": units,
            "unit_ms": {
                "traced_per_unit": (end_stats.units > 0).then(|| 1e3 * traced / end_stats.units as f64),
                "wall_per_unit_per_worker": (units > 0).then(|| 1e3 * refine_seconds * threads as f64 / units as f64),
                "cell_setup_total_seconds": end_stats.cell_setup_seconds,
                "directions_per_unit": config.unit_directions,
                "workers": threads,
            },
            "memory_bytes": {
                "peak_resident": peak_resident,
                "peak_pages_and_bakes": peak_budgeted,
                "resident": end_stats.resident_bytes,
                "pages": end_stats.page_bytes,
                "bakes": end_stats.bake_bytes,
                "fixed": end_stats.fixed_bytes,
                "published_pixels": published,
                "page_bytes_per_published_pixel": (published > 0).then(|| end_stats.page_bytes as f64 / published as f64),
                "resident_bytes_per_published_pixel": (published > 0).then(|| end_stats.resident_bytes as f64 / published as f64),
            },
        },
        "near_camera_error": {
            "points": points.len(),
            "reference": format!("in-crate path tracer, {spp} paths per point"),
            "measure": "relative RMS error of E, the reference's noise removed in quadrature",
            "shown_lod_at_points": { "median": quantile(&point_lods, 0.5), "max": finest_near },
            "t_seconds": t_end,
            "runtime_at_first_light": reader.error(&reference, &light_shown),
            "runtime_at_lod0_complete": lod0_complete.as_ref().map(|l| reader.error(&reference, &l.1)),
            "runtime_at_t": runtime_error,
            "runtime_median_point_error_at_t": median_point_error(&reference, &reader.values(&shown)),
            "runtime_worst_points_at_t": worst_points(&reference, &reader.values(&shown), 3),
            "runtime_curve": curve,
            "whole_bake_runtime_lod0_layout": whole_bake_json(&lod0, &reference, t_end, runtime_error),
            "whole_bake_at_finest_shown_texel": fine,
        },
    }))
}

pub fn run(bench: &Bench) -> Result<Value> {
    let (quick, ui) = (bench.quick, bench.ui);
    let rooms = ROOMS.iter().map(|r| room(r, quick, ui).with_context(|| r.to_string())).collect::<Result<Vec<_>>>()?;
    let curves: Vec<(String, Vec<(f64, f64)>)> = ROOMS
        .iter()
        .zip(&rooms)
        .flat_map(|(file, room)| {
            let name = Path::new(file).file_stem().map_or(file.to_string(), |s| s.to_string_lossy().into_owned());
            let near = &room["near_camera_error"];
            [
                (format!("{name}: runtime"), curve_points(&near["runtime_curve"])),
                (format!("{name}: whole-scene bake"), curve_points(&near["whole_bake_runtime_lod0_layout"]["curve"])),
            ]
        })
        .collect();
    let series: Vec<Series> = curves.iter().map(|(label, points)| Series { label, points }).collect();
    bench.plot_error("Near-camera error: the runtime and a whole-scene bake", &series, None)?;
    Ok(json!({
        "config": "RuntimeConfig::default(), CPU bundle backend",
        "clock": "seconds since Runtime::start (or, for whole-scene bakes, since before their atlas); the scene load and the reference are on neither",
        "rooms": rooms,
    }))
}
