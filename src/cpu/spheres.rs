//! A hierarchy of bounding spheres over the scene's triangles: which triangles' projections
//! along a bundle direction may overlap a bundle window. Light bundles ask this sixteen
//! times per global direction for windows a fraction of the scene wide; testing every
//! triangle's sphere each time cost as much as the rest of the light pass on scenes of
//! ~10⁴ triangles.

use glam::{Vec2, Vec3};

use crate::bundle::raster::BundleFrame;

/// Most triangles in a leaf.
const LEAF: usize = 8;

/// A sphere around a subtree: `count > 0` makes it a leaf holding `order[first..][..count]`;
/// otherwise its children are the next node and node `first`.
#[derive(Clone, Copy, Debug)]
struct Node {
    centre: Vec3,
    radius: f32,
    first: u32,
    count: u32,
}

pub struct SphereTree {
    /// Per triangle: its bounding sphere (centre, radius).
    spheres: Vec<(Vec3, f32)>,
    nodes: Vec<Node>,
    /// Triangle indices, leaf by leaf.
    order: Vec<u32>,
}

impl SphereTree {
    /// Builds the tree over triangles with bounding `spheres`, by median splits along the
    /// longest axis of their centres.
    pub fn new(spheres: Vec<(Vec3, f32)>) -> Self {
        let mut tree = SphereTree { order: (0..spheres.len() as u32).collect(), spheres, nodes: Vec::new() };
        if !tree.order.is_empty() {
            tree.build(0, tree.order.len());
        }
        tree
    }

    /// Appends the node over `order[first..end]` and its subtree.
    fn build(&mut self, first: usize, end: usize) {
        let (centre, radius) = self.enclosing(&self.order[first..end]);
        let at = self.nodes.len();
        self.nodes.push(Node { centre, radius, first: first as u32, count: (end - first) as u32 });
        if end - first <= LEAF {
            return;
        }
        let (lo, hi) = self.order[first..end]
            .iter()
            .map(|&t| self.spheres[t as usize].0)
            .fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), c| (lo.min(c), hi.max(c)));
        let axis = (hi - lo).max_position();
        let mid = first + (end - first) / 2;
        let spheres = &self.spheres;
        self.order[first..end].select_nth_unstable_by(mid - first, |&a, &b| {
            spheres[a as usize].0[axis].total_cmp(&spheres[b as usize].0[axis])
        });
        self.nodes[at].count = 0;
        self.build(first, mid);
        self.nodes[at].first = self.nodes.len() as u32;
        self.build(mid, end);
    }

    /// A sphere around the spheres of `triangles`, grown by a relative 10⁻⁵ so that float
    /// rounding in the window test never rejects a node whose triangles pass it.
    fn enclosing(&self, triangles: &[u32]) -> (Vec3, f32) {
        let (lo, hi) = triangles
            .iter()
            .map(|&t| self.spheres[t as usize])
            .fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), (c, r)| {
                (lo.min(c - Vec3::splat(r)), hi.max(c + Vec3::splat(r)))
            });
        let centre = (lo + hi) * 0.5;
        let radius = triangles
            .iter()
            .map(|&t| {
                let (c, r) = self.spheres[t as usize];
                (c - centre).length() + r
            })
            .fold(0.0f32, f32::max);
        (centre, radius + 1e-5 * (radius + centre.length()))
    }

    /// The triangles whose bounding spheres' projections along `frame` overlap the square
    /// window `[origin, origin + side]²` (frame coordinates), in ascending order.
    pub fn overlapping(&self, frame: &BundleFrame, origin: Vec2, side: f32, stack: &mut Vec<u32>, out: &mut Vec<u32>) {
        out.clear();
        stack.clear();
        if self.nodes.is_empty() {
            return;
        }
        let hi = origin + Vec2::splat(side);
        let overlaps = |c: Vec3, r: f32| {
            let (x, y) = (c.dot(frame.t), c.dot(frame.b));
            x + r >= origin.x && y + r >= origin.y && x - r <= hi.x && y - r <= hi.y
        };
        stack.push(0);
        while let Some(n) = stack.pop() {
            let node = self.nodes[n as usize];
            if !overlaps(node.centre, node.radius) {
                continue;
            }
            if node.count == 0 {
                stack.push(node.first);
                stack.push(n + 1);
                continue;
            }
            for &t in &self.order[node.first as usize..][..node.count as usize] {
                let (c, r) = self.spheres[t as usize];
                if overlaps(c, r) {
                    out.push(t);
                }
            }
        }
        out.sort_unstable();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Rng;

    /// The tree finds exactly the triangles a test of every sphere finds, for random
    /// directions and windows over a scene of clustered and scattered spheres.
    #[test]
    fn finds_what_testing_every_sphere_finds() {
        let mut rng = Rng::new(3, 7);
        let mut spheres = Vec::new();
        for i in 0..3000 {
            let scale = if i % 3 == 0 { 20.0 } else { 2.0 };
            let c = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * scale + Vec3::splat(100.0);
            spheres.push((c, rng.next_f32() * 0.3));
        }
        let tree = SphereTree::new(spheres.clone());
        let (mut stack, mut found) = (Vec::new(), Vec::new());
        let mut total = 0;
        for _ in 0..200 {
            let dir = Vec3::new(rng.next_f32() - 0.5, rng.next_f32() - 0.5, rng.next_f32() - 0.5);
            let frame = BundleFrame::new(dir);
            let centre = Vec3::splat(100.0) + Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 10.0;
            let side = rng.next_f32() * 3.0;
            let origin = Vec2::new(centre.dot(frame.t), centre.dot(frame.b));
            tree.overlapping(&frame, origin, side, &mut stack, &mut found);
            let hi = origin + Vec2::splat(side);
            let expected: Vec<u32> = (0..spheres.len() as u32)
                .filter(|&t| {
                    let (c, r) = spheres[t as usize];
                    let (x, y) = (c.dot(frame.t), c.dot(frame.b));
                    x + r >= origin.x && y + r >= origin.y && x - r <= hi.x && y - r <= hi.y
                })
                .collect();
            assert_eq!(found, expected);
            total += found.len();
        }
        assert!(total > 1000, "{total}");
    }
}
