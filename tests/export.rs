//! glTF export (`livebake::export`, `livebake bake --export-gltf`): the Khronos validator
//! accepts the files, the light map read back from the export equals the bake at the same
//! surface points (front and back of double-sided faces), the source's materials, textures
//! and images survive, instanced meshes and shared vertices are split as they must be, and
//! bad input gets one clear error with nothing half-written.
//!
//! The validator (and the engines checked in `engines_*`) run under Node.js from the npm
//! packages `scripts/test` installs into `$LIVEBAKE_NODE_TOOLS` (default
//! `~/.cache/livebake-node`). Without Node the tests that need it say so and pass; with Node
//! but without the packages they fail, naming `scripts/test`.

mod support;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use glam::{Vec2, Vec3};
use image::Rgb32FImage;
use livebake::atlas::{Atlas, AtlasConfig};
use livebake::bake::{BakeConfig, BakeOutput, BakedLod, bake};
use livebake::export::{ExportError, ExportOptions, ExportReport, export_gltf};
use livebake::output::irradiance_image;
use livebake::probe::{LightmapSampler, SurfacePoint};
use livebake::progress::NoProgress;
use livebake::scene::{LoadError, LoadOptions, Scene, SceneBuilder, SceneGeometry, Side, load_gltf};
use serde_json::{Value, json};
use support::livebake;

const CORNELL: &str = "cornell_box/cornellBox-2.79-Cycles-gltf.gltf";
const VAN_GOGH_LIT: &str = "van_gogh_room/van_gogh_room_lit.gltf";

fn asset(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets").join(rel)
}

fn load(path: &Path) -> Scene {
    load_gltf(path, &LoadOptions::default()).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// A quick bake (few directions, coarse texels): the export is checked against this bake, so
/// it need not be converged. Two LODs, so the exported map (the finest) is LOD 1.
fn quick_bake(scene: &Scene, texel: f32) -> BakeOutput {
    let config = BakeConfig {
        atlas: AtlasConfig { texel_size: Some(texel), ..AtlasConfig::default() },
        lods: 2,
        samples: 16,
        seed: 5,
        ..BakeConfig::default()
    };
    bake(&std::sync::Arc::new(scene.clone()), &config, &NoProgress).unwrap_or_else(|e| panic!("bake: {e}"))
}

fn export(scene: &Scene, baked: &BakeOutput, out: &Path) -> ExportReport {
    let lod = baked.lods.last().unwrap();
    export_gltf(scene, &baked.atlas, &irradiance_image(lod), out, &ExportOptions::default())
        .unwrap_or_else(|e| panic!("export {}: {e}", out.display()))
}

fn read_json(path: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())))
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .map(|d| d.filter_map(|e| e.ok()).map(|e| e.file_name().to_string_lossy().into_owned()).collect())
        .unwrap_or_default();
    names.sort();
    names
}

// ---------------------------------------------------------------------------------------
// Node.js and the npm tools of scripts/test

/// Where scripts/test installs the npm packages.
fn node_tools() -> PathBuf {
    match std::env::var_os("LIVEBAKE_NODE_TOOLS") {
        Some(dir) => PathBuf::from(dir),
        None => PathBuf::from(std::env::var_os("HOME").unwrap_or_default()).join(".cache/livebake-node"),
    }
}

fn node_present() -> bool {
    Command::new("node").arg("--version").output().is_ok_and(|o| o.status.success())
}

/// The npm package `name` from scripts/test. Node or the package missing is a failure, never a
/// skip: the README's test command installs both.
fn npm_package(name: &str) -> PathBuf {
    assert!(
        node_present(),
        "Node.js is not installed: run the tests through scripts/test, which installs it and {name}"
    );
    let dir = node_tools().join("node_modules").join(name);
    assert!(
        dir.join("package.json").exists(),
        "Node.js is installed but the npm package {name} is not in {} (LIVEBAKE_NODE_TOOLS): run scripts/test, which installs it",
        node_tools().display()
    );
    dir
}

/// Runs `node script args…`, requires success, returns stdout.
fn node(script: &Path, args: &[&str]) -> String {
    let out = Command::new("node").arg(script).args(args).output().expect("cannot run node");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "node {} {args:?} failed ({}):\n{stderr}", script.display(), out.status);
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The Khronos validator's report of `gltf`; panics on any error or warning.
fn validate(gltf: &Path) -> Value {
    npm_package("gltf-validator");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/engines/validate.cjs");
    let tools = node_tools();
    let report: Value = serde_json::from_str(&node(&script, &[tools.to_str().unwrap(), gltf.to_str().unwrap()]))
        .expect("validator report is JSON");
    let issues = &report["issues"];
    let bad: Vec<&Value> =
        issues["messages"].as_array().unwrap().iter().filter(|m| m["severity"].as_u64() <= Some(1)).collect();
    assert_eq!(issues["numErrors"], 0, "{}: validator errors: {bad:#?}", gltf.display());
    assert_eq!(issues["numWarnings"], 0, "{}: validator warnings: {bad:#?}", gltf.display());
    report
}

// ---------------------------------------------------------------------------------------
// Validator

/// Both bundled scenes (Cornell box: textures, TEXCOORD_1 in the file, a node hierarchy;
/// Van Gogh room with lamps: double-sided faces, a KHR_lights_punctual light, a default
/// material) export to files with no validator errors or warnings.
#[test]
fn validator_accepts_exports_of_the_bundled_scenes() {
    let dir = tempfile::tempdir().unwrap();
    for (rel, texel) in [(CORNELL, 0.05), (VAN_GOGH_LIT, 0.1)] {
        let scene = load(&asset(rel));
        let baked = quick_bake(&scene, texel);
        let out = dir.path().join(format!("{}.gltf", Path::new(rel).file_stem().unwrap().to_string_lossy()));
        let report = export(&scene, &baked, &out);
        assert!(report.primitives >= scene.meshes.len(), "{rel}: {} primitives", report.primitives);
        let v = validate(&out);
        // The validator read every resource: the buffer, the embedded images, the PNG.
        let resources = v["info"]["resources"].as_array().unwrap();
        assert!(resources.iter().any(|r| r["uri"].as_str().is_some_and(|u| u.ends_with(".lightmap.png"))), "{v:#}");
    }
}

/// A node whose mesh is instanced (`EXT_mesh_gpu_instancing`) and which also carries a light
/// exports its instances as world-space geometry, like every mesh, and keeps its light on a
/// node without the extension (the extension on a node without a mesh is invalid glTF): the
/// validator accepts the file, and loaded again it holds both instances' triangles where the
/// source put them.
#[test]
fn instanced_meshes_export_as_world_space_geometry() {
    let dir = tempfile::tempdir().unwrap();
    let mut d = support::Doc::new();
    let quad = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, -1.0], [0.0, 0.0, -1.0]];
    let p = d.prim(&quad, Some(&[[0.0, 1.0, 0.0]; 4]), Some(&[0, 1, 2, 0, 2, 3]));
    let t = d.vec3(&[[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]]);
    d.json["extensions"] = json!({ "KHR_lights_punctual": { "lights": [{ "type": "point", "intensity": 5.0 }] } });
    d.mesh_node(
        vec![p],
        json!({ "name": "pair", "translation": [0.0, 0.0, 2.0], "extensions": {
            "EXT_mesh_gpu_instancing": { "attributes": { "TRANSLATION": t } },
            "KHR_lights_punctual": { "light": 0 } } }),
    );
    d.json["extensionsUsed"] = json!(["EXT_mesh_gpu_instancing", "KHR_lights_punctual"]);
    let scene = load(&d.write_gltf(dir.path(), "pair"));
    assert_eq!(scene.meshes.len(), 2);
    let baked = quick_bake(&scene, 0.1);
    let out = dir.path().join("export.gltf");
    export(&scene, &baked, &out);
    let json = read_json(&out);
    let text = json.to_string();
    assert!(!text.contains("EXT_mesh_gpu_instancing"), "{text}");
    assert!(json["nodes"].as_array().unwrap().iter().any(|n| n.pointer("/extensions/KHR_lights_punctual").is_some()));
    validate(&out);
    let again = load(&out);
    let corners = |s: &Scene| {
        let geom = SceneGeometry::new(s);
        let mut c: Vec<[u32; 3]> = geom.corners.iter().flatten().map(|p| p.to_array().map(f32::to_bits)).collect();
        c.sort();
        c
    };
    assert_eq!(corners(&again), corners(&scene));
    let xs: Vec<f32> = scene.meshes.iter().map(|m| m.positions[0].x).collect();
    assert_eq!(xs, [0.0, 3.0]);
}

