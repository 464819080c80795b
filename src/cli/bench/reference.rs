//! Reference path tracer throughput: rays per second (path segments and shadow rays) on
//! the bundled rooms, one thread and all threads, from texel points of their light maps.

use anyhow::Result;
use livebake::glam::Vec3;
use serde_json::{Value, json};

use livebake::atlas::{Atlas, AtlasConfig, TexelMap};
use livebake::reference::ReferenceTracer;
use livebake::scene::{LoadOptions, SceneGeometry, load_gltf};

use super::Bench;
use super::{EMBREE_RAYS_PER_CORE, assets, median};

const SCENES: [&str; 2] = ["van_gogh_room/van_gogh_room_lit.gltf", "cornell_box/cornellBox-2.79-Cycles-gltf.gltf"];

pub fn run(bench: &Bench) -> Result<Value> {
    let quick = bench.quick;
    let (points, spp, runs) = if quick { (2_000, 8, 3) } else { (20_000, 16, 5) };
    let cores = livebake::parallel::available_threads();
    let mut out = Vec::new();
    for name in SCENES {
        let scene = load_gltf(&assets().join(name), &LoadOptions::default())?;
        let geom = SceneGeometry::new(&scene);
        let atlas = Atlas::build(&scene, &geom, &AtlasConfig::default())?;
        let texels = TexelMap::build(&scene, &geom, &atlas, 0);
        let step = (texels.len() / points).max(1);
        let queries: Vec<(Vec3, Vec3)> =
            (0..texels.len()).step_by(step).map(|i| (texels.position[i], texels.normal[i])).collect();
        let rate = |threads: usize| {
            let tracer = ReferenceTracer::new(&scene).with_threads(Some(threads));
            median(runs, || Ok(tracer.irradiance_batch(&queries, spp, 1, &|_| {}).1.rays_per_second()))
        };
        let (one, all) = (rate(1)?, rate(cores)?);
        out.push(json!({
            "scene": name,
            "triangles": geom.len(),
            "queries": queries.len(),
            "paths_per_query": spp,
            "median_rays_per_second": { "1_thread": one, "all_threads": all, "threads": cores },
            "rays_per_second_per_core": all / cores as f64,
            "target_per_core": 1.0e6,
            "ratio_to_embree_per_core": (all / cores as f64) / EMBREE_RAYS_PER_CORE,
        }));
    }
    Ok(Value::Array(out))
}
