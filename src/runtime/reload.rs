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
//! * a light, the sky or a material changed, or nothing fitted in the atlas (a full repack):
//!   everything is affected; LOD 0 is re-baked everywhere at once with first light's
//!   directions, keeping the grid.
//!
//! The new world is served (`reload_applied`) once its LOD 0 is published where it was
//! invalidated (`reload_relit`); until then the old one is, so nothing is ever half applied.
//! Workers wait while the re-bake runs (it uses every core).

use std::collections::BTreeSet;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Instant;

use glam::Vec3;

use super::scheduler::{CellState, Refining, Shared, bake_first_light, empty_shown, take_camera, update_views};
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
use crate::scene::{Rgb, Scene, SceneGeometry};
use crate::watch::{Aabb, SceneDiff, SceneWatcher, WatchEvent};

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

pub(super) fn watch_thread(shared: &Shared, watcher: SceneWatcher) {
    loop {
        if shared.shutdown.load(Ordering::SeqCst) {
            return;
        }
        let event = match watcher.events().recv_timeout(std::time::Duration::from_millis(100)) {
            Ok(e) => e,
            Err(crossbeam_channel::RecvTimeoutError::Timeout) => continue,
            Err(crossbeam_channel::RecvTimeoutError::Disconnected) => return,
        };
        match event {
            WatchEvent::Started { paths, .. } => shared
                .emit(RuntimeEvent::ReloadStarted { paths: paths.iter().map(|p| p.display().to_string()).collect() }),
            WatchEvent::Failed { path, error, .. } => {
                shared.emit(RuntimeEvent::ReloadFailed { path: path.display().to_string(), error })
            }
            WatchEvent::Loaded { scene, seen_at, .. } => {
                if let Err(e) = apply(shared, scene, seen_at) {
                    let path = shared.lock().world.scene.source.as_ref().map(|p| p.display().to_string());
                    shared.emit(RuntimeEvent::ReloadFailed { path: path.unwrap_or_default(), error: e.to_string() });
                }
            }
        }
    }
}

/// Replaces the world with `scene`'s (see the module docs).
pub(super) fn apply(shared: &Shared, scene: Arc<Scene>, seen_at: Instant) -> Result<(), RuntimeError> {
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

    // The cells to re-bake at LOD 0.
    let invalid: BTreeSet<CellId> = if everything || relaid {
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

    let threads = shared.config.threads();
    let full = everything || relaid;
    // The invalidated cells are first re-baked quickly, with `reload_directions`, and marked
    // provisional: the workers re-bake them with first light's directions before anything
    // else. A change to everything re-bakes LOD 0 everywhere at full quality at once.
    let full_directions = shared.config.bundle.directions;
    let directions = if full { full_directions } else { shared.config.reload_directions.min(full_directions) };
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
    let result = if everything || relaid {
        let r = bake_first_light(&world, backend.as_mut(), threads, empty_shown(&world), &shared.shutdown)
            .map(|(map, owned, _)| (map, owned));
        lap(&mut steps.bake);
        r
    } else {
        relight(shared, &world, &quick, backend.as_mut(), &invalid, threads, &mut lap, &mut steps)
    };
    let mut st = shared.lock();
    st.relighting = false;
    let (map, owned) = match result {
        Ok(r) => r,
        Err(e) => {
            drop(st);
            shared.wake.notify_all();
            return Err(RuntimeError::FirstLight(e));
        }
    };
    // Swap: the new world, its map, the cell table.
    st.generation += 1;
    st.world = world.clone();
    // Every bake in progress is of the old scene: parked ones are dropped here, those a worker
    // holds when it brings them back (their generation is old).
    for s in st.cells.iter_mut() {
        s.bake = None;
        s.member_of = None;
        s.baking_directions = 0;
    }
    st.bake_bytes = 0;
    let lights = !world.scene.lights.is_empty();
    for c in 0..grid.len() as u32 {
        let s = &mut st.cells[c as usize];
        if full || invalid.contains(&c) {
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
    st.refining = (left > 0).then_some(Refining { seen_at, left });
    take_camera(shared, &mut st);
    update_views(shared, &mut st);
    shared.set_shown(map);
    drop(st);
    shared.wake.notify_all();
    let t = ms();
    lap(&mut steps.publish);
    tracing::debug!(
        "reload: {} cells re-baked in {t:.0} ms: load {:.0}, diff {:.0}, atlas {:.0}, world {:.0}, region {:.0}, \
         bake {:.0}, publish {:.0} ms",
        invalid.len(),
        steps.load,
        steps.diff,
        steps.atlas,
        steps.world,
        steps.region,
        steps.bake,
        steps.publish
    );
    shared.emit(RuntimeEvent::ReloadApplied {
        changed_meshes,
        invalidated_cells: invalid.len(),
        repacked: relaid,
        ms: t,
        steps_ms: steps,
    });
    shared.emit(RuntimeEvent::ReloadRelit { ms: t, directions });
    Ok(())
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
) -> Result<(ShownLightmap, super::scheduler::PixelLists), String> {
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
    let reach = Vec3::splat(world.texel_size(0) * 1.5);
    let source = ShownSource { shown: Arc::new(map.clone()), bundle: world.bundle.clone() };
    let region = Region {
        texels: texels.view(),
        tables: &texels.tables,
        window: Some((lo - reach, hi + reach)),
        foreign: Some(&source),
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
