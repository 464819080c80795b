//! Choosing work: the most urgent job of both layers, and the group a new bundle bake takes.

use std::sync::Arc;

use crate::grid::CellId;
use crate::runtime::RuntimeConfig;
use crate::runtime::cell_bake::CellBake;
use crate::runtime::memory::{bake_estimate, lod_texels};
use crate::runtime::policy::{CellView, Step, Tier, Work, priority, screen_weight, urgency};
use crate::runtime::shown::Layer;
use crate::runtime::world::World;

use super::budget::{budgeted_bytes, make_room};
use super::punctual_jobs::{best_punctual, take_punctual};
use super::{CellState, Shared, State};

/// What a worker takes.
pub(super) enum Job {
    /// Bundles: cells (the first leads), the LOD to bake them at, and their bake if one is
    /// parked.
    Bundles { world: Arc<World>, generation: u64, cells: Vec<CellId>, lod: u32, bake: Option<Box<CellBake>> },
    /// A cell's punctual layer at these LODs (ascending; the finest the cell then has is shown).
    Punctual { world: Arc<World>, generation: u64, cell: CellId, levels: Vec<u32> },
}

/// The LOD a cell's next bake is at: LOD 0 again for a provisional cell (its quick re-bake
/// is replaced before it is refined on), its shown LOD for an unsettled cell still wanted at
/// least that fine (its level is finished before the next, see [`CellState::unsettled`]),
/// the next finer one below its target, else (a stale cell at its target) its shown LOD
/// again, to refresh it.
pub(in crate::runtime) fn next_lod(s: &CellState) -> Option<u32> {
    if s.provisional {
        Some(0)
    } else if s.unsettled && s.target >= s.shown {
        Some(s.shown)
    } else if s.target > s.shown {
        Some(s.shown + 1)
    } else if s.stale {
        Some(s.shown)
    } else {
        None
    }
}

/// The next job (from first light on: punctual bakes; once LOD 0 has all its directions,
/// bundle bakes too), the most urgent of both layers' work ([`priority`]: a reload's
/// provisional cells first, then the on-screen error a job removes per unit of work,
/// [`urgency`], one scale for both layers), not being worked on, with room within the
/// memory budget (made by evicting what matters less, [`make_room`]); `None` when nothing
/// is to be done or nothing fits. A
/// cell whose group bake is parked (it is a member) brings its leader's bake back; a new
/// bake gathers neighbours that want the same LOD ([`gather_group`]).
pub(super) fn pick(shared: &Shared, st: &mut State) -> Option<Job> {
    let punctual = best_punctual(st);
    // Bundle bakes see the shown map as converged light: they wait for all of LOD 0's
    // directions (punctual bakes, exact, need not).
    let bundles = if st.lod0_done { best_bundles(&shared.config, st) } else { None };
    // The more urgent first; when it does not fit the memory budget, the other. Bundle work
    // waiting gets every few jobs whatever the order says: a camera turning faster than
    // punctual bakes finish keeps raising in-view cells' punctual targets, and the
    // millisecond punctual bakes (evicting each other under a tight budget) took every job
    // (0 bundle publishes in 30 s, 26 943 punctual ones, 183 camera moves a second).
    let starved = st.punctual_streak >= PUNCTUAL_STREAK;
    let job = match (punctual, bundles) {
        (Some(p), Some(b)) if b.0 < p.0 || starved => {
            take_bundles(shared, st, b.1).or_else(|| take_punctual(shared, st, p.1))
        }
        (Some(p), b) => take_punctual(shared, st, p.1).or_else(|| b.and_then(|b| take_bundles(shared, st, b.1))),
        (None, Some((_, c))) => take_bundles(shared, st, c),
        (None, None) => None,
    };
    match &job {
        Some(Job::Punctual { .. }) if bundles.is_some() => st.punctual_streak += 1,
        Some(_) => st.punctual_streak = 0,
        None => {}
    }
    job
}

