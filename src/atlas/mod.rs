//! Light-map atlas: one unique light-map parametrisation for every lit face of the scene.
//!
//! A *face* is one side of a triangle that carries light-map texels: every triangle has a
//! front face; a triangle whose material is double-sided also has a back face, with its own
//! texels (architectural models are full of single-face walls lit from both sides).
//!
//! Faces are grouped into *charts* (from TEXCOORD_1 when the file has valid light-map UVs,
//! otherwise by our unwrapper), charts are packed into one atlas with gutters wide enough for
//! bilinear sampling at LOD 0 (the coarsest level), and [`texels::TexelMap`] gives, per LOD,
//! every texel's surface point (inverse mapping). Without a texel size, the size is searched
//! so that the faces cover `texel_budget` texels ([`Atlas::build`]). [`Atlas::update`]
//! changes an atlas for an edited scene, keeping unchanged meshes' charts in place.
//!
//! UV units: atlas UVs are stored in **LOD-0 texel units** (x right, y down, origin at the
//! atlas's top-left corner). LOD k coordinates are `uv · 2^k`; normalised UVs in \[0, 1\] are
//! `uv / (width, height)`.
//!
//! Pieces: [`charts`] (unwrapper: welding, planar charts, hinge merges), [`uv1`]
//! (TEXCOORD_1 validation), `copies` (rigid copies share charts), [`pack`] (chart rectangles and footprints, first-fit packing),
//! [`free`] (claimed texels, free space), [`update`] (incremental layout), [`raster`] (the
//! conservative coverage rule every part shares: what a face touches at LOD k is what the
//! packer reserved room for, what the TEXCOORD_1 check tested and what the texel map
//! rasterises), [`texels`] (inverse mapping).

pub mod chart_filter;
pub mod charts;
mod copies;
pub mod free;
pub mod lookup;
pub mod pack;
pub mod raster;
pub mod sparse;
pub mod texels;
pub mod update;
pub mod uv1;

#[cfg(test)]
mod tests;

use std::borrow::Cow;
use std::sync::Arc;
use std::time::Instant;

use glam::{DVec2, Vec2};
use serde::Serialize;

use crate::lod::LodHierarchy;
use crate::scene::{Scene, SceneGeometry, Side, TriangleId};
use copies::{CopyOf, link_copies};

pub use texels::TexelMap;
pub use update::{AtlasUpdate, MeshOrigin};

/// Index into [`Atlas::faces`].
pub type FaceId = u32;
/// Marks "no face" in [`Atlas::face_of`].
pub const NO_FACE: FaceId = u32::MAX;

