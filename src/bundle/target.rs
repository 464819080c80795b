//! What a bundle backend is asked to do, independent of how it does it: the scene-wide
//! inputs ([`BundleScene`]), the texels a batch credits ([`BakeTarget`]: a whole LOD, or
//! the texels of one runtime cell) and the radiance the bundles see ([`SourceRadiance`]).
//!
//! Every triangle in a direction's window occludes and is seen, wherever it is; only target
//! texels receive. A fragment side that is a lit face but not a target texel is *foreign*:
//! its radiance comes from [`SurfaceRadiance`] (the runtime reads its shown light map there).

use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use glam::Vec3;

use super::emitters::{EmitterPlan, plan_emitters};
use super::progressive::BatchSums;
use super::sky::BundleSky;
use super::stats::PassStats;
use super::{BundleConfig, DirectionJob};
use crate::atlas::lookup::TexelTable;
use crate::atlas::texels::TexelEmission;
use crate::atlas::{Atlas, FaceId, TexelMap};
use crate::scene::{Rgb, Scene, SceneGeometry, Side};

/// Marks a triangle that belongs to no light-pass emitter group.
pub const NO_GROUP: u32 = u32::MAX;

/// Scene-wide inputs of every bundle pass, owned so that long-lived workers can hold them.
pub struct BundleScene {
    pub scene: Arc<Scene>,
    pub geom: Arc<SceneGeometry>,
    pub atlas: Arc<Atlas>,
    pub config: BundleConfig,
    pub emitters: EmitterPlan,
    /// Per triangle: its light-pass group or [`NO_GROUP`].
    pub group_of: Vec<u32>,
    /// What lines leaving the scene see (the environment filtered for `config.directions`).
    pub sky: BundleSky,
}

impl BundleScene {
    pub fn new(scene: Arc<Scene>, geom: Arc<SceneGeometry>, atlas: Arc<Atlas>, config: BundleConfig) -> Self {
        let emitters = plan_emitters(&scene, &geom, atlas.stats.lit_area, config.small_emitter_fraction);
        let mut group_of = vec![NO_GROUP; geom.len()];
        for (g, group) in emitters.small.iter().enumerate() {
            for &t in &group.triangles {
                group_of[t as usize] = g as u32;
            }
        }
        let sky = BundleSky::new(&scene, config.directions);
        BundleScene { scene, geom, atlas, config, emitters, group_of, sky }
    }

    /// Light-pass bundle pixel side (metres) at LOD `lod`.
    pub fn light_pixel(&self, lod: u32) -> f32 {
        self.atlas.texel_size / (1u64 << lod) as f32 / self.config.oversampling
    }

    /// Whether the global bundles carry the emission of face `face` (a large emitter).
    pub fn carried(&self, face: FaceId) -> bool {
        self.emitters.carried_by_bundles[self.atlas.faces[face as usize].tri as usize]
    }
}

/// The texels one bake credits.
pub struct BakeTarget<'a> {
    pub lod: u32,
    /// Per texel: its face.
    pub face: &'a [FaceId],
    /// Per texel: emitted radiance of its side (the light pass's emitter texels).
    pub emission: TexelEmission<'a>,
    /// Where fragments find their texels: one whole-LOD table (`chart: None`), or one table
    /// per chart holding target texels (ascending by chart).
    pub tables: &'a [TexelTable],
    /// A world box holding every target texel's surface (with its footprint): bundle windows
    /// are its projection. `None`: the whole scene.
    pub window: Option<(Vec3, Vec3)>,
    /// Triangles holding target texels (ascending): the importance of Sect. 3 is their texel
    /// density; other triangles only occlude and are seen.
    pub triangles: &'a [u32],
    /// With one whole-LOD table holding some of the LOD's texels (a region shard's share),
    /// per face id: whether the face's lookups may find one of them ([`faces_reaching`]). A
    /// face that may not is foreign without a lookup, and the resolve skips the pixels where
    /// no face that may lies (no target texel can be credited there). `None`: every face may.
    pub reach: Option<&'a [bool]>,
}

