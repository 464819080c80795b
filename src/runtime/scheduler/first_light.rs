//! First light: LOD 0 of the whole scene on every core, published progressively.

use std::ops::ControlFlow;
use std::sync::atomic::{AtomicBool, Ordering};

use crate::atlas::chart_filter::filter_within_charts;
use crate::atlas::lookup::TexelTable;
use crate::bake::bundle::{BatchDone, BundleLodStats, bake_lod_observed};
use crate::bundle::BundleBackend;
use crate::grid::CellId;
use crate::progress::NoProgress;
use crate::runtime::RuntimeEvent;
use crate::runtime::shown::{Layer, PageWriter, ShownLightmap};
use crate::runtime::world::World;
use crate::scene::Rgb;

use super::{PixelLists, Shared, take_camera, update_views};

/// Bakes LOD 0 of the whole scene with `backend` and returns `map` with it published
/// (filtered within charts, as every publish is), the pixels each cell owns there, and the
/// bake's figures.
pub fn bake_first_light(
    world: &World,
    backend: &mut dyn BundleBackend,
    threads: usize,
    map: ShownLightmap,
    cancel: &AtomicBool,
) -> Result<(ShownLightmap, PixelLists, BundleLodStats), String> {
    bake_first_light_observed(world, backend, threads, map, cancel, &[], &mut |_, _, _| {})
}

/// [`bake_first_light`], handing out early results on the way: after the first batch that
/// reaches each of `early` directions, `published(map, owned, directions)` gets `map` with
/// the running estimate published (the progressive bake goes on: later directions only add
/// to it).
pub fn bake_first_light_observed(
    world: &World,
    backend: &mut dyn BundleBackend,
    threads: usize,
    map: ShownLightmap,
    cancel: &AtomicBool,
    early: &[u64],
    published: &mut dyn FnMut(ShownLightmap, &PixelLists, u64),
) -> Result<(ShownLightmap, PixelLists, BundleLodStats), String> {
    let lod0 = &world.lod0;
    let w = lod0.width;
    let pixels: Vec<[u32; 2]> = lod0.pixel.iter().map(|&p| [p % w, p / w]).collect();
    let table = TexelTable::of_map(lod0);
    let cell_of: Vec<CellId> = lod0.position.iter().map(|&p| world.grid.cell_of(p)).collect();
    let mut owned = vec![Vec::new(); world.grid.len()];
    for (i, p) in pixels.iter().enumerate() {
        owned[cell_of[i] as usize].push(*p);
    }
    for &(g, t) in &lod0.gutter {
        owned[cell_of[t as usize] as usize].push([g % w, g / w]);
    }
    // The published values: the noisy part (bundles, light pass) filtered within charts in
    // the bundle layer, the exact punctual part in the punctual layer.
    let lights = !world.scene.lights.is_empty();
    let publish =
        |mut map: ShownLightmap, irradiance: &dyn Fn(usize) -> Rgb, direct: &[Rgb], sampled: &dyn Fn(usize) -> bool| {
            // No punctual part (a scene without punctual lights) reads as zero.
            let direct_of = |i: usize| direct.get(i).copied().unwrap_or(Rgb::ZERO);
            let noisy: Vec<Rgb> = (0..pixels.len()).map(|i| irradiance(i) - direct_of(i)).collect();
            let filtered = filter_within_charts(&pixels, |_| &table, &noisy, sampled);
            let layers = [(Layer::Bundles, filtered), (Layer::Punctual, (0..pixels.len()).map(direct_of).collect())];
            let mut writer = PageWriter::new(&mut map);
            for (layer, values) in layers.iter().take(if lights { 2 } else { 1 }) {
                for (i, p) in pixels.iter().enumerate() {
                    writer.write(*layer, 0, p[0], p[1], values[i]);
                }
                for &(g, t) in &lod0.gutter {
                    writer.write(*layer, 0, g % w, g / w, values[t as usize]);
                }
            }
            writer.finish();
            map
        };
    let mut next = early.iter().copied().filter(|&d| d > 0).min();
    let mut observe = |done: &BatchDone| {
        if let Some(at) = next
            && done.directions >= at
        {
            let e = done.estimate;
            published(
                publish(map.clone(), &|i| e.irradiance_of(i), e.punctual(), &|i| e.sampled(i)),
                &owned,
                done.directions,
            );
            next = early.iter().copied().filter(|&d| d > done.directions).min();
        }
        ControlFlow::Continue(())
    };
    let baked =
        bake_lod_observed(&world.bundle, &world.bvh, backend, lod0, None, threads, &NoProgress, cancel, &mut observe)
            .map_err(|e| e.to_string())?;
    if baked.stats.pass.unplanned_directions > 0 {
        return Err(format!("{} bundle directions could not be planned", baked.stats.pass.unplanned_directions));
    }
    let sampled = |i: usize| baked.unsampled.binary_search(&(i as u32)).is_err();
    let map = publish(map, &|i| baked.irradiance[i], &baked.punctual, &sampled);
    Ok((map, owned, baked.stats))
}

