//! Per-bake triangle data the CPU bundle passes read for every direction: corners, face
//! UVs at the LOD being baked, importance, emitter group.

use glam::{Vec2, Vec3};

use super::spheres::SphereTree;
use crate::atlas::texels::NO_TEXEL;
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
    pub texel_lookup: BlockedTable,
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
            let sides =
                Side::BOTH.map(|s| atlas.face(t as u32, s).map(|f| atlas.faces[f as usize].uv.map(|uv| uv * scale)));
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
        let mut texel_lookup = BlockedTable::new(texels.width, texels.height, NO_TEXEL);
        for (&pixel, texel) in texels.pixel.iter().zip(0..).chain(texels.gutter.iter().map(|(p, t)| (p, *t))) {
            texel_lookup.set(pixel % texels.width, pixel / texels.width, texel);
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

/// A per-pixel table over the atlas stored in 8×8-pixel blocks (row-major blocks, row-major
/// pixels inside): a bundle span walks a line across the atlas in any direction, and
/// blocks keep the entries it reads next to each other far more often than rows do.
#[derive(Clone, Debug, Default)]
pub struct BlockedTable {
    entries: Vec<u32>,
    blocks_x: u32,
}

impl BlockedTable {
    const SHIFT: u32 = 3;
    const MASK: u32 = (1 << Self::SHIFT) - 1;

    fn new(width: u32, height: u32, fill: u32) -> Self {
        let blocks_x = width.div_ceil(1 << Self::SHIFT);
        let blocks_y = height.div_ceil(1 << Self::SHIFT);
        let len = blocks_x as usize * blocks_y as usize * (1 << (2 * Self::SHIFT));
        BlockedTable { entries: vec![fill; len], blocks_x }
    }

    #[inline(always)]
    fn index(&self, x: u32, y: u32) -> usize {
        let block = (y >> Self::SHIFT) as usize * self.blocks_x as usize + (x >> Self::SHIFT) as usize;
        block << (2 * Self::SHIFT) | ((y & Self::MASK) << Self::SHIFT | (x & Self::MASK)) as usize
    }

    fn set(&mut self, x: u32, y: u32, value: u32) {
        let i = self.index(x, y);
        self.entries[i] = value;
    }

    /// The entry of pixel (x, y), which must lie inside the table's width × height.
    #[inline(always)]
    pub fn get(&self, x: u32, y: u32) -> u32 {
        self.entries[self.index(x, y)]
    }
}

#[cfg(test)]
mod tests {
    use super::BlockedTable;

    #[test]
    fn blocked_table_keeps_every_pixel_apart() {
        // Sizes that are not whole blocks, so the ragged last block row and column count.
        let (w, h) = (13, 10);
        let mut t = BlockedTable::new(w, h, u32::MAX);
        for y in 0..h {
            for x in 0..w {
                t.set(x, y, y * w + x);
            }
        }
        for y in 0..h {
            for x in 0..w {
                assert_eq!(t.get(x, y), y * w + x);
            }
        }
        assert_eq!(t.entries.iter().filter(|&&e| e != u32::MAX).count(), (w * h) as usize);
    }
}
