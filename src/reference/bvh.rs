//! Bounding-volume hierarchy over the triangles of a [`SceneGeometry`]: binned-SAH BVH2 with
//! flattened 64-byte nodes (both child boxes per node, tested with one SIMD slab test) and
//! triangles copied in leaf order for the watertight test.
//!
//! Queries: closest hit ([`Bvh::intersect`], front-to-back), any hit ([`Bvh::occluded`]),
//! light passing through see-through surfaces ([`Bvh::transmittance`]) and
//! nearest surface point ([`Bvh::closest_point`]). Pure: no scene borrow, `Send + Sync`,
//! reusable by the baker and the probe command.
//!
//! Robustness: triangles use the watertight test of `super::triangle`; box exits are scaled
//! by `1 + 2γ₃` (Ize, "Robust BVH Ray Traversal", JCGT 2013) so rounding never culls a box the
//! ray touches, including the zero-thickness boxes of axis-aligned walls.

use glam::{Vec3, Vec3A, Vec4, Vec4Swizzles};

use super::alpha::AlphaMasks;
use super::bvh_build::{self, Aabb, COUNT_MASK, LEAF, MASKED, MAX_TREE_DEPTH, Node};
use super::triangle::{self, Shear};
use crate::scene::{Rgb, Scene, SceneGeometry, TriangleId};

/// A ray's closest intersection: parametric distance `t` (in units of the direction's
/// length), the triangle and the barycentric weights (u, v) of its corners 1 and 2.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f32,
    pub tri: TriangleId,
    pub u: f32,
    pub v: f32,
}

/// The surface point nearest to a query point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Nearest {
    pub tri: TriangleId,
    pub point: Vec3,
    pub u: f32,
    pub v: f32,
    pub distance: f32,
}

/// `1 + 2γ₃` with γₙ = nε/(1 − nε), ε = 2⁻²⁴ (Ize 2013).
const ROBUST_EXIT: f32 = 1.0 + 2.0 * (3.0 * f32::EPSILON * 0.5) / (1.0 - 3.0 * f32::EPSILON * 0.5);
const STACK: usize = MAX_TREE_DEPTH + 4;
/// See-through surfaces a shadow ray crosses before it counts as blocked (the Mitsuba
/// cross-check's limit).
pub const MAX_CROSSINGS: usize = 64;

/// See the [module docs](self).
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    nodes: Vec<Node>,
    /// Triangle corners in leaf order.
    tris: Vec<[Vec3A; 3]>,
    /// Leaf order → original [`TriangleId`].
    ids: Vec<TriangleId>,
    alpha: AlphaMasks,
    bounds: Option<(Vec3, Vec3)>,
}

/// Per-ray constants of the traversal.
struct Ray {
    o: Vec3A,
    o4: [Vec4; 3],
    inv4: [Vec4; 3],
    shear: Shear,
}

impl Ray {
    #[inline(always)]
    fn new<const KZ: usize>(o: Vec3, d: Vec3) -> Ray {
        // A zero component would give ∞ · 0 = NaN in the slab test: nudge it (the box test is
        // conservative anyway; the triangle test uses the exact direction).
        let safe = |x: f32| if x.abs() < 1e-30 { 1e30f32.copysign(x) } else { 1.0 / x };
        Ray {
            o: o.into(),
            o4: [Vec4::splat(o.x), Vec4::splat(o.y), Vec4::splat(o.z)],
            inv4: [Vec4::splat(safe(d.x)), Vec4::splat(safe(d.y)), Vec4::splat(safe(d.z))],
            shear: Shear::new::<KZ>(d.into()),
        }
    }

    /// Entry distances of both children (lanes 0, 1) and a 2-bit mask of the boxes hit
    /// within (tmin, tmax).
    #[inline(always)]
    fn test_children(&self, n: &Node, tmin: f32, tmax: f32) -> (Vec4, u32) {
        let tx = (n.x - self.o4[0]) * self.inv4[0];
        let ty = (n.y - self.o4[1]) * self.inv4[1];
        let tz = (n.z - self.o4[2]) * self.inv4[2];
        let (sx, sy, sz) = (tx.zwxy(), ty.zwxy(), tz.zwxy());
        let near = tx.min(sx).max(ty.min(sy)).max(tz.min(sz).max(Vec4::splat(tmin)));
        let far = (tx.max(sx).min(ty.max(sy)).min(tz.max(sz)) * ROBUST_EXIT).min(Vec4::splat(tmax));
        (near, near.cmple(far).bitmask() & 3)
    }
}