/// Vertex colours (COLOR_0) travel with the export, per vertex, so that an engine multiplies
/// them into the base colour as livebake's bake did: the validator accepts the file and,
/// loaded again, each triangle's corners hold the source's colours (written as float VEC4;
/// the source's normalised bytes k/255 come back as the same f32).
#[test]
fn vertex_colours_travel_with_the_export() {
    let dir = tempfile::tempdir().unwrap();
    let mut d = support::Doc::new();
    let quad = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, -1.0], [0.0, 0.0, -1.0]];
    let mut p = d.prim(&quad, Some(&[[0.0, 1.0, 0.0]; 4]), Some(&[0, 1, 2, 0, 2, 3]));
    let bytes = [255u8, 0, 0, 255, 0, 255, 0, 128, 0, 0, 255, 255, 51, 102, 153, 0];
    let view = d.view(&bytes, None);
    p["attributes"]["COLOR_0"] = json!(d.accessor(Some(view), 5121, "VEC4", 4, json!({ "normalized": true })));
    d.mesh_node(vec![p], json!({ "name": "tinted" }));
    let scene = load(&d.write_gltf(dir.path(), "tinted"));
    assert!(scene.meshes[0].colors.is_some());
    let baked = quick_bake(&scene, 0.1);
    let out = dir.path().join("export.gltf");
    export(&scene, &baked, &out);
    validate(&out);
    let again = load(&out);
    // Per triangle: its corners' positions and colours, as bits.
    type Corners = ([[u32; 3]; 3], [[u32; 4]; 3]);
    let by_corners = |s: &Scene| {
        let geom = SceneGeometry::new(s);
        let mut c: Vec<Corners> = (0..geom.len())
            .map(|t| {
                let colors = geom.color_corners(s, t).expect("vertex colours").map(|c| c.to_array().map(f32::to_bits));
                (geom.corners[t].map(|p| p.to_array().map(f32::to_bits)), colors)
            })
            .collect();
        c.sort();
        c
    };
    assert_eq!(by_corners(&again), by_corners(&scene));
}

/// A specular-glossiness material (KHR_materials_pbrSpecularGlossiness, required by the
/// source) is exported as metallic-roughness, its diffuse colour the base colour: the
/// extension is gone from the file (engines such as three.js no longer read it), the
/// validator accepts it, a warning says so, and loaded again it has the same albedo.
#[test]
fn specular_glossiness_materials_export_as_written() {
    let dir = tempfile::tempdir().unwrap();
    let mut d = support::Doc::new();
    let quad = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, -1.0], [0.0, 0.0, -1.0]];
    let mut p = d.prim(&quad, Some(&[[0.0, 1.0, 0.0]; 4]), Some(&[0, 1, 2, 0, 2, 3]));
    p["material"] = json!(0);
    d.mesh_node(vec![p], json!({ "name": "plaster" }));
    d.push(
        "materials",
        json!({ "extensions": { "KHR_materials_pbrSpecularGlossiness": { "diffuseFactor": [0.6, 0.5, 0.4, 1.0] } } }),
    );
    d.json["extensionsUsed"] = json!(["KHR_materials_pbrSpecularGlossiness"]);
    d.json["extensionsRequired"] = json!(["KHR_materials_pbrSpecularGlossiness"]);
    let scene = load(&d.write_gltf(dir.path(), "plaster"));
    assert_eq!(scene.materials[0].base_color.truncate(), Vec3::new(0.6, 0.5, 0.4));
    let baked = quick_bake(&scene, 0.1);
    let out = dir.path().join("export.gltf");
    let report = export(&scene, &baked, &out);
    assert!(report.warnings.iter().any(|w| w.contains("specular-glossiness")), "{:?}", report.warnings);
    validate(&out);
    let json = read_json(&out);
    assert!(!json.to_string().contains("KHR_materials_pbrSpecularGlossiness"), "{json}");
    assert_eq!(json["materials"][0]["pbrMetallicRoughness"]["metallicFactor"], json!(0.0));
    assert_eq!(load(&out).materials[0].base_color, scene.materials[0].base_color);
}

// ---------------------------------------------------------------------------------------
// Round trip

/// Original triangle corners → the triangles of the re-loaded export with the same three
/// corner positions (bit for bit: world positions are written as f32 and the export's nodes
/// have identity transforms).
fn corner_key(c: &[Vec3; 3]) -> [[u32; 3]; 3] {
    let mut k = c.map(|p| p.to_array().map(f32::to_bits));
    k.sort();
    k
}

/// Bilinear filtering with clamp-to-edge, pixel centres at +0.5: what a GPU sampler with the
/// export's sampler settings (LINEAR, CLAMP_TO_EDGE) does.
fn bilinear(img: &Rgb32FImage, p: Vec2) -> Vec3 {
    let q = p - Vec2::splat(0.5);
    let (b, f) = (q.floor(), q - q.floor());
    let texel = |x: i64, y: i64| {
        let x = x.clamp(0, img.width() as i64 - 1) as u32;
        let y = y.clamp(0, img.height() as i64 - 1) as u32;
        Vec3::from(img.get_pixel(x, y).0)
    };
    let (x, y) = (b.x as i64, b.y as i64);
    texel(x, y) * (1.0 - f.x) * (1.0 - f.y)
        + texel(x + 1, y) * f.x * (1.0 - f.y)
        + texel(x, y + 1) * (1.0 - f.x) * f.y
        + texel(x + 1, y + 1) * f.x * f.y
}

