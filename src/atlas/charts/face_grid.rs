//! Footprints: a uniform grid of a chart's faces in UV, for the exact overlap and clearance
//! tests of growing and merging.

use glam::DVec2;

use crate::atlas::raster::{floor_i64, triangles_overlap};

use super::OVERLAP_TOL;
use super::weld::FxMap;

/// Uniform grid over some faces of a mesh (a chart), for overlap and clearance tests. Cells
/// hold singly linked lists in one node array, so clearing it frees nothing.
pub(super) struct FaceGrid {
    inv_cell: f64,
    heads: FxMap<(i64, i64), u32>,
    /// (face, next node or u32::MAX)
    nodes: Vec<(u32, u32)>,
    /// Faces covering too many cells: tested against every query.
    big: Vec<u32>,
    members: Vec<u32>,
}

/// Most cells a face may be listed in before it goes to the grid's `big` list.
const MAX_CELLS: i64 = 64;

/// Marks of the faces a query has already tested (one per mesh, shared by all its grids).
pub(super) struct Visited {
    stamp: Vec<u32>,
    now: u32,
}

impl Visited {
    pub(super) fn new(faces: usize) -> Self {
        Visited { stamp: vec![0; faces], now: 0 }
    }

    fn next(&mut self) {
        self.now = self.now.wrapping_add(1);
        if self.now == 0 {
            self.stamp.fill(0);
            self.now = 1;
        }
    }

    /// Whether `f` is seen for the first time in this query.
    fn first(&mut self, f: u32) -> bool {
        let s = &mut self.stamp[f as usize];
        let fresh = *s != self.now;
        *s = self.now;
        fresh
    }
}

impl FaceGrid {
    pub(super) fn new(cell: f64) -> Self {
        FaceGrid {
            inv_cell: 1.0 / cell,
            heads: FxMap::default(),
            nodes: Vec::new(),
            big: Vec::new(),
            members: Vec::new(),
        }
    }

    pub(super) fn clear(&mut self) {
        self.heads.clear();
        self.nodes.clear();
        self.big.clear();
        self.members.clear();
    }

    fn cell_range(&self, lo: DVec2, hi: DVec2) -> Option<(i64, i64, i64, i64)> {
        let (lo, hi) = (lo * self.inv_cell, hi * self.inv_cell);
        let r = (floor_i64(lo.x), floor_i64(lo.y), floor_i64(hi.x), floor_i64(hi.y));
        ((r.2 - r.0 + 1) * (r.3 - r.1 + 1) <= MAX_CELLS).then_some(r)
    }

    /// Whether `hit(g)` holds for some face `g` of the grid whose cells meet the box
    /// `[lo, hi]` (every face is passed at most once).
    pub(super) fn any(&self, lo: DVec2, hi: DVec2, seen: &mut Visited, mut hit: impl FnMut(u32) -> bool) -> bool {
        seen.next();
        let mut test = |f: u32, seen: &mut Visited| seen.first(f) && hit(f);
        let Some((x0, y0, x1, y1)) = self.cell_range(lo, hi) else {
            return self.members.iter().any(|&f| test(f, seen));
        };
        if self.big.iter().any(|&f| test(f, seen)) {
            return true;
        }
        for y in y0..=y1 {
            for x in x0..=x1 {
                let mut n = self.heads.get(&(x, y)).copied().unwrap_or(u32::MAX);
                while n != u32::MAX {
                    let (f, next) = self.nodes[n as usize];
                    if test(f, seen) {
                        return true;
                    }
                    n = next;
                }
            }
        }
        false
    }

    /// Whether `t` overlaps a face of the grid (`uv` holds every face's UVs).
    pub(super) fn overlaps(&self, t: &[DVec2; 3], uv: &[[DVec2; 3]], seen: &mut Visited) -> bool {
        let (lo, hi) = bounds(t);
        self.any(lo, hi, seen, |f| triangles_overlap(t, &uv[f as usize], OVERLAP_TOL))
    }

    pub(super) fn insert(&mut self, f: u32, t: &[DVec2; 3]) {
        self.members.push(f);
        let (lo, hi) = bounds(t);
        match self.cell_range(lo, hi) {
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

pub(super) fn bounds(t: &[DVec2; 3]) -> (DVec2, DVec2) {
    (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]))
}
