//! Hot reload: a good save of the scene's files replaces the world the runtime serves.
//!
//! What a change invalidates (docs/ARCHITECTURE.md "Hot reload"):
//! * meshes moved, edited, added or removed: the atlas is updated in place (unchanged
//!   meshes keep their charts, so their published pages stay valid); the cells meeting the
//!   changed meshes' old or new bounds, grown by the mesh's own size for its shadows and
//!   bounce ([`invalidation_margin`]), drop to LOD 0 and are re-baked first — one progressive
//!   bake of all their LOD-0 texels together (multi-bounce among them as at first light; the
//!   rest of the scene seen through the shown map) with
//!   [`reload_directions`](super::RuntimeConfig::reload_directions), a quarter of first
//!   light's by default. They are published at once and marked provisional: the workers
//!   re-bake each at LOD 0 with first light's directions before any other work
//!   (`reload_refined` when none is left). Every other cell keeps its LOD but is marked
//!   stale: its indirect light predates the change; a stale cell is refreshed (re-baked at
//!   its shown LOD) when no refinement is waiting, or refined (which refreshes it too);
//! * a light, the sky or a material changed (a moved sun too: [`reload_thread`] applies new
//!   surroundings as it applies a save), or nothing fitted in the atlas (a full repack):
//!   everything is affected; LOD 0 is re-baked everywhere as first light bakes it, keeping
//!   the grid, and served after first light's `first_light_directions`.
//!
//! The new world is served (`reload_applied`) once its LOD 0 is published where it was
//! invalidated (`reload_relit`); until then the old one is, so nothing is ever half applied.
//! Workers wait while the re-bake runs (it uses every core).

use std::collections::BTreeSet;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use glam::Vec3;

use super::scheduler::{
    CellState, PixelLists, Refining, Shared, bake_first_light_observed, empty_shown, take_camera, update_views,
};
use super::shown::{Layer, PageWriter, ShownLightmap};
use super::source::ShownSource;
use super::world::World;
use super::{ReloadSteps, RuntimeError, RuntimeEvent};
use crate::atlas::Atlas;
use crate::atlas::chart_filter::filter_within_charts;
use crate::atlas::sparse::SparseTexels;
use crate::atlas::update::MeshOrigin;
use crate::bake::bundle::{PunctualPass, Region, bake_region};
use crate::bundle::{BundleConfig, BundleScene};
use crate::grid::CellId;
use crate::progress::NoProgress;
use crate::scene::{Rgb, Scene, SceneGeometry, Surroundings};
use crate::watch::{Aabb, SceneDiff, SceneWatcher, WatchEvent};
use crossbeam_channel::Receiver;

/// How far around a changed mesh's bounds (old or new) the cells re-baked with it reach,
/// metres: the mesh's own size (the largest side of those bounds), at least
/// [`MIN_MARGIN_TEXELS`] LOD-0 texels. Farther cells keep their light, marked stale, and are
/// refreshed later.
///
/// Why its size: what a mesh changes around it is the light it blocks and the light it
/// bounces. Seen from a point at distance `d` beyond its bounds, a mesh of size `s` covers
/// a solid angle of about `s² / (d + s/2)²`: at `d = s` some 0.44 sr, at most 14 % of the
/// cosine-weighted hemisphere (and much less at the grazing angles of the floor or wall it
/// stands on), so the change there is a few per cent of the irradiance and falls off as
/// `1/d²` beyond. Its shadow under a light above it reaches about its height beyond its
/// footprint. A margin in cells (the rule before) grew with the grid, not the change: cells
/// are at least 16 LOD-0 texels wide, so two of them covered most of a small room for a
/// 0.1 m move. What this leaves out — a long shadow cast by a low light, the faint bounce
/// beyond — is in the stale cells, refreshed at lower priority (see the module docs).
pub fn invalidation_margin(bounds: &Aabb, texel0: f32) -> f32 {
    let size = (bounds.max - bounds.min).max_element();
    let floor = MIN_MARGIN_TEXELS * texel0;
    if size.is_finite() { size.max(floor) } else { floor }
}

/// The least invalidation margin, in LOD-0 texels: the texels touching a changed surface,
/// and their filter neighbours (the published LOD 0 is filtered over 3×3 texels), are
/// re-baked even for a flat or tiny mesh.
pub const MIN_MARGIN_TEXELS: f32 = 2.0;

