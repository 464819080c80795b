//! One mesh primitive instanced by one node → one world-space [`Mesh`]: topology to a triangle
//! list, world transform (with winding flip for mirrors), degenerate-triangle removal, shading
//! normals (transformed, repaired or generated flat), texture coordinates, vertex colours.

use ::gltf::json;
use glam::{DMat4, Mat4, Vec2, Vec3, Vec4};
use json::mesh::{Mode, Semantic};
use json::validation::Checked;

use super::accessor;
use super::diag::{Diagnostics, Kind};
use super::nodes::{mirrors, normal_matrix};
use super::{Ctx, LoadError};
use crate::scene::{MaterialId, Mesh};

/// What to build: the primitive, where it is and what to call it.
pub(super) struct Instance<'a> {
    pub prim: &'a json::mesh::Primitive,
    pub node: usize,
    /// Into the scene's frame.
    pub world: Mat4,
    /// The same in `f64`, for a scene moved to an origin of its own
    /// ([`super::origin`]): positions go through it and are rounded to `f32` once, near the
    /// origin. `None`: the scene keeps the file's origin, and `world` places them.
    pub world64: Option<DMat4>,
    /// `node/mesh/primitive-index`.
    pub name: String,
    pub material: MaterialId,
}

/// What became of a primitive.
pub(super) enum Built {
    Mesh(Mesh),
    /// POINTS / LINES / LINE_LOOP / LINE_STRIP.
    NotTriangles,
    /// Every triangle was degenerate (or there were none).
    Empty,
    /// NORMAL was absent and flat normals were generated.
    GeneratedNormals(Mesh),
}

/// Below this, `|e1 × e2| ≤ DEGENERATE · L²` (L = longest edge), a triangle is dropped.
/// `|e1 × e2| / L` is the triangle's height, so the test asks whether the height is below
/// ~5·10⁻⁷ of the longest edge. That is the size of the f32 rounding error of the cross product
/// itself (a few ulps of |e1|·|e2| ≤ L²): below it the face normal is noise and the area is
/// negligible, while any triangle a modeller made on purpose is far above it. The test is
/// scale-free (the same shape is kept or dropped at any size) and catches exact zeros (repeated
/// indices, collinear or coincident corners).
const DEGENERATE: f32 = 4.0 * f32::EPSILON;

pub(super) fn build(ctx: &Ctx, diag: &mut Diagnostics, inst: &Instance) -> Result<Built, LoadError> {
    let mode = match inst.prim.mode {
        Checked::Valid(m) => m,
        Checked::Invalid => return Err(ctx.invalid(format!("mesh instance '{}': invalid primitive mode", inst.name))),
    };
    if matches!(mode, Mode::Points | Mode::Lines | Mode::LineLoop | Mode::LineStrip) {
        diag.note(Kind::NonTrianglePrimitive, 1, || format!("{} ({mode:?})", inst.name));
        return Ok(Built::NotTriangles);
    }
    if inst.prim.targets.as_ref().is_some_and(|t| !t.is_empty()) {
        diag.note(Kind::IgnoredMorphTargets, 1, || inst.name.clone());
    }

    let local = read_positions(ctx, inst)?;
    let vertex_count = local.len();
    let indices = read_or_make_indices(ctx, inst, vertex_count)?;
    let (mut triangles, trailing) = assemble(mode, &indices);
    diag.note(Kind::TrailingIndices, trailing, || inst.name.clone());

    let positions = to_world(ctx, inst, &local)?;
    if mirrors(&inst.world) {
        for t in &mut triangles {
            t.swap(1, 2);
        }
    }
    if let Some(t) = triangles.iter().position(|&t| overflows(corners(&positions, t))) {
        let [a, b, c] = corners(&positions, triangles[t]);
        let largest = a.abs().max(b.abs()).max(c.abs()).max_element();
        return Err(ctx.invalid(format!(
            "mesh instance '{}': the area of triangle {t} overflows f32 (coordinates up to {largest:e} m): \
             positions this far out cannot be light-mapped",
            inst.name
        )));
    }
    let before = triangles.len();
    triangles.retain(|&t| !is_degenerate(corners(&positions, t)));
    diag.note(Kind::DegenerateTriangles, before - triangles.len(), || inst.name.clone());
    if triangles.is_empty() {
        diag.note(Kind::EmptyMesh, 1, || inst.name.clone());
        return Ok(Built::Empty);
    }

    let uv0 = read_uv0(ctx, diag, inst, vertex_count)?;
    let uv1 = read_uv1(ctx, diag, inst, vertex_count)?;
    let colors = read_colors(ctx, inst, vertex_count)?;
    let mut mesh = Mesh {
        name: inst.name.clone(),
        node: Some(inst.node),
        material: inst.material,
        positions,
        normals: Vec::new(),
        uv0,
        uv1,
        colors,
        triangles,
    };
    match attribute(inst.prim, Semantic::Normals) {
        Some(acc) => {
            let file_normals = accessor::read_vec3(ctx, acc, &format!("NORMAL of '{}'", inst.name))?;
            check_count(ctx, inst, acc, "NORMAL", file_normals.len(), vertex_count)?;
            let (normals, bad) = shading_normals(&file_normals, &inst.world, &mesh.positions, &mesh.triangles);
            diag.note(Kind::BadNormals, bad, || inst.name.clone());
            mesh.normals = normals;
            Ok(Built::Mesh(mesh))
        }
        None => {
            flatten(&mut mesh);
            Ok(Built::GeneratedNormals(mesh))
        }
    }
}

