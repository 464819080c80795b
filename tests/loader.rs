//! glTF loader: the bundled scenes, one test per kind of broken input, geometry/material/light
//! correctness on small files written by the tests, and robustness against truncated and
//! corrupted files.

mod support;

use std::path::{Path, PathBuf};

use glam::{Mat4, Quat, Vec2, Vec3, Vec4};
use livebake::scene::{
    AlphaMode, LightKind, LoadError, LoadOptions, MaterialPoint, Mesh, Projection, Scene, SceneGeometry, WrapMode,
    load_gltf, load_gltf_bytes,
};
use serde_json::{Value, json};
use support::{Doc, FLOAT, U8, U16, base64, glb, png};

// ---------------------------------------------------------------------------------------------
// helpers

fn asset(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets").join(rel)
}

const CORNELL: &str = "cornell_box/cornellBox-2.79-Cycles-gltf.gltf";
const VAN_GOGH: &str = "van_gogh_room/van_gogh_room.gltf";

fn load(path: &Path) -> Result<Scene, LoadError> {
    load_gltf(path, &LoadOptions::default())
}

/// Loads a file that must fail and checks the message names the file.
fn load_err(path: &Path) -> LoadError {
    let e = match load(path) {
        Ok(_) => panic!("{} loaded but should not have", path.display()),
        Err(e) => e,
    };
    let msg = e.to_string();
    assert!(msg.starts_with(&path.display().to_string()), "message does not name the file: {msg}");
    assert_eq!(e.file(), path);
    e
}

fn tmp() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

fn write_json(dir: &Path, name: &str, j: &Value) -> PathBuf {
    write(dir, name, &serde_json::to_vec_pretty(j).unwrap())
}

fn mesh<'a>(s: &'a Scene, name: &str) -> &'a Mesh {
    s.meshes
        .iter()
        .find(|m| m.name == name)
        .unwrap_or_else(|| panic!("no mesh {name}; have {:?}", s.meshes.iter().map(|m| &m.name).collect::<Vec<_>>()))
}

fn face_normal(m: &Mesh, t: usize) -> Vec3 {
    let [a, b, c] = m.corners(t);
    (b - a).cross(c - a).normalize()
}

fn close(a: Vec3, b: Vec3, tol: f32) -> bool {
    (a - b).abs().max_element() <= tol
}

#[track_caller]
fn assert_close(a: Vec3, b: Vec3, tol: f32) {
    assert!(close(a, b, tol), "{a} != {b} (tolerance {tol})");
}

const TRI: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
const UP_Z: [[f32; 3]; 3] = [[0.0, 0.0, 1.0]; 3];

/// One triangle facing +Z with +Z normals on a root node.
fn one_triangle_doc() -> Doc {
    let mut d = Doc::new();
    let p = d.prim(&TRI, Some(&UP_Z), None);
    d.mesh_node(vec![p], json!({ "name": "tri" }));
    d
}

/// glTF JSON of a document whose buffer is the external `<name>.bin` (written too).
fn gltf_json(doc: &Doc, dir: &Path, name: &str) -> Value {
    doc.write_gltf(dir, name);
    doc.json_with_buffer(Some(format!("{name}.bin")))
}

// ---------------------------------------------------------------------------------------------
// bundled scenes

#[test]
fn cornell_box_loads_with_its_known_facts() {
    let s = load(&asset(CORNELL)).unwrap();
    assert_eq!(s.triangle_count(), 4410);
    assert_eq!(s.stats.triangles, 4410);
    assert_eq!(s.meshes.len(), 23);
    assert_eq!(s.stats.primitives, 23);
    assert_eq!(s.stats.nodes, 15);
    assert_eq!(s.stats.degenerate_triangles_dropped, 0);
    assert_eq!(s.stats.normals_generated, 0);
    assert_eq!(s.materials.len(), 13, "every primitive has a material: no default added");
    assert_eq!((s.lights.len(), s.cameras.len()), (0, 0));
    assert_eq!(s.source.as_deref(), Some(asset(CORNELL).as_path()));
    assert_eq!(s.sky, Vec3::ZERO);

    // The room: 4 × 3 × 4 m, x, z ∈ [−2, 2], y ∈ [0, 3].
    let (lo, hi) = s.bounds().unwrap();
    assert_close(lo, Vec3::new(-2.0, 0.0, -2.0), 1e-6);
    assert_close(hi, Vec3::new(2.0, 3.0, 2.0), 1e-6);

    // Two checker textures, sRGB, default sampler (repeat).
    let dims: Vec<_> = s.textures.iter().map(|t| (t.name.as_str(), t.width, t.height)).collect();
    assert_eq!(dims, [("checkerBJS", 1024, 1024), ("checker-meter", 256, 256)]);
    assert!(s.textures.iter().all(|t| t.srgb && t.wrap_s == WrapMode::Repeat && t.wrap_t == WrapMode::Repeat));
    assert!(s.textures.iter().all(|t| t.rgba8.len() == (t.width * t.height) as usize));
    let ground = s.materials.iter().find(|m| m.name == "cornellBox.ground.000").unwrap();
    assert_eq!(ground.base_color_texture.map(|t| s.textures[t.texture].name.as_str()), Some("checker-meter"));

    // One emitter: light.000, emissiveFactor (1, 1, 1).
    let emissive: Vec<_> = s.materials.iter().filter(|m| m.is_emissive()).collect();
    assert_eq!(emissive.len(), 1);
    assert_eq!(emissive[0].name, "light.000");
    assert_eq!(emissive[0].emission, Vec3::ONE);
    assert!(!emissive[0].double_sided);

    // The lamp: a 0.75 × 0.75 × 0.01 m box under the ceiling whose bottom faces down.
    let lamp = mesh(&s, "lamp.000/lamp.000/0");
    assert_eq!(s.material_of(lamp).name, "light.000");
    assert!(lamp.positions.iter().all(|p| (2.99 - 1e-5..=3.0 + 1e-5).contains(&p.y)));
    let g = SceneGeometry::new(&s);
    let lamp_index = s.meshes.iter().position(|m| m.name == lamp.name).unwrap() as u32;
    let lamp_tris: Vec<usize> = (0..g.len()).filter(|&t| g.mesh[t] == lamp_index).collect();
    assert_eq!(lamp_tris.len(), 10);
    let area_weighted: Vec3 = lamp_tris.iter().map(|&t| g.normals[t] * g.areas[t]).sum();
    assert_close(area_weighted, Vec3::new(0.0, -0.5625, 0.0), 1e-4);
    let bottom: Vec<usize> = lamp_tris.iter().copied().filter(|&t| g.areas[t] > 0.2).collect();
    assert_eq!(bottom.len(), 2);
    for t in bottom {
        assert_close(g.normals[t], Vec3::NEG_Y, 1e-6);
        assert!(g.corners[t].iter().all(|c| (c.y - 2.99).abs() < 1e-5));
    }
    // Declared normals agree with the winding everywhere in the lamp and the room.
    for m in s.meshes.iter().filter(|m| m.name.starts_with("lamp") || m.name.starts_with("cornellBox")) {
        for (t, tri) in m.triangles.iter().enumerate() {
            let f = face_normal(m, t);
            for &i in tri {
                assert!(m.normals[i as usize].dot(f) > 0.999, "{}: triangle {t}", m.name);
            }
        }
    }
    // The floor faces up, the ceiling down.
    let floor = mesh(&s, "cornellBox.000/cornellBox.000/3");
    assert!((0..floor.triangles.len()).all(|t| close(face_normal(floor, t), Vec3::Y, 1e-6)));

    // TEXCOORD_1 only where the file has it.
    let with_uv1: Vec<&str> = s.meshes.iter().filter(|m| m.uv1.is_some()).map(|m| m.name.as_str()).collect();
    assert_eq!(with_uv1.len(), 8, "{with_uv1:?}");
    assert!(
        with_uv1
            .iter()
            .all(|n| ["bloc", "suzanne", "cornellBox", "BJS-3D-logo_red01.000"].iter().any(|p| n.starts_with(p)))
    );
    // A missing TEXCOORD_1 is normal (the atlas unwraps those meshes): no warning.
    assert!(s.stats.warnings.iter().all(|w| !w.contains("TEXCOORD_1")), "{:?}", s.stats.warnings);
    assert!(s.meshes.iter().all(|m| m.uv0.as_ref().is_some_and(|u| u.len() == m.positions.len())));
    assert!(s.meshes.iter().all(|m| m.normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-5)));
}

/// Reads vertex `v` of accessor `acc` (VEC3 float) straight from the bundled file, and the TRS
/// matrix of a node, to check the loader's world positions independently.
fn raw_vec3(j: &Value, bin: &[u8], acc: usize, v: usize) -> Vec3 {
    let a = &j["accessors"][acc];
    let view = &j["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
    let stride = view["byteStride"].as_u64().unwrap_or(12) as usize;
    let off =
        view["byteOffset"].as_u64().unwrap_or(0) as usize + a["byteOffset"].as_u64().unwrap_or(0) as usize + v * stride;
    let f = |k: usize| f32::from_le_bytes(bin[off + 4 * k..off + 4 * k + 4].try_into().unwrap());
    Vec3::new(f(0), f(1), f(2))
}

fn trs(node: &Value) -> Mat4 {
    let v = |k: &str, d: Vec<f32>| -> Vec<f32> {
        node.get(k).map_or(d, |a| a.as_array().unwrap().iter().map(|x| x.as_f64().unwrap() as f32).collect())
    };
    let t = v("translation", vec![0.0; 3]);
    let r = v("rotation", vec![0.0, 0.0, 0.0, 1.0]);
    let s = v("scale", vec![1.0; 3]);
    Mat4::from_scale_rotation_translation(Vec3::from_slice(&s), Quat::from_slice(&r), Vec3::from_slice(&t))
}

#[test]
fn cornell_box_node_transforms_are_applied() {
    let j: Value = serde_json::from_slice(&std::fs::read(asset(CORNELL)).unwrap()).unwrap();
    let bin = std::fs::read(asset("cornell_box/cornellBox-2.79-Cycles-gltf.bin")).unwrap();
    let s = load(&asset(CORNELL)).unwrap();
    // suzanne.000 (node 14, a root) and BJS-3D-logo_red01.000 (node 7, child of node 0).
    let cases = [
        (14usize, None, "suzanne.000/suzanne.000/0"),
        (7, Some(0usize), "BJS-3D-logo_red01.000/BJS-3D-logo_red01.000/0"),
    ];
    for (node, parent, name) in cases {
        let mut world = trs(&j["nodes"][node]);
        if let Some(p) = parent {
            world = trs(&j["nodes"][p]) * world;
        }
        let mesh_index = j["nodes"][node]["mesh"].as_u64().unwrap() as usize;
        let acc = j["meshes"][mesh_index]["primitives"][0]["attributes"]["POSITION"].as_u64().unwrap() as usize;
        let m = mesh(&s, name);
        for v in [0, m.positions.len() / 2, m.positions.len() - 1] {
            let expected = world.transform_point3(raw_vec3(&j, &bin, acc, v));
            assert_close(m.positions[v], expected, 1e-5);
        }
        assert!(world.transform_point3(Vec3::ZERO).length() > 0.5, "the test must exercise a real offset");
    }
}

#[test]
fn van_gogh_room_loads() {
    let s = load(&asset(VAN_GOGH)).unwrap();
    assert_eq!(s.triangle_count(), 11272);
    assert_eq!(s.meshes.len(), 16);
    assert_eq!(s.materials.len(), 15);
    assert_eq!(s.materials.iter().filter(|m| m.double_sided).count(), 10);
    assert!(s.materials.iter().all(|m| !m.is_emissive() && m.base_color_texture.is_none()));
    assert!(s.lights.is_empty() && s.textures.is_empty() && s.cameras.is_empty());
    assert!(s.meshes.iter().all(|m| m.uv1.is_none() && m.uv0.is_some()));
    assert_eq!(s.stats.degenerate_triangles_dropped, 0);
    let (lo, hi) = s.bounds().unwrap();
    assert_close(lo, Vec3::new(-1.8653, -0.024, -0.7744), 1e-6);
    assert_close(hi, Vec3::new(1.6706, 3.8374, 5.9935), 1e-6);
    assert!(s.meshes.iter().all(|m| m.normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-5)));
}

