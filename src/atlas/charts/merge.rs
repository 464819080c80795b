//! Step 3 of the unwrapper: merging thin charts into their neighbours by rigid hinges.

use std::collections::BinaryHeap;

use glam::DVec2;

use crate::atlas::pack::axis_placement;
use crate::atlas::raster::triangles_overlap;

use super::face_grid::{FaceGrid, Visited, bounds};
use super::faces::{MeshFaces, coarse};
use super::finish::{convex_hull, min_area_rect_axis};
use super::weld::FxMap;
use super::{MERGE_CLEARANCE, OVERLAP_TOL};

/// The packer's rectangle for a chart whose convex hull is `hull` (LOD-0 texels of the hint):
/// its area, border included, and its shorter interior side.
fn rect_cost(hull: &[DVec2]) -> (f64, u32) {
    let u = min_area_rect_axis(hull);
    let v = u.perp();
    let (mut lo, mut hi) = (DVec2::INFINITY, DVec2::NEG_INFINITY);
    for p in hull {
        let q = DVec2::new(p.dot(u), p.dot(v));
        lo = lo.min(q);
        hi = hi.max(q);
    }
    let e = if lo.x <= hi.x { hi - lo } else { DVec2::ZERO };
    match (axis_placement(e.x), axis_placement(e.y)) {
        (Some((nx, _)), Some((ny, _))) => {
            let b = 2 * crate::atlas::pack::BORDER;
            ((nx + b) as f64 * (ny + b) as f64, nx.min(ny))
        }
        _ => (f64::INFINITY, u32::MAX),
    }
}

/// A rigid motion of the plane, possibly mirrored: `p ↦ o + R(p − c)`, with `R` a rotation
/// by the angle of `rot` (unit complex number), after a reflection across x when `mirror`.
#[derive(Clone, Copy)]
struct Rigid {
    c: DVec2,
    rot: DVec2,
    mirror: bool,
    o: DVec2,
}

impl Rigid {
    fn apply(&self, p: DVec2) -> DVec2 {
        let mut d = p - self.c;
        if self.mirror {
            d.y = -d.y;
        }
        self.o + self.rot.rotate(d)
    }
}

/// One shared welded edge between two charts: the face on each side (`a` in the chart that
/// moves) and the edge's welded endpoints.
#[derive(Clone, Copy, Debug)]
struct Hinge {
    a: u32,
    b: u32,
    v: [u32; 2],
    len2: f64,
}

impl Hinge {
    /// The longer edge ([`coarse`] lengths; ties: the lower face pair).
    fn longer_than(&self, o: &Hinge) -> bool {
        (coarse(self.len2), std::cmp::Reverse((self.a, self.b))) > (coarse(o.len2), std::cmp::Reverse((o.a, o.b)))
    }
}

/// The hinge moving face `h.a`'s chart so that its copy of the edge lies on face `h.b`'s,
/// unfolded (the moved face on the other side of the edge); `None` for a zero-length edge.
fn hinge_motion(faces: &MeshFaces, uv: &[[DVec2; 3]], h: &Hinge) -> Option<Rigid> {
    let at = |f: u32, v: u32| {
        let k = faces.corners[f as usize].iter().position(|&c| c == v)?;
        Some(uv[f as usize][k])
    };
    let third = |f: u32| {
        let k = faces.corners[f as usize].iter().position(|c| !h.v.contains(c))?;
        Some(uv[f as usize][k])
    };
    let (a0, a1, b0, b1) = (at(h.a, h.v[0])?, at(h.a, h.v[1])?, at(h.b, h.v[0])?, at(h.b, h.v[1])?);
    let (da, db) = ((a1 - a0).try_normalize()?, (b1 - b0).try_normalize()?);
    let (ca, cb) = ((a0 + a1) * 0.5, (b0 + b1) * 0.5);
    let (pa, pb) = (third(h.a)?, third(h.b)?);
    for mirror in [false, true] {
        let d = if mirror { DVec2::new(da.x, -da.y) } else { da };
        // Rotation taking d onto db: db · conj(d).
        let rot = DVec2::new(db.x * d.x + db.y * d.y, db.y * d.x - db.x * d.y);
        let m = Rigid { c: ca, rot, mirror, o: cb };
        if (db).perp_dot(m.apply(pa) - cb) * db.perp_dot(pb - cb) < 0.0 {
            return Some(m);
        }
    }
    None
}