/// Punctual jobs in a row after which waiting bundle work goes first ([`pick`]): bundle work
/// gets at least a third of the jobs, and most of the time (a punctual bake is one shadow
/// ray a texel, a bundle unit many directions). With 8, the stress test's spinning camera
/// saw 3 bundle publishes in 30 s.
const PUNCTUAL_STREAK: u32 = 2;

/// A job's place in the order of work ([`priority`]).
pub(super) type JobKey = ((Tier, std::cmp::Reverse<u32>), CellId);

/// Where a cell stands for the camera, and how much of the screen its surfaces may cover
/// ([`screen_weight`]).
pub(super) fn weight_of(world: &World, s: &CellState, c: CellId) -> f32 {
    let view = s.view.unwrap_or(CellView { distance: f32::MAX, in_frustum: false });
    let texel = world.atlas.texel_size;
    let area = world.lod0_texels[c as usize] as f32 * texel * texel;
    screen_weight(view, area, world.grid.cell_size)
}

/// The cell whose bundle layer is most urgent, if any has work waiting: a reload's
/// provisional cells first (the change is shown at full quality soonest), then refinement by
/// [`urgency`] (a finer level: the detail of the shown one, over the work until it swaps in;
/// an early-published level: its noise, over the work until it is published again), then
/// refreshing stale light.
fn best_bundles(config: &RuntimeConfig, st: &State) -> Option<(JobKey, CellId)> {
    let world = &st.world;
    let leader_of = |c: CellId| st.cells[c as usize].member_of.unwrap_or(c);
    world
        .non_empty_cells()
        .filter_map(|c| {
            let s = &st.cells[c as usize];
            if st.cells[leader_of(c) as usize].busy || s.view.is_none() {
                return None;
            }
            let lod = next_lod(s)?;
            let parked = st.cells[leader_of(c) as usize].bake.as_ref().filter(|b| b.lod == lod);
            let traced = parked.map_or(0, |b| b.directions());
            let (shown_directions, error) = s.history.get(s.shown as usize).copied().unwrap_or((0, f32::INFINITY));
            let texels = lod_texels(world, c, lod);
            let step = if lod > s.shown {
                let wanted = (config.min_directions as u64).max(shown_directions);
                Step::Refine { texels, directions: wanted.saturating_sub(traced).max(1), new: parked.is_none() }
            } else {
                Step::Continue { texels, directions: (2 * shown_directions).saturating_sub(traced).max(1), error }
            };
            let tier = if s.provisional {
                Tier::Provisional
            } else if lod > s.shown || s.unsettled {
                Tier::Refine
            } else {
                Tier::Refresh
            };
            let u = urgency(weight_of(world, s, c), s.light(Layer::Bundles, s.shown), step);
            Some(((priority(tier, u), c), c))
        })
        .min()
}

/// Takes the bundle bake of `c` (see [`pick`]): its group's parked bake, or a new one.
fn take_bundles(shared: &Shared, st: &mut State, c: CellId) -> Option<Job> {
    let world = st.world.clone();
    let leader = st.cells[c as usize].member_of.unwrap_or(c);
    if let Some(bake) = st.cells[leader as usize].bake.take() {
        // Resume the parked bake, unless it is of another level than its leader's next (the
        // cell was evicted or refreshed meanwhile): then it is dropped and made anew.
        let wanted = next_lod(&st.cells[leader as usize]);
        if bake.cells.len() > 1 || wanted == Some(bake.lod) {
            let (cells, lod) = (bake.cells.clone(), bake.lod);
            for &m in &cells {
                st.cells[m as usize].busy = true;
            }
            return Some(Job::Bundles { world, generation: st.generation, cells, lod, bake: Some(bake) });
        }
        st.bake_bytes -= bake.bytes() as u64;
        st.cells[leader as usize].baking_directions = 0;
    }
    let lod = next_lod(&st.cells[leader as usize])?;
    let cells = gather_group(shared, st, leader, lod);
    let need: u64 = cells.iter().map(|&m| bake_estimate(&world, m, lod)).sum();
    let texels: u64 = cells.iter().map(|&m| lod_texels(&world, m, lod)).sum();
    if !make_room(shared, st, &cells, need, texels, Work::Bundles) {
        return None;
    }
    for &m in &cells {
        st.cells[m as usize].busy = true;
    }
    Some(Job::Bundles { world, generation: st.generation, cells, lod, bake: None })
}

