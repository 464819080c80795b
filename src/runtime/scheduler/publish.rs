//! Publishing: the swap rule, and writing a bake into a new snapshot of the shown map.

use crate::runtime::RuntimeConfig;
use crate::runtime::cell_bake::CellBake;
use crate::runtime::shown::{Layer, PageWriter, ShownLightmap};
use crate::scene::Rgb;

use super::{Shared, State};

/// What a bake's cells show, as the swap rule reads it.
#[derive(Clone, Copy, Debug)]
pub(super) struct ShownNow {
    /// Their shown LOD (a group's cells share it: they are gathered from one shown LOD and
    /// are neither evicted nor re-baked apart while the group is).
    pub lod: u32,
    /// The most directions any of them shows that level with.
    pub directions: u64,
    /// Every one of them shows an early publish still being refined
    /// ([`CellState::unsettled`](super::CellState::unsettled)).
    pub unsettled: bool,
    /// One of them is stale (hot reload): its refresh publishes only settled, as before.
    pub stale: bool,
    /// One of them is provisional and the bake is at LOD 0: it replaces a reload's quick LOD 0.
    pub provisional: bool,
}

/// Whether a bake may be published after its latest unit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Due {
    /// Not yet.
    Wait,
    /// Published, and the bake goes on at this LOD into the same sums (no restart).
    Early,
    /// Published, and the bake is done: its error is below the bound or it has the most
    /// directions it may have.
    Settled,
}

/// The swap rule for a bake at `lod` with `directions` traced and an estimated `error`:
/// * settled when it has `min_directions` and its error is at most `error_bound`, or
///   `max_directions` (a reload's LOD-0 replacement: first light's directions);
/// * early, at a finer LOD than shown, once it has at least the directions of the shown level
///   (and `min_directions`): per-texel noise at equal directions is about the same at every
///   LOD (each texel gets ~oversampling² bundle lines per direction), so the finer level is
///   no noisier and is sharper. The error estimate is an upper bound (1.9–3.2× the measured
///   error, `tests/runtime.rs`), so waiting for it would keep most cells at the coarser
///   level until `max_directions`;
/// * early again, at the LOD an unsettled cell shows, each time its directions double (a
///   refresh of stale cells waits until settled, as it always has).
pub(super) fn publish_due(config: &RuntimeConfig, lod: u32, shown: ShownNow, directions: u64, error: f32) -> Due {
    let d = directions;
    let min = config.min_directions as u64;
    if shown.provisional {
        // Replacing a reload's quick LOD 0: with first light's directions, as LOD 0 is
        // everywhere else.
        return if d >= config.bundle.directions as u64 { Due::Settled } else { Due::Wait };
    }
    if d >= config.max_directions as u64 || (d >= min && error <= config.error_bound) {
        return Due::Settled;
    }
    let early = if lod > shown.lod {
        d >= min.max(shown.directions)
    } else {
        lod == shown.lod && shown.unsettled && !shown.stale && d >= min.max(2 * shown.directions)
    };
    if early { Due::Early } else { Due::Wait }
}

/// What the cells of `bake` show now (see [`ShownNow`]).
pub(super) fn shown_now(st: &State, bake: &CellBake) -> ShownNow {
    let leader = &st.cells[bake.leader() as usize];
    let lod = leader.shown;
    let cells = || bake.cells.iter().map(|&m| &st.cells[m as usize]);
    ShownNow {
        lod,
        directions: cells().map(|s| s.history.get(lod as usize).map_or(0, |h| h.0)).max().unwrap_or(0),
        unsettled: cells().all(|s| s.unsettled && s.shown == lod),
        stale: cells().any(|s| s.stale),
        provisional: bake.lod == 0 && cells().any(|s| s.provisional),
    }
}

/// Writes a bake's texels and gutter pixels (`values` per texel) into `map`'s bundle layer
/// at its LOD and swaps its cells to it. Returns the pixels written per cell of the bake.
pub fn publish_bake(map: &mut ShownLightmap, bake: &CellBake, values: &[Rgb]) -> Vec<Vec<[u32; 2]>> {
    publish_texels(map, bake, values, &[])
}

/// [`publish_bake`], withdrawing first the pixels `replaced` of the cells' previous bakes at
/// that LOD (a refresh).
fn publish_texels(
    map: &mut ShownLightmap,
    bake: &CellBake,
    values: &[Rgb],
    replaced: &[Vec<[u32; 2]>],
) -> Vec<Vec<[u32; 2]>> {
    let t = &bake.texels;
    let mut writer = PageWriter::new(map);
    for p in replaced.iter().flatten() {
        writer.clear(Layer::Bundles, bake.lod, p[0], p[1]);
    }
    for (i, p) in t.pixel.iter().enumerate() {
        writer.write(Layer::Bundles, bake.lod, p[0], p[1], values[i]);
    }
    for &(g, i) in &t.gutter {
        writer.write(Layer::Bundles, bake.lod, g[0], g[1], values[i as usize]);
    }
    for &c in &bake.cells {
        writer.set_cell_lod(Layer::Bundles, c, bake.lod);
    }
    writer.finish();
    bake.pixels_per_cell()
}

