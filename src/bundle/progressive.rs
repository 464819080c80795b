//! The progressive estimate of a bundle bake: directions arrive in batches; after each batch
//! the texels' irradiance (and the radiance they send to the next batch) is updated.
//!
//! Three parts add up to a texel's irradiance:
//! * punctual lights: exact, from the texel-space pass;
//! * small emitters: the light pass, `E = 2π/N_l · Σ a·Le / A_texel` (an absolute estimate:
//!   unbiased after any number of light directions N_l);
//! * everything else the global bundles see (sky, large emitters, reflected light):
//!   `E = π · Σ w_b S_b / Σ w_b A_b` with per-batch hit sums S (Σ a·L) and A (Σ a).
//!
//! Multi-bounce is a stochastic Jacobi iteration (Sbert's global lines): a batch reads the
//! radiance of what it sees from a *source* built from the previous batch alone (plus the
//! running light-pass and punctual estimates), so the source gains one bounce per batch and
//! converges geometrically (error ∝ ρ^b for albedo ρ). Building it from the running average
//! instead drags early, bounce-poor batches along: in a closed room of albedo 0.8 that
//! stays ~20% low after 256 batches. A single batch's source is noisy, but noise in the
//! source only adds variance, never bias, since the transport is linear in it.
//!
//! The result averages all batches with weights w_b ∝ b², so the first batches, whose
//! source still lacked bounces, count little (a plain running mean stays biased low:
//! −7.6% at 16k directions in a closed room). When the source is already converged (a finer
//! LOD reading the coarser one), every batch weighs the same.

use crate::atlas::texels::TexelEmission;
use crate::parallel::{par_chunks_mut, par_for_each};
use crate::scene::Rgb;

/// Hit sums of one batch, per texel.
#[derive(Clone, Debug, Default)]
pub struct BatchSums {
    /// Global bundles: (Σ a·L rgb, Σ a).
    pub bundle: Vec<[f32; 4]>,
    /// Light pass: Σ a·Le (rgb); empty when the bake has no light pass (no small emitter),
    /// which then reads as zero everywhere.
    pub light: Vec<Rgb>,
}

impl BatchSums {
    pub fn new(texels: usize) -> Self {
        Self::with_light(texels, true)
    }

    /// Zeroed sums of `texels` texels, the light-pass sums only when `light`.
    ///
    /// The zeros are written, not left to the allocator: `vec![[0.0; 4]; n]` asks for
    /// zeroed pages, which the resolve's first add reads before it writes, so each page was
    /// faulted twice (the shared zero page, then a copy-on-write that flushes the other
    /// threads' TLBs): ~4% of a direction shard's CPU time on the Van Gogh room (perf).
    pub fn with_light(texels: usize, light: bool) -> Self {
        let mut bundle = Vec::with_capacity(texels);
        bundle.resize(texels, [0.0; 4]);
        BatchSums { bundle, light: if light { vec![Rgb::ZERO; texels] } else { Vec::new() } }
    }

    /// Whether these are zeroed sums of `texels` texels with (or without) light-pass sums.
    pub fn fits(&self, texels: usize, light: bool) -> bool {
        self.bundle.len() == texels && self.light.len() == if light { texels } else { 0 }
    }

    pub fn clear(&mut self) {
        self.bundle.fill([0.0; 4]);
        self.light.fill(Rgb::ZERO);
    }