/// A pending subtree on the traversal stack.
#[derive(Clone, Copy, Default)]
struct Entry {
    child: u32,
    meta: u32,
    near: f32,
}

impl Bvh {
    /// A BVH over `geom` with every triangle opaque.
    pub fn new(geom: &SceneGeometry) -> Bvh {
        Self::build(geom, AlphaMasks::default())
    }

    /// A BVH over `geom` (built from `scene`) that cuts out alpha-masked materials.
    pub fn for_scene(scene: &Scene, geom: &SceneGeometry) -> Bvh {
        Self::build(geom, AlphaMasks::new(scene, geom))
    }

    fn build(geom: &SceneGeometry, alpha: AlphaMasks) -> Bvh {
        let boxes: Vec<Aabb> = geom
            .corners
            .iter()
            .map(|c| {
                let mut b = Aabb::EMPTY;
                c.iter().for_each(|&p| b.grow_point(p.into()));
                b
            })
            .collect();
        let centroids: Vec<Vec3A> = boxes.iter().map(|b| (b.min + b.max) * 0.5).collect();
        let built = bvh_build::build(&boxes, &centroids);
        let tris = built.order.iter().map(|&i| geom.corners[i as usize].map(Vec3A::from)).collect();
        let bounds = boxes.iter().fold(None, |acc: Option<(Vec3, Vec3)>, b| {
            let (lo, hi) = (Vec3::from(b.min), Vec3::from(b.max));
            Some(acc.map_or((lo, hi), |(a, c)| (a.min(lo), c.max(hi))))
        });
        let mut bvh = Bvh { nodes: built.nodes, tris, ids: built.order, alpha, bounds };
        bvh.flag_masked_leaves();
        bvh
    }

    fn flag_masked_leaves(&mut self) {
        if self.alpha.is_empty() {
            return;
        }
        for node in &mut self.nodes {
            for k in 0..2 {
                if node.meta[k] & LEAF == 0 {
                    continue;
                }
                let first = node.child[k] as usize;
                let count = (node.meta[k] & COUNT_MASK) as usize;
                if self.ids[first..first + count].iter().any(|&t| self.alpha.is_masked(t)) {
                    node.meta[k] |= MASKED;
                }
            }
        }
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.tris.len()
    }

    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Bytes held by nodes and leaf-ordered triangles.
    pub fn memory_bytes(&self) -> usize {
        self.nodes.len() * size_of::<Node>() + self.tris.len() * (size_of::<[Vec3A; 3]>() + 4)
    }

