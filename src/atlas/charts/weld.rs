//! Step 1 of the unwrapper: welding vertices within a tolerance, and the edge adjacency of
//! the welded faces.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use glam::{DVec3, Vec3};

use crate::atlas::raster::floor_i64;

/// Small fast hasher for integer keys (deterministic; no new dependency).
#[derive(Default)]
pub(crate) struct FxHasher(u64);

impl Hasher for FxHasher {
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(b as u64);
        }
    }
    fn write_u32(&mut self, x: u32) {
        self.write_u64(x as u64);
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

/// Distance (metres) under which two vertices of `positions` are one vertex for charting:
/// 10⁻⁴ of the bounding-box diagonal, at most 10⁻³ of `texel` (so a welded corner moves the
/// face's UVs by less than a thousandth of a texel), at least 16 ulps of the largest
/// coordinate (the noise of f32 world transforms).
pub fn weld_tolerance(positions: &[Vec3], texel: f64) -> f64 {
    let (mut lo, mut hi, mut big) = (DVec3::INFINITY, DVec3::NEG_INFINITY, 0f64);
    for p in positions.iter().filter(|p| p.is_finite()) {
        let p = p.as_dvec3();
        lo = lo.min(p);
        hi = hi.max(p);
        big = big.max(p.abs().max_element());
    }
    let diag = if lo.x <= hi.x { (hi - lo).length() } else { 0.0 };
    let noise = big * f32::EPSILON as f64 * 16.0;
    (1e-4 * diag).min(1e-3 * texel).max(noise)
}

/// Welds vertices within `tol` of each other (transitively). Returns the welded id of every
/// vertex (ids in order of each class's lowest vertex index) and one representative position
/// per id (that of its lowest-index vertex). `tol = 0` welds identical positions only.
pub(crate) fn weld(positions: &[Vec3], tol: f64) -> (Vec<u32>, Vec<DVec3>) {
    let n = positions.len();
    // Cells four tolerances wide: a ball of radius `tol` meets at most two cells per axis.
    let cell = if tol > 0.0 { 4.0 * tol } else { 1.0 };
    let key = |p: DVec3| {
        let q = p / cell;
        (floor_i64(q.x), floor_i64(q.y), floor_i64(q.z))
    };
    let pos: Vec<DVec3> = positions.iter().map(|p| p.as_dvec3()).collect();
    let keys: Vec<(i64, i64, i64)> =
        pos.iter().map(|&p| if p.is_finite() { key(p) } else { (i64::MIN, 0, 0) }).collect();
    let mut order: Vec<u32> = (0..n as u32).collect();
    order.sort_unstable_by_key(|&i| (keys[i as usize], i));
    let mut cells: FxMap<(i64, i64, i64), (u32, u32)> = FxMap::default();
    let mut s = 0;
    while s < n {
        let k = keys[order[s] as usize];
        let mut e = s + 1;
        while e < n && keys[order[e] as usize] == k {
            e += 1;
        }
        cells.insert(k, (s as u32, e as u32));
        s = e;
    }
    let mut parent: Vec<u32> = (0..n as u32).collect();
    let tol2 = tol * tol;
    for i in 0..n {
        let p = pos[i];
        if !p.is_finite() {
            continue;
        }
        let k = keys[i];
        let f = p / cell - DVec3::new(k.0 as f64, k.1 as f64, k.2 as f64);
        let r = tol / cell;
        let span = |f: f64| (if f < r { -1 } else { 0 }, if f > 1.0 - r { 1 } else { 0 });
        let (sx, sy, sz) = (span(f.x), span(f.y), span(f.z));
        for dz in sz.0..=sz.1 {
            for dy in sy.0..=sy.1 {
                for dx in sx.0..=sx.1 {
                    let Some(&(a, b)) = cells.get(&(k.0 + dx, k.1 + dy, k.2 + dz)) else { continue };
                    for &j in &order[a as usize..b as usize] {
                        if j as usize > i && pos[j as usize].distance_squared(p) <= tol2 {
                            let (ri, rj) = (root(&mut parent, i as u32), root(&mut parent, j));
                            // The lower index is the root: the class's representative.
                            if ri != rj {
                                parent[ri.max(rj) as usize] = ri.min(rj);
                            }
                        }
                    }
                }
            }
        }
    }
    let mut id = vec![u32::MAX; n];
    let mut reps = Vec::new();
    for i in 0..n {
        let r = root(&mut parent, i as u32) as usize;
        if id[r] == u32::MAX {
            id[r] = reps.len() as u32;
            reps.push(pos[r]);
        }
        id[i] = id[r];
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

/// The root of `i`'s set in a union-find forest (`parent[r] == r` at a root), halving the
/// path on the way.
pub(super) fn root(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        let g = parent[parent[i as usize] as usize];
        parent[i as usize] = g;
        i = g;
    }
    i
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Vertices within the tolerance weld whichever side of a grid line they fall on, also
    /// through a chain; farther ones do not.
    #[test]
    fn welding_is_by_distance_not_by_grid_cell() {
        let tol = 1e-3;
        // The weld grid has cells of 4·tol: 0.004 is on a cell boundary.
        let p = [
            Vec3::new(0.0039995, 0.0, 0.0),
            Vec3::new(0.0040005, 0.0, 0.0),
            Vec3::new(0.0049, 0.0, 0.0),
            Vec3::new(0.0070, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        let (id, reps) = weld(&p, tol);
        assert_eq!(id, vec![0, 0, 0, 1, 2, 2]);
        assert_eq!(reps.len(), 3);
        assert_eq!(reps[0], p[0].as_dvec3(), "the lowest index represents its class");
        // The tolerance follows the mesh and the texel size, not below float noise.
        let big = [Vec3::ZERO, Vec3::splat(100.0)];
        assert!((weld_tolerance(&big, 0.5) - 5e-4).abs() < 1e-12, "10⁻³ texel");
        assert!((weld_tolerance(&[Vec3::ZERO, Vec3::splat(0.1)], 0.5) - 1.7320508e-5).abs() < 1e-9, "10⁻⁴ diagonal");
        let far = [Vec3::splat(1e5), Vec3::splat(1e5 + 1e-3)];
        assert!(weld_tolerance(&far, 1e-3) >= 1e5 * f32::EPSILON as f64 * 16.0);
    }
}
