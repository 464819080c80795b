//! Memory accounting: what counts against the budget, and making room by eviction.

use crate::grid::CellId;
use crate::runtime::RuntimeEvent;
use crate::runtime::memory::PAGE_BYTES_PER_TEXEL;
use crate::runtime::policy::Work;
use crate::runtime::shown::{Layer, Page, PageWriter};

use super::{Shared, State};

/// Bytes counted against the budget: shown pages and bakes in progress.
pub(super) fn budgeted_bytes(shared: &Shared, st: &State) -> u64 {
    shared.shown().page_bytes() as u64 + st.bake_bytes
}

/// Frees memory until `need` more bytes fit the budget, taking from what matters less than
/// the work on `for_cells` (its leader first): first parked bakes and finest levels (of
/// either layer) of cells shown finer than they need, then bundle levels of cells farther
/// from the camera than the leader and punctual levels of cells out of view (when the
/// leader is in view, or farther), farthest first (at equal distance a punctual level, the
/// cheaper to make again). A punctual bake takes milliseconds: letting it evict in-view
/// cells' punctual levels by distance alone made cells in view evict each other as fast as
/// a turning camera reorders them, and no bundle work got through. A punctual bake takes
/// bundle work's room only from levels beyond their cell's target, never a parked bake: a
/// camera turning faster than a bundle bake's unit parked each bake at once, and the next
/// punctual bake dropped it (0 bundle publishes in 240 s, 183 camera moves a second).
/// Cells in a parked group bake are let alone (the group's leader stands for them: its
/// bake goes first). Returns whether it fits.
pub(super) fn make_room(
    shared: &Shared,
    st: &mut State,
    for_cells: &[CellId],
    need: u64,
    texels: u64,
    work: Work,
) -> bool {
    let budget = st.budget;
    // The front end's page limit, and the pages the work's `texels` will take.
    let page_cap = st.page_limit.map_or(u64::MAX, |p| p.saturating_mul(Page::BYTES as u64));
    let need_pages = texels * PAGE_BYTES_PER_TEXEL;
    let over = |st: &State| {
        budgeted_bytes(shared, st) + need > budget || shared.shown().page_bytes() as u64 + need_pages > page_cap
    };
    let world = st.world.clone();
    let view = |st: &State, c: CellId| st.cells[c as usize].view;
    let distance = |st: &State, c: CellId| view(st, c).map_or(f32::MAX, |v| v.distance);
    let in_view = |st: &State, c: CellId| view(st, c).is_some_and(|v| v.in_frustum);
    let (mine, mine_in_view) = (distance(st, for_cells[0]), in_view(st, for_cells[0]));
    while over(st) {
        // What matters least: beyond its cell's target first, then farthest.
        let mut victim: Option<((bool, f32, bool), CellId, Layer)> = None;
        for c in world.non_empty_cells().filter(|c| !for_cells.contains(c)) {
            let s = &st.cells[c as usize];
            let d = distance(st, c);
            let out_of_view = !in_view(st, c) && (mine_in_view || d > mine);
            let mut consider = |over: bool, layer: Layer| {
                let less_urgent = if layer == Layer::Bundles { d > mine } else { out_of_view };
                if !(over || less_urgent) {
                    return;
                }
                let key = (over, d, layer == Layer::Punctual);
                if victim.as_ref().is_none_or(|(k, _, _)| key.partial_cmp(k) == Some(std::cmp::Ordering::Greater)) {
                    victim = Some((key, c, layer));
                }
            };
            let parked = s.bake.is_some();
            if !s.busy && s.member_of.is_none() && (s.shown > 0 || parked) {
                let over = s.shown > s.target;
                if work == Work::Bundles || (over && !parked) {
                    consider(over, Layer::Bundles);
                }
            }
            if !s.punctual.busy && s.punctual.shown > 0 {
                consider(s.punctual.shown > s.punctual.target, Layer::Punctual);
            }
        }
        let Some((_, victim, layer)) = victim else { return false };
        match layer {
            // A parked bake's work is lost; it would be the first thing rebuilt if needed.
            Layer::Bundles if st.cells[victim as usize].bake.is_some() => drop_parked(st, victim),
            Layer::Bundles => evict(shared, st, victim),
            Layer::Punctual => evict_punctual(shared, st, victim),
        }
    }
    true
}

/// Drops the bake parked at `leader` (its group's with it): its work is lost.
fn drop_parked(st: &mut State, leader: CellId) {
    let Some(bake) = st.cells[leader as usize].bake.take() else { return };
    st.bake_bytes -= bake.bytes() as u64;
    for &m in &bake.cells {
        let s = &mut st.cells[m as usize];
        s.baking_directions = 0;
        s.member_of = None;
    }
}

/// Withdraws a cell's finest shown level of the bundle layer (its pixels at that LOD) and
/// shows the next coarser.
fn evict(shared: &Shared, st: &mut State, cell: CellId) {
    let s = &mut st.cells[cell as usize];
    let lod = s.shown;
    if lod == 0 {
        return;
    }
    let pixels = std::mem::take(&mut s.published[lod as usize]);
    s.shown = lod - 1;
    // Only the finest shown level may be unsettled: the coarser one was settled before the
    // cell swapped on from it.
    s.unsettled = false;
    s.history.truncate(lod as usize);
    withdraw(shared, Layer::Bundles, cell, lod, &pixels, lod - 1);
    st.stats.evictions += 1;
    shared.emit(RuntimeEvent::CellEvicted { cell, lod, layer: Layer::Bundles });
}

/// Withdraws a cell's finest punctual level and shows the next coarser one it has (LOD 0 at
/// least: levels in between are skipped, [`PunctualState`](super::PunctualState)).
fn evict_punctual(shared: &Shared, st: &mut State, cell: CellId) {
    let p = &mut st.cells[cell as usize].punctual;
    let lod = p.shown;
    if lod == 0 {
        return;
    }
    let pixels = p.published.get_mut(lod as usize).map(std::mem::take).unwrap_or_default();
    let below = (0..lod).rev().find(|&k| p.published.get(k as usize).is_some_and(|v| !v.is_empty())).unwrap_or(0);
    p.shown = below;
    withdraw(shared, Layer::Punctual, cell, lod, &pixels, below);
    st.stats.evictions += 1;
    shared.emit(RuntimeEvent::CellEvicted { cell, lod, layer: Layer::Punctual });
}

/// Clears `pixels` of `layer` at `lod` and shows `cell` at `shown` in that layer, in a new
/// snapshot.
fn withdraw(shared: &Shared, layer: Layer, cell: CellId, lod: u32, pixels: &[[u32; 2]], shown: u32) {
    let mut map = (*shared.shown()).clone();
    let mut writer = PageWriter::new(&mut map);
    for p in pixels {
        writer.clear(layer, lod, p[0], p[1]);
    }
    writer.set_cell_lod(layer, cell, shown);
    writer.finish();
    shared.set_shown(map);
}
