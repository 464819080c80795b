//! Scenes placed far from their file's origin (a building in site or map coordinates):
//! loaded into a frame of their own, so `f32` positions keep their millimetres, and read and
//! written in the file's coordinates at every boundary (points, exports).
//!
//! The scene is the bundled Cornell box under one more root node, translated by `FAR` (about
//! 4 200 km, where `f32` spacing is 0.5 m: before the scene had a frame of its own, every
//! vertex was off by up to a quarter metre there, and a probe at 332 points of the Cornell
//! room moved that far was wrong at every point).

use std::path::{Path, PathBuf};

use glam::{DVec3, Vec3};
use livebake::atlas::AtlasConfig;
use livebake::bake::{BakeConfig, bake};
use livebake::export::{ExportOptions, export_gltf};
use livebake::output::irradiance_image;
use livebake::points::read_points;
use livebake::progress::NoProgress;
use livebake::scene::{LoadOptions, Scene, SceneGeometry, load_gltf};
use serde_json::{Value, json};

const FAR: DVec3 = DVec3::new(4_194_304.0 + 1000.5, -2_097_152.0, 4_194_304.0);

fn cornell_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/cornell_box")
}

fn load(path: &Path) -> Scene {
    load_gltf(path, &LoadOptions::default()).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The Cornell box's files in `dir`, its glTF with every root under a node translated by
/// `by`, beside a camera and a point light (children of that node).
fn moved_cornell(dir: &Path, by: DVec3) -> PathBuf {
    for entry in std::fs::read_dir(cornell_dir()).unwrap() {
        let path = entry.unwrap().path();
        std::fs::copy(&path, dir.join(path.file_name().unwrap())).unwrap();
    }
    let source = dir.join("cornellBox-2.79-Cycles-gltf.gltf");
    let mut j: Value = serde_json::from_slice(&std::fs::read(&source).unwrap()).unwrap();
    let scene = j["scene"].as_u64().unwrap_or(0) as usize;
    let mut children: Vec<Value> = j["scenes"][scene]["nodes"].as_array().unwrap().clone();
    j["cameras"] = json!([{ "type": "perspective", "perspective": { "yfov": 0.8, "znear": 0.1 } }]);
    j["extensions"]["KHR_lights_punctual"] = json!({ "lights": [{ "type": "point", "intensity": 2.0 }] });
    j["extensionsUsed"] = json!(["KHR_lights_punctual"]);
    let nodes = j["nodes"].as_array_mut().unwrap();
    nodes.push(json!({ "name": "eye", "translation": [0.3, 1.2, 3.5], "camera": 0 }));
    nodes.push(json!({ "name": "lamp", "translation": [0.2, 1.6, 0.1], "extensions": { "KHR_lights_punctual": { "light": 0 } } }));
    children.extend([json!(nodes.len() - 2), json!(nodes.len() - 1)]);
    nodes.push(json!({ "name": "site", "children": children, "translation": by.to_array() }));
    let wrapper = nodes.len() - 1;
    j["scenes"][scene]["nodes"] = json!([wrapper]);
    let moved = dir.join("moved.gltf");
    std::fs::write(&moved, serde_json::to_vec(&j).unwrap()).unwrap();
    moved
}

/// Largest per-axis distance between the two scenes' vertices, the far one's carried back by
/// `FAR` and its origin (in f64), after checking both have the same meshes and vertex counts.
fn worst_vertex_gap(near: &Scene, far: &Scene) -> f64 {
    assert_eq!(near.meshes.len(), far.meshes.len());
    let mut worst = 0.0f64;
    for (a, b) in near.meshes.iter().zip(&far.meshes) {
        assert_eq!(a.positions.len(), b.positions.len(), "{}", a.name);
        for (p, q) in a.positions.iter().zip(&b.positions) {
            let back = q.as_dvec3() + far.origin - FAR;
            worst = worst.max((back - p.as_dvec3()).abs().max_element());
        }
    }
    worst
}

/// The moved box loads into a frame whose origin is near it and on the 256 m grid, and every
/// vertex, the camera and the light are where the box's are, to float rounding at the box's
/// size.
///
/// Tolerance: the near box's positions are `f32` at ≤ 4 m (spacing 4.8·10⁻⁷ m) and the far
/// one's are rounded once from `f64` at the same size, so they agree within a few spacings:
/// 10⁻⁵ m allows twenty. At 4 200 km `f32` spacing is 0.5 m: positions made there are off by
/// up to 0.25 m.
#[test]
fn a_scene_far_from_its_file_origin_loads_as_the_same_geometry() {
    let dir = tempfile::tempdir().unwrap();
    let (near_dir, far_dir) = (dir.path().join("near"), dir.path().join("far"));
    std::fs::create_dir_all(&near_dir).unwrap();
    std::fs::create_dir_all(&far_dir).unwrap();
    let near = load(&moved_cornell(&near_dir, DVec3::ZERO));
    let far = load(&moved_cornell(&far_dir, FAR));
    assert_eq!(near.origin, DVec3::ZERO, "a scene near its file's origin keeps it");
    assert_eq!(far.origin % 256.0, DVec3::ZERO, "{}", far.origin);
    assert!((far.origin - FAR).abs().max_element() <= 256.0, "origin {} for a box at {FAR}", far.origin);

    let worst = worst_vertex_gap(&near, &far);
    assert!(worst <= 1e-5, "a vertex is {worst} m from the box's");

    let same_place = |a: Vec3, b: Vec3, what: &str| {
        let back = far.to_file(b) - FAR;
        assert!((back - a.as_dvec3()).abs().max_element() <= 1e-5, "{what} at {back}, not {a}");
    };
    same_place(near.cameras[0].position, far.cameras[0].position, "camera");
    assert!(near.cameras[0].rotation.abs_diff_eq(far.cameras[0].rotation, 1e-6));
    same_place(near.lights[0].position, far.lights[0].position, "light");
}

/// Points are read in the file's coordinates and given in the scene's frame, from `f64`: a
/// quarter metre 4 194 304 m out survives (as `f32` it is 4 194 304.0).
#[test]
fn points_are_read_in_the_scenes_frame() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("points.json");
    let points = json!({ "points": [{ "p": [4_194_304.25, 0.5, -4_194_304.75], "n": [0.0, 1.0, 0.0] }] });
    std::fs::write(&path, points.to_string()).unwrap();
    let file = read_points(&path).unwrap();
    let q = file.queries(DVec3::new(4_194_304.0, 0.0, -4_194_304.0));
    assert_eq!(q[0].p, Vec3::new(0.25, 0.5, -0.75));
    assert_eq!(q[0].n, Vec3::Y);
    assert_eq!(file.queries(DVec3::ZERO)[0].p.y, 0.5);
}

