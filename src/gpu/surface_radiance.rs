//! What surfaces outside a bake's target show its bundles, on the GPU: the runtime's
//! `ShownSource` (albedo/π times the shown light map's irradiance, plus emission where the
//! global bundles carry it), evaluated in the resolve (bundle_resolve.wgsl); and the
//! scene's materials, which that and the transmittance of see-through surfaces and
//! cut-outs (bundle_through.inc.wgsl) read.
//!
//! - group 1: the shown light map's mirror ([`super::lightmap`], lightmap.inc.wgsl), kept in
//!   step with each batch's snapshot by partial page uploads;
//! - group 2: the scene's materials ([`SceneSurfaces`], surface_radiance.inc.wgsl): per
//!   triangle its texture coordinates at its corners, material, whether the bundles carry
//!   its emission and where its corners' vertex colours are; per material its factors, alpha
//!   mode, transmission and textures; the textures as RGBA8 words; the CPU's sRGB table; the
//!   vertex colours. The GPU mirror of `Scene::materials` and `textures`,
//!   uploaded once per backend (at its start when the scene lets light through surfaces,
//!   else at the first bake with a foreign source).
//!
//! A bake that reads neither binds [`ForeignBindings`]' placeholders instead (its resolve
//! pipeline, made with `FOREIGN_SOURCE` and `PASSING` false, never reads them).

use std::sync::Arc;

use wgpu::util::DeviceExt;

use super::GpuError;
use super::device::GpuContext;
use super::layout::{LightmapParams, SurfaceMaterial, SurfaceTriangle, TextureHeader};
use super::lightmap::{self, LightmapGpu};
use crate::bundle::target::BundleScene;
use crate::runtime::shown::ShownLightmap;
use crate::scene::texture::{WrapMode, srgb_to_linear_lut};
use crate::scene::{AlphaMode, Material};

/// `NO_TEXTURE` in the shader.
const NO_TEXTURE: u32 = u32::MAX;
/// `NO_COLOR` in the shader.
const NO_COLOR: u32 = u32::MAX;
/// Storage buffers of group 2.
const SURFACE_BINDINGS: u32 = 6;

/// Bind group layout of group 2 (surface_radiance.inc.wgsl).
pub fn bind_group_layout(device: &wgpu::Device) -> wgpu::BindGroupLayout {
    let read = wgpu::BufferBindingType::Storage { read_only: true };
    super::pass::buffer_layout(
        device,
        "scene surfaces",
        &[(wgpu::ShaderStages::COMPUTE, read); SURFACE_BINDINGS as usize],
    )
}

/// The scene's materials as the resolve reads them (group 2).
pub struct SceneSurfaces {
    bind_group: wgpu::BindGroup,
    /// Bytes uploaded.
    pub bytes: u64,
}

/// The records of group 2 for `scene`.
struct SurfaceRecords {
    triangles: Vec<SurfaceTriangle>,
    /// The corners' vertex colours of the triangles whose meshes have them, three each.
    colors: Vec<[f32; 4]>,
    materials: Vec<SurfaceMaterial>,
    headers: Vec<TextureHeader>,
    texels: Vec<u32>,
}

/// `ALPHA_*` in bundle_through.inc.wgsl, and the cutoff (0 unless `MASK`).
fn alpha_code(mode: AlphaMode) -> (u32, f32) {
    match mode {
        AlphaMode::Opaque => (0, 0.0),
        AlphaMode::Mask { cutoff } => (1, cutoff),
        AlphaMode::Blend => (2, 0.0),
    }
}

/// The record of material `m` (`texture`: a texture reference's index, or `NO_TEXTURE`).
fn material_record(m: &Material, texture: impl Fn(&Option<crate::scene::TextureRef>) -> u32) -> SurfaceMaterial {
    let (alpha_mode, alpha_cutoff) = alpha_code(m.alpha_mode);
    SurfaceMaterial {
        base_color: m.base_color.to_array(),
        emission: m.emission.to_array(),
        double_sided: m.double_sided as u32,
        base_texture: texture(&m.base_color_texture),
        emissive_texture: texture(&m.emissive_texture),
        alpha_mode,
        alpha_cutoff,
        transmission: m.transmission,
        transmission_texture: texture(&m.transmission_texture),
        passing: m.lets_light_through() as u32,
        _pad: 0,
    }
}

fn wrap_code(mode: WrapMode) -> u32 {
    match mode {
        WrapMode::Repeat => 0,
        WrapMode::MirroredRepeat => 1,
        WrapMode::ClampToEdge => 2,
    }
}

