//! Chart unwrapper for real meshes: architecture (walls and floors become one chart each) and
//! game or BIM assets (triangle soups, split normals and UVs, float noise, coincident faces).
//!
//! Per mesh (charts never span meshes):
//! 1. **Weld** vertices closer than [`weld_tolerance`] (scale-aware: 10⁻⁴ of the mesh's
//!    bounding-box diagonal, at most 10⁻³ texel, at least the float noise of its
//!    coordinates) and find edge-connected triangles. Exporters split vertices at UV and
//!    normal seams or write every triangle on its own; welding within a tolerance (not by
//!    rounding to a grid, which splits pairs straddling a grid line) joins them again.
//! 2. **Grow** planar charts: seeds in order of decreasing area (ties by triangle id); a chart
//!    grows breadth-first over welded edges to faces whose normal is within `chart_max_angle`
//!    of the seed's normal and whose projection onto the seed's plane does not overlap
//!    (interiors intersecting by more than [`OVERLAP_TOL`] texel) a face already in the
//!    chart: coplanar duplicates and curled surfaces are turned away and seed charts of their
//!    own. The overlap test is exact (separating axes), through a uniform grid of the chart's
//!    faces. The chart is then projected onto the plane ⟂ its area-weighted normal (checked
//!    again for overlaps; if that plane folds it, the seed's plane is kept). Degenerate faces
//!    (thinner than 10⁻⁷ of their length, or collapsed by welding) join the chart of an edge
//!    neighbour, projected onto its plane, or get a chart of their own when they have none.
//! 3. **Merge** charts across welded edges, greedily by gain: every rectangle the packer
//!    places costs its interior plus a one-texel border on each side ([`super::pack`]), so a
//!    small or thin chart costs far more atlas than its texels. Two neighbouring charts are
//!    merged when the merged chart's rectangle is smaller than their two rectangles
//!    together and one of them is thin (its rectangle at most [`MOVABLE_SIDE`] texels
//!    across): that one is unfolded rigidly about the longest edge they share (a hinge: its
//!    faces keep their shape exactly, a box's sides become a strip, a cap folds out next to
//!    its side). Large charts never move: a room's walls stay one chart each. A merge is
//!    refused when a moved face would overlap a face of the other chart, or come closer than
//!    [`MERGE_CLEARANCE`] texels in UV to one that is farther than that on the surface
//!    (faces that meet in UV must meet on the surface, so bilinear sampling and filtering
//!    within the chart never mix distant places).
//! 4. **Finish**: rotate to the minimum-area bounding rectangle (convex hull + rotating
//!    calipers) with the long side along x, move to the origin.
//!
//! Chart UVs come out in metres ([`LocalChart`]): the atlas scales them to whatever texel
//! size its budget gives. The texel size passed in (`texel_hint`) sets only the weld
//! tolerance, the overlap and clearance tolerances and the border cost of merges.

use std::collections::{BinaryHeap, HashMap};
use std::hash::{BuildHasherDefault, Hasher};

use glam::{DVec2, DVec3, Vec3};

use super::pack::axis_placement;
use super::raster::{floor_i64, triangles_overlap};
use crate::scene::{Mesh, SceneGeometry, TriangleId};

/// Two faces of a chart overlap when their projections intersect by more than this (LOD-0
/// texels) along every separating axis.
pub const OVERLAP_TOL: f64 = 1e-4;

/// Smallest distance (LOD-0 texels at the hint) between a face moved by a merge and a face
/// of the other chart that shares no vertex with it: more than the one-texel reach of
/// bilinear sampling, with room for a texel size up to a third finer than the hint.
pub const MERGE_CLEARANCE: f64 = 1.5;

