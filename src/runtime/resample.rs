//! The shown light map as one image over the atlas at one LOD: what `run --export-gltf`
//! hands to the glTF export (which takes a whole-LOD map, as a bake gives).
//!
//! The shown map is sparse and mixed: every cell shows its own LOD in each layer, with blends
//! at borders with coarser cells. The export gets one level, [`export_lod`]: the finest LOD
//! any cell shows in either layer, so refined cells keep their detail, unless the atlas at
//! that LOD would exceed [`MAX_EXPORT_PIXELS`]; then the finest LOD within it (the cells
//! shown finer lose detail, said in a warning). Every texel of that level (and each gutter
//! pixel, copying its texel) takes the value of the one sampling function,
//! [`ShownLightmap::irradiance`], at the texel's surface point and its pixel centre. An
//! engine's bilinear filter over that image then reproduces the shown map: exactly where a
//! cell shows the export LOD in both layers (a pixel centre reads its own pixel), and to
//! within the bilinear interpolation of the shown values at the export resolution elsewhere
//! (tests/export.rs states the bound).

use glam::Vec2;
use image::Rgb32FImage;

use super::shown::ShownLightmap;
use super::world::World;
use crate::atlas::TexelMap;
use crate::scene::Rgb;

/// Most pixels of an exported light map: 4 M (2048², 48 MB of f32 RGB), a size engines load
/// as one texture without trouble; the whole-LOD texel map the resampling builds takes about
/// 60 bytes a texel on top.
pub const MAX_EXPORT_PIXELS: u64 = 1 << 22;

/// The LOD to export `shown` at: the finest any cell shows (in either layer), lowered until
/// its atlas at that LOD has at most `max_pixels` pixels (LOD 0 whatever its size).
pub fn export_lod(shown: &ShownLightmap, max_pixels: u64) -> u32 {
    let finest = shown.finest_lod();
    let pixels = |k: u32| ((shown.atlas_width as u64) << k) * ((shown.atlas_height as u64) << k);
    (0..=finest).rev().find(|&k| pixels(k) <= max_pixels).unwrap_or(0)
}

/// `shown` resampled over `world`'s atlas at LOD `lod` (module docs): E in W/m², gutters
/// filled, 0 where no texel is.
pub fn shown_image(world: &World, shown: &ShownLightmap, lod: u32) -> Rgb32FImage {
    let texels = TexelMap::build(&world.scene, &world.geom, &world.atlas, lod);
    let scale = 1.0 / (1u64 << lod) as f32;
    let values: Vec<Rgb> = (0..texels.len())
        .map(|i| {
            let p = texels.pixel[i];
            let (x, y) = (p % texels.width, p / texels.width);
            shown.irradiance(texels.position[i], Vec2::new(x as f32 + 0.5, y as f32 + 0.5) * scale)
        })
        .collect();
    let img = texels.to_image(&values, Rgb::ZERO);
    let w = texels.width;
    Rgb32FImage::from_fn(w, texels.height, |x, y| image::Rgb(img[(y * w + x) as usize].to_array()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Grid;
    use crate::runtime::shown::{Layer, PageWriter};

    #[test]
    fn export_lod_is_the_finest_shown_within_the_pixel_cap() {
        let grid = Grid { origin: glam::Vec3::ZERO, cell_size: 1.0, dims: [2, 1, 1] };
        let mut shown = ShownLightmap::new(grid, 100, 50, 4, 0.0);
        assert_eq!(export_lod(&shown, MAX_EXPORT_PIXELS), 0);
        let mut w = PageWriter::new(&mut shown);
        w.set_cell_lod(Layer::Bundles, 1, 3);
        w.finish();
        // LOD 3: 800 × 400 = 320 000 pixels.
        assert_eq!(export_lod(&shown, 320_000), 3);
        assert_eq!(export_lod(&shown, 319_999), 2);
        assert_eq!(export_lod(&shown, 10), 0);
    }
}
