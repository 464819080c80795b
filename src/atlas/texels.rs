//! Inverse mapping (2017 thesis, 3.2.3): for every texel of a LOD, the surface point it stands
//! for.

use glam::{Vec2, Vec3};

use super::{Atlas, FaceId};
use crate::scene::{Rgb, Scene, SceneGeometry};

/// Marks an atlas pixel that holds no texel (not covered by any face, or gutter).
pub const NO_TEXEL: u32 = u32::MAX;

/// Every valid texel of one LOD, stored compactly (covered texels only, in row-major pixel
/// order), plus the pixel → texel lookup and the gutter pixels that copy a texel.
#[derive(Clone, Debug, Default)]
pub struct TexelMap {
    pub lod: u32,
    pub width: u32,
    pub height: u32,
    /// Per atlas pixel (row-major): index of its texel, or [`NO_TEXEL`].
    pub slot: Vec<u32>,
    /// Per texel: its pixel index (`y · width + x`).
    pub pixel: Vec<u32>,
    /// Per texel: the face whose surface point it holds.
    pub face: Vec<FaceId>,
    /// Per texel: world position on the face (the texel centre mapped to the face, clamped
    /// onto it when the centre lies outside: conservative coverage keeps thin triangles).
    pub position: Vec<Vec3>,
    /// Per texel: unit geometric normal of the face's side.
    pub normal: Vec<Vec3>,
    /// Per texel: diffuse albedo (material factor × base-colour texture at the point).
    pub albedo: Vec<Rgb>,
    /// Per texel: emitted radiance of that side, W/(sr·m²) (zero when that side emits nothing).
    pub emission: Vec<Rgb>,
    /// Per texel: world area (m²) of the surface that maps into the texel's square.
    pub area: Vec<f32>,
    /// Gutter pixels (empty pixels next to a chart) and the texel each copies, so bilinear
    /// sampling near a chart edge never reads an empty or foreign texel.
    pub gutter: Vec<(u32, u32)>,
}

impl TexelMap {
    pub fn build(scene: &Scene, geom: &SceneGeometry, atlas: &Atlas, lod: u32) -> TexelMap {
        let _ = (scene, geom, atlas, lod);
        todo!("texel map")
    }

    pub fn len(&self) -> usize {
        self.pixel.len()
    }

    pub fn is_empty(&self) -> bool {
        self.pixel.is_empty()
    }

    /// The texel at a LOD-`self.lod` pixel coordinate, if any.
    pub fn texel_at_pixel(&self, x: u32, y: u32) -> Option<u32> {
        if x >= self.width || y >= self.height {
            return None;
        }
        let t = self.slot[(y * self.width + x) as usize];
        (t != NO_TEXEL).then_some(t)
    }

    /// The texel under an atlas UV given in LOD-0 texel units.
    pub fn texel_at_uv(&self, uv_lod0: Vec2) -> Option<u32> {
        let p = uv_lod0 * (1u32 << self.lod) as f32;
        if p.x < 0.0 || p.y < 0.0 {
            return None;
        }
        self.texel_at_pixel(p.x as u32, p.y as u32)
    }

    /// Spreads per-texel `values` into a full row-major image, gutters filled from their
    /// source texel and other pixels set to `empty`.
    pub fn to_image<T: Copy>(&self, values: &[T], empty: T) -> Vec<T> {
        let mut img = vec![empty; (self.width * self.height) as usize];
        for (t, &p) in self.pixel.iter().enumerate() {
            img[p as usize] = values[t];
        }
        for &(p, t) in &self.gutter {
            img[p as usize] = values[t as usize];
        }
        img
    }
}
