//! Per-bake triangle data the CPU bundle passes read for every direction: corners, face
//! UVs at the LOD being baked, importance, emitter group.

use glam::{Vec2, Vec3};

use super::spheres::SphereTree;
use crate::atlas::{Atlas, TexelMap};
use crate::scene::{SceneGeometry, Side};

/// Marks a triangle that belongs to no light-pass emitter group.
pub const NO_GROUP: u32 = u32::MAX;

/// What the bundle rasteriser needs per triangle, flattened for cache-friendly loops.
pub struct PreparedScene<'a> {
    pub geom: &'a SceneGeometry,
    pub texels: &'a TexelMap,
    /// Per triangle, per side: UV corners in pixels of the LOD being baked, when that side is
    /// a lit face.
    pub face_uv: Vec<[Option<[Vec2; 3]>; 2]>,
    /// Per triangle: light-map texels per m² at the LOD being baked (the larger of its two
    /// faces): the importance of Sect. 3, in rays per m² of bundle.
    pub importance: Vec<f32>,
    /// Per triangle: the light-pass emitter group it belongs to, or [`NO_GROUP`].
    pub emitter_group: Vec<u32>,
    /// Per atlas pixel: its texel, or for a gutter pixel the texel it copies (its chart's
    /// nearest), else `NO_TEXEL`. A fragment whose UV rounds a hair outside its chart's
    /// covered pixels lands in the gutter ring and still finds its own chart's texel.
    pub texel_lookup: Vec<u32>,
    /// Bounding spheres of the triangles, for culling against bundle windows along any
    /// direction.
    pub spheres: SphereTree,
    /// Centre and radius of the scene's bounding sphere.
    pub centre: Vec3,
    pub radius: f32,
    /// Depth difference (m) below which two fragments count as coincident surfaces: far
    /// below any real wall thickness, above f32 rounding of depths at this scene's scale
    /// (~10⁻⁷ relative). Kept small because it also catches lines grazing a convex edge,
    /// where the tie-break (leak-safe: back sides face each other) costs that line's sample.
    pub coincident_depth: f32,
}

impl<'a> PreparedScene<'a> {
    pub fn new(geom: &'a SceneGeometry, atlas: &Atlas, texels: &'a TexelMap, emitter_group: Vec<u32>) -> Self {
        let scale = (1u32 << texels.lod) as f32;
        let mut face_uv = Vec::with_capacity(geom.len());
        let mut importance = Vec::with_capacity(geom.len());
        for t in 0..geom.len() {
            let sides = Side::BOTH.map(|s| atlas.face(t as u32, s).map(|f| atlas.faces[f as usize].uv.map(|uv| uv * scale)));
            let density = sides
                .iter()
                .flatten()
                .map(|uv| {
                    let uv_area = 0.5 * (uv[1] - uv[0]).perp_dot(uv[2] - uv[0]).abs();
                    uv_area / geom.areas[t].max(f32::MIN_POSITIVE)
                })
                .fold(0.0f32, f32::max);
            face_uv.push(sides);
            importance.push(density);
        }
        let (lo, hi) = geom
            .corners
            .iter()
            .flatten()
            .fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
        let centre = (lo + hi) * 0.5;
        let radius = geom.corners.iter().flatten().map(|p| (*p - centre).length()).fold(0.0f32, f32::max).max(1e-6);
        let spheres = geom
            .corners
            .iter()
            .map(|c| {
                let m = (c[0].min(c[1]).min(c[2]) + c[0].max(c[1]).max(c[2])) * 0.5;
                (m, c.iter().map(|p| (*p - m).length()).fold(0.0f32, f32::max))
            })
            .collect();
        let spheres = SphereTree::new(spheres);
        let coincident_depth = 1e-6 * (radius + centre.abs().max_element());
        let mut texel_lookup = texels.slot.clone();
        for &(pixel, texel) in &texels.gutter {
            texel_lookup[pixel as usize] = texel;
        }
        PreparedScene {
            geom,
            texels,
            face_uv,
            importance,
            emitter_group,
            texel_lookup,
            spheres,
            centre,
            radius,
            coincident_depth,
        }
    }
}
