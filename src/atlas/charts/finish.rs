//! Step 4 of the unwrapper: the minimum-area bounding rectangle, at the origin.

use glam::DVec2;

use crate::scene::TriangleId;

use super::LocalChart;

/// Rotates a chart (UVs in texels of `texel`) to its minimum-area bounding rectangle (long
/// side along x), moves it to the origin and converts it to metres.
pub(super) fn finish(members: &[u32], uv: &[[DVec2; 3]], tris: &[TriangleId], texel: f64) -> LocalChart {
    let mut uv: Vec<[DVec2; 3]> = members.iter().map(|&f| uv[f as usize]).collect();
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
            *p = if swap { DVec2::new(q.y, extent.x - q.x) } else { q } * texel;
        }
    }
    if swap {
        extent = DVec2::new(extent.y, extent.x);
    }
    LocalChart {
        tris: members.iter().map(|&f| tris[f as usize]).collect(),
        uv,
        extent: extent * texel,
        fixed_interior: None,
    }
}

/// Convex hull (Andrew's monotone chain), counter-clockwise, without collinear points nor
/// points within 10⁻⁹ of the edges' length of the segment between their neighbours (float
/// noise along a straight chart edge would otherwise keep every vertex on it).
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
    if hull.len() < 3 {
        return vec![p[0], p[p.len() - 1]];
    }
    // Drop vertices lying (up to noise) on the segment between their neighbours.
    let mut k = 0;
    while hull.len() > 3 && k < hull.len() {
        let n = hull.len();
        let (a, v, b) = (hull[(k + n - 1) % n], hull[k], hull[(k + 1) % n]);
        let (u, w) = (v - a, b - v);
        if u.perp_dot(w).abs() <= 1e-9 * (u.length_squared() + w.length_squared()) && u.dot(w) > 0.0 {
            hull.remove(k);
        } else {
            k += 1;
        }
    }
    hull
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
}