    /// Adds `lanes` to `self` texel by texel, in lane order after `self` (so `self` ends as
    /// `self + lanes[0] + lanes[1] + …`, deterministic whatever the thread count: `self` is
    /// lane 0 of the batch, and no separate buffer holds the total), and zeroes the lanes
    /// for the next batch. Every lane has the same shape as `self`.
    pub fn add_lanes(&mut self, lanes: &mut [BatchSums], threads: usize) {
        let n = self.bundle.len();
        let chunk = n.div_ceil(threads.max(1) * 4).max(4096);
        let light = !self.light.is_empty();
        // Work item: one chunk of the output and the same chunk of every lane (light-pass
        // chunks empty without a light pass).
        type Part<'a> = (&'a mut [[f32; 4]], &'a mut [Rgb]);
        fn split<'a>(s: &'a mut BatchSums, chunk: usize, light: bool) -> Vec<Part<'a>> {
            if light {
                s.bundle.chunks_mut(chunk).zip(s.light.chunks_mut(chunk)).collect()
            } else {
                s.bundle.chunks_mut(chunk).map(|b| (b, <&mut [Rgb]>::default())).collect()
            }
        }
        let mut items: Vec<(Part, Vec<Part>)> =
            split(self, chunk, light).into_iter().map(|out| (out, Vec::with_capacity(lanes.len()))).collect();
        for lane in lanes.iter_mut() {
            for (item, part) in items.iter_mut().zip(split(lane, chunk, light)) {
                item.1.push(part);
            }
        }
        // Lane after lane over the chunk: each texel's sum is still `self + lane 0 + lane 1 …`
        // in that order, and each lane is one straight loop the compiler vectorises.
        par_for_each(items, threads, |((out_b, out_l), parts)| {
            for (lane_b, lane_l) in parts {
                for (o, x) in out_b.iter_mut().zip(lane_b.iter_mut()) {
                    let x = std::mem::take(x);
                    for c in 0..4 {
                        o[c] += x[c];
                    }
                }
                for (o, x) in out_l.iter_mut().zip(lane_l.iter_mut()) {
                    *o += std::mem::take(x);
                }
            }
        });
    }
}

/// How batch results are weighted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SourceKind {
    /// The source is this bake's own running estimate: weight batch b by (b+1)².
    Progressive,
    /// The source is already converged (e.g. a coarser LOD): equal weights.
    Converged,
}

/// Weighted global-bundle sums of one texel over all batches so far, in f32 (16 B a texel,
/// half of f64's, at the bake's peak): each is a sum of positive terms, one per batch, so its
/// relative rounding error is at most `B·2⁻²⁴` after `B` batches (2·10⁻⁶ at the default 32,
/// 0.8% at the 131 072 batches of `converge`'s 2²⁰ directions, where the terms' roundings,
/// of either sign, leave ~√B·2⁻²⁴ = 2·10⁻⁵; either is far below the Monte Carlo error
/// there, ~1/√(directions)).
#[derive(Clone, Copy, Debug, Default)]
struct TexelTotals {
    bundle_sum: Rgb,
    bundle_weight: f32,
}

impl TexelTotals {
    /// Adds a batch's hit sums `b` (Σ a·L rgb, Σ a) with weight `w` (a texel it missed
    /// gets nothing).
    #[inline(always)]
    fn add(&mut self, b: [f32; 4], w: f32) {
        if b[3] > 0.0 {
            self.bundle_sum += Rgb::new(b[0], b[1], b[2]) * w;
            self.bundle_weight += b[3] * w;
        }
    }
}

/// Adds a batch's light-pass sum `Σ a·Le` of a texel of area `area` to its total over area
/// (a texel of no area gets none).
#[inline(always)]
fn add_light(total: &mut Rgb, sum: Rgb, area: f32) {
    if area > 0.0 {
        *total += sum / area;
    }
}

/// The global bundles' irradiance `π·Σw·S/Σw·A` of sums `(sum, weight)` (zero unsampled).
#[inline]
fn bundle_irradiance(sum: Rgb, weight: f32) -> Rgb {
    if weight > 0.0 { sum * (std::f32::consts::PI / weight) } else { Rgb::ZERO }
}

/// The light pass's irradiance `2π/N_l · Σ a·Le / A_texel` (zero without light-pass sums).
#[inline]
fn light_irradiance(light: Option<Rgb>, light_directions: u64) -> Rgb {
    scaled_light(light, light_scale(light_directions))
}

/// `2π/N_l` after `N_l` light directions (none before any): worked out once for a pass over
/// the texels, not as an f64 division a texel.
#[inline]
fn light_scale(light_directions: u64) -> Option<f32> {
    (light_directions > 0).then(|| (std::f64::consts::TAU / light_directions as f64) as f32)
}

/// [`light_irradiance`] with its scale worked out.
#[inline(always)]
fn scaled_light(light: Option<Rgb>, scale: Option<f32>) -> Rgb {
    match (light, scale) {
        (Some(l), Some(s)) => l * s,
        _ => Rgb::ZERO,
    }
}

