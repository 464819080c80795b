//! Region shards (docs/SHARDS.md): one round of a bounce-rounds bake
//! ([`super::rounds`]) cut into N disjoint shares of LOD 0's texels, each share a set of
//! whole charts (spatially coherent, and a chart's texels only ever read their own chart's
//! neighbours). A region shard traces every batch of the round, for its own texels only;
//! the rest of the scene is seen through [`ForeignSource`]: the round's source (the
//! previous round's merged irradiance as reflected light, plus the carried emission) of
//! every other texel, looked up at the fragment's surface point through the whole LOD's
//! table. The shard never holds the whole LOD's texel attributes: it places the texels
//! ([`TexelMap::build_lookup`]) and asks each one's albedo and emission once, to make the
//! source ([`whole_source`]).
//!
//! Why the merge is the single-machine round: within a round the source is fixed, so a
//! texel's sums depend on the source and the geometry alone, not on which texels are baked
//! beside it, provided the bundles are laid out the same. They are: the importance (the
//! bundles' resolution) is set from every texel-holding triangle of the LOD (not the
//! share's alone), the lane count is the whole LOD's, the lookup table is whole-LOD shaped
//! (a fragment of any chart finds the same pixel; a pixel of another share's texel gives
//! the foreign code instead of that texel's id), and a foreign side reads the texel at the
//! LOD pixel the whole bake's lookup computes ([`SurfaceRadiance::radiance_at`]). Round 1's
//! sums are therefore the single bake's bits. From round 2 the other shares' texels' source
//! is held in half floats ([`super::half_source`]): a hit on one of them reads it rounded,
//! relative 2⁻¹¹ at most.

use std::sync::atomic::AtomicBool;

use glam::{Vec2, Vec3};

use crate::atlas::lookup::TexelTable;
use crate::atlas::texels::{NO_TEXEL, TexelEmission, TexelSubset};
use crate::atlas::{Atlas, TexelMap};
use crate::bundle::progressive::ProgressiveEstimate;
use crate::bundle::target::{faces_reaching, target_triangles};
use crate::bundle::{BundleBackend, BundleScene, SurfaceRadiance};
use crate::progress::Progress;
use crate::reference::Bvh;
use crate::scene::{Rgb, SceneGeometry, Side};

use super::bundle::{BundleLodStats, DirectionShare, PunctualPass, Region, Traced, trace_region};
use super::half_source::{HalfRgb, HalfScale};
use super::rounds::{carried_emission, reflected, round_seed};
use crate::parallel::par_for_each;

/// Logs the resident set and its peak so far at a step of a region shard (debug).
pub(super) fn stage(step: &str) {
    let mb = |b: Option<u64>| b.unwrap_or(0) as f64 / 1e6;
    tracing::debug!(
        step,
        resident_mb = mb(crate::bake::memory::resident_bytes()),
        peak_mb = mb(crate::bake::memory::peak_resident_bytes()),
        "region shard memory"
    );
}

/// Per chart of `atlas`: how many texels of `map` it holds.
pub fn chart_texels(map: &TexelMap, atlas: &Atlas) -> Vec<u64> {
    let mut count = vec![0u64; atlas.charts.len()];
    for &f in &map.face {
        count[atlas.faces[f as usize].chart as usize] += 1;
    }
    count
}

/// Per chart of `atlas`: the centre of the box of its faces' triangles (the origin for a
/// chart without faces).
pub fn chart_centres(atlas: &Atlas, geom: &SceneGeometry) -> Vec<Vec3> {
    let mut bounds = vec![(Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)); atlas.charts.len()];
    for face in &atlas.faces {
        let b = &mut bounds[face.chart as usize];
        for &c in &geom.corners[face.tri as usize] {
            *b = (b.0.min(c), b.1.max(c));
        }
    }
    bounds.iter().map(|&(lo, hi)| if lo.cmple(hi).all() { (lo + hi) * 0.5 } else { Vec3::ZERO }).collect()
}

