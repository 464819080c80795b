//! Light-map atlas: one unique light-map parametrisation for every lit face of the scene.
//!
//! A *face* is one side of a triangle that carries light-map texels: every triangle has a
//! front face; a triangle whose material is double-sided also has a back face, with its own
//! texels (architectural models are full of single-face walls lit from both sides).
//!
//! Faces are grouped into *charts* (from TEXCOORD_1 when the file has valid light-map UVs,
//! otherwise by our planar unwrapper), charts are packed into one atlas with gutters wide
//! enough for bilinear sampling at LOD 0 (the coarsest level), and [`texels::TexelMap`] gives,
//! per LOD, every texel's surface point (inverse mapping).
//!
//! UV units: atlas UVs are stored in **LOD-0 texel units** (x right, y down, origin at the
//! atlas's top-left corner). LOD k coordinates are `uv · 2^k`; normalised [0,1] UVs are
//! `uv / (width, height)`.

pub mod charts;
pub mod pack;
pub mod raster;
pub mod texels;
pub mod uv1;

use glam::Vec2;
use serde::Serialize;

use crate::lod::LodHierarchy;
use crate::scene::{Scene, SceneGeometry, Side, TriangleId};

pub use texels::TexelMap;

/// Index into [`Atlas::faces`].
pub type FaceId = u32;
/// Marks "no face" in [`Atlas::face_of`].
pub const NO_FACE: FaceId = u32::MAX;

#[derive(Clone, Debug, Serialize)]
pub struct AtlasConfig {
    /// Metres per texel at LOD 0. `None`: derived from `texel_budget`.
    pub texel_size: Option<f32>,
    /// LOD-0 surface texels to aim for when `texel_size` is `None` (lit area / texel²).
    pub texel_budget: u64,
    /// Use TEXCOORD_1 as light-map UVs where it is present and valid.
    pub use_uv1: bool,
    /// Largest angle (radians) between a face's normal and its chart's seed normal.
    pub chart_max_angle: f32,
    /// Largest LOD-0 atlas side in texels; a texel size that needs more is an error.
    pub max_size: u32,
}

impl Default for AtlasConfig {
    fn default() -> Self {
        AtlasConfig {
            texel_size: None,
            texel_budget: 500_000,
            use_uv1: true,
            chart_max_angle: 40f32.to_radians(),
            max_size: 16384,
        }
    }
}

/// One light-mapped side of one triangle.
#[derive(Clone, Copy, Debug)]
pub struct AtlasFace {
    pub tri: TriangleId,
    pub side: Side,
    pub chart: u32,
    /// Atlas UV of the triangle's corners (same corner order as the triangle), LOD-0 texels.
    pub uv: [Vec2; 3],
}

/// Where a chart's UVs came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum ChartSource {
    Unwrapped,
    /// The mesh's own TEXCOORD_1 layout, placed as one block.
    Uv1,
}

/// A set of faces parametrised together, and the rectangle it occupies in the atlas.
#[derive(Clone, Debug)]
pub struct Chart {
    /// Mesh the faces belong to (charts never span meshes, so a changed mesh can be
    /// re-unwrapped alone).
    pub mesh: u32,
    pub side: Side,
    pub source: ChartSource,
    /// Top-left corner and size of the chart's rectangle in LOD-0 texels, including its
    /// one-texel dilation border.
    pub rect_min: (u32, u32),
    pub rect_size: (u32, u32),
    pub faces: Vec<FaceId>,
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct AtlasStats {
    pub charts: usize,
    pub faces: usize,
    pub meshes_from_uv1: usize,
    pub meshes_unwrapped: usize,
    /// Meshes whose TEXCOORD_1 was refused, with the reason.
    pub uv1_rejected: Vec<(String, String)>,
    /// Lit surface area in m² (double-sided faces counted twice).
    pub lit_area: f64,
    /// LOD-0 texels covered by some face / texels in the atlas.
    pub fill_ratio: f64,
    pub covered_texels_lod0: u64,
    pub unwrap_seconds: f64,
    pub pack_seconds: f64,
}

/// The packed light-map layout of a scene.
#[derive(Clone, Debug)]
pub struct Atlas {
    /// Metres per texel at LOD 0.
    pub texel_size: f32,
    /// LOD-0 atlas size in texels.
    pub width: u32,
    pub height: u32,
    pub faces: Vec<AtlasFace>,
    /// Per triangle: its front and back face, [`NO_FACE`] when absent.
    pub face_of: Vec<[FaceId; 2]>,
    pub charts: Vec<Chart>,
    pub stats: AtlasStats,
}

/// Errors building an atlas.
#[derive(Debug, thiserror::Error)]
pub enum AtlasError {
    #[error("the scene has no triangles to light-map")]
    Empty,
    #[error("texel size {0} m is not a positive finite number")]
    BadTexelSize(f32),
    #[error("the atlas would be {width}×{height} texels at LOD 0, above the limit of {max}; use a larger --texel-size")]
    TooLarge { width: u32, height: u32, max: u32 },
}

impl Atlas {
    /// Unwraps (or takes TEXCOORD_1) and packs every lit face of `scene`.
    pub fn build(scene: &Scene, geom: &SceneGeometry, config: &AtlasConfig) -> Result<Atlas, AtlasError> {
        let _ = (scene, geom, config);
        todo!("atlas build")
    }

    pub fn face(&self, tri: TriangleId, side: Side) -> Option<FaceId> {
        let f = self.face_of[tri as usize][side.index()];
        (f != NO_FACE).then_some(f)
    }

    pub fn lods(&self, levels: u32) -> LodHierarchy {
        LodHierarchy::new(self.width, self.height, levels)
    }
}