// ---------------------------------------------------------------------------------------------
// broken input: one test per case, each asserting the variant and that the file is named

#[test]
fn errors_and_scenes_cross_threads() {
    fn send_sync<T: Send + Sync + 'static>() {}
    send_sync::<LoadError>();
    send_sync::<Scene>();
}

#[test]
fn missing_file_is_io() {
    let d = tmp();
    let p = d.path().join("nowhere.gltf");
    let e = load_err(&p);
    assert!(matches!(e, LoadError::Io { .. }), "{e}");
}

#[test]
fn empty_file_is_not_gltf() {
    let d = tmp();
    let p = write(d.path(), "empty.gltf", b"");
    let e = load_err(&p);
    assert!(matches!(e, LoadError::NotGltf { .. }), "{e}");
    assert!(e.to_string().contains("empty"), "{e}");
}

#[test]
fn non_gltf_bytes_are_not_gltf() {
    let d = tmp();
    let p = write(d.path(), "picture.glb", &png(2, 2, |_, _| [0; 4]));
    let e = load_err(&p);
    assert!(matches!(e, LoadError::NotGltf { .. }), "{e}");
    assert!(e.to_string().contains("PNG"), "shows what the file starts with: {e}");
    let p = write(d.path(), "whitespace.gltf", b"  \n ");
    assert!(matches!(load_err(&p), LoadError::NotGltf { .. }));
}

#[test]
fn truncated_json_reports_position() {
    let d = tmp();
    let text = std::fs::read(asset(CORNELL)).unwrap();
    let p = write(d.path(), "half.gltf", &text[..text.len() / 2]);
    match load_err(&p) {
        LoadError::Json { line, column, message, .. } => {
            let expected_line = text[..text.len() / 2].iter().filter(|&&b| b == b'\n').count() + 1;
            assert_eq!(line, expected_line);
            assert!(column > 0);
            assert!(message.contains("truncated"), "{message}");
        }
        e => panic!("expected Json, got {e}"),
    }
}

#[test]
fn malformed_json_reports_position() {
    let d = tmp();
    let p = write(d.path(), "bad.gltf", b"{\n  \"asset\": {\"version\": \"2.0\"},\n  \"nodes\": [}\n");
    match load_err(&p) {
        LoadError::Json { line, column, .. } => assert_eq!((line, column), (3, 13)),
        e => panic!("expected Json, got {e}"),
    }
    // Valid JSON, but a required property is missing: still Json, with a position.
    let p = write(d.path(), "noasset.gltf", b"{\"nodes\": []}");
    let e = load_err(&p);
    assert!(matches!(e, LoadError::Json { .. }) && e.to_string().contains("asset"), "{e}");
}

#[test]
fn missing_buffer_file_names_the_uri() {
    let d = tmp();
    let p = one_triangle_doc().write_gltf(d.path(), "scene");
    std::fs::remove_file(d.path().join("scene.bin")).unwrap();
    match load_err(&p) {
        LoadError::MissingBuffer { buffer, uri, resolved, .. } => {
            assert_eq!((buffer, uri.as_str()), (0, "scene.bin"));
            assert_eq!(resolved, d.path().join("scene.bin"));
        }
        e => panic!("expected MissingBuffer, got {e}"),
    }
}

#[test]
fn short_buffer_reports_expected_and_actual() {
    let d = tmp();
    let doc = one_triangle_doc();
    let p = doc.write_gltf(d.path(), "scene");
    std::fs::write(d.path().join("scene.bin"), &doc.bin[..doc.bin.len() - 4]).unwrap();
    match load_err(&p) {
        LoadError::ShortBuffer { expected, actual, .. } => {
            assert_eq!((expected, actual), (doc.bin.len() as u64, doc.bin.len() as u64 - 4));
        }
        e => panic!("expected ShortBuffer, got {e}"),
    }
    // Same for a data: URI and a GLB BIN chunk.
    let mut j = doc.json_with_buffer(Some(format!("data:application/octet-stream;base64,{}", base64(&doc.bin[..8]))));
    let p = write_json(d.path(), "data.gltf", &j);
    assert!(matches!(load_err(&p), LoadError::ShortBuffer { actual: 8, .. }));
    j["buffers"] = json!([{ "byteLength": doc.bin.len() + 64 }]);
    let p = write(d.path(), "short.glb", &glb(&j, &doc.bin));
    assert!(matches!(load_err(&p), LoadError::ShortBuffer { .. }));
}

#[test]
fn accessor_larger_than_its_view_is_out_of_bounds() {
    let d = tmp();
    let doc = one_triangle_doc();
    let mut j = gltf_json(&doc, d.path(), "scene");
    j["accessors"][0]["count"] = json!(4); // POSITION: 4 × 12 bytes in a 36-byte view
    let p = write_json(d.path(), "scene.gltf", &j);
    match load_err(&p) {
        LoadError::AccessorOutOfBounds { accessor, detail, .. } => {
            assert_eq!(accessor, 0);
            assert!(detail.contains("needs 48 bytes") && detail.contains("has 36"), "{detail}");
        }
        e => panic!("expected AccessorOutOfBounds, got {e}"),
    }
    // An in-bounds count with a byteOffset that pushes the last element out.
    j["accessors"][0]["count"] = json!(3);
    j["accessors"][0]["byteOffset"] = json!(4);
    let p = write_json(d.path(), "scene.gltf", &j);
    assert!(matches!(load_err(&p), LoadError::AccessorOutOfBounds { accessor: 0, .. }));
}

#[test]
fn view_larger_than_its_buffer_is_out_of_bounds() {
    let d = tmp();
    let doc = one_triangle_doc();
    let mut j = gltf_json(&doc, d.path(), "scene");
    j["bufferViews"][1]["byteLength"] = json!(doc.bin.len()); // starts at 36
    let p = write_json(d.path(), "scene.gltf", &j);
    match load_err(&p) {
        LoadError::ViewOutOfBounds { view, buffer, offset, length, buffer_length, .. } => {
            assert_eq!((view, buffer, offset, length, buffer_length), (1, 0, 36, 72, 72));
        }
        e => panic!("expected ViewOutOfBounds, got {e}"),
    }
}

#[test]
fn out_of_range_index_is_an_error() {
    let d = tmp();
    let mut doc = Doc::new();
    let p = doc.prim(&TRI, None, Some(&[0, 1, 2, 2, 1, 7]));
    doc.mesh_node(vec![p], json!({ "name": "n" }));
    let path = doc.write_gltf(d.path(), "scene");
    match load_err(&path) {
        LoadError::IndexOutOfRange { mesh, position, index, vertex_count, .. } => {
            assert_eq!((mesh.as_str(), position, index, vertex_count), ("n/mesh0/0", 5, 7, 3));
        }
        e => panic!("expected IndexOutOfRange, got {e}"),
    }
}

fn non_finite_position(value: f32) {
    let d = tmp();
    let mut doc = Doc::new();
    let mut pos = TRI;
    pos[1][2] = value;
    let p = doc.prim(&pos, None, None);
    doc.mesh_node(vec![p], json!({ "name": "n" }));
    let path = doc.write_gltf(d.path(), "scene");
    match load_err(&path) {
        LoadError::NonFinite { mesh, attribute, vertex, .. } => {
            assert_eq!((mesh.as_str(), attribute.as_str(), vertex), ("n/mesh0/0", "POSITION", 1));
        }
        e => panic!("expected NonFinite, got {e}"),
    }
}

#[test]
fn nan_position_is_an_error() {
    non_finite_position(f32::NAN);
}

#[test]
fn inf_position_is_an_error() {
    non_finite_position(f32::INFINITY);
}

#[test]
fn position_overflowing_under_the_node_transform_is_an_error() {
    let d = tmp();
    let mut doc = Doc::new();
    let p = doc.prim(&[[0.0; 3], [3e38, 0.0, 0.0], [0.0, 1.0, 0.0]], None, None);
    doc.mesh_node(vec![p], json!({ "scale": [10.0, 1.0, 1.0] }));
    let e = load_err(&doc.write_gltf(d.path(), "scene"));
    assert!(
        matches!(&e, LoadError::NonFinite { attribute, vertex: 1, .. } if attribute.contains("node transform")),
        "{e}"
    );
}

