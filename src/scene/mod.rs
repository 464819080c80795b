//! The CPU scene: world-space triangle meshes, materials, punctual lights, cameras, and the
//! sky, environment and sun around it.
//!
//! Everything here is plain data in world space (metres). Loading from glTF lives in
//! [`gltf`]; programmatic construction (tests, analytic scenes) in [`builder`].
//! No GPU types: the GPU mirror of a scene is built from this elsewhere.

pub mod builder;
pub mod daylight;
pub mod environment;
pub mod geometry;
pub mod gltf;
pub mod radiometry;
pub mod sun;
mod surroundings;
pub mod texture;

use std::path::PathBuf;
use std::sync::Arc;

use glam::{DVec3, Quat, Vec2, Vec3, Vec4};

pub use builder::SceneBuilder;
pub use environment::Environment;
pub use geometry::{SceneGeometry, TriangleId};
pub use gltf::{
    DEFAULT_MAX_TEXTURE_PIXELS, ExternalFile, ExternalKind, LoadError, LoadOptions, MAX_SCENE_TRIANGLES,
    SourceDocument, SourceImage, external_files, load_gltf, load_gltf_bytes, read_scene_file, read_source,
};
pub use surroundings::{STAND_IN_SKY, SkyPicture, SunPlacement, Surroundings, SurroundingsSpec};
pub use texture::{Texture, TextureRef, TextureUv, UvTransform, WrapMode};

/// Linear RGB triple (radiance, irradiance, albedo...). Units are given where it is used.
pub type Rgb = Vec3;

/// Rec. 709 luminance of linear RGB.
#[inline]
pub fn luminance(c: Rgb) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

/// Which face of a triangle. `Front` is the side its counter-clockwise winding faces
/// (glTF convention); `Back` exists as a light-mapped surface only for double-sided materials.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
#[repr(u8)]
pub enum Side {
    Front = 0,
    Back = 1,
}

impl Side {
    pub const BOTH: [Side; 2] = [Side::Front, Side::Back];

    /// +1 for the front, −1 for the back: multiply a geometric normal by this to get the
    /// normal of that side.
    #[inline]
    pub fn sign(self) -> f32 {
        match self {
            Side::Front => 1.0,
            Side::Back => -1.0,
        }
    }

    #[inline]
    pub fn index(self) -> usize {
        self as usize
    }

    /// The side of a surface with geometric normal `ng` that a direction `d` (pointing away
    /// from the surface, e.g. a query normal) lies on.
    #[inline]
    pub fn facing(ng: Vec3, d: Vec3) -> Side {
        if ng.dot(d) >= 0.0 { Side::Front } else { Side::Back }
    }
}

/// glTF alpha mode: what fraction of the light meeting a surface interacts with it (its
/// coverage, [`Material::coverage`]). `Opaque`: all; `Mask`: all where `alpha ≥ cutoff`, none
/// elsewhere (cut out); `Blend`: `alpha`, the rest passes straight through untinted.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub enum AlphaMode {
    Opaque,
    Mask { cutoff: f32 },
    Blend,
}

impl AlphaMode {
    /// `Mask`'s cutoff: where alpha is below it the surface is cut out.
    pub fn cutoff(self) -> Option<f32> {
        match self {
            AlphaMode::Mask { cutoff } => Some(cutoff),
            _ => None,
        }
    }
}

/// A Lambertian material as light transport sees a glTF metallic-roughness material.
#[derive(Clone, Debug)]
pub struct Material {
    pub name: String,
    /// Linear RGBA factor (glTF `baseColorFactor`), multiplied by the texture when present.
    pub base_color: Vec4,
    pub base_color_texture: Option<TextureRef>,
    /// Emitted radiance in W/(sr·m²): `emissiveFactor × KHR_materials_emissive_strength`,
    /// multiplied by the emissive texture when present.
    pub emission: Rgb,
    pub emissive_texture: Option<TextureRef>,
    pub double_sided: bool,
    pub alpha_mode: AlphaMode,
    /// `KHR_materials_transmission` (thin-walled): the fraction of the light interacting
    /// with the surface that passes straight through, tinted by the albedo; multiplied by
    /// the red channel of `transmission_texture` (linear) when present.
    pub transmission: f32,
    pub transmission_texture: Option<TextureRef>,
}

/// What a thin sheet does with the light meeting it at one point: it passes straight
/// through with `pass` and is reflected diffusely (on the side it came from) with albedo
/// `reflect`. With coverage c, transmission t and albedo a:
/// `pass = (1 − c) + c·t·a`, `reflect = c·(1 − t)·a` (per channel, each in [0, 1]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sheet {
    pub pass: Rgb,
    pub reflect: Rgb,
}