impl BakeTarget<'_> {
    pub fn len(&self) -> usize {
        self.face.len()
    }

    pub fn is_empty(&self) -> bool {
        self.face.is_empty()
    }

    /// Whether face `f`'s lookups may find a target texel (see [`reach`](Self::reach)).
    #[inline]
    pub fn reaches(&self, f: FaceId) -> bool {
        self.reach.is_none_or(|r| r.get(f as usize) == Some(&true))
    }

    /// The index in [`tables`](Self::tables) of the table serving chart `chart`, if any.
    pub fn table_index(&self, chart: u32) -> Option<usize> {
        match self.tables {
            [t] if t.chart.is_none() => Some(0),
            tables => tables.binary_search_by_key(&Some(chart), |t| t.chart).ok(),
        }
    }
}

/// What a target made of every texel of a whole-LOD texel map needs besides the map: its
/// one whole-LOD lookup table and the triangles holding texels.
pub struct WholeLod {
    tables: [TexelTable; 1],
    triangles: Vec<u32>,
}

impl WholeLod {
    pub fn new(atlas: &Atlas, texels: &TexelMap) -> WholeLod {
        WholeLod { tables: [TexelTable::of_map(texels)], triangles: target_triangles(atlas, &texels.face) }
    }

    /// The target: every texel of `texels` (the map this was made from), whole-scene window.
    pub fn target<'a>(&'a self, texels: &'a TexelMap) -> BakeTarget<'a> {
        BakeTarget {
            lod: texels.lod,
            face: &texels.face,
            emission: TexelEmission::Dense(&texels.emission),
            tables: &self.tables,
            window: None,
            triangles: &self.triangles,
            reach: None,
        }
    }
}

/// Per face of `atlas`: whether a lookup of one of its points at `lod` may find an entry
/// (texel or gutter pixel) of `table`: whether the table holds one within a pixel of the
/// face's UV bounds ([`TexelTable::any_in`]). A fragment's lookup reads the pixel
/// under the UV interpolated at a pixel centre inside the triangle, which is within the
/// bounds up to float rounding; the pixel of margin covers that. (Chart membership is not
/// enough: a chart's edge pixel may belong to a neighbouring chart's texel or gutter, and a
/// whole-LOD bake credits that texel there.)
pub fn faces_reaching(atlas: &Atlas, table: &TexelTable, lod: u32) -> Vec<bool> {
    let scale = (1u64 << lod) as f32;
    atlas
        .faces
        .iter()
        .map(|face| {
            let uv = face.uv.map(|p| p * scale);
            let lo = uv[0].min(uv[1]).min(uv[2]).floor();
            let hi = uv[0].max(uv[1]).max(uv[2]).floor();
            if !(lo.is_finite() && hi.is_finite()) {
                return true;
            }
            table.any_in(lo.x as i64 - 1, lo.y as i64 - 1, hi.x as i64 + 1, hi.y as i64 + 1)
        })
        .collect()
}

/// The triangles holding texels of faces `faces` (ascending, once each): a target's
/// [`BakeTarget::triangles`].
pub fn target_triangles(atlas: &Atlas, faces: &[FaceId]) -> Vec<u32> {
    let mut t: Vec<u32> = faces.iter().map(|&f| atlas.faces[f as usize].tri).collect();
    t.sort_unstable();
    t.dedup();
    // Made a triangle a texel: without this a whole LOD's bake would hold 4 B a texel for it.
    t.shrink_to_fit();
    t
}