#[derive(Clone, Debug, Serialize)]
pub struct AtlasConfig {
    /// Metres per texel at LOD 0. `None`: derived from `texel_budget`.
    pub texel_size: Option<f32>,
    /// LOD-0 texels to cover when `texel_size` is `None`: the texel size is chosen so that
    /// the faces cover this many texels (conservatively, as the texel map counts them).
    pub texel_budget: u64,
    /// Use TEXCOORD_1 as light-map UVs where it is present and valid.
    pub use_uv1: bool,
    /// Largest angle (radians) between a face's normal and its chart's seed normal
    /// (used up to 80°).
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

/// Largest [`AtlasConfig::max_size`]: texel maps number pixels with `u32`, so a LOD-0 atlas
/// must have fewer than 2³² pixels.
pub const MAX_ATLAS_SIDE: u32 = 65535;

impl AtlasConfig {
    /// Refuses settings no atlas can satisfy, before any work.
    pub fn validate(&self) -> Result<(), AtlasError> {
        if let Some(ts) = self.texel_size
            && !(ts.is_finite() && ts > 0.0)
        {
            return Err(AtlasError::BadTexelSize(ts));
        }
        if !(1..=MAX_ATLAS_SIDE).contains(&self.max_size) {
            return Err(AtlasError::BadMaxSize(self.max_size));
        }
        // Every covered texel is a pixel of the atlas: a budget beyond max_size² cannot be
        // met by any texel size.
        let most = self.max_size as u64 * self.max_size as u64;
        if self.texel_size.is_none() && !(1..=most).contains(&self.texel_budget) {
            return Err(AtlasError::BadBudget { budget: self.texel_budget, most });
        }
        Ok(())
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

impl AtlasFace {
    /// Atlas UV (LOD-0 texels) at barycentrics (u, v) (weights of corners 1 and 2, as
    /// [`SceneGeometry::point`]).
    #[inline]
    pub fn uv_at(&self, u: f32, v: f32) -> Vec2 {
        crate::scene::geometry::at_barycentrics(self.uv, u, v)
    }

    /// Corner UVs in LOD-`lod` pixels, f64.
    #[inline]
    pub fn uv_lod(&self, lod: u32) -> [DVec2; 3] {
        let s = (1u64 << lod) as f64;
        self.uv.map(|p| p.as_dvec2() * s)
    }
}

/// A triangle gets faces when its area is positive and its corners finite.
fn is_lit(geom: &SceneGeometry, t: usize) -> bool {
    let a = geom.areas[t];
    a > 0.0 && a.is_finite() && geom.corners[t].iter().all(|p| p.is_finite()) && geom.normals[t].is_finite()
}

/// Where a chart's UVs came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum ChartSource {
    Unwrapped,
    /// The mesh's own TEXCOORD_1 layout, placed as one block.
    Uv1,
}

/// A set of faces parametrised together, and the rectangle it sits in in the atlas.
#[derive(Clone, Debug)]
pub struct Chart {
    /// Mesh the faces belong to (charts never span meshes, so a changed mesh can be
    /// re-unwrapped alone).
    pub mesh: u32,
    pub side: Side,
    pub source: ChartSource,
    /// Top-left corner and size of the chart's rectangle in LOD-0 texels, including its
    /// one-texel dilation border. Rectangles of charts may overlap; what a chart claims in
    /// its rectangle ([`Chart::footprint`]) never meets another's.
    pub rect_min: (u32, u32),
    pub rect_size: (u32, u32),
    pub faces: Vec<FaceId>,
}

impl Chart {
    /// The chart's interior (its rectangle minus the one-texel border) in LOD-`lod` pixels:
    /// every pixel its faces touch lies in it.
    pub fn interior(&self, lod: u32) -> raster::PixelRect {
        let s = 1i64 << lod;
        let b = pack::BORDER as i64;
        let (x, y) = (self.rect_min.0 as i64, self.rect_min.1 as i64);
        let (w, h) = (self.rect_size.0 as i64, self.rect_size.1 as i64);
        raster::PixelRect::new((x + b) * s, (y + b) * s, (x + w - b) * s, (y + h - b) * s)
    }

    /// The LOD-0 pixels of its rectangle the chart claims ([`pack::Footprint`]), from its
    /// faces as laid out: a TEXCOORD_1 block claims the whole rectangle.
    pub fn footprint(&self, faces: &[AtlasFace]) -> pack::Footprint {
        if self.source == ChartSource::Uv1 {
            return pack::Footprint::full(self.rect_size);
        }
        let corner = DVec2::new(self.rect_min.0 as f64, self.rect_min.1 as f64);
        let tris = self.faces.iter().map(|&f| faces[f as usize].uv_lod(0).map(|q| q - corner));
        pack::Footprint::of_triangles(tris, self.rect_size)
    }

