//! glTF 2.0 import (`.gltf` with external or `data:` buffers, and `.glb`) with typed errors
//! that name the file and the problem.
//!
//! The `gltf` crate is used only to deserialise and validate the JSON document. Buffers,
//! accessors and images are read by our own bounds-checked code (`buffers`, `accessor`,
//! `images`): every size or offset from the file goes through checked arithmetic, every slice
//! is taken with `get`, and a lie in the file becomes a [`LoadError`], never a panic, a silent
//! truncation or an allocation sized by an unchecked number.
//!
//! # Conventions
//!
//! - **Units**: glTF metres, right-handed, +Y up. Everything in the [`Scene`] is in world space:
//!   node transforms (`matrix`, or `T·R·S`) are applied to positions; normals go through the
//!   inverse transpose and are renormalised. A mirroring transform (negative determinant) flips
//!   the triangle winding, so the front face (counter-clockwise, glTF) stays the front.
//! - **Scene**: [`LoadOptions::scene`], else the file's `scene`, else the first scene, else all
//!   root nodes (nodes nobody lists as a child). Each (node, triangle primitive) instance becomes
//!   one [`Mesh`](crate::scene::Mesh) named `node/mesh/primitive-index`.
//! - **Topology**: TRIANGLES, TRIANGLE_STRIP and TRIANGLE_FAN become triangle lists with glTF's
//!   winding; POINTS and LINES* primitives are skipped and counted. Zero-area triangles are
//!   dropped and counted (threshold in `primitive.rs`). Without NORMAL, glTF means flat shading:
//!   each triangle gets its own vertices with its face normal.
//! - **Materials** (a Lambertian view of metallic-roughness): `base_color` is
//!   `baseColorFactor` (linear) times the base colour texture (sRGB); `emission` is
//!   `emissiveFactor × KHR_materials_emissive_strength`, taken **one-for-one as radiance in
//!   W/(sr·m²)**, times the emissive texture (sRGB). glTF material *i* is scene material *i*;
//!   primitives without a material share glTF's default material (white, single-sided),
//!   appended once after the file's materials.
//! - **Punctual lights** (KHR_lights_punctual): the glTF numbers are taken one-for-one in
//!   radiometric units, no 683 lm/W conversion: a directional light's `intensity` is the
//!   irradiance in **W/m²** on a surface facing it; a point or spot light's `intensity` is its
//!   radiant intensity in **W/sr** (on the axis, for spots). `color × intensity` gives
//!   [`PunctualLight::intensity`](crate::scene::PunctualLight::intensity) per channel. Position
//!   is the node's world origin; direction is the node's −Z through the world transform; `range`
//!   is kept for point and spot lights; spot cones default to 0 and π/4.
//! - **Cameras**: position and rotation from the node's world transform with scale dropped.
//! - **Warnings**: what was skipped or repaired is logged with `tracing::warn!` once per kind,
//!   with a count and examples, and kept in [`LoadStats::warnings`](crate::scene::LoadStats).
//!
//! Supported required extensions: `KHR_lights_punctual`, `KHR_materials_emissive_strength`,
//! `KHR_mesh_quantization` (integer and normalised vertex attributes). Anything else in
//! `extensionsRequired` (Draco, meshopt, BasisU...) is [`LoadError::Unsupported`].

mod accessor;
mod buffers;
mod diag;
mod document;
mod error;
mod files;
mod images;
mod lights;
mod materials;
mod nodes;
mod origin;
mod primitive;
mod references;
mod source;
mod uri;

use std::path::{Path, PathBuf};

use ::gltf::json;
use glam::{DMat4, DVec3, Mat4};

pub use error::LoadError;
pub use references::{ExternalFile, ExternalKind, external_files};
pub use source::{SourceDocument, SourceImage, read_source};

pub(crate) use files::{FileError, FileScope, read_regular};
pub(crate) use images::{DecodeError, decode_bounded, most_encoded_bytes};

use super::{Material, MaterialId, Scene};
use buffers::Buffers;
use diag::{Diagnostics, Kind};
use primitive::Built;