/// Deals charts to `count` shares of about 1/count of the texels each, in space: the charts
/// holding texels are ordered along a Z-order curve through their centres (`centres`, per
/// chart; ties by chart id), and the curve is cut in `count` runs: a chart goes to the share
/// its middle texel falls in (share k holds the texels k·T/count … (k+1)·T/count of the
/// curve). Deterministic. Neighbouring charts share a run, so a share's charts lie together
/// and a bundle line crosses them in a few places: a region shard resolves only the pixels
/// where its faces lie ([`faces_reaching`]). Every share holds within the largest chart of
/// T/count (its ends each move by at most half a chart). Charts without texels go to share 0.
/// Returns the share of each chart.
pub fn deal_charts(chart_texels: &[u64], centres: &[Vec3], count: u32) -> Vec<u32> {
    let count = count.max(1) as u128;
    let held: Vec<u32> = (0..chart_texels.len() as u32).filter(|&c| chart_texels[c as usize] > 0).collect();
    let (lo, hi) = held
        .iter()
        .map(|&c| centres[c as usize])
        .filter(|p| p.is_finite())
        .fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), p| (lo.min(p), hi.max(p)));
    // 21 bits an axis: a 63-bit key.
    let scale = ((1u32 << 21) - 1) as f32 / (hi - lo).max_element().max(f32::MIN_POSITIVE);
    let key = |c: u32| -> u64 {
        let p = centres[c as usize];
        let q = if p.is_finite() { ((p - lo) * scale).max(Vec3::ZERO) } else { Vec3::ZERO };
        crate::morton::key3(q.x as u32, q.y as u32, q.z as u32)
    };
    let mut order: Vec<(u64, u32)> = held.iter().map(|&c| (key(c), c)).collect();
    order.sort_unstable();
    let total: u128 = held.iter().map(|&c| chart_texels[c as usize] as u128).sum();
    let mut owner = vec![0u32; chart_texels.len()];
    let mut before = 0u128;
    for (_, c) in order {
        let n = chart_texels[c as usize] as u128;
        // The middle texel's share: ⌊(before + n/2)·count / T⌋, in halves to stay exact.
        owner[c as usize] = ((2 * before + n) * count / (2 * total)).min(count - 1) as u32;
        before += n;
    }
    owner
}

/// The texels of `map` whose chart `owner` gives to share `index` (ascending ids).
pub fn share_texels(map: &TexelMap, atlas: &Atlas, owner: &[u32], index: u32) -> Vec<u32> {
    (0..map.len() as u32)
        .filter(|&i| owner[atlas.faces[map.face[i as usize] as usize].chart as usize] == index)
        .collect()
}

/// The map of texels `keep` (ascending ids) of `map`: their per-texel values in the same
/// order, and the gutter pixels copying them (renumbered). Its ids still follow the pixel
/// blocks, so its [`TexelTable::of_map`] is a ranked whole-LOD table holding these texels
/// alone (24 B an 8×8 block and 4 B a gutter pixel).
pub fn subset_map(map: &TexelMap, keep: &[u32]) -> TexelMap {
    let pick = |v: &Vec<_>| -> Vec<_> {
        if v.is_empty() { Vec::new() } else { keep.iter().map(|&i| v[i as usize]).collect() }
    };
    let pick_rgb = |v: &Vec<Rgb>| -> Vec<Rgb> {
        if v.is_empty() { Vec::new() } else { keep.iter().map(|&i| v[i as usize]).collect() }
    };
    let pick_f = |v: &Vec<f32>| -> Vec<f32> {
        if v.is_empty() { Vec::new() } else { keep.iter().map(|&i| v[i as usize]).collect() }
    };
    let gutter = map.gutter.iter().filter_map(|&(p, t)| keep.binary_search(&t).ok().map(|k| (p, k as u32))).collect();
    TexelMap {
        lod: map.lod,
        width: map.width,
        height: map.height,
        pixel: pick(&map.pixel),
        face: pick(&map.face),
        position: if map.position.is_empty() {
            Vec::new()
        } else {
            keep.iter().map(|&i| map.position[i as usize]).collect()
        },
        normal: if map.normal.is_empty() { Vec::new() } else { keep.iter().map(|&i| map.normal[i as usize]).collect() },
        albedo: pick_rgb(&map.albedo),
        emission: pick_rgb(&map.emission),
        area: pick_f(&map.area),
        gutter,
    }
}