    /// The chart's whole rectangle in LOD-`lod` pixels.
    pub fn rect(&self, lod: u32) -> raster::PixelRect {
        let s = 1i64 << lod;
        let (x, y) = (self.rect_min.0 as i64, self.rect_min.1 as i64);
        let (w, h) = (self.rect_size.0 as i64, self.rect_size.1 as i64);
        raster::PixelRect::new(x * s, y * s, (x + w) * s, (y + h) * s)
    }
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
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
    /// The texel budget the texel size was solved for: `texel_budget`, or more where the
    /// charts need [`MIN_TEXELS_PER_CHART`] texels each; `None` with a given texel size.
    pub budget_used: Option<u64>,
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
    /// First triangle of each mesh in the geometry the atlas was built for (`len = meshes +
    /// 1`, as [`SceneGeometry::mesh_offsets`]): what [`Atlas::update`] maps old faces by.
    pub mesh_offsets: Vec<u32>,
    pub stats: AtlasStats,
}

/// Errors building an atlas.
#[derive(Debug, thiserror::Error)]
pub enum AtlasError {
    #[error("the scene has no triangles to light-map")]
    Empty,
    #[error("texel size {0} m is not a positive finite number")]
    BadTexelSize(f32),
    #[error("texel budget (--texel-budget) {budget} is not between 1 and {most} (the texels of the largest atlas)")]
    BadBudget { budget: u64, most: u64 },
    #[error("largest atlas side {0} is not between 1 and {MAX_ATLAS_SIDE} texels")]
    BadMaxSize(u32),
    #[error("the atlas would be {width}×{height} texels at LOD 0, above the limit of {max}; use a larger --texel-size")]
    TooLarge { width: u32, height: u32, max: u32 },
    #[error("atlas update: {0}")]
    BadUpdate(String),
}

/// The faces of a scene: a front face for every lit triangle, a back face when its material
/// is double-sided.
struct SceneFaces {
    faces: Vec<AtlasFace>,
    face_of: Vec<[FaceId; 2]>,
    lit_area: f64,
}

impl SceneFaces {
    fn new(scene: &Scene, geom: &SceneGeometry) -> Self {
        let lit: Vec<bool> = (0..geom.len()).map(|t| is_lit(geom, t)).collect();
        let count = (0..geom.len()).filter(|&t| lit[t]).map(|t| 1 + usize::from(double_sided(scene, geom, t))).sum();
        let mut faces = Vec::with_capacity(count);
        let mut face_of = vec![[NO_FACE; 2]; geom.len()];
        let mut lit_area = 0.0f64;
        for t in 0..geom.len() {
            if !lit[t] {
                continue;
            }
            let sides: &[Side] = if double_sided(scene, geom, t) { &Side::BOTH } else { &[Side::Front] };
            for &side in sides {
                face_of[t][side.index()] = faces.len() as FaceId;
                faces.push(AtlasFace { tri: t as TriangleId, side, chart: u32::MAX, uv: [Vec2::ZERO; 3] });
                lit_area += geom.areas[t] as f64;
            }
        }
        SceneFaces { faces, face_of, lit_area }
    }
}

/// The lit triangles (global ids, increasing) of mesh `mi`.
fn lit_triangles(face_of: &[[FaceId; 2]], geom: &SceneGeometry, mi: usize) -> Vec<TriangleId> {
    (geom.mesh_offsets[mi]..geom.mesh_offsets[mi + 1]).filter(|&t| face_of[t as usize][0] != NO_FACE).collect()
}

/// A lower bound of the LOD-0 texels [`Atlas::build`] would cover for `config`, from the lit
/// area alone (no charting or packing: milliseconds), as its own early refusal uses: a
/// chart's faces are within `chart_max_angle` of its seed's normal, so its UV area is at
/// least cos(angle) × its area. `None` without `--texel-size` (the budget bounds the texels,
/// and with them the atlas's cost).
pub fn min_texels(scene: &Scene, geom: &SceneGeometry, config: &AtlasConfig) -> Option<u64> {
    let t0 = config.texel_size? as f64;
    let lit_area: f64 = (0..geom.len())
        .filter(|&t| is_lit(geom, t))
        .map(|t| geom.areas[t] as f64 * (1.0 + f64::from(u8::from(double_sided(scene, geom, t)))))
        .sum();
    let cos = (charts::effective_max_angle(config.chart_max_angle) as f64).cos();
    let n = lit_area * cos / (t0 * t0);
    (n.is_finite() && t0 > 0.0).then_some(n.min(u64::MAX as f64 / 2.0) as u64)
}

/// Cheap lower bound before any work: a chart's faces are within `chart_max_angle` of its
/// seed's normal, so its UV area is at least cos(angle) × its area (and a TEXCOORD_1 block
/// has at least its area in texels).
fn check_lower_bound(lit_area: f64, texel: f64, config: &AtlasConfig) -> Result<(), AtlasError> {
    let cos = (charts::effective_max_angle(config.chart_max_angle) as f64).cos();
    let min_texels = lit_area * cos / (texel * texel);
    let max = config.max_size;
    if min_texels > max as f64 * max as f64 {
        let side = min_texels.sqrt().ceil().min(u32::MAX as f64) as u32;
        return Err(AtlasError::TooLarge { width: side, height: side, max });
    }
    Ok(())
}

fn double_sided(scene: &Scene, geom: &SceneGeometry, t: usize) -> bool {
    scene.materials.get(geom.material[t] as usize).is_some_and(|m| m.double_sided)
}

/// One chart in LOD-0 texels, ready to be packed: local UVs spanning `[0, extent]`, and how
/// it sits in its rectangle when not turned.
#[derive(Clone, Debug)]
struct TexelChart {
    mesh: u32,
    side: Side,
    source: ChartSource,
    tris: Vec<TriangleId>,
    uv: Vec<[DVec2; 3]>,
    extent: DVec2,
    placement: pack::Placement,
}

impl TexelChart {
    fn fixed(&self) -> bool {
        self.source == ChartSource::Uv1
    }

