//! Everything the runtime derives once from a scene: geometry, atlas, BVH, the grid and
//! which triangles meet each cell, the bundle inputs, and the LOD-0 texels.

use std::sync::Arc;

use glam::Vec3;

use super::RuntimeConfig;
use crate::atlas::sparse::SparseTexels;
use crate::atlas::{Atlas, TexelMap};
use crate::bundle::BundleScene;
use crate::grid::{CellId, CellTriangles, Grid};
use crate::reference::{Bvh, ray_epsilon};
use crate::scene::{Scene, SceneGeometry};

pub struct World {
    pub scene: Arc<Scene>,
    pub geom: Arc<SceneGeometry>,
    pub atlas: Arc<Atlas>,
    pub bvh: Arc<Bvh>,
    pub bundle: Arc<BundleScene>,
    pub grid: Grid,
    /// Per cell: triangles meeting it (its box grown by [`World::cell_margin`]).
    pub cell_triangles: CellTriangles,
    /// The whole LOD 0 (small by design: what first light bakes).
    pub lod0: TexelMap,
    /// Per cell: its LOD-0 texels (0 for empty cells).
    pub lod0_texels: Vec<u32>,
    /// LOD levels the runtime may refine to (LOD 0 … lods − 1).
    pub lods: u32,
    /// Ray offset for shadow rays (scene-scale).
    pub epsilon: f32,
}

impl World {
    /// How far a cell's box is grown when collecting the triangles that may hold its
    /// texels: a hair, so surface points on a cell's face are never missed to rounding.
    pub fn cell_margin(grid: &Grid) -> f32 {
        1e-4 * grid.cell_size
    }

    pub fn new(
        scene: Arc<Scene>,
        geom: Arc<SceneGeometry>,
        atlas: Arc<Atlas>,
        config: &RuntimeConfig,
    ) -> Result<World, super::RuntimeError> {
        let lods = config.levels_for(atlas.texel_size);
        // Cells of at least 16 LOD-0 texels, and at most 512 finest texels, a side.
        let finest = atlas.texel_size / (1u64 << (lods - 1)) as f32;
        let grid =
            Grid::for_scene(&geom, atlas.stats.lit_area, 16.0 * atlas.texel_size, 512.0 * finest, config.cell_size)?;
        World::with_grid(scene, geom, atlas, config, grid)
    }

    /// The world of a scene over a given grid (hot reload keeps the grid: cells and their
    /// shown LODs stay where they are).
    pub fn with_grid(
        scene: Arc<Scene>,
        geom: Arc<SceneGeometry>,
        atlas: Arc<Atlas>,
        config: &RuntimeConfig,
        grid: Grid,
    ) -> Result<World, super::RuntimeError> {
        let lods = config.levels_for(atlas.texel_size);
        let t = std::time::Instant::now();
        // The BVH's build is one thread's work: it runs beside the cells' triangles and the
        // LOD-0 texel map (1.4 s and 0.9 s on a million triangles).
        let (bvh, t_bvh, cell_triangles, t_cells, lod0, t_lod0) = std::thread::scope(|threads| {
            let bvh = threads.spawn(|| (Bvh::for_scene(&scene, &geom), t.elapsed()));
            let cell_triangles = CellTriangles::build(&grid, &geom, World::cell_margin(&grid));
            let t_cells = t.elapsed();
            let lod0 = TexelMap::build(&scene, &geom, &atlas, 0);
            let t_lod0 = t.elapsed();
            let (bvh, t_bvh) = match bvh.join() {
                Ok(done) => done,
                Err(panic) => std::panic::resume_unwind(panic),
            };
            (Arc::new(bvh), t_bvh, cell_triangles, t_cells, lod0, t_lod0)
        });
        let mut lod0_texels = vec![0u32; grid.len()];
        for p in &lod0.position {
            lod0_texels[grid.cell_of(*p) as usize] += 1;
        }
        let bundle = Arc::new(BundleScene::new(scene.clone(), geom.clone(), atlas.clone(), config.bundle.clone()));
        let epsilon = ray_epsilon(&scene);
        tracing::debug!(
            "world: BVH {:.1} ms beside cell triangles {:.1} ms and LOD-0 texels {:.1} ms, bundle scene {:.1} ms",
            t_bvh.as_secs_f64() * 1e3,
            t_cells.as_secs_f64() * 1e3,
            (t_lod0 - t_cells).as_secs_f64() * 1e3,
            (t.elapsed() - t_lod0.max(t_bvh)).as_secs_f64() * 1e3
        );
        Ok(World { scene, geom, atlas, bvh, bundle, grid, cell_triangles, lod0, lod0_texels, lods, epsilon })
    }

    /// Metres per texel at LOD `lod`.
    pub fn texel_size(&self, lod: u32) -> f32 {
        self.atlas.texel_size / (1u64 << lod) as f32
    }

    /// Cells holding LOD-0 texels.
    pub fn non_empty_cells(&self) -> impl Iterator<Item = CellId> + '_ {
        (0..self.grid.len() as u32).filter(|&c| self.lod0_texels[c as usize] > 0)
    }

    /// The box a cell bake's texels lie in, grown by the cell margin (see [`World::cell_margin`]).
    pub fn cell_box(&self, cell: CellId) -> (Vec3, Vec3) {
        let (lo, hi) = self.grid.bounds(cell);
        let m = Vec3::splat(World::cell_margin(&self.grid));
        (lo - m, hi + m)
    }

    /// The texels of LOD `lod` whose surface points lie in `cells` (made for them alone).
    pub fn cells_texels(&self, cells: &[CellId], lod: u32) -> SparseTexels {
        let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
        for &c in cells {
            let (a, b) = self.cell_box(c);
            lo = lo.min(a);
            hi = hi.max(b);
        }
        let mut core: Vec<u32> = cells.iter().flat_map(|&c| self.cell_triangles.of(c).iter().copied()).collect();
        if cells.len() > 1 {
            core.sort_unstable();
            core.dedup();
        }
        let grid = self.grid;
        SparseTexels::build(&self.scene, &self.geom, &self.atlas, lod, &core, lo, hi, |p| {
            cells.contains(&grid.cell_of(p))
        })
    }
}