/// Largest minus smallest channel value over the 4×4 pixels around `p`, and the largest.
fn local_range(img: &Rgb32FImage, p: Vec2) -> (f32, f32) {
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for dy in -2..2 {
        for dx in -2..2 {
            let x = (p.x.floor() as i64 + dx).clamp(0, img.width() as i64 - 1) as u32;
            let y = (p.y.floor() as i64 + dy).clamp(0, img.height() as i64 - 1) as u32;
            for v in img.get_pixel(x, y).0 {
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
    }
    (hi - lo, hi)
}

/// Deterministic barycentrics strictly inside a triangle (margin 0.05 from every edge).
fn barycentrics(i: usize) -> (f32, f32) {
    if i % 2 == 0 {
        return (1.0 / 3.0, 1.0 / 3.0);
    }
    let h = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    let (a, b) = ((h >> 40) as f32 / (1u64 << 24) as f32, ((h >> 16) & 0xFF_FFFF) as f32 / (1u64 << 24) as f32);
    let (a, b) = if a + b > 1.0 { (1.0 - a, 1.0 - b) } else { (a, b) };
    (0.05 + 0.85 * a, 0.05 + 0.85 * b)
}

/// One compared surface point, in terms an engine can find: the exported glTF mesh and
/// primitive, the triangle's corner positions, the point's weight on each of those corners.
#[derive(serde::Serialize)]
struct Sample {
    mesh: u64,
    primitive: u64,
    corners: [[f32; 3]; 3],
    weights: [f32; 3],
    /// What probe's sampler gives on the original bake.
    #[serde(skip)]
    expected: Vec3,
    /// The position part of the round-trip bound (see [`round_trip`]).
    #[serde(skip)]
    position_bound: f32,
    /// Largest channel value of the 4×4 pixels around the point.
    #[serde(skip)]
    local_max: f32,
}

struct RoundTrip {
    samples: Vec<Sample>,
    points: usize,
    double_sided_points: usize,
    /// Double-sided points whose front and back values differ by more than 10× the bound:
    /// where reading the wrong side's chart would fail the comparison.
    sides_differ: usize,
}

/// Loads the export back with our loader (TEXCOORD_1 as the lookup layout), samples its EXR
/// bilinearly at surface points of every `stride`-th face, and compares with
/// `probe::LightmapSampler` on the original bake at the same points.
///
/// Bound, per point: the EXR holds the bake's f32 values exactly, so only the position differs:
/// TEXCOORD_1 is the atlas UV divided by the atlas size in f32 (relative error 2⁻²⁴), and the
/// two sides interpolate the corners in different orders (a few more ulps of a coordinate of
/// at most the map size S). Together at most δ = 8·S·2⁻²⁴ pixels; bilinear filtering changes
/// by at most 2·δ × the value range of the 4×4 pixels around the point when moved by δ; plus
/// f32 rounding of the filter, 1e-6 of the values.
fn round_trip(scene: &Scene, baked: &BakeOutput, report: &ExportReport, stride: usize) -> RoundTrip {
    let geom = SceneGeometry::new(scene);
    let atlas = &baked.atlas;
    let lod: &BakedLod = baked.lods.last().unwrap();
    let sampler = LightmapSampler::new(atlas, lod);
    let exr = image::open(&report.hdr).unwrap().to_rgb32f();
    assert_eq!((exr.width(), exr.height()), (lod.texels.width, lod.texels.height));
    let size = Vec2::new(exr.width() as f32, exr.height() as f32);
    let delta = 8.0 * size.max_element() * f32::EPSILON / 2.0;

    let back = load(&report.gltf);
    let exported = read_json(&report.gltf);
    let mut by_corners: HashMap<[[u32; 3]; 3], Vec<(usize, usize)>> = HashMap::new();
    for (mi, m) in back.meshes.iter().enumerate() {
        assert!(m.uv1.is_some(), "{}: exported primitive without TEXCOORD_1", m.name);
        for t in 0..m.triangles.len() {
            by_corners.entry(corner_key(&m.corners(t))).or_default().push((mi, t));
        }
    }
    let mut rt = RoundTrip { samples: Vec::new(), points: 0, double_sided_points: 0, sides_differ: 0 };
    let mut ambiguous = 0;
    for (fi, face) in atlas.faces.iter().enumerate().step_by(stride) {
        let corners = geom.corners[face.tri as usize];
        let normal = geom.normals[face.tri as usize] * face.side.sign();
        // The exported triangle facing this side: the back of a double-sided face is a front
        // face of the back primitive.
        let same_corners = by_corners.get(&corner_key(&corners));
        let same_corners =
            same_corners.unwrap_or_else(|| panic!("face {fi}: triangle {} is not in the export", face.tri));
        let candidates: Vec<&(usize, usize)> = same_corners
            .iter()
            .filter(|&&(m, t)| {
                let [a, b, c] = back.meshes[m].corners(t);
                (b - a).cross(c - a).dot(normal) > 0.0
            })
            .collect();
        if candidates.len() != 1 {
            ambiguous += 1;
            continue;
        }
        let &(m, t) = candidates[0];
        let mesh = &back.meshes[m];
        let exported_corners = mesh.corners(t);
        let uv1 = mesh.uv1.as_ref().unwrap();
        let (u, v) = barycentrics(fi);
        let weights = [1.0 - u - v, u, v];
        // Exported corner j is original corner k.
        let uv = (0..3).fold(Vec2::ZERO, |acc, j| {
            let k = corners.iter().position(|c| *c == exported_corners[j]).unwrap();
            acc + uv1[mesh.triangles[t][j] as usize] * weights[k]
        });
        let p = uv * size;
        let got = bilinear(&exr, p);
        let at = |side| SurfacePoint { tri: face.tri, u, v, side, distance: 0.0 };
        let expected = sampler.irradiance(&at(face.side)).unwrap();
        let (range, local_max) = local_range(&exr, p);
        let position_bound = 2.0 * delta * range;
        let bound = position_bound + 1e-6 * expected.abs().max_element().max(1e-6);
        let err = (got - expected).abs().max_element();
        assert!(
            err <= bound,
            "face {fi} (triangle {}, {:?}) at ({u}, {v}): export {got} vs bake {expected} (error {err:e} > bound {bound:e})",
            face.tri,
            face.side
        );
        rt.points += 1;
        // The loader names a mesh instance `node/mesh/primitive`; the export's node says which mesh.
        let primitive = mesh.name.rsplit('/').next().and_then(|p| p.parse().ok()).unwrap();
        rt.samples.push(Sample {
            mesh: exported["nodes"][mesh.node.unwrap()]["mesh"].as_u64().unwrap(),
            primitive,
            corners: corners.map(|c| c.to_array()),
            weights,
            expected,
            position_bound,
            local_max,
        });
        if let Ok(other) = sampler.irradiance(&at(match face.side {
            Side::Front => Side::Back,
            Side::Back => Side::Front,
        })) {
            rt.double_sided_points += 1;
            rt.sides_differ += usize::from((other - expected).abs().max_element() > 10.0 * bound);
        }
    }
    // Coincident duplicate triangles cannot be told apart by position; real files have few.
    assert!(ambiguous * 50 <= rt.points, "{ambiguous} ambiguous faces against {} compared", rt.points);
    rt
}

/// The Van Gogh room (double-sided walls, furniture): front and back of double-sided faces
/// read back their own charts' values.
#[test]
fn round_trip_van_gogh_room_front_and_back() {
    let dir = tempfile::tempdir().unwrap();
    let scene = load(&asset(VAN_GOGH_LIT));
    let baked = quick_bake(&scene, 0.1);
    let report = export(&scene, &baked, &dir.path().join("room.gltf"));
    assert_eq!(report.lod, 1);
    let rt = round_trip(&scene, &baked, &report, 3);
    assert!(rt.points > 1000, "{} points", rt.points);
    assert!(rt.double_sided_points > 300, "{} double-sided points", rt.double_sided_points);
    // The comparison can tell the sides apart (a wall is lit inside and dark outside).
    assert!(rt.sides_differ * 4 > rt.double_sided_points, "{} of {}", rt.sides_differ, rt.double_sided_points);
}

/// The Cornell box (TEXCOORD_1 in the file used as charts, a node hierarchy with rotations).
#[test]
fn round_trip_cornell_box() {
    let dir = tempfile::tempdir().unwrap();
    let scene = load(&asset(CORNELL));
    let baked = quick_bake(&scene, 0.05);
    assert!(baked.atlas.stats.meshes_from_uv1 > 0, "the file's TEXCOORD_1 should be used for some meshes");
    let report = export(&scene, &baked, &dir.path().join("cornell.gltf"));
    let rt = round_trip(&scene, &baked, &report, 2);
    assert!(rt.points > 1000, "{} points", rt.points);
}

// ---------------------------------------------------------------------------------------
// Structure: a small file written here

/// A small file: a textured double-sided quad (with its own TEXCOORD_1, read by the
/// occlusion texture) instanced twice under a rotated parent that also holds a camera, and a
/// single-sided L (floor + wall sharing an edge, no TEXCOORD_1) with an external PNG texture.
fn small_file(dir: &Path) -> PathBuf {
    use support::*;
    let mut d = Doc::new();
    let tex = png(4, 4, |x, y| [(x * 60) as u8, (y * 60) as u8, 200, 255]);
    std::fs::write(dir.join("tex.png"), &tex).unwrap();
    d.push("images", json!({ "name": "checker", "uri": "tex.png" }));
    d.push("images", json!({ "uri": format!("data:image/png;base64,{}", base64(&tex)) }));
    d.push("samplers", json!({ "wrapS": 33648 }));
    d.push("textures", json!({ "sampler": 0, "source": 0 }));
    d.push("textures", json!({ "source": 1 }));
    d.push(
        "materials",
        json!({ "name": "two-sided", "doubleSided": true, "extras": { "keep": "me" },
                "pbrMetallicRoughness": { "baseColorTexture": { "index": 0 }, "metallicFactor": 0.0 },
                "occlusionTexture": { "index": 1, "texCoord": 1 } }),
    );
    d.push("materials", json!({ "name": "plain", "pbrMetallicRoughness": { "baseColorTexture": { "index": 1 } } }));
    let quad = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
    let mut p = d.prim(&quad, Some(&[[0.0, 0.0, 1.0]; 4]), Some(&[0, 1, 2, 0, 2, 3]));
    p["attributes"]["TEXCOORD_0"] = json!(d.vec2(&[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]));
    p["attributes"]["TEXCOORD_1"] = json!(d.vec2(&[[0.1, 0.1], [0.9, 0.1], [0.9, 0.9], [0.1, 0.9]]));
    p["material"] = json!(0);
    let quad_mesh = d.push("meshes", json!({ "name": "quad", "primitives": [p] }));
    let l = [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 0.0, -1.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [2.0, 1.0, 0.0]];
    let mut q = d.prim(&l, Some(&[[0.0, 1.0, 0.0]; 6]), Some(&[0, 1, 2, 0, 2, 3, 0, 4, 5, 0, 5, 1]));
    q["attributes"]["TEXCOORD_0"] = json!(d.vec2(&[[0.0, 0.0]; 6]));
    q["material"] = json!(1);
    let l_mesh = d.push("meshes", json!({ "name": "L", "primitives": [q] }));
    let a = d.push("nodes", json!({ "name": "A", "mesh": quad_mesh, "translation": [0.0, 0.0, 3.0] }));
    let b = d.push(
        "nodes",
        json!({ "name": "B", "mesh": quad_mesh, "translation": [2.0, 0.0, 3.0], "scale": [1.0, 2.0, 1.0] }),
    );
    d.push("cameras", json!({ "type": "perspective", "perspective": { "yfov": 0.8, "znear": 0.1 } }));
    let cam = d.push("nodes", json!({ "name": "cam", "camera": 0, "translation": [0.0, 1.0, 5.0] }));
    let parent = d.push(
        "nodes",
        json!({ "name": "parent", "children": [a, b, cam], "rotation": [0.0, 0.382_683_4, 0.0, 0.923_879_5] }),
    );
    d.add_root(parent);
    let l_node = d.mesh_node(vec![], json!({ "name": "floor and wall" }));
    d.json["nodes"][l_node]["mesh"] = json!(l_mesh);
    d.json["meshes"].as_array_mut().unwrap().pop();
    d.write_gltf(dir, "small")
}

fn atlas_for(scene: &Scene, texel: f32) -> Atlas {
    let geom = SceneGeometry::new(scene);
    Atlas::build(scene, &geom, &AtlasConfig { texel_size: Some(texel), ..AtlasConfig::default() }).unwrap()
}

/// A map over the atlas at LOD `lod` whose value encodes the pixel, so a wrong lookup shows.
fn gradient_map(atlas: &Atlas, lod: u32) -> Rgb32FImage {
    Rgb32FImage::from_fn(atlas.width << lod, atlas.height << lod, |x, y| image::Rgb([x as f32, y as f32, 1.0]))
}

fn accessor_f32(gltf: &Value, bin: &[u8], accessor: u64, width: usize) -> Vec<Vec<f32>> {
    let a = &gltf["accessors"][accessor as usize];
    let v = &gltf["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
    let start = v["byteOffset"].as_u64().unwrap() as usize;
    let count = a["count"].as_u64().unwrap() as usize;
    let floats: Vec<f32> =
        bin[start..start + count * width * 4].chunks(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect();
    floats.chunks(width).map(<[f32]>::to_vec).collect()
}

/// What the source had is kept (materials with extras, textures, samplers, images embedded
/// byte for byte, the camera under its rotated parent), every material gets MOZ_lightmap, the
/// file's TEXCOORD_1 moves to TEXCOORD_2 for the texture that reads it, each instance gets
/// its own TEXCOORD_1, vertices are split at chart seams, and double-sided primitives become
/// a front and a back primitive.
#[test]
fn export_keeps_the_source_and_splits_what_one_uv_set_cannot_address() {
    let dir = tempfile::tempdir().unwrap();
    let src = small_file(dir.path());
    let scene = load(&src);
    assert_eq!(scene.meshes.len(), 3);
    let atlas = atlas_for(&scene, 0.05);
    let out = dir.path().join("out/small export.gltf");
    let report = export_gltf(&scene, &atlas, &gradient_map(&atlas, 0), &out, &ExportOptions::default()).unwrap();
    assert_eq!(report.lod, 0);
    let source = read_json(&src);
    let g = read_json(&out);
    let bin = std::fs::read(&report.bin).unwrap();
    assert_eq!(g["buffers"][0]["uri"], "small%20export.bin");

    // Materials: the source's, single-sided, with the light map.
    for (i, m) in source["materials"].as_array().unwrap().iter().enumerate() {
        let e = &g["materials"][i];
        assert_eq!(e["name"], m["name"]);
        assert_eq!(e["pbrMetallicRoughness"], m["pbrMetallicRoughness"]);
        assert_eq!(e["extras"], m["extras"]);
        assert!(e.get("doubleSided").is_none());
        let lm = &e["extensions"]["MOZ_lightmap"];
        assert_eq!(lm["texCoord"], 1);
        assert_eq!(lm["intensity"].as_f64().unwrap() as f32, report.png_intensity);
        let t = &g["textures"][lm["index"].as_u64().unwrap() as usize];
        let img = &g["images"][t["source"].as_u64().unwrap() as usize];
        assert_eq!(img["uri"], "small%20export.lightmap.png");
        let s = &g["samplers"][t["sampler"].as_u64().unwrap() as usize];
        assert_eq!(s, &json!({ "magFilter": 9729, "minFilter": 9729, "wrapS": 33071, "wrapT": 33071 }));
    }
    assert_eq!(g["materials"][0]["occlusionTexture"], json!({ "index": 1, "texCoord": 2 }));
    assert!(g["extensionsUsed"].as_array().unwrap().contains(&json!("MOZ_lightmap")));
    // Textures, samplers as they were; images embedded with their bytes.
    assert_eq!(g["textures"][0], source["textures"][0]);
    assert_eq!(g["textures"][1], source["textures"][1]);
    assert_eq!(g["samplers"][0], source["samplers"][0]);
    let tex = std::fs::read(dir.path().join("tex.png")).unwrap();
    for i in 0..2 {
        let img = &g["images"][i];
        assert_eq!(img["mimeType"], "image/png");
        assert!(img.get("uri").is_none());
        let v = &g["bufferViews"][img["bufferView"].as_u64().unwrap() as usize];
        let (o, n) = (v["byteOffset"].as_u64().unwrap() as usize, v["byteLength"].as_u64().unwrap() as usize);
        assert_eq!(&bin[o..o + n], &tex[..], "image {i}");
    }
    assert_eq!(g["images"][0]["name"], "checker");

    // The camera keeps its place in the hierarchy; mesh-only nodes leave it.
    assert_eq!(g["cameras"], source["cameras"]);
    let parent = g["nodes"].as_array().unwrap().iter().find(|n| n["name"] == "parent").unwrap();
    assert_eq!(parent["rotation"], source["nodes"][3]["rotation"]);
    let children = parent["children"].as_array().unwrap();
    assert_eq!(children.len(), 1);
    let cam = &g["nodes"][children[0].as_u64().unwrap() as usize];
    assert_eq!((&cam["camera"], &cam["translation"]), (&json!(0), &source["nodes"][2]["translation"]));
    assert!(g["nodes"].as_array().unwrap().iter().filter(|n| n.get("mesh").is_none()).count() == 2);

    // Geometry: one node per instance, named as the source node, identity transform.
    let geometry: Vec<&Value> = g["nodes"].as_array().unwrap().iter().filter(|n| n.get("mesh").is_some()).collect();
    let names: Vec<&str> = geometry.iter().map(|n| n["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["A", "B", "floor and wall"]);
    assert!(geometry.iter().all(|n| n.get("translation").is_none() && n.get("matrix").is_none()));
    let prims = |n: &Value| g["meshes"][n["mesh"].as_u64().unwrap() as usize]["primitives"].as_array().unwrap().clone();
    let (pa, pb, pl) = (prims(geometry[0]), prims(geometry[1]), prims(geometry[2]));
    assert_eq!((pa.len(), pb.len(), pl.len()), (2, 2, 1), "double-sided quads get a back primitive");
    let attr = |p: &Value, name: &str, w| accessor_f32(&g, &bin, p["attributes"][name].as_u64().unwrap(), w);
    // World positions as the loader computed them.
    let world: Vec<Vec<f32>> = scene.meshes[0].positions.iter().map(|p| p.to_array().to_vec()).collect();
    assert_eq!(attr(&pa[0], "POSITION", 3), world);
    // Instances get different light-map UVs; front and back too.
    let (uv_a, uv_b) = (attr(&pa[0], "TEXCOORD_1", 2), attr(&pb[0], "TEXCOORD_1", 2));
    assert_ne!(uv_a, uv_b);
    assert_ne!(uv_a, attr(&pa[1], "TEXCOORD_1", 2));
    // The back: same points, reversed normals.
    let (n_front, n_back) = (attr(&pa[0], "NORMAL", 3), attr(&pa[1], "NORMAL", 3));
    for (f, b) in n_front.iter().zip(&n_back) {
        assert!(f.iter().zip(b).all(|(x, y)| *x == -*y), "{f:?} vs {b:?}");
    }
    // The file's TEXCOORD_1 travels as TEXCOORD_2 with its vertex.
    let file_uv1: Vec<Vec<f32>> = vec![vec![0.1, 0.1], vec![0.9, 0.1], vec![0.9, 0.9], vec![0.1, 0.9]];
    assert_eq!(attr(&pa[0], "TEXCOORD_2", 2), file_uv1);
    assert!(pl[0]["attributes"].get("TEXCOORD_2").is_none());
    // The L's floor and wall are two charts: the two vertices of their shared edge are split.
    let l_uv = attr(&pl[0], "TEXCOORD_1", 2);
    assert_eq!(l_uv.len(), 8, "4 + 4 vertices for two charts of 2 triangles");
    assert!(l_uv.iter().flatten().all(|v| (0.0..=1.0).contains(v)));
    assert!(report.warnings.is_empty(), "{:?}", report.warnings);

    // Sampling the map (pixel (x, y) holds (x, y, 1)) at a vertex's TEXCOORD_1 lands on the
    // pixel its atlas UV names: the layout is the atlas's, normalised.
    let f = atlas.face(0, Side::Front).unwrap();
    let expected = atlas.faces[f as usize].uv[0] / Vec2::new(atlas.width as f32, atlas.height as f32);
    let i0 = {
        let idx = &g["accessors"][pa[0]["indices"].as_u64().unwrap() as usize];
        let v = &g["bufferViews"][idx["bufferView"].as_u64().unwrap() as usize];
        let o = v["byteOffset"].as_u64().unwrap() as usize;
        u32::from_le_bytes(bin[o..o + 4].try_into().unwrap()) as usize
    };
    assert_eq!(Vec2::new(uv_a[i0][0], uv_a[i0][1]), expected);

    validate(&out);
}

// ---------------------------------------------------------------------------------------
// Bad input

/// Exports `scene` with `map`, expecting an error; checks `dir` got no file.
#[track_caller]
fn fails_in(scene: &Scene, atlas: &Atlas, map: &Rgb32FImage, out: &Path, dir: &Path) -> ExportError {
    let before = files_in(dir);
    let err = export_gltf(scene, atlas, map, out, &ExportOptions::default()).expect_err("export should fail");
    assert_eq!(files_in(dir), before, "a failed export wrote files: {err}");
    err
}

#[test]
fn bad_input_is_one_clear_error_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let src = small_file(dir.path());
    let scene = load(&src);
    let atlas = atlas_for(&scene, 0.05);
    let map = gradient_map(&atlas, 1);
    let out_dir = dir.path().join("out");
    std::fs::create_dir(&out_dir).unwrap();
    let out = out_dir.join("x.gltf");

    // Not a .gltf name.
    let e = fails_in(&scene, &atlas, &map, &out_dir.join("x.glb"), &out_dir);
    assert!(matches!(e, ExportError::OutputName { .. }) && e.to_string().contains(".gltf"), "{e}");
    // A map of no LOD of the atlas.
    let wrong = Rgb32FImage::new(atlas.width * 2 + 1, atlas.height * 2);
    let e = fails_in(&scene, &atlas, &wrong, &out, &out_dir);
    assert!(matches!(e, ExportError::LightmapSize { .. }), "{e}");
    // A NaN in the map.
    let mut nan = map.clone();
    nan.put_pixel(3, 2, image::Rgb([0.0, f32::NAN, 0.0]));
    let e = fails_in(&scene, &atlas, &nan, &out, &out_dir);
    assert!(matches!(e, ExportError::NonFinite { x: 3, y: 2 }), "{e}");
    // An atlas of another scene.
    let other = load(&asset(VAN_GOGH_LIT));
    let other_atlas = atlas_for(&other, 0.2);
    let e = fails_in(&scene, &other_atlas, &gradient_map(&other_atlas, 0), &out, &out_dir);
    assert!(matches!(e, ExportError::AtlasMismatch(_)), "{e}");
    // A scene made in code has no source file.
    let mut b = SceneBuilder::new();
    let m = b.material(livebake::scene::builder::white());
    b.quad("q", [Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y], m);
    let made = b.build();
    let made_atlas = atlas_for(&made, 0.1);
    let e = fails_in(&made, &made_atlas, &gradient_map(&made_atlas, 0), &out, &out_dir);
    assert!(matches!(e, ExportError::NoSource), "{e}");
    // The output directory cannot be created (a file is in the way).
    let blocker = dir.path().join("blocker");
    std::fs::write(&blocker, b"file").unwrap();
    let e = fails_in(&scene, &atlas, &map, &blocker.join("sub/x.gltf"), dir.path());
    assert!(matches!(e, ExportError::CreateDir { .. }) && e.to_string().contains("blocker"), "{e}");

    // The source's buffer is gone: the loader's error, naming the file.
    let bin = dir.path().join("small.bin");
    let bin_bytes = std::fs::read(&bin).unwrap();
    std::fs::remove_file(&bin).unwrap();
    let e = fails_in(&scene, &atlas, &map, &out, &out_dir);
    assert!(matches!(e, ExportError::Source(LoadError::MissingBuffer { .. })), "{e}");
    assert!(format!("{:#}", anyhow::Error::from(e)).contains("small.bin"));
    std::fs::write(&bin, &bin_bytes).unwrap();
    // The source changed since loading.
    let mut changed = read_json(&src);
    changed["materials"].as_array_mut().unwrap().pop();
    changed["meshes"][1]["primitives"][0]["material"] = json!(0);
    std::fs::write(&src, serde_json::to_vec(&changed).unwrap()).unwrap();
    let e = fails_in(&scene, &atlas, &map, &out, &out_dir);
    assert!(matches!(e, ExportError::SourceChanged { .. }) && e.to_string().contains("materials"), "{e}");
    // The source file itself is gone.
    std::fs::remove_file(&src).unwrap();
    let e = fails_in(&scene, &atlas, &map, &out, &out_dir);
    assert!(matches!(e, ExportError::Source(LoadError::Io { .. })), "{e}");
}

/// A failure while writing (here: a directory where the PNG goes) leaves an earlier export
/// of the same name whole and no temporary files.
#[test]
fn a_failed_export_leaves_the_previous_one_whole() {
    let dir = tempfile::tempdir().unwrap();
    let src = small_file(dir.path());
    let scene = load(&src);
    let atlas = atlas_for(&scene, 0.05);
    let out_dir = dir.path().join("out");
    let out = out_dir.join("x.gltf");
    let first = export_gltf(&scene, &atlas, &gradient_map(&atlas, 0), &out, &ExportOptions::default()).unwrap();
    let snapshot: Vec<(PathBuf, Vec<u8>)> =
        [&first.gltf, &first.bin, &first.hdr].iter().map(|p| (p.to_path_buf(), std::fs::read(p).unwrap())).collect();
    std::fs::remove_file(&first.png).unwrap();
    std::fs::create_dir(&first.png).unwrap();
    let e = export_gltf(&scene, &atlas, &gradient_map(&atlas, 1), &out, &ExportOptions::default()).unwrap_err();
    assert!(matches!(e, ExportError::Io { .. }) && e.to_string().contains("x.lightmap.png"), "{e}");
    for (p, bytes) in snapshot {
        assert_eq!(std::fs::read(&p).unwrap(), bytes, "{} changed", p.display());
    }
    let names = files_in(&out_dir);
    assert!(names.iter().all(|n| !n.ends_with(".partial")), "{names:?}");
}

// ---------------------------------------------------------------------------------------
// Command line

/// `livebake bake SCENE --export-gltf OUT.gltf` writes the export beside the bake's own files;
/// a bad export name is one `error:` line.
#[test]
fn cli_bake_exports_gltf() {
    let dir = tempfile::tempdir().unwrap();
    let scene = asset(VAN_GOGH_LIT).display().to_string();
    let args = [
        "bake",
        &scene,
        "--out",
        "bake",
        "--export-gltf",
        "web/room.gltf",
        "--samples",
        "8",
        "--texel-size",
        "0.2",
        "--lods",
        "2",
    ];
    let out = livebake(dir.path(), &args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert_eq!(files_in(&dir.path().join("web")), ["room.bin", "room.gltf", "room.lightmap.exr", "room.lightmap.png"]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("room.gltf") && stdout.contains("room.lightmap.exr"), "{stdout}");
    let g = read_json(&dir.path().join("web/room.gltf"));
    // The finest baked LOD (1) is exported: the EXR is the bake's own lightmap_lod1.exr.
    assert_eq!(g["asset"]["extras"]["livebake"]["lightmap"]["lod"], 1);
    let ours = image::open(dir.path().join("web/room.lightmap.exr")).unwrap().to_rgb32f();
    let bake_exr = image::open(dir.path().join("bake/lightmap_lod1.exr")).unwrap().to_rgb32f();
    assert!(ours == bake_exr, "the exported EXR differs from the bake's LOD 1");
    for m in g["meshes"].as_array().unwrap() {
        for p in m["primitives"].as_array().unwrap() {
            assert!(p["attributes"].get("TEXCOORD_1").is_some());
            let mat = &g["materials"][p["material"].as_u64().unwrap() as usize];
            assert_eq!(mat["extensions"]["MOZ_lightmap"]["texCoord"], 1);
        }
    }

    let bad = livebake(
        dir.path(),
        &["bake", &scene, "--out", "bake2", "--export-gltf", "web/room.glb", "--samples", "8", "--texel-size", "0.2"],
    );
    let stderr = String::from_utf8_lossy(&bad.stderr);
    assert!(!bad.status.success());
    let line = stderr.lines().find(|l| l.starts_with("error:")).unwrap_or_else(|| panic!("{stderr}"));
    assert!(line.contains("room.glb") && line.contains(".gltf"), "{line}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}

// ---------------------------------------------------------------------------------------
// Engines: docs/EXPORT.md's snippets, run on an export

/// Runs `tests/engines/HARNESS` (with docs/EXPORT.md's snippet files beside it and the npm tools as
/// its node_modules) on an export and the samples; returns its JSON.
fn run_harness(harness: &str, gltf: &Path, samples: &[Sample]) -> Value {
    let work = tempfile::tempdir().unwrap();
    let node_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/engines");
    for f in std::fs::read_dir(&node_dir).unwrap().filter_map(|e| e.ok()) {
        std::fs::copy(f.path(), work.path().join(f.file_name())).unwrap();
    }
    std::os::unix::fs::symlink(node_tools().join("node_modules"), work.path().join("node_modules")).unwrap();
    let samples_file = work.path().join("samples.json");
    std::fs::write(&samples_file, serde_json::to_vec(samples).unwrap()).unwrap();
    let out = node(&work.path().join(harness), &[gltf.to_str().unwrap(), samples_file.to_str().unwrap()]);
    serde_json::from_str(&out).unwrap_or_else(|e| panic!("{harness}: {e}: {}", &out[..out.len().min(2000)]))
}

/// A bake of the lit Van Gogh room exported, and every 7th face's sample point.
fn engine_fixture(dir: &Path) -> (ExportReport, RoundTrip) {
    let scene = load(&asset(VAN_GOGH_LIT));
    let baked = quick_bake(&scene, 0.1);
    let report = export(&scene, &baked, &dir.join("room.gltf"));
    let rt = round_trip(&scene, &baked, &report, 7);
    (report, rt)
}

/// Compares what an engine shades with (`values`, E in W/m² per sample) with the bake.
/// Bound: the PNG's 8-bit sRGB rounding for the values of the texels filtered there
/// ([`livebake::export::lightmap::png_error_below`] their largest value, × intensity; a
/// weighted mean of texel errors is no larger), the UV position bound of [`round_trip`], and
/// the harness's f32 → f64 arithmetic (1e-6 of intensity).
fn check_engine_values(engine: &str, values: &Value, rt: &RoundTrip, intensity: f32) {
    let values = values.as_array().unwrap();
    assert_eq!(values.len(), rt.samples.len());
    let mut worst = 0.0f32;
    for (s, v) in rt.samples.iter().zip(values) {
        let got =
            Vec3::from_slice(&v.as_array().unwrap().iter().map(|c| c.as_f64().unwrap() as f32).collect::<Vec<_>>());
        let png_bound = livebake::export::lightmap::png_error_below(s.local_max / intensity) * intensity;
        let bound = png_bound + s.position_bound + 1e-6 * intensity;
        let err = (got - s.expected).abs().max_element();
        worst = worst.max(err / bound);
        assert!(
            err <= bound,
            "{engine}: mesh {} primitive {}: {got} vs bake {} (error {err:e} > {bound:e})",
            s.mesh,
            s.primitive,
            s.expected
        );
    }
    eprintln!("{engine}: {} points, worst error {:.2} of the bound", values.len(), worst);
}

/// three.js (the pinned `three` of scripts/test) with docs/EXPORT.md's `MozLightmap` plugin: every
/// material gets the PNG as `lightMap` on channel 1 (TEXCOORD_1 = three's `uv1`), sRGB, with
/// `lightMapIntensity` = the file's intensity; the installed shader adds `lightMap ×
/// lightMapIntensity` to the irradiance it shades with; and that irradiance, computed from
/// three.js's parsed geometry and the PNG at each point, is the bake's E within the PNG's
/// rounding.
#[test]
fn engines_three_js_reads_the_light_map_as_irradiance() {
    npm_package("three");
    let dir = tempfile::tempdir().unwrap();
    let (report, rt) = engine_fixture(dir.path());
    let out = run_harness("three_check.mjs", &report.gltf, &rt.samples);
    let revision: u32 = out["revision"].as_str().unwrap().trim_end_matches("dev").parse().unwrap();
    assert!(revision >= 151, "three r{revision}: lightMap.channel needs r151");
    let chunk = out["shaderChunk"].as_str().unwrap();
    assert!(chunk.contains("vec3 lightMapIrradiance = lightMapTexel.rgb * lightMapIntensity;"), "{chunk}");
    assert!(chunk.contains("irradiance += lightMapIrradiance;"), "{chunk}");
    let materials = out["materials"].as_array().unwrap();
    assert_eq!(materials.len(), report.primitives);
    for m in materials {
        assert_eq!(m["hasLightMap"], true, "{m}");
        assert_eq!(m["channel"], 1, "{m}");
        assert_eq!(m["colorSpace"], "srgb", "{m}");
        assert_eq!(m["flipY"], false, "{m}");
        assert_eq!(m["lightMapIntensity"].as_f64().unwrap() as f32, report.png_intensity, "{m}");
        assert_eq!(m["side"], 0, "{m}: every exported material is single-sided (THREE.FrontSide)");
        assert_eq!(m["uv1"], true, "{m}");
    }
    check_engine_values("three.js", &out["values"], &rt, report.png_intensity);
}

/// Babylon.js (the pinned `@babylonjs/core` + `@babylonjs/loaders`, NullEngine) with the
/// MOZ_lightmap extension of docs/EXPORT.md: every PBR material gets the PNG as `lightmapTexture` on
/// coordinates index 1 (UV2 = TEXCOORD_1), as a colour (sRGB) texture, `level` = intensity/π,
/// `useLightmapAsShadowmap` with white ambient; the installed shaders multiply the final
/// colour by `lightmap × level` and make the ambient term `ambient × albedo`, so the surface
/// shows albedo × level × map; π × level × map at each point is the bake's E within the PNG's
/// rounding.
#[test]
fn engines_babylon_js_reads_the_light_map_as_irradiance_over_pi() {
    npm_package("@babylonjs/core");
    npm_package("@babylonjs/loaders");
    let dir = tempfile::tempdir().unwrap();
    let (report, rt) = engine_fixture(dir.path());
    let out = run_harness("babylon_check.mjs", &report.gltf, &rt.samples);
    let shaders: Vec<&str> = out["shaders"].as_array().unwrap().iter().map(|s| s.as_str().unwrap()).collect();
    let [init, compose, unlit] = shaders[..] else { panic!("{shaders:?}") };
    assert!(init.contains("lightmapColor.rgb*=vLightmapInfos.y;"), "{init}");
    assert!(compose.contains("#ifdef USELIGHTMAPASSHADOWMAP\nfinalColor.rgb*=lightmapColor.rgb;"), "{compose}");
    assert!(unlit.contains("vec3 finalAmbient=vAmbientColor;finalAmbient*=surfaceAlbedo.rgb;"), "{unlit}");
    let materials = out["materials"].as_array().unwrap();
    assert_eq!(materials.len(), report.primitives);
    for m in materials {
        assert_eq!(m["className"], "PBRMaterial", "{m}");
        assert_eq!(m["hasLightmap"], true, "{m}");
        assert_eq!(m["coordinatesIndex"], 1, "{m}");
        let level = m["level"].as_f64().unwrap();
        assert!((level - report.png_intensity as f64 / std::f64::consts::PI).abs() < 1e-6 * level, "{m}");
        assert!(m["gammaSpace"] == true || m["srgbBuffer"] == true, "{m}: the PNG must be decoded as sRGB");
        assert_eq!(m["useLightmapAsShadowmap"], true, "{m}");
        for key in ["ambient", "sceneAmbient"] {
            assert!(m[key].as_array().unwrap().iter().all(|c| c.as_f64() == Some(1.0)), "{m}: {key} must be white");
        }
        assert_eq!(m["uv2"], true, "{m}");
        assert!(
            m["pointers"].as_array().unwrap().iter().any(|p| p.as_str().unwrap().ends_with("/extensions/MOZ_lightmap")),
            "{m}"
        );
    }
    check_engine_values("Babylon.js", &out["values"], &rt, report.png_intensity);
}

/// The engine snippets of docs/EXPORT.md are the files the engine tests run (and the Bevy one
/// the file the Bevy test reads), word for word.
#[test]
fn export_doc_snippets_are_the_tested_files() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let doc = std::fs::read_to_string(root.join("docs/EXPORT.md")).unwrap();
    for (file, lang) in
        [("three_moz_lightmap.mjs", "js"), ("babylon_moz_lightmap.mjs", "js"), ("bevy_lightmap.rs", "rust")]
    {
        let text = std::fs::read_to_string(root.join("tests/engines").join(file)).unwrap();
        assert!(
            doc.contains(&format!("```{lang}\n{text}```")),
            "docs/EXPORT.md does not show tests/engines/{file} as it is"
        );
    }
}

/// Bevy is not built here (a full Bevy build is far too heavy for this project's CI). What the
/// Bevy snippet of docs/EXPORT.md relies on is checked on an export named as in the snippet: the image
/// it loads exists and `intensity × ` its sRGB-decoded texels is E (the EXR) at every texel
/// within the PNG's rounding; its `intensity` is `MOZ_lightmap.intensity`; and TEXCOORD_1 of
/// every primitive lies in [0, 1] over the whole image, so `uv_rect` is the full rectangle.
/// The snippet's Bevy calls and Bevy's shader arithmetic (docs/EXPORT.md) are read, not run.
#[test]
fn engines_bevy_snippet_matches_the_files() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let snippet = std::fs::read_to_string(root.join("tests/engines/bevy_lightmap.rs")).unwrap();
    for needle in [
        r#"from_asset("room.gltf")"#,
        r#"assets.load("room.lightmap.png")"#,
        "uv_rect: Rect::new(0.0, 0.0, 1.0, 1.0)",
        "m.lightmap_exposure = lightmap.intensity / std::f32::consts::PI;",
    ] {
        assert!(snippet.contains(needle), "the Bevy snippet no longer says {needle}");
    }
    let dir = tempfile::tempdir().unwrap();
    let scene = load(&asset(VAN_GOGH_LIT));
    let baked = quick_bake(&scene, 0.1);
    let report = export(&scene, &baked, &dir.path().join("room.gltf"));
    assert_eq!(report.png, dir.path().join("room.lightmap.png"));
    let g = read_json(&report.gltf);
    let bin = std::fs::read(&report.bin).unwrap();
    let s = report.png_intensity;
    assert_eq!(g["asset"]["extras"]["livebake"]["lightmap"]["png_intensity"].as_f64().unwrap() as f32, s);
    for m in g["materials"].as_array().unwrap() {
        assert_eq!(m["extensions"]["MOZ_lightmap"]["intensity"].as_f64().unwrap() as f32, s);
    }
    // TEXCOORD_1 in [0, 1], and together the primitives reach across the image.
    let (mut lo, mut hi) = (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY));
    for mesh in g["meshes"].as_array().unwrap() {
        for p in mesh["primitives"].as_array().unwrap() {
            for uv in accessor_f32(&g, &bin, p["attributes"]["TEXCOORD_1"].as_u64().unwrap(), 2) {
                let uv = Vec2::new(uv[0], uv[1]);
                lo = lo.min(uv);
                hi = hi.max(uv);
            }
        }
    }
    assert!(lo.cmpge(Vec2::ZERO).all() && hi.cmple(Vec2::ONE).all(), "TEXCOORD_1 spans {lo}..{hi}");
    assert!(lo.max_element() < 0.1 && hi.min_element() > 0.9, "TEXCOORD_1 spans only {lo}..{hi}: not the full image");
    // The PNG Bevy loads (sRGB) times intensity is the EXR.
    let png = image::open(&report.png).unwrap().to_rgb8();
    let exr = image::open(&report.hdr).unwrap().to_rgb32f();
    assert_eq!(png.dimensions(), exr.dimensions());
    for (q, e) in png.pixels().zip(exr.pixels()) {
        for c in 0..3 {
            let decoded = s * livebake::export::lightmap::srgb_decode(q.0[c] as f32 / 255.0);
            let bound = livebake::export::lightmap::png_error_below(e.0[c] / s) * s;
            assert!((decoded - e.0[c]).abs() <= bound, "PNG {} vs EXR {} (bound {bound})", decoded, e.0[c]);
        }
    }
}

/// `livebake run SCENE --export-gltf OUT.gltf`: when the run ends, the light map as shown is
/// exported at the finest LOD any cell shows; the validator accepts the files, and the
/// export's light map, read back as an engine reads it (TEXCOORD_1 of the re-loaded export,
/// bilinear over the EXR), matches what `run --points` read from the shown map at the same
/// 332 surface points of the 2 m room and 2000 on its walls.
///
/// Bound, per point (E_exp: the export read back; E_run: `run --points`). The export's pixels
/// hold the one sampling function S at their texels' surface points and pixel centres, so
/// E_exp is bilinear interpolation of S at the export's resolution:
/// * **Cells shown at the export LOD L**, farther than the blend band plus 3 LOD-L texels from
///   any face shared with a coarser cell (so no tap is blended, and every tap's texel lies in
///   a cell at LOD L; checked as every cell within that distance being at LOD L): S at a pixel centre is that published pixel itself (the bilinear
///   weight there is 1), so both sides interpolate the same four values with the same
///   weights; only the position differs, as in [`round_trip`]: 2·δ × the 4×4 range, plus f32
///   rounding (1e-6 of the values).
/// * **Elsewhere** (cells shown coarser, blend bands): S is bilinear at a coarser LOD k
///   (possibly blended), whose breaks (the LOD-k pixel centres) fall midway between LOD-L
///   pixel centres. Along one axis, interpolating a piecewise linear function with a break
///   midway between two samples errs by at most |a − b|/4 for slopes a, b on the two sides;
///   each slope is a difference of two neighbouring samples on its side (a piece spans
///   2^(L−k) ≥ 2 samples), so at most the range R of the 4×4 samples around the point: at
///   most R/2 per axis, R for the two axes. The blend weight, linear in position over a band
///   of 2^(L+1) LOD-L texels, adds at most (1/8)·2·|∇w|·R ≤ R/8 (curvature of w·(C − F) over
///   a unit square). Bound: 1.125·R + the rounding above.
#[test]
fn run_exports_the_light_map_it_showed() {
    let dir = tempfile::tempdir().unwrap();
    let room = asset("cornell_2m/cornell_2m.gltf");
    // The room's 332 reference points, and a 20 × 20 grid on each of its five walls (so
    // that, whichever cells the run's few seconds refine, some points lie in them).
    let mut list = read_json(&asset("cornell_2m/points.json"))["points"].as_array().unwrap().clone();
    for i in 0..20 {
        for j in 0..20 {
            let (a, b) = (0.05 + 0.1 * i as f32, 0.05 + 0.1 * j as f32);
            for (p, n) in [
                ([a, 0.0, b], [0.0, 1.0, 0.0]),
                ([a, 2.0, b], [0.0, -1.0, 0.0]),
                ([a, b, 0.0], [0.0, 0.0, 1.0]),
                ([0.0, a, b], [1.0, 0.0, 0.0]),
                ([2.0, a, b], [-1.0, 0.0, 0.0]),
            ] {
                list.push(json!({ "p": p, "n": n }));
            }
        }
    }
    let points = dir.path().join("points.json");
    std::fs::write(&points, serde_json::to_vec(&json!({ "points": list })).unwrap()).unwrap();
    let (room_s, points_s) = (room.display().to_string(), points.display().to_string());
    let args = [
        "run",
        &room_s,
        "--seconds",
        "4",
        "--threads",
        "2",
        // Swaps after 16 to 64 directions: cells (and groups of cells) refine within the
        // run's seconds on a slow machine too; this test is about the export, not convergence.
        "--min-directions",
        "16",
        "--max-directions",
        "64",
        // More levels than the room's default two, so that the run ends with cells at
        // several LODs (with early swaps every cell reaches LOD 1 within the seconds):
        // points in cells at the exported LOD and points elsewhere are both compared.
        "--lods",
        "4",
        "--camera",
        "0.3,1,1.7,1.7,0.6,0.3",
        "--out",
        "o",
        "--points",
        &points_s,
        "--points-out",
        "p.json",
        "--export-gltf",
        "web/room.gltf",
    ];
    let out = livebake(dir.path(), &args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert_eq!(files_in(&dir.path().join("web")), ["room.bin", "room.gltf", "room.lightmap.exr", "room.lightmap.png"]);
    let report = read_json(&dir.path().join("o/report.json"));
    let export = &report["export"];
    let lod = export["lod"].as_u64().unwrap() as u32;
    assert_eq!(export["finest_shown_lod"].as_u64(), Some(lod as u64), "{export}");
    assert!(lod >= 1, "no cell was refined in the run: {export}");
    let gltf = dir.path().join("web/room.gltf");
    assert_eq!(read_json(&gltf)["asset"]["extras"]["livebake"]["lightmap"]["lod"], lod);
    validate(&gltf);

    // The run's grid and the LOD each cell showed at the end.
    let cells = read_json(&dir.path().join("o/cells.json"));
    let g = &cells["grid"];
    let v3 = |v: &Value| {
        Vec3::new(v[0].as_f64().unwrap() as f32, v[1].as_f64().unwrap() as f32, v[2].as_f64().unwrap() as f32)
    };
    let grid = livebake::grid::Grid {
        origin: v3(&g["origin"]),
        cell_size: g["cell_size"].as_f64().unwrap() as f32,
        dims: [0, 1, 2].map(|i| g["dims"][i].as_u64().unwrap() as u32),
    };
    let mut cell_lod = vec![0u32; grid.len()];
    for c in cells["cells"].as_array().unwrap() {
        cell_lod[c["cell"].as_u64().unwrap() as usize] = c["shown_lod"].as_u64().unwrap() as u32;
    }
    let texel0 = report["atlas"]["texel_size"].as_f64().unwrap() as f32;
    let texel_l = texel0 / (1u32 << lod) as f32;
    // As the runtime sets it (runtime::scheduler::empty_shown).
    let blend_band = (2.0 * texel0).min(grid.cell_size * 0.25);
    // Every cell coming within the band plus 3 LOD-L texels of the point is at LOD L: then
    // the point is that far from any face shared with a coarser cell, its own cell's or
    // those of the cells its taps lie in (a tap in a neighbouring cell is blended when that
    // cell has a coarser neighbour within the band, diagonal to the point's own cell).
    let reach = blend_band + 3.0 * texel_l;
    let exact_class = |p: Vec3| {
        let lo = grid.coords_of(p - Vec3::splat(reach));
        let hi = grid.coords_of(p + Vec3::splat(reach));
        (lo[2]..=hi[2])
            .all(|z| (lo[1]..=hi[1]).all(|y| (lo[0]..=hi[0]).all(|x| cell_lod[grid.index([x, y, z]) as usize] >= lod)))
    };

    let scene = load(&room);
    let geom = SceneGeometry::new(&scene);
    let bvh = livebake::reference::Bvh::for_scene(&scene, &geom);
    let locator = livebake::probe::SurfaceLocator::new(&geom, &bvh);
    let back = load(&gltf);
    let mut by_corners: HashMap<[[u32; 3]; 3], Vec<(usize, usize)>> = HashMap::new();
    for (mi, m) in back.meshes.iter().enumerate() {
        for t in 0..m.triangles.len() {
            by_corners.entry(corner_key(&m.corners(t))).or_default().push((mi, t));
        }
    }
    let exr = image::open(dir.path().join("web/room.lightmap.exr")).unwrap().to_rgb32f();
    let size = Vec2::new(exr.width() as f32, exr.height() as f32);
    assert_eq!(
        (exr.width(), exr.height()),
        (export["width"].as_u64().unwrap() as u32, export["height"].as_u64().unwrap() as u32)
    );
    let delta = 8.0 * size.max_element() * f32::EPSILON / 2.0;
    let probed = read_json(&dir.path().join("p.json"));
    let (mut exact, mut other, mut worst_exact, mut worst_other, mut unread) = (0, 0, 0.0f32, 0.0f32, 0);
    for q in probed["points"].as_array().unwrap() {
        let (p, n) = (v3(&q["p"]), v3(&q["n"]));
        // Floor points under a box find the box's bottom (the back of a single-sided face).
        let Some(e) = q["E"].as_array() else {
            assert!(q["error"].as_str().is_some_and(|e| e.contains("single-sided")), "{q}");
            unread += 1;
            continue;
        };
        let expected =
            Vec3::new(e[0].as_f64().unwrap() as f32, e[1].as_f64().unwrap() as f32, e[2].as_f64().unwrap() as f32);
        let at = locator.locate(p, n).unwrap();
        let corners = geom.corners[at.tri as usize];
        let normal = geom.normals[at.tri as usize] * at.side.sign();
        let candidates: Vec<&(usize, usize)> = by_corners[&corner_key(&corners)]
            .iter()
            .filter(|&&(m, t)| {
                let [a, b, c] = back.meshes[m].corners(t);
                (b - a).cross(c - a).dot(normal) > 0.0
            })
            .collect();
        assert_eq!(candidates.len(), 1, "point {p}: {} exported triangles", candidates.len());
        let &(m, t) = candidates[0];
        let mesh = &back.meshes[m];
        let exported_corners = mesh.corners(t);
        let uv1 = mesh.uv1.as_ref().unwrap();
        let weights = [1.0 - at.u - at.v, at.u, at.v];
        let uv = (0..3).fold(Vec2::ZERO, |acc, j| {
            let k = corners.iter().position(|c| *c == exported_corners[j]).unwrap();
            acc + uv1[mesh.triangles[t][j] as usize] * weights[k]
        });
        let px = uv * size;
        let got = bilinear(&exr, px);
        let (range, _) = local_range(&exr, px);
        let rounding = 1e-6 * expected.abs().max_element().max(1e-6);
        let surface = geom.point(at.tri, at.u, at.v);
        let is_exact = exact_class(surface);
        let bound = if is_exact { 2.0 * delta * range + rounding } else { 1.125 * range + rounding };
        let err = (got - expected).abs().max_element();
        assert!(
            err <= bound,
            "point {p} ({}): export {got} vs run {expected} (error {err:e} > bound {bound:e}, 4×4 range {range:e})",
            if is_exact { "cell at the export LOD" } else { "coarser or blended" }
        );
        let ratio = err / range.max(1e-12);
        if is_exact {
            exact += 1;
            worst_exact = worst_exact.max(err);
        } else {
            other += 1;
            worst_other = worst_other.max(ratio);
        }
    }
    eprintln!(
        "export LOD {lod} ({}×{}): {exact} points in cells at LOD {lod} (worst error {worst_exact:e} W/m²), {other} elsewhere (worst error {worst_other:.3} of the 4×4 range)",
        exr.width(),
        exr.height()
    );
    // Both kinds of point are compared.
    assert!(exact >= 10 && other >= 100 && unread < 400, "{exact} exact, {other} other, {unread} not read");
}

/// Glass and cut-outs keep what makes them glass and cut-outs: alpha mode, cutoff and
/// `KHR_materials_transmission` (its texture still names the same image) are in the export,
/// and the extension is declared.
#[test]
fn export_keeps_alpha_modes_and_transmission() {
    use support::*;
    let dir = tempfile::tempdir().unwrap();
    let mut d = Doc::new();
    let tex = png(2, 2, |x, y| [128, 0, 0, if (x + y) % 2 == 0 { 255 } else { 0 }]);
    d.push("images", json!({ "name": "glass", "uri": format!("data:image/png;base64,{}", base64(&tex)) }));
    d.push("textures", json!({ "source": 0 }));
    d.push(
        "materials",
        json!({ "name": "pane", "alphaMode": "BLEND",
        "pbrMetallicRoughness": { "baseColorFactor": [0.8, 0.9, 1.0, 0.3] } }),
    );
    d.push(
        "materials",
        json!({ "name": "grille", "alphaMode": "MASK", "alphaCutoff": 0.3,
        "pbrMetallicRoughness": { "baseColorTexture": { "index": 0 } } }),
    );
    d.push("materials", json!({ "name": "glass",
        "extensions": { "KHR_materials_transmission": { "transmissionFactor": 0.9, "transmissionTexture": { "index": 0 } } } }));
    d.json["extensionsUsed"] = json!(["KHR_materials_transmission"]);
    let quad = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
    let mut prims = Vec::new();
    for m in 0..3 {
        let q = quad.map(|[x, y, z]| [x + 1.5 * m as f32, y, z]);
        let mut p = d.prim(&q, Some(&[[0.0, 0.0, 1.0]; 4]), Some(&[0, 1, 2, 0, 2, 3]));
        p["attributes"]["TEXCOORD_0"] = json!(d.vec2(&[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]));
        p["material"] = json!(m);
        prims.push(p);
    }
    d.mesh_node(prims, json!({ "name": "panes" }));
    let src = d.write_gltf(dir.path(), "glass");
    let scene = load(&src);
    let atlas = atlas_for(&scene, 0.05);
    let out = dir.path().join("out/glass.gltf");
    export_gltf(&scene, &atlas, &gradient_map(&atlas, 0), &out, &ExportOptions::default()).unwrap();
    let g = read_json(&out);
    let m = &g["materials"];
    assert_eq!((m[0]["name"].as_str(), m[0]["alphaMode"].as_str()), (Some("pane"), Some("BLEND")));
    assert_eq!(m[0]["pbrMetallicRoughness"]["baseColorFactor"], json!([0.8, 0.9, 1.0, 0.3]));
    assert_eq!((m[1]["alphaMode"].as_str(), m[1]["alphaCutoff"].as_f64()), (Some("MASK"), Some(0.3)));
    let t = &m[2]["extensions"]["KHR_materials_transmission"];
    assert_eq!(t["transmissionFactor"].as_f64(), Some(0.9));
    let texture = &g["textures"][t["transmissionTexture"]["index"].as_u64().unwrap() as usize];
    assert_eq!(g["images"][texture["source"].as_u64().unwrap() as usize]["name"], "glass");
    assert!(g["extensionsUsed"].as_array().unwrap().contains(&json!("KHR_materials_transmission")));
    // Loaded again, the export is the same glass.
    let again = load(&out);
    assert_eq!(again.materials[0].alpha_mode, scene.materials[0].alpha_mode);
    assert_eq!(again.materials[1].alpha_mode, scene.materials[1].alpha_mode);
    assert_eq!(again.materials[2].transmission, 0.9);
    assert!(again.materials[2].transmission_texture.is_some());
}