/// The irradiance of a texel whose sums are `bundle` (`Σw·S rgb, Σw·A`), `light` (the light
/// pass's `Σ a·Le / A`, none without a light pass) after `light_directions`, and
/// `punctual`: what [`ProgressiveEstimate::irradiance_of`] gives for a texel holding them,
/// the same float operations in the same order (a round reading its previous round's
/// merged file texel by texel, [`crate::shard::PreviousRound`], makes the bits a single
/// bake makes from its whole estimate).
#[inline]
pub fn irradiance_of_sums(bundle: [f32; 4], light: Option<Rgb>, light_directions: u64, punctual: Option<Rgb>) -> Rgb {
    (punctual.unwrap_or(Rgb::ZERO) + light_irradiance(light, light_directions))
        + bundle_irradiance(Rgb::new(bundle[0], bundle[1], bundle[2]), bundle[3])
}

/// Running irradiance estimate of one LOD's texels.
pub struct ProgressiveEstimate {
    kind: SourceKind,
    totals: Vec<TexelTotals>,
    /// Light-pass sums per texel over its area, `Σ a·Le / A_texel` (f32, as the totals);
    /// empty until a batch brings light-pass sums (a bake without small emitters never
    /// does), zero where empty.
    light: Vec<Rgb>,
    /// Light directions traced so far (per emitter group: every group gets the same count).
    light_directions: u64,
    batches: u64,
    /// Irradiance from punctual lights (W/m²); empty when the estimate holds none (zero).
    punctual: Vec<Rgb>,
}

impl ProgressiveEstimate {
    /// The estimate of `punctual.len()` texels, no batch folded in yet.
    pub fn new(kind: SourceKind, punctual: Vec<Rgb>) -> Self {
        let mut e = Self::without_punctual(kind, punctual.len());
        e.punctual = punctual;
        e
    }

    /// This estimate holding `punctual` (one per texel; empty: none) as its punctual part,
    /// in place of what it held.
    ///
    /// # Panics
    /// When `punctual` is neither empty nor one per texel.
    pub fn with_punctual(mut self, punctual: Vec<Rgb>) -> Self {
        assert!(punctual.is_empty() || punctual.len() == self.totals.len(), "one punctual value per texel");
        self.punctual = punctual;
        self
    }

    /// The estimate of `texels` texels whose punctual light is held elsewhere (a runtime
    /// cell's is a layer of its own): reads as zero, and costs no 12 B a texel.
    pub fn without_punctual(kind: SourceKind, texels: usize) -> Self {
        ProgressiveEstimate {
            kind,
            totals: vec![TexelTotals::default(); texels],
            light: Vec::new(),
            light_directions: 0,
            batches: 0,
            punctual: Vec::new(),
        }
    }

    pub fn len(&self) -> usize {
        self.totals.len()
    }

    pub fn is_empty(&self) -> bool {
        self.totals.is_empty()
    }

    pub fn batches(&self) -> u64 {
        self.batches
    }

    pub fn light_directions(&self) -> u64 {
        self.light_directions
    }

    /// Texel `i`'s estimate in its parts: the global bundles' irradiance `π·Σw·S/Σw·A`, their
    /// total weight Σw·A, and the light pass's irradiance.
    pub fn parts(&self, i: usize) -> (Rgb, f64, Rgb) {
        (self.bundle_of(i), self.totals[i].bundle_weight as f64, self.light_of(i))
    }

    /// The global bundles' irradiance of texel `i`, `π·Σw·S/Σw·A`.
    #[inline]
    fn bundle_of(&self, i: usize) -> Rgb {
        let t = &self.totals[i];
        bundle_irradiance(t.bundle_sum, t.bundle_weight)
    }

    /// The light pass's irradiance of texel `i`, `2π/N_l · Σ a·Le / A_texel`.
    #[inline]
    fn light_of(&self, i: usize) -> Rgb {
        light_irradiance(self.light.get(i).copied(), self.light_directions)
    }

    /// Irradiance from punctual lights per texel (exact, noise-free); empty when the
    /// estimate holds none ([`without_punctual`](Self::without_punctual)).
    pub fn punctual(&self) -> &[Rgb] {
        &self.punctual
    }

    fn batch_weight(&self) -> f64 {
        match self.kind {
            SourceKind::Progressive => ((self.batches + 1) as f64).powi(2),
            SourceKind::Converged => 1.0,
        }
    }

