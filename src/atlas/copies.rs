//! Rigid copies among the scene's meshes (instancing nodes: the loader gives each copy its
//! own world-space mesh): a copy takes its original's charts, unwrapped once, instead of
//! being unwrapped again.

use super::MeshCharts;
use super::charts;
use crate::scene::{Scene, SceneGeometry, TriangleId};

/// What a rigid copy of a mesh (an instancing node: the loader gives each its own
/// world-space mesh) takes from its original: the original's charts, unwrapped once, with
/// triangle ids shifted and UVs (metres) scaled.
pub(super) struct CopyOf {
    pub(super) mesh: u32,
    /// The original's lit triangles (what its charts are made from).
    pub(super) tris: Vec<TriangleId>,
    /// This mesh's triangle id minus the original's, triangle for triangle.
    pub(super) offset: i64,
    /// This mesh's lengths over the original's.
    pub(super) scale: f64,
}

/// Relative tolerance of the copy test on lengths and volumes (f32 positions moved by a
/// node transform agree to ~10⁻⁶), beside the rounding of the positions' magnitudes.
const COPY_TOLERANCE: f64 = 1e-4;

/// Marks each mesh that is a rigid copy (rotation, translation, uniform scale, no mirror) of
/// an earlier one, with the same triangles and material, as such: its charts are the
/// original's. Each candidate pair is verified triangle by triangle (every edge's length,
/// and the signed volume with the next triangle's first corner), never assumed from a name.
pub(super) fn link_copies(scene: &Scene, geom: &SceneGeometry, meshes: &mut [MeshCharts]) {
    use std::collections::HashMap;
    use std::hash::{Hash, Hasher};
    let mut originals: HashMap<u64, Vec<usize>> = HashMap::new();
    for i in 0..meshes.len() {
        if meshes[i].try_uv1 {
            continue;
        }
        let mesh = &scene.meshes[meshes[i].mesh as usize];
        let first = geom.mesh_offsets[meshes[i].mesh as usize] as i64;
        let mut h = charts::FxHasher::default();
        (mesh.material, mesh.positions.len(), meshes[i].back).hash(&mut h);
        mesh.triangles.hash(&mut h);
        for &t in &meshes[i].tris {
            (t as i64 - first).hash(&mut h);
        }
        let key = h.finish();
        let found = originals.get(&key).and_then(|list| {
            list.iter().find_map(|&o| rigid_copy(scene, geom, &meshes[o], &meshes[i]).map(|c| (o, c)))
        });
        match found {
            Some((o, copy)) => {
                meshes[i].unwrapped = meshes[o].unwrapped.clone();
                meshes[i].hint = meshes[o].hint;
                meshes[i].copy_of = Some(copy);
            }
            None => originals.entry(key).or_default().push(i),
        }
    }
}

/// `copy` as a rigid copy of `original`, if it is one.
pub(super) fn rigid_copy(
    scene: &Scene,
    geom: &SceneGeometry,
    original: &MeshCharts,
    copy: &MeshCharts,
) -> Option<CopyOf> {
    let (a, b) = (&scene.meshes[original.mesh as usize], &scene.meshes[copy.mesh as usize]);
    if a.material != b.material
        || a.triangles != b.triangles
        || a.positions.len() != b.positions.len()
        || original.tris.len() != copy.tris.len()
        || original.back != copy.back
    {
        return None;
    }
    let offset = geom.mesh_offsets[copy.mesh as usize] as i64 - geom.mesh_offsets[original.mesh as usize] as i64;
    if original.tris.iter().zip(&copy.tris).any(|(&s, &t)| t as i64 - s as i64 != offset) {
        return None;
    }
    let pa = |i: u32| a.positions[i as usize].as_dvec3();
    let pb = |i: u32| b.positions[i as usize].as_dvec3();
    let far = (0..a.positions.len() as u32)
        .max_by(|&i, &j| (pa(i) - pa(0)).length_squared().total_cmp(&(pa(j) - pa(0)).length_squared()))?;
    // How far f32 rounding may have moved a position, in the copy's units: a copy placed
    // far from the origin rounds its small triangles by more than the relative tolerance
    // (0.1 m from the origin of a 140 m scene, a 5 cm edge is 3·10⁻⁴ off).
    let reach = |m: &crate::scene::Mesh| m.positions.iter().fold(0.0f64, |r, p| r.max(p.abs().max_element() as f64));
    let (reach_a, reach_b) = (reach(a), reach(b));
    let mut scale = None;
    let mut rounding = 0.0;
    for tri in &a.triangles {
        for e in 0..3 {
            let (i, j) = (tri[e], tri[(e + 1) % 3]);
            let (la, lb) = ((pa(j) - pa(i)).length(), (pb(j) - pb(i)).length());
            let s = *scale.get_or_insert_with(|| {
                let s = if la > 0.0 { lb / la } else { 1.0 };
                rounding = 8.0 * f32::EPSILON as f64 * (s * reach_a + reach_b);
                s
            });
            if (lb - s * la).abs() > COPY_TOLERANCE * (s * la).max(1e-9) + 2.0 * rounding {
                return None;
            }
        }
        // A mirror keeps every length: the signed volume with a far vertex tells it (zero
        // for a planar mesh, whose mirror image is a turned copy).
        let vol = |p: &dyn Fn(u32) -> glam::DVec3| {
            let o = p(tri[0]);
            (p(tri[1]) - o).cross(p(tri[2]) - o).dot(p(far) - o)
        };
        let (va, vb) = (vol(&pa), vol(&pb));
        let s3 = scale.unwrap_or(1.0).powi(3);
        let lengths = |p: &dyn Fn(u32) -> glam::DVec3| {
            let o = p(tri[0]);
            [(p(tri[1]) - o).length(), (p(tri[2]) - o).length(), (p(far) - o).length()]
        };
        let [e1, e2, f] = lengths(&pa);
        let [g1, g2, h] = lengths(&pb);
        // Each vector's rounding times the other two lengths, both meshes' corners.
        let rounded = 2.0 * rounding * (g1 * g2 + g1 * h + g2 * h);
        if (vb - s3 * va).abs() > COPY_TOLERANCE * s3 * (e1 * e2 * f).max(1e-12) + rounded {
            return None;
        }
    }
    let scale = scale?;
    (scale.is_finite() && scale > 0.0).then(|| CopyOf {
        mesh: original.mesh,
        tris: original.tris.clone(),
        offset,
        scale,
    })
}