    /// Placement and local UVs in an orientation.
    fn oriented(&self, o: pack::Orient) -> (pack::Placement, impl Iterator<Item = [DVec2; 3]> + '_) {
        let p = self.placement.oriented(o, self.fixed());
        (p, self.uv.iter().map(move |t| t.map(|q| o.apply(q, self.extent))))
    }

    /// The pixels the chart claims in its rectangle, placed unturned ([`pack::Footprint`]): a
    /// TEXCOORD_1 block claims its whole rectangle.
    fn footprint(&self) -> pack::Footprint {
        let size = self.placement.rect_size();
        if self.fixed() {
            return pack::Footprint::full(size);
        }
        let offset = self.placement.offset;
        pack::Footprint::of_triangles(self.uv.iter().map(|t| t.map(|q| q + offset)), size)
    }
}

/// A mesh's charts before scaling: unwrapped (UVs in metres, any texel size) and, when its
/// TEXCOORD_1 is used, that layout (validated per texel size).
struct MeshCharts {
    mesh: u32,
    /// Whether the mesh's triangles have back faces (a double-sided material).
    back: bool,
    tris: Vec<TriangleId>,
    /// The unwrapped charts, made on first use; a rigid copy shares its original's.
    unwrapped: Arc<std::sync::OnceLock<Vec<charts::LocalChart>>>,
    /// Texel size the unwrapper was told to expect.
    hint: f64,
    try_uv1: bool,
    /// Set when the mesh is a rigid copy of an earlier one ([`copies::link_copies`]).
    copy_of: Option<CopyOf>,
}

/// Unwraps the meshes that are not given their TEXCOORD_1 ahead of their first use, on
/// `threads` threads: a mesh holding at least 1/`threads` of their faces on all threads
/// (through its components, [`charts::unwrap_mesh`]), one after another; the others side by
/// side, one thread each. (A mesh whose TEXCOORD_1 a texel size refuses is unwrapped on
/// first use, on one thread.) The charts do not depend on the threads.
fn unwrap_all(meshes: &[MeshCharts], scene: &Scene, geom: &SceneGeometry, config: &AtlasConfig, threads: usize) {
    let pending: Vec<&MeshCharts> = meshes.iter().filter(|m| !m.try_uv1).collect();
    let faces: usize = pending.iter().map(|m| m.tris.len()).sum();
    let (large, small): (Vec<&MeshCharts>, Vec<&MeshCharts>) =
        pending.into_iter().partition(|m| m.tris.len() * threads >= faces);
    for m in large {
        m.unwrapped(scene, geom, config, threads);
    }
    crate::parallel::par_for_each(small, threads, |m| {
        m.unwrapped(scene, geom, config, 1);
    });
    // The unwrappers' scratch was freed on their threads, into their own malloc arenas,
    // which keep it: given back, it does not add to the bake's peak.
    crate::parallel::give_back_free_heap();
}

/// A local chart's extent at `scale` (LOD-0 texels per unit of its UVs) and its placement.
fn placement(c: &charts::LocalChart, scale: f64, config: &AtlasConfig) -> Result<(DVec2, pack::Placement), AtlasError> {
    let extent = c.extent * scale;
    let p = match c.fixed_interior {
        Some(interior) => pack::place_fixed(interior),
        None => pack::place_free(extent).ok_or(AtlasError::TooLarge {
            width: u32::MAX,
            height: u32::MAX,
            max: config.max_size,
        })?,
    };
    Ok((extent, p))
}

/// A mesh's charts at one texel size.
struct MeshAtTexel {
    source: ChartSource,
    charts: Vec<TexelChart>,
    /// Why TEXCOORD_1 was refused at this texel size.
    uv1_rejected: Option<String>,
}

impl MeshCharts {
    /// Mesh `mi`'s charts, unwrapped for texels of about `hint`; `None` without lit triangles.
    fn new(
        scene: &Scene,
        geom: &SceneGeometry,
        face_of: &[[FaceId; 2]],
        mi: usize,
        hint: f64,
        config: &AtlasConfig,
    ) -> Option<MeshCharts> {
        let tris = lit_triangles(face_of, geom, mi);
        let first = *tris.first()?;
        Some(MeshCharts {
            mesh: mi as u32,
            back: double_sided(scene, geom, first as usize),
            tris,
            unwrapped: Arc::new(std::sync::OnceLock::new()),
            hint,
            try_uv1: config.use_uv1 && scene.meshes[mi].uv1.is_some(),
            copy_of: None,
        })
    }