/// An export of the far scene puts its geometry back where the file has it: loaded again, it
/// gets the same origin and the same vertices, bit for bit (f32 positions under a translation
/// by the origin, taken off again in f64).
#[test]
fn an_export_of_a_far_scene_lies_where_the_file_has_it() {
    let dir = tempfile::tempdir().unwrap();
    let far = load(&moved_cornell(dir.path(), FAR));
    let config = BakeConfig {
        atlas: AtlasConfig { texel_size: Some(0.1), ..AtlasConfig::default() },
        samples: 8,
        ..BakeConfig::default()
    };
    let baked = bake(&std::sync::Arc::new(far.clone()), &config, &NoProgress).unwrap();
    let out = dir.path().join("export.gltf");
    let lod = baked.lods.last().unwrap();
    export_gltf(&far, &baked.atlas, &irradiance_image(lod), &out, &ExportOptions::default()).unwrap();

    let again = load(&out);
    assert_eq!(again.origin, far.origin);
    let corners = |s: &Scene| -> Vec<[u32; 3]> {
        let geom = SceneGeometry::new(s);
        let mut v: Vec<[u32; 3]> = geom.corners.iter().flatten().map(|p| p.to_array().map(f32::to_bits)).collect();
        v.sort();
        v
    };
    assert_eq!(corners(&again), corners(&far));
}
