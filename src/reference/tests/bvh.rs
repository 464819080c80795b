//! BVH queries against brute force, and watertightness on closed boxes.

use glam::{DVec3, Quat, Vec3};

use crate::reference::bvh::{Bvh, Hit};
use crate::reference::scenes::uv_sphere;
use crate::sampling::{Rng, uniform_sphere};
use crate::scene::builder::white;
use crate::scene::{SceneBuilder, SceneGeometry};

fn rand_vec(r: &mut Rng, lo: f32, hi: f32) -> Vec3 {
    Vec3::new(r.next_f32(), r.next_f32(), r.next_f32()) * (hi - lo) + Vec3::splat(lo)
}

/// `n` random triangles of size ~0.05–0.3 inside the unit cube.
fn soup(n: usize, seed: u64) -> SceneGeometry {
    let mut r = Rng::new(seed, 0);
    let mut b = SceneBuilder::new();
    let m = b.material(white());
    let mut pos = Vec::new();
    let mut tris = Vec::new();
    for i in 0..n as u32 {
        let c = rand_vec(&mut r, 0.0, 1.0);
        let s = 0.05 + 0.25 * r.next_f32();
        for _ in 0..3 {
            pos.push(c + rand_vec(&mut r, -s, s));
        }
        tris.push([3 * i, 3 * i + 1, 3 * i + 2]);
    }
    b.mesh("soup", pos, tris, m);
    SceneGeometry::new(&b.build())
}

/// Independent brute force: Möller–Trumbore in f64 over every triangle.
fn brute_closest(g: &SceneGeometry, o: Vec3, d: Vec3, tmin: f64, tmax: f64) -> Option<(f64, u32, f64, f64)> {
    let (o, d) = (o.as_dvec3(), d.as_dvec3());
    let mut best = None;
    let mut tbest = tmax;
    for (i, c) in g.corners.iter().enumerate() {
        let [a, b, c] = c.map(|p| p.as_dvec3());
        let (e1, e2) = (b - a, c - a);
        let pv = d.cross(e2);
        let det = e1.dot(pv);
        if det == 0.0 {
            continue;
        }
        let tv = o - a;
        let u = tv.dot(pv) / det;
        let qv = tv.cross(e1);
        let v = d.dot(qv) / det;
        let t = e2.dot(qv) / det;
        if u >= 0.0 && v >= 0.0 && u + v <= 1.0 && t > tmin && t < tbest {
            tbest = t;
            best = Some((t, i as u32, u, v));
        }
    }
    best
}

/// Smallest barycentric coordinate of a hit: how close to an edge it is.
fn edge_margin(u: f64, v: f64) -> f64 {
    u.min(v).min(1.0 - u - v)
}

#[test]
fn closest_hit_matches_brute_force_on_a_soup() {
    let g = soup(600, 11);
    let bvh = Bvh::new(&g);
    let mut r = Rng::new(5, 0);
    let (mut hits, mut edge_cases) = (0, 0);
    for i in 0..20_000 {
        let o = rand_vec(&mut r, -0.5, 1.5);
        let d = uniform_sphere(r.next_vec2()) * (0.5 + r.next_f32());
        let (tmin, tmax) = if i % 4 == 0 { (0.2 * r.next_f32(), 0.5 + r.next_f32()) } else { (0.0, f32::INFINITY) };
        let got = bvh.intersect(o, d, tmin, tmax);
        let want = brute_closest(&g, o, d, tmin as f64, tmax as f64);
        match (got, want) {
            (None, None) => {}
            (Some(h), Some((t, tri, u, v))) => {
                hits += 1;
                // f32 vs f64 kernels: t agrees to ~1e-6 relative; a different triangle is only
                // allowed where two triangles are hit at (nearly) the same t.
                assert!((h.t as f64 - t).abs() <= 1e-5 * t.max(1.0), "ray {i}: t {} vs {t}", h.t);
                if h.tri == tri {
                    assert!((h.u as f64 - u).abs() < 1e-4 && (h.v as f64 - v).abs() < 1e-4, "ray {i}");
                }
                let p = g.point(h.tri, h.u, h.v);
                assert!((p - (o + d * h.t)).length() < 1e-4, "ray {i}: hit point off its ray");
            }
            (g_, w) => {
                // Disagreement is only acceptable for a ray grazing an edge of the f64 hit
                // (or of the f32 hit when the brute force missed), within rounding.
                edge_cases += 1;
                let margin = match (g_, w) {
                    (_, Some((_, _, u, v))) => edge_margin(u, v),
                    (Some(h), None) => edge_margin(h.u as f64, h.v as f64),
                    _ => unreachable!(),
                };
                assert!(margin.abs() < 1e-5, "ray {i}: bvh {g_:?} vs brute {w:?}");
            }
        }
    }
    // The test must exercise hits, and edge disagreements must stay rare.
    assert!(hits > 3_000, "{hits}");
    assert!(edge_cases < 10, "{edge_cases}");
}