impl SurfaceRecords {
    /// The records of `scene`; an error, before anything is allocated, when the textures or
    /// the triangles' records would exceed `limit` bytes (the device's storage binding size).
    fn of(scene: &BundleScene, limit: u64) -> Result<SurfaceRecords, GpuError> {
        let (s, geom) = (&scene.scene, &scene.geom);
        let words: u64 = s.textures.iter().map(|t| t.rgba8.len() as u64).sum();
        let triangle_bytes = size_of::<SurfaceTriangle>() as u64 * geom.len() as u64;
        let colored = (0..geom.len()).filter(|&t| geom.has_colors(s, t)).count() as u64;
        let color_bytes = 3 * 16 * colored;
        for (what, bytes) in
            [("textures", 4 * words), ("triangle materials", triangle_bytes), ("vertex colours", color_bytes)]
        {
            if bytes > limit {
                return Err(GpuError::Validation(format!(
                    "the scene's {what} need {bytes} bytes, over the device's storage binding limit of {limit}"
                )));
            }
        }
        let mut colors = Vec::with_capacity(3 * colored as usize);
        let triangles = (0..geom.len())
            .map(|t| SurfaceTriangle {
                uv0: geom.texture_uv_corners(s, t).map(|p| p.to_array()),
                material: geom.material[t],
                carried: scene.emitters.carried_by_bundles[t] as u32,
                colors: geom.color_corners(s, t).map_or(NO_COLOR, |corners| {
                    let first = colors.len() as u32;
                    colors.extend(corners.map(|c| c.to_array()));
                    first
                }),
                _pad: 0,
            })
            .collect();
        let texture = |r: &Option<crate::scene::TextureRef>| r.as_ref().map_or(NO_TEXTURE, |r| r.texture as u32);
        let materials = s.materials.iter().map(|m| material_record(m, texture)).collect();
        let words = u32::try_from(words)
            .map_err(|_| GpuError::Validation(format!("the scene's textures hold {words} texels, over 2^32")))?;
        let mut texels = Vec::with_capacity(words as usize);
        let mut headers = Vec::with_capacity(s.textures.len());
        for t in &s.textures {
            headers.push(TextureHeader {
                width: t.width,
                height: t.height,
                first: texels.len() as u32,
                srgb: t.srgb as u32,
                wrap_s: wrap_code(t.wrap_s),
                wrap_t: wrap_code(t.wrap_t),
                _pad0: 0,
                _pad1: 0,
            });
            texels.extend(t.rgba8.iter().map(|&p| u32::from_le_bytes(p)));
        }
        Ok(SurfaceRecords { triangles, colors, materials, headers, texels })
    }
}

/// A storage buffer holding `data`, or zeros when it is empty: a binding must hold one
/// element of its array (the largest here is 64 bytes).
fn storage(device: &wgpu::Device, label: &str, data: &[u8]) -> wgpu::Buffer {
    let zero = [0u8; 64];
    let contents = if data.is_empty() { &zero[..] } else { data };
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(label),
        contents,
        usage: wgpu::BufferUsages::STORAGE,
    })
}

impl SceneSurfaces {
    /// Uploads `scene`'s materials; an error when a buffer exceeds the device's binding limit.
    pub fn new(
        gpu: &GpuContext,
        layout: &wgpu::BindGroupLayout,
        scene: &BundleScene,
    ) -> Result<SceneSurfaces, GpuError> {
        let records = SurfaceRecords::of(scene, gpu.device.limits().max_storage_buffer_binding_size)?;
        let lut = srgb_to_linear_lut();
        let buffers = [
            storage(&gpu.device, "surface triangles", bytemuck::cast_slice(&records.triangles)),
            storage(&gpu.device, "surface materials", bytemuck::cast_slice(&records.materials)),
            storage(&gpu.device, "texture headers", bytemuck::cast_slice(&records.headers)),
            storage(&gpu.device, "texture texels", bytemuck::cast_slice(&records.texels)),
            storage(&gpu.device, "sRGB table", bytemuck::cast_slice(&lut[..])),
            storage(&gpu.device, "vertex colours", bytemuck::cast_slice(&records.colors)),
        ];
        let bytes = buffers.iter().map(|b| b.size()).sum();
        let bind_group = bind_buffers(&gpu.device, layout, &buffers);
        gpu.take_error()?;
        Ok(SceneSurfaces { bind_group, bytes })
    }
}

fn bind_buffers(device: &wgpu::Device, layout: &wgpu::BindGroupLayout, buffers: &[wgpu::Buffer]) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = buffers
        .iter()
        .enumerate()
        .map(|(i, b)| wgpu::BindGroupEntry { binding: i as u32, resource: b.as_entire_binding() })
        .collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor { label: Some("scene surfaces"), layout, entries: &entries })
}

/// The layouts of the resolve's groups 1 and 2, and bind groups the resolve binds when the
/// bake has no foreign source (it never reads them then).
pub struct ForeignBindings {
    pub lightmap_layout: wgpu::BindGroupLayout,
    pub surfaces_layout: wgpu::BindGroupLayout,
    placeholder_lightmap: wgpu::BindGroup,
    placeholder_surfaces: wgpu::BindGroup,
}