/// Options for [`load_gltf`].
#[derive(Clone, Debug)]
pub struct LoadOptions {
    /// Load this scene (index into the file's `scenes`) instead of the default one.
    pub scene: Option<usize>,
    /// Read buffer and image files outside the scene's folder: URIs with `..` leading out,
    /// absolute paths, symbolic links whose target is outside. Off: such a URI is refused.
    pub allow_outside_files: bool,
    /// Most pixels one texture may have: its header's width × height, checked before it is
    /// decoded ([`DEFAULT_MAX_TEXTURE_PIXELS`]).
    pub max_texture_pixels: u64,
    /// Most bytes the scene's decoded textures may hold together, the decode of the next
    /// one included (`None`: no limit besides `max_texture_pixels`).
    pub texture_memory_limit: Option<u64>,
    /// Place the scene's frame at this origin (file coordinates) rather than choosing one
    /// ([`Scene::origin`]): a reload keeps the frame the runtime's world was made in.
    pub origin: Option<DVec3>,
}

/// A texture of 4096 × 4096 pixels (64 MiB decoded) is the largest a glTF asset commonly
/// ships; light maps sample albedo at their texels (centimetres), far coarser than any
/// texture this size, so a larger one would only cost memory. A decompression bomb (a few
/// kB of PNG declaring 16384² pixels) is refused from its header.
pub const DEFAULT_MAX_TEXTURE_PIXELS: u64 = 4096 * 4096;

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions {
            scene: None,
            allow_outside_files: false,
            max_texture_pixels: DEFAULT_MAX_TEXTURE_PIXELS,
            texture_memory_limit: None,
            origin: None,
        }
    }
}

/// What every part of the loader needs: the file (for messages), the document, the buffers,
/// where files may be read and the options.
struct Ctx<'a> {
    file: &'a Path,
    root: &'a json::Root,
    buffers: Buffers<'a>,
    scope: FileScope,
    options: &'a LoadOptions,
}

impl Ctx<'_> {
    fn invalid(&self, message: String) -> LoadError {
        LoadError::Invalid { file: self.file.to_path_buf(), message }
    }
}

/// Loads a `.gltf` or `.glb` file into a world-space [`Scene`]. See the module documentation
/// for the conventions and [`LoadError`] for what can fail.
pub fn load_gltf(path: &Path, options: &LoadOptions) -> Result<Scene, LoadError> {
    let bytes = read_scene_file(path)?;
    load_gltf_bytes(path, &bytes, options)
}

/// The bytes of the scene file at `path`, which must be a regular file (a FIFO or a device
/// is refused without blocking or reading).
pub fn read_scene_file(path: &Path) -> Result<Vec<u8>, LoadError> {
    files::read_regular(path, None, 0, u64::MAX, None).map_err(|e| match e {
        files::FileError::Io(source) => LoadError::Io { file: path.to_path_buf(), source },
        e => LoadError::NotGltf { file: path.to_path_buf(), reason: format!("the file {e}") },
    })
}

/// Where the files of the scene `path` may be, under `options`.
fn file_scope(path: &Path, options: &LoadOptions) -> FileScope {
    FileScope::new(path.parent().unwrap_or(Path::new(".")), options.allow_outside_files)
}