    /// The unwrapped charts of the mesh (of its original, for a rigid copy: shared), made on
    /// `threads` threads on first use.
    fn unwrapped(
        &self,
        scene: &Scene,
        geom: &SceneGeometry,
        config: &AtlasConfig,
        threads: usize,
    ) -> &Vec<charts::LocalChart> {
        let (mesh, tris) = match &self.copy_of {
            None => (&scene.meshes[self.mesh as usize], &self.tris),
            Some(copy) => (&scene.meshes[copy.mesh as usize], &copy.tris),
        };
        self.unwrapped.get_or_init(|| charts::unwrap_mesh(mesh, geom, tris, self.hint, config.chart_max_angle, threads))
    }

    /// The mesh's local charts at `texel`: its TEXCOORD_1 blocks when they validate there
    /// (LOD-0 texels, scale 1), else its unwrapped charts (metres, scale 1/texel); and why
    /// TEXCOORD_1 was refused.
    fn local_at(
        &self,
        scene: &Scene,
        geom: &SceneGeometry,
        texel: f64,
        config: &AtlasConfig,
    ) -> (ChartSource, Cow<'_, [charts::LocalChart]>, f64, Option<String>) {
        let mesh = &scene.meshes[self.mesh as usize];
        let mut rejected = None;
        if self.try_uv1 {
            match uv1::validate(mesh, geom, &self.tris, texel, config.max_size) {
                Ok(block) => return (ChartSource::Uv1, Cow::Owned(block.charts(mesh, geom, &self.tris)), 1.0, None),
                Err(reason) => rejected = Some(reason),
            }
        }
        let unwrapped = self.unwrapped(scene, geom, config, 1);
        let Some(copy) = &self.copy_of else {
            return (ChartSource::Unwrapped, Cow::Borrowed(unwrapped.as_slice()), 1.0 / texel, rejected);
        };
        let moved = unwrapped
            .iter()
            .map(|c| charts::LocalChart {
                tris: c.tris.iter().map(|&t| (t as i64 + copy.offset) as TriangleId).collect(),
                uv: c.uv.iter().map(|t| t.map(|q| q * copy.scale)).collect(),
                extent: c.extent * copy.scale,
                fixed_interior: None,
            })
            .collect();
        (ChartSource::Unwrapped, Cow::Owned(moved), 1.0 / texel, rejected)
    }

    /// Charts [`Self::at`] makes at `texel` (both sides).
    fn chart_count(&self, scene: &Scene, geom: &SceneGeometry, texel: f64, config: &AtlasConfig) -> u64 {
        (self.local_at(scene, geom, texel, config).1.len() * self.sides().len()) as u64
    }

    fn sides(&self) -> &'static [Side] {
        if self.back { &Side::BOTH } else { &[Side::Front] }
    }

