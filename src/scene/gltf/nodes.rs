//! Scene selection, node hierarchy traversal and world transforms.

use ::gltf::json;
use glam::{DMat4, Mat3, Mat4, Quat, Vec3};

use super::accessor;
use super::diag::{Diagnostics, Kind};
use super::{Ctx, LoadError, LoadOptions};

/// One visited node with its world transform (node → world, metres).
#[derive(Clone, Copy, Debug)]
pub(super) struct NodeInstance {
    pub node: usize,
    /// Node → the scene's frame (world less [`crate::scene::Scene::origin`]; the world
    /// itself until the origin is chosen).
    pub world: Mat4,
    /// Node → world, composed in f64: a model placed kilometres from the file's origin
    /// keeps its millimetres (see [`super::origin`]).
    pub world64: DMat4,
}

/// The scene to load: `options.scene`, else the file's default scene, else the first scene;
/// `None` when the file has no scenes.
pub(super) fn chosen_scene(root: &json::Root, options: &LoadOptions) -> Option<usize> {
    options.scene.or(root.scene.map(|s| s.value())).or((!root.scenes.is_empty()).then_some(0))
}

/// Root nodes to load: `options.scene`, else the file's default scene, else the first scene,
/// else (no scenes at all) every node that is nobody's child.
pub(super) fn scene_roots(ctx: &Ctx, options: &LoadOptions) -> Result<Vec<usize>, LoadError> {
    let root = ctx.root;
    match chosen_scene(root, options) {
        Some(s) => {
            let scene = root.scenes.get(s).ok_or_else(|| {
                ctx.invalid(format!("scene {s} does not exist (the file has {} scenes)", root.scenes.len()))
            })?;
            Ok(scene.nodes.iter().map(|n| n.value()).collect())
        }
        None => {
            let mut is_child = vec![false; root.nodes.len()];
            for node in &root.nodes {
                for c in node.children.iter().flatten() {
                    if let Some(flag) = is_child.get_mut(c.value()) {
                        *flag = true;
                    }
                }
            }
            Ok((0..root.nodes.len()).filter(|&n| !is_child.get(n).copied().unwrap_or(true)).collect())
        }
    }
}

/// Visits the hierarchy below `roots` depth-first (parents before children, in file order)
/// without recursion, so a deep chain cannot overflow the stack. A node reached twice (a
/// cycle, or a node shared by two parents) is an error: glTF requires disjoint trees.
pub(super) fn traverse(ctx: &Ctx, roots: &[usize], diag: &mut Diagnostics) -> Result<Vec<NodeInstance>, LoadError> {
    let nodes = &ctx.root.nodes;
    let mut visited = vec![false; nodes.len()];
    let mut out = Vec::new();
    let mut stack: Vec<(usize, Mat4, DMat4)> =
        roots.iter().rev().map(|&n| (n, Mat4::IDENTITY, DMat4::IDENTITY)).collect();
    while let Some((index, parent, parent64)) = stack.pop() {
        let node = nodes
            .get(index)
            .ok_or_else(|| ctx.invalid(format!("node {index} does not exist ({} nodes)", nodes.len())))?;
        let seen = visited.get_mut(index).ok_or_else(|| ctx.invalid(format!("node {index} does not exist")))?;
        if *seen {
            return Err(ctx.invalid(format!(
                "node {index}{} is reached twice: the node hierarchy has a cycle or a node with two parents",
                name_suffix(&node.name)
            )));
        }
        *seen = true;
        let local = local_transform(ctx, index, node, diag)?;
        let (world, world64) = (parent * local, parent64 * local.as_dmat4());
        if !world.is_finite() {
            return Err(ctx.invalid(format!(
                "node {index}{}: its world transform overflows to non-finite values",
                name_suffix(&node.name)
            )));
        }
        out.push(NodeInstance { node: index, world, world64 });
        for child in node.children.iter().flatten().rev() {
            stack.push((child.value(), world, world64));
        }
    }
    Ok(out)
}

fn name_suffix(name: &Option<String>) -> String {
    name.as_ref().map(|n| format!(" '{n}'")).unwrap_or_default()
}

/// The node's name, or `node<index>` when it has none.
pub(super) fn node_name(ctx: &Ctx, index: usize) -> String {
    ctx.root.nodes.get(index).and_then(|n| n.name.clone()).unwrap_or_else(|| format!("node{index}"))
}

/// `matrix` (column-major) or `T · R · S`.
fn local_transform(ctx: &Ctx, index: usize, node: &json::Node, diag: &mut Diagnostics) -> Result<Mat4, LoadError> {
    let bad = |what: &str| ctx.invalid(format!("node {index}{}: {what}", name_suffix(&node.name)));
    if let Some(m) = node.matrix {
        let m = Mat4::from_cols_array(&m);
        if !m.is_finite() {
            return Err(bad("matrix has non-finite values"));
        }
        return Ok(m);
    }
    let t = Vec3::from(node.translation.unwrap_or([0.0; 3]));
    let s = Vec3::from(node.scale.unwrap_or([1.0; 3]));
    let q = Quat::from_array(node.rotation.map_or([0.0, 0.0, 0.0, 1.0], |r| r.0));
    if !t.is_finite() || !s.is_finite() || !q.is_finite() {
        return Err(bad("translation, rotation or scale has non-finite values"));
    }
    let len = q.length();
    if len == 0.0 {
        return Err(bad("rotation is the zero quaternion"));
    }
    // glTF asks for unit quaternions; exporters round to ~1e-7. Anything clearly off is reported.
    if (len - 1.0).abs() > 1e-3 {
        diag.note(Kind::UnnormalizedRotation, 1, || node_name(ctx, index));
    }
    Ok(Mat4::from_scale_rotation_translation(s, q / len, t))
}