/// At most how many triangles `prim` makes, from its accessors' counts (nothing is read).
pub(super) fn triangle_bound(ctx: &Ctx, prim: &json::mesh::Primitive) -> Result<u64, LoadError> {
    let count = match (prim.indices, attribute(prim, Semantic::Positions)) {
        (Some(i), _) => accessor::count(ctx, i.value())? as u64,
        (None, Some(p)) => accessor::count(ctx, p)? as u64,
        (None, None) => 0,
    };
    Ok(match prim.mode {
        Checked::Valid(Mode::Triangles) => count / 3,
        Checked::Valid(Mode::TriangleStrip | Mode::TriangleFan) => count.saturating_sub(2),
        _ => 0,
    })
}

/// The primitive's POSITION accessor, if it has one.
pub(super) fn position_accessor(prim: &json::mesh::Primitive) -> Option<usize> {
    attribute(prim, Semantic::Positions)
}

fn attribute(prim: &json::mesh::Primitive, semantic: Semantic) -> Option<usize> {
    prim.attributes.get(&Checked::Valid(semantic)).map(|i| i.value())
}

fn check_count(
    ctx: &Ctx,
    inst: &Instance,
    acc: usize,
    what: &str,
    got: usize,
    expected: usize,
) -> Result<(), LoadError> {
    if got == expected {
        return Ok(());
    }
    Err(ctx.invalid(format!(
        "mesh instance '{}': {what} (accessor {acc}) has {got} elements but POSITION has {expected}",
        inst.name
    )))
}

fn read_positions(ctx: &Ctx, inst: &Instance) -> Result<Vec<Vec3>, LoadError> {
    let acc = position_accessor(inst.prim)
        .ok_or_else(|| ctx.invalid(format!("mesh instance '{}' has no POSITION attribute", inst.name)))?;
    let positions = accessor::read_vec3(ctx, acc, &format!("POSITION of '{}'", inst.name))?;
    check_finite(ctx, inst, "POSITION", &positions)?;
    Ok(positions)
}

fn check_finite(ctx: &Ctx, inst: &Instance, attribute: &str, values: &[Vec3]) -> Result<(), LoadError> {
    match values.iter().position(|p| !p.is_finite()) {
        None => Ok(()),
        Some(vertex) => Err(LoadError::NonFinite {
            file: ctx.file.into(),
            mesh: inst.name.clone(),
            attribute: attribute.into(),
            vertex,
            value: values.get(vertex).map(|v| format!("{v}")).unwrap_or_default(),
        }),
    }
}

