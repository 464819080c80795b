//! A group of neighbouring cells refined to one LOD together: their texels (made for these
//! cells only) and a resumable accumulation of bundle batches with a per-texel variance
//! estimate. It computes the shown map's bundle layer; punctual lights are the other layer
//! (`runtime::punctual`). One bundle direction costs about the same for a few texels
//! as for thousands (the window's occluders are rasterised either way), so the scheduler
//! bakes small cells in groups (see `RuntimeConfig::group_texels`); a group of one is a
//! cell bake.
//!
//! The bundles see the shown light map as it was when the bake started (one bounce from a
//! converged field: every batch weighs the same), so the result depends only on that
//! snapshot, the seed and the number of directions — not on what other cells publish
//! meanwhile or on which worker ran which batch.

use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use glam::Vec3;

use super::shown::ShownLightmap;
use super::source::ShownSource;
use super::world::World;
use crate::atlas::chart_filter::{filter_scalar_within_charts, filter_within_charts};
use crate::atlas::sparse::SparseTexels;
use crate::atlas::texels::TexelEmission;
use crate::bundle::progressive::{BatchSums, ProgressiveEstimate, SourceKind};
use crate::bundle::stats::PassStats;
use crate::bundle::target::target_triangles;
use crate::bundle::{BakeTarget, BundleBackend, Cancelled, JobSequence, SourceRadiance};
use crate::grid::CellId;
use crate::sampling::mix64;
use crate::scene::{Rgb, luminance};

/// Per texel: batches folded in and the sum of their squared (filtered) residuals.
#[derive(Clone, Copy, Default)]
struct BatchMoments {
    n: u32,
    sum2: f64,
}

pub struct CellBake {
    /// The cells baked together; the first leads (a parked bake is kept in its slot, and
    /// its id seeds the directions).
    pub cells: Vec<CellId>,
    pub lod: u32,
    pub texels: SparseTexels,
    /// Per texel: the index in `cells` of the cell holding it.
    owner: Vec<u16>,
    triangles: Vec<u32>,
    window: (Vec3, Vec3),
    carried: Vec<bool>,
    estimate: ProgressiveEstimate,
    moments: Vec<BatchMoments>,
    jobs: JobSequence,
    directions: u64,
    sums: BatchSums,
    /// What the bundles see: the shown map at the bake's start, and its texels' radiance.
    source: ShownSource,
    own_source: Vec<Rgb>,
    /// Mean luminance of the texels' punctual light (the shown map's other layer, at the
    /// bake's start): the error is relative to all the light a texel shows.
    punctual_mean: f64,
}

/// Most cells one bake may group (their index per texel is a `u16`; groups stay far smaller).
pub const MAX_GROUP: usize = 512;

/// What one unit of work did.
pub struct UnitStats {
    pub pass: PassStats,
    pub directions: u64,
    /// Texels × directions traced.
    pub texel_samples: u64,
}

/// The window of a bake of `texels` (texel side `texel`, metres): their footprint, where every
/// bundle line crediting one of them crosses its surface (a line outside it credits none:
/// bundle windows, and the CPU's outline of the window, rest on that), padded by a hundredth
/// of a texel for the footprint's rounding to f32. A box of the texels' points grown by a
/// texel and a half, as it was, missed lines on faces a chart stretches (zdm2).
pub fn bundle_window(texels: &SparseTexels, texel: f32) -> (Vec3, Vec3) {
    let (lo, hi) = texels.footprint.unwrap_or((Vec3::ZERO, Vec3::ZERO));
    let pad = Vec3::splat(texel * 0.01) + (lo.abs().max(hi.abs()) * f32::EPSILON * 4.0);
    (lo - pad, hi + pad)
}

/// Seed of the direction sequence of `cell` at `lod`: independent per cell and level.
pub fn cell_seed(seed: u64, cell: CellId, lod: u32) -> u64 {
    mix64(seed ^ mix64(((lod as u64) << 32 | cell as u64) + 0x5EED))
}