    /// The mesh's charts at `texel`, in LOD-0 texels, ready to pack.
    fn at(
        &self,
        scene: &Scene,
        geom: &SceneGeometry,
        texel: f64,
        config: &AtlasConfig,
    ) -> Result<MeshAtTexel, AtlasError> {
        let (source, local, scale, rejected) = self.local_at(scene, geom, texel, config);
        let mut out = Vec::with_capacity(local.len() * self.sides().len());
        for &side in self.sides() {
            for c in local.iter() {
                let (extent, placement) = placement(c, scale, config)?;
                out.push(TexelChart {
                    mesh: self.mesh,
                    side,
                    source,
                    tris: c.tris.clone(),
                    uv: c.uv.iter().map(|t| t.map(|q| q * scale)).collect(),
                    extent,
                    placement,
                });
            }
        }
        Ok(MeshAtTexel { source, charts: out, uv1_rejected: rejected })
    }

    /// LOD-0 texels the mesh's faces cover at `texel` (both sides): what [`Self::at`]'s
    /// charts cover, without making them.
    fn coverage_at(
        &self,
        scene: &Scene,
        geom: &SceneGeometry,
        texel: f64,
        config: &AtlasConfig,
    ) -> Result<u64, AtlasError> {
        let (_, local, scale, _) = self.local_at(scene, geom, texel, config);
        let mut mask = Vec::new();
        let mut total = 0;
        for c in local.iter() {
            let (_, p) = placement(c, scale, config)?;
            total += pack::coverage(c.uv.iter().map(|t| t.map(|q| q * scale + p.offset)), &p, &mut mask);
        }
        Ok(total * self.sides().len() as u64)
    }
}

/// Texels a chart is given at least: the budget is raised to this many a chart.
pub const MIN_TEXELS_PER_CHART: u64 = 4;

/// Most texel sizes tried to land the covered texels on the budget.
const BUDGET_STEPS: usize = 4;

/// Covered texels within this ratio of the budget end the search.
const BUDGET_TOLERANCE: f64 = 1.02;

/// The texel size whose covered texel count `count(t)` is closest to `budget` among at most
/// [`BUDGET_STEPS`] tries from `t0`: Newton steps on `ln count` against `ln t`, the slope
/// measured between the last two tries (−2 at first: count ∝ area / t²; kept within
/// [−3, −½], as conservative coverage of small faces makes it shallower).
fn solve_texel_size(
    budget: u64,
    t0: f64,
    mut count: impl FnMut(f64) -> Result<u64, AtlasError>,
) -> Result<f64, AtlasError> {
    let target = (budget as f64).ln();
    let mut tried: Vec<(f64, f64)> = Vec::new();
    let mut t = t0;
    let mut best = (f64::INFINITY, t0);
    for _ in 0..BUDGET_STEPS {
        let c = (count(t)?.max(1) as f64).ln();
        let miss = (c - target).abs();
        if miss < best.0 {
            best = (miss, t);
        }
        if miss < BUDGET_TOLERANCE.ln() {
            break;
        }
        let lt = t.ln();
        let slope = match tried.last() {
            Some(&(lt0, c0)) if (lt - lt0).abs() > 1e-9 => ((c - c0) / (lt - lt0)).clamp(-3.0, -0.5),
            _ => -2.0,
        };
        tried.push((lt, c));
        // Rounded to f32, as the atlas stores it: the layout is made at the stored size.
        t = (lt + (target - c) / slope).exp() as f32 as f64;
        if !(t.is_finite() && t > 0.0 && (t as f32) > 0.0) {
            break;
        }
    }
    Ok(best.1)
}

/// Lays chart `c` out as chart `id` with its rectangle's corner at `rect_min`, turned by `o`:
/// its faces' UVs and chart id, and the chart.
fn lay_out(
    faces: &mut [AtlasFace],
    face_of: &[[FaceId; 2]],
    id: u32,
    c: TexelChart,
    rect_min: (u32, u32),
    o: pack::Orient,
) -> Chart {
    let (p, uv) = c.oriented(o);
    let origin = DVec2::new(rect_min.0 as f64, rect_min.1 as f64) + p.offset;
    let mut ids = Vec::with_capacity(c.tris.len());
    for (t, uv) in c.tris.iter().zip(uv) {
        let f = face_of[*t as usize][c.side.index()];
        faces[f as usize].chart = id;
        faces[f as usize].uv = uv.map(|q| (q + origin).as_vec2());
        ids.push(f);
    }
    Chart { mesh: c.mesh, side: c.side, source: c.source, rect_min, rect_size: p.rect_size(), faces: ids }
}

impl Atlas {
    /// Unwraps (or takes TEXCOORD_1) and packs every lit face of `scene`.
    ///
    /// Without a texel size, the size is searched so that the faces cover
    /// `config.texel_budget` texels at LOD 0 as the texel map counts them (conservative
    /// coverage, each chart's partly covered border pixels and small faces' whole pixels
    /// included): charts are made once, at `√(lit area / budget)`, and scaled.
    pub fn build(scene: &Scene, geom: &SceneGeometry, config: &AtlasConfig) -> Result<Atlas, AtlasError> {
        let started = Instant::now();
        config.validate()?;
        let SceneFaces { mut faces, face_of, lit_area } = SceneFaces::new(scene, geom);
        if faces.is_empty() {
            return Err(AtlasError::Empty);
        }
        let t0 = match config.texel_size {
            Some(ts) => ts as f64,
            None => (lit_area / config.texel_budget as f64).sqrt() as f32 as f64,
        };
        if !(t0.is_finite() && t0 > 0.0 && (t0 as f32) > 0.0) {
            return Err(AtlasError::BadTexelSize(t0 as f32));
        }
        check_lower_bound(lit_area, t0, config)?;

        let mut meshes: Vec<MeshCharts> =
            (0..scene.meshes.len()).filter_map(|mi| MeshCharts::new(scene, geom, &face_of, mi, t0, config)).collect();
        link_copies(scene, geom, &mut meshes);
        let threads = crate::parallel::available_threads();
        unwrap_all(&meshes, scene, geom, config, threads);
        let layout = |texel: f64| -> Result<Vec<MeshAtTexel>, AtlasError> {
            crate::parallel::par_map(meshes.iter().collect(), threads, |m| m.at(scene, geom, texel, config))
                .into_iter()
                .collect()
        };
        // A chart covers at least one texel however large the texels: below a few texels a
        // chart, a budget only makes the texels huge (every chart one texel of 13 m on 90
        // instanced rooms at 40 000 texels) without covering fewer, so it is raised.
        let charts_at_t0: u64 = meshes.iter().map(|m| m.chart_count(scene, geom, t0, config)).sum();
        let floor = MIN_TEXELS_PER_CHART * charts_at_t0;
        let budget = if config.texel_size.is_none() && floor > config.texel_budget {
            let most = config.max_size as u64 * config.max_size as u64;
            let raised = floor.min(most);
            tracing::warn!(
                "--texel-budget {} is below {MIN_TEXELS_PER_CHART} texels for each of the scene's {charts_at_t0} \
                 charts: using {raised}",
                config.texel_budget
            );
            raised
        } else {
            config.texel_budget
        };
        let texel = match config.texel_size {
            Some(_) => t0,
            None => solve_texel_size(budget, t0, |t| {
                crate::parallel::par_map(meshes.iter().collect(), threads, |m| m.coverage_at(scene, geom, t, config))
                    .into_iter()
                    .sum()
            })?,
        };
        let laid = layout(texel)?;
        let budget_used = config.texel_size.is_none().then_some(budget);
        let mut stats = AtlasStats { faces: faces.len(), lit_area, budget_used, ..AtlasStats::default() };
        let mut charts = Vec::new();
        for m in laid {
            match m.source {
                ChartSource::Uv1 => stats.meshes_from_uv1 += 1,
                ChartSource::Unwrapped => stats.meshes_unwrapped += 1,
            }
            if let Some(reason) = m.uv1_rejected {
                let name = &scene.meshes[m.charts[0].mesh as usize].name;
                tracing::warn!(mesh = %name, "TEXCOORD_1 not used as light-map UVs: {reason}; unwrapping instead");
                stats.uv1_rejected.push((name.clone(), reason));
            }
            charts.extend(m.charts);
        }
        stats.unwrap_seconds = started.elapsed().as_secs_f64();

        let packing_started = Instant::now();
        let footprints: Vec<pack::Footprint> = crate::parallel::par_map(charts.chunks(1024).collect(), threads, |cs| {
            cs.iter().map(TexelChart::footprint).collect::<Vec<_>>()
        })
        .into_iter()
        .flatten()
        .collect();
        let max = config.max_size;
        let packing =
            pack::pack(&footprints, max).map_err(|(width, height)| AtlasError::TooLarge { width, height, max })?;
        let charts: Vec<Chart> = charts
            .into_iter()
            .zip(packing.positions.iter().zip(&packing.orient))
            .enumerate()
            .map(|(id, (c, (&p, &o)))| lay_out(&mut faces, &face_of, id as u32, c, p, o))
            .collect();
        stats.charts = charts.len();
        stats.pack_seconds = packing_started.elapsed().as_secs_f64();

        let mut atlas = Atlas {
            texel_size: texel as f32,
            width: packing.width,
            height: packing.height,
            faces,
            face_of,
            charts,
            mesh_offsets: geom.mesh_offsets.clone(),
            stats,
        };
        atlas.finish_stats();
        Ok(atlas)
    }