/// COLOR_0 as linear RGBA (alpha 1 where the accessor is VEC3), or `None` where the
/// primitive has none or it is white everywhere (it then changes nothing, and a mesh without
/// it keeps the uniform-albedo paths). glTF allows float and normalised unsigned byte and
/// short components; other encodings and values that are not finite are errors naming the
/// mesh. Values are clamped to [0, 1], the range the glTF spec gives them.
fn read_colors(ctx: &Ctx, inst: &Instance, vertex_count: usize) -> Result<Option<Vec<Vec4>>, LoadError> {
    let Some(acc) = attribute(inst.prim, Semantic::Colors(0)) else { return Ok(None) };
    let colors = accessor::read_color(ctx, acc, &format!("COLOR_0 of '{}'", inst.name))?;
    check_count(ctx, inst, acc, "COLOR_0", colors.len(), vertex_count)?;
    if let Some(vertex) = colors.iter().position(|c| !c.is_finite()) {
        return Err(LoadError::NonFinite {
            file: ctx.file.into(),
            mesh: inst.name.clone(),
            attribute: "COLOR_0".into(),
            vertex,
            value: format!("{}", colors[vertex]),
        });
    }
    let colors: Vec<Vec4> = colors.into_iter().map(|c| c.clamp(Vec4::ZERO, Vec4::ONE)).collect();
    Ok((!colors.iter().all(|&c| c == Vec4::ONE)).then_some(colors))
}

fn read_or_make_indices(ctx: &Ctx, inst: &Instance, vertex_count: usize) -> Result<Vec<u32>, LoadError> {
    let Some(acc) = inst.prim.indices.map(|i| i.value()) else {
        let n = u32::try_from(vertex_count)
            .map_err(|_| ctx.invalid(format!("mesh instance '{}' has more than 2³² vertices", inst.name)))?;
        return Ok((0..n).collect());
    };
    let indices = accessor::read_indices(ctx, acc, &format!("indices of '{}'", inst.name))?;
    if let Some((position, &index)) = indices.iter().enumerate().find(|&(_, &i)| i as usize >= vertex_count) {
        return Err(LoadError::IndexOutOfRange {
            file: ctx.file.into(),
            mesh: inst.name.clone(),
            position,
            index,
            vertex_count,
        });
    }
    Ok(indices)
}

/// Triangle list from TRIANGLES / TRIANGLE_STRIP / TRIANGLE_FAN, keeping glTF's front-face
/// winding (glTF 2.0 §3.7.2.1): strip triangle i is (v_i, v_{i+1+i%2}, v_{i+2−i%2}) — every other
/// triangle is reversed so all face the same way — and fan triangle i is (v_{i+1}, v_{i+2}, v_0).
/// Returns the triangles and how many trailing indices made no whole triangle.
fn assemble(mode: Mode, idx: &[u32]) -> (Vec<[u32; 3]>, usize) {
    match mode {
        Mode::TriangleStrip => {
            let tris = idx
                .windows(3)
                .enumerate()
                .map(|(i, w)| if i % 2 == 0 { [w[0], w[1], w[2]] } else { [w[0], w[2], w[1]] })
                .collect();
            (tris, 0)
        }
        Mode::TriangleFan => match idx.split_first() {
            Some((&v0, rest)) => (rest.windows(2).map(|w| [w[0], w[1], v0]).collect(), 0),
            None => (Vec::new(), 0),
        },
        _ => {
            let chunks = idx.chunks_exact(3);
            let trailing = chunks.remainder().len();
            (chunks.map(|c| [c[0], c[1], c[2]]).collect(), trailing)
        }
    }
}

