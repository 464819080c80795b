//! One bundle direction on the CPU, in units the batch scheduler ([`super::batch`]) hands to
//! its threads: the plan (analysis → mips → tile plan), then each planned tile (fragment
//! build and resolve of the global bundle) and each light bundle assigned to the direction.
//! A unit writes its hits into any [`HitSink`]: the sums themselves, or records added to
//! them later in unit order.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use glam::Vec2;

use super::analysis::Analysis;
use super::emitter_rows::EmitterRows;
use super::fragments::{ForeignSides, Row, TileFragments};
use super::prefetch::prefetcher;
use super::scene::CpuScene;
use super::through::{Line, ThroughScratch};
use crate::atlas::texels::TexelEmission;
use crate::bundle::estimator::{FOREIGN, HitSink, Layering, TexelLayout, emit, exchange, is_own};
use crate::bundle::mips::MipChain;
use crate::bundle::raster::{BundleFrame, Viewport};
use crate::bundle::sky::{BundleSky, SkySeen};
use crate::bundle::stats::PassStats;
use crate::bundle::target::{BakeTarget, Cancelled, SourceRadiance};
use crate::bundle::tiles::{Tile, TilePlanner, TilingMode, bundle_resolution};
use crate::bundle::window::{WindowOutline, WindowSource, split_overflowed, tile_viewport, unplanned};
use crate::bundle::{BundleConfig, DirectionJob, LightJob};
use crate::scene::Rgb;

/// Read-only inputs shared by every thread of a batch.
pub struct PassContext<'a> {
    pub scene: &'a CpuScene,
    pub config: &'a BundleConfig,
    pub target: &'a BakeTarget<'a>,
    pub source: &'a SourceRadiance<'a>,
    /// Per triangle: rays needed per m² of bundle (the target's texel density ×
    /// oversampling²; 0 for triangles holding no target texel).
    pub importance: &'a [f32],
    /// What lines leaving the scene see.
    pub sky: &'a BundleSky,
    /// Light-pass bundle pixel side, metres.
    pub light_pixel: f32,
    pub cancel: &'a AtomicBool,
    /// Whether to trace the global bundles; `false` traces only the light bundles (the
    /// GPU backend resolves the global bundles itself and reuses the CPU's light pass).
    pub global: bool,
    /// Whether planned tiles filling over [`SPLIT_TILE_SHARE`] of the node budget are traced
    /// as their parts: when the batch has one lane, whose threads would otherwise wait
    /// behind them. Decided by the lanes, not the threads, since it changes the order hits
    /// are added in.
    pub split_large_tiles: bool,
    /// Whether a windowed target's fragments are built only inside its outline.
    pub outline_clip: bool,
    /// Hits a thread working ahead may keep waiting, per thread beyond the first
    /// ([`super::WAITING_HITS_PER_THREAD`] × N, scaled by
    /// [`crate::bundle::BundleBackend::scale_waiting_hits`]).
    pub waiting_hits: u64,
}

/// One thread's scratch buffers, reused across units, and the statistics of its units.
#[derive(Default)]
pub struct Worker {
    fragments: TileFragments,
    candidates: Vec<u32>,
    /// One bit per triangle (see [`Analysis::candidates`]).
    collected: Vec<u64>,
    /// Traversal stack of the triangles' bounds tree.
    bounds_stack: Vec<u32>,
    /// Triangles whose projection may meet the current window.
    window_triangles: Vec<u32>,
    /// Viewports still to trace of the current unit (its parts after an overflow).
    queue: Vec<Viewport>,
    /// The current light bundle's emitter silhouette.
    emitter_rows: EmitterRows,
    /// Lines through see-through surfaces and cut-outs.
    through: ThroughScratch,
    pub stats: PassStats,
}

/// A planned direction: what its units read.
pub struct DirectionPlan {
    frame: BundleFrame,
    /// What the two ends of the direction's lines see.
    sky: SkySeen,
    /// The analysis window the tiles are cut from.
    global: Viewport,
    /// Its triangle bins (the tiles gather their candidates from them).
    analysis: Analysis,
    /// The planned tiles of the global bundle in plan order, large ones as their parts
    /// ([`PassContext::split_large_tiles`]), each with whether it is a planned tile's first (none when
    /// the global bundles are not traced, or the direction could not be planned).
    tiles: Vec<(Viewport, bool)>,
    lights: usize,
}