#[test]
fn absurd_sizes_are_errors_not_allocations() {
    let d = tmp();
    let doc = one_triangle_doc();
    let base = gltf_json(&doc, d.path(), "scene");
    let huge = 1_000_000_000_000_000u64; // 1e15

    let mut j = base.clone();
    j["buffers"][0]["byteLength"] = json!(huge);
    let e = load_err(&write_json(d.path(), "a.gltf", &j));
    assert!(matches!(e, LoadError::ShortBuffer { expected, .. } if expected == huge), "{e}");

    let mut j = base.clone();
    j["bufferViews"][0]["byteLength"] = json!(huge);
    assert!(matches!(load_err(&write_json(d.path(), "b.gltf", &j)), LoadError::ViewOutOfBounds { .. }));

    let mut j = base.clone();
    j["bufferViews"][0]["byteOffset"] = json!(u64::MAX);
    assert!(matches!(load_err(&write_json(d.path(), "c.gltf", &j)), LoadError::ViewOutOfBounds { .. }));

    let mut j = base.clone();
    j["accessors"][0]["count"] = json!(huge);
    assert!(matches!(load_err(&write_json(d.path(), "d.gltf", &j)), LoadError::AccessorOutOfBounds { .. }));

    let mut j = base.clone();
    j["accessors"][0]["count"] = json!(u64::MAX);
    assert!(matches!(load_err(&write_json(d.path(), "e.gltf", &j)), LoadError::AccessorOutOfBounds { .. }));

    // No bufferView: `count` zeros with nothing in the file to back them.
    let mut j = base.clone();
    j["accessors"][0].as_object_mut().unwrap().remove("bufferView");
    j["accessors"][0]["count"] = json!(huge);
    assert!(matches!(load_err(&write_json(d.path(), "f.gltf", &j)), LoadError::AccessorOutOfBounds { .. }));

    // A GLB whose header claims 4 GB.
    let mut bytes = glb(&doc.json_with_buffer(None), &doc.bin);
    bytes[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(matches!(load_err(&write(d.path(), "g.glb", &bytes)), LoadError::Glb { .. }));
}

#[test]
fn unsupported_required_extension_is_named() {
    let d = tmp();
    let mut j = one_triangle_doc().json_with_buffer(None);
    j["extensionsUsed"] = json!(["KHR_draco_mesh_compression", "KHR_lights_punctual"]);
    j["extensionsRequired"] = json!(["KHR_draco_mesh_compression", "KHR_lights_punctual"]);
    let e = load_err(&write_json(d.path(), "draco.gltf", &j));
    assert!(matches!(e, LoadError::Unsupported { .. }), "{e}");
    let msg = e.to_string();
    assert!(msg.contains("KHR_draco_mesh_compression") && msg.contains("without mesh compression"), "{msg}");
    assert!(
        !msg.contains("lists KHR_draco_mesh_compression, KHR_lights_punctual"),
        "supported ones are not listed: {msg}"
    );
    for ext in ["KHR_texture_basisu", "EXT_meshopt_compression", "KHR_materials_volume"] {
        j["extensionsRequired"] = json!([ext]);
        let e = load_err(&write_json(d.path(), "x.gltf", &j));
        assert!(matches!(e, LoadError::Unsupported { .. }) && e.to_string().contains(ext), "{e}");
    }
}

#[test]
fn gltf_1_is_unsupported() {
    let d = tmp();
    let mut j = one_triangle_doc().json_with_buffer(None);
    j["asset"]["version"] = json!("1.0");
    assert!(matches!(load_err(&write_json(d.path(), "old.gltf", &j)), LoadError::Unsupported { .. }));
}

fn textured_doc(image: Value) -> Doc {
    let mut d = Doc::new();
    let mut p = d.prim(&TRI, Some(&UP_Z), None);
    p["material"] = json!(0);
    d.mesh_node(vec![p], json!({}));
    d.push("images", image);
    d.push("textures", json!({ "source": 0 }));
    d.push("materials", json!({ "pbrMetallicRoughness": { "baseColorTexture": { "index": 0 } } }));
    d
}

#[test]
fn missing_image_is_named() {
    let d = tmp();
    let doc = textured_doc(json!({ "name": "wood", "uri": "tex/wood.png" }));
    match load_err(&doc.write_gltf(d.path(), "scene")) {
        LoadError::Image { image, reason, .. } => {
            assert_eq!(image, "image 0 'wood' (tex/wood.png)");
            assert!(reason.contains("cannot read") && reason.contains("wood.png"), "{reason}");
        }
        e => panic!("expected Image, got {e}"),
    }
}

#[test]
fn undecodable_image_is_named() {
    let d = tmp();
    let doc = textured_doc(json!({ "uri": "broken.png" }));
    let mut bytes = png(4, 4, |_, _| [255; 4]);
    bytes.truncate(30);
    write(d.path(), "broken.png", &bytes);
    let e = load_err(&doc.write_gltf(d.path(), "scene"));
    assert!(matches!(&e, LoadError::Image { image, .. } if image == "image 0 (broken.png)"), "{e}");
    write(d.path(), "broken.png", b"GIF89a not really");
    let e = load_err(&doc.write_gltf(d.path(), "scene"));
    assert!(
        matches!(&e, LoadError::Image { reason, .. } if reason.contains("unrecognised") || reason.contains("decode")),
        "{e}"
    );
}

/// A texture whose only image is an extension's (KHR_texture_basisu's KTX2,
/// EXT_texture_webp's WebP: glTF lets `source` be absent then) is valid glTF: the scene
/// loads, the material shows its factor alone, and a warning names the texture and its
/// extension. Required, KHR_texture_basisu stays refused (the file says it cannot be shown
/// without it: `unsupported_required_extension_is_named`).
#[test]
fn textures_with_only_an_extension_image_load_without_them() {
    let d = tmp();
    for (ext, uri) in [("KHR_texture_basisu", "wood.ktx2"), ("EXT_texture_webp", "wood.webp")] {
        let mut doc = textured_doc(json!({ "uri": uri }));
        doc.json["textures"] = json!([{ "extensions": { ext: { "source": 0 } } }]);
        doc.json["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"] = json!([0.5, 0.5, 0.5, 1.0]);
        doc.json["extensionsUsed"] = json!([ext]);
        let s = load(&doc.write_gltf(d.path(), "scene")).unwrap();
        let m = &s.materials[0];
        assert_eq!((m.base_color_texture, m.base_color), (None, Vec4::new(0.5, 0.5, 0.5, 1.0)), "{ext}");
        let warned = s.stats.warnings.iter().any(|w| w.contains("texture 0") && w.contains(ext));
        assert!(warned, "{ext}: {:?}", s.stats.warnings);
    }
}

#[test]
fn no_triangles_is_an_error() {
    let d = tmp();
    // Only lines.
    let mut doc = Doc::new();
    let mut p = doc.prim(&TRI, None, None);
    p["mode"] = json!(1);
    doc.mesh_node(vec![p], json!({}));
    let e = load_err(&doc.write_gltf(d.path(), "lines"));
    assert!(matches!(e, LoadError::NoTriangles { .. }), "{e}");
    assert!(e.to_string().contains("1 point/line primitive(s) skipped"), "{e}");
    // Only a degenerate triangle.
    let mut doc = Doc::new();
    let p = doc.prim(&[[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]], None, None);
    doc.mesh_node(vec![p], json!({}));
    let e = load_err(&doc.write_gltf(d.path(), "flat"));
    assert!(matches!(e, LoadError::NoTriangles { .. }) && e.to_string().contains("1 degenerate"), "{e}");
    // No nodes at all.
    let p = write_json(d.path(), "empty.gltf", &json!({ "asset": { "version": "2.0" } }));
    let e = load_err(&p);
    assert!(matches!(e, LoadError::NoTriangles { .. }) && e.to_string().contains("no nodes"), "{e}");
}

#[test]
fn malformed_glb_containers() {
    let d = tmp();
    let doc = one_triangle_doc();
    let good = glb(&doc.json_with_buffer(None), &doc.bin);
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("header cut", good[..10].to_vec()),
        ("truncated", good[..good.len() - 8].to_vec()),
        ("chunk too long", {
            let mut b = good.clone();
            b[12..16].copy_from_slice(&(good.len() as u32).to_le_bytes());
            b
        }),
        ("BIN first", {
            let mut b = good.clone();
            b[16..20].copy_from_slice(b"BIN\0");
            b
        }),
    ];
    for (what, bytes) in cases {
        let e = load_err(&write(d.path(), "x.glb", &bytes));
        assert!(matches!(e, LoadError::Glb { .. }), "{what}: {e}");
    }
    let mut v1 = good.clone();
    v1[4] = 1;
    assert!(matches!(load_err(&write(d.path(), "v1.glb", &v1)), LoadError::Unsupported { .. }));
}

#[test]
fn validation_failures_are_invalid() {
    let d = tmp();
    let base = gltf_json(&one_triangle_doc(), d.path(), "scene");
    type Change = Box<dyn Fn(&mut Value)>;
    let cases: Vec<(&str, Change)> = vec![
        ("node mesh index", Box::new(|j| j["nodes"][0]["mesh"] = json!(5))),
        ("POSITION index", Box::new(|j| j["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = json!(99))),
        ("node cycle", Box::new(|j| j["nodes"][0]["children"] = json!([0]))),
        ("POSITION type", Box::new(|j| j["accessors"][0]["type"] = json!("VEC2"))),
        ("scene index", Box::new(|j| j["scene"] = json!(3))),
        ("componentType", Box::new(|j| j["accessors"][0]["componentType"] = json!(1234))),
        ("byteStride", Box::new(|j| j["bufferViews"][0]["byteStride"] = json!(2))),
        ("primitive mode", Box::new(|j| j["meshes"][0]["primitives"][0]["mode"] = json!(9))),
        ("NORMAL count", Box::new(|j| j["accessors"][1]["count"] = json!(2))),
        (
            "buffer without uri in .gltf",
            Box::new(|j| {
                j["buffers"][0].as_object_mut().unwrap().remove("uri");
            }),
        ),
        (
            "non-finite matrix",
            Box::new(|j| {
                j["nodes"][0]["matrix"] = json!([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1e39]);
            }),
        ),
    ];
    for (what, change) in cases {
        let mut j = base.clone();
        change(&mut j);
        let e = load_err(&write_json(d.path(), "scene.gltf", &j));
        assert!(matches!(e, LoadError::Invalid { .. }), "{what}: {e}");
    }
}

// ---------------------------------------------------------------------------------------------
// correctness

/// Two meshes (one indexed with normals and UVs, one flat-shaded) in a small hierarchy.
fn sample_doc() -> Doc {
    let mut d = Doc::new();
    let quad = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
    let mut p = d.prim(&quad, Some(&[[0.0, 0.0, 1.0]; 4]), Some(&[0, 1, 2, 0, 2, 3]));
    p["attributes"]["TEXCOORD_0"] = json!(d.vec2(&[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]));
    let tetra = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]];
    let q = d.prim(&tetra, None, Some(&[0, 2, 1, 0, 1, 3, 1, 2, 3, 2, 0, 3]));
    let parent = d.mesh_node(vec![p], json!({ "name": "parent", "translation": [0.0, 2.0, 0.0] }));
    let mesh = d.push("meshes", json!({ "name": "tetra", "primitives": [q] }));
    let child =
        d.push("nodes", json!({ "name": "child", "mesh": mesh, "rotation": [0.0, 0.0, 0.38268343, 0.92387953] }));
    d.json["nodes"][parent]["children"] = json!([child]);
    d
}

fn assert_same_scene(a: &Scene, b: &Scene) {
    assert_eq!(a.meshes.len(), b.meshes.len());
    for (x, y) in a.meshes.iter().zip(&b.meshes) {
        assert_eq!(x.name, y.name);
        assert_eq!(x.positions, y.positions);
        assert_eq!(x.normals, y.normals);
        assert_eq!(x.triangles, y.triangles);
        assert_eq!(x.uv0, y.uv0);
        assert_eq!(x.uv1, y.uv1);
        assert_eq!(x.material, y.material);
    }
    assert_eq!(a.materials.len(), b.materials.len());
}

#[test]
fn glb_and_data_uri_load_like_their_gltf_twin() {
    let d = tmp();
    let doc = sample_doc();
    let gltf = load(&doc.write_gltf(d.path(), "twin")).unwrap();
    let glb = load(&doc.write_glb(d.path(), "twin")).unwrap();
    let data = load(&doc.write_data_uri(d.path(), "embedded")).unwrap();
    assert_eq!(gltf.meshes.len(), 2);
    assert_eq!(gltf.triangle_count(), 2 + 4);
    assert_same_scene(&gltf, &glb);
    assert_same_scene(&gltf, &data);
    // In memory, too.
    let bytes = std::fs::read(d.path().join("twin.glb")).unwrap();
    let mem = load_gltf_bytes(&d.path().join("twin.glb"), &bytes, &LoadOptions::default()).unwrap();
    assert_same_scene(&gltf, &mem);
}

#[test]
fn percent_encoded_buffer_uri() {
    let d = tmp();
    let doc = one_triangle_doc();
    std::fs::write(d.path().join("my mesh.bin"), &doc.bin).unwrap();
    let j = doc.json_with_buffer(Some("my%20mesh.bin".into()));
    let s = load(&write_json(d.path(), "scene.gltf", &j)).unwrap();
    assert_eq!(s.triangle_count(), 1);
}

/// A primitive with `mode` over `positions` in the z = 0 plane, all with +Z normals.
fn mode_scene(positions: &[[f32; 3]], indices: Option<&[u16]>, mode: u32) -> Scene {
    let d = tmp();
    let mut doc = Doc::new();
    let normals = vec![[0.0, 0.0, 1.0]; positions.len()];
    let mut p = doc.prim(positions, Some(&normals), indices);
    p["mode"] = json!(mode);
    doc.mesh_node(vec![p], json!({}));
    load(&doc.write_gltf(d.path(), "scene")).unwrap()
}

#[test]
fn strips_alternate_winding_and_all_face_front() {
    // A zig-zag strip up the y axis whose first triangle is counter-clockwise seen from +Z.
    let strip = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 2.0, 0.0]];
    for indices in [None, Some(&[0u16, 1, 2, 3, 4][..])] {
        let s = mode_scene(&strip, indices, 5);
        let m = &s.meshes[0];
        assert_eq!(m.triangles, vec![[0, 1, 2], [1, 3, 2], [2, 3, 4]]);
        for t in 0..3 {
            assert_close(face_normal(m, t), Vec3::Z, 1e-6);
        }
    }
    // Indexed strip walking the same vertices top-down: the odd triangle is still reversed.
    let s = mode_scene(&strip, Some(&[4, 2, 3, 0, 1][..]), 5);
    assert_eq!(s.meshes[0].triangles, vec![[4, 2, 3], [2, 0, 3], [3, 0, 1]]);
    for t in 0..3 {
        assert_close(face_normal(&s.meshes[0], t), Vec3::Z, 1e-6);
    }
    // Reversing the whole strip makes every triangle face −Z.
    let s = mode_scene(&strip, Some(&[1, 0, 3, 2, 4][..]), 5);
    for t in 0..3 {
        assert_close(face_normal(&s.meshes[0], t), Vec3::NEG_Z, 1e-6);
    }
}

