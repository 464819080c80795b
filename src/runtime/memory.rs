//! The runtime's memory: what the scene's fixed structures hold, what a bake and its pages
//! will hold, and the budget the shown pages and the bakes in progress keep to.
//!
//! The default budget follows the scene and the view rather than the machine: the fixed
//! structures, LOD 0's pages, and the pages of as many texels as the screen can tell apart
//! all around the viewer. A screen of P pixels shows at most P / t² distinct texels at `t`
//! pixels a texel ([`RuntimeConfig::texel_pixels`]); a head that turns sees the rest of the
//! sphere too, the cells out of view one LOD coarser (a quarter of the texels each): about
//! 8 frusta of a 60° camera, 1 + 7/4 ≈ 2.75 screens of texels, for each of the two layers.
//! Pages hold their texels at a fill of ~37% (16×16-pixel pages; charts scattered over the
//! atlas: measured over a 60 s run on zdm2 beside another game map), so a shown texel costs
//! ~16 B / 0.37 ≈ 43 B of pages (48 counted). The bakes in progress get the rest of what the
//! budget allows.

use super::RuntimeConfig;
use super::policy::CameraView;
use super::shown::{Page, ShownLightmap};
use super::world::World;
use crate::grid::CellId;

/// Bytes of what the runtime holds for the scene whatever the camera does: geometry, atlas,
/// BVH, the LOD-0 texels and the grid's triangle lists.
pub(super) fn fixed_bytes(world: &World) -> u64 {
    let tris = world.geom.len() as u64;
    let lod0 = world.lod0.len() as u64 * (4 + 4 + 12 * 4 + 4) + world.lod0.gutter.len() as u64 * 8;
    tris * (36 + 12 + 4 + 4 + 4 + 4) // geometry
        + world.atlas.faces.len() as u64 * 36
        + world.bvh.memory_bytes() as u64
        + lod0
        + world.cell_triangles.triangles.len() as u64 * 4
}

/// Texels of `cell` at `lod`, estimated from its LOD-0 count (4^lod times as many).
pub(super) fn lod_texels(world: &World, cell: CellId, lod: u32) -> u64 {
    world.lod0_texels[cell as usize] as u64 * (1u64 << (2 * lod))
}

/// Bytes a bake of `cell` at `lod` will hold while it runs and its pages once published, from
/// the cell's LOD-0 texel count (4^lod times as many texels at LOD `lod`).
pub(super) fn bake_estimate(world: &World, cell: CellId, lod: u32) -> u64 {
    bake_estimate_of(lod_texels(world, cell, lod))
}

/// A cell bake holds its texels (~68 B), sums per lane (28 B × lanes, 2 by default, plus the
/// reduced copy), the running totals (56 B), sources and variance (~40 B): ~250 B a texel.
pub(super) const BAKE_BYTES_PER_TEXEL: u64 = 256;
/// A published texel is 16 B in a page; pages are partly filled (charts scattered over the
/// atlas, other cells' texels not published): ~37% (module docs).
pub(super) const PAGE_BYTES_PER_TEXEL: u64 = 48;

/// Screens of texels a turning head sees, per layer (module docs).
const SURROUND: f64 = 2.75;
/// Least derived budget: a small scene in a small window still refines a few cells at once.
const LEAST_BUDGET: u64 = 256 << 20;

/// The budget for `world` seen through `camera` when the user gave none (module docs), at
/// most `ceiling` (a quarter of the machine's memory); `shown`'s LOD-0 pages are counted.
pub fn derived_budget(
    config: &RuntimeConfig,
    world: &World,
    shown: &ShownLightmap,
    camera: &CameraView,
    ceiling: u64,
) -> u64 {
    let pixels = camera.height_px as f64 * (camera.height_px as f64 * camera.aspect as f64);
    let screen_texels = pixels / (config.texel_pixels as f64).powi(2);
    let view = SURROUND * screen_texels * 2.0 * PAGE_BYTES_PER_TEXEL as f64;
    let lod0_pages = shown.layers.iter().filter_map(|l| l.levels.first()).map(|l| l.live_pages()).sum::<usize>() as u64
        * Page::BYTES as u64;
    let bakes = config.threads() as u64 * 2 * bake_estimate_of(config.group_texels as u64);
    let derived = fixed_bytes(world) + lod0_pages + view as u64 + bakes;
    derived.max(LEAST_BUDGET).min(ceiling.max(LEAST_BUDGET))
}

/// Bytes of a bake of `texels` texels and its pages.
fn bake_estimate_of(texels: u64) -> u64 {
    texels * (BAKE_BYTES_PER_TEXEL + PAGE_BYTES_PER_TEXEL)
}
