//! Binned-SAH construction of the BVH2, written straight into the flat node layout of
//! [`super::bvh`]: each node holds the boxes of its two children (one 64-byte cache line per
//! visit), interior children are laid out depth-first (the left child follows its parent).

use glam::{Vec3A, Vec4};

/// Bins per axis for the SAH sweep.
const BINS: usize = 32;
/// Leaves never hold more than this many triangles unless their centroids coincide.
pub(crate) const MAX_LEAF: usize = 8;
/// Beyond this depth splits are object medians, so the depth stays below
/// `SAH_DEPTH + log2(n) + 1` ≤ [`MAX_TREE_DEPTH`] and the fixed traversal stacks suffice.
const SAH_DEPTH: u32 = 64;
pub(crate) const MAX_TREE_DEPTH: usize = 100;
/// SAH costs of one node visit (two box tests) and of one triangle test.
const C_TRAV: f32 = 1.0;
const C_ISECT: f32 = 1.0;

/// Leaf flag in [`Node::meta`]; the low 30 bits hold the triangle count.
pub(crate) const LEAF: u32 = 1 << 31;
/// The leaf holds at least one alpha-masked triangle.
pub(crate) const MASKED: u32 = 1 << 30;
pub(crate) const COUNT_MASK: u32 = MASKED - 1;

/// A BVH2 node: the boxes of both children, SIMD-friendly, and the children themselves.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
pub(crate) struct Node {
    /// Per axis: `[left.min, right.min, left.max, right.max]`.
    pub x: Vec4,
    pub y: Vec4,
    pub z: Vec4,
    /// Per child: node index (interior child) or first triangle (leaf child).
    pub child: [u32; 2],
    /// Per child: 0 for an interior child, `LEAF | [MASKED] | count` for a leaf.
    pub meta: [u32; 2],
}

#[derive(Clone, Copy, Debug)]
pub(crate) struct Aabb {
    pub min: Vec3A,
    pub max: Vec3A,
}

impl Aabb {
    pub const EMPTY: Aabb = Aabb { min: Vec3A::splat(f32::INFINITY), max: Vec3A::splat(f32::NEG_INFINITY) };

    #[inline]
    pub fn grow(&mut self, b: &Aabb) {
        self.min = self.min.min(b.min);
        self.max = self.max.max(b.max);
    }

    #[inline]
    pub fn grow_point(&mut self, p: Vec3A) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }

    /// Half the surface area (the SAH only needs ratios); 0 for an empty box.
    #[inline]
    pub fn half_area(&self) -> f32 {
        let e = (self.max - self.min).max(Vec3A::ZERO);
        e.x * e.y + e.y * e.z + e.z * e.x
    }
}

/// One child as seen from its parent.
#[derive(Clone, Copy)]
struct ChildRef {
    bounds: Aabb,
    child: u32,
    meta: u32,
}

/// The result of a build: nodes (root at 0) and the triangle order the leaves refer to.
pub(crate) struct Built {
    pub nodes: Vec<Node>,
    pub order: Vec<u32>,
}

struct Builder<'a> {
    boxes: &'a [Aabb],
    centroids: &'a [Vec3A],
    order: Vec<u32>,
    nodes: Vec<Node>,
}

#[derive(Clone, Copy)]
struct Bin {
    bounds: Aabb,
    count: u32,
}

struct Split {
    axis: usize,
    /// Triangles whose bin is below this go left.
    bin: usize,
    cost: f32,
}

/// Builds the BVH over triangles with the given boxes and centroids.
pub(crate) fn build(boxes: &[Aabb], centroids: &[Vec3A]) -> Built {
    let n = boxes.len();
    let mut b = Builder { boxes, centroids, order: (0..n as u32).collect(), nodes: Vec::with_capacity(n.max(1)) };
    if n == 0 {
        return Built { nodes: Vec::new(), order: Vec::new() };
    }
    let root = b.subdivide(0, n, 0);
    if root.meta != 0 {
        // The whole scene is one leaf: wrap it in a root whose second child is an empty leaf.
        let empty = ChildRef { bounds: root.bounds, child: 0, meta: LEAF };
        b.nodes.push(make_node(&root, &empty));
    }
    Built { nodes: b.nodes, order: b.order }
}

fn make_node(l: &ChildRef, r: &ChildRef) -> Node {
    let (a, b) = (&l.bounds, &r.bounds);
    Node {
        x: Vec4::new(a.min.x, b.min.x, a.max.x, b.max.x),
        y: Vec4::new(a.min.y, b.min.y, a.max.y, b.max.y),
        z: Vec4::new(a.min.z, b.min.z, a.max.z, b.max.z),
        child: [l.child, r.child],
        meta: [l.meta, r.meta],
    }
}

