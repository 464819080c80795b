//! Bounce rounds: LOD 0 baked as a chain of rounds whose sums add up across machines.
//!
//! The default bake gets its multi-bounce light from its own running estimate, refreshed
//! after every batch ([`crate::bundle::progressive`]): batch b reads batch b−1, so its
//! batches cannot be traced apart. In rounds each round reads a source fixed before it
//! starts, and its batches are independent:
//! * round 1's source is the emission the global bundles carry: it holds the direct light
//!   of the sky, the emitters (the light pass's small ones too) and the punctual lights;
//! * round r's source is round r−1's irradiance `E` as reflected light, `albedo/π · E`, plus
//!   that emission: round r holds the light of r−1 bounces.
//!
//! A round's estimate is a converged-source one (every batch weighs the same), so its sums
//! are plain sums over its batches: a share of the batches (a direction shard,
//! [`DirectionShare`]) sums its own, and the shards' sums added texel by texel are the
//! whole round's up to the order of the float additions. Round r's directions come from a
//! sequence of their own ([`round_seed`]): reading a source made from the same directions
//! would correlate the two rounds' noise (a bias, the second power of the same error).
//!
//! What rounds cost: each round traces all the bake's directions, so R rounds take R times
//! the directions of the default bake, which reaches its bounces in one pass. Light that
//! needs more than R−1 bounces is missing (for an albedo-weighted return ρ the missing part
//! is ~ρ^R of the reflected light).

use std::sync::atomic::AtomicBool;

use crate::atlas::TexelMap;
use crate::atlas::lookup::TexelTable;
use crate::bundle::progressive::ProgressiveEstimate;
use crate::bundle::{BundleBackend, BundleScene, Cancelled};
use crate::progress::Progress;
use crate::reference::Bvh;
use crate::sampling::mix64;
use crate::scene::Rgb;

use super::bundle::{BundleLodStats, DirectionShare, LodIrradiance, PunctualPass, Region, Traced, trace_region};

/// Most rounds a bake may take (each costs a whole bake's directions).
pub const MAX_ROUNDS: u32 = 64;

/// The seed of round `round`'s direction sequence (rounds count from 1; round 1 uses the
/// bake's own seed, so a one-round bake traces the directions of the default bake).
pub fn round_seed(seed: u64, round: u32) -> u64 {
    if round <= 1 { seed } else { mix64(seed ^ mix64(0x5245_424f_554e_4400 | round as u64)) }
}

/// One round's sums over a share of its batches, and what tracing them did.
pub struct RoundSums {
    pub estimate: ProgressiveEstimate,
    pub stats: BundleLodStats,
}

/// Source radiance of a round: each texel's carried emission plus, after round 1, its
/// reflection of the previous round's irradiance `previous` (one per texel, made in its
/// place: a round holds 12 B a texel of the previous round, not its estimate).
pub(super) fn round_source(bundle: &BundleScene, texels: &TexelMap, previous: Option<Vec<Rgb>>) -> Vec<Rgb> {
    let emitted = |i: usize| carried_emission(bundle, texels.face[i], texels.emission[i]);
    match previous {
        Some(mut e) => {
            for (i, e) in e.iter_mut().enumerate() {
                *e = reflected(texels.albedo[i], *e) + emitted(i);
            }
            e
        }
        None => (0..texels.len()).map(emitted).collect(),
    }
}

/// The part of a texel's `emission` (on face `face`) that the global bundles carry: all of
/// it, or none where the light pass carries it.
pub(super) fn carried_emission(bundle: &BundleScene, face: crate::atlas::FaceId, emission: Rgb) -> Rgb {
    if bundle.carried(face) { emission } else { Rgb::ZERO }
}

/// Diffuse reflection of `irradiance` (W/m²) by a surface of `albedo`: radiance, W/(sr·m²).
pub(super) fn reflected(albedo: Rgb, irradiance: Rgb) -> Rgb {
    albedo * irradiance * std::f32::consts::FRAC_1_PI
}

