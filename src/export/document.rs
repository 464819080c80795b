//! The exported glTF document: the source file's materials, textures, samplers, images,
//! cameras and lights, new world-space geometry per mesh instance, the light map as a texture
//! referenced by every material through `MOZ_lightmap`, and one binary buffer.

use std::collections::{BTreeMap, BTreeSet};

use glam::{Vec2, Vec3, Vec4};
use serde_json::{Map, Value, json};

use super::geometry::{SidePrimitive, build_side};
use crate::atlas::Atlas;
use crate::scene::{Scene, Side, SourceDocument, TriangleId};

/// glTF constants.
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const LINEAR: u32 = 9729;
const CLAMP_TO_EDGE: u32 = 33071;

/// What the document refers to by URI, and what went into it.
pub(super) struct Names<'a> {
    pub bin_uri: &'a str,
    pub png_uri: &'a str,
    pub exr_uri: &'a str,
}

/// Light-map facts recorded in the document.
pub(super) struct LightmapInfo {
    pub lod: u32,
    pub width: u32,
    pub height: u32,
    pub texel_size: f32,
    pub png_intensity: f32,
}

pub(super) struct Built {
    pub json: Value,
    pub bin: Vec<u8>,
    pub primitives: usize,
    pub warnings: Vec<String>,
}