impl Default for Material {
    /// glTF's default material: white, opaque, single-sided, not emissive.
    fn default() -> Self {
        Material {
            name: "default".into(),
            base_color: Vec4::ONE,
            base_color_texture: None,
            emission: Vec3::ZERO,
            emissive_texture: None,
            double_sided: false,
            alpha_mode: AlphaMode::Opaque,
            transmission: 0.0,
            transmission_texture: None,
        }
    }
}

impl Material {
    pub fn is_emissive(&self) -> bool {
        self.emission.max_element() > 0.0
    }

    /// Where this material's textures are read on a mesh: its base colour texture's set and
    /// transform, else its transmission or emissive texture's. The loader warns where the
    /// others differ; every texture of the material is read there (the `uv` the methods
    /// below take: [`SceneGeometry::texture_uv`]).
    pub fn texture_uv(&self) -> TextureUv {
        [self.base_color_texture, self.transmission_texture, self.emissive_texture]
            .into_iter()
            .flatten()
            .next()
            .map_or_else(TextureUv::default, |t| t.uv())
    }

    /// What multiplies the base-colour factor at `p`: the base colour texture's value times
    /// the vertex colour, either alone, or `None` (the factor alone). The GPU's twin
    /// (`surface_radiance.inc.wgsl`) multiplies in the same order.
    #[inline]
    fn base_sample(&self, textures: &[Texture], p: MaterialPoint) -> Option<Vec4> {
        let texel = self.base_color_texture.as_ref().map(|t| textures[t.texture].sample(p.uv));
        match (texel, p.color) {
            (Some(t), Some(c)) => Some(t * c),
            (t, c) => t.or(c),
        }
    }

    /// Diffuse albedo at `p` (linear RGB, clamped to [0, 1]).
    pub fn albedo(&self, textures: &[Texture], p: MaterialPoint) -> Rgb {
        let mut c = self.base_color.truncate();
        if let Some(s) = self.base_sample(textures, p) {
            c *= s.truncate();
        }
        c.clamp(Vec3::ZERO, Vec3::ONE)
    }

    /// The albedo light maps reflect with at `p`: [`Sheet::reflect`] where the surface
    /// exists. A cut-out (`Mask`) is whole where it exists and absent elsewhere (nothing is
    /// lit there), so its reflectance is the albedo; a `Blend` surface reflects the covered
    /// fraction α, a transmissive one the fraction 1 − t of that.
    pub fn reflectance(&self, textures: &[Texture], p: MaterialPoint) -> Rgb {
        if !self.is_see_through() {
            return self.albedo(textures, p);
        }
        self.sheet(textures, p).reflect
    }

    /// The reflectance ([`reflectance`](Self::reflectance)) where it is the same at every
    /// point of a mesh without vertex colours (no texture varies it), `None` where a texture
    /// does.
    pub fn uniform_albedo(&self, textures: &[Texture]) -> Option<Rgb> {
        (self.base_color_texture.is_none() && self.transmission_texture.is_none())
            .then(|| self.reflectance(textures, MaterialPoint::default()))
    }

    /// Alpha at `p` (factor × texture alpha × vertex alpha).
    pub fn alpha(&self, textures: &[Texture], p: MaterialPoint) -> f32 {
        let mut a = self.base_color.w;
        if let Some(s) = self.base_sample(textures, p) {
            a *= s.w;
        }
        a
    }

    /// Whether light passes through any part of the surface: cut out (`Mask`) or
    /// see-through ([`is_see_through`](Self::is_see_through)).
    pub fn lets_light_through(&self) -> bool {
        self.is_see_through() || matches!(self.alpha_mode, AlphaMode::Mask { .. })
    }

    /// Whether light can pass through the surface where it exists (`Blend` or transmission).
    /// Cut-outs (`Mask`) are not: where a masked surface exists it is whole.
    pub fn is_see_through(&self) -> bool {
        self.alpha_mode == AlphaMode::Blend || self.transmission > 0.0
    }

    /// The fraction of the light meeting the surface at `p` that interacts with it
    /// ([`AlphaMode`]), in [0, 1].
    pub fn coverage(&self, textures: &[Texture], p: MaterialPoint) -> f32 {
        match self.alpha_mode {
            AlphaMode::Opaque => 1.0,
            AlphaMode::Mask { cutoff } => (self.alpha(textures, p) >= cutoff) as u32 as f32,
            AlphaMode::Blend => self.alpha(textures, p).clamp(0.0, 1.0),
        }
    }