impl DirectionPlan {
    /// Units: the tiles in plan order, then the light bundles in job order.
    pub fn units(&self) -> usize {
        self.tiles.len() + self.lights
    }

    /// Whether unit `u` is a global-bundle tile (else a light bundle).
    pub fn is_tile(&self, u: usize) -> bool {
        u < self.tiles.len()
    }
}

/// Share of the node budget above which a planned tile is traced as its four parts (the same
/// pixels, so the same hits, in another order), units of their own: a tile filling the node
/// buffer is a few times the mean tile, and threads would otherwise wait behind it.
const SPLIT_TILE_SHARE: f64 = 0.25;

/// Global-bundle hits added straight to the sums.
pub struct BundleHits<'a>(pub &'a mut [[f32; 4]]);

impl HitSink for BundleHits<'_> {
    #[inline]
    fn hit(&mut self, texel: u32, l: Rgb, a: f32) {
        let s = &mut self.0[texel as usize];
        s[0] += l.x;
        s[1] += l.y;
        s[2] += l.z;
        s[3] += a;
    }

    fn sums_layout(&self) -> TexelLayout {
        TexelLayout::of(self.0)
    }
}

/// Light-pass hits added straight to the sums.
pub struct LightHits<'a>(pub &'a mut [Rgb]);

impl HitSink for LightHits<'_> {
    #[inline]
    fn hit(&mut self, texel: u32, l: Rgb, _a: f32) {
        self.0[texel as usize] += l;
    }

    fn sums_layout(&self) -> TexelLayout {
        TexelLayout::of(self.0)
    }
}

fn seconds(t: Instant) -> f64 {
    t.elapsed().as_secs_f64()
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

/// The outline of the target's window along `frame` (a windowed pass; see [`WindowOutline`]).
fn target_outline(ctx: &PassContext, frame: &BundleFrame) -> Option<WindowOutline> {
    ctx.target.window.filter(|_| ctx.outline_clip).map(|w| WindowOutline::new(frame, w))
}

/// The triangles that may touch `vp`, from the analysis bins over `global`.
fn gather(analysis: &Analysis, global: &Viewport, vp: &Viewport, collected: &mut Vec<u64>, out: &mut Vec<u32>) {
    let lo = (vp.corner() - global.origin) / global.pixel;
    let hi = lo + Vec2::new(vp.width as f32, vp.height as f32) * (vp.pixel / global.pixel);
    analysis.candidates(lo.x as f64, lo.y as f64, hi.x as f64, hi.y as f64, collected, out);
}

/// Foreign sides looked up by a tile's resolve: resolved, and lost (no foreign source).
#[derive(Default)]
struct ForeignLookups {
    resolved: u64,
    lost: u64,
}

/// The radiance a bundle line sees of the side with code `code` at grid centre (cx, cy):
/// a target texel's source, or a foreign side's radiance at its surface point (black, and
/// counted lost, when the source has no foreign radiance).
#[inline(always)]
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
    seen_foreign(source, foreign, code, cx, cy, lookups)
}

/// [`seen`] of a foreign side at the surface point `at` gives, out of line: a whole LOD has
/// none, a cell's bake a few.
#[inline(never)]
fn seen_foreign(
    source: &SourceRadiance,
    foreign: &ForeignSides,
    code: u32,
    cx: f32,
    cy: f32,
    lookups: &mut ForeignLookups,
) -> Rgb {
    match source.foreign {
        Some(f) => {
            lookups.resolved += 1;
            if f.by_lod_pixel() {
                return foreign.lod_pixel(code, cx, cy).map_or(Rgb::ZERO, |(x, y)| f.radiance_at(x, y));
            }
            let (tri, side, u, v) = foreign.locate(code, cx, cy);
            f.radiance(tri, side, u, v)
        }
        None => {
            lookups.lost += 1;
            Rgb::ZERO
        }
    }
}