/// The binary buffer and the bufferViews and accessors into it.
#[derive(Default)]
struct Bin {
    bytes: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl Bin {
    /// A bufferView over `data`, 4-byte aligned (every component type we write is ≤ 4 bytes).
    fn view(&mut self, data: &[u8], target: Option<u32>) -> usize {
        self.bytes.resize(self.bytes.len().next_multiple_of(4), 0);
        let mut v = json!({ "buffer": 0, "byteOffset": self.bytes.len(), "byteLength": data.len() });
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        self.bytes.extend_from_slice(data);
        self.views.push(v);
        self.views.len() - 1
    }

    fn accessor(&mut self, data: &[u8], target: u32, accessor: Value) -> usize {
        let mut a = accessor;
        a["bufferView"] = json!(self.view(data, Some(target)));
        self.accessors.push(a);
        self.accessors.len() - 1
    }

    /// VEC3 float; `bounds` adds the `min`/`max` glTF requires on POSITION.
    fn vec3(&mut self, data: &[Vec3], bounds: bool) -> usize {
        let bytes: Vec<u8> = data.iter().flat_map(|v| v.to_array()).flat_map(f32::to_le_bytes).collect();
        let mut a = json!({ "componentType": FLOAT, "type": "VEC3", "count": data.len() });
        if bounds {
            let lo = data.iter().fold(Vec3::splat(f32::INFINITY), |a, &b| a.min(b));
            let hi = data.iter().fold(Vec3::splat(f32::NEG_INFINITY), |a, &b| a.max(b));
            a["min"] = json!(lo.to_array());
            a["max"] = json!(hi.to_array());
        }
        self.accessor(&bytes, ARRAY_BUFFER, a)
    }

    fn vec2(&mut self, data: &[Vec2]) -> usize {
        let bytes: Vec<u8> = data.iter().flat_map(|v| v.to_array()).flat_map(f32::to_le_bytes).collect();
        self.accessor(&bytes, ARRAY_BUFFER, json!({ "componentType": FLOAT, "type": "VEC2", "count": data.len() }))
    }

    fn vec4(&mut self, data: &[Vec4]) -> usize {
        let bytes: Vec<u8> = data.iter().flat_map(|v| v.to_array()).flat_map(f32::to_le_bytes).collect();
        self.accessor(&bytes, ARRAY_BUFFER, json!({ "componentType": FLOAT, "type": "VEC4", "count": data.len() }))
    }

    fn indices(&mut self, triangles: &[[u32; 3]]) -> usize {
        let bytes: Vec<u8> = triangles.iter().flatten().flat_map(|i| i.to_le_bytes()).collect();
        let a = json!({ "componentType": UNSIGNED_INT, "type": "SCALAR", "count": triangles.len() * 3 });
        self.accessor(&bytes, ELEMENT_ARRAY_BUFFER, a)
    }

    /// An image's bytes as a bufferView (no target: not vertex data).
    fn image(&mut self, data: &[u8]) -> usize {
        self.view(data, None)
    }
}

/// Rewrites a material that uses KHR_materials_pbrSpecularGlossiness as metallic-roughness,
/// the model engines read today (the extension is archived, and engines such as three.js no
/// longer read it; beside the light map's extension the validator warns about it): its
/// diffuse factor and texture, the albedo the bake used, become the base colour; metallic 0,
/// roughness 1 − glossiness. Returns whether it did.
fn as_metallic_roughness(material: &mut Value) -> bool {
    let extensions = material.get_mut("extensions").and_then(Value::as_object_mut);
    let Some(sg) = extensions.and_then(|e| e.remove("KHR_materials_pbrSpecularGlossiness")) else {
        return false;
    };
    let glossiness = sg.get("glossinessFactor").and_then(Value::as_f64).unwrap_or(1.0);
    let mut pbr = json!({ "metallicFactor": 0.0, "roughnessFactor": (1.0 - glossiness).clamp(0.0, 1.0) });
    if let Some(f) = sg.get("diffuseFactor") {
        pbr["baseColorFactor"] = f.clone();
    }
    if let Some(t) = sg.get("diffuseTexture") {
        pbr["baseColorTexture"] = t.clone();
    }
    material["pbrMetallicRoughness"] = pbr;
    true
}

/// Texture references of a material copy, remapped to the sets the export writes:
/// TEXCOORD_0 stays, the file's TEXCOORD_1 moves to TEXCOORD_2 (TEXCOORD_1 is the light map's
/// now), and higher sets (which the loader does not read, so the export cannot write) are
/// dropped with a warning.
#[derive(Default)]
struct TexCoordUse {
    reads_uv1: bool,
    dropped: Vec<String>,
}

/// Walks a material's JSON; every object with an integer `index` is a textureInfo there (its
/// `texCoord`, and the one of `KHR_texture_transform`, which overrides it, are remapped).
/// Returns whether `value` itself is to be removed.
fn remap_tex_coords(value: &mut Value, path: &str, usage: &mut TexCoordUse) -> bool {
    match value {
        Value::Object(obj) => {
            if obj.get("index").is_some_and(Value::is_u64) {
                let base = obj.get_mut("texCoord");
                let keep = remap_set(base, path, usage);
                let transform = obj
                    .get_mut("extensions")
                    .and_then(|e| e.get_mut("KHR_texture_transform"))
                    .and_then(|t| t.get_mut("texCoord"));
                return !(keep && remap_set(transform, path, usage));
            }
            // `extras` is the application's own data, not texture references.
            let keys: Vec<String> = obj.keys().filter(|k| *k != "extras").cloned().collect();
            for k in keys {
                let remove =
                    obj.get_mut(&k).is_some_and(|child| remap_tex_coords(child, &format!("{path}.{k}"), usage));
                if remove {
                    obj.remove(&k);
                }
            }
            false
        }
        Value::Array(items) => {
            for (i, item) in items.iter_mut().enumerate() {
                remap_tex_coords(item, &format!("{path}[{i}]"), usage);
            }
            false
        }
        _ => false,
    }
}

/// One `texCoord` value: 0 stays, 1 becomes 2; false (drop the reference) for higher sets.
fn remap_set(set: Option<&mut Value>, path: &str, usage: &mut TexCoordUse) -> bool {
    let Some(v) = set else { return true };
    match v.as_u64() {
        Some(0) | None => true,
        Some(1) => {
            usage.reads_uv1 = true;
            *v = json!(2);
            true
        }
        Some(n) => {
            usage.dropped.push(format!("{path} (TEXCOORD_{n})"));
            false
        }
    }
}

/// Names of every extension used anywhere inside `value` (keys of `extensions` objects).
fn collect_extensions(value: &Value, out: &mut BTreeSet<String>) {
    match value {
        Value::Object(obj) => {
            if let Some(Value::Object(ext)) = obj.get("extensions") {
                out.extend(ext.keys().cloned());
            }
            obj.values().for_each(|v| collect_extensions(v, out));
        }
        Value::Array(items) => items.iter().for_each(|v| collect_extensions(v, out)),
        _ => {}
    }
}

fn array<'a>(json: &'a Value, key: &str) -> &'a [Value] {
    json.get(key).and_then(Value::as_array).map_or(&[], Vec::as_slice)
}