    /// Transmission at texture coordinate `uv`: factor × the texture's red channel, in
    /// [0, 1] (vertex colours do not scale it).
    pub fn transmission_at(&self, textures: &[Texture], uv: Vec2) -> f32 {
        let mut t = self.transmission;
        if let Some(tex) = &self.transmission_texture {
            t *= textures[tex.texture].sample(uv).x;
        }
        t.clamp(0.0, 1.0)
    }

    /// What the surface does with light meeting it at `p` ([`Sheet`]).
    pub fn sheet(&self, textures: &[Texture], p: MaterialPoint) -> Sheet {
        let a = self.albedo(textures, p);
        let c = self.coverage(textures, p);
        let t = if self.transmission > 0.0 { self.transmission_at(textures, p.uv) } else { 0.0 };
        Sheet { pass: Rgb::splat(1.0 - c) + a * (c * t), reflect: a * (c * (1.0 - t)) }
    }

    /// Emitted radiance (W/(sr·m²)) at `uv0` from the emitting side(s).
    pub fn emission_at(&self, textures: &[Texture], uv0: Vec2) -> Rgb {
        let mut e = self.emission;
        if let Some(t) = &self.emissive_texture {
            e *= textures[t.texture].sample(uv0).truncate();
        }
        e
    }

    /// Whether `side` of a surface with this material emits. A single-sided emitter emits
    /// from its front only; a double-sided one from both faces.
    #[inline]
    pub fn emits_from(&self, side: Side) -> bool {
        side == Side::Front || self.double_sided
    }

    /// Whether `side` of a surface with this material is a real, lit surface. The back of a
    /// single-sided surface is the inside of closed geometry: it reflects and emits nothing.
    #[inline]
    pub fn has_side(&self, side: Side) -> bool {
        side == Side::Front || self.double_sided
    }
}

/// Index into [`Scene::materials`].
pub type MaterialId = u32;

/// Where a material is read at a surface point: its texture coordinate
/// ([`SceneGeometry::texture_uv`]) and the mesh's vertex colour there (glTF `COLOR_0`, which
/// multiplies the base colour and its alpha; `None` where the mesh has none, which is
/// white).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MaterialPoint {
    pub uv: Vec2,
    pub color: Option<Vec4>,
}

impl MaterialPoint {
    /// Texture coordinate `uv` on a mesh without vertex colours.
    pub fn at_uv(uv: Vec2) -> MaterialPoint {
        MaterialPoint { uv, color: None }
    }
}

/// A vertex colour as the viewer and the web page draw it: linear RGBA in 16-bit unorm,
/// which holds every 8- and 16-bit file colour exactly (65535 = 255 · 257).
pub fn color_unorm16(c: Vec4) -> [u16; 4] {
    c.to_array().map(|x| (x.clamp(0.0, 1.0) * 65535.0).round() as u16)
}

/// One triangle primitive instance, already transformed to world space.
#[derive(Clone, Debug)]
pub struct Mesh {
    /// `node name / mesh name / primitive index`, for messages and reports.
    pub name: String,
    /// glTF node index this instance came from, when loaded from a file.
    pub node: Option<usize>,
    pub material: MaterialId,
    /// World-space positions (metres).
    pub positions: Vec<Vec3>,
    /// World-space unit shading normals, one per vertex (generated when the file has none).
    pub normals: Vec<Vec3>,
    /// TEXCOORD_0 (material textures), when present.
    pub uv0: Option<Vec<Vec2>>,
    /// TEXCOORD_1 (candidate light-map UVs), when present.
    pub uv1: Option<Vec<Vec2>>,
    /// COLOR_0 (linear RGBA), when present and not white everywhere: it multiplies the
    /// material's base colour and alpha ([`MaterialPoint::color`]).
    pub colors: Option<Vec<Vec4>>,
    /// Counter-clockwise triangles (front face), indices into the vertex arrays.
    /// Degenerate triangles were dropped at load time.
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    #[inline]
    pub fn corners(&self, t: usize) -> [Vec3; 3] {
        let [a, b, c] = self.triangles[t];
        [self.positions[a as usize], self.positions[b as usize], self.positions[c as usize]]
    }

