//! The shown map's punctual layer for one cell: its texels at a LOD and their direct light
//! from the scene's punctual lights over each texel's visible part
//! ([`punctual_irradiance_of_texels`]). There is nothing to converge, so the layer is baked straight
//! at the LOD the cell wants, ahead of the bundle layer (whose light, the sky and every
//! bounce, varies more slowly and is noisy): near the viewer, sharp sun shadows come at the
//! screen's resolution within a fraction of a second of the camera arriving.

use super::world::World;
use crate::atlas::sparse::SparseTexels;
use crate::grid::CellId;
use crate::reference::punctual::punctual_irradiance_of_texels;
use crate::scene::Rgb;

/// One cell's punctual light at one LOD.
pub struct PunctualBake {
    pub cell: CellId,
    pub lod: u32,
    pub texels: SparseTexels,
    /// Per texel: the direct irradiance of every punctual light (W/m²).
    pub irradiance: Vec<Rgb>,
}

impl PunctualBake {
    pub fn new(world: &World, cell: CellId, lod: u32) -> PunctualBake {
        let texels = world.cells_texels(&[cell], lod);
        let irradiance = punctual_irradiance_of_texels(
            &world.scene,
            &world.geom,
            &world.atlas,
            &world.bvh,
            lod,
            &texels.face,
            &|i| texels.pixel[i],
            |i| texels.table_of(i),
            world.epsilon,
            1,
        );
        PunctualBake { cell, lod, texels, irradiance }
    }

    /// The pixels it publishes (texels, then the gutter pixels copying them) with their values.
    pub fn pixels(&self) -> impl Iterator<Item = ([u32; 2], Rgb)> + '_ {
        let t = &self.texels;
        t.pixel
            .iter()
            .zip(&self.irradiance)
            .map(|(p, e)| (*p, *e))
            .chain(t.gutter.iter().map(|&(g, i)| (g, self.irradiance[i as usize])))
    }
}

/// Bytes a punctual bake of a cell with `texels` texels holds while it runs (the texel map,
/// ~68 B a texel, and the values), and its pages once published (as a bundle publish,
/// [`PAGE_BYTES_PER_TEXEL`](super::memory::PAGE_BYTES_PER_TEXEL) a texel).
pub fn punctual_bake_bytes(texels: u64) -> u64 {
    texels * (68 + 12 + super::memory::PAGE_BYTES_PER_TEXEL)
}
