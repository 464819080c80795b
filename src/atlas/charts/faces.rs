//! The welded, flattened view of one mesh's faces the unwrapper works on, and planar
//! projection frames.

use glam::{DVec2, DVec3};

use crate::scene::{Mesh, SceneGeometry, TriangleId};

use super::weld::{edge_adjacency, weld, weld_tolerance};

/// The welded, flattened view of one mesh's lit triangles the unwrapper works on (texel
/// units of the hint).
pub(super) struct MeshFaces<'a> {
    tris: &'a [TriangleId],
    /// Welded corner ids per face.
    pub(super) corners: Vec<[u32; 3]>,
    /// Welded corner positions per face, in texels.
    pub(super) pos: Vec<[DVec3; 3]>,
    pub(super) normal: Vec<DVec3>,
    pub(super) area: Vec<f32>,
    pub(super) degenerate: Vec<bool>,
    adj_start: Vec<u32>,
    adj: Vec<u32>,
    /// Grid cell size (texels): the median longest edge, so a typical face covers a few cells.
    pub(super) cell: f64,
}

impl<'a> MeshFaces<'a> {
    pub(super) fn new(mesh: &Mesh, geom: &SceneGeometry, tris: &'a [TriangleId], texel: f64) -> Self {
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

    pub(super) fn len(&self) -> usize {
        self.tris.len()
    }

    pub(super) fn neighbours(&self, f: u32) -> &[u32] {
        &self.adj[self.adj_start[f as usize] as usize..self.adj_start[f as usize + 1] as usize]
    }

    /// Distance (texels) between the bounding boxes of two faces on the surface: a lower
    /// bound of the distance between the faces.
    pub(super) fn box_distance(&self, f: u32, g: u32) -> f64 {
        let bb = |p: &[DVec3; 3]| (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
        let ((alo, ahi), (blo, bhi)) = (bb(&self.pos[f as usize]), bb(&self.pos[g as usize]));
        (alo - bhi).max(blo - ahi).max(DVec3::ZERO).length()
    }
}

/// A planar projection frame: the plane ⟂ `n` through `origin`.
#[derive(Clone, Copy)]
pub(super) struct Frame {
    pub(super) n: DVec3,
    pub(super) origin: DVec3,
}

impl Frame {
    pub(super) fn project(&self, p: &[DVec3; 3]) -> [DVec2; 3] {
        let (t, b) = self.n.any_orthonormal_pair();
        p.map(|q| {
            let d = q - self.origin;
            DVec2::new(d.dot(t), d.dot(b))
        })
    }
}

/// A positive value with its last bits dropped (about 5 significant digits), so that
/// values equal up to float noise — the areas of a box's opposite faces after it moved —
/// compare equal and fall to the tie-break: the unwrap of a moved mesh is the unwrap of the
/// mesh, made in the same order.
pub(super) fn coarse(x: f64) -> u32 {
    (x as f32).to_bits() >> 6
}