/// Whether node JSON carries a camera or a punctual light.
fn has_camera_or_light(node: &Value) -> bool {
    node.get("camera").is_some() || node.pointer("/extensions/KHR_lights_punctual/light").is_some()
}

/// Counts `what` under `kind` for one warning line per kind.
fn tally(t: &mut BTreeMap<String, usize>, what: impl Into<String>) {
    *t.entry(what.into()).or_default() += 1;
}

pub(super) fn build(
    scene: &Scene,
    atlas: &Atlas,
    source: &SourceDocument,
    names: &Names,
    info: &LightmapInfo,
) -> Built {
    let src = &source.json;
    let mut warnings = Vec::new();
    let mut bin = Bin::default();

    // Materials: the file's, then glTF's default material if the loader appended it. Each is
    // made single-sided (a double-sided surface becomes two primitives, see below) and gets
    // the light map.
    let file_materials = array(src, "materials");
    let images = array(src, "images");
    let lightmap_texture = array(src, "textures").len();
    let mut materials = Vec::with_capacity(scene.materials.len());
    let mut reads_uv1 = Vec::with_capacity(scene.materials.len());
    let mut spec_gloss = Vec::new();
    for (m, material) in scene.materials.iter().enumerate() {
        // (The loader's glTF parser has made sure every material and node is a JSON object.)
        let mut value = match file_materials.get(m) {
            Some(v @ Value::Object(_)) => v.clone(),
            _ => json!({ "name": material.name }),
        };
        if as_metallic_roughness(&mut value) {
            spec_gloss.push(material.name.clone());
        }
        let mut usage = TexCoordUse::default();
        remap_tex_coords(&mut value, &format!("materials[{m}]"), &mut usage);
        if !usage.dropped.is_empty() {
            warnings.push(format!(
                "texture references dropped (livebake does not carry texture coordinate sets above TEXCOORD_1): {}",
                usage.dropped.join(", ")
            ));
        }
        reads_uv1.push(usage.reads_uv1);
        if let Value::Object(obj) = &mut value {
            obj.remove("doubleSided");
            let ext = obj.entry("extensions").or_insert_with(|| json!({}));
            if !ext.is_object() {
                *ext = json!({});
            }
            ext["MOZ_lightmap"] = json!({ "index": lightmap_texture, "texCoord": 1, "intensity": info.png_intensity });
        }
        materials.push(value);
    }
    if !spec_gloss.is_empty() {
        warnings.push(format!(
            "specular-glossiness materials written as metallic-roughness (their diffuse colour, the albedo \
             livebake baked with, as the base colour; specular colour and glossiness textures dropped): {}",
            spec_gloss.join(", ")
        ));
    }

    // Geometry: one glTF mesh per instancing node, one primitive per side of each of its
    // primitives, at the node's place in world space.
    let file_nodes = array(src, "nodes");
    let file_meshes = array(src, "meshes");
    let mut meshes: Vec<Value> = Vec::new();
    let mut geometry_nodes: Vec<Value> = Vec::new();
    let mut primitive_count = 0;
    let mut first_tri: TriangleId = 0;
    // The loader emits the primitives of one node consecutively.
    for instance in scene.meshes.chunk_by(|a, b| a.node.is_some() && a.node == b.node) {
        let mut primitives = Vec::new();
        for mesh in instance {
            let keep_uv1 = reads_uv1[mesh.material as usize];
            for side in Side::BOTH {
                if let Some(prim) = build_side(mesh, first_tri, atlas, side, keep_uv1) {
                    primitives.push(write_primitive(&mut bin, &prim, mesh.material));
                }
            }
            first_tri += mesh.triangles.len() as TriangleId;
        }
        if primitives.is_empty() {
            continue;
        }
        primitive_count += primitives.len();
        let node_json = instance[0].node.and_then(|n| file_nodes.get(n));
        let mut mesh = json!({ "primitives": primitives });
        let file_mesh =
            node_json.and_then(|n| n.get("mesh")).and_then(Value::as_u64).and_then(|m| file_meshes.get(m as usize));
        if let Some(name) = file_mesh.and_then(|m| m.get("name")) {
            mesh["name"] = name.clone();
        }
        meshes.push(mesh);
        let mut node = json!({ "mesh": meshes.len() - 1 });
        // Positions are in the scene's frame: its origin puts them back where the file has
        // them (beside the file's cameras and lights, kept below as they are).
        if scene.origin != glam::DVec3::ZERO {
            node["translation"] = json!(scene.origin.to_array());
        }
        for key in ["name", "extras"] {
            if let Some(v) = node_json.and_then(|j| j.get(key)) {
                node[key] = v.clone();
            }
        }
        geometry_nodes.push(node);
    }

    // The node hierarchy of the loaded scene, without meshes (the geometry is above, in world
    // space), kept where it carries cameras or lights.
    let mut keep = vec![false; file_nodes.len()];
    for &n in source.nodes.iter().rev() {
        let Some(node) = file_nodes.get(n) else { continue };
        let children = array(node, "children").iter().filter_map(Value::as_u64);
        let any_child = children.into_iter().any(|c| keep.get(c as usize).copied().unwrap_or(false));
        keep[n] = has_camera_or_light(node) || any_child;
    }
    let mut new_index = vec![usize::MAX; file_nodes.len()];
    for (i, &n) in source.nodes.iter().filter(|&&n| keep[n]).enumerate() {
        new_index[n] = i;
    }
    let mut nodes: Vec<Value> = Vec::new();
    for &n in source.nodes.iter().filter(|&&n| keep[n]) {
        let mut obj = file_nodes[n].as_object().cloned().unwrap_or_default();
        for key in ["mesh", "skin", "weights"] {
            obj.remove(key);
        }
        // Its mesh's instances are geometry above, in world space, like the mesh.
        if let Some(Value::Object(ext)) = obj.get_mut("extensions") {
            ext.remove("EXT_mesh_gpu_instancing");
            if ext.is_empty() {
                obj.remove("extensions");
            }
        }
        let children: Vec<usize> = array(&file_nodes[n], "children")
            .iter()
            .filter_map(Value::as_u64)
            .filter_map(|c| new_index.get(c as usize).copied())
            .filter(|&c| c != usize::MAX)
            .collect();
        if children.is_empty() {
            obj.remove("children");
        } else {
            obj.insert("children".into(), json!(children));
        }
        nodes.push(Value::Object(obj));
    }
    let hierarchy_roots: Vec<usize> =
        source.roots.iter().filter(|&&r| keep.get(r).copied().unwrap_or(false)).map(|&r| new_index[r]).collect();
    let first_geometry_node = nodes.len();
    let scene_nodes: Vec<usize> =
        hierarchy_roots.into_iter().chain(first_geometry_node..first_geometry_node + geometry_nodes.len()).collect();
    nodes.extend(geometry_nodes);

    // Images: embedded in the buffer, so every reference resolves wherever the export is
    // copied; then the light map's PNG, by URI (the file an engine or a person swaps for the
    // EXR).
    let mut out_images = Vec::with_capacity(images.len() + 1);
    for (i, image) in images.iter().enumerate() {
        let mut value = image.clone();
        if let Some(obj) = value.as_object_mut() {
            obj.remove("uri");
            obj.insert("bufferView".into(), json!(bin.image(&source.images[i].bytes)));
            obj.insert("mimeType".into(), json!(source.images[i].mime_type));
        }
        out_images.push(value);
    }
    out_images.push(json!({ "name": "livebake light map", "uri": names.png_uri, "mimeType": "image/png" }));
    let mut samplers = array(src, "samplers").to_vec();
    samplers.push(json!({ "magFilter": LINEAR, "minFilter": LINEAR, "wrapS": CLAMP_TO_EDGE, "wrapT": CLAMP_TO_EDGE }));
    let mut textures = array(src, "textures").to_vec();
    textures
        .push(json!({ "name": "livebake light map", "sampler": samplers.len() - 1, "source": out_images.len() - 1 }));

    let mut root = Map::new();
    let mut asset = src.get("asset").cloned().unwrap_or_else(|| json!({ "version": "2.0" }));
    asset["generator"] = json!(format!("livebake {} glTF export", env!("CARGO_PKG_VERSION")));
    if !asset.get("extras").is_some_and(Value::is_object) {
        asset["extras"] = json!({});
    }
    asset["extras"]["livebake"] = json!({
        "lightmap": {
            "holds": "irradiance E in W/m², linear RGB; outgoing radiance = emission + baseColor/π · E",
            "hdr": names.exr_uri,
            "png": names.png_uri,
            "png_encoding": "sRGB-encoded E / png_intensity (decode sRGB, multiply by png_intensity)",
            "png_intensity": info.png_intensity,
            "lod": info.lod,
            "width": info.width,
            "height": info.height,
            "texel_size_m": info.texel_size / (1u64 << info.lod) as f32,
            "uv_set": "TEXCOORD_1 over the whole map, no uv_rect"
        }
    });
    root.insert("asset".into(), asset);
    let mut scene_json = json!({ "nodes": scene_nodes });
    if let Some(name) = source.scene.and_then(|s| array(src, "scenes").get(s)).and_then(|s| s.get("name")) {
        scene_json["name"] = name.clone();
    }
    root.insert("scene".into(), json!(0));
    root.insert("scenes".into(), json!([scene_json]));
    root.insert("nodes".into(), json!(nodes));
    root.insert("meshes".into(), json!(meshes));
    root.insert("materials".into(), json!(materials));
    root.insert("textures".into(), json!(textures));
    root.insert("samplers".into(), json!(samplers));
    root.insert("images".into(), json!(out_images));
    if let Some(cameras) = src.get("cameras").filter(|c| c.as_array().is_some_and(|a| !a.is_empty())) {
        root.insert("cameras".into(), cameras.clone());
    }
    if let Some(lights) = src.pointer("/extensions/KHR_lights_punctual") {
        root.insert("extensions".into(), json!({ "KHR_lights_punctual": lights }));
    }
    root.insert("accessors".into(), json!(std::mem::take(&mut bin.accessors)));
    root.insert("bufferViews".into(), json!(std::mem::take(&mut bin.views)));
    root.insert("buffers".into(), json!([{ "uri": names.bin_uri, "byteLength": bin.bytes.len() }]));

    let mut used = BTreeSet::new();
    collect_extensions(&Value::Object(root.clone()), &mut used);
    let required: Vec<String> = array(src, "extensionsRequired")
        .iter()
        .filter_map(Value::as_str)
        .filter(|e| used.contains(*e) && *e != "KHR_mesh_quantization")
        .map(str::to_string)
        .collect();
    root.insert("extensionsUsed".into(), json!(used));
    if !required.is_empty() {
        root.insert("extensionsRequired".into(), json!(required));
    }

    warnings.extend(dropped_content(src, source));
    Built { json: Value::Object(root), bin: bin.bytes, primitives: primitive_count, warnings }
}