    /// The texture coordinates of triangle `t`'s corners where a material reads its textures
    /// at `uv` ([`Material::texture_uv`]): TEXCOORD_0 or TEXCOORD_1, transformed; zero where
    /// the mesh lacks that set.
    #[inline]
    pub fn texture_uv_corners(&self, t: usize, uv: TextureUv) -> [Vec2; 3] {
        let set = if uv.set == 1 { &self.uv1 } else { &self.uv0 };
        match set {
            Some(coords) => self.triangles[t].map(|i| uv.transform.apply(coords[i as usize])),
            None => [uv.transform.apply(Vec2::ZERO); 3],
        }
    }

    /// Triangle `t`'s corners' vertex colours (`None`: the mesh has none).
    #[inline]
    pub fn color_corners(&self, t: usize) -> Option<[Vec4; 3]> {
        let colors = self.colors.as_ref()?;
        Some(self.triangles[t].map(|i| colors[i as usize]))
    }
}

/// A KHR_lights_punctual light, in livebake's radiometric convention:
/// directional `intensity` is the irradiance (W/m²) on a surface facing the light;
/// point and spot `intensity` is radiant intensity (W/sr) (on the axis, for spots).
/// The light's colour multiplies the intensity.
#[derive(Clone, Debug)]
pub struct PunctualLight {
    pub name: String,
    pub kind: LightKind,
    /// `color × intensity`: W/m² (directional) or W/sr (point, spot) per channel.
    pub intensity: Rgb,
    /// World-space position (unused for directional lights).
    pub position: Vec3,
    /// Unit direction the light travels in (the node's −Z); unused for point lights.
    pub direction: Vec3,
    /// glTF `range`: beyond it the light contributes nothing; within it glTF's recommended
    /// smooth window `clamp(1 − (d/range)⁴, 0, 1)² / d²` applies.
    pub range: Option<f32>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LightKind {
    Directional,
    Point,
    /// Cone angles in radians from the axis. Between them the intensity falls off with glTF's
    /// recommended curve: `t²` with `t = (cosθ − cos outer) / (cos inner − cos outer)` clamped.
    Spot {
        inner_cone: f32,
        outer_cone: f32,
    },
}

impl PunctualLight {
    /// Irradiance (W/m²) this light delivers to a point `p` with unit normal `n`, ignoring
    /// occlusion, together with the unit direction from `p` towards the light and the
    /// distance to it (`f32::INFINITY` for directional lights).
    pub fn unoccluded_irradiance(&self, p: Vec3, n: Vec3) -> (Rgb, Vec3, f32) {
        match self.kind {
            LightKind::Directional => {
                let wi = -self.direction;
                (self.intensity * n.dot(wi).max(0.0), wi, f32::INFINITY)
            }
            LightKind::Point | LightKind::Spot { .. } => {
                let to_light = self.position - p;
                let d2 = to_light.length_squared();
                if d2 <= 0.0 {
                    return (Vec3::ZERO, Vec3::Y, 0.0);
                }
                let d = d2.sqrt();
                let wi = to_light / d;
                let cos_surface = n.dot(wi).max(0.0);
                let mut falloff = 1.0 / d2;
                if let Some(range) = self.range {
                    let r = d / range;
                    falloff *= (1.0 - r * r * r * r).clamp(0.0, 1.0).powi(2);
                }
                if let LightKind::Spot { inner_cone, outer_cone } = self.kind {
                    let cos_axis = self.direction.dot(-wi);
                    let (ci, co) = (inner_cone.cos(), outer_cone.cos());
                    let t = if ci - co > 1e-6 {
                        ((cos_axis - co) / (ci - co)).clamp(0.0, 1.0)
                    } else if cos_axis >= co {
                        1.0
                    } else {
                        0.0
                    };
                    falloff *= t * t;
                }
                (self.intensity * (cos_surface * falloff), wi, d)
            }
        }
    }
}

/// A camera from the file (or made up for previews).
#[derive(Clone, Debug)]
pub struct Camera {
    pub name: String,
    pub position: Vec3,
    /// World rotation; the camera looks along its local −Z with +Y up (glTF convention).
    pub rotation: Quat,
    pub projection: Projection,
}

#[derive(Clone, Copy, Debug)]
pub enum Projection {
    Perspective { yfov: f32, aspect: Option<f32>, znear: f32, zfar: Option<f32> },
    Orthographic { xmag: f32, ymag: f32, znear: f32, zfar: f32 },
}

/// Counts of what loading skipped or repaired, for warnings and reports.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct LoadStats {
    /// Nodes visited in the loaded scene.
    pub nodes: usize,
    /// Triangle primitive instances loaded (one [`Mesh`] each).
    pub primitives: usize,
    /// Triangles loaded (after dropping degenerate ones).
    pub triangles: usize,
    /// Zero-area (or non-finite-normal) triangles dropped.
    pub degenerate_triangles_dropped: usize,
    /// Point and line primitives skipped.
    pub non_triangle_primitives_skipped: usize,
    /// Primitives whose normals were generated because the file had none.
    pub normals_generated: usize,
    /// Vertex normals in the file that were zero or not finite, replaced by face normals.
    pub normals_replaced: usize,
    pub textures: usize,
    pub lights: usize,
    pub cameras: usize,
    /// What loading skipped or repaired, one line per kind (also logged with `tracing::warn!`).
    pub warnings: Vec<String>,
}