#[test]
fn occluded_agrees_with_intersect() {
    let g = soup(400, 3);
    let bvh = Bvh::new(&g);
    let mut r = Rng::new(6, 0);
    let mut blocked = 0;
    for _ in 0..20_000 {
        let o = rand_vec(&mut r, -0.2, 1.2);
        let d = uniform_sphere(r.next_vec2());
        let tmax = 2.0 * r.next_f32();
        let occ = bvh.occluded(o, d, tmax);
        assert_eq!(occ, bvh.intersect(o, d, 0.0, tmax).is_some());
        blocked += occ as u32;
    }
    assert!(blocked > 2_000 && blocked < 18_000, "{blocked}");
}

/// The shadow cache's queries: `occluder` finds a slot exactly when `occluded` is true, that
/// slot occludes the same ray, and a slot that does not lie on a ray says so (a cache miss
/// then falls back to the traversal).
#[test]
fn occluder_slots_occlude_their_rays() {
    let g = soup(400, 4);
    let bvh = Bvh::new(&g);
    let mut r = Rng::new(7, 0);
    let (mut found, mut other_hits, mut other_misses) = (0, 0, 0);
    let mut last = None;
    for _ in 0..20_000 {
        let o = rand_vec(&mut r, -0.2, 1.2);
        let d = uniform_sphere(r.next_vec2());
        let tmax = 2.0 * r.next_f32();
        let slot = bvh.occluder(o, d, tmax);
        assert_eq!(slot.is_some(), bvh.occluded(o, d, tmax));
        if let Some(s) = slot {
            assert!(bvh.occluded_by(s, o, d, tmax));
            found += 1;
        }
        // Another ray's occluder: occluding this ray only where the traversal agrees.
        if let Some(prev) = last {
            if bvh.occluded_by(prev, o, d, tmax) {
                assert!(bvh.occluded(o, d, tmax));
                other_hits += 1;
            } else {
                other_misses += 1;
            }
        }
        last = slot.or(last);
    }
    assert!(!bvh.occluded_by(u32::MAX, Vec3::ZERO, Vec3::X, 1.0));
    assert!(found > 2_000 && other_misses > 1_000, "{found} {other_misses}");
    assert!(other_hits > 0, "no ray met another ray's occluder: the check tests nothing");
}

/// A closed box of side 2 centred at the origin, each face an n × n grid, then rotated by
/// `rot`. Vertices shared between faces are bitwise equal before the rotation (the grids
/// interpolate exact axis-aligned corners) and so after it: rotating the corners first and
/// interpolating afterwards would give cracks that no watertight test can close.
fn closed_box(n: u32, rot: Quat, inward: bool) -> SceneGeometry {
    let mut b = SceneBuilder::new();
    let m = b.material(white());
    let p = Vec3::new;
    let faces = [
        [p(-1., -1., -1.), p(-1., -1., 1.), p(-1., 1., 1.), p(-1., 1., -1.)],
        [p(1., -1., -1.), p(1., 1., -1.), p(1., 1., 1.), p(1., -1., 1.)],
        [p(-1., -1., -1.), p(1., -1., -1.), p(1., -1., 1.), p(-1., -1., 1.)],
        [p(-1., 1., -1.), p(-1., 1., 1.), p(1., 1., 1.), p(1., 1., -1.)],
        [p(-1., -1., -1.), p(-1., 1., -1.), p(1., 1., -1.), p(1., -1., -1.)],
        [p(-1., -1., 1.), p(1., -1., 1.), p(1., 1., 1.), p(-1., 1., 1.)],
    ];
    // grid_quad spans (b − a) and (d − a): reorder [a, b, c, d] → [a, d, c, b] to flip.
    for f in faces {
        let f = if inward { [f[0], f[3], f[2], f[1]] } else { f };
        b.grid_quad("face", f, n, m);
    }
    let mut scene = b.build();
    for mesh in &mut scene.meshes {
        mesh.positions.iter_mut().for_each(|q| *q = rot * *q);
    }
    SceneGeometry::new(&scene)
}