/// Where the fragments of pixel (cx, cy) of `viewport` lie, for their transmittances.
fn line<'a>(
    ctx: &'a PassContext,
    frame: &'a BundleFrame,
    viewport: &'a Viewport,
    foreign: &'a ForeignSides<'a>,
    cx: f32,
    cy: f32,
) -> Line<'a> {
    let bundle = &ctx.scene.bundle;
    Line {
        scene: &bundle.scene,
        geom: &bundle.geom,
        atlas: &bundle.atlas,
        target: ctx.target,
        frame,
        viewport,
        foreign,
        foreign_as_own: ctx.source.foreign.is_some_and(|f| f.by_lod_pixel()),
        cx,
        cy,
    }
}

/// Plans direction `job`: analysis, mips and tile plan of its global bundle (when the pass
/// traces global bundles; a direction that cannot be planned gets no tiles and is counted
/// in `w.stats`, which the driver refuses), and its light bundles.
pub fn plan_direction(ctx: &PassContext, job: &DirectionJob, w: &mut Worker) -> Result<DirectionPlan, Cancelled> {
    let cfg = ctx.config;
    let frame = BundleFrame::new(job.dir);
    let global = window(ctx).analysis_viewport(cfg, &frame, job.jitter);
    let mut plan = DirectionPlan {
        frame,
        sky: ctx.sky.seen(frame.dir),
        global,
        analysis: Analysis::default(),
        tiles: Vec::new(),
        lights: job.lights.len(),
    };
    if !ctx.global {
        return Ok(plan);
    }
    let (frame, global) = (&plan.frame, &plan.global);
    w.stats.directions += 1;

    let t = Instant::now();
    let candidates = match ctx.target.window {
        None => None,
        Some(_) => {
            let side = global.pixel * global.width as f32;
            ctx.scene.bounds.overlapping(frame, global.origin, side, &mut w.bounds_stack, &mut w.window_triangles);
            Some(&w.window_triangles[..])
        }
    };
    plan.analysis.run(ctx.scene, frame, global, candidates, ctx.importance);
    w.stats.analysis_seconds += seconds(t);

    let t = Instant::now();
    let res = global.width;
    let importance = MipChain::max_mips(res, std::mem::take(&mut plan.analysis.importance));
    let fragments = MipChain::average_mips(res, std::mem::take(&mut plan.analysis.fragments));
    w.stats.mip_seconds += seconds(t);
    // The config is validated when it is built, so none of these fail in practice; if one
    // does, the direction is counted as unplanned and the driver refuses the result.
    let (importance, fragments) = match (importance, fragments) {
        (Ok(i), Ok(f)) => (i, f),
        (Err(e), _) | (_, Err(e)) => {
            unplanned(&mut w.stats, &e);
            return Ok(plan);
        }
    };

    let t = Instant::now();
    let params = cfg.tile_params(global.pixel);
    let planned =
        TilePlanner::new(&importance, &fragments, params).and_then(|p| p.plan(cfg.tiling).map(|plan| (p, plan)));
    let (planner, tiles) = match planned {
        Ok(planned) => planned,
        Err(e) => {
            unplanned(&mut w.stats, &e);
            return Ok(plan);
        }
    };
    w.stats.subdivision_seconds += seconds(t);
    w.stats.add_plan(&tiles.stats);

    if cfg.measure_false_alarms && cfg.tiling == TilingMode::Adaptive {
        count_false_alarms(ctx, &planner, &tiles.tiles, &plan, w)?;
    }
    let split_above =
        if ctx.split_large_tiles { SPLIT_TILE_SHARE * planner.params().node_budget() } else { f64::INFINITY };
    for tile in &tiles.tiles {
        let vp = tile_viewport(&plan.global, tile);
        match vp.split() {
            Some(parts) if planner.predicted_nodes(tile) > split_above => {
                plan.tiles.extend(parts.into_iter().enumerate().map(|(k, part)| (part, k == 0)));
            }
            _ => plan.tiles.push((vp, true)),
        }
    }
    Ok(plan)
}

/// Traces unit `u` of `plan` (direction `job`) into `bundle` (a tile) or `light` (a light
/// bundle).
pub fn trace_unit(
    ctx: &PassContext,
    job: &DirectionJob,
    plan: &DirectionPlan,
    u: usize,
    w: &mut Worker,
    bundle: &mut impl HitSink,
    light: &mut impl HitSink,
) -> Result<(), Cancelled> {
    match plan.tiles.get(u) {
        Some((tile, first)) => trace_tile(ctx, plan, tile, *first, w, bundle),
        None => {
            let t = Instant::now();
            let r = trace_light(ctx, &job.lights[u - plan.tiles.len()], w, light);
            w.stats.light_seconds += seconds(t);
            r
        }
    }
}