/// What the reload thread is asked to do.
pub(super) enum ReloadRequest {
    /// Follow this watcher's scenes (hot reload).
    Watch(SceneWatcher),
    /// Light the scene with these surroundings (a moved sun), asked for at that instant.
    Surroundings(Surroundings, Instant),
}

/// The one thread that replaces the world: scenes from the watcher (once one is given) and
/// new surroundings from the front end, one at a time, in the order they come. Of several
/// surroundings waiting only the last is applied (a sun dragged across the sky re-lights for
/// where it is, not for every step of the way); one arriving while the previous is still
/// being baked at full quality cuts that bake short (`cancel`, raised by
/// [`Runtime::set_surroundings`](super::Runtime::set_surroundings)).
pub(super) fn reload_thread(shared: &Shared, requests: Receiver<ReloadRequest>, cancel: &AtomicBool) {
    let mut watcher: Option<SceneWatcher> = None;
    loop {
        if shared.shutdown.load(Ordering::SeqCst) {
            return;
        }
        let never = crossbeam_channel::never();
        let events = watcher.as_ref().map_or(&never, |w| w.events());
        let timeout = crossbeam_channel::after(std::time::Duration::from_millis(100));
        crossbeam_channel::select! {
            recv(requests) -> r => match r {
                Ok(ReloadRequest::Watch(w)) => watcher = Some(w),
                Ok(ReloadRequest::Surroundings(mut surroundings, mut asked)) => {
                    // Only the latest of those waiting.
                    while let Ok(next) = requests.try_recv() {
                        match next {
                            ReloadRequest::Surroundings(s, t) => (surroundings, asked) = (s, t),
                            ReloadRequest::Watch(w) => watcher = Some(w),
                        }
                    }
                    cancel.store(false, Ordering::SeqCst);
                    relight_with(shared, &surroundings, asked, cancel);
                }
                Err(_) => return,
            },
            recv(events) -> e => match e {
                Ok(event) => on_watch_event(shared, event, cancel),
                Err(_) => watcher = None,
            },
            recv(timeout) -> _ => {}
        }
    }
}

fn on_watch_event(shared: &Shared, event: WatchEvent, cancel: &AtomicBool) {
    match event {
        WatchEvent::Started { paths, .. } => {
            shared.emit(RuntimeEvent::ReloadStarted { paths: paths.iter().map(|p| p.display().to_string()).collect() })
        }
        WatchEvent::Failed { path, error, .. } => {
            shared.emit(RuntimeEvent::ReloadFailed { path: path.display().to_string(), error })
        }
        WatchEvent::Loaded { scene, seen_at, .. } => {
            // The file's scene under the surroundings shown now (a moved sun stays moved), the
            // stand-in sky decided again (the save may have added or removed its light).
            let (current, automatic) = {
                let shown = &shared.lock().world.scene;
                (shown.surroundings(), shown.sky_automatic)
            };
            let mut scene = Arc::unwrap_or_clone(scene);
            scene.sky_automatic = automatic;
            let result =
                scene.set_surroundings(&current).map_err(|e| RuntimeError::BadOption(e.to_string())).and_then(|()| {
                    stand_in_sky(&mut scene);
                    apply(shared, Arc::new(scene), seen_at, cancel)
                });
            if let Err(e) = result {
                let path = shared.lock().world.scene.source.as_ref().map(|p| p.display().to_string());
                shared.emit(RuntimeEvent::ReloadFailed { path: path.unwrap_or_default(), error: e.to_string() });
            }
        }
    }
}

/// [`Scene::stand_in_sky`](crate::scene::Scene::stand_in_sky) for a scene about to be shown,
/// said when it lights the scene.
fn stand_in_sky(scene: &mut crate::scene::Scene) {
    if scene.stand_in_sky() {
        tracing::info!("nothing lights the scene: a white sky of {} W/(sr·m²) stands in", crate::scene::STAND_IN_SKY);
    }
}