/// Like [`load_gltf`] with the file's bytes already in memory; `path` names the file in
/// messages and is the base for relative URIs.
pub fn load_gltf_bytes(path: &Path, bytes: &[u8], options: &LoadOptions) -> Result<Scene, LoadError> {
    let start = std::time::Instant::now();
    let parsed = document::parse(path, bytes)?;
    let scope = file_scope(path, options);
    let buffers = buffers::load(path, &parsed.root, parsed.bin, &scope)?;
    let ctx = Ctx { file: path, root: &parsed.root, buffers, scope, options };
    let mut diag = Diagnostics::default();
    diag.note(Kind::UnsupportedExtensionUsed, parsed.ignored_extensions.len(), || parsed.ignored_extensions.join(", "));

    let mut scene = Scene { source: Some(PathBuf::from(path)), ..Scene::default() };
    let roots = nodes::scene_roots(&ctx, options)?;
    let mut instances = nodes::traverse(&ctx, &roots, &mut diag)?;
    scene.stats.nodes = instances.len();
    scene.origin = match options.origin {
        Some(o) if o.is_finite() => o,
        _ => origin::scene_origin(&ctx, &instances)?,
    };
    if scene.origin != DVec3::ZERO {
        for inst in &mut instances {
            inst.world = origin::relative(inst.world64, scene.origin);
        }
        tracing::info!(
            "{}: the scene lies far from the file's origin: loaded relative to ({}, {}, {}) m (points and camera paths are read, and positions written, in the file's coordinates)",
            path.display(),
            scene.origin.x,
            scene.origin.y,
            scene.origin.z
        );
    }

    // Geometry first (cheap, and what most errors are about); images are decoded only for a
    // scene that has something to light.
    let mut uses_default_material = false;
    let mut triangles = 0u64;
    for inst in &instances {
        load_node_meshes(&ctx, &mut diag, &mut scene, &mut uses_default_material, &mut triangles, inst)?;
        if let Some(light) = lights::light_of(&ctx, &mut diag, inst)? {
            scene.lights.push(light);
        }
        if let Some(camera) = lights::camera_of(&ctx, &mut diag, inst)? {
            scene.cameras.push(camera);
        }
    }
    if scene.meshes.is_empty() {
        return Err(no_triangles(path, &scene, &diag, &instances));
    }
    let ceiling = scene.light_ceiling();
    lights::check_brightness(&ctx, &scene.lights, &ceiling)?;
    let mut textures = images::TextureCache::default();
    scene.materials = materials::convert_all(&ctx, &mut textures, &mut diag, &ceiling)?;
    if uses_default_material {
        scene.materials.push(Material::default());
    }
    scene.textures = textures.textures;
    finish_stats(&mut scene, &diag);
    scene.stats.warnings = diag.finish();
    for w in &scene.stats.warnings {
        tracing::warn!("{}: {w}", path.display());
    }
    tracing::info!(
        "{}: {} meshes, {} triangles, {} materials, {} textures, {} lights in {:.0} ms{}",
        path.display(),
        scene.meshes.len(),
        scene.stats.triangles,
        scene.materials.len(),
        scene.textures.len(),
        scene.lights.len(),
        start.elapsed().as_secs_f64() * 1e3,
        if parsed.is_glb { " (GLB)" } else { "" },
    );
    Ok(scene)
}

/// Most triangles a scene may hold once every mesh instance is made (nodes sharing a mesh,
/// `EXT_mesh_gpu_instancing`): a few hundred bytes each through loading, atlas and bake, so
/// far past what one machine bakes; a small file cannot ask for more.
pub const MAX_SCENE_TRIANGLES: u64 = 1 << 26;