/// `EXT_mesh_gpu_instancing`: the transforms, relative to node `index`, at which its mesh is
/// drawn, one per instance: T·R·S from the TRANSLATION, ROTATION and SCALE accessors (each
/// optional, identity when absent; all of one count). `None` when the node does not use it.
pub(super) fn instance_transforms(ctx: &Ctx, index: usize) -> Result<Option<Vec<Mat4>>, LoadError> {
    let Some(node) = ctx.root.nodes.get(index) else { return Ok(None) };
    let Some(ext) = node.extensions.as_ref().and_then(|e| e.others.get(INSTANCING)) else { return Ok(None) };
    let bad = |what: String| ctx.invalid(format!("node {index}{}: {INSTANCING}: {what}", name_suffix(&node.name)));
    let attributes = ext.get("attributes").and_then(|a| a.as_object()).ok_or_else(|| bad("no attributes".into()))?;
    let accessor = |name: &str| -> Result<Option<usize>, LoadError> {
        match attributes.get(name) {
            None => Ok(None),
            Some(v) => v
                .as_u64()
                .and_then(|i| usize::try_from(i).ok())
                .map(Some)
                .ok_or_else(|| bad(format!("{name} is not an accessor index"))),
        }
    };
    let (t, r, s) = (accessor("TRANSLATION")?, accessor("ROTATION")?, accessor("SCALE")?);
    let mut counts = Vec::new();
    for i in [t, r, s].into_iter().flatten() {
        counts.push(accessor::count(ctx, i)?);
    }
    let Some(&count) = counts.first() else { return Err(bad("none of TRANSLATION, ROTATION, SCALE".into())) };
    if counts.iter().any(|&c| c != count) {
        return Err(bad(format!("its accessors hold different counts of instances ({counts:?})")));
    }
    let what = |name: &str| format!("{INSTANCING} {name} of node {index}");
    let t = t.map(|i| accessor::read_vec3(ctx, i, &what("TRANSLATION"))).transpose()?;
    let r = r.map(|i| accessor::read_vec4(ctx, i, &what("ROTATION"))).transpose()?;
    let s = s.map(|i| accessor::read_vec3(ctx, i, &what("SCALE"))).transpose()?;
    (0..count)
        .map(|k| {
            let t = t.as_ref().map_or(Vec3::ZERO, |t| t[k]);
            let s = s.as_ref().map_or(Vec3::ONE, |s| s[k]);
            let q = r.as_ref().map_or(Quat::IDENTITY, |r| Quat::from_vec4(r[k]));
            let len = q.length();
            if !(t.is_finite() && s.is_finite() && q.is_finite()) || len == 0.0 {
                return Err(bad(format!("instance {k} has a non-finite value or a zero rotation")));
            }
            Ok(Mat4::from_scale_rotation_translation(s, q / len, t))
        })
        .collect::<Result<Vec<_>, _>>()
        .map(Some)
}

/// The instancing extension's name.
const INSTANCING: &str = "EXT_mesh_gpu_instancing";

/// How normals transform: the inverse transpose of the linear part, computed as the cofactor
/// matrix (`det · M⁻ᵀ`) times the sign of `det`, so it stays defined (and right up to length)
/// for singular matrices; normals are renormalised afterwards. With a mirroring transform the
/// triangle winding is flipped too, and then this keeps the shading normals on the front side.
pub(super) fn normal_matrix(world: &Mat4) -> Mat3 {
    let m = Mat3::from_mat4(*world);
    let cof = Mat3::from_cols(m.y_axis.cross(m.z_axis), m.z_axis.cross(m.x_axis), m.x_axis.cross(m.y_axis));
    if m.determinant() < 0.0 { -cof } else { cof }
}

/// Whether the transform mirrors (negative determinant): front faces would turn into back
/// faces unless the winding is flipped.
pub(super) fn mirrors(world: &Mat4) -> bool {
    Mat3::from_mat4(*world).determinant() < 0.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_matrix_is_inverse_transpose_up_to_scale() {
        let world = Mat4::from_scale_rotation_translation(
            Vec3::new(2.0, -0.5, 3.0),
            Quat::from_rotation_y(0.7),
            Vec3::new(1.0, 2.0, 3.0),
        );
        let expected = Mat3::from_mat4(world).inverse().transpose();
        let got = normal_matrix(&world);
        for n in [Vec3::X, Vec3::Y, Vec3::Z, Vec3::new(1.0, 2.0, -3.0)] {
            let a = (expected * n).normalize();
            let b = (got * n).normalize();
            assert!((a - b).length() < 1e-6, "{a} vs {b}");
        }
        assert!(mirrors(&world));
    }

    #[test]
    fn normal_matrix_survives_flattening() {
        // Scale z to 0: the xy-plane normal still maps to ±z, not NaN.
        let world = Mat4::from_scale(Vec3::new(1.0, 1.0, 0.0));
        let n = normal_matrix(&world) * Vec3::Z;
        assert_eq!(n.normalize(), Vec3::Z);
    }
}