    /// Folds one batch in. `area`: each texel's world area (m²), normalising the light pass
    /// (a texel of no area gets none); `light_directions`: how many light directions each
    /// emitter group received in the batch.
    pub fn add_batch(&mut self, sums: &BatchSums, area: &[f32], light_directions: u64, threads: usize) {
        let w = self.batch_weight() as f32;
        par_chunks_mut(&mut self.totals, threads, |start, chunk| {
            for (k, t) in chunk.iter_mut().enumerate() {
                t.add(sums.bundle[start + k], w);
            }
        });
        if !sums.light.is_empty() {
            if self.light.is_empty() {
                self.light = vec![Rgb::ZERO; self.totals.len()];
            }
            par_chunks_mut(&mut self.light, threads, |start, chunk| {
                for (k, l) in chunk.iter_mut().enumerate() {
                    add_light(l, sums.light[start + k], area[start + k]);
                }
            });
        }
        self.light_directions += light_directions;
        self.batches += 1;
    }

    /// Irradiance (W/m²) of texel `i` now.
    #[inline]
    pub fn irradiance_of(&self, i: usize) -> Rgb {
        self.direct_of(i) + self.bundle_of(i)
    }

    /// Punctual plus light-pass irradiance of texel `i`: the parts estimated absolutely.
    #[inline]
    fn direct_of(&self, i: usize) -> Rgb {
        self.punctual.get(i).copied().unwrap_or(Rgb::ZERO) + self.light_of(i)
    }

    pub fn irradiance(&self) -> Vec<Rgb> {
        (0..self.len()).map(|i| self.irradiance_of(i)).collect()
    }

    /// [`irradiance`](Self::irradiance) into `out`, reusing its allocation (a bake's source
    /// buffer at its end: no second per-texel buffer while the totals are alive).
    pub fn irradiance_into(&self, threads: usize, out: &mut Vec<Rgb>) {
        out.clear();
        out.resize(self.len(), Rgb::ZERO);
        par_chunks_mut(out, threads, |start, chunk| {
            for (k, o) in chunk.iter_mut().enumerate() {
                *o = self.irradiance_of(start + k);
            }
        });
    }

    /// The punctual irradiance, the estimate given up (empty when it held none).
    pub fn into_punctual(self) -> Vec<Rgb> {
        self.punctual
    }

    /// Texel `i`'s global-bundle sums `(Σw·S rgb, Σw·A)`: with [`light_sums`](Self::light_sums),
    /// [`light_directions`](Self::light_directions), [`batches`](Self::batches) and
    /// [`punctual`](Self::punctual) what the estimate is made of (what a direction shard
    /// writes, [`crate::shard`]).
    #[inline]
    pub fn bundle_sums(&self, i: usize) -> [f32; 4] {
        let t = &self.totals[i];
        [t.bundle_sum.x, t.bundle_sum.y, t.bundle_sum.z, t.bundle_weight]
    }

    /// The light pass's `Σ a·Le / A_texel` per texel; empty without a light pass.
    pub fn light_sums(&self) -> &[Rgb] {
        &self.light
    }

    /// The estimate made of the sums [`bundle_sums`](Self::bundle_sums) and the rest give
    /// (or their merge): `bundle` as
    /// `(Σw·S rgb, Σw·A)` per texel, `light` empty or one per texel, `punctual` empty or
    /// one per texel.
    pub fn from_sums(
        kind: SourceKind,
        bundle: Vec<[f32; 4]>,
        light: Vec<Rgb>,
        light_directions: u64,
        batches: u64,
        punctual: Vec<Rgb>,
    ) -> Self {
        let totals =
            bundle.into_iter().map(|b| TexelTotals { bundle_sum: Rgb::new(b[0], b[1], b[2]), bundle_weight: b[3] });
        ProgressiveEstimate { kind, totals: totals.collect(), light, light_directions, batches, punctual }
    }

    /// Texels no global bundle has hit yet.
    pub fn unsampled(&self) -> usize {
        self.totals.iter().filter(|t| t.bundle_weight == 0.0).count()
    }

    /// Whether a global bundle has hit texel `i` (one wholly inside closed geometry never
    /// is: [`crate::bundle::estimator`]'s buried layers).
    #[inline]
    pub fn sampled(&self, i: usize) -> bool {
        self.totals[i].bundle_weight > 0.0
    }

    /// The texels no global bundle has hit, ascending.
    pub fn unsampled_texels(&self) -> Vec<u32> {
        (0..self.totals.len() as u32).filter(|&i| !self.sampled(i as usize)).collect()
    }