#[test]
fn fans_pivot_on_the_first_vertex() {
    // Centre then a counter-clockwise ring.
    let fan = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0], [-1.0, -1.0, 0.0]];
    let s = mode_scene(&fan, None, 6);
    let m = &s.meshes[0];
    assert_eq!(m.triangles, vec![[1, 2, 0], [2, 3, 0], [3, 4, 0]]);
    for t in 0..3 {
        assert_close(face_normal(m, t), Vec3::Z, 1e-6);
    }
    assert!((SceneGeometry::new(&s).total_area() - 2.5).abs() < 1e-6);
}

#[test]
fn points_and_lines_are_skipped_and_counted() {
    let d = tmp();
    let mut doc = Doc::new();
    let mut prims = Vec::new();
    for mode in [0, 1, 2, 3, 4] {
        let mut p = doc.prim(&TRI, Some(&UP_Z), None);
        p["mode"] = json!(mode);
        prims.push(p);
    }
    doc.mesh_node(prims, json!({ "name": "n" }));
    let s = load(&doc.write_gltf(d.path(), "scene")).unwrap();
    assert_eq!(s.stats.non_triangle_primitives_skipped, 4);
    assert_eq!(s.meshes.len(), 1);
    assert_eq!(s.meshes[0].name, "n/mesh0/4");
    assert!(
        s.stats.warnings.iter().any(|w| w.starts_with("4 point/line primitive(s) skipped")),
        "{:?}",
        s.stats.warnings
    );
}

#[test]
fn trs_and_matrix_hierarchy_place_vertices() {
    let d = tmp();
    let mut doc = Doc::new();
    // A triangle in the x = 1 plane facing +X, with +X normals.
    let p = doc.prim(&[[1.0, 0.0, 0.0], [1.0, 0.0, -1.0], [1.0, 1.0, 0.0]], Some(&[[1.0, 0.0, 0.0]; 3]), None);
    let mesh = doc.push("meshes", json!({ "name": "m", "primitives": [p] }));
    // Child: matrix = translation (0, 0, 1), column-major.
    let child = doc.push(
        "nodes",
        json!({
            "name": "child", "mesh": mesh,
            "matrix": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 1, 1]
        }),
    );
    // Parent: T (10, 0, 0) · R (90° about +Y) · S (2).
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let parent = doc.push(
        "nodes",
        json!({
            "name": "parent", "children": [child],
            "translation": [10.0, 0.0, 0.0], "rotation": [0.0, h, 0.0, h], "scale": [2.0, 2.0, 2.0]
        }),
    );
    doc.add_root(parent);
    let s = load(&doc.write_gltf(d.path(), "scene")).unwrap();
    let m = mesh_named(&s, "child/m/0");
    // (1,0,0) → child (1,0,1) → scale (2,0,2) → R_y(90°): (x, z) → (z, −x) = (2,0,−2) → +T.
    assert_close(m.positions[0], Vec3::new(12.0, 0.0, -2.0), 1e-5);
    assert_close(m.positions[1], Vec3::new(10.0, 0.0, -2.0), 1e-5);
    assert_close(m.positions[2], Vec3::new(12.0, 2.0, -2.0), 1e-5);
    // The +X normal turns to −Z and stays unit length despite the scale; the face agrees.
    assert!(m.normals.iter().all(|n| close(*n, Vec3::NEG_Z, 1e-6)));
    assert_close(face_normal(m, 0), Vec3::NEG_Z, 1e-6);
    assert_eq!(m.node, Some(child));
    assert_eq!(s.stats.nodes, 2);
}

fn mesh_named<'a>(s: &'a Scene, name: &str) -> &'a Mesh {
    mesh(s, name)
}

#[test]
fn non_uniform_scale_transforms_normals_by_the_inverse_transpose() {
    let d = tmp();
    let mut doc = Doc::new();
    // A 45° slope in x-y; its normal (−1, 1, 0)/√2.
    let n = [-std::f32::consts::FRAC_1_SQRT_2, std::f32::consts::FRAC_1_SQRT_2, 0.0];
    let p = doc.prim(&[[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, -1.0]], Some(&[n; 3]), None);
    doc.mesh_node(vec![p], json!({ "scale": [4.0, 1.0, 1.0] }));
    let s = load(&doc.write_gltf(d.path(), "scene")).unwrap();
    let m = &s.meshes[0];
    // Stretching x by 4 flattens the slope: the normal becomes (−1/4, 1, 0) normalised,
    // i.e. it stays perpendicular to the stretched surface.
    let expected = Vec3::new(-0.25, 1.0, 0.0).normalize();
    assert_close(m.normals[0], expected, 1e-6);
    assert_close(face_normal(m, 0), expected, 1e-6);
}

fn mirrored(scale: [f32; 3]) -> Scene {
    let d = tmp();
    let mut doc = Doc::new();
    let p = doc.prim(&TRI, Some(&UP_Z), None);
    doc.mesh_node(vec![p], json!({ "scale": scale }));
    load(&doc.write_gltf(d.path(), "scene")).unwrap()
}

#[test]
fn mirrored_node_keeps_the_front_face() {
    // Mirror in x: the triangle stays in the z = 0 plane, its front must still face +Z.
    let s = mirrored([-1.0, 1.0, 1.0]);
    let m = &s.meshes[0];
    assert_eq!(m.triangles, vec![[0, 2, 1]], "winding flipped");
    assert_close(face_normal(m, 0), Vec3::Z, 1e-6);
    assert!(m.normals.iter().all(|n| close(*n, Vec3::Z, 1e-6)));
    // Mirror in z: the front now faces −Z, and so do the shading normals.
    let s = mirrored([1.0, 1.0, -2.0]);
    let m = &s.meshes[0];
    assert_close(face_normal(m, 0), Vec3::NEG_Z, 1e-6);
    assert!(m.normals.iter().all(|n| close(*n, Vec3::NEG_Z, 1e-6)));
    // A double mirror is a rotation: no flip.
    let s = mirrored([-1.0, -1.0, 1.0]);
    assert_eq!(s.meshes[0].triangles, vec![[0, 1, 2]]);
    assert_close(face_normal(&s.meshes[0], 0), Vec3::Z, 1e-6);
}

#[test]
fn missing_normals_are_generated_flat() {
    let d = tmp();
    let doc = sample_doc();
    let s = load(&doc.write_gltf(d.path(), "scene")).unwrap();
    assert_eq!(s.stats.normals_generated, 1);
    let m = mesh(&s, "child/tetra/0");
    assert_eq!(m.positions.len(), 12, "each triangle gets its own vertices");
    assert_eq!(m.triangles, (0..4).map(|k| [3 * k, 3 * k + 1, 3 * k + 2]).collect::<Vec<_>>());
    for t in 0..4 {
        let f = face_normal(m, t);
        for k in 0..3 {
            assert_eq!(m.normals[3 * t + k], f);
        }
    }
    // The tetrahedron is closed and wound outwards: its face normals point away from its centre.
    let centre: Vec3 = m.positions.iter().copied().sum::<Vec3>() / 12.0;
    for t in 0..4 {
        let c = (m.corners(t)[0] + m.corners(t)[1] + m.corners(t)[2]) / 3.0;
        assert!((c - centre).dot(face_normal(m, t)) > 0.0);
    }
    let quad = mesh(&s, "parent/mesh0/0");
    assert_eq!(quad.positions.len(), 4, "normals in the file: vertices stay shared");
}

#[test]
fn bad_normals_are_replaced_by_face_normals() {
    let d = tmp();
    let mut doc = Doc::new();
    let p = doc.prim(&TRI, Some(&[[f32::NAN, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 2.0]]), None);
    doc.mesh_node(vec![p], json!({}));
    let s = load(&doc.write_gltf(d.path(), "scene")).unwrap();
    assert_eq!(s.meshes[0].normals, vec![Vec3::Z; 3]);
    assert_eq!(s.stats.normals_replaced, 2);
    assert!(s.stats.warnings.iter().any(|w| w.starts_with("2 vertex normal(s)")), "{:?}", s.stats.warnings);
}

#[test]
fn degenerate_triangles_are_dropped_and_counted() {
    let d = tmp();
    let mut doc = Doc::new();
    let pos = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [2.0, 0.0, 0.0], [0.5, 1e-8, 0.0]];
    // Good, repeated index, collinear, needle (height 1e-8 over a 1 m edge).
    let p = doc.prim(&pos, Some(&[[0.0, 0.0, 1.0]; 5]), Some(&[0, 1, 2, 0, 0, 1, 0, 1, 3, 0, 1, 4]));
    doc.mesh_node(vec![p], json!({}));
    let s = load(&doc.write_gltf(d.path(), "scene")).unwrap();
    assert_eq!(s.meshes[0].triangles, vec![[0, 1, 2]]);
    assert_eq!(s.stats.degenerate_triangles_dropped, 3);
    assert_eq!(s.stats.triangles, 1);
    assert!(s.stats.warnings.iter().any(|w| w.starts_with("3 zero-area triangle(s) dropped")));
    // A tiny but well-shaped triangle (1 µm) is kept: the threshold is relative.
    let mut doc = Doc::new();
    let tiny: Vec<[f32; 3]> = TRI.iter().map(|p| p.map(|c| c * 1e-6)).collect();
    let p = doc.prim(&tiny, None, None);
    doc.mesh_node(vec![p], json!({}));
    let s = load(&doc.write_gltf(d.path(), "tiny")).unwrap();
    assert_eq!((s.triangle_count(), s.stats.degenerate_triangles_dropped), (1, 0));
}

#[test]
fn materials_factors_emission_and_alpha() {
    let d = tmp();
    let mut doc = Doc::new();
    let mut prims = Vec::new();
    for m in [Some(0), Some(1), None, Some(2), None] {
        let mut p = doc.prim(&TRI, Some(&UP_Z), None);
        if let Some(m) = m {
            p["material"] = json!(m);
        }
        prims.push(p);
    }
    doc.mesh_node(prims, json!({}));
    doc.push(
        "materials",
        json!({
            "name": "lamp", "emissiveFactor": [0.5, 1.0, 2.0],
            "extensions": { "KHR_materials_emissive_strength": { "emissiveStrength": 4.0 } }
        }),
    );
    doc.push(
        "materials",
        json!({
            "pbrMetallicRoughness": { "baseColorFactor": [0.25, 0.5, 0.75, 0.5] },
            "alphaMode": "MASK", "doubleSided": true
        }),
    );
    doc.push("materials", json!({ "alphaMode": "MASK", "alphaCutoff": 0.3, "emissiveFactor": [1.0, 1.0, 1.0] }));
    doc.json["extensionsUsed"] = json!(["KHR_materials_emissive_strength"]);
    doc.json["extensionsRequired"] = json!(["KHR_materials_emissive_strength"]);
    let s = load(&doc.write_gltf(d.path(), "scene")).unwrap();
    assert_eq!(s.materials.len(), 4, "three from the file and the default, once");
    assert_eq!(s.materials[0].emission, Vec3::new(2.0, 4.0, 8.0));
    assert_eq!(s.materials[0].name, "lamp");
    assert_eq!(s.materials[1].base_color, Vec4::new(0.25, 0.5, 0.75, 0.5));
    assert_eq!(s.materials[1].alpha_mode, AlphaMode::Mask { cutoff: 0.5 });
    assert!(s.materials[1].double_sided && !s.materials[0].double_sided);
    assert_eq!(s.materials[2].alpha_mode, AlphaMode::Mask { cutoff: 0.3 });
    assert_eq!(s.materials[2].emission, Vec3::ONE, "strength defaults to 1");
    let default = &s.materials[3];
    assert_eq!((default.base_color, default.emission, default.double_sided), (Vec4::ONE, Vec3::ZERO, false));
    let ids: Vec<u32> = s.meshes.iter().map(|m| m.material).collect();
    assert_eq!(ids, [0, 1, 3, 2, 3]);
}

