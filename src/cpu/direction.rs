//! One bundle direction on the CPU: analysis → mips → tile plan → per tile fragment build
//! and resolve (global bundles), then the light bundles assigned to that direction.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use glam::Vec2;

use super::analysis::Analysis;
use super::emitter_rows::EmitterRows;
use super::fragments::{ForeignSides, TileFragments};
use super::scene::CpuScene;
use crate::bundle::estimator::{FOREIGN, HitSink, emit, exchange, is_own};
use crate::bundle::mips::MipChain;
use crate::bundle::progressive::BatchSums;
use crate::bundle::raster::{BundleFrame, Viewport};
use crate::bundle::stats::PassStats;
use crate::bundle::target::{BakeTarget, Cancelled, SourceRadiance};
use crate::bundle::tiles::{Tile, TilePlanner, TilingMode, bundle_resolution};
use crate::bundle::window::{WindowSource, split_overflowed, tile_viewport, unplanned};
use crate::bundle::{BundleConfig, DirectionJob, LightJob};
use crate::scene::Rgb;

/// Read-only inputs shared by every lane of a batch.
pub struct PassContext<'a> {
    pub scene: &'a CpuScene,
    pub config: &'a BundleConfig,
    pub target: &'a BakeTarget<'a>,
    pub source: &'a SourceRadiance<'a>,
    /// Per triangle: rays needed per m² of bundle (the target's texel density ×
    /// oversampling²; 0 for triangles holding no target texel).
    pub importance: &'a [f32],
    pub sky: Rgb,
    /// Light-pass bundle pixel side, metres.
    pub light_pixel: f32,
    pub cancel: &'a AtomicBool,
    /// Whether to trace the global bundles; `false` traces only the light bundles (the
    /// GPU backend resolves the global bundles itself and reuses the CPU's light pass).
    pub global: bool,
}

/// Per-lane scratch buffers, reused across directions.
#[derive(Default)]
pub struct Scratch {
    analysis: Analysis,
    fragments: TileFragments,
    candidates: Vec<u32>,
    /// Traversal stack of the triangles' bounds tree.
    bounds_stack: Vec<u32>,
    /// Triangles whose projection may meet the current window.
    window_triangles: Vec<u32>,
    queue: Vec<Viewport>,
    /// The current light bundle's emitter silhouette.
    emitter_rows: EmitterRows,
}

struct BundleHits<'a>(&'a mut [[f32; 4]]);

impl HitSink for BundleHits<'_> {
    #[inline]
    fn hit(&mut self, texel: u32, l: Rgb, a: f32) {
        let s = &mut self.0[texel as usize];
        s[0] += l.x;
        s[1] += l.y;
        s[2] += l.z;
        s[3] += a;
    }
}

struct LightHits<'a>(&'a mut [Rgb]);

impl HitSink for LightHits<'_> {
    #[inline]
    fn hit(&mut self, texel: u32, l: Rgb, _a: f32) {
        self.0[texel as usize] += l;
    }
}

fn seconds(t: Instant) -> f64 {
    t.elapsed().as_secs_f64()
}

/// Traces global direction `job` and its light bundles into `sums`.
pub fn trace_direction(
    ctx: &PassContext,
    job: &DirectionJob,
    sums: &mut BatchSums,
    s: &mut Scratch,
    stats: &mut PassStats,
) -> Result<(), Cancelled> {
    if ctx.global {
        trace_global(ctx, job, sums, s, stats)?;
        stats.directions += 1;
    }
    let t = Instant::now();
    for light in &job.lights {
        trace_light(ctx, light, sums, s, stats)?;
    }
    stats.light_seconds += seconds(t);
    Ok(())
}

fn check(ctx: &PassContext) -> Result<(), Cancelled> {
    if ctx.cancel.load(Ordering::Relaxed) { Err(Cancelled) } else { Ok(()) }
}

/// The window source of this pass's target.
fn window(ctx: &PassContext) -> WindowSource {
    WindowSource {
        target: ctx.target.window,
        centre: ctx.scene.centre,
        radius: ctx.scene.radius,
        bundle_pixel: ctx.light_pixel,
    }
}

/// The triangles that may touch `vp`, from the analysis bins over `global`.
fn gather(analysis: &mut Analysis, global: &Viewport, vp: &Viewport, out: &mut Vec<u32>) {
    let lo = (vp.corner() - global.origin) / global.pixel;
    let hi = lo + Vec2::new(vp.width as f32, vp.height as f32) * (vp.pixel / global.pixel);
    analysis.candidates(lo.x as f64, lo.y as f64, hi.x as f64, hi.y as f64, out);
}

/// Foreign sides looked up by a direction's resolve: resolved, and lost (no foreign source).
#[derive(Default)]
struct ForeignLookups {
    resolved: u64,
    lost: u64,
}