impl CellBake {
    /// Makes the texels of `cells` (the first leads; at most [`MAX_GROUP`] cells) at `lod`;
    /// the bundles will see `shown`.
    pub fn new(world: &World, cells: &[CellId], lod: u32, shown: Arc<ShownLightmap>, seed: u64) -> CellBake {
        assert!(!cells.is_empty() && cells.len() <= MAX_GROUP, "a bake of {} cells", cells.len());
        let texels = world.cells_texels(cells, lod);
        let grid = world.grid;
        let owner = texels
            .position
            .iter()
            .map(|&p| cells.iter().position(|&m| m == grid.cell_of(p)).unwrap_or(0) as u16)
            .collect();
        let carried = texels.face.iter().map(|&f| world.bundle.carried(f)).collect();
        let config = &world.bundle.config;
        let n = texels.len();
        let source = ShownSource { shown, bundle: world.bundle.clone() };
        CellBake {
            cells: cells.to_vec(),
            owner,
            lod,
            triangles: target_triangles(&world.atlas, &texels.face),
            window: bundle_window(&texels, world.texel_size(lod)),
            carried,
            // Punctual lights are the shown map's other layer (`runtime::punctual`): the bake
            // holds the bundles' part of the light only.
            estimate: ProgressiveEstimate::without_punctual(SourceKind::Converged, n),
            moments: vec![BatchMoments::default(); n],
            jobs: JobSequence::new(
                cell_seed(seed, cells[0], lod),
                world.bundle.emitters.small.len(),
                config.light_directions,
            ),
            directions: 0,
            sums: BatchSums::new(n),
            source,
            own_source: Vec::new(),
            punctual_mean: 0.0,
            texels,
        }
    }

    pub fn directions(&self) -> u64 {
        self.directions
    }

    /// The world box the bake's bundles are windowed to ([`bundle_window`]).
    pub fn window(&self) -> (Vec3, Vec3) {
        self.window
    }

    /// The leading cell (see [`CellBake::cells`]).
    pub fn leader(&self) -> CellId {
        self.cells[0]
    }

    /// Per cell of the group (as in `cells`): the LOD pixels its texels and their gutter
    /// pixels cover.
    pub fn pixels_per_cell(&self) -> Vec<Vec<[u32; 2]>> {
        let t = &self.texels;
        let mut out = vec![Vec::new(); self.cells.len()];
        for (i, p) in t.pixel.iter().enumerate() {
            out[self.owner[i] as usize].push(*p);
        }
        for &(g, i) in &t.gutter {
            out[self.owner[i as usize] as usize].push(g);
        }
        out
    }

    /// The snapshot the bundles see.
    pub fn source_version(&self) -> u64 {
        self.source.shown.version
    }

    /// Traces the next `count` directions. A cancelled unit leaves the bake as it was.
    pub fn step(
        &mut self,
        world: &World,
        backend: &mut dyn BundleBackend,
        count: u32,
        cancel: &AtomicBool,
    ) -> Result<UnitStats, Cancelled> {
        if self.texels.is_empty() {
            self.directions += count as u64;
            return Ok(UnitStats { pass: PassStats::default(), directions: count as u64, texel_samples: 0 });
        }
        if self.own_source.is_empty() {
            self.own_source = self.source.own(&self.texels, &self.carried);
            self.punctual_mean = self.source.punctual_mean(&self.texels);
        }
        let batch: Vec<_> = (self.directions..self.directions + count as u64).map(|i| self.jobs.job(i)).collect();
        let target = BakeTarget {
            lod: self.lod,
            face: &self.texels.face,
            emission: TexelEmission::Dense(&self.texels.emission),
            tables: &self.texels.tables,
            window: Some(self.window),
            triangles: &self.triangles,
            reach: None,
        };
        let source = SourceRadiance { own: &self.own_source, foreign: Some(&self.source) };
        let pass = backend.trace_batch(&target, &batch, &source, &mut self.sums, cancel)?;
        let light_directions = count as u64 * world.bundle.config.light_directions as u64;
        self.estimate.add_batch(&self.sums, &self.texels.area, light_directions, 1);
        self.add_moments(light_directions);
        self.directions += count as u64;
        Ok(UnitStats { pass, directions: count as u64, texel_samples: count as u64 * self.texels.len() as u64 })
    }

