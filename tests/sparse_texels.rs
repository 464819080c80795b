//! Per-cell texel maps against the whole-LOD one: the runtime makes LOD k's texels cell by
//! cell, and they must be exactly the whole map's texels cut by cell (same pixels, faces,
//! positions, normals, albedo, emission and areas, bit for bit; same gutter pixels copying
//! the same texels), with every texel in exactly one cell.

use std::collections::HashMap;
use std::path::Path;

use glam::Vec3;
use livebake::atlas::sparse::SparseTexels;
use livebake::atlas::texels::NO_TEXEL;
use livebake::atlas::{Atlas, AtlasConfig, TexelMap};
use livebake::grid::{CellTriangles, Grid};
use livebake::scene::{LoadOptions, Scene, SceneGeometry, load_gltf};

fn load(rel: &str) -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets").join(rel);
    load_gltf(&path, &LoadOptions::default()).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

/// Every cell's sparse texels at `lod` against the whole map.
fn check(scene: &Scene, texel: f32, cell: f32, lod: u32) {
    let geom = SceneGeometry::new(scene);
    let atlas = Atlas::build(scene, &geom, &AtlasConfig { texel_size: Some(texel), ..AtlasConfig::default() }).unwrap();
    let whole = TexelMap::build(scene, &geom, &atlas, lod);
    let slots = whole.slots();
    let texel_at = |x: u32, y: u32| Some(slots[(y * whole.width + x) as usize]).filter(|&t| t != NO_TEXEL);
    let grid = Grid::for_scene(&geom, atlas.stats.lit_area, texel, texel, Some(cell)).unwrap();
    // Core triangles: those meeting the cell grown by a hair (float safety for points on a face).
    let eps = 1e-4 * cell;
    let index = CellTriangles::build(&grid, &geom, eps);
    let mut seen: HashMap<(u32, u32), usize> = HashMap::new();
    let mut gutters: HashMap<(u32, u32), (u32, u32)> = HashMap::new();
    let mut cells_with_texels = 0;
    for c in 0..grid.len() as u32 {
        let (lo, hi) = grid.bounds(c);
        let sparse = SparseTexels::build(
            scene,
            &geom,
            &atlas,
            lod,
            index.of(c),
            lo - Vec3::splat(eps),
            hi + Vec3::splat(eps),
            |p| grid.cell_of(p) == c,
        );
        cells_with_texels += usize::from(!sparse.is_empty());
        for i in 0..sparse.len() {
            let [x, y] = sparse.pixel[i];
            let w = texel_at(x, y).unwrap_or_else(|| panic!("cell {c}: pixel ({x},{y}) is no texel")) as usize;
            assert!(seen.insert((x, y), c as usize).is_none(), "pixel ({x},{y}) in two cells");
            assert_eq!(grid.cell_of(whole.position[w]), c);
            assert_eq!(sparse.face[i], whole.face[w], "face at ({x},{y})");
            assert_eq!(sparse.position[i].to_array(), whole.position[w].to_array());
            assert_eq!(sparse.normal[i].to_array(), whole.normal[w].to_array());
            assert_eq!(sparse.albedo[i].to_array(), whole.albedo[w].to_array());
            assert_eq!(sparse.emission[i].to_array(), whole.emission[w].to_array());
            assert_eq!(sparse.area[i].to_bits(), whole.area[w].to_bits(), "area at ({x},{y})");
            // The lookup finds the texel through its chart's table.
            let chart = atlas.faces[sparse.face[i] as usize].chart;
            assert_eq!(sparse.table(chart).unwrap().get(x as i64, y as i64), i as u32);
        }
        for &([x, y], t) in &sparse.gutter {
            let src = sparse.pixel[t as usize];
            assert!(gutters.insert((x, y), (src[0], src[1])).is_none(), "gutter ({x},{y}) written twice");
        }
        // Texels come in the whole map's order (block order).
        let ids: Vec<u32> = sparse.pixel.iter().map(|p| texel_at(p[0], p[1]).unwrap()).collect();
        assert!(ids.windows(2).all(|w| w[0] < w[1]), "cell {c}: texels out of block order");
    }
    assert_eq!(seen.len(), whole.len(), "every texel belongs to exactly one cell");
    assert_eq!(gutters.len(), whole.gutter.len(), "gutter pixels");
    for &(p, t) in &whole.gutter {
        let (x, y) = (p % whole.width, p / whole.width);
        let src = whole.pixel[t as usize];
        assert_eq!(gutters.get(&(x, y)), Some(&(src % whole.width, src / whole.width)), "gutter ({x},{y})");
    }
    assert!(cells_with_texels > 8, "the grid should cut the scene into many cells: {cells_with_texels}");
}

#[test]
fn cornell_box_cells_partition_lod0_and_lod1() {
    let scene = load("cornell_box/cornellBox-2.79-Cycles-gltf.gltf");
    check(&scene, 0.08, 0.7, 0);
    check(&scene, 0.08, 0.7, 1);
}

#[test]
fn van_gogh_room_cells_partition_lod1() {
    // Double-sided faces, TEXCOORD-less meshes, thin furniture: many charts per cell.
    let scene = load("van_gogh_room/van_gogh_room.gltf");
    check(&scene, 0.06, 0.9, 1);
}