/// The cells a new bake of `leader` at `lod` takes: the leader, then its nearest neighbours
/// (within [`GROUP_REACH`] cells on each axis) that also want `lod` next from the same shown
/// LOD (and are as provisional and as unsettled, see [`CellState::provisional`] and
/// [`CellState::unsettled`]: a group follows one swap rule) and are free (no bake of
/// their own, not in a group), until the group has `config.group_texels` texels at `lod` (estimated from LOD 0's); never more than twice that,
/// nor more than the memory budget has free.
fn gather_group(shared: &Shared, st: &State, leader: CellId, lod: u32) -> Vec<CellId> {
    let world = &st.world;
    let want = shared.config.group_texels as u64;
    let texels = |c: CellId| (world.lod0_texels[c as usize] as u64) << (2 * lod);
    let mut cells = vec![leader];
    let mut total = texels(leader);
    if total >= want {
        return cells;
    }
    let free = st.budget.saturating_sub(budgeted_bytes(shared, st));
    let mut bytes = bake_estimate(world, leader, lod);
    let l = &st.cells[leader as usize];
    let (shown, provisional, unsettled) = (l.shown, l.provisional, l.unsettled);
    let [x, y, z] = world.grid.coords(leader);
    let dims = world.grid.dims;
    let range = |v: u32, n: u32| v.saturating_sub(GROUP_REACH)..=(v + GROUP_REACH).min(n - 1);
    let mut near: Vec<(u32, CellId)> = Vec::new();
    for k in range(z, dims[2]) {
        for j in range(y, dims[1]) {
            for i in range(x, dims[0]) {
                let c = world.grid.index([i, j, k]);
                let s = &st.cells[c as usize];
                let free = !s.busy && s.bake.is_none() && s.member_of.is_none();
                if c != leader
                    && world.lod0_texels[c as usize] > 0
                    && free
                    && s.shown == shown
                    && s.provisional == provisional
                    && s.unsettled == unsettled
                    && next_lod(s) == Some(lod)
                {
                    let d = i.abs_diff(x).max(j.abs_diff(y)).max(k.abs_diff(z));
                    near.push((d, c));
                }
            }
        }
    }
    near.sort_unstable();
    for (_, c) in near {
        if total >= want || cells.len() == crate::runtime::cell_bake::MAX_GROUP {
            break;
        }
        // Never past twice the wanted size, and a group grows only into free memory: making
        // room for a larger one would drop other cells' parked work (under a tight budget and
        // a moving camera, again and again).
        if total + texels(c) > 2 * want || bytes + bake_estimate(world, c, lod) > free {
            continue;
        }
        bytes += bake_estimate(world, c, lod);
        total += texels(c);
        cells.push(c);
    }
    cells
}

/// How far (cells, per axis) a group reaches from its leader.
const GROUP_REACH: u32 = 3;

#[cfg(test)]
mod tests {
    use super::*;

    /// The LOD a cell bakes next: an unsettled level is finished before the next, unless the
    /// cell is now wanted coarser.
    #[test]
    fn an_unsettled_cell_bakes_its_shown_lod_next() {
        let cell = |shown, target, unsettled| CellState { shown, target, unsettled, ..CellState::default() };
        assert_eq!(next_lod(&cell(1, 3, true)), Some(1));
        assert_eq!(next_lod(&cell(1, 1, true)), Some(1));
        assert_eq!(next_lod(&cell(1, 0, true)), None);
        assert_eq!(next_lod(&cell(1, 3, false)), Some(2));
        assert_eq!(next_lod(&cell(1, 1, false)), None);
    }
}