fn write_primitive(bin: &mut Bin, prim: &SidePrimitive, material: u32) -> Value {
    let mut attributes = Map::new();
    attributes.insert("POSITION".into(), json!(bin.vec3(&prim.positions, true)));
    attributes.insert("NORMAL".into(), json!(bin.vec3(&prim.normals, false)));
    attributes.insert("TEXCOORD_0".into(), json!(bin.vec2(&prim.uv0)));
    attributes.insert("TEXCOORD_1".into(), json!(bin.vec2(&prim.lightmap_uv)));
    if let Some(uv1) = &prim.original_uv1 {
        attributes.insert("TEXCOORD_2".into(), json!(bin.vec2(uv1)));
    }
    if let Some(colors) = &prim.colors {
        attributes.insert("COLOR_0".into(), json!(bin.vec4(colors)));
    }
    json!({ "attributes": attributes, "indices": bin.indices(&prim.triangles), "material": material })
}

/// What the export does not carry over from the source, one line per kind.
fn dropped_content(src: &Value, source: &SourceDocument) -> Vec<String> {
    let mut lines = Vec::new();
    let nodes = array(src, "nodes");
    let meshes = array(src, "meshes");
    let mut attributes: BTreeMap<String, usize> = BTreeMap::new();
    let mut morphs = 0;
    for &n in &source.nodes {
        let Some(mesh) = nodes.get(n).and_then(|n| n.get("mesh")).and_then(Value::as_u64) else { continue };
        for prim in meshes.get(mesh as usize).map_or(&[][..], |m| array(m, "primitives")) {
            if let Some(attrs) = prim.get("attributes").and_then(Value::as_object) {
                for name in attrs.keys() {
                    // COLOR_0 is carried (or, white everywhere, left out as changing nothing).
                    if !matches!(name.as_str(), "POSITION" | "NORMAL" | "TEXCOORD_0" | "TEXCOORD_1" | "COLOR_0") {
                        tally(&mut attributes, name.clone());
                    }
                }
            }
            morphs += usize::from(prim.get("targets").is_some_and(|t| t.as_array().is_some_and(|a| !a.is_empty())));
        }
    }
    if !attributes.is_empty() {
        let list: Vec<String> = attributes.iter().map(|(a, n)| format!("{a} ({n} primitive instances)")).collect();
        lines.push(format!(
            "vertex attributes not carried over (the loader does not read them; engines generate missing tangents): {}",
            list.join(", ")
        ));
    }
    if morphs > 0 {
        lines.push(format!("{morphs} primitive instance(s) with morph targets exported in their rest pose"));
    }
    for (key, what) in [("animations", "animation(s)"), ("skins", "skin(s)")] {
        let count = array(src, key).len();
        if count > 0 {
            lines.push(format!("{count} {what} dropped: the light map is baked for the static rest pose"));
        }
    }
    let scenes = array(src, "scenes").len();
    if scenes > 1 {
        lines.push(format!("only the loaded scene is exported ({} other scene(s) dropped)", scenes - 1));
    }
    lines
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tex_coord_one_moves_to_two_and_higher_sets_are_dropped() {
        let mut m = json!({
            "pbrMetallicRoughness": { "baseColorTexture": { "index": 0 }, "metallicRoughnessTexture": { "index": 1, "texCoord": 1 } },
            "occlusionTexture": { "index": 2, "texCoord": 3 },
            "extras": { "note": { "index": 7, "texCoord": 9 } },
            "emissiveTexture": { "index": 3, "extensions": { "KHR_texture_transform": { "texCoord": 1, "scale": [2, 2] } } }
        });
        let mut usage = TexCoordUse::default();
        remap_tex_coords(&mut m, "materials[0]", &mut usage);
        assert!(usage.reads_uv1);
        assert_eq!(usage.dropped, vec!["materials[0].occlusionTexture (TEXCOORD_3)".to_string()]);
        assert!(m.get("occlusionTexture").is_none());
        assert_eq!(m.pointer("/extras/note"), Some(&json!({ "index": 7, "texCoord": 9 })));
        assert_eq!(m.pointer("/pbrMetallicRoughness/baseColorTexture"), Some(&json!({ "index": 0 })));
        assert_eq!(m.pointer("/pbrMetallicRoughness/metallicRoughnessTexture/texCoord"), Some(&json!(2)));
        assert_eq!(m.pointer("/emissiveTexture/extensions/KHR_texture_transform/texCoord"), Some(&json!(2)));
        assert_eq!(m.pointer("/emissiveTexture/texCoord"), None);
    }

    #[test]
    fn extensions_are_collected_at_any_depth() {
        let v = json!({ "materials": [{ "extensions": { "KHR_materials_emissive_strength": {} },
            "normalTexture": { "index": 0, "extensions": { "KHR_texture_transform": {} } } }],
            "extensions": { "KHR_lights_punctual": { "lights": [] } } });
        let mut out = BTreeSet::new();
        collect_extensions(&v, &mut out);
        let names: Vec<&str> = out.iter().map(String::as_str).collect();
        assert_eq!(names, ["KHR_lights_punctual", "KHR_materials_emissive_strength", "KHR_texture_transform"]);
    }
}
