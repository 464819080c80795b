//! Throughput on the ~10k-triangle furnished room. Ignored by default; run with
//! `cargo test --release --lib reference::tests::bench -- --ignored --nocapture`.

use std::time::Instant;

use glam::Vec3;

use super::batch::surface_queries;
use crate::reference::ReferenceTracer;
use crate::reference::scenes::furnished_room;
use crate::sampling::{Rng, cosine_hemisphere};

/// Incoherent diffuse rays: from surface points (offset by ε), cosine-distributed.
fn diffuse_rays(t: &ReferenceTracer<'_>, n: usize) -> Vec<(Vec3, Vec3)> {
    let mut r = Rng::new(77, 0);
    surface_queries(t, n, 99)
        .into_iter()
        .map(|(p, nn)| (p + nn * t.epsilon(), cosine_hemisphere(nn, r.next_vec2())))
        .collect()
}

#[test]
#[ignore]
fn bench_furnished_room() {
    let scene = furnished_room();
    let t0 = Instant::now();
    let tracer = ReferenceTracer::new(&scene);
    let build = t0.elapsed().as_secs_f64();
    let bvh = tracer.bvh();
    println!(
        "scene: {} triangles, {} emitters, {} lights; build {:.1} ms; BVH {} nodes, {:.2} MB; ε = {:.3e} m",
        scene.triangle_count(),
        tracer.emitters().len(),
        scene.lights.len(),
        build * 1e3,
        bvh.node_count(),
        bvh.memory_bytes() as f64 / 1e6,
        tracer.epsilon()
    );

    // Raw BVH, one core: closest hit and any hit of 2M incoherent diffuse rays.
    let rays = diffuse_rays(&tracer, 2_000_000);
    let t = Instant::now();
    let mut hits = 0u32;
    for &(o, d) in &rays {
        hits += bvh.intersect(o, d, 0.0, f32::INFINITY).is_some() as u32;
    }
    let s = t.elapsed().as_secs_f64();
    println!("BVH closest hit, 1 thread: {:.2} M rays/s ({hits} hits)", rays.len() as f64 / s / 1e6);
    let t = Instant::now();
    let mut occ = 0u32;
    for &(o, d) in &rays {
        occ += bvh.occluded(o, d, 1.5) as u32;
    }
    let s = t.elapsed().as_secs_f64();
    println!("BVH any hit (tmax 1.5 m), 1 thread: {:.2} M rays/s ({occ} occluded)", rays.len() as f64 / s / 1e6);

    // The full tracer (paths, NEE, shadow rays, shading), 1 and 2 threads.
    let queries = surface_queries(&tracer, 4096, 5);
    for threads in [1, 2] {
        let tr = ReferenceTracer::new(&scene).with_threads(Some(threads));
        let (_, st) = tr.irradiance_batch(&queries, 64, 1, &|_| {});
        println!(
            "tracer, {threads} thread(s): {:.2} M rays/s total, {:.2} M rays/s per thread, {:.1} rays/path, {:.2} s",
            st.rays_per_second() / 1e6,
            st.rays_per_second() / 1e6 / threads as f64,
            st.rays as f64 / st.paths as f64,
            st.seconds
        );
    }
}