/// An empty shown map for `world` (nothing published yet).
pub fn empty_shown(world: &World) -> ShownLightmap {
    let blend_band = (2.0 * world.atlas.texel_size).min(world.grid.cell_size * 0.25);
    ShownLightmap::new(world.grid, world.atlas.width, world.atlas.height, world.lods, blend_band)
}

/// Bakes LOD 0 of the whole scene on every core and publishes it: first light after
/// `first_light_directions` (progressive: the bake goes on), then again at twice as many
/// directions and so on, and when the bake has all its directions; refinement starts then.
pub(in crate::runtime) fn first_light(shared: &Shared) {
    let world = shared.lock().world.clone();
    let threads = shared.config.threads();
    let total = shared.config.bundle.directions as u64;
    let mut early = Vec::new();
    let mut d = (shared.config.first_light_directions as u64).max(1);
    while d < total {
        early.push(d);
        d *= 2;
    }
    let generation = shared.lock().generation;
    let mut show = |map: ShownLightmap, owned: &PixelLists, directions: u64| {
        let mut st = shared.lock();
        if st.generation != generation {
            // A hot reload replaced the world meanwhile: it published its own light.
            return;
        }
        // LOD 0 only: punctual bakes may have published finer levels meanwhile.
        let mut shown = (*shared.shown()).clone();
        shown.adopt_level(&map, 0);
        let first = !st.first_light;
        let lights = !world.scene.lights.is_empty();
        for (c, pixels) in owned.iter().enumerate() {
            let cell = &mut st.cells[c];
            cell.history = vec![(directions, f32::NAN)];
            if first {
                cell.published = vec![pixels.clone()];
                if lights {
                    cell.punctual.published = vec![pixels.clone()];
                }
            }
            if !pixels.is_empty() {
                cell.set_light(Layer::Bundles, 0, shown.layer_light(Layer::Bundles, 0, pixels));
                if lights {
                    cell.set_light(Layer::Punctual, 0, shown.layer_light(Layer::Punctual, 0, pixels));
                }
            }
        }
        shared.set_shown(shown);
        st.lod0_directions = directions;
        if first {
            st.first_light = true;
            st.stats.first_light_seconds = Some(shared.started.elapsed().as_secs_f64());
            take_camera(shared, &mut st);
            update_views(shared, &mut st);
        }
        drop(st);
        shared.wake.notify_all();
        shared.emit(if first {
            RuntimeEvent::FirstLight { texels: world.lod0.len(), directions: directions as u32 }
        } else {
            RuntimeEvent::Lod0Published { directions }
        });
    };
    let result = (shared.make_backend)(&world.bundle, threads).map_err(|e| e.to_string()).and_then(|mut backend| {
        bake_first_light_observed(
            &world,
            backend.as_mut(),
            threads,
            empty_shown(&world),
            &shared.shutdown,
            &early,
            &mut show,
        )
    });
    let (map, owned, stats) = match result {
        Ok(r) => r,
        Err(_) if shared.shutdown.load(Ordering::SeqCst) => return,
        Err(error) => {
            tracing::error!("first light failed: {error}");
            shared.lock().failed = Some(error.clone());
            shared.wake.notify_all();
            shared.emit(RuntimeEvent::Failed { error });
            return;
        }
    };
    // The LOD-0 bake's counters before its map is shown: whoever wakes on the event that
    // shows it (first light, or LOD 0 published) reads them.
    {
        let mut st = shared.lock();
        st.stats.directions_traced += stats.directions;
        st.stats.first_light_pass = stats.pass.clone();
    }
    show(map, &owned, stats.directions);
    let mut st = shared.lock();
    st.lod0_done = true;
    st.first_light = true;
    drop(st);
    shared.wake.notify_all();
}