#[test]
fn textures_from_data_uri_and_buffer_view_with_samplers() {
    let d = tmp();
    let mut doc = Doc::new();
    let mut p = doc.prim(&TRI, Some(&UP_Z), None);
    p["attributes"]["TEXCOORD_0"] = json!(doc.vec2(&[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]));
    p["material"] = json!(0);
    doc.mesh_node(vec![p], json!({}));
    let red_green = png(2, 1, |x, _| if x == 0 { [255, 0, 0, 255] } else { [0, 255, 0, 128] });
    let blue = png(1, 1, |_, _| [0, 0, 188, 255]);
    let view = doc.view(&blue, None);
    doc.push("images", json!({ "name": "rg", "uri": format!("data:image/png;base64,{}", base64(&red_green)) }));
    doc.push("images", json!({ "bufferView": view, "mimeType": "image/png" }));
    doc.push("samplers", json!({ "wrapS": 33071, "wrapT": 33648 }));
    doc.push("textures", json!({ "source": 0, "sampler": 0 }));
    doc.push("textures", json!({ "source": 1 }));
    doc.push(
        "materials",
        json!({
            "pbrMetallicRoughness": { "baseColorTexture": { "index": 0 } },
            "emissiveTexture": { "index": 1, "texCoord": 1 },
            "emissiveFactor": [1.0, 1.0, 1.0]
        }),
    );
    for path in [doc.write_gltf(d.path(), "scene"), doc.write_glb(d.path(), "scene")] {
        let s = load(&path).unwrap();
        assert_eq!(s.textures.len(), 2);
        assert_eq!(s.stats.textures, 2);
        let rg = &s.textures[0];
        assert_eq!((rg.name.as_str(), rg.width, rg.height), ("rg", 2, 1));
        assert_eq!(*rg.rgba8, [[255, 0, 0, 255], [0, 255, 0, 128]]);
        assert_eq!((rg.wrap_s, rg.wrap_t), (WrapMode::ClampToEdge, WrapMode::MirroredRepeat));
        assert!(rg.srgb);
        let b = &s.textures[1];
        assert_eq!(*b.rgba8, [[0, 0, 188, 255]]);
        assert_eq!((b.wrap_s, b.wrap_t), (WrapMode::Repeat, WrapMode::Repeat));
        let m = &s.materials[0];
        assert_eq!(m.base_color_texture.map(|t| (t.texture, t.tex_coord)), Some((0, 0)));
        assert_eq!(m.emissive_texture.map(|t| (t.texture, t.tex_coord)), Some((1, 1)));
        // Emission = factor × sRGB-decoded texture (188 → ~0.503).
        let e = m.emission_at(&s.textures, Vec2::splat(0.5));
        assert!(e.x == 0.0 && (e.z - 0.5029).abs() < 1e-3, "{e}");
        // The emissive texture reads TEXCOORD_1, the base colour TEXCOORD_0: both are read at
        // the base colour's, and the load says so.
        assert!(s.stats.warnings.iter().any(|w| w.contains("at other coordinates")), "{:?}", s.stats.warnings);
    }
}

/// Where a material's textures are read: `KHR_texture_transform` (required here, so a reader
/// without it must refuse the file) of the set the texture names, uv' = T·R·S·uv, at the
/// triangle's corners (values worked by hand from the extension's matrices). A transform
/// outside f32 is a clear error; a set livebake does not read is a warning.
#[test]
fn texture_transforms_and_sets_say_where_textures_are_read() {
    let d = tmp();
    let file = |name: &str, info: Value| {
        let mut doc = Doc::new();
        let mut p = doc.prim(&TRI, Some(&UP_Z), None);
        p["attributes"]["TEXCOORD_0"] = json!(doc.vec2(&[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]));
        p["attributes"]["TEXCOORD_1"] = json!(doc.vec2(&[[0.5, 0.5], [1.0, 0.5], [0.5, 1.0]]));
        p["material"] = json!(0);
        doc.mesh_node(vec![p], json!({}));
        let white = png(1, 1, |_, _| [255; 4]);
        doc.push("images", json!({ "uri": format!("data:image/png;base64,{}", base64(&white)) }));
        doc.push("textures", json!({ "source": 0 }));
        doc.push("materials", json!({ "pbrMetallicRoughness": { "baseColorTexture": info } }));
        doc.json["extensionsUsed"] = json!(["KHR_texture_transform"]);
        doc.json["extensionsRequired"] = json!(["KHR_texture_transform"]);
        doc.write_gltf(d.path(), name)
    };
    let corners = |s: &Scene| SceneGeometry::new(s).texture_uv_corners(s, 0);
    let transform = |t: Value| json!({ "index": 0, "extensions": { "KHR_texture_transform": t } });
    // Offset (0.5, −1), scale (2, 4) on TEXCOORD_1 (the extension's texCoord overrides the
    // textureInfo's 0): (2u + 0.5, 4v − 1).
    let s =
        load(&file("scaled", transform(json!({ "offset": [0.5, -1.0], "scale": [2.0, 4.0], "texCoord": 1 })))).unwrap();
    assert_eq!(corners(&s), [Vec2::new(1.5, 1.0), Vec2::new(2.5, 1.0), Vec2::new(1.5, 3.0)]);
    assert!(!s.stats.warnings.iter().any(|w| w.contains("KHR_texture_transform")), "{:?}", s.stats.warnings);
    // A quarter turn on TEXCOORD_0: R·uv = (v, −u).
    let s = load(&file("turned", transform(json!({ "rotation": std::f64::consts::FRAC_PI_2 })))).unwrap();
    let want = [Vec2::new(0.0, 0.0), Vec2::new(0.0, -1.0), Vec2::new(1.0, 0.0)];
    for (got, want) in corners(&s).iter().zip(want) {
        assert!((*got - want).abs().max_element() < 1e-6, "{got} vs {want}");
    }
    // The textureInfo's own texCoord: TEXCOORD_1 untransformed.
    let s = load(&file("second_set", json!({ "index": 0, "texCoord": 1 }))).unwrap();
    assert_eq!(corners(&s), [Vec2::new(0.5, 0.5), Vec2::new(1.0, 0.5), Vec2::new(0.5, 1.0)]);
    // TEXCOORD_2 is not read: TEXCOORD_0, said.
    let s = load(&file("third_set", json!({ "index": 0, "texCoord": 2 }))).unwrap();
    assert_eq!(corners(&s), [Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0), Vec2::new(0.0, 1.0)]);
    assert!(s.stats.warnings.iter().any(|w| w.contains("texCoord above 1")), "{:?}", s.stats.warnings);
    // 10³⁹ is past f32: an error naming the transform, not coordinates at infinity.
    let e = load_err(&file("huge", transform(json!({ "scale": [1e39, 1.0] })))).to_string();
    assert!(e.contains("KHR_texture_transform") && e.contains("not finite"), "{e}");
}

/// `EXT_mesh_gpu_instancing` (required here): the node's mesh once per instance, at the
/// node's transform times the instance's T·R·S (positions worked by hand); accessors of
/// unequal counts are a clear error, and so is a small file whose instances would make more
/// triangles than livebake loads, before any is made.
#[test]
fn gpu_instancing_places_one_mesh_per_instance() {
    let d = tmp();
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let file = |name: &str, translations: &[[f32; 3]]| {
        let mut doc = Doc::new();
        let p = doc.prim(&TRI, Some(&UP_Z), None);
        let t = doc.vec3(translations);
        let r = doc.accessor(None, FLOAT, "VEC4", 2, json!({}));
        let rotations: Vec<u8> = [0.0f32, 0.0, h, h, 0.0, 0.0, 0.0, 1.0].iter().flat_map(|v| v.to_le_bytes()).collect();
        doc.json["accessors"][r]["bufferView"] = json!(doc.view(&rotations, None));
        let s = doc.vec3(&[[1.0, 1.0, 1.0], [2.0, 2.0, 2.0]]);
        let instancing = json!({ "attributes": { "TRANSLATION": t, "ROTATION": r, "SCALE": s } });
        doc.mesh_node(
            vec![p],
            json!({ "name": "row", "translation": [10.0, 0.0, 0.0], "extensions": { "EXT_mesh_gpu_instancing": instancing } }),
        );
        doc.json["extensionsUsed"] = json!(["EXT_mesh_gpu_instancing"]);
        doc.json["extensionsRequired"] = json!(["EXT_mesh_gpu_instancing"]);
        doc.write_gltf(d.path(), name)
    };
    let s = load(&file("two", &[[0.0, 0.0, 0.0], [0.0, 2.0, 0.0]])).unwrap();
    assert_eq!(s.meshes.len(), 2);
    // Instance 0: a quarter turn about +Z, then the node's (10, 0, 0). Instance 1: scaled 2,
    // raised 2, then the node's move.
    let want = [
        [Vec3::new(10.0, 0.0, 0.0), Vec3::new(10.0, 1.0, 0.0), Vec3::new(9.0, 0.0, 0.0)],
        [Vec3::new(10.0, 2.0, 0.0), Vec3::new(12.0, 2.0, 0.0), Vec3::new(10.0, 4.0, 0.0)],
    ];
    for (m, want) in s.meshes.iter().zip(want) {
        for (got, want) in m.positions.iter().zip(want) {
            assert_close(*got, want, 1e-6);
        }
        assert!(m.normals.iter().all(|n| (*n - Vec3::Z).length() < 1e-6), "{:?}", m.normals);
    }
    assert_eq!((s.meshes[0].name.as_str(), s.meshes[1].name.as_str()), ("row#0/mesh0/0", "row#1/mesh0/0"));
    let e = load_err(&file("uneven", &[[0.0; 3]; 3])).to_string();
    assert!(e.contains("EXT_mesh_gpu_instancing") && e.contains("different counts"), "{e}");

    // 32 instances of 2²² triangles (an index accessor of zeros: no bytes behind it).
    let mut doc = Doc::new();
    let mut p = doc.prim(&TRI, Some(&UP_Z), None);
    p["indices"] = json!(doc.accessor(None, 5125, "SCALAR", 3 << 22, json!({})));
    let t = doc.accessor(None, FLOAT, "VEC3", 32, json!({ "min": [0.0, 0.0, 0.0], "max": [0.0, 0.0, 0.0] }));
    doc.mesh_node(
        vec![p],
        json!({ "extensions": { "EXT_mesh_gpu_instancing": { "attributes": { "TRANSLATION": t } } } }),
    );
    doc.json["extensionsUsed"] = json!(["EXT_mesh_gpu_instancing"]);
    let start = std::time::Instant::now();
    let e = load_err(&doc.write_gltf(d.path(), "bomb")).to_string();
    assert!(e.contains("triangles") && e.contains(&livebake::scene::MAX_SCENE_TRIANGLES.to_string()), "{e}");
    eprintln!("refused in {:.3} s: {e}", start.elapsed().as_secs_f64());
}

