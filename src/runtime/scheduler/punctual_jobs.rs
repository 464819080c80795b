//! Punctual jobs: which cell's punctual layer is baked next, and baking and publishing it.

use std::time::Instant;

use crate::grid::CellId;
use crate::runtime::RuntimeEvent;
use crate::runtime::memory::lod_texels;
use crate::runtime::policy::{Step, Tier, Work, priority, urgency};
use crate::runtime::punctual::{PunctualBake, punctual_bake_bytes};
use crate::runtime::shown::{Layer, PageWriter};
use crate::runtime::world::World;

use super::budget::make_room;
use super::pick::{Job, JobKey, weight_of};
use super::{CellState, Shared, State};

/// The LODs a cell's punctual layer is to be baked at next, if the scene has punctual lights
/// and the cell has such work waiting (see [`PunctualState::next_levels`](super::PunctualState::next_levels)).
pub(super) fn punctual_work(world: &World, s: &CellState) -> Option<Vec<u32>> {
    if world.scene.lights.is_empty() || s.view.is_none() {
        return None;
    }
    s.punctual.next_levels()
}

/// The cell whose punctual layer is most urgent ([`urgency`] of its next level's bake), if
/// any has work waiting; a stale layer's re-bake after all refinement.
pub(super) fn best_punctual(st: &State) -> Option<(JobKey, CellId)> {
    let world = &st.world;
    world
        .non_empty_cells()
        .filter_map(|c| {
            let s = &st.cells[c as usize];
            let levels = punctual_work(world, s)?;
            let p = &s.punctual;
            let texels = levels.iter().map(|&k| lod_texels(world, c, k)).sum();
            let u = urgency(weight_of(world, s, c), s.light(Layer::Punctual, p.shown), Step::Punctual { texels });
            let tier = if p.stale { Tier::Refresh } else { Tier::Refine };
            Some(((priority(tier, u), c), c))
        })
        .min()
}

/// Takes the punctual bake of `c` (see [`pick`](super::pick::pick)).
pub(super) fn take_punctual(shared: &Shared, st: &mut State, c: CellId) -> Option<Job> {
    let world = st.world.clone();
    let levels = punctual_work(&world, &st.cells[c as usize])?;
    let texels: u64 = levels.iter().map(|&k| lod_texels(&world, c, k)).sum();
    let need = punctual_bake_bytes(texels);
    if !make_room(shared, st, &[c], need, texels, Work::Punctual) {
        return None;
    }
    st.cells[c as usize].punctual.busy = true;
    st.bake_bytes += need;
    Some(Job::Punctual { world, generation: st.generation, cell: c, levels })
}

/// Bakes `cell`'s punctual layer at `levels` and publishes it (the finest level it then has
/// shown): each level's earlier pixels are replaced, and a stale cell's other levels
/// withdrawn (their shadows predate the change).
pub(super) fn bake_punctual(shared: &Shared, world: &World, generation: u64, cell: CellId, levels: &[u32]) {
    let t = Instant::now();
    let bakes: Vec<PunctualBake> = levels.iter().map(|&k| PunctualBake::new(world, cell, k)).collect();
    let mut st = shared.lock();
    let need: u64 = levels.iter().map(|&k| punctual_bake_bytes(lod_texels(world, cell, k))).sum();
    st.bake_bytes = st.bake_bytes.saturating_sub(need);
    st.stats.cell_setup_seconds += t.elapsed().as_secs_f64();
    if st.generation != generation {
        // A hot reload replaced the world (and reset what it invalidated).
        st.cells[cell as usize].punctual.busy = false;
        return;
    }
    let p = &mut st.cells[cell as usize].punctual;
    p.busy = false;
    let stale = std::mem::take(&mut p.stale);
    let mut map = (*shared.shown()).clone();
    let mut writer = PageWriter::new(&mut map);
    let top = levels.iter().copied().max().unwrap_or(0);
    p.published.resize(p.published.len().max(top as usize + 1), Vec::new());
    for (k, pixels) in p.published.iter_mut().enumerate() {
        if levels.contains(&(k as u32)) || stale {
            for q in pixels.drain(..) {
                writer.clear(Layer::Punctual, k as u32, q[0], q[1]);
            }
        }
    }
    let mut texels = 0;
    for bake in &bakes {
        let pixels = &mut p.published[bake.lod as usize];
        for (q, e) in bake.pixels() {
            writer.write(Layer::Punctual, bake.lod, q[0], q[1], e);
            pixels.push(q);
        }
        texels = bake.texels.len();
    }
    // The finest level it has now.
    let shown = p.published.iter().rposition(|v| !v.is_empty()).unwrap_or(0) as u32;
    writer.set_cell_lod(Layer::Punctual, cell, shown);
    writer.finish();
    p.shown = shown;
    let s = &mut st.cells[cell as usize];
    for &k in levels {
        let light = map.layer_light(Layer::Punctual, k, &s.punctual.published[k as usize]);
        s.set_light(Layer::Punctual, k, light);
    }
    shared.set_shown(map);
    st.stats.publishes += 1;
    drop(st);
    shared.emit(RuntimeEvent::PunctualPublished { cell, lod: shown, texels, ms: t.elapsed().as_secs_f64() * 1e3 });
    shared.wake.notify_all();
}