#[test]
fn closed_boxes_have_no_leaks_through_edges_or_vertices() {
    let rotations = [Quat::IDENTITY, Quat::from_euler(glam::EulerRot::XYZ, 0.3, 1.1, -0.7)];
    for (k, rot) in rotations.into_iter().enumerate() {
        let g = closed_box(6, rot, k == 0);
        let bvh = Bvh::new(&g);
        // Aim at every vertex and every edge midpoint of the tessellation (where a
        // non-watertight test leaks), from random interior points, plus random directions.
        let mut targets: Vec<Vec3> = g
            .corners
            .iter()
            .flat_map(|c| [c[0], c[1], c[2], (c[0] + c[1]) * 0.5, (c[1] + c[2]) * 0.5, (c[2] + c[0]) * 0.5])
            .collect();
        targets.dedup();
        let mut r = Rng::new(9, k as u64);
        let mut rays = 0;
        for round in 0..40 {
            let o = rot * rand_vec(&mut r, -0.95, 0.95);
            for (j, &t) in targets.iter().enumerate() {
                let d = if (j + round) % 2 == 0 { t - o } else { uniform_sphere(r.next_vec2()) };
                let hit = bvh.intersect(o, d, 0.0, f32::INFINITY);
                assert!(hit.is_some(), "box {k}: ray from {o} along {d} escaped");
                assert!(bvh.occluded(o, d, f32::INFINITY), "box {k}: occluded ray escaped");
                rays += 1;
            }
        }
        assert!(rays > 100_000, "{rays}");
    }
}

#[test]
fn rays_from_outside_through_box_edges_hit_the_near_face() {
    // From outside, aimed at edge points of the tessellated faces: the hit must be at the
    // entry distance computed analytically (no leak to the far side).
    let g = closed_box(5, Quat::IDENTITY, false);
    let bvh = Bvh::new(&g);
    let mut r = Rng::new(4, 4);
    for c in &g.corners {
        for target in [c[0], (c[0] + c[1]) * 0.5] {
            let o = target + (uniform_sphere(r.next_vec2()) + target * 1.5);
            let d = target - o;
            // Entry into the cube [−1, 1]³ by the slab method in f64.
            let (od, dd) = (o.as_dvec3(), d.as_dvec3());
            let t0 = (DVec3::splat(-1.0) - od) / dd;
            let t1 = (DVec3::splat(1.0) - od) / dd;
            let entry = t0.min(t1).max_element();
            let exit = t0.max(t1).min_element();
            if entry > exit || entry < 0.0 {
                continue;
            }
            let h: Hit = bvh.intersect(o, d, 0.0, f32::INFINITY).expect("missed the box");
            assert!((h.t as f64 - entry).abs() < 1e-5, "t {} vs entry {entry}", h.t);
        }
    }
}

#[test]
fn closest_point_matches_brute_force() {
    let mut b = SceneBuilder::new();
    let m = b.material(white());
    uv_sphere(&mut b, "s", Vec3::splat(0.5), 0.3, 8, 12, m);
    let mut scene = b.build();
    let g0 = soup(300, 21);
    // Combine soup and sphere.
    let mut pos = Vec::new();
    let mut tris = Vec::new();
    for (i, c) in g0.corners.iter().enumerate() {
        pos.extend_from_slice(c);
        tris.push([3 * i as u32, 3 * i as u32 + 1, 3 * i as u32 + 2]);
    }
    let mut b2 = SceneBuilder::new();
    b2.material(white());
    b2.mesh("soup", pos, tris, 0);
    scene.meshes.extend(b2.build().meshes);
    let g = SceneGeometry::new(&scene);
    let bvh = Bvh::new(&g);
    let mut r = Rng::new(8, 8);
    let mut found = 0;
    for _ in 0..3_000 {
        let p = rand_vec(&mut r, -0.5, 1.5);
        let max_dist = if r.next_f32() < 0.3 { 0.1 } else { f32::INFINITY };
        let brute = (0..g.len())
            .map(|t| {
                let [a, b, c] = g.corners[t];
                let q = crate::reference::triangle::closest_point(p, a, b, c).0;
                (q.distance(p), t as u32)
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .unwrap();
        match bvh.closest_point(p, max_dist) {
            None => assert!(brute.0 > max_dist, "missed {brute:?}"),
            Some(n) => {
                found += 1;
                assert!((n.distance - brute.0).abs() <= 1e-6, "{} vs {}", n.distance, brute.0);
                assert!((n.point.distance(p) - n.distance).abs() < 1e-5);
                assert!((g.point(n.tri, n.u, n.v) - n.point).length() < 1e-5);
            }
        }
    }
    assert!(found > 1_500, "{found}");
}

#[test]
fn tiny_and_empty_scenes() {
    let empty = Bvh::new(&SceneGeometry::default());
    assert!(empty.intersect(Vec3::ZERO, Vec3::X, 0.0, f32::INFINITY).is_none());
    assert!(!empty.occluded(Vec3::ZERO, Vec3::X, f32::INFINITY));
    assert!(empty.closest_point(Vec3::ZERO, f32::INFINITY).is_none());
    let one = soup(1, 2);
    let bvh = Bvh::new(&one);
    let c = one.corners[0];
    let centroid = (c[0] + c[1] + c[2]) / 3.0;
    let o = centroid + one.normals[0];
    let h = bvh.intersect(o, centroid - o, 0.0, f32::INFINITY).unwrap();
    assert!((h.t - 1.0).abs() < 1e-5 && h.tri == 0);
}