/// What a region shard sees of the texels outside its share: the round's source of the
/// texels of the LOD but its own ([`WholeSource::without`]: 6 B a texel from round 2, the
/// sending texels' alone in round 1) found through the whole LOD's lookup table (24 B an
/// 8×8 block of pixels, 4 B a gutter pixel), and the emission of the emitting texels (for
/// the light pass; 12 B an emitting texel and ~0.2 B a texel, [`TexelSubset`]). A side
/// whose pixel holds no texel is black, as a whole-LOD bake's lost lookup is; so would be
/// one that found a texel of the share, but the share's own table answers at its texels'
/// pixels and gutter pixels first (short of the rounding the module's notes describe, a
/// fragment within ~10⁻⁵ of a pixel's edge).
pub struct ForeignSource<'a> {
    atlas: &'a Atlas,
    table: TexelTable,
    source: OtherTexels,
    emitting: TexelSubset,
    scale: f32,
}

impl<'a> ForeignSource<'a> {
    /// The foreign source of `map` (a whole LOD's pixels: [`TexelMap::build_lookup`]) whose
    /// texels send `source` and emit `emitting`.
    pub fn new(atlas: &'a Atlas, map: &TexelMap, source: OtherTexels, emitting: TexelSubset) -> Self {
        ForeignSource { atlas, table: TexelTable::of_map(map), source, emitting, scale: (1u64 << map.lod) as f32 }
    }

    /// The texel under barycentrics `(u, v)` of `tri`'s side `side`, if any.
    fn texel(&self, tri: u32, side: Side, u: f32, v: f32) -> Option<u32> {
        let f = self.atlas.face(tri, side)?;
        let p: Vec2 = self.atlas.faces[f as usize].uv_at(u, v) * self.scale;
        if !(p.x >= 0.0 && p.y >= 0.0 && p.x < 1.6e7 && p.y < 1.6e7) {
            return None;
        }
        let p = p.floor();
        match self.table.get(p.x as i64, p.y as i64) {
            NO_TEXEL => None,
            t => Some(t),
        }
    }

    /// Bytes held (the source, the table, the emitting texels).
    pub fn bytes(&self) -> usize {
        self.source.bytes() + self.table.bytes() + self.emitting.bytes()
    }
}

impl SurfaceRadiance for ForeignSource<'_> {
    fn radiance(&self, tri: u32, side: Side, u: f32, v: f32) -> Rgb {
        self.texel(tri, side, u, v).map_or(Rgb::ZERO, |t| self.source.at(t))
    }

    fn emission(&self, tri: u32, side: Side, u: f32, v: f32) -> Rgb {
        self.texel(tri, side, u, v).map_or(Rgb::ZERO, |t| self.emitting.at(t))
    }

    fn by_lod_pixel(&self) -> bool {
        true
    }

    fn radiance_at(&self, x: i64, y: i64) -> Rgb {
        match self.table.get(x, y) {
            NO_TEXEL => Rgb::ZERO,
            t => self.source.at(t),
        }
    }

    fn emission_at(&self, x: i64, y: i64) -> Rgb {
        match self.table.get(x, y) {
            NO_TEXEL => Rgb::ZERO,
            t => self.emitting.at(t),
        }
    }
}

/// A round's source of every texel of the whole LOD, as a region shard holds it: dense
/// where it reflects the last round's light (every texel sends some), the sending texels
/// alone in round 1, whose source is the carried emission (a few emitters' texels: ~0.2 B
/// a texel where dense is 12).
pub enum WholeSource {
    Dense(Vec<Rgb>),
    Sending(TexelSubset),
}

impl WholeSource {
    /// Texel `i`'s source radiance.
    #[inline]
    pub fn at(&self, i: u32) -> Rgb {
        match self {
            WholeSource::Dense(v) => v[i as usize],
            WholeSource::Sending(s) => s.at(i),
        }
    }

    /// The source of the texels a region shard finds through its foreign lookup: all but
    /// the share's own texels `own` (ascending ids), whose source it holds apart and finds
    /// through its own table (their pixels and gutters are its table's entries).
    pub fn without(self, own: &[u32]) -> OtherTexels {
        match self {
            WholeSource::Dense(v) => {
                let scale = HalfScale::of(&v);
                OtherTexels::Half(TexelSubset::all_but(&v, own, |c| scale.encode(c)), scale)
            }
            WholeSource::Sending(s) => OtherTexels::Sending(s),
        }
    }
}