    /// Folds the batch just traced into each texel's variance estimate. The published value
    /// is a ratio (global bundles: `π·ΣS/ΣA` over batches) plus a mean (light pass), so the
    /// batch's contribution to its error is the linearised residual
    /// `π·(S_b − R·A_b)/Ā + (l_b − l̄)` (luminance; R, Ā, l̄ the running estimates), filtered
    /// as the published result is ([`filter_within_charts`]), so neighbours' correlated
    /// noise (one light direction lights a whole patch) is not mistaken for noise the
    /// filter removes.
    fn add_moments(&mut self, light_directions: u64) {
        let t = &self.texels;
        let batches = self.estimate.batches() as f64;
        let residual: Vec<f32> = (0..t.len())
            .map(|i| {
                let (bundle, weight, light) = self.estimate.parts(i);
                let b = self.sums.bundle[i];
                let mut r = 0.0;
                if weight > 0.0 {
                    let mean_weight = weight / batches;
                    let seen = luminance(Rgb::new(b[0], b[1], b[2])) as f64;
                    let ratio = luminance(bundle) as f64 / std::f64::consts::PI;
                    r += std::f64::consts::PI * (seen - ratio * b[3] as f64) / mean_weight;
                }
                if light_directions > 0 && t.area[i] > 0.0 {
                    let l = luminance(self.sums.light.get(i).copied().unwrap_or(Rgb::ZERO)) as f64
                        * std::f64::consts::TAU
                        / light_directions as f64
                        / t.area[i] as f64;
                    r += l - luminance(light) as f64;
                }
                r as f32
            })
            .collect();
        let filtered = filter_scalar_within_charts(&t.pixel, |i| t.table_of(i), &residual);
        for (m, &r) in self.moments.iter_mut().zip(&filtered) {
            m.n += 1;
            m.sum2 += (r as f64) * (r as f64);
        }
    }

    /// Estimated relative error of the cell's published irradiance: the RMS over texels of
    /// each texel's standard error (from its filtered batch residuals: variance of the
    /// mean ≈ Σr²/(n(n−1))), over the cell's mean irradiance (the bundles' and the punctual
    /// layer's: what the cell shows). Infinite before two batches.
    pub fn error(&self) -> f32 {
        let n = self.estimate.batches() as f64;
        if self.texels.is_empty() {
            return 0.0;
        }
        if n < 2.0 {
            return f32::INFINITY;
        }
        let var: f64 = self.moments.iter().map(|m| m.sum2 / (n * (n - 1.0))).sum::<f64>() / self.moments.len() as f64;
        let mean_e: f64 = (0..self.texels.len()).map(|i| luminance(self.estimate.irradiance_of(i)) as f64).sum::<f64>()
            / self.texels.len() as f64
            + self.punctual_mean;
        if mean_e <= 0.0 {
            return 0.0;
        }
        (var.sqrt() / mean_e) as f32
    }

    /// The irradiance to publish in the shown map's bundle layer: the bundle and light-pass
    /// parts, lightly filtered within charts ([`filter_within_charts`]).
    pub fn result(&self) -> Vec<Rgb> {
        let total: Vec<Rgb> = (0..self.texels.len()).map(|i| self.estimate.irradiance_of(i)).collect();
        let t = &self.texels;
        filter_within_charts(&t.pixel, |i| t.table_of(i), &total, |i| self.estimate.sampled(i))
    }

    /// Bytes held by the bake.
    pub fn bytes(&self) -> usize {
        let n = self.texels.len();
        // Batch sums and totals (28 B each: bundle and light pass), own source (12), carried
        // flag (1), owner (2).
        self.texels.bytes() + n * (std::mem::size_of::<BatchMoments>() + 28 + 28 + 12 + 1 + 2)
    }
}
