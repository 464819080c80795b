//! Planar chart unwrapper (suits architecture: walls and floors become one chart each).
//!
//! Per mesh (charts never span meshes):
//! 1. Weld vertices by quantised position (glTF splits vertices at UV and normal seams) and
//!    find edge-connected triangles.
//! 2. Seeds in order of decreasing area (ties by triangle id). A chart grows breadth-first
//!    over edge neighbours whose normal is within `chart_max_angle` of the seed's normal and
//!    whose projection onto the seed's plane does not overlap (interiors intersecting by
//!    more than [`OVERLAP_TOL`] texel) a face already in the chart — coplanar duplicates and
//!    curled surfaces are turned away and seed charts of their own. The overlap test is
//!    exact (separating axes), through a uniform grid of the chart's faces.
//! 3. The chart is projected onto the plane ⟂ to its area-weighted normal (checked again for
//!    overlaps; in the rare case the new plane folds it, the seed's plane is kept), rotated
//!    to its minimum-area bounding rectangle (convex hull + rotating calipers) with the long
//!    side along x, scaled to LOD-0 texels and moved to the origin.
//!
//! Truly degenerate faces (thinner than 1e-7 of their length, or collapsed by welding) get
//! a chart of their own: conservative rasterisation still gives them a pixel.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use glam::{DVec2, DVec3, Vec3};

use super::raster::{floor_i64, triangles_overlap};
use crate::scene::{Mesh, SceneGeometry, TriangleId};

/// Two faces of a chart overlap when their projections intersect by more than this (LOD-0
/// texels) along every separating axis.
pub const OVERLAP_TOL: f64 = 1e-4;

/// One chart before packing.
#[derive(Clone, Debug)]
pub struct LocalChart {
    /// Triangles of the chart (global ids, increasing).
    pub tris: Vec<TriangleId>,
    /// Chart-local UVs per triangle (same corner order), LOD-0 texels; bounding box from
    /// the origin to `extent`.
    pub uv: Vec<[DVec2; 3]>,
    pub extent: DVec2,
    /// TEXCOORD_1 blocks: the interior pixel size of the validated layout (kept pixel-aligned).
    pub fixed_interior: Option<(u32, u32)>,
}

/// Small fast hasher for integer keys (deterministic; no new dependency).
#[derive(Default)]
pub(crate) struct FxHasher(u64);

impl Hasher for FxHasher {
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(b as u64);
        }
    }
    fn write_u64(&mut self, x: u64) {
        self.0 = (self.0.rotate_left(5) ^ x).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    fn write_i64(&mut self, x: i64) {
        self.write_u64(x as u64);
    }
    fn finish(&self) -> u64 {
        self.0
    }
}

pub(crate) type FxMap<K, V> = HashMap<K, V, BuildHasherDefault<FxHasher>>;

/// Welds vertices by position quantised to 1e-6 of the bounding-box diagonal. Returns the
/// welded id of every vertex (ids in order of quantised position) and one representative
/// position per id (that of its lowest-index vertex).
pub(crate) fn weld(positions: &[Vec3]) -> (Vec<u32>, Vec<DVec3>) {
    let finite = positions.iter().filter(|p| p.is_finite());
    let (lo, hi) =
        finite.fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), p| (lo.min(p.as_dvec3()), hi.max(p.as_dvec3())));
    let diag = if lo.x <= hi.x { (hi - lo).length() } else { 0.0 };
    let q = if diag > 0.0 { diag * 1e-6 } else { 1.0 };
    let key = |p: Vec3| {
        let p = p.as_dvec3() / q;
        (p.x.round() as i64, p.y.round() as i64, p.z.round() as i64)
    };
    let keys: Vec<_> = positions.iter().map(|&p| key(p)).collect();
    let mut order: Vec<u32> = (0..positions.len() as u32).collect();
    order.sort_unstable_by_key(|&i| (keys[i as usize], i));
    let mut id = vec![0u32; positions.len()];
    let mut reps = Vec::new();
    for (k, &i) in order.iter().enumerate() {
        if k == 0 || keys[i as usize] != keys[order[k - 1] as usize] {
            reps.push(positions[i as usize].as_dvec3());
        }
        id[i as usize] = (reps.len() - 1) as u32;
    }
    (id, reps)
}

