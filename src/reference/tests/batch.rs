//! Batches: thread-count independence, agreement with single queries, stats and progress.

use std::sync::atomic::{AtomicUsize, Ordering};

use glam::Vec3;

use crate::reference::ReferenceTracer;
use crate::reference::scenes::furnished_room;
use crate::sampling::{Rng, cosine_hemisphere};

/// Query points spread over the room's triangles (area-uniform is not needed here).
pub(super) fn surface_queries(t: &ReferenceTracer<'_>, n: usize, seed: u64) -> Vec<(Vec3, Vec3)> {
    let g = t.geometry();
    let mut r = Rng::new(seed, 0);
    (0..n)
        .map(|_| {
            let tri = (r.next_u32() as usize) % g.len();
            let (u, v) = crate::sampling::uniform_triangle(r.next_vec2());
            (g.point(tri as u32, u, v), g.normals[tri])
        })
        .collect()
}

#[test]
fn batch_results_do_not_depend_on_thread_count() {
    let scene = furnished_room();
    let queries = surface_queries(&ReferenceTracer::new(&scene), 150, 1);
    let one = ReferenceTracer::new(&scene).with_threads(Some(1));
    let two = ReferenceTracer::new(&scene).with_threads(Some(2));
    let three = ReferenceTracer::new(&scene).with_threads(Some(3));
    let calls = AtomicUsize::new(0);
    let last = AtomicUsize::new(0);
    let progress = |done: usize| {
        calls.fetch_add(1, Ordering::Relaxed);
        last.fetch_max(done, Ordering::Relaxed);
    };
    let (a, sa) = one.irradiance_batch(&queries, 8, 42, &progress);
    assert_eq!(last.load(Ordering::Relaxed), queries.len());
    assert!(calls.load(Ordering::Relaxed) >= 1);
    let (b, sb) = two.irradiance_batch(&queries, 8, 42, &|_| {});
    let (c, _) = three.irradiance_batch(&queries, 8, 42, &|_| {});
    // Bit-identical, not merely close.
    assert_eq!(a, b);
    assert_eq!(a, c);
    assert_eq!(sa.rays, sb.rays);
    assert_eq!(sa.paths, 150 * 8);
    // Every path casts at least its first ray; the room is closed and lit, so most paths do
    // more (shadow rays, bounces).
    assert!(sa.rays > 3 * sa.paths, "{sa:?}");
    // Most points are lit. About a fifth legitimately read 0: the floor under the rug (which
    // sees the rug's single-sided back), under the sofa, and furniture faces coplanar with the
    // floor or walls (their offset origin is inside closed geometry).
    let lit = a.iter().filter(|e| e.max_element() > 0.0).count();
    assert!(lit > 100, "{lit}");
    // A batch entry equals the single query with stream = its index.
    for i in [0, 77, 149] {
        assert_eq!(one.irradiance(queries[i].0, queries[i].1, 8, 42, i as u64), a[i]);
    }
    // A different seed changes the result.
    let (d, _) = two.irradiance_batch(&queries, 8, 43, &|_| {});
    assert_ne!(a, d);
}

#[test]
fn sampling_directions_used_by_the_benchmark_are_valid() {
    let n = Vec3::new(0.0, 1.0, 0.0);
    let mut r = Rng::new(0, 0);
    for _ in 0..100 {
        assert!(cosine_hemisphere(n, r.next_vec2()).dot(n) >= 0.0);
    }
}