fn to_world(ctx: &Ctx, inst: &Instance, local: &[Vec3]) -> Result<Vec<Vec3>, LoadError> {
    let world: Vec<Vec3> = match inst.world64 {
        Some(m) => local.iter().map(|&p| m.transform_point3(p.as_dvec3()).as_vec3()).collect(),
        None => local.iter().map(|&p| inst.world.transform_point3(p)).collect(),
    };
    check_finite(ctx, inst, "POSITION (after the node transform)", &world)?;
    Ok(world)
}

/// Positions of the corners of `t`; indices were checked against the vertex count.
fn corners(positions: &[Vec3], t: [u32; 3]) -> [Vec3; 3] {
    t.map(|i| positions.get(i as usize).copied().unwrap_or(Vec3::ZERO))
}

/// Whether a triangle of finite corners has an area (or edge lengths squared) beyond f32.
fn overflows([a, b, c]: [Vec3; 3]) -> bool {
    let (ab, ac, bc) = (b - a, c - a, c - b);
    let longest2 = ab.length_squared().max(ac.length_squared()).max(bc.length_squared());
    !(ab.cross(ac).length().is_finite() && longest2.is_finite())
}

fn is_degenerate([a, b, c]: [Vec3; 3]) -> bool {
    let (ab, ac, bc) = (b - a, c - a, c - b);
    let longest2 = ab.length_squared().max(ac.length_squared()).max(bc.length_squared());
    let (twice_area, limit) = (ab.cross(ac).length(), DEGENERATE * longest2);
    // NaN or overflow counts as degenerate too.
    !(twice_area.is_finite() && limit.is_finite() && twice_area > limit)
}

/// Unnormalised front-face normal (length = twice the area).
fn face_cross(positions: &[Vec3], t: [u32; 3]) -> Vec3 {
    let [a, b, c] = corners(positions, t);
    (b - a).cross(c - a)
}

/// File normals through the normal matrix, normalised. Zero or non-finite ones (in the file or
/// after a singular transform) become the area-weighted mean of the face normals around the
/// vertex (the face normal itself for an unshared vertex). Returns the normals and how many were
/// replaced.
fn shading_normals(file: &[Vec3], world: &Mat4, positions: &[Vec3], triangles: &[[u32; 3]]) -> (Vec<Vec3>, usize) {
    let nm = normal_matrix(world);
    let mut normals: Vec<Option<Vec3>> =
        file.iter().map(|&n| Some(nm * n).filter(|v| v.is_finite()).and_then(|v| v.try_normalize())).collect();
    let bad = normals.iter().filter(|n| n.is_none()).count();
    if bad == 0 {
        return (normals.into_iter().map(|n| n.unwrap_or(Vec3::Z)).collect(), 0);
    }
    let mut sums = vec![Vec3::ZERO; normals.len()];
    for &t in triangles {
        let n = face_cross(positions, t);
        for i in t {
            if let Some(s) = sums.get_mut(i as usize) {
                *s += n;
            }
        }
    }
    for (n, s) in normals.iter_mut().zip(&sums) {
        if n.is_none() {
            *n = Some(s.try_normalize().unwrap_or(Vec3::Z));
        }
    }
    (normals.into_iter().map(|n| n.unwrap_or(Vec3::Z)).collect(), bad)
}

/// Flat shading (what glTF specifies when NORMAL is absent): every triangle gets its own three
/// vertices carrying its face normal.
fn flatten(mesh: &mut Mesh) {
    let n = mesh.triangles.len() * 3;
    let mut positions = Vec::with_capacity(n);
    let mut normals = Vec::with_capacity(n);
    let mut uv0 = mesh.uv0.as_ref().map(|_| Vec::with_capacity(n));
    let mut uv1 = mesh.uv1.as_ref().map(|_| Vec::with_capacity(n));
    let pick2 = |src: &Option<Vec<Vec2>>, dst: &mut Option<Vec<Vec2>>, i: u32| {
        if let (Some(src), Some(dst)) = (src, dst) {
            dst.push(src.get(i as usize).copied().unwrap_or(Vec2::ZERO));
        }
    };
    for &t in &mesh.triangles {
        let face = face_cross(&mesh.positions, t).normalize_or(Vec3::Z);
        for (p, i) in corners(&mesh.positions, t).into_iter().zip(t) {
            positions.push(p);
            normals.push(face);
            pick2(&mesh.uv0, &mut uv0, i);
            pick2(&mesh.uv1, &mut uv1, i);
        }
    }
    mesh.triangles = (0..mesh.triangles.len() as u32).map(|k| [3 * k, 3 * k + 1, 3 * k + 2]).collect();
    mesh.positions = positions;
    mesh.normals = normals;
    mesh.uv0 = uv0;
    mesh.uv1 = uv1;
}