    /// Covered texels and fill ratio from the laid-out faces.
    fn finish_stats(&mut self) {
        self.stats.covered_texels_lod0 = self.covered_texels(0);
        let area = self.width as f64 * self.height as f64;
        self.stats.fill_ratio = if area > 0.0 { self.stats.covered_texels_lod0 as f64 / area } else { 0.0 };
        tracing::debug!(
            charts = self.stats.charts,
            faces = self.stats.faces,
            width = self.width,
            height = self.height,
            texel_size = self.texel_size,
            covered = self.stats.covered_texels_lod0,
            fill = self.stats.fill_ratio,
            "light-map atlas built"
        );
    }

    /// Pixels covered (conservatively) by some face at LOD `lod`: the number of texels of
    /// [`TexelMap::build`] at that LOD.
    pub fn covered_texels(&self, lod: u32) -> u64 {
        let chunks: Vec<&[Chart]> = self.charts.chunks(256).collect();
        let counts = crate::parallel::par_map(chunks, crate::parallel::available_threads(), |charts| {
            let mut total = 0u64;
            let mut mask = Vec::new();
            for chart in charts {
                let b = chart.interior(lod);
                mask.clear();
                mask.resize((b.width() * b.height()) as usize, false);
                for &f in &chart.faces {
                    let t = self.faces[f as usize].uv_lod(lod);
                    raster::conservative(&t, b, (i64::MIN, i64::MAX), |x, y| {
                        mask[((y - b.y0) * b.width() + (x - b.x0)) as usize] = true;
                    });
                }
                total += mask.iter().filter(|&&m| m).count() as u64;
            }
            total
        });
        counts.into_iter().sum()
    }

