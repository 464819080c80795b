//! New vertex data for one side of one mesh instance: world-space positions and normals, the
//! original TEXCOORD_0 (and TEXCOORD_1 when a material texture reads it), vertex colours,
//! and the light-map layout as TEXCOORD_1. A vertex is split wherever the faces around it sit in different
//! places of the atlas (chart seams, and always between the front and the back).

use std::collections::HashMap;

use glam::{Vec2, Vec3, Vec4};

use crate::atlas::Atlas;
use crate::scene::{Mesh, Side, TriangleId};

/// One single-sided primitive: the front faces of a mesh, or its back faces with the
/// winding reversed and the normals negated (so the back is an ordinary front-facing surface).
#[derive(Clone, Debug, Default, PartialEq)]
pub(super) struct SidePrimitive {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    /// TEXCOORD_0; zeros when the file had none (glTF wants TEXCOORD_0 before TEXCOORD_1, and
    /// no material texture of a valid file reads a set the primitive lacks).
    pub uv0: Vec<Vec2>,
    /// The file's own TEXCOORD_1, written as TEXCOORD_2 when a material texture reads it.
    pub original_uv1: Option<Vec<Vec2>>,
    /// COLOR_0 (linear RGBA), when the mesh has vertex colours.
    pub colors: Option<Vec<Vec4>>,
    /// Light-map UV in [0, 1] over the whole atlas (any LOD).
    pub lightmap_uv: Vec<Vec2>,
    /// Counter-clockwise triangles, as seen from the side's normal.
    pub triangles: Vec<[u32; 3]>,
}