impl Builder<'_> {
    fn range_bounds(&self, start: usize, end: usize) -> (Aabb, Aabb) {
        let mut bounds = Aabb::EMPTY;
        let mut cb = Aabb::EMPTY;
        for &i in &self.order[start..end] {
            bounds.grow(&self.boxes[i as usize]);
            cb.grow_point(self.centroids[i as usize]);
        }
        (bounds, cb)
    }

    fn subdivide(&mut self, start: usize, end: usize, depth: u32) -> ChildRef {
        let n = end - start;
        let (bounds, cb) = self.range_bounds(start, end);
        let leaf = ChildRef { bounds, child: start as u32, meta: LEAF | n as u32 };
        if n <= 1 {
            return leaf;
        }
        let mid = if depth >= SAH_DEPTH {
            self.median_split(start, end, &cb)
        } else {
            match self.best_split(start, end, &bounds, &cb) {
                Some(s) if n <= MAX_LEAF && s.cost >= C_ISECT * n as f32 => return leaf,
                Some(s) => self.partition(start, end, &s, &cb).unwrap_or_else(|| self.median_split(start, end, &cb)),
                None if n <= MAX_LEAF => return leaf,
                None => self.median_split(start, end, &cb),
            }
        };
        let index = self.nodes.len();
        // Placeholder, filled once both children exist.
        self.nodes.push(make_node(&leaf, &leaf));
        let l = self.subdivide(start, mid, depth + 1);
        let r = self.subdivide(mid, end, depth + 1);
        self.nodes[index] = make_node(&l, &r);
        ChildRef { bounds, child: index as u32, meta: 0 }
    }

    #[inline]
    fn bin_of(c: f32, lo: f32, scale: f32) -> usize {
        (((c - lo) * scale) as usize).min(BINS - 1)
    }

    /// The cheapest SAH plane over `BINS` centroid bins on each axis; `None` when the
    /// centroids all coincide.
    fn best_split(&self, start: usize, end: usize, bounds: &Aabb, cb: &Aabb) -> Option<Split> {
        let ext = cb.max - cb.min;
        let parent_area = bounds.half_area().max(f32::MIN_POSITIVE);
        let mut best: Option<Split> = None;
        for axis in 0..3 {
            if ext[axis] <= 0.0 {
                continue;
            }
            let scale = BINS as f32 / ext[axis];
            let mut bins = [Bin { bounds: Aabb::EMPTY, count: 0 }; BINS];
            for &i in &self.order[start..end] {
                let k = Self::bin_of(self.centroids[i as usize][axis], cb.min[axis], scale);
                bins[k].bounds.grow(&self.boxes[i as usize]);
                bins[k].count += 1;
            }
            // Right-to-left sweep: area × count of everything at or above each plane.
            let mut right_cost = [0.0f32; BINS];
            let mut acc = Aabb::EMPTY;
            let mut cnt = 0u32;
            for k in (1..BINS).rev() {
                acc.grow(&bins[k].bounds);
                cnt += bins[k].count;
                right_cost[k] = if cnt > 0 { acc.half_area() * cnt as f32 } else { 0.0 };
            }
            let mut acc = Aabb::EMPTY;
            let mut cnt = 0u32;
            for k in 1..BINS {
                acc.grow(&bins[k - 1].bounds);
                cnt += bins[k - 1].count;
                if cnt == 0 || cnt as usize == end - start {
                    continue;
                }
                let cost = C_TRAV + C_ISECT * (acc.half_area() * cnt as f32 + right_cost[k]) / parent_area;
                if best.as_ref().is_none_or(|b| cost < b.cost) {
                    best = Some(Split { axis, bin: k, cost });
                }
            }
        }
        best
    }

    /// Partitions by the split's bin; `None` if one side would be empty.
    fn partition(&mut self, start: usize, end: usize, s: &Split, cb: &Aabb) -> Option<usize> {
        let lo = cb.min[s.axis];
        let scale = BINS as f32 / (cb.max[s.axis] - lo);
        let mut i = start;
        let mut j = end;
        while i < j {
            let c = self.centroids[self.order[i] as usize][s.axis];
            if Self::bin_of(c, lo, scale) < s.bin {
                i += 1;
            } else {
                j -= 1;
                self.order.swap(i, j);
            }
        }
        (i > start && i < end).then_some(i)
    }

    /// Object median along the widest centroid axis (index halves if all coincide).
    fn median_split(&mut self, start: usize, end: usize, cb: &Aabb) -> usize {
        let mid = start + (end - start) / 2;
        let ext = cb.max - cb.min;
        let axis = if ext.x >= ext.y && ext.x >= ext.z {
            0
        } else if ext.y >= ext.z {
            1
        } else {
            2
        };
        if ext[axis] > 0.0 {
            let cs = self.centroids;
            self.order[start..end]
                .select_nth_unstable_by(mid - start, |&a, &b| cs[a as usize][axis].total_cmp(&cs[b as usize][axis]));
        }
        mid
    }
}
