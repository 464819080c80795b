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
//!
//! One file a step: `weld.rs`, `grow.rs`, `merge.rs` and `finish.rs`; `faces.rs` is the
//! welded view of a mesh they share, and `face_grid.rs` the grid of a chart's faces in UV
//! their overlap tests go through.

mod face_grid;
mod faces;
mod finish;
mod grow;
mod merge;
mod weld;

use glam::DVec2;

use crate::scene::{Mesh, SceneGeometry, TriangleId};

use face_grid::Visited;
use faces::MeshFaces;
use finish::finish;
use grow::{ChartOrder, grow};
pub use merge::MOVABLE_SIDE;
use merge::merge;
use weld::root;
pub use weld::weld_tolerance;
pub(crate) use weld::{FxHasher, edge_adjacency, weld};

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

/// `chart_max_angle` as the unwrapper uses it: at most 80° (beyond, faces would project
/// almost edge-on, with no texels to speak of), 0 when it is not a number.
pub fn effective_max_angle(a: f32) -> f32 {
    if a.is_nan() { 0.0 } else { a.clamp(0.0, 80f32.to_radians()) }
}

/// Unwraps the lit triangles `tris` (global ids, increasing) of `mesh` into charts whose UVs
/// are in metres (see the module docs); `texel_hint` is the texel size the atlas expects.
///
/// On up to `threads` threads: a chart never spans two edge-connected components of the
/// mesh, so the components are dealt into sets of about equal face counts, each set is
/// grown and merged on its own, and the charts are put back in the mesh's [`ChartOrder`]:
/// the result does not depend on `threads` (one set is the whole mesh at once).
pub fn unwrap_mesh(
    mesh: &Mesh,
    geom: &SceneGeometry,
    tris: &[TriangleId],
    texel_hint: f64,
    max_angle: f32,
    threads: usize,
) -> Vec<LocalChart> {
    if tris.is_empty() {
        return Vec::new();
    }
    let faces = MeshFaces::new(mesh, geom, tris, texel_hint);
    let cos_max = (effective_max_angle(max_angle) as f64).cos();
    let sets = component_sets(&faces, if faces.len() >= PARALLEL_FACES { threads } else { 1 });
    let parts = crate::parallel::par_map(sets, threads, |subset| {
        // Each set's own scratch (only its faces' entries are written or read).
        let mut uv = vec![[DVec2::ZERO; 3]; faces.len()];
        let mut seen = Visited::new(faces.len());
        let (order, grown): (Vec<ChartOrder>, Vec<Vec<u32>>) =
            grow(&faces, &subset, cos_max, &mut uv, &mut seen).into_iter().unzip();
        merge(&faces, grown, &mut uv, &mut seen)
            .into_iter()
            .map(|(i, members)| (order[i], finish(&members, &uv, tris, texel_hint)))
            .collect::<Vec<_>>()
    });
    let mut charts: Vec<(ChartOrder, LocalChart)> = parts.into_iter().flatten().collect();
    // Keys are distinct (a seed face or a lone face each).
    charts.sort_unstable_by_key(|(order, _)| *order);
    charts.into_iter().map(|(_, c)| c).collect()
}

/// Faces below which a mesh is unwrapped on one thread (a thread costs more than the work).
const PARALLEL_FACES: usize = 2048;