impl ForeignBindings {
    pub fn new(gpu: &GpuContext) -> ForeignBindings {
        let device = &gpu.device;
        let lightmap_layout = lightmap::bind_group_layout(device);
        let surfaces_layout = bind_group_layout(device);
        let params = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("placeholder lightmap params"),
            contents: bytemuck::bytes_of(&<LightmapParams as bytemuck::Zeroable>::zeroed()),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let word = |label| storage(device, label, &[]);
        let pool = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("placeholder lightmap pool"),
            size: wgpu::Extent3d { width: 1, height: 1, depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: lightmap::POOL_FORMAT,
            usage: wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        });
        let placeholder_lightmap = lightmap::create_bind_group(
            device,
            &lightmap_layout,
            &params,
            &word("placeholder cell LODs"),
            &word("placeholder page table"),
            &pool,
        );
        let buffers: Vec<wgpu::Buffer> = (0..SURFACE_BINDINGS).map(|_| word("placeholder surfaces")).collect();
        let placeholder_surfaces = bind_buffers(device, &surfaces_layout, &buffers);
        ForeignBindings { lightmap_layout, surfaces_layout, placeholder_lightmap, placeholder_surfaces }
    }

    /// Groups 1 and 2 for a resolve: `foreign`'s shown map, or the placeholder; the scene's
    /// `surfaces` (`foreign`'s when it has one), or the placeholder.
    pub fn groups<'a>(
        &'a self,
        foreign: Option<&'a ForeignRadiance>,
        surfaces: Option<&'a SceneSurfaces>,
    ) -> [&'a wgpu::BindGroup; 2] {
        let lightmap = foreign.map_or(&self.placeholder_lightmap, |f| f.lightmap.bind_group());
        let surfaces = foreign.map(|f| &*f.surfaces).or(surfaces);
        [lightmap, surfaces.map_or(&self.placeholder_surfaces, |s| &s.bind_group)]
    }
}

/// One backend's foreign source on the GPU: the scene's materials (uploaded once, shared
/// with the backend) and the mirror of the last shown-map snapshot a batch saw.
pub struct ForeignRadiance {
    surfaces: Arc<SceneSurfaces>,
    lightmap: LightmapGpu,
    /// The snapshot mirrored, and a bound on the radiance any foreign side shows in it.
    shown: Arc<ShownLightmap>,
    brightest: f32,
}

impl ForeignRadiance {
    /// The mirror of `shown` beside the scene's `surfaces`.
    pub fn new(
        gpu: &GpuContext,
        bindings: &ForeignBindings,
        scene: &BundleScene,
        shown: &Arc<ShownLightmap>,
        surfaces: Arc<SceneSurfaces>,
    ) -> Result<ForeignRadiance, GpuError> {
        let lightmap = LightmapGpu::new(gpu, &bindings.lightmap_layout, shown)?;
        Ok(ForeignRadiance { surfaces, lightmap, shown: shown.clone(), brightest: brightest(scene, shown) })
    }

    /// Brings the mirror to snapshot `shown` (only the pages that changed are uploaded;
    /// nothing when it is the snapshot mirrored).
    pub fn sync(
        &mut self,
        gpu: &GpuContext,
        bindings: &ForeignBindings,
        scene: &BundleScene,
        shown: &Arc<ShownLightmap>,
    ) -> Result<(), GpuError> {
        if !Arc::ptr_eq(shown, &self.shown) {
            self.lightmap.sync(gpu, &bindings.lightmap_layout, shown)?;
            self.shown = shown.clone();
            self.brightest = brightest(scene, shown);
        }
        Ok(())
    }

    /// A bound on any channel of any foreign side's radiance (for the fixed-point scales).
    pub fn brightest(&self) -> f32 {
        self.brightest
    }
}

/// `ShownSource::radiance` ≤ albedo (≤ 1)/π · max E + the largest emission (texture
/// values are ≤ 1).
fn brightest(scene: &BundleScene, shown: &ShownLightmap) -> f32 {
    let emission = scene.scene.materials.iter().fold(0f32, |m, mat| m.max(mat.emission.max_element()));
    shown.max_irradiance() * std::f32::consts::FRAC_1_PI + emission
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A scene whose materials a device cannot bind is refused with the figure and the
    /// limit (the backend then bakes its foreign sides on the CPU); otherwise every triangle
    /// and texture texel gets its record.
    #[test]
    fn materials_beyond_the_binding_limit_are_refused() {
        let scene = crate::gpu::bundle_analysis::tests::cornell();
        let bundle = &scene.bundle;
        let texels: u64 = bundle.scene.textures.iter().map(|t| t.rgba8.len() as u64).sum();
        assert!(texels > 256, "the Cornell box has textures");
        let Err(e) = SurfaceRecords::of(bundle, 4 * texels - 4) else { panic!("a limit below the textures passed") };
        assert!(e.to_string().contains("storage binding limit"), "{e}");
        let records = SurfaceRecords::of(bundle, u64::MAX).expect("no limit");
        assert_eq!(records.triangles.len(), bundle.geom.len());
        assert_eq!(records.texels.len() as u64, texels);
        assert_eq!(records.headers.len(), bundle.scene.textures.len());
    }
}