    /// Folds one batch in (as [`add_batch`](Self::add_batch)) and writes into `out` the
    /// outgoing radiance each texel sends into the next batch, in one pass over the texels
    /// (two would read the batch's sums and the totals twice). A texel sends reflected light `albedo/π · E_src`, plus its
    /// emission when the global bundles carry it; `reflectance()` makes what tells, over a
    /// run of texels, a texel's albedo and whether it is carried. `E_src` is the direct
    /// estimate so far plus the indirect light of this batch alone (see the module docs), or,
    /// for a texel this batch missed, the running indirect estimate.
    #[allow(clippy::too_many_arguments)]
    pub fn add_batch_and_source<R: Reflectance>(
        &mut self,
        sums: &BatchSums,
        area: &[f32],
        light_directions: u64,
        reflectance: &(impl Fn() -> R + Sync),
        emission: TexelEmission,
        threads: usize,
        out: &mut Vec<Rgb>,
    ) {
        let n = self.len();
        let w = self.batch_weight() as f32;
        if !sums.light.is_empty() && self.light.is_empty() {
            self.light = vec![Rgb::ZERO; n];
        }
        self.light_directions += light_directions;
        self.batches += 1;
        let light_scale = light_scale(self.light_directions);
        // Every entry is written below: no need to clear what a previous batch left.
        out.resize(n, Rgb::ZERO);
        let chunk = n.div_ceil(threads.max(1) * 4).max(4096);
        // A chunk of the light-pass totals beside each chunk of the others (empty without them).
        let mut lights: Vec<&mut [Rgb]> = self.light.chunks_mut(chunk).collect();
        lights.resize_with(n.div_ceil(chunk), Default::default);
        let items: Vec<_> = self.totals.chunks_mut(chunk).zip(lights).zip(out.chunks_mut(chunk)).enumerate().collect();
        let punctual = &self.punctual;
        par_for_each(items, threads, |(c, ((totals, light), out))| {
            let mut reflect = reflectance();
            for (k, (t, o)) in totals.iter_mut().zip(out.iter_mut()).enumerate() {
                let i = c * chunk + k;
                let b = sums.bundle[i];
                t.add(b, w);
                let mut l = light.get_mut(k);
                if let Some(l) = l.as_deref_mut()
                    && let Some(&sum) = sums.light.get(i)
                {
                    add_light(l, sum, area[i]);
                }
                let direct = punctual.get(i).copied().unwrap_or(Rgb::ZERO) + scaled_light(l.copied(), light_scale);
                let indirect = if b[3] > 0.0 {
                    Rgb::new(b[0], b[1], b[2]) * (std::f32::consts::PI / b[3])
                } else {
                    bundle_irradiance(t.bundle_sum, t.bundle_weight)
                };
                *o = sent(direct + indirect, reflect.at(i), || emission.at(i));
            }
        });
    }

    /// The radiance each texel sends into the first batch (see
    /// [`add_batch_and_source`](Self::add_batch_and_source)): its reflected direct light.
    pub fn initial_source<R: Reflectance>(
        &self,
        reflectance: &(impl Fn() -> R + Sync),
        emission: TexelEmission,
        threads: usize,
        out: &mut Vec<Rgb>,
    ) {
        out.resize(self.len(), Rgb::ZERO);
        par_chunks_mut(out, threads, |start, chunk| {
            let mut reflect = reflectance();
            for (k, o) in chunk.iter_mut().enumerate() {
                let i = start + k;
                *o = sent(self.irradiance_of(i), reflect.at(i), || emission.at(i));
            }
        });
    }
}

/// What a texel reflects with, asked of it texel by texel in a pass over the texels (rather
/// than held: a per-texel albedo or flag is bytes a texel at the bake's peak).
pub trait Reflectance {
    /// Texel `i`'s albedo, and whether the global bundles carry its emission.
    fn at(&mut self, i: usize) -> (Rgb, bool);
}

