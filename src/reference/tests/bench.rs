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
        let c0 = process_cpu_seconds();
        let (_, st) = tr.irradiance_batch(&queries, 64, 1, &|_| {});
        let cpu = process_cpu_seconds().zip(c0).map_or(f64::NAN, |(c1, c0)| c1 - c0);
        println!(
            "tracer, {threads} thread(s): {:.2} M rays/s total, {:.2} M rays/s per thread, {:.2} M rays/s per CPU-second, {:.1} rays/path, {:.2} s",
            st.rays_per_second() / 1e6,
            st.rays_per_second() / 1e6 / threads as f64,
            st.rays as f64 / cpu / 1e6,
            st.rays as f64 / st.paths as f64,
            st.seconds
        );
    }
}

/// Time this thread has spent on a CPU (s), from /proc/thread-self/schedstat (Linux): per-core
/// throughput that other jobs on a shared machine do not dilute (caches are still shared).
fn thread_cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    Some(s.split_whitespace().next()?.parse::<f64>().ok()? * 1e-9)
}

/// CPU time of the whole process (all threads), s, from /proc/self/stat (10 ms ticks).
fn process_cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = &s[s.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// Best of `reps` runs of `f`: (wall seconds, on-CPU seconds, result).
fn best_of(reps: usize, mut f: impl FnMut() -> u32) -> (f64, f64, u32) {
    let (mut wall, mut cpu) = (f64::INFINITY, f64::INFINITY);
    let mut out = 0;
    for _ in 0..reps {
        let (t, c) = (Instant::now(), thread_cpu_seconds());
        out = f();
        wall = wall.min(t.elapsed().as_secs_f64());
        if let (Some(c0), Some(c1)) = (c, thread_cpu_seconds()) {
            cpu = cpu.min(c1 - c0);
        }
    }
    (wall, cpu, out)
}

#[test]
#[ignore]
fn bench_bvh_only() {
    let scene = furnished_room();
    let tracer = ReferenceTracer::new(&scene);
    let bvh = tracer.bvh();
    let rays = diffuse_rays(&tracer, 1_000_000);
    let m = rays.len() as f64 / 1e6;
    let (w, c, hits) =
        best_of(5, || rays.iter().map(|&(o, d)| bvh.intersect(o, d, 0.0, f32::INFINITY).is_some() as u32).sum());
    println!(
        "{} nodes; closest hit: {:.2} M rays/s wall, {:.2} M rays/s per CPU-second ({hits} hits)",
        bvh.node_count(),
        m / w,
        m / c
    );
    let (w, c, occ) = best_of(5, || rays.iter().map(|&(o, d)| bvh.occluded(o, d, 1.5) as u32).sum());
    println!("any hit (tmax 1.5 m): {:.2} M rays/s wall, {:.2} M rays/s per CPU-second ({occ} occluded)", m / w, m / c);
}