/// The served scene with `surroundings` instead of its own, applied as a light change.
fn relight_with(shared: &Shared, surroundings: &Surroundings, asked: Instant, cancel: &AtomicBool) {
    let old = shared.lock().world.scene.clone();
    let mut scene = (*old).clone();
    let result =
        scene.set_surroundings(surroundings).map_err(|e| RuntimeError::BadOption(e.to_string())).and_then(|()| {
            stand_in_sky(&mut scene);
            apply(shared, Arc::new(scene), asked, cancel)
        });
    if let Err(e) = result {
        let path = old.source.as_ref().map(|p| p.display().to_string());
        shared.emit(RuntimeEvent::ReloadFailed { path: path.unwrap_or_default(), error: e.to_string() });
    }
}

/// Replaces the world with `scene`'s (see the module docs).
pub(super) fn apply(
    shared: &Shared,
    scene: Arc<Scene>,
    seen_at: Instant,
    cancel: &AtomicBool,
) -> Result<(), RuntimeError> {
    let ms = || seen_at.elapsed().as_secs_f64() * 1e3;
    let mut steps = ReloadSteps { load: ms(), ..ReloadSteps::default() };
    let mut clock = Instant::now();
    let mut lap = |step: &mut f64| {
        *step = clock.elapsed().as_secs_f64() * 1e3;
        clock = Instant::now();
    };
    let old = shared.lock().world.clone();
    let diff = SceneDiff::between(&old.scene, &scene);
    if diff.is_empty() {
        lap(&mut steps.diff);
        shared.emit(RuntimeEvent::ReloadApplied {
            changed_meshes: 0,
            invalidated_cells: 0,
            repacked: false,
            ms: ms(),
            steps_ms: steps,
        });
        shared.emit(RuntimeEvent::ReloadRelit { ms: ms(), directions: 0 });
        return Ok(());
    }
    let geom = Arc::new(SceneGeometry::new(&scene));
    lap(&mut steps.diff);
    let mut origins = vec![MeshOrigin::Added; scene.meshes.len()];
    for &(o, n) in &diff.unchanged {
        origins[n] = MeshOrigin::Unchanged(o as u32);
    }
    for c in &diff.changed {
        origins[c.new] = MeshOrigin::Changed(c.old as u32);
    }
    let (atlas, update) = Atlas::update(&old.atlas, &scene, &geom, &shared.config.atlas, &origins)?;
    lap(&mut steps.atlas);
    let changed_meshes = diff.changed.len() + diff.added.len() + diff.removed.len();
    let everything = diff.lights_changed || diff.sky_changed || diff.materials_changed;
    let relaid = update.repacked || atlas.width != old.atlas.width;
    let world = Arc::new(World::with_grid(scene, geom, Arc::new(atlas), &shared.config, old.grid)?);
    let grid = world.grid;
    lap(&mut steps.world);

    let full = everything || relaid;
    // The cells to re-bake at LOD 0.
    let invalid: BTreeSet<CellId> = if full {
        world.non_empty_cells().collect()
    } else {
        let texel0 = world.texel_size(0);
        let mut set: BTreeSet<CellId> = diff
            .touched_bounds()
            .flat_map(|b| grid.cells_meeting(b.min, b.max, invalidation_margin(&b, texel0)).collect::<Vec<_>>())
            .collect();
        // Cells that gained or lost all their texels.
        set.extend(
            (0..grid.len() as u32)
                .filter(|&c| (old.lod0_texels[c as usize] > 0) != (world.lod0_texels[c as usize] > 0)),
        );
        set.retain(|&c| world.lod0_texels[c as usize] > 0);
        set
    };
    let swap = Swap { world: &world, invalid: &invalid, full, seen_at, changed_meshes, relaid };

    let threads = shared.config.threads();
    let full_directions = shared.config.bundle.directions;
    if full {
        return relight_everything(shared, &swap, threads, &mut lap, steps, cancel);
    }
    // The invalidated cells are first re-baked quickly, with `reload_directions`, and marked
    // provisional: the workers re-bake them with first light's directions before anything
    // else.
    let directions = shared.config.reload_directions.min(full_directions);
    let provisional = directions < full_directions;
    let quick = if directions == full_directions {
        world.bundle.clone()
    } else {
        let config = BundleConfig { directions, ..world.bundle.config.clone() };
        Arc::new(BundleScene::new(world.scene.clone(), world.geom.clone(), world.atlas.clone(), config))
    };
    let mut backend = (shared.make_backend)(&quick, threads).map_err(|e| RuntimeError::Backend(e.to_string()))?;
    // Pause the workers: the re-bake takes every core, and nothing may be published into
    // the map being rebuilt.
    shared.lock().relighting = true;
    let result = relight(shared, &world, &quick, backend.as_mut(), &invalid, threads, &mut lap, &mut steps);
    let (map, owned) = match result {
        Ok(r) => r,
        Err(e) => {
            shared.lock().relighting = false;
            shared.wake.notify_all();
            return Err(RuntimeError::FirstLight(e));
        }
    };
    swap.publish(shared, map, &owned, directions, provisional, &mut lap, steps);
    Ok(())
}