/// The radiance a bundle line sees of the side with code `code` at grid centre (cx, cy):
/// a target texel's source, or a foreign side's radiance at its surface point (black, and
/// counted lost, when the source has no foreign radiance).
#[inline]
fn seen(
    source: &SourceRadiance,
    foreign: &ForeignSides,
    code: u32,
    cx: f32,
    cy: f32,
    lookups: &mut ForeignLookups,
) -> Rgb {
    if is_own(code) {
        return source.own[code as usize];
    }
    debug_assert!(code >= FOREIGN);
    match source.foreign {
        Some(f) => {
            lookups.resolved += 1;
            let (tri, side, u, v) = foreign.locate(code, cx, cy);
            f.radiance(tri, side, u, v)
        }
        None => {
            lookups.lost += 1;
            Rgb::ZERO
        }
    }
}

fn trace_global(
    ctx: &PassContext,
    job: &DirectionJob,
    sums: &mut BatchSums,
    s: &mut Scratch,
    stats: &mut PassStats,
) -> Result<(), Cancelled> {
    let cfg = ctx.config;
    let frame = BundleFrame::new(job.dir);
    let global = window(ctx).analysis_viewport(cfg, &frame, job.jitter);

    let t = Instant::now();
    let candidates = match ctx.target.window {
        None => None,
        Some(_) => {
            let side = global.pixel * global.width as f32;
            ctx.scene.bounds.overlapping(&frame, global.origin, side, &mut s.bounds_stack, &mut s.window_triangles);
            Some(&s.window_triangles[..])
        }
    };
    s.analysis.run(ctx.scene, &frame, &global, candidates, ctx.importance);
    stats.analysis_seconds += seconds(t);

    let t = Instant::now();
    let res = global.width;
    let importance = MipChain::max_mips(res, std::mem::take(&mut s.analysis.importance));
    let fragments = MipChain::average_mips(res, std::mem::take(&mut s.analysis.fragments));
    stats.mip_seconds += seconds(t);
    // The config is validated when it is built, so none of these fail in practice; if one
    // does, the direction is counted as unplanned and the driver refuses the result.
    let (importance, fragments) = match (importance, fragments) {
        (Ok(i), Ok(f)) => (i, f),
        (Err(e), _) | (_, Err(e)) => {
            unplanned(stats, &e);
            return Ok(());
        }
    };

    let t = Instant::now();
    let params = cfg.tile_params(global.pixel);
    let planned =
        TilePlanner::new(&importance, &fragments, params).and_then(|p| p.plan(cfg.tiling).map(|plan| (p, plan)));
    let (planner, plan) = match planned {
        Ok(planned) => planned,
        Err(e) => {
            unplanned(stats, &e);
            return Ok(());
        }
    };
    stats.subdivision_seconds += seconds(t);
    stats.add_plan(&plan.stats);

    if cfg.measure_false_alarms && cfg.tiling == TilingMode::Adaptive {
        count_false_alarms(ctx, &planner, &plan.tiles, &frame, &global, s, stats)?;
    }

    s.queue.clear();
    s.queue.extend(plan.tiles.iter().rev().map(|tile| tile_viewport(&global, tile)));
    let mut lookups = ForeignLookups::default();
    while let Some(vp) = s.queue.pop() {
        check(ctx)?;
        gather(&mut s.analysis, &global, &vp, &mut s.candidates);
        let t = Instant::now();
        let count = s.fragments.prepare(ctx.scene, &frame, &vp, &s.candidates, None);
        if count > cfg.node_capacity && split_overflowed(&vp, count, cfg.node_capacity, &mut s.queue, stats) {
            stats.build_seconds += seconds(t);
            continue;
        }
        stats.build_seconds += seconds(t);
        stats.tiles += 1;
        stats.fragments += count;
        stats.peak_tile_fragments = stats.peak_tile_fragments.max(count);

        let t = Instant::now();
        let a_px = vp.pixel_area();
        let (sky, source, coincidence) = (ctx.sky, ctx.source, ctx.scene.coincidence_at(vp.pixel));
        let mut sink = BundleHits(&mut sums.bundle);
        stats.covered_pixels += s.fragments.resolve(ctx.scene, ctx.target, |f, foreign, cx, cy| {
            exchange(f, coincidence, a_px, sky, |code| seen(source, foreign, code, cx, cy, &mut lookups), &mut sink)
        });
        stats.resolve_seconds += seconds(t);
    }
    stats.lost_lookups += lookups.lost;
    stats.foreign_lookups += lookups.resolved;
    Ok(())
}

