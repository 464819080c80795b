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
//! atlas's top-left corner). LOD k coordinates are `uv · 2^k`; normalised UVs in \[0, 1\] are
//! `uv / (width, height)`.
//!
//! Pieces: [`charts`] (planar unwrapper), [`uv1`] (TEXCOORD_1 validation), [`pack`] (chart
//! rectangles and skyline packing), [`raster`] (the conservative coverage rule every part
//! shares: what a face touches at LOD k is what the packer reserved room for, what the
//! TEXCOORD_1 check tested and what the texel map rasterises), [`texels`] (inverse mapping).

pub mod charts;
pub mod lookup;
pub mod pack;
pub mod raster;
pub mod sparse;
pub mod texels;
pub mod uv1;

#[cfg(test)]
mod tests;

use std::time::Instant;

use glam::{DVec2, Vec2};
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
        let [a, b, c] = self.uv;
        a + (b - a) * u + (c - a) * v
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

    /// The chart's whole rectangle in LOD-`lod` pixels.
    pub fn rect(&self, lod: u32) -> raster::PixelRect {
        let s = 1i64 << lod;
        let (x, y) = (self.rect_min.0 as i64, self.rect_min.1 as i64);
        let (w, h) = (self.rect_size.0 as i64, self.rect_size.1 as i64);
        raster::PixelRect::new(x * s, y * s, (x + w) * s, (y + h) * s)
    }
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
        let started = Instant::now();
        if let Some(ts) = config.texel_size {
            if !(ts.is_finite() && ts > 0.0) {
                return Err(AtlasError::BadTexelSize(ts));
            }
        }
        let double_sided = |t: usize| scene.materials.get(geom.material[t] as usize).is_some_and(|m| m.double_sided);

        // Faces: a front face for every non-degenerate triangle, a back face when its
        // material is double-sided.
        let lit: Vec<bool> = (0..geom.len()).map(|t| is_lit(geom, t)).collect();
        let count = (0..geom.len()).filter(|&t| lit[t]).map(|t| 1 + usize::from(double_sided(t))).sum();
        let mut faces = Vec::with_capacity(count);
        let mut face_of = vec![[NO_FACE; 2]; geom.len()];
        let mut lit_area = 0.0f64;
        for t in 0..geom.len() {
            if !lit[t] {
                continue;
            }
            let sides: &[Side] = if double_sided(t) { &Side::BOTH } else { &[Side::Front] };
            for &side in sides {
                face_of[t][side.index()] = faces.len() as FaceId;
                faces.push(AtlasFace { tri: t as TriangleId, side, chart: u32::MAX, uv: [Vec2::ZERO; 3] });
                lit_area += geom.areas[t] as f64;
            }
        }
        if faces.is_empty() {
            return Err(AtlasError::Empty);
        }
        let texel = match config.texel_size {
            Some(ts) => ts as f64,
            None => (lit_area / config.texel_budget as f64).sqrt() as f32 as f64,
        };
        if !(texel.is_finite() && texel > 0.0 && (texel as f32) > 0.0) {
            return Err(AtlasError::BadTexelSize(texel as f32));
        }
        // Cheap lower bound before any work: a chart's faces are within `chart_max_angle` of
        // its seed's normal, so its UV area is at least cos(angle) × its area (and a
        // TEXCOORD_1 block has at least its area in texels).
        let cos = (charts::effective_max_angle(config.chart_max_angle) as f64).cos();
        let min_texels = lit_area * cos / (texel * texel);
        let max = config.max_size;
        if min_texels > max as f64 * max as f64 {
            let side = min_texels.sqrt().ceil().min(u32::MAX as f64) as u32;
            return Err(AtlasError::TooLarge { width: side, height: side, max });
        }

        // Charts, mesh by mesh; a double-sided mesh's back faces get a copy of its layout.
        let mut stats = AtlasStats { faces: faces.len(), lit_area, ..AtlasStats::default() };
        let mut layouts: Vec<(u32, Side, ChartSource, charts::LocalChart)> = Vec::new();
        for (mi, mesh) in scene.meshes.iter().enumerate() {
            let range = geom.mesh_offsets[mi]..geom.mesh_offsets[mi + 1];
            let tris: Vec<TriangleId> = range.filter(|&t| face_of[t as usize][0] != NO_FACE).collect();
            if tris.is_empty() {
                continue;
            }
            let mut local = None;
            if config.use_uv1 && mesh.uv1.is_some() {
                match uv1::validate(mesh, geom, &tris, texel, max) {
                    Ok(block) => {
                        stats.meshes_from_uv1 += 1;
                        local = Some((ChartSource::Uv1, block.charts(mesh, geom, &tris)));
                    }
                    Err(reason) => {
                        tracing::warn!(mesh = %mesh.name, "TEXCOORD_1 not used as light-map UVs: {reason}; unwrapping instead");
                        stats.uv1_rejected.push((mesh.name.clone(), reason));
                    }
                }
            }
            let (source, local) = local.unwrap_or_else(|| {
                stats.meshes_unwrapped += 1;
                (ChartSource::Unwrapped, charts::unwrap_mesh(mesh, geom, &tris, texel, config.chart_max_angle))
            });
            let backs = if double_sided(tris[0] as usize) { local.clone() } else { Vec::new() };
            layouts.extend(local.into_iter().map(|c| (mi as u32, Side::Front, source, c)));
            layouts.extend(backs.into_iter().map(|c| (mi as u32, Side::Back, source, c)));
        }
        stats.unwrap_seconds = started.elapsed().as_secs_f64();

        // Pack.
        let packing_started = Instant::now();
        let mut placements = Vec::with_capacity(layouts.len());
        for (_, _, _, c) in &layouts {
            let p = match c.fixed_interior {
                Some(interior) => pack::place_fixed(interior),
                None => {
                    pack::place_free(c.extent).ok_or(AtlasError::TooLarge { width: u32::MAX, height: u32::MAX, max })?
                }
            };
            placements.push(p);
        }
        let sizes: Vec<(u32, u32)> = placements.iter().map(|p| p.rect_size()).collect();
        let packing = pack::pack(&sizes, max).map_err(|(width, height)| AtlasError::TooLarge { width, height, max })?;
        let mut chart_list = Vec::with_capacity(layouts.len());
        for (ci, ((mesh, side, source, c), p)) in layouts.into_iter().zip(&placements).enumerate() {
            let rect_min = packing.positions[ci];
            let origin = DVec2::new(rect_min.0 as f64, rect_min.1 as f64) + p.offset;
            let mut ids = Vec::with_capacity(c.tris.len());
            for (t, uv) in c.tris.iter().zip(&c.uv) {
                let f = face_of[*t as usize][side.index()];
                faces[f as usize].chart = ci as u32;
                faces[f as usize].uv = uv.map(|q| (q + origin).as_vec2());
                ids.push(f);
            }
            chart_list.push(Chart { mesh, side, source, rect_min, rect_size: p.rect_size(), faces: ids });
        }
        stats.charts = chart_list.len();
        stats.pack_seconds = packing_started.elapsed().as_secs_f64();

        let mut atlas = Atlas {
            texel_size: texel as f32,
            width: packing.width,
            height: packing.height,
            faces,
            face_of,
            charts: chart_list,
            stats,
        };
        atlas.stats.covered_texels_lod0 = atlas.covered_texels(0);
        let area = atlas.width as f64 * atlas.height as f64;
        atlas.stats.fill_ratio = if area > 0.0 { atlas.stats.covered_texels_lod0 as f64 / area } else { 0.0 };
        tracing::debug!(
            charts = atlas.stats.charts,
            faces = atlas.stats.faces,
            width = atlas.width,
            height = atlas.height,
            fill = atlas.stats.fill_ratio,
            "light-map atlas built"
        );
        Ok(atlas)
    }

    /// Pixels covered (conservatively) by some face at LOD `lod`: the number of texels of
    /// [`TexelMap::build`] at that LOD.
    pub fn covered_texels(&self, lod: u32) -> u64 {
        let mut total = 0u64;
        let mut mask = Vec::new();
        for chart in &self.charts {
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