/// One planned tile of a global bundle (or a part of one: `first` says whether it counts as
/// the tile in the statistics): fragment build and resolve, split in parts (in order) while
/// it overflows the node buffer.
fn trace_tile(
    ctx: &PassContext,
    plan: &DirectionPlan,
    tile: &Viewport,
    first: bool,
    w: &mut Worker,
    sink: &mut impl HitSink,
) -> Result<(), Cancelled> {
    let cfg = ctx.config;
    let mut lookups = ForeignLookups::default();
    let outline = target_outline(ctx, &plan.frame);
    w.queue.clear();
    w.queue.push(*tile);
    while let Some(vp) = w.queue.pop() {
        check(ctx)?;
        gather(&plan.analysis, &plan.global, &vp, &mut w.collected, &mut w.candidates);
        let t = Instant::now();
        let count = w.fragments.prepare(ctx.scene, &plan.frame, &vp, &w.candidates, None, outline.as_ref());
        let stats = &mut w.stats;
        if count > cfg.node_capacity && split_overflowed(&vp, count, cfg.node_capacity, &mut w.queue, stats) {
            stats.build_seconds += seconds(t);
            continue;
        }
        stats.build_seconds += seconds(t);
        stats.tiles += u64::from(first || vp != *tile);
        stats.fragments += count;
        stats.peak_tile_fragments = stats.peak_tile_fragments.max(count);

        let t = Instant::now();
        let (a_px, source) = (vp.pixel_area(), ctx.source);
        let (sky, layering) = (plan.sky, ctx.scene.coincidence_at(vp.pixel).layering());
        let lines = OpaqueLines { source: *source, sky, layering, a_px };
        let prefetch = prefetcher(TexelLayout::of(ctx.source.own), sink.sums_layout());
        stats.covered_pixels += w.fragments.resolve(ctx.scene, ctx.target, prefetch, |row| match &ctx.scene.passing {
            None => exchange_row(row, &lines, &mut lookups, sink),
            Some(passing) => row.for_each_pixel(|f, foreign, cx, cy| {
                let line = line(ctx, &plan.frame, &vp, foreign, cx, cy);
                let seen = |code| seen(source, foreign, code, cx, cy, &mut lookups);
                passing.exchange(f, &line, layering, a_px, sky, seen, sink, &mut w.through)
            }),
        });
        stats.resolve_seconds += seconds(t);
    }
    w.stats.lost_lookups += lookups.lost;
    w.stats.foreign_lookups += lookups.resolved;
    Ok(())
}

/// What every pixel of a tile's resolve reads besides its fragments, where no surface lets
/// light through.
struct OpaqueLines<'a> {
    source: SourceRadiance<'a>,
    sky: SkySeen,
    layering: Layering,
    a_px: f32,
}

/// The exchange of every covered pixel of one row. Out of line: inside the whole tile pass the
/// pixel loop kept its state on the stack (the pass's own values took the registers), a
/// store and a load for most of what a pixel reads.
#[inline(never)]
fn exchange_row(row: &mut Row, lines: &OpaqueLines, lookups: &mut ForeignLookups, sink: &mut impl HitSink) {
    let OpaqueLines { source, sky, layering, a_px } = lines;
    row.for_each_pixel(|f, foreign, cx, cy| {
        exchange(f, *layering, *a_px, *sky, |code| seen(source, foreign, code, cx, cy, lookups), sink)
    });
}

/// What every pixel of a light bundle's resolve reads besides its fragments, where no
/// surface lets light through.
struct EmitterLines<'a> {
    own: TexelEmission<'a>,
    source: SourceRadiance<'a>,
    layering: Layering,
    a_px: f32,
}

/// The light-pass exchange of every covered pixel of one row, out of line as
/// [`exchange_row`] is; `covered` counts the pixels with an emitter.
#[inline(never)]
fn emit_row(row: &mut Row, lines: &EmitterLines, lost: &mut u64, covered: &mut u64, sink: &mut impl HitSink) {
    let EmitterLines { own, source, layering, a_px } = lines;
    row.for_each_pixel(|f, foreign, cx, cy| {
        *covered += f.iter().any(|f| f.is_emitter()) as u64;
        emit(f, *layering, *a_px, |code| emission(*own, source, foreign, code, cx, cy, lost), sink)
    });
}