/// False alarms (paper Table 2): splits for predicted memory overflow where the tile, at the
/// resolution it asked for, would in fact have fitted in the node buffer. Fragment counts
/// come from exact span counting, so this costs one count pass per such split.
fn count_false_alarms(
    ctx: &PassContext,
    planner: &TilePlanner,
    tiles: &[Tile],
    frame: &BundleFrame,
    global: &Viewport,
    s: &mut Scratch,
    stats: &mut PassStats,
) -> Result<(), Cancelled> {
    let mut seen = std::collections::BTreeSet::new();
    let top_level = global.width.trailing_zeros();
    for tile in tiles {
        let mut level = tile.level.max(0) as u32 + 1;
        let (mut x, mut y) = (tile.x >> 1, tile.y >> 1);
        if tile.level < 0 {
            continue;
        }
        while level <= top_level {
            if !seen.insert((level, x, y)) {
                break;
            }
            let rays = planner.rays_needed(level, x, y);
            let w2 = (ctx.config.head_side as f64).powi(2);
            if rays <= w2 {
                // The split was for memory (importance alone fitted in W×W).
                stats.memory_splits_checked += 1;
                let res = bundle_resolution(rays, w2);
                let vp = tile_viewport(global, &Tile { level: level as i32, x, y, res });
                gather(&mut s.analysis, global, &vp, &mut s.candidates);
                let count = s.fragments.prepare(ctx.scene, frame, &vp, &s.candidates, None);
                if count <= ctx.config.node_capacity {
                    stats.false_alarms += 1;
                }
            }
            level += 1;
            x >>= 1;
            y >>= 1;
        }
        check(ctx)?;
    }
    Ok(())
}

/// One light bundle: the window around an emitter group's footprint along ω (cut to the
/// target's window, where only target texels can be lit), in tiles of at most W×W pixels;
/// emitter fragments light the neighbours facing them.
fn trace_light(
    ctx: &PassContext,
    job: &LightJob,
    sums: &mut BatchSums,
    s: &mut Scratch,
    stats: &mut PassStats,
) -> Result<(), Cancelled> {
    let cfg = ctx.config;
    let group = &ctx.scene.bundle.emitters.small[job.group as usize];
    let frame = BundleFrame::new(job.dir);
    let (mut lo, mut hi) = (Vec2::splat(f32::MAX), Vec2::splat(f32::MIN));
    for c in group.corners() {
        let f = frame.coords(c);
        lo = lo.min(Vec2::new(f.x, f.y));
        hi = hi.max(Vec2::new(f.x, f.y));
    }
    if ctx.target.window.is_some() {
        let (corner, side) = window(ctx).square(&frame);
        lo = lo.max(corner);
        hi = hi.min(corner + Vec2::splat(side));
        if lo.x > hi.x || lo.y > hi.y {
            return Ok(());
        }
    }
    let pixel = ctx.light_pixel;
    let origin = lo - (job.jitter + Vec2::ONE) * pixel;
    let extent = (hi - origin).max_element() + pixel;
    let res = (extent / pixel).ceil().max(1.0) as u32;
    let per_side = res.div_ceil(cfg.head_side);
    let tile_res = res.div_ceil(per_side);
    // Only triangles reaching a pixel between the group's emitter spans can take part.
    let grid = Viewport::square(origin, pixel, tile_res * per_side);
    s.emitter_rows.fill(&ctx.scene.bundle.geom, &group.triangles, &frame, &grid);
    let rows = &s.emitter_rows;
    ctx.scene.bounds.select(&frame, |lo, hi| rows.reaches(lo, hi), &mut s.bounds_stack, &mut s.candidates);
    let candidates = std::mem::take(&mut s.candidates);
    s.queue.clear();
    for ty in (0..per_side).rev() {
        for tx in (0..per_side).rev() {
            let corner = origin + Vec2::new(tx as f32, ty as f32) * (tile_res as f32 * pixel);
            s.queue.push(Viewport::square(corner, pixel, tile_res));
        }
    }
    let mut lost = 0u64;
    let mut result = Ok(());
    while let Some(vp) = s.queue.pop() {
        if let Err(c) = check(ctx) {
            result = Err(c);
            break;
        }
        let count = s.fragments.prepare(ctx.scene, &frame, &vp, &candidates, Some(job.group));
        if count > cfg.node_capacity && split_overflowed(&vp, count, cfg.node_capacity, &mut s.queue, stats) {
            continue;
        }
        stats.light_tiles += 1;
        stats.light_fragments += count;
        stats.peak_tile_fragments = stats.peak_tile_fragments.max(count);
        let a_px = vp.pixel_area();
        let coincidence = ctx.scene.coincidence_at(vp.pixel);
        let (own, source) = (ctx.target.emission, ctx.source);
        let mut sink = LightHits(&mut sums.light);
        s.fragments.resolve(ctx.scene, ctx.target, |f, foreign, cx, cy| {
            stats.light_covered_pixels += f.iter().any(|f| f.is_emitter()) as u64;
            emit(
                f,
                coincidence,
                a_px,
                |code| {
                    if is_own(code) {
                        return own.at(code as usize);
                    }
                    match source.foreign {
                        Some(src) => {
                            let (tri, side, u, v) = foreign.locate(code, cx, cy);
                            src.emission(tri, side, u, v)
                        }
                        None => {
                            lost += 1;
                            Rgb::ZERO
                        }
                    }
                },
                &mut sink,
            )
        });
    }
    stats.lost_lookups += lost;
    s.candidates = candidates;
    result
}