/// Edge adjacency (CSR) of triangles given by welded corner ids: triangles sharing an edge.
pub(crate) fn edge_adjacency(corners: &[[u32; 3]]) -> (Vec<u32>, Vec<u32>) {
    let mut edges: Vec<(u64, u32)> = Vec::with_capacity(corners.len() * 3);
    for (i, c) in corners.iter().enumerate() {
        for e in 0..3 {
            let (a, b) = (c[e], c[(e + 1) % 3]);
            if a != b {
                edges.push((((a.min(b) as u64) << 32) | a.max(b) as u64, i as u32));
            }
        }
    }
    edges.sort_unstable();
    // Runs of equal edges: every pair of triangles in a run is adjacent. Count, then fill
    // (a pair sharing two edges — duplicates — is listed twice, which is harmless).
    let runs = |f: &mut dyn FnMut(u32, u32)| {
        let mut s = 0;
        while s < edges.len() {
            let mut e = s + 1;
            while e < edges.len() && edges[e].0 == edges[s].0 {
                e += 1;
            }
            for i in s..e {
                for j in s..e {
                    if edges[i].1 != edges[j].1 {
                        f(edges[i].1, edges[j].1);
                    }
                }
            }
            s = e;
        }
    };
    let mut start = vec![0u32; corners.len() + 1];
    runs(&mut |a, _| start[a as usize + 1] += 1);
    for i in 0..corners.len() {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut adj = vec![0u32; start[corners.len()] as usize];
    runs(&mut |a, b| {
        adj[fill[a as usize] as usize] = b;
        fill[a as usize] += 1;
    });
    (start, adj)
}

/// Uniform grid over the faces of one chart, for the overlap test. Cells hold singly linked
/// lists in one node array, so clearing it between charts frees nothing.
struct OverlapGrid {
    inv_cell: f64,
    heads: FxMap<(i64, i64), u32>,
    /// (face, next node or u32::MAX)
    nodes: Vec<(u32, u32)>,
    /// Faces covering too many cells: tested against every candidate.
    big: Vec<u32>,
    members: Vec<u32>,
    stamp: Vec<u32>,
    now: u32,
}

const MAX_CELLS: i64 = 64;

impl OverlapGrid {
    fn new(cell: f64, faces: usize) -> Self {
        OverlapGrid {
            inv_cell: 1.0 / cell,
            heads: FxMap::default(),
            nodes: Vec::new(),
            big: Vec::new(),
            members: Vec::new(),
            stamp: vec![0; faces],
            now: 0,
        }
    }

    fn clear(&mut self) {
        self.heads.clear();
        self.nodes.clear();
        self.big.clear();
        self.members.clear();
    }

    fn cell_range(&self, t: &[DVec2; 3]) -> Option<(i64, i64, i64, i64)> {
        let lo = t[0].min(t[1]).min(t[2]) * self.inv_cell;
        let hi = t[0].max(t[1]).max(t[2]) * self.inv_cell;
        let r = (floor_i64(lo.x), floor_i64(lo.y), floor_i64(hi.x), floor_i64(hi.y));
        ((r.2 - r.0 + 1) * (r.3 - r.1 + 1) <= MAX_CELLS).then_some(r)
    }

    /// Whether `t` overlaps a face of the chart (`uv` holds every face's projection).
    fn overlaps(&mut self, t: &[DVec2; 3], uv: &[[DVec2; 3]]) -> bool {
        self.now = self.now.wrapping_add(1);
        if self.now == 0 {
            self.stamp.fill(0);
            self.now = 1;
        }
        let now = self.now;
        let hit = |f: u32, stamp: &mut [u32]| {
            if stamp[f as usize] == now {
                return false;
            }
            stamp[f as usize] = now;
            triangles_overlap(t, &uv[f as usize], OVERLAP_TOL)
        };
        let Some((x0, y0, x1, y1)) = self.cell_range(t) else {
            return self.members.iter().any(|&f| hit(f, &mut self.stamp));
        };
        if self.big.iter().any(|&f| hit(f, &mut self.stamp)) {
            return true;
        }
        for y in y0..=y1 {
            for x in x0..=x1 {
                let mut n = self.heads.get(&(x, y)).copied().unwrap_or(u32::MAX);
                while n != u32::MAX {
                    let (f, next) = self.nodes[n as usize];
                    if hit(f, &mut self.stamp) {
                        return true;
                    }
                    n = next;
                }
            }
        }
        false
    }

    fn insert(&mut self, f: u32, t: &[DVec2; 3]) {
        self.members.push(f);
        match self.cell_range(t) {
            None => self.big.push(f),
            Some((x0, y0, x1, y1)) => {
                for y in y0..=y1 {
                    for x in x0..=x1 {
                        let head = self.heads.entry((x, y)).or_insert(u32::MAX);
                        self.nodes.push((f, *head));
                        *head = (self.nodes.len() - 1) as u32;
                    }
                }
            }
        }
    }
}

/// `chart_max_angle` as the unwrapper uses it: at most 80° (beyond, faces would project
/// almost edge-on, with no texels to speak of), 0 when it is not a number.
pub fn effective_max_angle(a: f32) -> f32 {
    if a.is_nan() { 0.0 } else { a.clamp(0.0, 80f32.to_radians()) }
}

/// Unwraps the lit triangles `tris` (global ids, increasing) of `mesh` into planar charts,
/// in LOD-0 texels of `texel_size` metres.
pub fn unwrap_mesh(
    mesh: &Mesh,
    geom: &SceneGeometry,
    tris: &[TriangleId],
    texel_size: f64,
    max_angle: f32,
) -> Vec<LocalChart> {
    let n = tris.len();
    if n == 0 {
        return Vec::new();
    }
    let inv_texel = 1.0 / texel_size;
    let max_angle = effective_max_angle(max_angle);
    let cos_max = (max_angle as f64).cos();
    let (wid, reps) = weld(&mesh.positions);
    let corners: Vec<[u32; 3]> =
        tris.iter().map(|&t| mesh.triangles[geom.local[t as usize] as usize].map(|v| wid[v as usize])).collect();
    let (adj_start, adj) = edge_adjacency(&corners);
    let pos: Vec<[DVec3; 3]> = corners.iter().map(|c| c.map(|v| reps[v as usize])).collect();
    let normal: Vec<DVec3> = tris.iter().map(|&t| geom.normals[t as usize].as_dvec3()).collect();
    let area: Vec<f32> = tris.iter().map(|&t| geom.areas[t as usize]).collect();

    // Degenerate faces (in texel units, after welding) and a grid cell size: the median
    // longest edge, so that a typical face covers one or a few cells.
    let mut longest = Vec::with_capacity(n);
    let degenerate: Vec<bool> = (0..n)
        .map(|i| {
            let [a, b, c] = pos[i].map(|p| p * inv_texel);
            let e2 = (b - a).length_squared().max((c - b).length_squared()).max((a - c).length_squared());
            longest.push(e2.sqrt());
            let a2 = (b - a).cross(c - a).length();
            let [i0, i1, i2] = corners[i];
            i0 == i1 || i1 == i2 || i2 == i0 || a2 <= 1e-7 * e2 || e2 < 1e-12
        })
        .collect();
    let cell = {
        let mut l = longest.clone();
        let mid = l.len() / 2;
        let (_, m, _) = l.select_nth_unstable_by(mid, f64::total_cmp);
        m.max(1e-6)
    };

    let mut seeds: Vec<u32> = (0..n as u32).collect();
    seeds.sort_unstable_by(|&a, &b| area[b as usize].total_cmp(&area[a as usize]).then(a.cmp(&b)));

    let mut chart_of = vec![u32::MAX; n];
    let mut tried = vec![u32::MAX; n];
    let mut proj = vec![[DVec2::ZERO; 3]; n];
    let mut grid = OverlapGrid::new(cell, n);
    let mut charts = Vec::new();
    let mut queue = std::collections::VecDeque::new();

    for &seed in &seeds {
        let s = seed as usize;
        if chart_of[s] != u32::MAX {
            continue;
        }
        let id = charts.len() as u32;
        let mut members = vec![seed];
        chart_of[s] = id;
        if degenerate[s] {
            let uv = project(&pos[s], normal[s], pos[s][0], inv_texel);
            charts.push(finish(&members, vec![uv], tris));
            continue;
        }
        let n0 = normal[s];
        let origin = pos[s][0];
        grid.clear();
        proj[s] = project(&pos[s], n0, origin, inv_texel);
        grid.insert(seed, &proj[s]);
        tried[s] = id;
        queue.clear();
        queue.push_back(seed);
        while let Some(f) = queue.pop_front() {
            for &g in &adj[adj_start[f as usize] as usize..adj_start[f as usize + 1] as usize] {
                let gi = g as usize;
                if chart_of[gi] != u32::MAX || tried[gi] == id || degenerate[gi] {
                    continue;
                }
                tried[gi] = id;
                if normal[gi].dot(n0) < cos_max {
                    continue;
                }
                let t = project(&pos[gi], n0, origin, inv_texel);
                if grid.overlaps(&t, &proj) {
                    continue;
                }
                proj[gi] = t;
                grid.insert(g, &t);
                chart_of[gi] = id;
                members.push(g);
                queue.push_back(g);
            }
        }
        members.sort_unstable();

        // Final plane: area-weighted normal, unless it folds the chart.
        let na = members.iter().map(|&f| normal[f as usize] * area[f as usize] as f64).sum::<DVec3>();
        let na = na.try_normalize().unwrap_or(n0);
        let mut uv: Vec<[DVec2; 3]> = members.iter().map(|&f| proj[f as usize]).collect();
        if na.dot(n0) < 1.0 - 1e-12 {
            let candidate: Vec<[DVec2; 3]> =
                members.iter().map(|&f| project(&pos[f as usize], na, origin, inv_texel)).collect();
            grid.clear();
            let mut ok = true;
            for (k, &f) in members.iter().enumerate() {
                proj[f as usize] = candidate[k];
                if grid.overlaps(&candidate[k], &proj) {
                    ok = false;
                    break;
                }
                grid.insert(f, &candidate[k]);
            }
            if ok {
                uv = candidate;
            }
        }
        charts.push(finish(&members, uv, tris));
    }
    charts
}

/// Projects a triangle onto the plane ⟂ `n` through `origin`, in texels.
fn project(p: &[DVec3; 3], n: DVec3, origin: DVec3, inv_texel: f64) -> [DVec2; 3] {
    let (t, b) = n.any_orthonormal_pair();
    p.map(|q| {
        let d = q - origin;
        DVec2::new(d.dot(t), d.dot(b)) * inv_texel
    })
}

/// Rotates a chart to its minimum-area bounding rectangle (long side along x) and moves it
/// to the origin.
fn finish(members: &[u32], mut uv: Vec<[DVec2; 3]>, tris: &[TriangleId]) -> LocalChart {
    let pts: Vec<DVec2> = uv.iter().flatten().copied().collect();
    let hull = convex_hull(&pts);
    let u = min_area_rect_axis(&hull);
    let v = u.perp();
    let o = pts[0];
    let rot = |p: DVec2| DVec2::new((p - o).dot(u), (p - o).dot(v));
    let (mut lo, mut hi) = (DVec2::INFINITY, DVec2::NEG_INFINITY);
    for t in uv.iter_mut() {
        for p in t.iter_mut() {
            *p = rot(*p);
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
    }
    let mut extent = hi - lo;
    let swap = extent.y > extent.x;
    for t in uv.iter_mut() {
        for p in t.iter_mut() {
            let q = *p - lo;
            // Quarter turn when the chart is taller than wide: (x, y) → (y, e.x − x).
            *p = if swap { DVec2::new(q.y, extent.x - q.x) } else { q };
        }
    }
    if swap {
        extent = DVec2::new(extent.y, extent.x);
    }
    LocalChart { tris: members.iter().map(|&f| tris[f as usize]).collect(), uv, extent, fixed_interior: None }
}

/// Convex hull (Andrew's monotone chain), counter-clockwise, no collinear points.
pub(crate) fn convex_hull(points: &[DVec2]) -> Vec<DVec2> {
    let mut p: Vec<DVec2> = points.to_vec();
    p.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    p.dedup();
    if p.len() < 3 {
        return p;
    }
    let cross = |o: DVec2, a: DVec2, b: DVec2| (a - o).perp_dot(b - o);
    let chain = |it: &mut dyn Iterator<Item = DVec2>| {
        let mut h: Vec<DVec2> = Vec::new();
        for q in it {
            while h.len() >= 2 && cross(h[h.len() - 2], h[h.len() - 1], q) <= 0.0 {
                h.pop();
            }
            h.push(q);
        }
        h.pop();
        h
    };
    let mut hull = chain(&mut p.iter().copied());
    hull.extend(chain(&mut p.iter().rev().copied()));
    if hull.len() < 3 { vec![p[0], p[p.len() - 1]] } else { hull }
}

/// Unit direction of the x axis of the minimum-area bounding rectangle of a convex polygon
/// (counter-clockwise), by rotating calipers: one of the rectangle's sides lies on a hull
/// edge. Ties go to the first edge.
pub(crate) fn min_area_rect_axis(h: &[DVec2]) -> DVec2 {
    let n = h.len();
    if n < 3 {
        return if n == 2 { (h[1] - h[0]).try_normalize().unwrap_or(DVec2::X) } else { DVec2::X };
    }
    let mut best = (f64::INFINITY, DVec2::X);
    let (mut j, mut k, mut m) = (1usize, 1usize, 1usize);
    for i in 0..n {
        let a = h[i];
        let Some(u) = (h[(i + 1) % n] - a).try_normalize() else { continue };
        let v = u.perp();
        let pu = |idx: usize| (h[idx % n] - a).dot(u);
        let pv = |idx: usize| (h[idx % n] - a).dot(v);
        // Going counter-clockwise from edge i: the point furthest along u, then the one
        // furthest from the edge, then the one furthest along −u. Each only moves forward.
        j = j.max(i + 1);
        while j < i + n && pu(j + 1) > pu(j) {
            j += 1;
        }
        k = k.max(j);
        while k < j + n && pv(k + 1) > pv(k) {
            k += 1;
        }
        m = m.max(k);
        while m < k + n && pu(m + 1) < pu(m) {
            m += 1;
        }
        let area = (pu(j) - pu(m)) * pv(k);
        if area < best.0 * (1.0 - 1e-12) {
            best = (area, u);
        }
    }
    best.1
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::SceneBuilder;
    use crate::scene::builder::white;

    fn unwrap_all(s: &crate::scene::Scene, texel: f64) -> Vec<Vec<LocalChart>> {
        let g = SceneGeometry::new(s);
        s.meshes
            .iter()
            .enumerate()
            .map(|(mi, m)| {
                let tris: Vec<u32> = (g.mesh_offsets[mi]..g.mesh_offsets[mi + 1]).collect();
                unwrap_mesh(m, &g, &tris, texel, 40f32.to_radians())
            })
            .collect()
    }

    fn assert_no_overlap(c: &LocalChart) {
        for i in 0..c.uv.len() {
            for j in i + 1..c.uv.len() {
                assert!(!triangles_overlap(&c.uv[i], &c.uv[j], OVERLAP_TOL), "faces {i} and {j} overlap");
            }
        }
    }

    #[test]
    fn hull_and_min_area_rectangle_of_a_rotated_rectangle() {
        let a = 0.3f64;
        let (u, v) = (DVec2::new(a.cos(), a.sin()), DVec2::new(-a.sin(), a.cos()));
        let mut pts = Vec::new();
        for i in 0..=10 {
            for j in 0..=4 {
                pts.push(u * (i as f64) * 0.5 + v * j as f64);
            }
        }
        // (Float noise may keep a few nearly collinear points on the hull: harmless.)
        let h = convex_hull(&pts);
        assert!(h.len() >= 4);
        let axis = min_area_rect_axis(&h);
        assert!(axis.dot(u).abs() > 1.0 - 1e-9 || axis.dot(v).abs() > 1.0 - 1e-9, "{axis:?}");
        // A regular polygon with many sides: the calipers agree with brute force.
        let poly: Vec<DVec2> = (0..37)
            .map(|i| DVec2::from_angle(i as f64 * 0.17 + (i * i) as f64 * 0.001) * (3.0 + (i % 3) as f64))
            .collect();
        let h = convex_hull(&poly);
        let area_of = |d: DVec2| {
            let e = d.perp();
            let (mut lo, mut hi) = (DVec2::INFINITY, DVec2::NEG_INFINITY);
            for p in &h {
                let q = DVec2::new(p.dot(d), p.dot(e));
                lo = lo.min(q);
                hi = hi.max(q);
            }
            (hi - lo).x * (hi - lo).y
        };
        let brute =
            (0..h.len()).map(|i| area_of((h[(i + 1) % h.len()] - h[i]).normalize())).fold(f64::INFINITY, f64::min);
        assert!((area_of(min_area_rect_axis(&h)) - brute).abs() < 1e-9 * brute);
    }

    #[test]
    fn walls_become_axis_aligned_rectangles() {
        let mut b = SceneBuilder::new();
        let m = b.material(white());
        b.cuboid("room", Vec3::ZERO, Vec3::new(4.0, 2.5, 3.0), true, m);
        // A tessellated, rotated wall: still one chart, a 2 m × 1 m rectangle.
        let (c, s) = (0.6f32.cos(), 0.6f32.sin());
        let (x, z) = (Vec3::new(c, 0.0, s) * 2.0, Vec3::new(-s, 0.0, c));
        b.grid_quad("floor", [Vec3::ZERO, x, x + z, z], 8, m);
        let s = b.build();
        let charts = unwrap_all(&s, 0.1);
        assert_eq!(charts[0].len(), 6);
        let mut ext: Vec<(i64, i64)> =
            charts[0].iter().map(|c| ((c.extent.x * 1e3).round() as i64, (c.extent.y * 1e3).round() as i64)).collect();
        ext.sort();
        assert_eq!(
            ext,
            vec![(30000, 25000), (30000, 25000), (40000, 25000), (40000, 25000), (40000, 30000), (40000, 30000)]
        );
        assert_eq!(charts[1].len(), 1);
        let e = charts[1][0].extent;
        assert!((e.x - 20.0).abs() < 1e-4 && (e.y - 10.0).abs() < 1e-4, "{e:?}");
        assert_eq!(charts[1][0].tris.len(), 128);
        assert_no_overlap(&charts[1][0]);
    }

    #[test]
    fn coplanar_duplicates_and_curled_surfaces_split() {
        let mut b = SceneBuilder::new();
        let m = b.material(white());
        // The same quad twice in one mesh, sharing vertices.
        b.mesh(
            "dup",
            vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 0.0, -1.0), Vec3::new(0.0, 0.0, -1.0)],
            vec![[0, 1, 2], [0, 2, 3], [0, 1, 2], [0, 2, 3]],
            m,
        );
        // A shallow helicoid ramp winding 1.5 turns: normals stay within 40° of each other
        // but the projection overlaps itself.
        let (turns, seg, r0, r1, rise) = (1.5f32, 60, 1.0f32, 2.0f32, 0.8f32);
        let mut pos = Vec::new();
        let mut tris = Vec::new();
        for i in 0..=seg {
            let a = i as f32 / seg as f32 * turns * std::f32::consts::TAU;
            let y = i as f32 / seg as f32 * turns * rise;
            pos.push(Vec3::new(r0 * a.cos(), y, r0 * a.sin()));
            pos.push(Vec3::new(r1 * a.cos(), y, r1 * a.sin()));
        }
        for i in 0..seg as u32 {
            let (a, b2, c, d) = (2 * i, 2 * i + 1, 2 * i + 2, 2 * i + 3);
            tris.push([a, c, b2]);
            tris.push([b2, c, d]);
        }
        b.mesh("ramp", pos, tris, m);
        let s = b.build();
        let charts = unwrap_all(&s, 0.05);
        assert_eq!(charts[0].len(), 2, "a duplicate quad is its own chart");
        assert!(charts[1].len() >= 2, "the ramp overlaps itself: {} chart(s)", charts[1].len());
        for c in charts.iter().flatten() {
            assert_no_overlap(c);
        }
        let total: usize = charts[1].iter().map(|c| c.tris.len()).sum();
        assert_eq!(total, 120);
    }

    #[test]
    fn degenerate_faces_get_their_own_chart() {
        let mut b = SceneBuilder::new();
        let m = b.material(white());
        b.mesh(
            "m",
            vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 0.0, -1.0), Vec3::new(0.5, 0.0, 1e-9)],
            vec![[0, 1, 2], [0, 3, 1]],
            m,
        );
        let s = b.build();
        let charts = unwrap_all(&s, 0.1);
        assert_eq!(charts[0].len(), 2);
        assert!(charts[0].iter().all(|c| c.extent.is_finite()));
    }
}