/// The mesh's faces dealt into at most `sets` sets of whole edge-connected components, of
/// about equal face counts (largest component first, to the set with the fewest faces so
/// far); each set's face ids increasing. Deterministic: ties go to the lower face or set.
fn component_sets(faces: &MeshFaces, sets: usize) -> Vec<Vec<u32>> {
    let n = faces.len();
    if sets <= 1 || n == 0 {
        return vec![(0..n as u32).collect()];
    }
    // Union-find over edge neighbours, each root the lowest face of its component.
    let mut parent: Vec<u32> = (0..n as u32).collect();
    for f in 0..n as u32 {
        for &g in faces.neighbours(f) {
            let (a, b) = (root(&mut parent, f), root(&mut parent, g));
            if a != b {
                parent[a.max(b) as usize] = a.min(b);
            }
        }
    }
    let mut members: Vec<Vec<u32>> = Vec::new();
    let mut index_of_root = vec![u32::MAX; n];
    for f in 0..n as u32 {
        let r = root(&mut parent, f) as usize;
        if index_of_root[r] == u32::MAX {
            index_of_root[r] = members.len() as u32;
            members.push(Vec::new());
        }
        members[index_of_root[r] as usize].push(f);
    }
    if members.len() == 1 {
        return members;
    }
    // Components in order of their lowest face: a stable sort keeps that among equal sizes.
    members.sort_by_key(|m| std::cmp::Reverse(m.len()));
    let mut out: Vec<Vec<u32>> = vec![Vec::new(); sets.min(members.len())];
    for m in members {
        let emptiest = (0..out.len()).min_by_key(|&k| (out[k].len(), k)).unwrap_or(0);
        out[emptiest].extend(m);
    }
    for set in &mut out {
        set.sort_unstable();
    }
    out
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;
    use crate::atlas::raster::triangles_overlap;
    use crate::scene::SceneBuilder;
    use crate::scene::builder::white;

    fn unwrap_all(s: &crate::scene::Scene, texel: f64) -> Vec<Vec<LocalChart>> {
        let g = SceneGeometry::new(s);
        s.meshes
            .iter()
            .enumerate()
            .map(|(mi, m)| {
                let tris: Vec<u32> = (g.mesh_offsets[mi]..g.mesh_offsets[mi + 1]).collect();
                unwrap_mesh(m, &g, &tris, texel, 40f32.to_radians(), 1)
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

    /// One mesh of many edge-connected components (thin boxes whose sides merge, a finely
    /// tessellated floor, a face collapsed onto a box's edge, a lone collapsed face):
    /// unwrapped on 1, 2, 3 and 8 threads (its components dealt into that many sets), the
    /// same charts in the same order, to the bit.
    #[test]
    fn charts_do_not_depend_on_the_threads() {
        let mut pos: Vec<Vec3> = Vec::new();
        let mut tris: Vec<[u32; 3]> = Vec::new();
        let quad = |pos: &mut Vec<Vec3>, tris: &mut Vec<[u32; 3]>, c: [Vec3; 4]| {
            let k = pos.len() as u32;
            pos.extend(c);
            tris.extend([[k, k + 1, k + 2], [k, k + 2, k + 3]]);
        };
        // Thin shafts (0.2–0.66 m across, 1–3.3 m tall: at 0.25 m texels, sides one to three
        // texels wide), each a component of its own, of sizes whose seeds interleave with the
        // floor's.
        for i in 0..24 {
            let (o, w, h) =
                (Vec3::new(i as f32 * 1.7, 0.0, (i % 5) as f32), 0.2 + 0.02 * i as f32, 1.0 + 0.1 * i as f32);
            let c = |x: f32, y: f32, z: f32| o + Vec3::new(x * w, y * h, z * w);
            let k = pos.len() as u32;
            for z in [0.0, 1.0] {
                for y in [0.0, 1.0] {
                    for x in [0.0, 1.0] {
                        pos.push(c(x, y, z));
                    }
                }
            }
            // The cube's 12 triangles over its 8 shared corners (index = x + 2y + 4z).
            for [a, b, c2, d] in [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]] {
                tris.extend([[k + a, k + b, k + c2], [k + a, k + c2, k + d]]);
            }
            if i == 3 {
                // A face collapsed onto the bottom edge (0–1): joins a neighbour's chart.
                let m = pos.len() as u32;
                pos.push(c(0.5, 0.0, 0.0) + Vec3::new(0.0, 0.0, 1e-9));
                tris.push([k, m, k + 1]);
            }
        }
        // A floor of 2 × 40² triangles, one component.
        let n = 40;
        for j in 0..n {
            for i in 0..n {
                let p = |a: usize, b: usize| Vec3::new(a as f32 * 0.5, -1.0, b as f32 * 0.5 + 10.0);
                quad(&mut pos, &mut tris, [p(i, j), p(i + 1, j), p(i + 1, j + 1), p(i, j + 1)]);
            }
        }
        // A lone collapsed face.
        let k = pos.len() as u32;
        pos.extend([Vec3::new(0.0, 5.0, 0.0), Vec3::new(2.0, 5.0, 0.0), Vec3::new(1.0, 5.0 + 1e-9, 0.0)]);
        tris.push([k, k + 1, k + 2]);
        assert!(tris.len() >= PARALLEL_FACES, "{} faces", tris.len());

        let mut b = SceneBuilder::new();
        let m = b.material(white());
        b.mesh("parts", pos, tris, m);
        let s = b.build();
        let g = SceneGeometry::new(&s);
        let all: Vec<u32> = (g.mesh_offsets[0]..g.mesh_offsets[1]).collect();
        let one = unwrap_mesh(&s.meshes[0], &g, &all, 0.25, 40f32.to_radians(), 1);
        // Boxes merged into strips (fewer charts than faces of the boxes and floor apart).
        assert!(one.len() < 24 * 6 + 2, "{} charts", one.len());
        for threads in [2, 3, 8] {
            let many = unwrap_mesh(&s.meshes[0], &g, &all, 0.25, 40f32.to_radians(), threads);
            assert_eq!(many.len(), one.len(), "{threads} threads");
            for (k, (a, b)) in one.iter().zip(&many).enumerate() {
                assert_eq!(a.tris, b.tris, "chart {k}, {threads} threads");
                assert_eq!(a.extent, b.extent, "chart {k}, {threads} threads");
                assert!(a.uv.iter().zip(&b.uv).all(|(p, q)| p == q), "chart {k}, {threads} threads");
            }
        }
    }
}