/// TEXCOORD_0: non-finite values become (0, 0) (counted).
fn read_uv0(ctx: &Ctx, diag: &mut Diagnostics, inst: &Instance, n: usize) -> Result<Option<Vec<Vec2>>, LoadError> {
    let Some(acc) = attribute(inst.prim, Semantic::TexCoords(0)) else { return Ok(None) };
    let mut uv = accessor::read_vec2(ctx, acc, &format!("TEXCOORD_0 of '{}'", inst.name))?;
    check_count(ctx, inst, acc, "TEXCOORD_0", uv.len(), n)?;
    let mut bad = 0;
    for v in uv.iter_mut().filter(|v| !v.is_finite()) {
        *v = Vec2::ZERO;
        bad += 1;
    }
    diag.note(Kind::BadTexcoord0, bad, || inst.name.clone());
    Ok(Some(uv))
}

/// TEXCOORD_1 (light-map UV candidates): missing → `None` (normal: most files have none,
/// and the atlas reports how many meshes it unwrapped); non-finite → `None` (warned).
fn read_uv1(ctx: &Ctx, diag: &mut Diagnostics, inst: &Instance, n: usize) -> Result<Option<Vec<Vec2>>, LoadError> {
    let Some(acc) = attribute(inst.prim, Semantic::TexCoords(1)) else {
        return Ok(None);
    };
    let uv = accessor::read_vec2(ctx, acc, &format!("TEXCOORD_1 of '{}'", inst.name))?;
    check_count(ctx, inst, acc, "TEXCOORD_1", uv.len(), n)?;
    if uv.iter().all(|v| v.is_finite()) {
        Ok(Some(uv))
    } else {
        diag.note(Kind::BadTexcoord1, 1, || inst.name.clone());
        Ok(None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strips_alternate_and_fans_pivot() {
        let (s, _) = assemble(Mode::TriangleStrip, &[0, 1, 2, 3, 4]);
        assert_eq!(s, vec![[0, 1, 2], [1, 3, 2], [2, 3, 4]]);
        let (f, _) = assemble(Mode::TriangleFan, &[0, 1, 2, 3]);
        assert_eq!(f, vec![[1, 2, 0], [2, 3, 0]]);
        let (t, trailing) = assemble(Mode::Triangles, &[0, 1, 2, 3, 4]);
        assert_eq!((t, trailing), (vec![[0, 1, 2]], 2));
        assert!(assemble(Mode::TriangleStrip, &[0, 1]).0.is_empty());
        assert!(assemble(Mode::TriangleFan, &[]).0.is_empty());
    }

    #[test]
    fn degenerate_test_is_scale_free() {
        for scale in [1e-6f32, 1.0, 1e6] {
            let ok = [Vec3::ZERO, Vec3::X * scale, Vec3::new(0.5, 1e-5, 0.0) * scale];
            let sliver = [Vec3::ZERO, Vec3::X * scale, Vec3::new(0.5, 1e-8, 0.0) * scale];
            assert!(!is_degenerate(ok), "scale {scale}");
            assert!(is_degenerate(sliver), "scale {scale}");
        }
        assert!(is_degenerate([Vec3::ONE; 3]));
        assert!(is_degenerate([Vec3::ZERO, Vec3::X, Vec3::X * 2.0]));
        assert!(is_degenerate([Vec3::ZERO, Vec3::X, Vec3::NAN]));
    }
}