/// Publishes a bake in one new snapshot (every cell of a group at once); `settled`: by the
/// error bound or the most directions, else early (the bake goes on, [`publish_due`]).
/// Returns the milliseconds since the change was seen when this published the last
/// provisional cell of a reload (`reload_refined`).
pub(super) fn publish(shared: &Shared, st: &mut State, bake: &CellBake, error: f32, settled: bool) -> Option<f64> {
    let values = bake.result();
    let lod = bake.lod as usize;
    let replaced: Vec<Vec<[u32; 2]>> = bake
        .cells
        .iter()
        .map(|&c| st.cells[c as usize].published.get_mut(lod).map(std::mem::take).unwrap_or_default())
        .collect();
    let mut map = (*shared.shown()).clone();
    let pixels = publish_texels(&mut map, bake, &values, &replaced);
    let mut refreshed = 0;
    for (&c, pixels) in bake.cells.iter().zip(pixels) {
        let cell = &mut st.cells[c as usize];
        cell.set_light(Layer::Bundles, bake.lod, map.layer_light(Layer::Bundles, bake.lod, &pixels));
        cell.shown = bake.lod;
        cell.stale = false;
        cell.unsettled = !settled;
        // (A provisional cell's next bake is at LOD 0: `next_lod`.)
        if cell.provisional && bake.lod == 0 {
            cell.provisional = false;
            refreshed += 1;
        }
        cell.history.resize(lod + 1, (0, f32::INFINITY));
        cell.history[lod] = (bake.directions(), error);
        cell.published.resize(lod + 1, Vec::new());
        cell.published[lod] = pixels;
    }
    shared.set_shown(map);
    st.stats.publishes += 1;
    if refreshed == 0 {
        return None;
    }
    let r = st.refining.as_mut()?;
    r.left = r.left.saturating_sub(refreshed);
    if r.left > 0 {
        return None;
    }
    let ms = r.seen_at.elapsed().as_secs_f64() * 1e3;
    st.refining = None;
    Some(ms)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config() -> RuntimeConfig {
        RuntimeConfig { min_directions: 32, max_directions: 512, error_bound: 0.03, ..RuntimeConfig::default() }
    }

    fn shown(lod: u32, directions: u64) -> ShownNow {
        ShownNow { lod, directions, unsettled: false, stale: false, provisional: false }
    }

    /// A finer level is published early at exactly the shown level's directions, whatever
    /// its error; the error bound still settles it sooner, never before the minimum.
    #[test]
    fn a_finer_level_swaps_at_the_shown_levels_directions() {
        let c = config();
        let from = shown(0, 128);
        assert_eq!(publish_due(&c, 1, from, 124, 0.2), Due::Wait);
        assert_eq!(publish_due(&c, 1, from, 128, 0.2), Due::Early);
        assert_eq!(publish_due(&c, 1, from, 32, 0.02), Due::Settled);
        assert_eq!(publish_due(&c, 1, from, 28, 0.0), Due::Wait, "below the minimum");
        // A shown level with fewer directions than the minimum: the minimum holds.
        assert_eq!(publish_due(&c, 1, shown(0, 16), 28, 0.2), Due::Wait);
        assert_eq!(publish_due(&c, 1, shown(0, 16), 32, 0.2), Due::Early);
        // More than the maximum shown: the maximum settles first.
        assert_eq!(publish_due(&c, 2, shown(1, 1024), 512, 0.2), Due::Settled);
    }

    /// An unsettled level is published again each time its directions double and settled by
    /// the bound or the maximum; a settled level (a stale refresh) or a stale unsettled one
    /// only when settled.
    #[test]
    fn an_unsettled_level_is_republished_as_its_directions_double() {
        let c = config();
        let unsettled = ShownNow { unsettled: true, ..shown(1, 128) };
        assert_eq!(publish_due(&c, 1, unsettled, 252, 0.2), Due::Wait);
        assert_eq!(publish_due(&c, 1, unsettled, 256, 0.2), Due::Early);
        assert_eq!(publish_due(&c, 1, unsettled, 140, 0.02), Due::Settled);
        assert_eq!(publish_due(&c, 1, ShownNow { unsettled: true, ..shown(1, 256) }, 512, 0.2), Due::Settled);
        assert_eq!(publish_due(&c, 1, shown(1, 128), 256, 0.2), Due::Wait, "a refresh of a settled level");
        let stale = ShownNow { stale: true, ..unsettled };
        assert_eq!(publish_due(&c, 1, stale, 256, 0.2), Due::Wait, "a stale level");
        assert_eq!(publish_due(&c, 1, stale, 512, 0.2), Due::Settled);
    }

    /// Replacing a reload's quick LOD 0 takes first light's directions, as before: no early
    /// publish and no error bound.
    #[test]
    fn a_provisional_lod0_waits_for_first_lights_directions() {
        let c = config();
        let provisional = ShownNow { provisional: true, ..shown(0, 32) };
        let full = c.bundle.directions as u64;
        assert_eq!(publish_due(&c, 0, provisional, full - 4, 0.0), Due::Wait);
        assert_eq!(publish_due(&c, 0, provisional, full, 0.5), Due::Settled);
    }
}