/// Every primitive of the mesh on node `inst` (if any) becomes a world-space mesh, once per
/// instance of the node (`EXT_mesh_gpu_instancing`: the node's transform times the
/// instance's). `triangles` counts the scene's triangles so far, against
/// [`MAX_SCENE_TRIANGLES`], before any is made.
fn load_node_meshes(
    ctx: &Ctx,
    diag: &mut Diagnostics,
    scene: &mut Scene,
    uses_default_material: &mut bool,
    triangles: &mut u64,
    inst: &nodes::NodeInstance,
) -> Result<(), LoadError> {
    let Some(node) = ctx.root.nodes.get(inst.node) else { return Ok(()) };
    let Some(mesh_index) = node.mesh.map(|m| m.value()) else { return Ok(()) };
    let mesh = ctx
        .root
        .meshes
        .get(mesh_index)
        .ok_or_else(|| ctx.invalid(format!("node {}: mesh {mesh_index} does not exist", inst.node)))?;
    let node_name = nodes::node_name(ctx, inst.node);
    if node.skin.is_some() {
        diag.note(Kind::IgnoredSkin, 1, || node_name.clone());
    }
    let mesh_name = mesh.name.clone().unwrap_or_else(|| format!("mesh{mesh_index}"));
    // Each place in the scene's frame, and in f64 when the scene has an origin of its own.
    let origin = scene.origin;
    let place = |world64: DMat4, world: Mat4| match origin == DVec3::ZERO {
        true => (world, None),
        false => {
            let local = origin::relative64(world64, origin);
            (local.as_mat4(), Some(local))
        }
    };
    let places: Vec<(Mat4, Option<DMat4>, String)> = match nodes::instance_transforms(ctx, inst.node)? {
        None => {
            let (world, world64) = place(inst.world64, inst.world);
            vec![(world, world64, node_name.clone())]
        }
        Some(transforms) => transforms
            .iter()
            .enumerate()
            .map(|(i, t)| {
                let (world, world64) = place(inst.world64 * t.as_dmat4(), inst.world * *t);
                (world, world64, format!("{node_name}#{i}"))
            })
            .collect(),
    };
    let mut per_place = 0u64;
    for prim in &mesh.primitives {
        per_place = per_place.saturating_add(primitive::triangle_bound(ctx, prim)?);
    }
    *triangles = triangles.saturating_add(per_place.saturating_mul(places.len() as u64));
    if *triangles > MAX_SCENE_TRIANGLES {
        return Err(LoadError::Unsupported {
            file: ctx.file.into(),
            what: format!(
                "node {} takes the scene past {MAX_SCENE_TRIANGLES} triangles once its mesh instances are made ({} of its mesh at up to {per_place} triangles each); livebake loads at most that many",
                node_name,
                places.len()
            ),
        });
    }
    for (world, world64, place_name) in &places {
        if !world.is_finite() {
            return Err(ctx.invalid(format!("{place_name}: its world transform overflows to non-finite values")));
        }
        for (p, prim) in mesh.primitives.iter().enumerate() {
            let material = match prim.material.map(|m| m.value()) {
                Some(m) if m < ctx.root.materials.len() => m as MaterialId,
                Some(m) => {
                    return Err(ctx.invalid(format!("mesh {mesh_index} primitive {p}: material {m} does not exist")));
                }
                // glTF's default material goes right after the file's materials.
                None => {
                    *uses_default_material = true;
                    ctx.root.materials.len() as MaterialId
                }
            };
            let name = format!("{place_name}/{mesh_name}/{p}");
            let instance =
                primitive::Instance { prim, node: inst.node, world: *world, world64: *world64, name, material };
            match primitive::build(ctx, diag, &instance)? {
                Built::Mesh(m) => scene.meshes.push(m),
                Built::GeneratedNormals(m) => {
                    scene.stats.normals_generated += 1;
                    scene.meshes.push(m);
                }
                Built::NotTriangles => scene.stats.non_triangle_primitives_skipped += 1,
                Built::Empty => {}
            }
        }
    }
    Ok(())
}

fn finish_stats(scene: &mut Scene, diag: &Diagnostics) {
    let s = &mut scene.stats;
    s.primitives = scene.meshes.len();
    s.triangles = scene.meshes.iter().map(|m| m.triangles.len()).sum();
    s.degenerate_triangles_dropped = diag.count(Kind::DegenerateTriangles);
    s.normals_replaced = diag.count(Kind::BadNormals);
    s.textures = scene.textures.len();
    s.lights = scene.lights.len();
    s.cameras = scene.cameras.len();
}

fn no_triangles(path: &Path, scene: &Scene, diag: &Diagnostics, instances: &[nodes::NodeInstance]) -> LoadError {
    let detail = if instances.is_empty() {
        "the scene has no nodes".to_string()
    } else {
        format!(
            "{} node(s) visited; {} point/line primitive(s) skipped, {} degenerate triangle(s) dropped",
            instances.len(),
            scene.stats.non_triangle_primitives_skipped,
            diag.count(Kind::DegenerateTriangles)
        )
    };
    LoadError::NoTriangles { file: path.to_path_buf(), detail }
}