/// Radiance of surfaces outside the target, at barycentrics `(u, v)` of triangle `tri`
/// (weights of corners 1 and 2) on side `side`.
pub trait SurfaceRadiance: Sync {
    /// Outgoing radiance toward the bundles: reflected light, plus emission where the
    /// global bundles carry it.
    fn radiance(&self, tri: u32, side: Side, u: f32, v: f32) -> Rgb;
    /// Emitted radiance (the light pass's emitters).
    fn emission(&self, tri: u32, side: Side, u: f32, v: f32) -> Rgb;
    /// Whether the source is held per texel of the whole LOD being baked (a region shard's,
    /// [`crate::bake::region_shard`]): a backend then asks [`radiance_at`](Self::radiance_at)
    /// and [`emission_at`](Self::emission_at) with the LOD pixel its own lookup would read,
    /// so that a foreign side reads the very texel a whole-LOD bake's table gives there.
    fn by_lod_pixel(&self) -> bool {
        false
    }
    /// The radiance of the texel at LOD pixel (x, y) (zero where none is); asked only of a
    /// source that is [`by_lod_pixel`](Self::by_lod_pixel).
    fn radiance_at(&self, _x: i64, _y: i64) -> Rgb {
        Rgb::ZERO
    }
    /// The emission of the texel at LOD pixel (x, y), as [`radiance_at`](Self::radiance_at).
    /// Apart from it because the global bundles never need it, and finding it costs a search
    /// among the emitting texels.
    fn emission_at(&self, _x: i64, _y: i64) -> Rgb {
        Rgb::ZERO
    }
    /// The concrete source, for a backend that evaluates some sources in its own kernels
    /// (the GPU resolve evaluates the runtime's shown-light-map source); `None`: backends
    /// call the methods above.
    fn as_any(&self) -> Option<&dyn std::any::Any> {
        None
    }
}

/// What the bundles of a batch see.
#[derive(Clone, Copy)]
pub struct SourceRadiance<'a> {
    /// Per target texel: its outgoing radiance toward the bundles.
    pub own: &'a [Rgb],
    /// Foreign sides; `None` when the target covers every lit face of the window (a side
    /// that still misses its texel then sees black and is counted as a lost lookup).
    pub foreign: Option<&'a dyn SurfaceRadiance>,
}

/// A batch stopped at a tile boundary because its cancel flag was raised; its sums are
/// partial and must be dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("the bundle batch was cancelled")]
pub struct Cancelled;

/// Errors making a backend.
#[derive(Debug, thiserror::Error)]
pub enum BackendError {
    #[error("{0}")]
    Unavailable(String),
}

/// Something that traces bundles: the CPU backend, and the GPU backend. The driver (bake
/// or runtime) owns directions, batching and the estimate; a backend turns a batch of
/// directions into the target's hit sums.
pub trait BundleBackend: Send {
    fn name(&self) -> &'static str;
    /// Traces `batch` for `target`, overwriting `sums` (sized to the target) with the
    /// batch's hit sums. Checks `cancel` between tiles.
    fn trace_batch(
        &mut self,
        target: &BakeTarget,
        batch: &[DirectionJob],
        source: &SourceRadiance,
        sums: &mut BatchSums,
        cancel: &AtomicBool,
    ) -> Result<PassStats, Cancelled>;

    /// Gives up what the backend keeps per texel of its last target (its own sums) once the
    /// driver is done with that target; the next batch sizes them again. A whole-LOD bake
    /// calls it before it rebuilds what it gave up of the texel map, so that the two are
    /// not held at once.
    fn release_texel_buffers(&mut self) {}

    /// Scales by `share` (in (0, 1]) the hits that threads working ahead of the unit due may
    /// keep waiting: a target that credits about that share of a whole LOD's texels, laid
    /// out as the whole LOD (a region shard's), makes about that share of its hits a tile,
    /// so the same tiles ahead keep that share of the hits. Results do not depend on it.
    fn scale_waiting_hits(&mut self, _share: f64) {}
}

/// Makes backends for a scene: the runtime is generic over this, never over a concrete
/// backend. `threads` is how many threads the backend may use for one batch.
pub trait BackendProvider: Send + Sync + 'static {
    type Backend: BundleBackend + 'static;
    fn name(&self) -> &'static str;
    fn backend(&self, scene: &Arc<BundleScene>, threads: usize) -> Result<Self::Backend, BackendError>;
}

/// A made-up source radiance for tests: every one of `texels` texels a different colour, so
/// that which texel a line sees shows in the sums.
#[cfg(test)]
pub(crate) fn distinct_colours(texels: usize) -> Vec<crate::scene::Rgb> {
    (0..texels)
        .map(|i| {
            let h = crate::sampling::mix64(i as u64);
            crate::scene::Rgb::new((h & 0xFF) as f32, (h >> 8 & 0xFF) as f32, (h >> 16 & 0xFF) as f32) / 64.0
        })
        .collect()
}
