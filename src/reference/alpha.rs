//! Triangles that let light through: alpha-masked ones (`AlphaMode::Mask`), cut out where
//! their alpha is below the cutoff, and see-through ones (`Blend` or
//! `KHR_materials_transmission`, [`Material::is_see_through`]), which pass a fraction of
//! the light meeting them ([`Sheet`]).
//!
//! The BVH owns this (no borrow of the [`Scene`]). Masked materials that are not see-through
//! are cloned with their base-colour texture replaced by an alpha-only copy, so the cut-out
//! test is exactly [`Material::alpha`] at the hit's texture coordinate and vertex colour;
//! see-through materials keep their textures (shared pixels, no copy), since their sheet
//! needs the albedo too. Opaque triangles have no entry and never reach this code (the BVH
//! flags leaves that contain entries).

use glam::{Vec2, Vec4};

use crate::scene::geometry::at_barycentrics;
use crate::scene::{AlphaMode, Material, MaterialPoint, Scene, SceneGeometry, Sheet, Texture, TriangleId};

const NONE: u32 = u32::MAX;

#[derive(Clone, Debug)]
struct MaskedTriangle {
    uv0: [Vec2; 3],
    /// Its corners' vertex colours (COLOR_0 scales alpha and tint), when its mesh has them.
    colors: Option<[Vec4; 3]>,
    material: u32,
}

impl MaskedTriangle {
    /// Where its material is read at barycentrics (u, v), interpolated as
    /// [`SceneGeometry::material_point`] does.
    #[inline]
    fn point(&self, u: f32, v: f32) -> MaterialPoint {
        let color = self.colors.map(|c| at_barycentrics(c, u, v));
        MaterialPoint { uv: at_barycentrics(self.uv0, u, v), color }
    }
}

#[derive(Clone, Debug)]
struct MaskMaterial {
    material: Material,
    /// The alpha cutoff of a masked material.
    cutoff: Option<f32>,
    see_through: bool,
}

/// Cut-out data for the masked triangles of a scene.
#[derive(Clone, Debug, Default)]
pub struct AlphaMasks {
    /// Per [`TriangleId`]: index into `triangles`, or `NONE`. Empty when nothing is masked.
    slot: Vec<u32>,
    triangles: Vec<MaskedTriangle>,
    materials: Vec<MaskMaterial>,
    textures: Vec<Texture>,
    see_through: bool,
}

/// The alpha channel of `t` only (RGB set to white): enough for [`Material::alpha`].
fn alpha_only(t: &Texture) -> Texture {
    Texture { rgba8: t.rgba8.iter().map(|&[_, _, _, a]| [255, 255, 255, a]).collect(), srgb: false, ..t.clone() }
}

impl AlphaMasks {
    /// Bytes of the alpha-only textures [`AlphaMasks::new`] makes of `scene`: one copy of
    /// each texture a masked material reads its alpha from.
    pub fn texture_bytes(scene: &Scene) -> u64 {
        let mut textures: Vec<usize> = scene
            .materials
            .iter()
            .filter(|m| matches!(m.alpha_mode, AlphaMode::Mask { .. }) && !m.is_see_through())
            .filter_map(|m| m.base_color_texture.map(|t| t.texture))
            .collect();
        textures.sort_unstable();
        textures.dedup();
        textures.iter().filter_map(|&t| scene.textures.get(t)).map(|t| t.rgba8.len() as u64 * 4).sum()
    }

    /// Collects the masked and see-through triangles of `scene` (as laid out by `geom`).
    pub fn new(scene: &Scene, geom: &SceneGeometry) -> AlphaMasks {
        let mut out = AlphaMasks::default();
        let mut local_material = vec![NONE; scene.materials.len()];
        // One copy per texture (alpha-only or whole), however many materials use it.
        let mut local_texture = std::collections::HashMap::new();
        for (mi, m) in scene.materials.iter().enumerate() {
            let cutoff = match m.alpha_mode {
                AlphaMode::Mask { cutoff } => Some(cutoff),
                _ => None,
            };
            let see_through = m.is_see_through();
            if cutoff.is_none() && !see_through {
                continue;
            }
            let mut material = m.clone();
            material.emissive_texture = None;
            for t in
                [material.base_color_texture.as_mut(), material.transmission_texture.as_mut()].into_iter().flatten()
            {
                t.texture = *local_texture.entry((t.texture, see_through)).or_insert_with(|| {
                    let source = &scene.textures[t.texture];
                    out.textures.push(if see_through { source.clone() } else { alpha_only(source) });
                    out.textures.len() - 1
                });
            }
            out.see_through |= see_through;
            local_material[mi] = out.materials.len() as u32;
            out.materials.push(MaskMaterial { material, cutoff, see_through });
        }
        if out.materials.is_empty() {
            return out;
        }
        out.slot = vec![NONE; geom.len()];
        for t in 0..geom.len() {
            let lm = local_material[geom.material[t] as usize];
            if lm == NONE {
                continue;
            }
            let uv0 = geom.texture_uv_corners(scene, t);
            out.slot[t] = out.triangles.len() as u32;
            out.triangles.push(MaskedTriangle { uv0, colors: geom.color_corners(scene, t), material: lm });
        }
        out
    }

    /// Whether no triangle is masked or see-through.
    pub fn is_empty(&self) -> bool {
        self.triangles.is_empty()
    }

    /// Whether some triangle is see-through.
    #[inline]
    pub fn has_see_through(&self) -> bool {
        self.see_through
    }

    /// Whether triangle `tri` has an alpha-masked or see-through material.
    #[inline]
    pub fn is_masked(&self, tri: TriangleId) -> bool {
        self.slot.get(tri as usize).is_some_and(|&s| s != NONE)
    }

    /// The [`Sheet`] of a see-through triangle at barycentrics (u, v), `None` for the others
    /// (where they exist, they stop all light).
    #[inline]
    pub fn sheet_at(&self, tri: TriangleId, u: f32, v: f32) -> Option<Sheet> {
        let &s = self.slot.get(tri as usize)?;
        if s == NONE {
            return None;
        }
        let mt = &self.triangles[s as usize];
        let mm = &self.materials[mt.material as usize];
        if !mm.see_through {
            return None;
        }
        Some(mm.material.sheet(&self.textures, mt.point(u, v)))
    }

    /// Whether the surface exists at barycentrics (u, v) of `tri`: true for unmasked
    /// triangles, otherwise `alpha ≥ cutoff` (glTF: below the cutoff it is fully transparent).
    #[inline]
    pub fn opaque_at(&self, tri: TriangleId, u: f32, v: f32) -> bool {
        let Some(&s) = self.slot.get(tri as usize) else { return true };
        if s == NONE {
            return true;
        }
        let mt = &self.triangles[s as usize];
        let mm = &self.materials[mt.material as usize];
        let Some(cutoff) = mm.cutoff else { return true };
        mm.material.alpha(&self.textures, mt.point(u, v)) >= cutoff
    }
}
