//! Per-triangle geometric kernels: the watertight ray–triangle test (Woop, Benthin & Wald,
//! "Watertight Ray/Triangle Intersection", JCGT 2013) and the closest point on a triangle
//! (Ericson, "Real-Time Collision Detection", 5.1.5).
//!
//! Watertightness: both triangles that share an edge compute that edge's 2D edge function
//! from the same sheared vertex coordinates with the operands swapped, so the two values are
//! exact negatives of each other (floating-point products are commutative and
//! `a − b = −(b − a)` exactly). A ray therefore can never pass between two triangles that
//! share an edge. When an edge function is exactly 0 (ray through an edge or vertex) it is
//! recomputed in f64, as the paper prescribes. Both faces are hit (sidedness is the
//! tracer's business), so the paper's swap of kx/ky for a negative dominant component is
//! not needed: we accept U, V, W all ≥ 0 or all ≤ 0.

use glam::{Vec3, Vec3A};

/// Per-ray constants of the watertight test for a ray whose dominant axis is `KZ`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Shear {
    pub sx: f32,
    pub sy: f32,
    pub sz: f32,
}

/// The two axes following `kz` cyclically.
#[inline(always)]
pub(crate) const fn axes(kz: usize) -> (usize, usize) {
    let kx = (kz + 1) % 3;
    (kx, (kx + 1) % 3)
}

/// Index of the largest-magnitude component of `d`.
#[inline]
pub(crate) fn dominant_axis(d: Vec3A) -> usize {
    let a = d.abs();
    if a.x >= a.y && a.x >= a.z {
        0
    } else if a.y >= a.z {
        1
    } else {
        2
    }
}

#[inline(always)]
fn at(v: Vec3A, k: usize) -> f32 {
    match k {
        0 => v.x,
        1 => v.y,
        _ => v.z,
    }
}

impl Shear {
    #[inline]
    pub fn new<const KZ: usize>(d: Vec3A) -> Shear {
        let (kx, ky) = axes(KZ);
        let dz = at(d, KZ);
        Shear { sx: at(d, kx) / dz, sy: at(d, ky) / dz, sz: 1.0 / dz }
    }
}

/// Watertight intersection of the ray `o + t·d` (with [`Shear`] precomputed from `d`) with
/// triangle `tri`. Returns `(t, u, v)` for `tmin < t < tmax`, with (u, v) the weights of
/// corners 1 and 2. Hits either face.
#[inline(always)]
pub(crate) fn intersect<const KZ: usize>(
    o: Vec3A,
    s: &Shear,
    tri: &[Vec3A; 3],
    tmin: f32,
    tmax: f32,
) -> Option<(f32, f32, f32)> {
    let (kx, ky) = axes(KZ);
    let a = tri[0] - o;
    let b = tri[1] - o;
    let c = tri[2] - o;
    let (az, bz, cz) = (at(a, KZ), at(b, KZ), at(c, KZ));
    let ax = at(a, kx) - s.sx * az;
    let ay = at(a, ky) - s.sy * az;
    let bx = at(b, kx) - s.sx * bz;
    let by = at(b, ky) - s.sy * bz;
    let cx = at(c, kx) - s.sx * cz;
    let cy = at(c, ky) - s.sy * cz;
    let mut u = cx * by - cy * bx;
    let mut v = ax * cy - ay * cx;
    let mut w = bx * ay - by * ax;
    if u == 0.0 || v == 0.0 || w == 0.0 {
        let (ax, ay, bx, by, cx, cy) = (ax as f64, ay as f64, bx as f64, by as f64, cx as f64, cy as f64);
        u = (cx * by - cy * bx) as f32;
        v = (ax * cy - ay * cx) as f32;
        w = (bx * ay - by * ax) as f32;
    }
    if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
        return None;
    }
    let det = u + v + w;
    if det == 0.0 {
        return None;
    }
    let inv = 1.0 / det;
    let t = s.sz * (u * az + v * bz + w * cz) * inv;
    // NaN fails both comparisons.
    if t > tmin && t < tmax { Some((t, v * inv, w * inv)) } else { None }
}

/// Closest point to `p` on triangle (a, b, c): `(point, u, v)` with (u, v) the weights of
/// b and c.
pub(crate) fn closest_point(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> (Vec3, f32, f32) {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return (a, 0.0, 0.0);
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return (b, 1.0, 0.0);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let t = d1 / (d1 - d3);
        return (a + ab * t, t, 0.0);
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return (c, 0.0, 1.0);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let t = d2 / (d2 - d6);
        return (a + ac * t, 0.0, t);
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let t = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (b + (c - b) * t, 1.0 - t, t);
    }
    let denom = 1.0 / (va + vb + vc);
    let v = vb * denom;
    let w = vc * denom;
    (a + ab * v + ac * w, v, w)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hit(o: Vec3, d: Vec3, tri: [Vec3; 3]) -> Option<(f32, f32, f32)> {
        let d = Vec3A::from(d);
        let t = tri.map(Vec3A::from);
        match dominant_axis(d) {
            0 => intersect::<0>(o.into(), &Shear::new::<0>(d), &t, 0.0, f32::INFINITY),
            1 => intersect::<1>(o.into(), &Shear::new::<1>(d), &t, 0.0, f32::INFINITY),
            _ => intersect::<2>(o.into(), &Shear::new::<2>(d), &t, 0.0, f32::INFINITY),
        }
    }

    #[test]
    fn hits_both_faces_with_the_right_barycentrics() {
        let tri = [Vec3::ZERO, Vec3::X, Vec3::Y];
        for (o, d) in [(Vec3::new(0.2, 0.3, 1.0), -Vec3::Z), (Vec3::new(0.2, 0.3, -2.0), Vec3::Z)] {
            let (t, u, v) = hit(o, d, tri).unwrap();
            assert!((t - o.z.abs()).abs() < 1e-6);
            assert!((u - 0.2).abs() < 1e-6 && (v - 0.3).abs() < 1e-6);
        }
        assert!(hit(Vec3::new(0.8, 0.8, 1.0), -Vec3::Z, tri).is_none());
        assert!(hit(Vec3::new(0.2, 0.3, 1.0), Vec3::Z, tri).is_none(), "behind the origin");
    }

    #[test]
    fn closest_point_regions() {
        let (a, b, c) = (Vec3::ZERO, Vec3::X, Vec3::Y);
        let (q, u, v) = closest_point(Vec3::new(0.25, 0.25, 3.0), a, b, c);
        assert!((q - Vec3::new(0.25, 0.25, 0.0)).length() < 1e-6 && (u - 0.25).abs() < 1e-6 && (v - 0.25).abs() < 1e-6);
        assert_eq!(closest_point(Vec3::new(-1.0, -1.0, 0.0), a, b, c).0, a);
        assert_eq!(closest_point(Vec3::new(2.0, -0.5, 0.0), a, b, c).0, b);
        let (q, u, v) = closest_point(Vec3::new(1.0, 1.0, 0.0), a, b, c);
        assert!((q - Vec3::new(0.5, 0.5, 0.0)).length() < 1e-6 && (u - 0.5).abs() < 1e-6 && (v - 0.5).abs() < 1e-6);
    }
}