/// A light, the sky, a material or the whole atlas changed: LOD 0 is re-baked everywhere as
/// first light bakes it, one progressive bake, and the new world is served as soon as it has
/// first light's `first_light_directions` (`reload_relit`); it is published again as its
/// directions double, the workers waiting, until it has all of them (`reload_refined`). A
/// newer request or shutdown (`cancel`) cuts the bake short; if the new world was shown
/// already, its cells are then provisional, re-baked by the workers unless the next request
/// re-bakes them first.
fn relight_everything(
    shared: &Shared,
    swap: &Swap,
    threads: usize,
    lap: &mut impl FnMut(&mut f64),
    steps: ReloadSteps,
    cancel: &AtomicBool,
) -> Result<(), RuntimeError> {
    let world = swap.world;
    let total = shared.config.bundle.directions as u64;
    let mut early = Vec::new();
    let mut d = (shared.config.first_light_directions as u64).clamp(1, total);
    while d < total {
        early.push(d);
        d *= 2;
    }
    let mut backend =
        (shared.make_backend)(&world.bundle, threads).map_err(|e| RuntimeError::Backend(e.to_string()))?;
    shared.lock().relighting = true;
    let mut shown_at: Option<u64> = None;
    let mut first_steps = Some(steps);
    let mut show = |map: ShownLightmap, owned: &PixelLists, directions: u64| match first_steps.take() {
        Some(mut steps) => {
            lap(&mut steps.bake);
            swap.publish(shared, map, owned, directions as u32, false, lap, steps);
            // The workers wait for the rest of the bake.
            shared.lock().relighting = true;
            shown_at = Some(directions);
        }
        None => swap.republish(shared, map, owned, directions),
    };
    // `cancel` is raised by a newer request and by shutdown.
    let result =
        bake_first_light_observed(world, backend.as_mut(), threads, empty_shown(world), cancel, &early, &mut show);
    match result {
        Ok((map, owned, _)) => {
            match first_steps.take() {
                // Fewer directions than first light shows first: one publish.
                Some(mut steps) => {
                    lap(&mut steps.bake);
                    swap.publish(shared, map, &owned, total as u32, false, lap, steps);
                }
                None => {
                    swap.republish(shared, map, &owned, total);
                    shared.lock().relighting = false;
                    shared.wake.notify_all();
                    shared.emit(RuntimeEvent::ReloadRefined {
                        ms: swap.seen_at.elapsed().as_secs_f64() * 1e3,
                        directions: total as u32,
                    });
                }
            }
            Ok(())
        }
        Err(e) => {
            let mut st = shared.lock();
            st.relighting = false;
            if shown_at.is_some() {
                // Cut short after the new world was served: its cells are re-baked later.
                for c in world.non_empty_cells() {
                    st.cells[c as usize].provisional = true;
                }
                let left = world.non_empty_cells().count();
                st.refining = (left > 0).then_some(Refining { seen_at: swap.seen_at, left });
            }
            drop(st);
            shared.wake.notify_all();
            if shared.shutdown.load(Ordering::SeqCst) || cancel.load(Ordering::SeqCst) {
                return Ok(());
            }
            Err(RuntimeError::FirstLight(e))
        }
    }
}

/// What publishing a reload's re-bake needs to know.
struct Swap<'a> {
    world: &'a Arc<World>,
    invalid: &'a BTreeSet<CellId>,
    /// Every cell was re-baked.
    full: bool,
    seen_at: Instant,
    changed_meshes: usize,
    relaid: bool,
}