/// COLOR_0 in every encoding glTF allows (float VEC3 and VEC4, normalised unsigned byte and
/// short) is read as linear RGBA per vertex, alpha 1 for VEC3; a white one is dropped (it
/// changes nothing); the other encodings and values that are not finite are errors naming
/// the attribute; and it multiplies the base colour and alpha where the material is read
/// (`SceneGeometry::material_point`, `Material::albedo`, `Material::alpha`).
#[test]
fn vertex_colours_are_read_in_every_encoding() {
    let d = tmp();
    let colored = |name: &str, color: &dyn Fn(&mut Doc) -> usize| {
        let mut doc = Doc::new();
        let mut p = doc.prim(&TRI, Some(&UP_Z), None);
        p["attributes"]["COLOR_0"] = json!(color(&mut doc));
        p["material"] = json!(0);
        doc.json["materials"] = json!([{ "pbrMetallicRoughness": { "baseColorFactor": [0.5, 0.5, 0.5, 0.8] } }]);
        doc.mesh_node(vec![p], json!({}));
        doc.write_gltf(d.path(), name)
    };
    // Float VEC3: alpha 1.
    let s = load(&colored("vec3", &|doc| doc.vec3(&[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.25]]))).unwrap();
    let colors = s.meshes[0].colors.clone().expect("COLOR_0 read");
    assert_eq!(
        colors,
        vec![Vec4::new(1.0, 0.0, 0.0, 1.0), Vec4::new(0.0, 1.0, 0.0, 1.0), Vec4::new(0.0, 0.0, 0.25, 1.0)]
    );
    assert!(s.stats.warnings.iter().all(|w| !w.contains("COLOR_0")), "{:?}", s.stats.warnings);
    // At barycentrics (0.25, 0.5) the colour is 0.25·c1 + 0.5·c2 + 0.25·c0 = (0.25, 0.25, 0.125);
    // the albedo is the factor 0.5 times it, the alpha the factor's 0.8 times 1.
    let geom = SceneGeometry::new(&s);
    let p = geom.material_point(&s, 0, 0.25, 0.5);
    assert_eq!(p.color, Some(Vec4::new(0.25, 0.25, 0.125, 1.0)));
    let m = &s.materials[0];
    assert_eq!(m.albedo(&s.textures, p), Vec3::new(0.125, 0.125, 0.0625));
    assert_eq!(geom.albedo(&s, 0, 0.25, 0.5), Vec3::new(0.125, 0.125, 0.0625));
    assert_eq!(m.alpha(&s.textures, p), 0.8);
    assert_eq!(geom.uniform_albedo(&s, 0), None, "vertex colours vary the albedo");

    // Normalised unsigned byte VEC4 (k/255) and unsigned short VEC4 (k/65535).
    let unorm = |doc: &mut Doc, component: u32, values: &[u16]| {
        let bytes: Vec<u8> = match component {
            5121 => values.iter().map(|&v| v as u8).collect(),
            _ => values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        };
        let view = doc.view(&bytes, None);
        doc.accessor(Some(view), component, "VEC4", 3, json!({ "normalized": true }))
    };
    let bytes = [255, 0, 51, 255, 0, 255, 0, 128, 10, 20, 30, 0];
    let s = load(&colored("u8", &|doc| unorm(doc, 5121, &bytes))).unwrap();
    let expected: Vec<Vec4> =
        bytes.chunks(4).map(|c| Vec4::new(c[0] as f32, c[1] as f32, c[2] as f32, c[3] as f32) / 255.0).collect();
    assert_eq!(s.meshes[0].colors.as_deref(), Some(&expected[..]));
    let shorts = [65535, 0, 13107, 65535, 0, 65535, 0, 32768, 1, 2, 3, 0];
    let s = load(&colored("u16", &|doc| unorm(doc, 5123, &shorts))).unwrap();
    let expected: Vec<Vec4> =
        shorts.chunks(4).map(|c| Vec4::new(c[0] as f32, c[1] as f32, c[2] as f32, c[3] as f32) / 65535.0).collect();
    assert_eq!(s.meshes[0].colors.as_deref(), Some(&expected[..]));

    // White everywhere: changes nothing, not kept.
    let s = load(&colored("white", &|doc| doc.vec3(&[[1.0; 3]; 3]))).unwrap();
    assert_eq!(s.meshes[0].colors, None);
    // Out of [0, 1]: clamped, as the spec bounds it.
    let s = load(&colored("bright", &|doc| doc.vec3(&[[2.0, -1.0, 0.5]; 3]))).unwrap();
    assert_eq!(s.meshes[0].colors.as_ref().map(|c| c[0]), Some(Vec4::new(1.0, 0.0, 0.5, 1.0)));

    // Not finite, an unnormalised integer, a signed byte: clear errors.
    let e = load_err(&colored("nan", &|doc| doc.vec3(&[[f32::NAN, 0.0, 0.0]; 3]))).to_string();
    assert!(e.contains("COLOR_0"), "{e}");
    let e = load_err(&colored("raw", &|doc| {
        let view = doc.view(&[255u8; 12], None);
        doc.accessor(Some(view), 5121, "VEC4", 3, json!({}))
    }))
    .to_string();
    assert!(e.contains("COLOR_0") && e.contains("vertex colours must be"), "{e}");
    let e = load_err(&colored("signed", &|doc| {
        let view = doc.view(&[100u8; 12], None);
        doc.accessor(Some(view), 5120, "VEC4", 3, json!({ "normalized": true }))
    }))
    .to_string();
    assert!(e.contains("COLOR_0") && e.contains("vertex colours must be"), "{e}");
    // Fewer colours than positions.
    let e = load_err(&colored("short", &|doc| doc.vec3(&[[0.5; 3]; 2]))).to_string();
    assert!(e.contains("COLOR_0") && e.contains("POSITION has 3"), "{e}");
}

/// Specular-glossiness materials (KHR_materials_pbrSpecularGlossiness, which older exporters
/// write and list as required): the diffuse factor and texture are the albedo, in place of
/// the metallic-roughness fallback the file also carries; the file loads without a warning;
/// a diffuse factor that is not finite is an error naming it.
#[test]
fn specular_glossiness_materials_take_their_diffuse_colour() {
    let d = tmp();
    let doc = |diffuse: Value| {
        let mut doc = Doc::new();
        let mut p = doc.prim(&TRI, Some(&UP_Z), None);
        p["attributes"]["TEXCOORD_0"] = json!(doc.vec2(&[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]));
        p["material"] = json!(0);
        doc.mesh_node(vec![p], json!({}));
        let red = png(1, 1, |_, _| [255, 0, 0, 255]);
        let grey = png(1, 1, |_, _| [188, 188, 188, 128]);
        for image in [red, grey] {
            doc.push("images", json!({ "uri": format!("data:image/png;base64,{}", base64(&image)) }));
        }
        doc.push("textures", json!({ "source": 0 }));
        doc.push("textures", json!({ "source": 1 }));
        doc.push(
            "materials",
            json!({
                "pbrMetallicRoughness": { "baseColorFactor": [0.1, 0.1, 0.1, 1.0], "baseColorTexture": { "index": 0 } },
                "alphaMode": "BLEND",
                "extensions": { "KHR_materials_pbrSpecularGlossiness": diffuse }
            }),
        );
        doc.json["extensionsUsed"] = json!(["KHR_materials_pbrSpecularGlossiness"]);
        doc.json["extensionsRequired"] = json!(["KHR_materials_pbrSpecularGlossiness"]);
        doc
    };
    let s = load(
        &doc(json!({ "diffuseFactor": [0.5, 0.25, 1.0, 0.5], "diffuseTexture": { "index": 1 },
        "specularFactor": [1.0, 1.0, 1.0], "glossinessFactor": 0.9 }))
        .write_gltf(d.path(), "spec_gloss"),
    )
    .unwrap();
    assert!(s.stats.warnings.is_empty(), "{:?}", s.stats.warnings);
    let m = &s.materials[0];
    assert_eq!(m.base_color, Vec4::new(0.5, 0.25, 1.0, 0.5));
    let texture = m.base_color_texture.expect("the diffuse texture");
    assert_eq!(s.textures[texture.texture].rgba8[0], [188, 188, 188, 128]);
    assert!(s.textures[texture.texture].srgb, "the diffuse texture is sRGB");
    // Albedo: the factor times sRGB 188 decoded (0.502 886); alpha 0.5 × 128/255.
    let p = MaterialPoint::at_uv(Vec2::splat(0.5));
    assert!((m.albedo(&s.textures, p) - Vec3::new(0.5, 0.25, 1.0) * 0.502_886).abs().max_element() < 1e-5);
    assert!((m.alpha(&s.textures, p) - 0.5 * 128.0 / 255.0).abs() < 1e-6);
    // Without a diffuse texture the factor alone (the fallback's texture is not read).
    let s = load(&doc(json!({ "diffuseFactor": [0.5, 0.25, 1.0, 1.0] })).write_gltf(d.path(), "factor_only")).unwrap();
    assert_eq!((s.materials[0].base_color, s.materials[0].base_color_texture), (Vec4::new(0.5, 0.25, 1.0, 1.0), None));
    let e =
        load_err(&doc(json!({ "diffuseFactor": [1e39, 0.0, 0.0, 1.0] })).write_gltf(d.path(), "infinite")).to_string();
    assert!(e.contains("diffuseFactor"), "{e}");
}

/// Glass and cut-outs as architectural exports write them: a BLEND pane, a transmission
/// pane whose texture is shared with the base colour (read linearly for transmission, as
/// sRGB for colour), a MASK grille; their sheets follow T = (1 − α) + α·t·a.
#[test]
fn blend_transmission_and_mask_materials() {
    let d = tmp();
    let mut doc = Doc::new();
    let mut prims = Vec::new();
    for m in 0..3 {
        let mut p = doc.prim(&TRI, Some(&UP_Z), None);
        p["attributes"]["TEXCOORD_0"] = json!(doc.vec2(&[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]));
        p["material"] = json!(m);
        prims.push(p);
    }
    doc.mesh_node(prims, json!({}));
    let grey = png(1, 1, |_, _| [188, 188, 188, 255]);
    doc.push("images", json!({ "uri": format!("data:image/png;base64,{}", base64(&grey)) }));
    doc.push("textures", json!({ "source": 0 }));
    doc.push(
        "materials",
        json!({ "pbrMetallicRoughness": { "baseColorFactor": [0.8, 0.9, 1.0, 0.25] }, "alphaMode": "BLEND" }),
    );
    doc.push(
        "materials",
        json!({
            "pbrMetallicRoughness": { "baseColorTexture": { "index": 0 } },
            "extensions": { "KHR_materials_transmission": {
                "transmissionFactor": 0.5, "transmissionTexture": { "index": 0 } } }
        }),
    );
    doc.push("materials", json!({ "alphaMode": "MASK", "alphaCutoff": 0.25 }));
    doc.json["extensionsUsed"] = json!(["KHR_materials_transmission"]);
    doc.json["extensionsRequired"] = json!(["KHR_materials_transmission"]);
    let s = load(&doc.write_gltf(d.path(), "glass")).unwrap();
    assert!(s.stats.warnings.iter().all(|w| !w.contains("KHR_materials_transmission")), "{:?}", s.stats.warnings);
    let uv = Vec2::splat(0.5);
    let blend = &s.materials[0];
    assert_eq!((blend.alpha_mode, blend.transmission), (AlphaMode::Blend, 0.0));
    let sheet = blend.sheet(&s.textures, MaterialPoint::at_uv(uv));
    assert!((sheet.pass - Vec3::splat(0.75)).abs().max_element() < 1e-6, "{sheet:?}");
    assert!((sheet.reflect - Vec3::new(0.2, 0.225, 0.25)).abs().max_element() < 1e-6, "{sheet:?}");
    let glass = &s.materials[1];
    assert_eq!(glass.transmission, 0.5);
    let (colour, transmission) = (glass.base_color_texture.unwrap(), glass.transmission_texture.unwrap());
    assert_ne!(colour.texture, transmission.texture, "one image, two decodings");
    assert!(s.textures[colour.texture].srgb && !s.textures[transmission.texture].srgb);
    // t = 0.5 × 188/255 (linear); a = sRGB 188 decoded (0.5029).
    let (t, a) = (0.5 * 188.0 / 255.0, 0.502_886);
    let sheet = glass.sheet(&s.textures, MaterialPoint::at_uv(uv));
    assert!((sheet.pass.x - t * a).abs() < 1e-4 && (sheet.reflect.x - (1.0 - t) * a).abs() < 1e-4, "{sheet:?}");
    assert_eq!(s.materials[2].alpha_mode, AlphaMode::Mask { cutoff: 0.25 });
    assert!(!s.materials[2].is_see_through() && blend.is_see_through() && glass.is_see_through());
}