/// The source of the texels outside a region shard's share: from round 2 every one's, in
/// half floats (6 B a texel where f32 took 12; [`super::half_source`]), in round 1 the
/// sending texels' alone (f32, as the single bake's).
pub enum OtherTexels {
    Half(TexelSubset<HalfRgb>, HalfScale),
    Sending(TexelSubset),
}

impl OtherTexels {
    #[inline]
    fn at(&self, i: u32) -> Rgb {
        match self {
            OtherTexels::Half(s, scale) => s.get(i).map_or(Rgb::ZERO, |h| scale.decode(h)),
            OtherTexels::Sending(s) => s.at(i),
        }
    }

    fn bytes(&self) -> usize {
        match self {
            OtherTexels::Half(s, _) => s.bytes(),
            OtherTexels::Sending(s) => s.bytes(),
        }
    }
}

/// Round `round`'s source of every texel of `map`, a whole LOD's lookup map
/// ([`TexelMap::build_lookup`]): what [`super::rounds::round_source`] makes of the full map
/// (`previous`: the last round's irradiance, none in round 1), and the emission of the
/// emitting texels. Each texel's attributes are asked once, in parallel chunks, and none is
/// held.
fn whole_source(
    bundle: &BundleScene,
    map: &TexelMap,
    previous: Option<Vec<Rgb>>,
    threads: usize,
) -> (WholeSource, TexelSubset) {
    let n = map.len();
    let chunk = n.div_ceil(threads.max(1) * 4).max(4096);
    let starts = || (0..n).step_by(chunk);
    let attributes = |i: usize| map.attributes_of(&bundle.scene, &bundle.geom, &bundle.atlas, i);
    // Per chunk, the emitting texels (texel, emission) and in round 1 the sending ones.
    let mut emitting: Vec<Vec<(u32, Rgb)>> = vec![Vec::new(); n.div_ceil(chunk)];
    let source = match previous {
        Some(mut source) => {
            let items: Vec<_> = source.chunks_mut(chunk).zip(emitting.iter_mut()).zip(starts()).collect();
            par_for_each(items, threads, |((source, emitting), first)| {
                for (k, s) in source.iter_mut().enumerate() {
                    let (i, a) = (first + k, attributes(first + k));
                    *s = reflected(a.albedo, *s) + carried_emission(bundle, map.face[i], a.emission);
                    if a.emission != Rgb::ZERO {
                        emitting.push((i as u32, a.emission));
                    }
                }
            });
            WholeSource::Dense(source)
        }
        None => {
            let mut sending: Vec<Vec<(u32, Rgb)>> = vec![Vec::new(); emitting.len()];
            let items: Vec<_> = sending.iter_mut().zip(emitting.iter_mut()).zip(starts()).collect();
            par_for_each(items, threads, |((sending, emitting), first)| {
                for i in first..(first + chunk).min(n) {
                    let a = attributes(i);
                    if a.emission != Rgb::ZERO {
                        emitting.push((i as u32, a.emission));
                        let sent = carried_emission(bundle, map.face[i], a.emission);
                        if sent != Rgb::ZERO {
                            sending.push((i as u32, sent));
                        }
                    }
                }
            });
            WholeSource::Sending(TexelSubset::from_entries(n, sending.into_iter().flatten()))
        }
    };
    (source, TexelSubset::from_entries(n, emitting.into_iter().flatten()))
}

/// Bytes a texel of the share takes in its map while its bundles run (face, area; no
/// positions, normals or albedo, the emission of the emitting texels alone, its pixel held
/// by the share's table), its id in the whole LOD, and its own source.
pub const SHARE_MAP_BYTES: u64 = 4 + 4 + 4 + 12;

/// Bytes a texel of the whole LOD takes in a region shard that reads a previous round while
/// it sets up: its source, dense in f32.
pub const DENSE_SOURCE_BYTES: u64 = 12;

/// Bytes a texel of the whole LOD takes in a region shard that reads a previous round while
/// its bundles run: its source in half floats ([`OtherTexels`]). Round 1's source is the
/// carried emission, held for the sending texels alone (counted with the emitting texels').
pub const FOREIGN_BYTES: u64 = 6;