impl Swap<'_> {
    /// Serves the new world with `map` (its re-baked cells' LOD 0 at `directions`):
    /// `reload_applied` and `reload_relit`.
    #[allow(clippy::too_many_arguments)]
    fn publish(
        &self,
        shared: &Shared,
        map: ShownLightmap,
        owned: &PixelLists,
        directions: u32,
        provisional: bool,
        lap: &mut impl FnMut(&mut f64),
        mut steps: ReloadSteps,
    ) {
        let (world, grid) = (self.world, self.world.grid);
        let mut st = shared.lock();
        st.relighting = false;
        // Swap: the new world, its map, the cell table.
        st.generation += 1;
        st.world = world.clone();
        // Every bake in progress is of the old scene: parked ones are dropped here, those a
        // worker holds when it brings them back (their generation is old).
        for s in st.cells.iter_mut() {
            s.bake = None;
            s.member_of = None;
            s.baking_directions = 0;
        }
        st.bake_bytes = 0;
        let lights = !world.scene.lights.is_empty();
        for c in 0..grid.len() as u32 {
            let s = &mut st.cells[c as usize];
            if self.full || self.invalid.contains(&c) {
                let (busy, punctual_busy) = (s.busy, s.punctual.busy);
                *s = CellState { busy, provisional, ..CellState::default() };
                s.punctual.busy = punctual_busy;
                s.history = vec![(directions as u64, f32::NAN)];
                s.published = vec![owned[c as usize].clone()];
                s.set_light(Layer::Bundles, 0, map.layer_light(Layer::Bundles, 0, &owned[c as usize]));
                if lights {
                    s.punctual.published = vec![owned[c as usize].clone()];
                    s.set_light(Layer::Punctual, 0, map.layer_light(Layer::Punctual, 0, &owned[c as usize]));
                }
            } else if world.lod0_texels[c as usize] > 0 {
                s.stale = true;
                // Its shadows may have changed too (a long shadow reaches past the margin): the
                // punctual layer is re-baked, LOD 0 and the LOD wanted (cheap and exact).
                s.punctual.stale = lights;
            }
        }
        // Provisional cells an earlier reload left (not invalidated this time) are still so.
        let left = world.non_empty_cells().filter(|&c| st.cells[c as usize].provisional).count();
        st.refining = (left > 0).then_some(Refining { seen_at: self.seen_at, left });
        take_camera(shared, &mut st);
        update_views(shared, &mut st);
        shared.set_shown(map);
        drop(st);
        shared.wake.notify_all();
        let t = self.seen_at.elapsed().as_secs_f64() * 1e3;
        lap(&mut steps.publish);
        tracing::debug!(
            "reload: {} cells re-baked in {t:.0} ms: load {:.0}, diff {:.0}, atlas {:.0}, world {:.0}, region {:.0}, \
             bake {:.0}, publish {:.0} ms",
            self.invalid.len(),
            steps.load,
            steps.diff,
            steps.atlas,
            steps.world,
            steps.region,
            steps.bake,
            steps.publish
        );
        shared.emit(RuntimeEvent::ReloadApplied {
            changed_meshes: self.changed_meshes,
            invalidated_cells: self.invalid.len(),
            repacked: self.relaid,
            ms: t,
            steps_ms: steps,
        });
        shared.emit(RuntimeEvent::ReloadRelit { ms: t, directions });
    }

    /// Shows a later state of the full re-bake (LOD 0 of every cell at `directions`), as
    /// first light shows its doubling counts: LOD 0 only, punctual levels kept.
    fn republish(&self, shared: &Shared, map: ShownLightmap, owned: &PixelLists, directions: u64) {
        let mut st = shared.lock();
        let mut shown = (*shared.shown()).clone();
        shown.adopt_level(&map, 0);
        let lights = !self.world.scene.lights.is_empty();
        for (c, pixels) in owned.iter().enumerate() {
            let cell = &mut st.cells[c];
            cell.history = vec![(directions, f32::NAN)];
            if !pixels.is_empty() {
                cell.set_light(Layer::Bundles, 0, shown.layer_light(Layer::Bundles, 0, pixels));
                if lights {
                    cell.set_light(Layer::Punctual, 0, shown.layer_light(Layer::Punctual, 0, pixels));
                }
            }
        }
        shared.set_shown(shown);
        drop(st);
        shared.emit(RuntimeEvent::Lod0Published { directions });
    }
}