/// A whole scene in world space.
#[derive(Clone, Debug, Default)]
pub struct Scene {
    /// The file this was loaded from, if any.
    pub source: Option<PathBuf>,
    pub meshes: Vec<Mesh>,
    pub materials: Vec<Material>,
    pub textures: Vec<Texture>,
    pub lights: Vec<PunctualLight>,
    pub cameras: Vec<Camera>,
    /// Uniform sky radiance, W/(sr·m²), seen by rays that leave the scene (added to the
    /// environment's). Comes from configuration, not the file; black by default.
    pub sky: Rgb,
    /// No sky was asked for: the white stand-in sky lights the scene whenever nothing else
    /// does, decided again on every reload and change of surroundings
    /// ([`Scene::stand_in_sky`]).
    pub sky_automatic: bool,
    /// Radiance by direction seen by rays that leave the scene (see [`environment`]); from
    /// configuration, not the file.
    pub environment: Option<Arc<Environment>>,
    /// How many of the last [`lights`](Self::lights) came from the surroundings (the sun of
    /// [`Surroundings`]) rather than the file.
    pub surrounding_lights: usize,
    /// Where the scene's frame has its origin, in the file's coordinates (metres): every
    /// position here is relative to it. Zero unless the scene lies far from the file's
    /// origin (`gltf::origin`); points read from the user and positions written out are
    /// converted with [`Scene::to_scene`] and [`Scene::to_file`].
    pub origin: DVec3,
    pub stats: LoadStats,
}

impl Scene {
    /// A point in the file's coordinates, in the scene's frame (see [`Scene::origin`]).
    pub fn to_scene(&self, p: Vec3) -> Vec3 {
        if self.origin == DVec3::ZERO { p } else { (p.as_dvec3() - self.origin).as_vec3() }
    }

    /// A camera pose (eye, target) in the file's coordinates, in the scene's frame.
    pub fn pose_to_scene(&self, (eye, target): (Vec3, Vec3)) -> (Vec3, Vec3) {
        (self.to_scene(eye), self.to_scene(target))
    }

    /// A point of the scene's frame in the file's coordinates (see [`Scene::origin`]).
    pub fn to_file(&self, p: Vec3) -> DVec3 {
        p.as_dvec3() + self.origin
    }

    pub fn triangle_count(&self) -> usize {
        self.meshes.iter().map(|m| m.triangles.len()).sum()
    }

    pub fn material_of(&self, mesh: &Mesh) -> &Material {
        &self.materials[mesh.material as usize]
    }

    /// The area its triangles cover (one side each), m².
    pub fn surface_area(&self) -> f64 {
        let area = |m: &Mesh, t: usize| {
            let [a, b, c] = m.corners(t).map(|p| p.as_dvec3());
            (b - a).cross(c - a).length() / 2.0
        };
        self.meshes.iter().map(|m| (0..m.triangles.len()).map(|t| area(m, t)).sum::<f64>()).sum()
    }

    /// The brightest light its estimator's sums can hold ([`radiometry`]).
    pub fn light_ceiling(&self) -> radiometry::LightCeiling {
        radiometry::LightCeiling::for_area(self.surface_area())
    }

    /// Sets the sky radiance, refusing one too bright for the scene's sums (see
    /// [`radiometry`]).
    pub fn set_sky(&mut self, sky: Rgb) -> Result<(), radiometry::TooBright> {
        let c = self.light_ceiling();
        c.check(|| "the sky radiance".into(), sky.max_element() as f64, c.radiance(), "W/(sr·m²)")?;
        self.sky = sky;
        Ok(())
    }

    /// World-space bounds of all mesh vertices (`None` for an empty scene).
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let mut it = self.meshes.iter().flat_map(|m| m.positions.iter().copied());
        let first = it.next()?;
        Some(it.fold((first, first), |(lo, hi), p| (lo.min(p), hi.max(p))))
    }
}