/// What a texel of irradiance `e`, albedo `albedo` sends: `albedo/π · e`, plus its emission
/// when the global bundles carry it (`carried`).
#[inline(always)]
fn sent(e: Rgb, (albedo, carried): (Rgb, bool), emission: impl FnOnce() -> Rgb) -> Rgb {
    let reflected = albedo * e * std::f32::consts::FRAC_1_PI;
    if carried { reflected + emission() } else { reflected }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atlas::texels::TexelSubset;

    #[test]
    fn self_normalised_bundles_and_absolute_light_pass() {
        let mut est = ProgressiveEstimate::new(SourceKind::Converged, vec![Rgb::splat(1.0); 2]);
        let mut b = BatchSums::new(2);
        // Texel 0 saw L = 2 over total weight 3: E = 2π. Texel 1 got light-pass hits only.
        b.bundle[0] = [6.0, 6.0, 6.0, 3.0];
        b.light[1] = Rgb::splat(0.25);
        est.add_batch(&b, &[0.5, 0.5], 4, 2);
        let e = est.irradiance();
        let pi = std::f32::consts::PI;
        assert!((e[0] - Rgb::splat(1.0 + 2.0 * pi)).length() < 1e-5);
        // 2π/4 · 0.25 / 0.5 = π/4
        assert!((e[1] - Rgb::splat(1.0 + pi / 4.0)).length() < 1e-5);
        assert_eq!(est.unsampled(), 1);
    }

    /// What three texels send into the next batch, worked out by hand. Albedo 0.5, punctual
    /// irradiance 1, two batches (weights 1 and 4), the second's light pass 4 directions.
    /// Texel 0, hit by both batches (L = 1 then L = 3): E = 1 + π·3 from the last batch
    /// alone, and it sends 0.5/π·E. Texel 1, missed by the last batch: the running estimate,
    /// π·(1·1)/(1·1) = π, plus its light pass 2π/4 · 0.5 / 0.25 = π: E = 1 + 2π. Texel 2,
    /// never hit, carried, emitting 7: 0.5/π + 7. Folding in the same batch as `add_batch`
    /// does leaves the same estimate.
    #[test]
    fn a_batch_folded_in_sends_its_own_indirect_light_to_the_next() {
        let texels = 3;
        let mut fused = ProgressiveEstimate::new(SourceKind::Progressive, vec![Rgb::ONE; texels]);
        let mut plain = ProgressiveEstimate::new(SourceKind::Progressive, vec![Rgb::ONE; texels]);
        let mut first = BatchSums::new(texels);
        first.bundle[0] = [1.0, 1.0, 1.0, 1.0];
        first.bundle[1] = [1.0, 1.0, 1.0, 1.0];
        let mut second = BatchSums::new(texels);
        second.bundle[0] = [6.0, 6.0, 6.0, 2.0];
        second.light[1] = Rgb::splat(0.5);
        let area = [0.25; 3];
        let emission = TexelSubset::from_dense(&[Rgb::ZERO, Rgb::ZERO, Rgb::splat(7.0)]);
        struct Grey;
        impl Reflectance for Grey {
            fn at(&mut self, i: usize) -> (Rgb, bool) {
                (Rgb::splat(0.5), i == 2)
            }
        }
        let mut source = Vec::new();
        for (batch, light_directions) in [(&first, 0), (&second, 4)] {
            fused.add_batch_and_source(
                batch,
                &area,
                light_directions,
                &|| Grey,
                TexelEmission::Emitting(&emission),
                2,
                &mut source,
            );
            plain.add_batch(batch, &area, light_directions, 2);
        }
        let pi = std::f32::consts::PI;
        let expected = [0.5 / pi * (1.0 + 3.0 * pi), 0.5 / pi * (1.0 + 2.0 * pi), 0.5 / pi + 7.0];
        for (i, (s, e)) in source.iter().zip(expected).enumerate() {
            assert!((*s - Rgb::splat(e)).abs().max_element() < 1e-5, "texel {i}: {s} against {e}");
        }
        for i in 0..texels {
            assert_eq!(fused.irradiance_of(i), plain.irradiance_of(i), "texel {i}");
        }
        assert_eq!((fused.batches(), fused.light_directions()), (2, 4));
    }

    #[test]
    fn progressive_weights_favour_late_batches() {
        let mut est = ProgressiveEstimate::new(SourceKind::Progressive, vec![Rgb::ZERO]);
        let mut b = BatchSums::new(1);
        b.bundle[0] = [0.0, 0.0, 0.0, 1.0]; // batch 1 saw L = 0 (weight 1)
        est.add_batch(&b, &[1.0], 0, 1);
        b.bundle[0] = [1.0, 1.0, 1.0, 1.0]; // batch 2 saw L = 1 (weight 4)
        est.add_batch(&b, &[1.0], 0, 1);
        let e = est.irradiance()[0].x;
        assert!((e - std::f32::consts::PI * 4.0 / 5.0).abs() < 1e-5, "{e}");
    }
}