/// Bytes a texel of the whole LOD takes in a region shard's lookup map while it sets up
/// ([`TexelMap::build_lookup`]: pixel, face, area, plus 8 B a gutter pixel, about 0.25 a
/// texel).
pub const LOOKUP_MAP_BYTES: f64 = 12.0 + 8.0 * crate::bake::memory::GUTTER_PER_TEXEL;

/// The peak a region shard of `count` shares of a LOD of `texels` texels is expected to
/// hold, before it allocates anything per texel: the larger of its set-up (the whole LOD's
/// lookup map and source beside the share's map and its source) and its bundles (the other
/// texels' source and the whole lookup table, and 1/`count` of what a single-machine bake
/// of the LOD holds per texel: [`crate::bake::memory::estimate_from_lod0`]). A merged
/// previous round is streamed ([`crate::shard::PreviousRound`]): its irradiance is read into
/// the buffer that becomes the round's source ([`DENSE_SOURCE_BYTES`]), its sums are never
/// held, and the share's punctual part (12 B a texel of the share) is read once the
/// bundles have given back their sums, which it does not outweigh.
pub fn estimate(
    texels: u64,
    count: u32,
    previous: bool,
    config: &crate::bake::BakeConfig,
) -> crate::bake::memory::MemoryEstimate {
    use crate::bake::memory::{SceneTraits, TABLE_BLOCK_BYTES, estimate_from_lod0};
    let single = estimate_from_lod0(texels, None, config, SceneTraits::LEAST);
    let t = texels as f64;
    let share = t / count.max(1) as f64;
    let table = t * TABLE_BLOCK_BYTES as f64 / 64.0 + t * crate::bake::memory::GUTTER_PER_TEXEL * 4.0;
    // The emitting (and in round 1 the sending) texels' bit and word counts (12 B a
    // 64-texel word each; their values are few).
    let emitting = t * 24.0 / 64.0;
    let (dense, source) = if previous { (t * DENSE_SOURCE_BYTES as f64, t * FOREIGN_BYTES as f64) } else { (0.0, 0.0) };
    // The share's pixels are in its map while it sets up.
    let own = share * (SHARE_MAP_BYTES + 4) as f64;
    // The dense source and its half floats are both held while the latter are made.
    let setup = t * LOOKUP_MAP_BYTES + dense + source + emitting + table + own;
    let run = source + table + emitting + single.texel_bytes as f64 / count.max(1) as f64;
    let texel_bytes = setup.max(run) as u64;
    let bytes = texel_bytes + single.thread_bytes + single.texture_bytes + single.passing_bytes;
    crate::bake::memory::MemoryEstimate {
        texels,
        texel_bytes,
        bytes,
        bytes_per_texel: bytes as f64 / texels.max(1) as f64,
        ..single
    }
}

/// One region shard's round: the sums of its texels, which texels and charts they are.
pub struct RegionRound {
    pub estimate: ProgressiveEstimate,
    pub stats: BundleLodStats,
    /// The share's charts (ascending).
    pub charts: Vec<u32>,
    /// The share's texels: ids in the whole LOD's map (ascending).
    pub texels: Vec<u32>,
    /// The share's map (its texels in the order of the estimate).
    pub map: TexelMap,
    /// Bytes of the share's map, its table, the foreign source and the importance's
    /// triangles while the bundles ran.
    pub held_bytes: usize,
}