#[test]
fn texcoords_non_finite_and_normalized() {
    let d = tmp();
    let mut doc = Doc::new();
    let mut p = doc.prim(&TRI, Some(&UP_Z), None);
    p["attributes"]["TEXCOORD_0"] = json!(doc.vec2(&[[0.5, 0.5], [f32::NAN, 1.0], [1.0, 0.0]]));
    p["attributes"]["TEXCOORD_1"] = json!(doc.vec2(&[[0.0, 0.0], [0.0, f32::INFINITY], [1.0, 0.0]]));
    // Normalized unsigned byte / short UVs (core glTF allows them for TEXCOORD).
    let mut q = doc.prim(&TRI, Some(&UP_Z), None);
    let v8 = doc.view(&[0, 255, 255, 0, 51, 102, 0, 0], None);
    q["attributes"]["TEXCOORD_0"] = json!(doc.accessor(Some(v8), U8, "VEC2", 3, json!({ "normalized": true })));
    let shorts: Vec<u8> = [0u16, 65535, 65535, 0, 13107, 26214].iter().flat_map(|s| s.to_le_bytes()).collect();
    let v16 = doc.view(&shorts, None);
    q["attributes"]["TEXCOORD_1"] = json!(doc.accessor(Some(v16), U16, "VEC2", 3, json!({ "normalized": true })));
    doc.mesh_node(vec![p, q], json!({}));
    let s = load(&doc.write_gltf(d.path(), "scene")).unwrap();
    let a = &s.meshes[0];
    assert_eq!(a.uv0.as_deref(), Some(&[Vec2::new(0.5, 0.5), Vec2::ZERO, Vec2::new(1.0, 0.0)][..]));
    assert!(a.uv1.is_none());
    let b = &s.meshes[1];
    let expected = [Vec2::new(0.0, 1.0), Vec2::new(1.0, 0.0), Vec2::new(0.2, 0.4)];
    assert_eq!(b.uv0.as_deref(), Some(&expected[..]));
    assert_eq!(b.uv1.as_deref(), Some(&expected[..]));
    let w = &s.stats.warnings;
    assert!(w.iter().any(|w| w.starts_with("1 non-finite TEXCOORD_0")), "{w:?}");
    assert!(w.iter().any(|w| w.starts_with("1 primitive(s) have non-finite TEXCOORD_1")), "{w:?}");
}

#[test]
fn interleaved_strided_attributes_and_index_types() {
    let d = tmp();
    let mut doc = Doc::new();
    // POSITION and NORMAL interleaved, 24-byte stride; accessor byteOffset 12 for NORMAL.
    let mut bytes = Vec::new();
    for p in TRI {
        bytes.extend(p.iter().flat_map(|f| f.to_le_bytes()));
        bytes.extend([0.0f32, 0.0, 1.0].iter().flat_map(|f| f.to_le_bytes()));
    }
    let view = doc.view(&bytes, Some(24));
    let pos = doc.accessor(Some(view), FLOAT, "VEC3", 3, json!({ "min": [0, 0, 0], "max": [1, 1, 0] }));
    let nrm = doc.accessor(Some(view), FLOAT, "VEC3", 3, json!({ "byteOffset": 12 }));
    let i8 = doc.indices_u8(&[0, 1, 2]);
    let i32 = doc.indices_u32(&[2, 0, 1]);
    let prims = vec![
        json!({ "attributes": { "POSITION": pos, "NORMAL": nrm }, "indices": i8 }),
        json!({ "attributes": { "POSITION": pos, "NORMAL": nrm }, "indices": i32 }),
    ];
    doc.mesh_node(prims, json!({}));
    let s = load(&doc.write_gltf(d.path(), "scene")).unwrap();
    for m in &s.meshes {
        assert_eq!(m.positions, TRI.map(Vec3::from).to_vec());
        assert_eq!(m.normals, vec![Vec3::Z; 3]);
    }
    assert_eq!(s.meshes[0].triangles, vec![[0, 1, 2]]);
    assert_eq!(s.meshes[1].triangles, vec![[2, 0, 1]]);
}