/// Re-bakes LOD 0 of the `invalid` cells of the new `world` together and returns the shown
/// map with it published and every other cell's levels kept, and the LOD-0 pixels each cell
/// owns (for the invalid cells).
#[allow(clippy::too_many_arguments)]
fn relight(
    shared: &Shared,
    world: &World,
    bundle: &BundleScene,
    backend: &mut dyn crate::bundle::BundleBackend,
    invalid: &BTreeSet<CellId>,
    threads: usize,
    lap: &mut impl FnMut(&mut f64),
    steps: &mut ReloadSteps,
) -> Result<(ShownLightmap, PixelLists), String> {
    let grid = world.grid;
    let mut map = (*shared.shown()).clone();
    map.resize(world.atlas.width, world.atlas.height);
    // Withdraw everything the invalid cells showed (their texels may have moved in the atlas),
    // and whatever lies in the charts laid out anew.
    {
        let st = shared.lock();
        let mut writer = PageWriter::new(&mut map);
        for &c in invalid {
            let s = &st.cells[c as usize];
            for (layer, published) in [(Layer::Bundles, &s.published), (Layer::Punctual, &s.punctual.published)] {
                for (lod, pixels) in published.iter().enumerate() {
                    for p in pixels {
                        writer.clear(layer, lod as u32, p[0], p[1]);
                    }
                }
                writer.set_cell_lod(layer, c, 0);
            }
        }
        writer.finish();
    }
    // The region: every invalid cell's LOD-0 texels.
    let mut is_invalid = vec![false; grid.len()];
    for &c in invalid {
        is_invalid[c as usize] = true;
    }
    let mut core: Vec<u32> = invalid.iter().flat_map(|&c| world.cell_triangles.of(c).iter().copied()).collect();
    core.sort_unstable();
    core.dedup();
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for &c in invalid {
        let (a, b) = world.cell_box(c);
        lo = lo.min(a);
        hi = hi.max(b);
    }
    let texels = SparseTexels::build(&world.scene, &world.geom, &world.atlas, 0, &core, lo, hi, |p| {
        is_invalid[grid.cell_of(p) as usize]
    });
    let source = ShownSource { shown: Arc::new(map.clone()), bundle: world.bundle.clone() };
    let region = Region {
        texels: texels.view(),
        tables: &texels.tables,
        window: Some(crate::runtime::cell_bake::bundle_window(&texels, world.texel_size(0))),
        foreign: Some(&source),
        triangles: None,
        reach: None,
    };
    lap(&mut steps.region);
    let punctual =
        PunctualPass::of(bundle, &world.bvh, 0, &texels.face, &|i| texels.pixel[i], |i| texels.table_of(i), threads);
    let baked = bake_region(bundle, backend, &region, None, punctual, threads, &NoProgress, &shared.shutdown)
        .map_err(|e| e.to_string())?;
    lap(&mut steps.bake);
    // The bundles' part filtered within charts in the bundle layer, the exact punctual part
    // in the punctual layer (as first light publishes them).
    // No punctual part (a scene without punctual lights) reads as zero.
    let direct = |i: usize| baked.punctual.get(i).copied().unwrap_or(Rgb::ZERO);
    let noisy: Vec<Rgb> = (0..baked.irradiance.len()).map(|i| baked.irradiance[i] - direct(i)).collect();
    let sampled = |i: usize| baked.unsampled.binary_search(&(i as u32)).is_err();
    let filtered = filter_within_charts(&texels.pixel, |i| texels.table_of(i), &noisy, sampled);
    let punctual: Vec<Rgb> = (0..baked.irradiance.len()).map(direct).collect();
    let layers = [(Layer::Bundles, &filtered), (Layer::Punctual, &punctual)];
    let lights = !world.scene.lights.is_empty();
    let mut owned = vec![Vec::new(); grid.len()];
    for (i, p) in texels.pixel.iter().enumerate() {
        owned[grid.cell_of(texels.position[i]) as usize].push(*p);
    }
    for &(g, t) in &texels.gutter {
        owned[grid.cell_of(texels.position[t as usize]) as usize].push(g);
    }
    let mut writer = PageWriter::new(&mut map);
    for (layer, values) in layers.iter().take(if lights { 2 } else { 1 }) {
        for (i, p) in texels.pixel.iter().enumerate() {
            writer.write(*layer, 0, p[0], p[1], values[i]);
        }
        for &(g, t) in &texels.gutter {
            writer.write(*layer, 0, g[0], g[1], values[t as usize]);
        }
    }
    writer.finish();
    Ok((map, owned))
}
