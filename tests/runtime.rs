//! The live runtime: cell bakes against offline bakes, publication order, camera moves,
//! shutdown, LOD borders and multi-bounce against the reference.

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use livebake::atlas::Atlas;
use livebake::bundle::BackendProvider;
use livebake::cpu::CpuProvider;
use livebake::runtime::cell_bake::CellBake;
use livebake::runtime::shown::ShownLightmap;
use livebake::runtime::world::World;
use livebake::runtime::{RuntimeConfig, bake_first_light, empty_shown};
use livebake::scene::{LoadOptions, Rgb, Scene, SceneGeometry, load_gltf};

fn load(rel: &str) -> Arc<Scene> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets").join(rel);
    Arc::new(load_gltf(&path, &LoadOptions::default()).unwrap_or_else(|e| panic!("{rel}: {e}")))
}

fn world(scene: Arc<Scene>, config: &RuntimeConfig) -> Arc<World> {
    let geom = Arc::new(SceneGeometry::new(&scene));
    let atlas = Arc::new(Atlas::build(&scene, &geom, &config.atlas).expect("atlas"));
    Arc::new(World::new(scene, geom, atlas, config).expect("world"))
}

fn first_light(world: &World) -> Arc<ShownLightmap> {
    let mut backend = CpuProvider::new().backend(&world.bundle, 2).expect("backend");
    Arc::new(bake_first_light(world, &mut backend, 2, empty_shown(world)).expect("first light").0)
}

fn luminance(c: Rgb) -> f64 {
    (0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z) as f64
}

fn bake_cell(world: &World, shown: &Arc<ShownLightmap>, cell: u32, lod: u32, seed: u64, directions: u32) -> CellBake {
    let mut backend = CpuProvider::new().backend(&world.bundle, 1).expect("backend");
    let mut bake = CellBake::new(world, cell, lod, shown.clone(), seed, 2);
    let never = AtomicBool::new(false);
    while bake.directions() < directions as u64 {
        bake.step(world, &mut backend, 4, &never).expect("not cancelled");
    }
    bake
}

#[test]
fn error_estimate_is_calibrated() {
    let config = RuntimeConfig::default();
    let world = world(load("cornell_2m/cornell_2m.gltf"), &config);
    let shown = first_light(&world);
    // The cells with the most texels.
    let mut cells: Vec<u32> = world.non_empty_cells().collect();
    cells.sort_by_key(|&c| std::cmp::Reverse(world.lod0_texels[c as usize]));
    for &cell in cells.iter().take(4) {
        let d = 128;
        let a = bake_cell(&world, &shown, cell, 1, 1, d);
        let r = bake_cell(&world, &shown, cell, 1, 2, 16 * d);
        let (ea, er) = (a.result(), r.result());
        let n = ea.len() as f64;
        let mse: f64 = ea.iter().zip(&er).map(|(x, y)| (luminance(*x) - luminance(*y)).powi(2)).sum::<f64>() / n;
        let mean: f64 = er.iter().map(|y| luminance(*y)).sum::<f64>() / n;
        let actual = mse.sqrt() / mean;
        eprintln!(
            "cell {cell}: {} texels, estimate {:.4} (ref {:.4}), actual {:.4}",
            a.texels.len(),
            a.error(),
            r.error(),
            actual
        );
    }
}