#[test]
fn sparse_accessors_and_accessors_without_buffer_view() {
    let d = tmp();
    let mut doc = Doc::new();
    // Zeros + sparse values at vertices 1 and 2.
    let idx = doc.view(&[1u16, 2].iter().flat_map(|i| i.to_le_bytes()).collect::<Vec<_>>(), None);
    let vals: Vec<u8> = [1.0f32, 0.0, 0.0, 0.0, 1.0, 0.0].iter().flat_map(|f| f.to_le_bytes()).collect();
    let val = doc.view(&vals, None);
    let sparse =
        json!({ "count": 2, "indices": { "bufferView": idx, "componentType": U16 }, "values": { "bufferView": val } });
    let pos = doc.accessor(None, FLOAT, "VEC3", 3, json!({ "min": [0, 0, 0], "max": [1, 1, 0], "sparse": sparse }));
    // Dense normals with vertex 0 overridden sparsely (u8 index).
    let dense = doc.vec3(&[[9.0, 9.0, 9.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]);
    let one = doc.view(&[0u8], None);
    let zup: Vec<u8> = [0.0f32, 0.0, 1.0].iter().flat_map(|f| f.to_le_bytes()).collect();
    let zv = doc.view(&zup, None);
    doc.json["accessors"][dense]["sparse"] =
        json!({ "count": 1, "indices": { "bufferView": one, "componentType": U8 }, "values": { "bufferView": zv } });
    // A normals accessor with no bufferView and no sparse: all zeros → repaired.
    let zeros = doc.accessor(None, FLOAT, "VEC3", 3, json!({}));
    let prims = vec![
        json!({ "attributes": { "POSITION": pos, "NORMAL": dense } }),
        json!({ "attributes": { "POSITION": pos, "NORMAL": zeros } }),
    ];
    doc.mesh_node(prims, json!({}));
    let s = load(&doc.write_gltf(d.path(), "scene")).unwrap();
    assert_eq!(s.meshes[0].positions, TRI.map(Vec3::from).to_vec());
    assert_eq!(s.meshes[0].normals, vec![Vec3::Z; 3]);
    assert_eq!(s.meshes[1].normals, vec![Vec3::Z; 3]);
    assert_eq!(s.stats.normals_replaced, 3);

    // A sparse index beyond the count is out of bounds.
    let mut j = doc.json_with_buffer(Some("scene.bin".into()));
    let bad_idx = [5u16, 2].iter().flat_map(|i| i.to_le_bytes()).collect::<Vec<_>>();
    let mut bin = doc.bin.clone();
    let off = j["bufferViews"][idx]["byteOffset"].as_u64().unwrap() as usize;
    bin[off..off + 4].copy_from_slice(&bad_idx);
    std::fs::write(d.path().join("scene.bin"), &bin).unwrap();
    j["buffers"][0]["uri"] = json!("scene.bin");
    let e = load_err(&write_json(d.path(), "scene.gltf", &j));
    assert!(matches!(&e, LoadError::AccessorOutOfBounds { detail, .. } if detail.contains("sparse index 5")), "{e}");
}

#[test]
fn quantized_attributes_with_khr_mesh_quantization() {
    let d = tmp();
    let mut doc = Doc::new();
    // POSITION as plain u16 (scaled by the node), NORMAL as normalized i8.
    let pos: Vec<u8> = [0u16, 0, 0, 0, 100, 0, 0, 0, 0, 100, 0, 0].iter().flat_map(|v| v.to_le_bytes()).collect();
    let pv = doc.view(&pos, Some(8));
    let p = doc.accessor(Some(pv), U16, "VEC3", 3, json!({ "min": [0, 0, 0], "max": [100, 100, 0] }));
    let nrm: [i8; 12] = [0, 0, 127, 0, -128, 0, 0, 0, 0, 127, 0, 0];
    let nv = doc.view(&nrm.map(|b| b as u8), Some(4));
    let n = doc.accessor(Some(nv), 5120, "VEC3", 3, json!({ "normalized": true }));
    doc.mesh_node(
        vec![json!({ "attributes": { "POSITION": p, "NORMAL": n } })],
        json!({ "scale": [0.01, 0.01, 0.01] }),
    );
    doc.json["extensionsUsed"] = json!(["KHR_mesh_quantization", "KHR_materials_volume"]);
    doc.json["extensionsRequired"] = json!(["KHR_mesh_quantization"]);
    let s = load(&doc.write_gltf(d.path(), "scene")).unwrap();
    let m = &s.meshes[0];
    assert_eq!(m.positions, TRI.map(Vec3::from).to_vec());
    // (0, 0, 127) → +Z; (−128, 0, 0) → −1 (clamped) → −X; (0, 127, 0) → +Y.
    assert_eq!(m.normals, vec![Vec3::Z, Vec3::NEG_X, Vec3::Y]);
    let w = &s.stats.warnings;
    assert!(
        w.iter().any(|w| w.contains("not supported and were ignored") && w.contains("KHR_materials_volume")),
        "{w:?}"
    );
    assert!(!w.iter().any(|w| w.contains("KHR_mesh_quantization")), "{w:?}");
}

#[test]
fn punctual_lights_in_world_space() {
    let d = tmp();
    let mut doc = Doc::new();
    let p = doc.prim(&TRI, Some(&UP_Z), None);
    doc.mesh_node(vec![p], json!({}));
    let s45 = std::f32::consts::FRAC_1_SQRT_2;
    // Rotation −90° about X turns −Z into −Y (pointing down).
    let down = json!([-s45, 0.0, 0.0, s45]);
    doc.json["extensions"] = json!({ "KHR_lights_punctual": { "lights": [
        { "type": "directional", "color": [1.0, 0.5, 0.25], "intensity": 3.0, "name": "sun" },
        { "type": "point", "intensity": 10.0, "range": 5.0 },
        { "type": "spot", "intensity": 7.0, "spot": { "innerConeAngle": 0.2, "outerConeAngle": 0.5 } },
        { "type": "spot", "spot": {} },
    ]}});
    doc.json["extensionsUsed"] = json!(["KHR_lights_punctual"]);
    let ext = |i: usize| json!({ "KHR_lights_punctual": { "light": i } });
    let sun = doc.push("nodes", json!({ "rotation": down, "translation": [5.0, 5.0, 5.0], "extensions": ext(0) }));
    let point = doc.push("nodes", json!({ "name": "bulb", "translation": [1.0, 2.0, 3.0], "extensions": ext(1) }));
    let spot = doc.push(
        "nodes",
        json!({ "name": "spot", "translation": [0.0, 3.0, 0.0], "rotation": down, "extensions": ext(2) }),
    );
    let spot2 = doc.push("nodes", json!({ "name": "spot2", "extensions": ext(3) }));
    // The point light hangs under a translated, scaled parent.
    let parent =
        doc.push("nodes", json!({ "translation": [0.0, 10.0, 0.0], "scale": [2.0, 2.0, 2.0], "children": [point] }));
    for n in [sun, parent, spot, spot2] {
        doc.add_root(n);
    }
    let s = load(&doc.write_gltf(d.path(), "scene")).unwrap();
    assert_eq!(s.lights.len(), 4);
    assert_eq!(s.stats.lights, 4);
    let sun = &s.lights[0];
    assert_eq!((sun.name.as_str(), sun.kind), ("sun", LightKind::Directional));
    assert_eq!(sun.intensity, Vec3::new(3.0, 1.5, 0.75));
    assert_close(sun.direction, Vec3::NEG_Y, 1e-6);
    assert_eq!(sun.range, None);
    // A surface facing the sun gets exactly its intensity (W/m²).
    let (e, _, _) = sun.unoccluded_irradiance(Vec3::ZERO, Vec3::Y);
    assert_close(e, Vec3::new(3.0, 1.5, 0.75), 1e-5);

    let point = s.lights.iter().find(|l| l.name == "bulb").unwrap();
    assert_eq!(point.kind, LightKind::Point);
    assert_close(point.position, Vec3::new(2.0, 14.0, 6.0), 1e-5);
    assert_eq!(point.intensity, Vec3::splat(10.0));
    assert_eq!(point.range, Some(5.0));

    let spot = s.lights.iter().find(|l| l.name == "spot").unwrap();
    assert_eq!(spot.kind, LightKind::Spot { inner_cone: 0.2, outer_cone: 0.5 });
    assert_close(spot.position, Vec3::new(0.0, 3.0, 0.0), 1e-6);
    assert_close(spot.direction, Vec3::NEG_Y, 1e-6);
    assert_eq!(spot.intensity, Vec3::splat(7.0));
    let spot2 = s.lights.iter().find(|l| l.name == "spot2").unwrap();
    assert_eq!(spot2.kind, LightKind::Spot { inner_cone: 0.0, outer_cone: std::f32::consts::FRAC_PI_4 });
    assert_eq!(spot2.direction, Vec3::NEG_Z);
    assert_eq!(spot2.intensity, Vec3::ONE);
}

#[test]
fn cameras_drop_scale() {
    let d = tmp();
    let mut doc = Doc::new();
    let p = doc.prim(&TRI, Some(&UP_Z), None);
    doc.mesh_node(vec![p], json!({}));
    doc.push(
        "cameras",
        json!({ "type": "perspective", "name": "eye",
        "perspective": { "yfov": 0.8, "znear": 0.1, "zfar": 100.0, "aspectRatio": 1.5 } }),
    );
    doc.push(
        "cameras",
        json!({ "type": "orthographic",
        "orthographic": { "xmag": 2.0, "ymag": 1.0, "znear": 0.5, "zfar": 50.0 } }),
    );
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let a = doc.push("nodes", json!({ "camera": 0, "translation": [1.0, 2.0, 3.0], "rotation": [0.0, h, 0.0, h] }));
    let b = doc.push(
        "nodes",
        json!({ "name": "ortho", "camera": 1, "scale": [3.0, 3.0, 3.0], "translation": [0.0, 0.0, 5.0] }),
    );
    let parent = doc.push("nodes", json!({ "translation": [10.0, 0.0, 0.0], "children": [b] }));
    doc.add_root(a);
    doc.add_root(parent);
    let s = load(&doc.write_gltf(d.path(), "scene")).unwrap();
    assert_eq!(s.cameras.len(), 2);
    let c = &s.cameras[0];
    assert_eq!(c.name, "eye");
    assert_close(c.position, Vec3::new(1.0, 2.0, 3.0), 1e-6);
    // Looking along −Z rotated 90° about +Y: along −X.
    assert_close(c.rotation * Vec3::NEG_Z, Vec3::NEG_X, 1e-6);
    assert!(matches!(
        c.projection,
        Projection::Perspective { yfov: 0.8, aspect: Some(1.5), znear: 0.1, zfar: Some(100.0) }
    ));
    let o = &s.cameras[1];
    assert_eq!(o.name, "ortho");
    assert_close(o.position, Vec3::new(10.0, 0.0, 5.0), 1e-6);
    assert!((o.rotation.length() - 1.0).abs() < 1e-6);
    assert_close(o.rotation * Vec3::NEG_Z, Vec3::NEG_Z, 1e-6);
    assert!(matches!(o.projection, Projection::Orthographic { xmag: 2.0, ymag: 1.0, znear: 0.5, zfar: 50.0 }));
}

#[test]
fn scene_selection() {
    let d = tmp();
    let mut doc = Doc::new();
    let p = doc.prim(&TRI, Some(&UP_Z), None);
    let q = doc.prim(&TRI, Some(&UP_Z), None);
    let a = doc.mesh_node(vec![p], json!({ "name": "a" }));
    let mesh_b = doc.push("meshes", json!({ "primitives": [q] }));
    let b = doc.push("nodes", json!({ "name": "b", "mesh": mesh_b }));
    let c = doc.push("nodes", json!({ "name": "c", "children": [b] }));
    doc.push("scenes", json!({ "nodes": [c] }));
    let names = |s: &Scene| s.meshes.iter().map(|m| m.name.clone()).collect::<Vec<_>>();
    // Default scene (0), then "scene": 1, then LoadOptions overriding it.
    assert_eq!(names(&load(&doc.write_gltf(d.path(), "s0")).unwrap()), ["a/mesh0/0"]);
    doc.json["scene"] = json!(1);
    let path = doc.write_gltf(d.path(), "s1");
    assert_eq!(names(&load(&path).unwrap()), ["b/mesh1/0"]);
    let s = load_gltf(&path, &LoadOptions { scene: Some(0), ..LoadOptions::default() }).unwrap();
    assert_eq!(names(&s), ["a/mesh0/0"]);
    assert!(matches!(
        load_gltf(&path, &LoadOptions { scene: Some(7), ..LoadOptions::default() }),
        Err(LoadError::Invalid { .. })
    ));
    // No scenes at all: every root node (b only once, under c).
    let mut j = doc.json_with_buffer(Some("s1.bin".into()));
    j.as_object_mut().unwrap().remove("scenes");
    j.as_object_mut().unwrap().remove("scene");
    let s = load(&write_json(d.path(), "none.gltf", &j)).unwrap();
    assert_eq!(names(&s), ["a/mesh0/0", "b/mesh1/0"]);
    assert_eq!(s.stats.nodes, 3);
    let _ = (a, c);
}

#[test]
fn unnamed_objects_get_index_names() {
    let d = tmp();
    let mut doc = Doc::new();
    let p = doc.prim(&TRI, Some(&UP_Z), None);
    let mesh = doc.push("meshes", json!({ "primitives": [p] }));
    let n = doc.push("nodes", json!({ "mesh": mesh }));
    doc.add_root(n);
    let s = load(&doc.write_gltf(d.path(), "scene")).unwrap();
    assert_eq!(s.meshes[0].name, "node0/mesh0/0");
    assert_eq!(s.meshes[0].node, Some(0));
}

// ---------------------------------------------------------------------------------------------
// robustness: truncations and byte flips must give Ok or Err, never a panic

/// Deterministic positions (an LCG), so a failure reproduces.
fn positions(len: usize, n: usize, seed: u64) -> Vec<usize> {
    let mut x = seed;
    (0..n)
        .map(|_| {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((x >> 33) as usize) % len.max(1)
        })
        .collect()
}

fn must_not_panic(path: &Path, bytes: &[u8], what: &str) -> bool {
    let r = std::panic::catch_unwind(|| load_gltf_bytes(path, bytes, &LoadOptions::default()));
    match r {
        Ok(Ok(_)) => true,
        Ok(Err(e)) => {
            assert!(e.to_string().starts_with(&path.display().to_string()), "{what}: {e}");
            false
        }
        Err(_) => panic!("{what}: the loader panicked"),
    }
}

/// The Cornell box as one GLB: the .bin and both PNGs in the BIN chunk.
fn cornell_glb() -> Vec<u8> {
    let mut j: Value = serde_json::from_slice(&std::fs::read(asset(CORNELL)).unwrap()).unwrap();
    let mut bin = std::fs::read(asset("cornell_box/cornellBox-2.79-Cycles-gltf.bin")).unwrap();
    let images = j["images"].as_array().unwrap().clone();
    for (i, img) in images.iter().enumerate() {
        let bytes = std::fs::read(asset(&format!("cornell_box/{}", img["uri"].as_str().unwrap()))).unwrap();
        while bin.len() % 4 != 0 {
            bin.push(0);
        }
        let view = j["bufferViews"].as_array().unwrap().len();
        j["bufferViews"]
            .as_array_mut()
            .unwrap()
            .push(json!({ "buffer": 0, "byteOffset": bin.len(), "byteLength": bytes.len() }));
        bin.extend_from_slice(&bytes);
        j["images"][i] = json!({ "name": img["name"], "bufferView": view, "mimeType": "image/png" });
    }
    j["buffers"] = json!([{ "byteLength": bin.len() }]);
    glb(&j, &bin)
}

#[test]
fn cornell_glb_loads_like_the_gltf() {
    let glb = cornell_glb();
    let d = tmp();
    let a = load(&write(d.path(), "cornell.glb", &glb)).unwrap();
    let b = load(&asset(CORNELL)).unwrap();
    assert_same_scene(&a, &b);
    assert_eq!(a.textures.len(), 2);
    assert_eq!(a.textures[0].rgba8, b.textures[0].rgba8);
}

#[test]
fn truncated_files_never_panic() {
    let gltf_path = asset(CORNELL); // relative URIs still resolve next to it
    let text = std::fs::read(&gltf_path).unwrap();
    let mut lengths: Vec<usize> = (0..64).collect();
    lengths.extend(positions(text.len(), 150, 1));
    for &n in &lengths {
        assert!(!must_not_panic(&gltf_path, &text[..n], &format!("gltf cut at {n}")));
    }
    let glb = cornell_glb();
    let glb_path = Path::new("/nonexistent/cornell.glb");
    let mut lengths: Vec<usize> = (0..80).collect();
    lengths.extend(positions(glb.len(), 250, 2));
    for &n in &lengths {
        assert!(!must_not_panic(glb_path, &glb[..n], &format!("glb cut at {n}")));
    }
    assert!(must_not_panic(glb_path, &glb, "whole glb"));
}

#[test]
fn flipped_bytes_never_panic() {
    let gltf_path = asset(CORNELL);
    let text = std::fs::read(&gltf_path).unwrap();
    let masks = [0x01u8, 0x02, 0x04, 0x08, 0x10, 0x20, 0x40, 0x80, 0xFF];
    let mut ok = 0;
    for (k, &pos) in positions(text.len(), 400, 3).iter().enumerate() {
        let mut b = text.clone();
        b[pos] ^= masks[k % masks.len()];
        ok += usize::from(must_not_panic(&gltf_path, &b, &format!("gltf byte {pos} ^ {:#x}", masks[k % masks.len()])));
    }
    // Flip digits into other digits: numbers change but the JSON stays valid, which reaches
    // the bounds checks rather than the parser.
    let digits: Vec<usize> = (0..text.len()).filter(|&i| text[i].is_ascii_digit()).collect();
    for (k, &i) in positions(digits.len(), 400, 4).iter().enumerate() {
        let pos = digits[i];
        let mut b = text.clone();
        b[pos] = b'0' + ((b[pos] - b'0' + 1 + (k % 9) as u8) % 10);
        ok += usize::from(must_not_panic(&gltf_path, &b, &format!("gltf digit {pos}")));
    }
    assert!(ok > 0, "some corruptions are harmless and must still load");

    let glb = cornell_glb();
    let glb_path = Path::new("/nonexistent/cornell.glb");
    let json_len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    // Header and JSON chunk densely, the BIN chunk (geometry and PNG data) sparsely.
    let mut spots = positions(20 + json_len, 300, 5);
    spots.extend(positions(glb.len(), 300, 6));
    for (k, &pos) in spots.iter().enumerate() {
        let mut b = glb.clone();
        b[pos] ^= masks[k % masks.len()];
        must_not_panic(glb_path, &b, &format!("glb byte {pos} ^ {:#x}", masks[k % masks.len()]));
    }
}

/// Longer corruption run (not part of the default suite):
/// `LOADER_FUZZ_ITERS=20000 cargo test --release --test loader -- --ignored fuzz_long`.
#[test]
#[ignore = "long fuzz run; set LOADER_FUZZ_ITERS"]
fn fuzz_long() {
    let iters: usize = std::env::var("LOADER_FUZZ_ITERS").ok().and_then(|v| v.parse().ok()).unwrap_or(2000);
    let glb = cornell_glb();
    let glb_path = Path::new("/nonexistent/cornell.glb");
    let json_end = 20 + u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let rand = positions(usize::MAX, iters * 4, 7);
    let (mut ok, mut err) = (0, 0);
    for i in 0..iters {
        let mut b = glb.clone();
        // 1–3 edits, half of them in the JSON chunk; digits stay digits there half the time.
        for k in 0..1 + rand[4 * i] % 3 {
            let r = rand[4 * i + 1 + k];
            let pos = if r % 2 == 0 { r / 2 % json_end } else { r / 2 % b.len() };
            b[pos] = match (r >> 8) % 4 {
                0 if b[pos].is_ascii_digit() => b'0' + (r >> 12) as u8 % 10,
                1 => 0xFF,
                2 => 0,
                _ => b[pos] ^ (1 << ((r >> 12) % 8)),
            };
        }
        if must_not_panic(glb_path, &b, &format!("fuzz iteration {i}")) {
            ok += 1;
        } else {
            err += 1;
        }
    }
    println!("{iters} corrupted GLBs: {ok} loaded, {err} rejected");
}