/// Bakes round `round` (from 1) of share `index` of `count` of `map`'s texels (a whole LOD
/// with its albedo and emission) over every batch of the round. `previous`: round
/// `round − 1`'s merged state (whole LOD, streamed), none in round 1; its punctual part is carried,
/// and in round 1 the share's punctual pass is made here (each share holds its own texels'
/// part). The backend must lay bundles out as for the whole LOD: the caller makes it with
/// the whole LOD's lane count ([`crate::bundle::Lanes::for_texels`] of `map.len()`).
#[allow(clippy::too_many_arguments)]
pub fn bake_region_round(
    bundle: &BundleScene,
    bvh: &Bvh,
    backend: &mut dyn BundleBackend,
    map: TexelMap,
    previous: Option<&crate::shard::PreviousRound>,
    round: u32,
    (index, count): (u32, u32),
    threads: usize,
    progress: &dyn Progress,
) -> Result<RegionRound, crate::shard::ShardError> {
    let atlas = &*bundle.atlas;
    let owner = deal_charts(&chart_texels(&map, atlas), &chart_centres(atlas, &bundle.geom), count);
    let charts: Vec<u32> = (0..owner.len() as u32).filter(|&c| owner[c as usize] == index).collect();
    let keep = share_texels(&map, atlas, &owner, index);
    drop(owner);
    backend.scale_waiting_hits(keep.len() as f64 / map.len().max(1) as f64);
    stage("dealt");
    let triangles = target_triangles(atlas, &map.face);
    // The previous round's irradiance, read into the buffer that becomes the source.
    let (whole_source, emitting) = whole_source(bundle, &map, previous.map(|p| p.irradiance()).transpose()?, threads);
    stage("source");
    let own_source: Vec<Rgb> = keep.iter().map(|&i| whole_source.at(i)).collect();
    // The rest of the LOD's source, in half floats before anything else is made: the dense
    // source (12 B a texel of the LOD) is given up here, at the set-up's peak.
    let others = whole_source.without(&keep);
    // The share's texels; its source is made, so its bundles read that, not the albedo, and
    // the emission of its emitting texels alone.
    let mut sub = subset_map(&map, &keep);
    let own_emitting = TexelSubset::from_entries(
        keep.len(),
        keep.iter().enumerate().filter_map(|(k, &i)| emitting.get(i).map(|e| (k as u32, e))),
    );
    // What the bundles read of the whole LOD from here on: its source and its lookup. The
    // whole map is given up before they run.
    let foreign = ForeignSource::new(atlas, &map, others, emitting);
    drop(map);
    stage("subset");
    let tables = [TexelTable::of_map(&sub)];
    let reach = faces_reaching(atlas, &tables[0], sub.lod);
    // The share's table holds its pixels while the bundles run (given back after).
    sub.drop_pixels(&tables[0]);
    let held_bytes = foreign.bytes()
        + tables[0].bytes()
        + sub.len() * SHARE_MAP_BYTES as usize
        + sub.pixel.len() * 4
        + sub.gutter.len() * 8
        + triangles.len() * 4
        + reach.len()
        + own_emitting.bytes();
    let mut texels = sub.view();
    texels.emission = TexelEmission::Emitting(&own_emitting);
    let region = Region {
        texels,
        tables: &tables,
        window: None,
        foreign: Some(&foreign),
        triangles: Some(&triangles),
        reach: Some(&reach),
    };
    let share = DirectionShare::whole(round_seed(bundle.config.seed, round));
    // The punctual part is no input of a round's bundles (their source is fixed): it joins
    // the estimate after them, not held beside their sums.
    let no_punctual = PunctualPass { irradiance: Vec::new(), seconds: 0.0 };
    let never = AtomicBool::new(false);
    let traced = trace_region(
        bundle,
        backend,
        &region,
        Some(own_source),
        no_punctual,
        share,
        threads,
        progress,
        &never,
        &mut |_| std::ops::ControlFlow::Continue(()),
    );
    let Ok(Traced { estimate, stats, source }) = traced else { unreachable!("a round is never cancelled") };
    drop((source, foreign));
    backend.release_texel_buffers();
    stage("traced");
    sub.restore_pixels(&tables[0]);
    // Carried from the previous round, or made by the share's punctual pass in round 1
    // (each share holds its own texels' part).
    let punctual = match previous {
        Some(p) => p.punctual(Some(&keep))?,
        None => {
            let w = sub.width;
            let pixel = |i: usize| [sub.pixel[i] % w, sub.pixel[i] / w];
            PunctualPass::of(bundle, bvh, sub.lod, &sub.face, &pixel, |_| &tables[0], threads).irradiance
        }
    };
    drop(tables);
    let estimate = estimate.with_punctual(punctual);
    Ok(RegionRound { estimate, stats, charts, texels: keep, map: sub, held_bytes })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Dealing is a partition (every chart with texels in exactly one share), deterministic,
    /// and balanced: every share within the largest chart of the mean.
    #[test]
    fn charts_are_dealt_disjoint_complete_and_balanced() {
        let charts: Vec<u64> = (0..500u64).map(|c| 1 + crate::sampling::mix64(c) % 300).collect();
        let centres: Vec<Vec3> = (0..500u64)
            .map(|c| {
                let m = crate::sampling::mix64(c ^ 0xC0FFEE);
                Vec3::new((m & 0xffff) as f32, (m >> 16 & 0xffff) as f32, (m >> 32 & 0xffff) as f32) * 1e-3
            })
            .collect();
        let total: u64 = charts.iter().sum();
        let largest = *charts.iter().max().expect("charts");
        for n in [1u32, 2, 3, 4, 7, 16] {
            let owner = deal_charts(&charts, &centres, n);
            assert_eq!(owner, deal_charts(&charts, &centres, n), "deterministic");
            let mut held = vec![0u64; n as usize];
            for (c, &o) in owner.iter().enumerate() {
                assert!(o < n);
                held[o as usize] += charts[c];
            }
            assert_eq!(held.iter().sum::<u64>(), total, "complete and disjoint");
            let mean = total as f64 / n as f64;
            for h in &held {
                assert!((*h as f64 - mean).abs() <= largest as f64, "{h} texels, mean {mean}, largest chart {largest}");
            }
        }
        // More shares than charts: the extra shares hold nothing, nothing is lost; a chart
        // without texels goes to share 0.
        // Chart 0's middle texel is texel 2.5 of 8 (share 1 of 4), chart 2's 6.5 (share 3).
        let owner = deal_charts(&[5, 0, 3], &[Vec3::ZERO, Vec3::ONE, Vec3::X], 4);
        assert_eq!(owner, vec![1, 0, 3]);
    }

    /// Shares are compact: charts on a line, dealt in two, split at the middle (a Z-order
    /// curve visits one half-space of the first axis bit before the other).
    #[test]
    fn charts_are_dealt_by_place() {
        let centres: Vec<Vec3> = (0..64).map(|i| Vec3::new(((i * 37) % 64) as f32, 0.0, 0.0)).collect();
        let owner = deal_charts(&[10; 64], &centres, 2);
        for (c, p) in centres.iter().enumerate() {
            assert_eq!(owner[c], u32::from(p.x >= 32.0), "chart {c} at x = {}", p.x);
        }
    }

    /// `faces_reaching` misses no face: on the Van Gogh room at LOD 0, a share's table and
    /// points sampled over every face (a 12 × 12 barycentric lattice, edges included, each
    /// point's UV rounded down as a lookup does), a face whose point lands on an entry of the
    /// share's table always reaches. And it leaves faces out: most of the other shares' faces.
    #[test]
    fn a_face_that_finds_a_share_texel_reaches() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/van_gogh_room/van_gogh_room_lit.gltf");
        let scene = crate::scene::load_gltf(&path, &crate::scene::LoadOptions::default()).expect("bundled scene");
        let geom = SceneGeometry::new(&scene);
        let config = crate::atlas::AtlasConfig { texel_budget: 60_000, ..Default::default() };
        let atlas = Atlas::build(&scene, &geom, &config).expect("atlas");
        let map = TexelMap::build(&scene, &geom, &atlas, 0);
        let owner = deal_charts(&chart_texels(&map, &atlas), &chart_centres(&atlas, &geom), 4);
        let (mut found, mut left_out) = (0, 0);
        for index in 0..4 {
            let sub = subset_map(&map, &share_texels(&map, &atlas, &owner, index));
            let table = TexelTable::of_map(&sub);
            let reach = faces_reaching(&atlas, &table, 0);
            for (f, face) in atlas.faces.iter().enumerate() {
                let n = 12;
                let finds = (0..=n).any(|i| {
                    (0..=n - i).any(|j| {
                        let p = face.uv_at(i as f32 / n as f32, j as f32 / n as f32).floor();
                        table.get(p.x as i64, p.y as i64) != NO_TEXEL
                    })
                });
                assert!(!finds || reach[f], "share {index}: face {f} finds a texel but is not reaching");
                found += finds as u32;
                left_out += (!reach[f] && owner[face.chart as usize] != index) as u32;
            }
        }
        let faces = atlas.faces.len() as u32;
        assert!(found >= faces * 9 / 10, "{found} of {faces} faces found a texel of their share");
        assert!(left_out > faces * 2, "{left_out} faces of other shares left out (of {} in all)", faces * 3);
    }
}