/// Bakes round `round` (from 1) of `texels` (a whole LOD's map with its albedo and emission;
/// `table` its [`TexelTable::of_map`], built once for the punctual pass and every round)
/// over the batches of share `index` of `count`. `previous`: round `round − 1`'s
/// irradiance (all shares merged), none in round 1. `punctual`: the exact punctual part the
/// estimate holds (empty: none; shards other than the first hold none, so that the merge
/// counts it once).
#[allow(clippy::too_many_arguments)]
pub fn bake_round(
    bundle: &BundleScene,
    backend: &mut dyn BundleBackend,
    texels: &TexelMap,
    table: &TexelTable,
    previous: Option<Vec<Rgb>>,
    punctual: Vec<Rgb>,
    round: u32,
    (index, count): (u32, u32),
    threads: usize,
    progress: &dyn Progress,
) -> RoundSums {
    let source = round_source(bundle, texels, previous);
    bake_round_from_source(bundle, backend, texels, table, source, punctual, round, (index, count), threads, progress)
}

/// [`bake_round`] from the round's `source` ([`round_source`]), made by the caller: a
/// shard gives up its map's albedo once the source is made (12 B a texel; the round reads
/// the source alone).
#[allow(clippy::too_many_arguments)]
pub(super) fn bake_round_from_source(
    bundle: &BundleScene,
    backend: &mut dyn BundleBackend,
    texels: &TexelMap,
    table: &TexelTable,
    source: Vec<Rgb>,
    punctual: Vec<Rgb>,
    round: u32,
    (index, count): (u32, u32),
    threads: usize,
    progress: &dyn Progress,
) -> RoundSums {
    let tables = std::slice::from_ref(table);
    let region = Region { texels: texels.view(), tables, window: None, foreign: None, triangles: None, reach: None };
    let share = DirectionShare { seed: round_seed(bundle.config.seed, round), index, count };
    let punctual = PunctualPass { irradiance: punctual, seconds: 0.0 };
    let never = AtomicBool::new(false);
    let traced =
        trace_region(bundle, backend, &region, Some(source), punctual, share, threads, progress, &never, &mut |_| {
            std::ops::ControlFlow::Continue(())
        });
    let Ok(Traced { estimate, stats, .. }) = traced else { unreachable!("a round is never cancelled") };
    RoundSums { estimate, stats }
}

/// A whole LOD baked in `rounds` rounds on this machine: the punctual pass once, then
/// every round over all its batches, each reading the one before. What `bake
/// --bounce-rounds` runs, and what direction shards merged round by round equal.
pub fn bake_lod_rounds(
    bundle: &BundleScene,
    bvh: &Bvh,
    backend: &mut dyn BundleBackend,
    texels: &TexelMap,
    rounds: u32,
    threads: usize,
    progress: &dyn Progress,
) -> Result<LodIrradiance, Cancelled> {
    let table = TexelTable::of_map(texels);
    let PunctualPass { irradiance: punctual, seconds } = PunctualPass::of_map(bundle, bvh, texels, &table, threads);
    let mut stats = BundleLodStats { punctual_seconds: seconds, ..BundleLodStats::default() };
    let mut last: Option<ProgressiveEstimate> = None;
    for round in 1..=rounds.max(1) {
        // The round reads the last one's irradiance alone (12 B a texel, not its 40 B of sums).
        let previous = last.take().map(|e| {
            let mut irradiance = Vec::new();
            e.irradiance_into(threads, &mut irradiance);
            irradiance
        });
        let r =
            bake_round(bundle, backend, texels, &table, previous, punctual.clone(), round, (0, 1), threads, progress);
        add_round_stats(&mut stats, &r.stats);
        last = Some(r.estimate);
    }
    let Some(estimate) = last else { unreachable!("at least one round") };
    stats.unsampled_texels = estimate.unsampled();
    Ok(LodIrradiance {
        irradiance: estimate.irradiance(),
        unsampled: estimate.unsampled_texels(),
        punctual: estimate.into_punctual(),
        stats,
    })
}

/// Adds a round's (or a shard's) figures to `total`: directions, batches, times and pass
/// counters summed; the layout figures (light-pass groups, emitters carried) are the same
/// in every round.
pub fn add_round_stats(total: &mut BundleLodStats, round: &BundleLodStats) {
    total.directions += round.directions;
    total.batches += round.batches;
    total.light_directions_per_group += round.light_directions_per_group;
    total.light_pass_groups = round.light_pass_groups;
    total.emitter_triangles_in_global_bundles = round.emitter_triangles_in_global_bundles;
    total.punctual_seconds += round.punctual_seconds;
    total.bundle_seconds += round.bundle_seconds;
    total.unsampled_texels = round.unsampled_texels;
    total.pass.add(&round.pass);
}