    /// Texel density of a face at LOD `lod`: LOD-`lod` texels per m² of its surface (UV area
    /// in LOD-`lod` texels over world area). What the ray-bundle baker's importance uses.
    pub fn texel_density(&self, geom: &SceneGeometry, face: FaceId, lod: u32) -> f32 {
        let f = &self.faces[face as usize];
        let uv = f.uv_lod(lod);
        let uv_area = 0.5 * raster::area2(&uv).abs();
        let area = geom.areas[f.tri as usize] as f64;
        if area > 0.0 { (uv_area / area) as f32 } else { 0.0 }
    }

    /// [`Atlas::texel_density`] per triangle (the larger of its faces'; 0 for a triangle
    /// without faces), for a per-triangle importance buffer.
    pub fn triangle_texel_densities(&self, geom: &SceneGeometry, lod: u32) -> Vec<f32> {
        self.face_of
            .iter()
            .map(|fs| {
                fs.iter().filter(|&&f| f != NO_FACE).map(|&f| self.texel_density(geom, f, lod)).fold(0.0, f32::max)
            })
            .collect()
    }

    pub fn face(&self, tri: TriangleId, side: Side) -> Option<FaceId> {
        let f = self.face_of[tri as usize][side.index()];
        (f != NO_FACE).then_some(f)
    }

    pub fn lods(&self, levels: u32) -> LodHierarchy {
        LodHierarchy::new(self.width, self.height, levels)
    }
}