/// One chart before packing.
#[derive(Clone, Debug)]
pub struct LocalChart {
    /// Triangles of the chart (global ids, increasing).
    pub tris: Vec<TriangleId>,
    /// Chart-local UVs per triangle (same corner order), bounding box from the origin to
    /// `extent`: in metres for unwrapped charts, in LOD-0 texels for TEXCOORD_1 blocks.
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
    fn root(parent: &mut [u32], mut i: u32) -> u32 {
        while parent[i as usize] != i {
            let g = parent[parent[i as usize] as usize];
            parent[i as usize] = g;
            i = g;
        }
        i
    }
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

/// Uniform grid over some faces of a mesh (a chart), for overlap and clearance tests. Cells
/// hold singly linked lists in one node array, so clearing it frees nothing.
struct FaceGrid {
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
struct Visited {
    stamp: Vec<u32>,
    now: u32,
}

impl Visited {
    fn new(faces: usize) -> Self {
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
    fn new(cell: f64) -> Self {
        FaceGrid {
            inv_cell: 1.0 / cell,
            heads: FxMap::default(),
            nodes: Vec::new(),
            big: Vec::new(),
            members: Vec::new(),
        }
    }

    fn clear(&mut self) {
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
    fn any(&self, lo: DVec2, hi: DVec2, seen: &mut Visited, mut hit: impl FnMut(u32) -> bool) -> bool {
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
    fn overlaps(&self, t: &[DVec2; 3], uv: &[[DVec2; 3]], seen: &mut Visited) -> bool {
        let (lo, hi) = bounds(t);
        self.any(lo, hi, seen, |f| triangles_overlap(t, &uv[f as usize], OVERLAP_TOL))
    }

    fn insert(&mut self, f: u32, t: &[DVec2; 3]) {
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

fn bounds(t: &[DVec2; 3]) -> (DVec2, DVec2) {
    (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]))
}

/// `chart_max_angle` as the unwrapper uses it: at most 80° (beyond, faces would project
/// almost edge-on, with no texels to speak of), 0 when it is not a number.
pub fn effective_max_angle(a: f32) -> f32 {
    if a.is_nan() { 0.0 } else { a.clamp(0.0, 80f32.to_radians()) }
}

/// The welded, flattened view of one mesh's lit triangles the unwrapper works on (texel
/// units of the hint).
struct MeshFaces<'a> {
    tris: &'a [TriangleId],
    /// Welded corner ids per face.
    corners: Vec<[u32; 3]>,
    /// Welded corner positions per face, in texels.
    pos: Vec<[DVec3; 3]>,
    normal: Vec<DVec3>,
    area: Vec<f32>,
    degenerate: Vec<bool>,
    adj_start: Vec<u32>,
    adj: Vec<u32>,
    /// Grid cell size (texels): the median longest edge, so a typical face covers a few cells.
    cell: f64,
}

impl<'a> MeshFaces<'a> {
    fn new(mesh: &Mesh, geom: &SceneGeometry, tris: &'a [TriangleId], texel: f64) -> Self {
        let inv_texel = 1.0 / texel;
        let (wid, reps) = weld(&mesh.positions, weld_tolerance(&mesh.positions, texel));
        let corners: Vec<[u32; 3]> =
            tris.iter().map(|&t| mesh.triangles[geom.local[t as usize] as usize].map(|v| wid[v as usize])).collect();
        let (adj_start, adj) = edge_adjacency(&corners);
        let pos: Vec<[DVec3; 3]> = corners.iter().map(|c| c.map(|v| reps[v as usize] * inv_texel)).collect();
        let normal = tris.iter().map(|&t| geom.normals[t as usize].as_dvec3()).collect();
        let area = tris.iter().map(|&t| geom.areas[t as usize]).collect();
        let mut longest = Vec::with_capacity(tris.len());
        let degenerate = pos
            .iter()
            .zip(&corners)
            .map(|(&[a, b, c], &[i0, i1, i2])| {
                let e2 = (b - a).length_squared().max((c - b).length_squared()).max((a - c).length_squared());
                longest.push(e2.sqrt());
                let a2 = (b - a).cross(c - a).length();
                i0 == i1 || i1 == i2 || i2 == i0 || a2 <= 1e-7 * e2 || e2 < 1e-12
            })
            .collect();
        let mid = longest.len() / 2;
        let cell = longest.select_nth_unstable_by(mid, f64::total_cmp).1.max(1e-6);
        MeshFaces { tris, corners, pos, normal, area, degenerate, adj_start, adj, cell }
    }

    fn len(&self) -> usize {
        self.tris.len()
    }

    fn neighbours(&self, f: u32) -> &[u32] {
        &self.adj[self.adj_start[f as usize] as usize..self.adj_start[f as usize + 1] as usize]
    }

    /// Distance (texels) between the bounding boxes of two faces on the surface: a lower
    /// bound of the distance between the faces.
    fn box_distance(&self, f: u32, g: u32) -> f64 {
        let bb = |p: &[DVec3; 3]| (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
        let ((alo, ahi), (blo, bhi)) = (bb(&self.pos[f as usize]), bb(&self.pos[g as usize]));
        (alo - bhi).max(blo - ahi).max(DVec3::ZERO).length()
    }
}

/// A planar projection frame: the plane ⟂ `n` through `origin`.
#[derive(Clone, Copy)]
struct Frame {
    n: DVec3,
    origin: DVec3,
}

impl Frame {
    fn project(&self, p: &[DVec3; 3]) -> [DVec2; 3] {
        let (t, b) = self.n.any_orthonormal_pair();
        p.map(|q| {
            let d = q - self.origin;
            DVec2::new(d.dot(t), d.dot(b))
        })
    }
}

/// Unwraps the lit triangles `tris` (global ids, increasing) of `mesh` into charts whose UVs
/// are in metres (see the module docs); `texel_hint` is the texel size the atlas expects.
pub fn unwrap_mesh(
    mesh: &Mesh,
    geom: &SceneGeometry,
    tris: &[TriangleId],
    texel_hint: f64,
    max_angle: f32,
) -> Vec<LocalChart> {
    if tris.is_empty() {
        return Vec::new();
    }
    let faces = MeshFaces::new(mesh, geom, tris, texel_hint);
    let mut uv = vec![[DVec2::ZERO; 3]; faces.len()];
    let mut seen = Visited::new(faces.len());
    let grown = grow(&faces, (effective_max_angle(max_angle) as f64).cos(), &mut uv, &mut seen);
    let merged = merge(&faces, grown, &mut uv, &mut seen);
    merged.into_iter().map(|members| finish(&members, &uv, tris, texel_hint)).collect()
}

/// Step 2 of the module docs: planar charts (face lists, increasing), UVs (texels) in `uv`.
fn grow(faces: &MeshFaces, cos_max: f64, uv: &mut [[DVec2; 3]], seen: &mut Visited) -> Vec<Vec<u32>> {
    let n = faces.len();
    let mut seeds: Vec<u32> = (0..n as u32).filter(|&f| !faces.degenerate[f as usize]).collect();
    seeds.sort_unstable_by_key(|&f| (std::cmp::Reverse(coarse(faces.area[f as usize] as f64)), f));

    let mut chart_of = vec![u32::MAX; n];
    let mut tried = vec![u32::MAX; n];
    let mut grid = FaceGrid::new(faces.cell);
    let mut charts: Vec<Vec<u32>> = Vec::new();
    let mut frames: Vec<Frame> = Vec::new();
    let mut queue = std::collections::VecDeque::new();

    for &seed in &seeds {
        let s = seed as usize;
        if chart_of[s] != u32::MAX {
            continue;
        }
        let id = charts.len() as u32;
        let mut members = vec![seed];
        chart_of[s] = id;
        let seed_frame = Frame { n: faces.normal[s], origin: faces.pos[s][0] };
        grid.clear();
        uv[s] = seed_frame.project(&faces.pos[s]);
        grid.insert(seed, &uv[s]);
        tried[s] = id;
        queue.clear();
        queue.push_back(seed);
        while let Some(f) = queue.pop_front() {
            for &g in faces.neighbours(f) {
                let gi = g as usize;
                if chart_of[gi] != u32::MAX || tried[gi] == id || faces.degenerate[gi] {
                    continue;
                }
                tried[gi] = id;
                if faces.normal[gi].dot(seed_frame.n) < cos_max {
                    continue;
                }
                let t = seed_frame.project(&faces.pos[gi]);
                if grid.overlaps(&t, uv, seen) {
                    continue;
                }
                uv[gi] = t;
                grid.insert(g, &t);
                chart_of[gi] = id;
                members.push(g);
                queue.push_back(g);
            }
        }

        // Final plane: area-weighted normal, unless it folds the chart.
        let mut frame = seed_frame;
        let na = members.iter().map(|&f| faces.normal[f as usize] * faces.area[f as usize] as f64).sum::<DVec3>();
        let na = na.try_normalize().unwrap_or(seed_frame.n);
        if na.dot(seed_frame.n) < 1.0 - 1e-12 {
            let candidate = Frame { n: na, origin: seed_frame.origin };
            let kept: Vec<[DVec2; 3]> = members.iter().map(|&f| uv[f as usize]).collect();
            grid.clear();
            let mut ok = true;
            for &f in &members {
                let t = candidate.project(&faces.pos[f as usize]);
                uv[f as usize] = t;
                if grid.overlaps(&t, uv, seen) {
                    ok = false;
                    break;
                }
                grid.insert(f, &t);
            }
            if ok {
                frame = candidate;
            } else {
                for (&f, t) in members.iter().zip(kept) {
                    uv[f as usize] = t;
                }
            }
        }
        charts.push(members);
        frames.push(frame);
    }

    // Degenerate faces: into the chart of their first non-degenerate edge neighbour,
    // projected onto its plane, else alone. (No overlap test: thinner than 10⁻⁷ of their
    // length, or collapsed to a segment, they have no interior to overlap with.)
    for f in 0..n as u32 {
        if !faces.degenerate[f as usize] {
            continue;
        }
        let home = faces.neighbours(f).iter().map(|&g| chart_of[g as usize]).find(|&c| c != u32::MAX);
        let c = home.unwrap_or_else(|| {
            charts.push(Vec::new());
            frames.push(Frame { n: faces.normal[f as usize], origin: faces.pos[f as usize][0] });
            (charts.len() - 1) as u32
        });
        uv[f as usize] = frames[c as usize].project(&faces.pos[f as usize]);
        chart_of[f as usize] = c;
        charts[c as usize].push(f);
    }
    for c in &mut charts {
        c.sort_unstable();
    }
    charts
}

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
            let b = 2 * super::pack::BORDER;
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

/// A positive value with its last bits dropped (about 5 significant digits), so that
/// values equal up to float noise — the areas of a box's opposite faces after it moved —
/// compare equal and fall to the tie-break: the unwrap of a moved mesh is the unwrap of the
/// mesh, made in the same order.
fn coarse(x: f64) -> u32 {
    (x as f32).to_bits() >> 6
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

/// Step 3 of the module docs.
fn merge(faces: &MeshFaces, charts: Vec<Vec<u32>>, uv: &mut [[DVec2; 3]], seen: &mut Visited) -> Vec<Vec<u32>> {
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
        return clusters.into_iter().map(|c| c.faces).collect();
    }
    for f in 0..faces.len() as u32 {
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
        .filter(|c| c.alive)
        .map(|mut c| {
            c.faces.sort_unstable();
            c.faces
        })
        .collect()
}

/// Rotates a chart (UVs in texels of `texel`) to its minimum-area bounding rectangle (long
/// side along x), moves it to the origin and converts it to metres.
fn finish(members: &[u32], uv: &[[DVec2; 3]], tris: &[TriangleId], texel: f64) -> LocalChart {
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

    /// No two faces of a chart (UVs in metres, checked in texels) overlap.
    fn assert_no_overlap(c: &LocalChart, texel: f64) {
        let uv: Vec<[DVec2; 3]> = c.uv.iter().map(|t| t.map(|p| p / texel)).collect();
        for i in 0..uv.len() {
            for j in i + 1..uv.len() {
                assert!(!triangles_overlap(&uv[i], &uv[j], OVERLAP_TOL), "faces {i} and {j} overlap");
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
        // Extents in metres, compared in thousandths of a texel.
        let mut ext: Vec<(i64, i64)> = charts[0]
            .iter()
            .map(|c| ((c.extent.x / 0.1 * 1e3).round() as i64, (c.extent.y / 0.1 * 1e3).round() as i64))
            .collect();
        ext.sort();
        assert_eq!(
            ext,
            vec![(30000, 25000), (30000, 25000), (40000, 25000), (40000, 25000), (40000, 30000), (40000, 30000)]
        );
        assert_eq!(charts[1].len(), 1);
        let e = charts[1][0].extent;
        assert!((e.x - 2.0).abs() < 1e-5 && (e.y - 1.0).abs() < 1e-5, "{e:?} m");
        assert_eq!(charts[1][0].tris.len(), 128);
        assert_no_overlap(&charts[1][0], 0.1);
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
            assert_no_overlap(c, 0.05);
        }
        let total: usize = charts[1].iter().map(|c| c.tris.len()).sum();
        assert_eq!(total, 120);
    }

    /// A face collapsed to a segment (10⁻⁹ m off its base) joins the chart of the face it
    /// shares an edge with; one with no neighbour keeps a chart of its own.
    #[test]
    fn degenerate_faces_join_a_neighbour_or_stand_alone() {
        let mut b = SceneBuilder::new();
        let m = b.material(white());
        b.mesh(
            "m",
            vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 0.0, -1.0), Vec3::new(0.5, 0.0, 1e-9)],
            vec![[0, 1, 2], [0, 3, 1]],
            m,
        );
        b.mesh("lone", vec![Vec3::ZERO, Vec3::X * 2.0, Vec3::new(1.0, 1e-9, 0.0)], vec![[0, 1, 2]], m);
        let s = b.build();
        let charts = unwrap_all(&s, 0.1);
        assert_eq!(charts[0].len(), 1);
        assert_eq!(charts[0][0].tris, vec![0, 1]);
        assert_eq!(charts[1].len(), 1);
        assert!(charts.iter().flatten().all(|c| c.extent.is_finite()));
    }

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

    /// A box seen at coarse texels (a 0.6 m × 5.5 m column shaft at 0.33 m: sides two
    /// texels wide) is unfolded into fewer, larger charts whose rectangles together are
    /// smaller than the six separate ones; at 5 cm (sides 12 texels across, never thin) the
    /// six faces stay six charts.
    #[test]
    fn thin_box_sides_unfold_into_strips() {
        let mut b = SceneBuilder::new();
        let m = b.material(white());
        b.cuboid("shaft", Vec3::ZERO, Vec3::new(0.6, 5.5, 0.6), false, m);
        let s = b.build();
        let rect_area = |charts: &[LocalChart], texel: f64| -> u64 {
            charts
                .iter()
                .map(|c| {
                    let p = super::super::pack::place_free(c.extent / texel).unwrap().rect_size();
                    p.0 as u64 * p.1 as u64
                })
                .sum()
        };
        let coarse = &unwrap_all(&s, 0.33)[0];
        assert!(coarse.len() < 6, "{} charts", coarse.len());
        for c in coarse {
            assert_no_overlap(c, 0.33);
        }
        // Six separate faces: four 2×17 sides and two 2×2 caps, with borders.
        assert!(rect_area(coarse, 0.33) < 4 * 4 * 19 + 2 * 4 * 4, "{} texels", rect_area(coarse, 0.33));
        let fine = &unwrap_all(&s, 0.05)[0];
        assert_eq!(fine.len(), 6);
    }
}