    /// World bounds of all triangles (`None` when empty).
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        self.bounds
    }

    /// The alpha-mask data (cut-out test for a triangle at barycentrics).
    pub fn alpha(&self) -> &AlphaMasks {
        &self.alpha
    }

    /// Closest intersection of the ray `origin + t·dir` with `tmin < t < tmax`, seen from
    /// either face; alpha-masked triangles are skipped where cut out. `dir` need not be
    /// unit length (t is in units of its length) but must not be zero.
    pub fn intersect(&self, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
        match triangle::dominant_axis(dir.into()) {
            0 => self.closest::<0>(&Ray::new::<0>(origin, dir), tmin, tmax),
            1 => self.closest::<1>(&Ray::new::<1>(origin, dir), tmin, tmax),
            _ => self.closest::<2>(&Ray::new::<2>(origin, dir), tmin, tmax),
        }
    }

    /// The fraction of light (per channel) that passes along the ray `origin + t·dir` with
    /// `0 < t < tmax`: the product of the [`Sheet::pass`](crate::scene::Sheet) of every
    /// see-through surface crossed, 0 at the first surface that is not. Successive
    /// crossings are looked for from `step` past the last one (the scene's ray offset ε),
    /// at most [`MAX_CROSSINGS`] of them (as the Mitsuba cross-check). Without see-through
    /// triangles it is the any-hit test [`Self::occluded`].
    pub fn transmittance(&self, origin: Vec3, dir: Vec3, tmax: f32, step: f32) -> Rgb {
        if !self.alpha.has_see_through() {
            return if self.occluded(origin, dir, tmax) { Rgb::ZERO } else { Rgb::ONE };
        }
        let mut pass = Rgb::ONE;
        let mut tmin = 0.0;
        for _ in 0..MAX_CROSSINGS {
            let Some(hit) = self.intersect(origin, dir, tmin, tmax) else { return pass };
            let Some(sheet) = self.alpha.sheet_at(hit.tri, hit.u, hit.v) else { return Rgb::ZERO };
            pass *= sheet.pass;
            if pass.max_element() <= 0.0 {
                return Rgb::ZERO;
            }
            tmin = hit.t + step;
        }
        Rgb::ZERO
    }

    /// Whether anything (not cut out) lies on the ray `origin + t·dir` with `0 < t < tmax`.
    pub fn occluded(&self, origin: Vec3, dir: Vec3, tmax: f32) -> bool {
        self.occluder(origin, dir, tmax).is_some()
    }

    /// A triangle's slot in this tree found on the ray as [`Self::occluded`] finds it, or
    /// `None`: what a shadow cache keeps.
    pub fn occluder(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<u32> {
        match triangle::dominant_axis(dir.into()) {
            0 => self.any::<0>(&Ray::new::<0>(origin, dir), tmax),
            1 => self.any::<1>(&Ray::new::<1>(origin, dir), tmax),
            _ => self.any::<2>(&Ray::new::<2>(origin, dir), tmax),
        }
    }

    /// Whether the triangle in slot `slot` (from [`Self::occluder`]) lies on the ray, by the
    /// test [`Self::occluded`] applies to it: `true` means occluded, `false` only that this
    /// triangle does not occlude.
    pub fn occluded_by(&self, slot: u32, origin: Vec3, dir: Vec3, tmax: f32) -> bool {
        let i = slot as usize;
        if i >= self.tris.len() {
            return false;
        }
        // Masked: `opaque_at` is true for unmasked triangles, so this is the leaf's test.
        match triangle::dominant_axis(dir.into()) {
            0 => self.slot_any::<0>(&Ray::new::<0>(origin, dir), i, tmax, true),
            1 => self.slot_any::<1>(&Ray::new::<1>(origin, dir), i, tmax, true),
            _ => self.slot_any::<2>(&Ray::new::<2>(origin, dir), i, tmax, true),
        }
    }

    /// Whether the triangle in slot `i` lies on the ray (where not cut out, when `masked`).
    #[inline(always)]
    fn slot_any<const KZ: usize>(&self, r: &Ray, i: usize, tmax: f32, masked: bool) -> bool {
        triangle::intersect::<KZ>(r.o, &r.shear, &self.tris[i], 0.0, tmax)
            .is_some_and(|(_, u, v)| !masked || self.alpha.opaque_at(self.ids[i], u, v))
    }

    /// Closest hit among the triangles of one leaf, shrinking `tmax`.
    #[inline(always)]
    fn leaf_closest<const KZ: usize>(
        &self,
        r: &Ray,
        e: Entry,
        tmin: f32,
        tmax: &mut f32,
        best: &mut Option<(u32, f32, f32)>,
    ) {
        let first = e.child as usize;
        let count = (e.meta & COUNT_MASK) as usize;
        let masked = e.meta & MASKED != 0;
        for i in first..first + count {
            if let Some((t, u, v)) = triangle::intersect::<KZ>(r.o, &r.shear, &self.tris[i], tmin, *tmax) {
                if masked && !self.alpha.opaque_at(self.ids[i], u, v) {
                    continue;
                }
                *tmax = t;
                *best = Some((i as u32, u, v));
            }
        }
    }

    fn closest<const KZ: usize>(&self, r: &Ray, tmin: f32, mut tmax: f32) -> Option<Hit> {
        if self.nodes.is_empty() {
            return None;
        }
        let mut stack = [Entry::default(); STACK];
        let mut sp = 0usize;
        let mut best: Option<(u32, f32, f32)> = None;
        let mut cur = Entry { child: 0, meta: 0, near: tmin };
        loop {
            if cur.meta & LEAF != 0 {
                self.leaf_closest::<KZ>(r, cur, tmin, &mut tmax, &mut best);
            } else {
                let n = &self.nodes[cur.child as usize];
                let (near, mask) = r.test_children(n, tmin, tmax);
                let e0 = Entry { child: n.child[0], meta: n.meta[0], near: near.x };
                let e1 = Entry { child: n.child[1], meta: n.meta[1], near: near.y };
                match mask {
                    1 => {
                        cur = e0;
                        continue;
                    }
                    2 => {
                        cur = e1;
                        continue;
                    }
                    3 => {
                        let (first, second) = if e1.near < e0.near { (e1, e0) } else { (e0, e1) };
                        stack[sp] = second;
                        sp += 1;
                        cur = first;
                        continue;
                    }
                    _ => {}
                }
            }
            // Pop the next pending subtree (far children are pushed, so roughly front to back),
            // skipping those that start beyond the closest hit so far.
            loop {
                if sp == 0 {
                    let (i, u, v) = best?;
                    return Some(Hit { t: tmax, tri: self.ids[i as usize], u, v });
                }
                sp -= 1;
                if stack[sp].near <= tmax {
                    cur = stack[sp];
                    break;
                }
            }
        }
    }

    #[inline(always)]
    fn leaf_any<const KZ: usize>(&self, r: &Ray, e: Entry, tmax: f32) -> Option<u32> {
        let first = e.child as usize;
        let count = (e.meta & COUNT_MASK) as usize;
        let masked = e.meta & MASKED != 0;
        (first..first + count).find(|&i| self.slot_any::<KZ>(r, i, tmax, masked)).map(|i| i as u32)
    }

    fn any<const KZ: usize>(&self, r: &Ray, tmax: f32) -> Option<u32> {
        if self.nodes.is_empty() {
            return None;
        }
        let mut stack = [Entry::default(); STACK];
        let mut sp = 0usize;
        let mut cur = Entry { child: 0, meta: 0, near: 0.0 };
        loop {
            if cur.meta & LEAF != 0 {
                if let Some(slot) = self.leaf_any::<KZ>(r, cur, tmax) {
                    return Some(slot);
                }
            } else {
                let n = &self.nodes[cur.child as usize];
                let (_, mask) = r.test_children(n, 0.0, tmax);
                let e0 = Entry { child: n.child[0], meta: n.meta[0], near: 0.0 };
                let e1 = Entry { child: n.child[1], meta: n.meta[1], near: 0.0 };
                match mask {
                    1 => {
                        cur = e0;
                        continue;
                    }
                    2 => {
                        cur = e1;
                        continue;
                    }
                    3 => {
                        stack[sp] = e1;
                        sp += 1;
                        cur = e0;
                        continue;
                    }
                    _ => {}
                }
            }
            if sp == 0 {
                return None;
            }
            sp -= 1;
            cur = stack[sp];
        }
    }

    /// The surface point nearest to `p` within `max_dist` (alpha is ignored: this is a
    /// geometric query). Branch and bound on the distance to child boxes.
    pub fn closest_point(&self, p: Vec3, max_dist: f32) -> Option<Nearest> {
        if self.nodes.is_empty() {
            return None;
        }
        let p4 = [Vec4::splat(p.x), Vec4::splat(p.y), Vec4::splat(p.z)];
        let mut best_d2 = max_dist * max_dist;
        let mut best: Option<(u32, Vec3, f32, f32)> = None;
        let mut stack = [Entry::default(); STACK];
        let mut sp = 0usize;
        let mut cur = Entry { child: 0, meta: 0, near: 0.0 };
        loop {
            if cur.meta & LEAF != 0 {
                let first = cur.child as usize;
                for i in first..first + (cur.meta & COUNT_MASK) as usize {
                    let [a, b, c] = self.tris[i].map(Vec3::from);
                    let (q, u, v) = triangle::closest_point(p, a, b, c);
                    let d2 = q.distance_squared(p);
                    if d2 <= best_d2 {
                        best_d2 = d2;
                        best = Some((i as u32, q, u, v));
                    }
                }
            } else {
                let n = &self.nodes[cur.child as usize];
                let d2 = box_distance2(n, &p4);
                let e0 = Entry { child: n.child[0], meta: n.meta[0], near: d2.x };
                let e1 = Entry { child: n.child[1], meta: n.meta[1], near: d2.y };
                let (first, second) = if e1.near < e0.near { (e1, e0) } else { (e0, e1) };
                if first.near <= best_d2 {
                    if second.near <= best_d2 {
                        stack[sp] = second;
                        sp += 1;
                    }
                    cur = first;
                    continue;
                }
            }
            loop {
                if sp == 0 {
                    let (i, point, u, v) = best?;
                    let distance = best_d2.sqrt();
                    return Some(Nearest { tri: self.ids[i as usize], point, u, v, distance });
                }
                sp -= 1;
                if stack[sp].near <= best_d2 {
                    cur = stack[sp];
                    break;
                }
            }
        }
    }
}

/// Squared distances from a point to both child boxes (lanes 0 and 1).
#[inline(always)]
fn box_distance2(n: &Node, p4: &[Vec4; 3]) -> Vec4 {
    let axis = |slab: Vec4, p: Vec4| {
        let a = slab - p; // [lmin − p, rmin − p, lmax − p, rmax − p]
        let d = a.max(-a.zwxy()).max(Vec4::ZERO);
        d * d
    };
    axis(n.x, p4[0]) + axis(n.y, p4[1]) + axis(n.z, p4[2])
}