/// A chart during merging.
struct Cluster {
    faces: Vec<u32>,
    hull: Vec<DVec2>,
    /// Its rectangle's area and shorter interior side ([`rect_cost`]).
    cost: f64,
    short_side: u32,
    /// Neighbouring clusters: the longest shared edge with each.
    links: FxMap<u32, Hinge>,
    /// Bumped on every merge, to drop stale candidates.
    version: u32,
    alive: bool,
}

/// Only charts whose rectangle's shorter interior side is at most this many texels (at the
/// hint) are moved by merges: such a chart pays at least half its texels again in border, while
/// a hinge across a hard edge shares texels between the two sides of the edge along it (one
/// texel either side) — a price worth paying only where the border costs more.
pub const MOVABLE_SIDE: u32 = 4;

/// Merges whose two charts have at most this many face pairs are tested pair by pair; larger
/// ones through a grid of the target chart, kept between merges.
const BRUTE_FORCE_PAIRS: usize = 2048;

/// Step 3 of the [unwrapper](super): the charts left (face lists, increasing), each with
/// its index in `charts` (a merged chart keeps the index of the chart the other moved into).
pub(super) fn merge(
    faces: &MeshFaces,
    charts: Vec<Vec<u32>>,
    uv: &mut [[DVec2; 3]],
    seen: &mut Visited,
) -> Vec<(usize, Vec<u32>)> {
    // The charts' faces: whole edge-connected components of the mesh, the only faces read.
    let mut subset: Vec<u32> = charts.iter().flatten().copied().collect();
    subset.sort_unstable();
    let mut chart_of = vec![0u32; faces.len()];
    for (c, members) in charts.iter().enumerate() {
        for &f in members {
            chart_of[f as usize] = c as u32;
        }
    }
    let mut clusters: Vec<Cluster> = charts
        .into_iter()
        .map(|members| {
            let pts: Vec<DVec2> = members.iter().flat_map(|&f| uv[f as usize]).collect();
            let hull = convex_hull(&pts);
            let (cost, short_side) = rect_cost(&hull);
            Cluster { faces: members, hull, cost, short_side, links: FxMap::default(), version: 0, alive: true }
        })
        .collect();
    if clusters.len() < 2 {
        return clusters.into_iter().map(|c| c.faces).enumerate().collect();
    }
    for &f in &subset {
        for &g in faces.neighbours(f) {
            let (cf, cg) = (chart_of[f as usize], chart_of[g as usize]);
            if cf == cg {
                continue;
            }
            let [x, y, z] = faces.corners[f as usize];
            let shared: Vec<u32> = [x, y, z].into_iter().filter(|v| faces.corners[g as usize].contains(v)).collect();
            if shared.len() < 2 {
                continue;
            }
            let v = [shared[0].min(shared[1]), shared[0].max(shared[1])];
            let k = faces.corners[f as usize].iter().position(|&c| c == v[0]).unwrap_or(0);
            let l = faces.corners[f as usize].iter().position(|&c| c == v[1]).unwrap_or(0);
            let len2 = faces.pos[f as usize][k].distance_squared(faces.pos[f as usize][l]);
            let h = Hinge { a: f, b: g, v, len2 };
            let e = clusters[cf as usize].links.entry(cg).or_insert(h);
            if h.longer_than(e) {
                *e = h;
            }
        }
    }

    // Candidates, best gain first (ties: the pair with the smaller ids), with the versions of
    // both clusters they were computed for.
    struct Candidate {
        gain: f64,
        pair: (u32, u32),
        moving: u32,
        into: u32,
        versions: (u32, u32),
        /// Convex hull of the merged chart (in the target's frame), once exact.
        hull: Vec<DVec2>,
        /// Whether `gain` is the gain (else a bound of it).
        exact: bool,
    }
    impl Ord for Candidate {
        fn cmp(&self, o: &Self) -> std::cmp::Ordering {
            self.gain.total_cmp(&o.gain).then(o.pair.cmp(&self.pair)).then(o.versions.cmp(&self.versions))
        }
    }
    impl PartialOrd for Candidate {
        fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
            Some(self.cmp(o))
        }
    }
    impl PartialEq for Candidate {
        fn eq(&self, o: &Self) -> bool {
            self.cmp(o).is_eq()
        }
    }
    impl Eq for Candidate {}
    // Moves one of `x` and `y` into the other: the one with the smaller rectangle (ties: the
    // higher id) if it is thin enough, else the other if that one is.
    // A candidate first enters the heap with a bound of its gain: the merged rectangle holds
    // the larger of the two, so the gain is at most the smaller's cost. Only when it comes
    // out on top is the gain worked out (hinge, merged hull, rectangle) and the candidate put
    // back exact: candidates made stale by other merges before their turn cost nothing.
    let propose = |clusters: &[Cluster], x: u32, y: u32| -> Option<Candidate> {
        let (cx, cy) = (&clusters[x as usize], &clusters[y as usize]);
        let x_first = (cx.cost, std::cmp::Reverse(x)) < (cy.cost, std::cmp::Reverse(y));
        let order = if x_first { [(x, y), (y, x)] } else { [(y, x), (x, y)] };
        let (moving, into) = order.into_iter().find(|&(m, _)| clusters[m as usize].short_side <= MOVABLE_SIDE)?;
        let (cm, ci) = (&clusters[moving as usize], &clusters[into as usize]);
        Some(Candidate {
            gain: cm.cost.min(ci.cost),
            pair: (x.min(y), x.max(y)),
            moving,
            into,
            versions: (cm.version, ci.version),
            hull: Vec::new(),
            exact: false,
        })
    };
    let evaluate = |clusters: &[Cluster], uv: &[[DVec2; 3]], c: Candidate| -> Option<Candidate> {
        let (cm, ci) = (&clusters[c.moving as usize], &clusters[c.into as usize]);
        let link = ci.links.get(&c.moving)?;
        let hinge = Hinge { a: link.b, b: link.a, v: link.v, len2: link.len2 };
        let m = hinge_motion(faces, uv, &hinge)?;
        let mut pts: Vec<DVec2> = cm.hull.iter().map(|&p| m.apply(p)).collect();
        pts.extend_from_slice(&ci.hull);
        let hull = convex_hull(&pts);
        let gain = cm.cost + ci.cost - rect_cost(&hull).0;
        (gain > 0.0).then_some(Candidate { gain, hull, exact: true, ..c })
    };
    let mut heap = BinaryHeap::new();
    for x in 0..clusters.len() as u32 {
        let mut ns: Vec<u32> = clusters[x as usize].links.keys().copied().filter(|&y| y > x).collect();
        ns.sort_unstable();
        for y in ns {
            if let Some(c) = propose(&clusters, x, y) {
                heap.push(c);
            }
        }
    }

    let mut grids: FxMap<u32, FaceGrid> = FxMap::default();
    let clearance = MERGE_CLEARANCE;
    while let Some(cand) = heap.pop() {
        let (m, i) = (cand.moving as usize, cand.into as usize);
        if !clusters[m].alive || !clusters[i].alive || (clusters[m].version, clusters[i].version) != cand.versions {
            continue;
        }
        if !cand.exact {
            if let Some(c) = evaluate(&clusters, uv, cand) {
                heap.push(c);
            }
            continue;
        }
        let link = clusters[i].links[&cand.moving];
        let Some(motion) = hinge_motion(faces, uv, &Hinge { a: link.b, b: link.a, v: link.v, len2: link.len2 }) else {
            continue;
        };
        let moved: Vec<[DVec2; 3]> =
            clusters[m].faces.iter().map(|&f| uv[f as usize].map(|p| motion.apply(p))).collect();
        // Near in UV (within the clearance) is a conflict for faces apart on the surface;
        // for the others only an overlap is.
        let conflict = |f: u32, t: &[DVec2; 3], g: u32| {
            let tol = if faces.box_distance(f, g) > clearance { -clearance } else { OVERLAP_TOL };
            triangles_overlap(t, &uv[g as usize], tol)
        };
        let r = DVec2::splat(clearance);
        let blocked = if clusters[m].faces.len() * clusters[i].faces.len() <= BRUTE_FORCE_PAIRS {
            // Small pairs: every pair whose boxes (grown by the clearance) meet.
            let target: Vec<(u32, DVec2, DVec2)> = clusters[i]
                .faces
                .iter()
                .map(|&g| {
                    let (lo, hi) = bounds(&uv[g as usize]);
                    (g, lo - r, hi + r)
                })
                .collect();
            clusters[m].faces.iter().zip(&moved).any(|(&f, t)| {
                let (lo, hi) = bounds(t);
                target
                    .iter()
                    .any(|&(g, l, h)| lo.x < h.x && l.x < hi.x && lo.y < h.y && l.y < hi.y && conflict(f, t, g))
            })
        } else {
            // The target's grid, built on first use and kept up to date.
            let grid = grids.entry(cand.into).or_insert_with(|| {
                let mut g = FaceGrid::new(faces.cell);
                for &f in &clusters[i].faces {
                    g.insert(f, &uv[f as usize]);
                }
                g
            });
            clusters[m].faces.iter().zip(&moved).any(|(&f, t)| {
                let (lo, hi) = bounds(t);
                grid.any(lo - r, hi + r, seen, |g| conflict(f, t, g))
            })
        };
        if blocked {
            // Never retried with these versions.
            continue;
        }
        // Merge m into i.
        for (&f, t) in clusters[m].faces.iter().zip(&moved) {
            uv[f as usize] = *t;
        }
        if let Some(g) = grids.get_mut(&cand.into) {
            for &f in &clusters[m].faces {
                g.insert(f, &uv[f as usize]);
            }
        }
        grids.remove(&cand.moving);
        let moved_faces = std::mem::take(&mut clusters[m].faces);
        let links = std::mem::take(&mut clusters[m].links);
        clusters[m].alive = false;
        let ci = &mut clusters[i];
        ci.faces.extend(moved_faces);
        ci.hull = cand.hull;
        (ci.cost, ci.short_side) = rect_cost(&ci.hull);
        ci.version += 1;
        ci.links.remove(&cand.moving);
        for (k, h) in links {
            if k == cand.into {
                continue;
            }
            // The moved chart's link to k now belongs to i (its faces moved with it).
            let e = ci.links.entry(k).or_insert(h);
            if h.longer_than(e) {
                *e = h;
            }
        }
        let mut ns: Vec<u32> = clusters[i].links.keys().copied().collect();
        ns.sort_unstable();
        for k in ns {
            let back = clusters[i].links[&k];
            let kc = &mut clusters[k as usize];
            kc.links.remove(&cand.moving);
            let flipped = Hinge { a: back.b, b: back.a, v: back.v, len2: back.len2 };
            kc.links.insert(cand.into, flipped);
            if let Some(c) = propose(&clusters, cand.into, k) {
                heap.push(c);
            }
        }
    }
    clusters
        .into_iter()
        .enumerate()
        .filter(|(_, c)| c.alive)
        .map(|(i, mut c)| {
            c.faces.sort_unstable();
            (i, c.faces)
        })
        .collect()
}