/// The faces of `side` of `mesh`, whose first triangle has global id `first_tri` in the
/// atlas's numbering ([`crate::scene::SceneGeometry`] order). `None` when the mesh has no face
/// on that side (single-sided materials have no back). Triangles without a face (degenerate
/// ones the atlas left out) are left out too: they have no light-map texels to address.
pub(super) fn build_side(
    mesh: &Mesh,
    first_tri: TriangleId,
    atlas: &Atlas,
    side: Side,
    keep_uv1: bool,
) -> Option<SidePrimitive> {
    // Corner order per triangle: the back reverses the winding so it faces −n.
    let order: [usize; 3] = match side {
        Side::Front => [0, 1, 2],
        Side::Back => [0, 2, 1],
    };
    let size = Vec2::new(atlas.width as f32, atlas.height as f32);
    let mut out = SidePrimitive {
        original_uv1: if keep_uv1 { Some(Vec::new()) } else { None },
        colors: mesh.colors.as_ref().map(|_| Vec::new()),
        ..SidePrimitive::default()
    };
    // (source vertex, light-map UV bits) → new vertex: a vertex is shared only by faces that
    // put it at the same place of the atlas.
    let mut index: HashMap<(u32, [u32; 2]), u32> = HashMap::new();
    for (t, tri) in mesh.triangles.iter().enumerate() {
        let Some(f) = atlas.face(first_tri + t as TriangleId, side) else { continue };
        let face = &atlas.faces[f as usize];
        let mut corners = [0u32; 3];
        for (slot, &k) in corners.iter_mut().zip(&order) {
            let v = tri[k];
            // Correctly rounded division: within 2⁻²⁴ (relative) of the exact normalised UV.
            let uv = face.uv[k] / size;
            *slot = *index.entry((v, [uv.x.to_bits(), uv.y.to_bits()])).or_insert_with(|| {
                let vi = v as usize;
                out.positions.push(mesh.positions[vi]);
                out.normals.push(mesh.normals[vi] * side.sign());
                out.uv0.push(mesh.uv0.as_ref().map_or(Vec2::ZERO, |src| src[vi]));
                if let Some(dst) = &mut out.original_uv1 {
                    // A material reads TEXCOORD_1 but the file had none (or an unusable one):
                    // the file was already broken there; zeros keep the output valid.
                    dst.push(mesh.uv1.as_ref().map_or(Vec2::ZERO, |src| src[vi]));
                }
                if let (Some(dst), Some(src)) = (&mut out.colors, &mesh.colors) {
                    dst.push(src[vi]);
                }
                out.lightmap_uv.push(uv);
                (out.positions.len() - 1) as u32
            });
        }
        out.triangles.push(corners);
    }
    (!out.triangles.is_empty()).then_some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atlas::AtlasConfig;
    use crate::scene::{Material, Scene, SceneGeometry};

    /// A unit quad (two triangles sharing an edge) with the given material.
    fn quad_scene(double_sided: bool) -> Scene {
        let mesh = Mesh {
            name: "quad".into(),
            node: None,
            material: 0,
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y],
            normals: vec![Vec3::Z; 4],
            uv0: Some(vec![Vec2::ZERO, Vec2::X, Vec2::ONE, Vec2::Y]),
            uv1: None,
            colors: None,
            triangles: vec![[0, 1, 2], [0, 2, 3]],
        };
        Scene {
            meshes: vec![mesh],
            materials: vec![Material { double_sided, ..Material::default() }],
            ..Scene::default()
        }
    }

    fn atlas_of(scene: &Scene) -> Atlas {
        let geom = SceneGeometry::new(scene);
        Atlas::build(scene, &geom, &AtlasConfig { texel_size: Some(0.1), ..AtlasConfig::default() }).unwrap()
    }

    #[test]
    fn front_keeps_winding_and_shares_vertices_within_a_chart() {
        let scene = quad_scene(false);
        let atlas = atlas_of(&scene);
        let mesh = &scene.meshes[0];
        let front = build_side(mesh, 0, &atlas, Side::Front, false).unwrap();
        assert!(build_side(mesh, 0, &atlas, Side::Back, false).is_none(), "a single-sided mesh has no back");
        // One planar chart: the shared edge keeps its two vertices.
        assert_eq!(front.positions.len(), 4);
        assert_eq!(front.triangles.len(), 2);
        for (t, tri) in front.triangles.iter().enumerate() {
            let p = tri.map(|i| front.positions[i as usize]);
            assert_eq!(p, mesh.corners(t), "corner order of triangle {t}");
            // The new TEXCOORD_1 is the atlas UV of that corner, normalised.
            let f = atlas.face(t as TriangleId, Side::Front).unwrap();
            for (&vertex, uv) in tri.iter().zip(atlas.faces[f as usize].uv) {
                let expected = uv / Vec2::new(atlas.width as f32, atlas.height as f32);
                assert_eq!(front.lightmap_uv[vertex as usize], expected);
            }
        }
        assert!(front.lightmap_uv.iter().all(|uv| (0.0..=1.0).contains(&uv.x) && (0.0..=1.0).contains(&uv.y)));
        assert!(front.normals.iter().all(|&n| n == Vec3::Z));
        assert_eq!(front.uv0, mesh.uv0.clone().unwrap());
    }

    #[test]
    fn back_is_reversed_negated_and_uses_the_back_chart() {
        let scene = quad_scene(true);
        let atlas = atlas_of(&scene);
        let mesh = &scene.meshes[0];
        let front = build_side(mesh, 0, &atlas, Side::Front, false).unwrap();
        let back = build_side(mesh, 0, &atlas, Side::Back, true).unwrap();
        assert!(back.normals.iter().all(|&n| n == -Vec3::Z));
        for (t, tri) in back.triangles.iter().enumerate() {
            let [a, b, c] = tri.map(|i| back.positions[i as usize]);
            // Counter-clockwise seen from −z: the geometric normal points down.
            assert!((b - a).cross(c - a).z < 0.0, "triangle {t} must face −z");
            let f = atlas.face(t as TriangleId, Side::Back).unwrap();
            let uv = atlas.faces[f as usize].uv;
            let s = Vec2::new(atlas.width as f32, atlas.height as f32);
            assert_eq!(back.lightmap_uv[tri[1] as usize], uv[2] / s);
            assert_eq!(back.lightmap_uv[tri[2] as usize], uv[1] / s);
        }
        // Front and back charts are different rectangles of the atlas.
        let (f0, b0) = (front.lightmap_uv[0], back.lightmap_uv[0]);
        assert_ne!(f0, b0);
        // Without a file TEXCOORD_1, the kept set is zeros.
        assert!(back.original_uv1.unwrap().iter().all(|&v| v == Vec2::ZERO));
    }
}
