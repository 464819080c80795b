//! Alpha-masked triangles (`AlphaMode::Mask`): what the BVH needs to cut them out.
//!
//! The BVH owns this (no borrow of the [`Scene`]): the masked materials are cloned with
//! their base-colour texture replaced by an alpha-only copy, so the cut-out test is exactly
//! [`Material::alpha`] at the hit's TEXCOORD_0. Opaque and blended triangles have no entry
//! and never reach this code (the BVH flags leaves that contain masked triangles).

use glam::Vec2;

use crate::scene::{AlphaMode, Material, Scene, SceneGeometry, Texture, TriangleId};

const NONE: u32 = u32::MAX;

#[derive(Clone, Debug)]
struct MaskedTriangle {
    uv0: [Vec2; 3],
    material: u32,
}

#[derive(Clone, Debug)]
struct MaskMaterial {
    material: Material,
    cutoff: f32,
}

/// Cut-out data for the masked triangles of a scene.
#[derive(Clone, Debug, Default)]
pub struct AlphaMasks {
    /// Per [`TriangleId`]: index into `triangles`, or `NONE`. Empty when nothing is masked.
    slot: Vec<u32>,
    triangles: Vec<MaskedTriangle>,
    materials: Vec<MaskMaterial>,
    textures: Vec<Texture>,
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
            .filter(|m| matches!(m.alpha_mode, AlphaMode::Mask { .. }))
            .filter_map(|m| m.base_color_texture.map(|t| t.texture))
            .collect();
        textures.sort_unstable();
        textures.dedup();
        textures.iter().filter_map(|&t| scene.textures.get(t)).map(|t| t.rgba8.len() as u64 * 4).sum()
    }

    /// Collects the masked triangles of `scene` (as laid out by `geom`).
    pub fn new(scene: &Scene, geom: &SceneGeometry) -> AlphaMasks {
        let mut out = AlphaMasks::default();
        let mut local_material = vec![NONE; scene.materials.len()];
        // One alpha-only copy per texture, however many masked materials use it.
        let mut local_texture = std::collections::HashMap::new();
        for (mi, m) in scene.materials.iter().enumerate() {
            let AlphaMode::Mask { cutoff } = m.alpha_mode else { continue };
            let mut material = m.clone();
            material.emissive_texture = None;
            if let Some(t) = material.base_color_texture.as_mut() {
                t.texture = *local_texture.entry(t.texture).or_insert_with(|| {
                    out.textures.push(alpha_only(&scene.textures[t.texture]));
                    out.textures.len() - 1
                });
            }
            local_material[mi] = out.materials.len() as u32;
            out.materials.push(MaskMaterial { material, cutoff });
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
            let mesh = &scene.meshes[geom.mesh[t] as usize];
            let uv0 = mesh.uv0_corners(geom.local[t] as usize);
            out.slot[t] = out.triangles.len() as u32;
            out.triangles.push(MaskedTriangle { uv0, material: lm });
        }
        out
    }

    /// Whether any triangle is masked.
    pub fn is_empty(&self) -> bool {
        self.triangles.is_empty()
    }

    /// Whether triangle `tri` has an alpha-masked material.
    #[inline]
    pub fn is_masked(&self, tri: TriangleId) -> bool {
        self.slot.get(tri as usize).is_some_and(|&s| s != NONE)
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
        let [a, b, c] = mt.uv0;
        let uv = a + (b - a) * u + (c - a) * v;
        let mm = &self.materials[mt.material as usize];
        mm.material.alpha(&self.textures, uv) >= mm.cutoff
    }
}