/// The emitted radiance of the side with code `code` at grid centre (cx, cy): a target
/// texel's, or a foreign side's at its surface point (black, and counted lost, when the source
/// has no foreign emission).
#[inline(always)]
fn emission(
    own: TexelEmission,
    source: &SourceRadiance,
    foreign: &ForeignSides,
    code: u32,
    cx: f32,
    cy: f32,
    lost: &mut u64,
) -> Rgb {
    if is_own(code) {
        return own.at(code as usize);
    }
    // Out of line, as [`seen_foreign`] is.
    #[inline(never)]
    fn elsewhere(source: &SourceRadiance, sides: &ForeignSides, code: u32, at: (f32, f32), lost: &mut u64) -> Rgb {
        match source.foreign {
            Some(src) if src.by_lod_pixel() => {
                sides.lod_pixel(code, at.0, at.1).map_or(Rgb::ZERO, |(x, y)| src.emission_at(x, y))
            }
            Some(src) => {
                let (tri, side, u, v) = sides.locate(code, at.0, at.1);
                src.emission(tri, side, u, v)
            }
            None => {
                *lost += 1;
                Rgb::ZERO
            }
        }
    }
    elsewhere(source, foreign, code, (cx, cy), lost)
}

/// False alarms (paper Table 2): splits for predicted memory overflow where the tile, at the
/// resolution it asked for, would in fact have fitted in the node buffer. Fragment counts
/// come from exact span counting, so this costs one count pass per such split.
fn count_false_alarms(
    ctx: &PassContext,
    planner: &TilePlanner,
    tiles: &[Tile],
    plan: &DirectionPlan,
    w: &mut Worker,
) -> Result<(), Cancelled> {
    let (frame, global) = (&plan.frame, &plan.global);
    let outline = target_outline(ctx, frame);
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
                w.stats.memory_splits_checked += 1;
                let res = bundle_resolution(rays, w2);
                let vp = tile_viewport(global, &Tile { level: level as i32, x, y, res });
                gather(&plan.analysis, global, &vp, &mut w.collected, &mut w.candidates);
                let count = w.fragments.prepare(ctx.scene, frame, &vp, &w.candidates, None, outline.as_ref());
                if count <= ctx.config.node_capacity {
                    w.stats.false_alarms += 1;
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
fn trace_light(ctx: &PassContext, job: &LightJob, s: &mut Worker, sink: &mut impl HitSink) -> Result<(), Cancelled> {
    let sums = sink.sums_layout();
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
    let outline = target_outline(ctx, &frame);
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
        let count = s.fragments.prepare(ctx.scene, &frame, &vp, &candidates, Some(job.group), outline.as_ref());
        let stats = &mut s.stats;
        if count > cfg.node_capacity && split_overflowed(&vp, count, cfg.node_capacity, &mut s.queue, stats) {
            continue;
        }
        stats.light_tiles += 1;
        stats.light_fragments += count;
        stats.peak_tile_fragments = stats.peak_tile_fragments.max(count);
        let a_px = vp.pixel_area();
        let layering = ctx.scene.coincidence_at(vp.pixel).layering();
        let (own, source) = (ctx.target.emission, ctx.source);
        // Emission is read for emitter texels alone: only the sums are worth fetching.
        let prefetch = prefetcher(TexelLayout::NONE, sums);
        let lines = EmitterLines { own, source: *source, layering, a_px };
        s.fragments.resolve(ctx.scene, ctx.target, prefetch, |row| match &ctx.scene.passing {
            None => emit_row(row, &lines, &mut lost, &mut stats.light_covered_pixels, sink),
            Some(passing) => row.for_each_pixel(|f, foreign, cx, cy| {
                stats.light_covered_pixels += f.iter().any(|f| f.is_emitter()) as u64;
                let emission = |code| emission(own, source, foreign, code, cx, cy, &mut lost);
                let line = line(ctx, &frame, &vp, foreign, cx, cy);
                passing.emit(f, &line, layering, a_px, emission, sink, &mut s.through)
            }),
        });
    }
    s.stats.lost_lookups += lost;
    s.candidates = candidates;
    result
}
