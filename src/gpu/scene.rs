//! The scene on the GPU: de-indexed triangle corners grouped by material, each material's
//! uniforms, textures and sampler.
//!
//! Corners are de-indexed because a corner's light-map UV depends on the triangle (its face's
//! chart), not on the shared vertex. Each corner carries both faces' UVs; the fragment shader
//! picks by `front_facing`. Single-sided materials are drawn with back faces culled (their
//! back is the inside of closed geometry and has no texels); double-sided ones are not.
//! Material textures get mip maps (the display minifies them; the bake samples level 0).

use glam::{Vec3, Vec4};
use wgpu::util::DeviceExt;

use super::device::GpuContext;
use super::layout::{MaterialUniforms, SurfaceVertex};
use super::sky::SkyGpu;
use crate::atlas::{Atlas, NO_FACE};
use crate::scene::{AlphaMode, Scene, SceneGeometry, Texture, WrapMode};

/// Light-map UV of a side without a face: the shader shows no irradiance there.
const NO_UV: [f32; 2] = [-1.0, -1.0];

/// Bind group layout of group 2 (the material, surface.wgsl).
pub fn material_bind_group_layout(device: &wgpu::Device) -> wgpu::BindGroupLayout {
    let texture = |binding| wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::FRAGMENT,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: true },
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    };
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("material"),
        entries: &[
            wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            },
            texture(1),
            texture(2),
            wgpu::BindGroupLayoutEntry {
                binding: 3,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                count: None,
            },
            texture(4),
        ],
    })
}

/// The corners of one material's triangles: a draw range.
pub struct Batch {
    pub bind_group: wgpu::BindGroup,
    pub vertices: std::ops::Range<u32>,
    pub double_sided: bool,
    /// A `MASK` material: drawn with the pipeline that cuts its fragments out.
    pub cut_out: bool,
    /// A see-through material (`BLEND` or transmission, [`Material::is_see_through`]):
    /// composited over what lies behind it, after the rest.
    ///
    /// [`Material::is_see_through`]: crate::scene::Material::is_see_through
    pub sheet: bool,
    /// The centre of its corners' bounding box: sheets are drawn farthest first.
    pub centre: Vec3,
}

pub struct SceneGpu {
    pub vertex_buffer: wgpu::Buffer,
    pub batches: Vec<Batch>,
    /// Some batch is a see-through sheet: the scene is drawn through the HDR target.
    pub has_sheets: bool,
    /// The sky shown where no surface is (`None`: the scene's sky is black; the backdrop
    /// shows).
    pub sky: Option<SkyGpu>,
    pub vertex_count: u32,
}

impl SceneGpu {
    /// `layout` and `sky_layout`: groups 2 and 3 of surface.wgsl.
    pub fn new(
        gpu: &GpuContext,
        layout: &wgpu::BindGroupLayout,
        sky_layout: &wgpu::BindGroupLayout,
        scene: &Scene,
        atlas: &Atlas,
    ) -> SceneGpu {
        let device = &gpu.device;
        let geom = SceneGeometry::new(scene);
        let mut per_material: Vec<Vec<SurfaceVertex>> = vec![Vec::new(); scene.materials.len()];
        for t in 0..geom.len() {
            let material = geom.material[t] as usize;
            let Some(out) = per_material.get_mut(material) else { continue };
            let uv0 = geom.texture_uv_corners(scene, t);
            let colors = geom.color_corners(scene, t).unwrap_or([Vec4::ONE; 3]);
            let faces = atlas.face_of.get(t).copied().unwrap_or([NO_FACE; 2]);
            let face_uv = |f: u32, i: usize| {
                if f == NO_FACE { NO_UV } else { atlas.faces[f as usize].uv[i].to_array() }
            };
            for (i, (corner, uv0)) in geom.corners[t].iter().zip(uv0).enumerate() {
                out.push(SurfaceVertex {
                    position: corner.to_array(),
                    uv0: uv0.to_array(),
                    lightmap_front: face_uv(faces[0], i),
                    lightmap_back: face_uv(faces[1], i),
                    color: crate::scene::color_unorm16(colors[i]),
                });
            }
        }
        let textures: Vec<Option<wgpu::TextureView>> = scene.textures.iter().map(|t| upload_texture(gpu, t)).collect();
        let white = upload_texture(
            gpu,
            &Texture {
                name: "white".into(),
                width: 1,
                height: 1,
                rgba8: vec![[255; 4]].into(),
                srgb: false,
                wrap_s: WrapMode::Repeat,
                wrap_t: WrapMode::Repeat,
            },
        )
        .expect("a 1×1 texture fits every adapter");
        let mut vertices = Vec::new();
        let mut batches = Vec::new();
        for (mi, corners) in per_material.into_iter().enumerate() {
            if corners.is_empty() {
                continue;
            }
            let m = &scene.materials[mi];
            let uniforms = MaterialUniforms {
                base_color: m.base_color.to_array(),
                emission: m.emission.to_array(),
                alpha_cutoff: m.alpha_mode.cutoff().unwrap_or(0.0),
                blend: (m.alpha_mode == AlphaMode::Blend) as u32,
                transmission: m.transmission,
                _pad0: 0,
                _pad1: 0,
            };
            let buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(&m.name),
                contents: bytemuck::bytes_of(&uniforms),
                usage: wgpu::BufferUsages::UNIFORM,
            });
            let view_of = |r: &Option<crate::scene::TextureRef>| {
                r.and_then(|r| textures.get(r.texture).and_then(|t| t.as_ref())).unwrap_or(&white)
            };
            let wrap = m
                .base_color_texture
                .or(m.emissive_texture)
                .and_then(|r| scene.textures.get(r.texture))
                .map_or((WrapMode::Repeat, WrapMode::Repeat), |t| (t.wrap_s, t.wrap_t));
            let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
                label: Some(&m.name),
                address_mode_u: address_mode(wrap.0),
                address_mode_v: address_mode(wrap.1),
                mag_filter: wgpu::FilterMode::Linear,
                min_filter: wgpu::FilterMode::Linear,
                mipmap_filter: wgpu::MipmapFilterMode::Linear,
                ..Default::default()
            });
            let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some(&m.name),
                layout,
                entries: &[
                    wgpu::BindGroupEntry { binding: 0, resource: buffer.as_entire_binding() },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: wgpu::BindingResource::TextureView(view_of(&m.base_color_texture)),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: wgpu::BindingResource::TextureView(view_of(&m.emissive_texture)),
                    },
                    wgpu::BindGroupEntry { binding: 3, resource: wgpu::BindingResource::Sampler(&sampler) },
                    wgpu::BindGroupEntry {
                        binding: 4,
                        resource: wgpu::BindingResource::TextureView(view_of(&m.transmission_texture)),
                    },
                ],
            });
            let (lo, hi) = corners.iter().fold((Vec3::MAX, Vec3::MIN), |(lo, hi), c| {
                let p = Vec3::from_array(c.position);
                (lo.min(p), hi.max(p))
            });
            let start = vertices.len() as u32;
            vertices.extend(corners);
            batches.push(Batch {
                bind_group,
                vertices: start..vertices.len() as u32,
                double_sided: m.double_sided,
                cut_out: m.alpha_mode.cutoff().is_some(),
                sheet: m.is_see_through(),
                centre: (lo + hi) * 0.5,
            });
        }
        let vertex_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("scene corners"),
            contents: if vertices.is_empty() { &[0u8; 4] } else { bytemuck::cast_slice(&vertices) },
            usage: wgpu::BufferUsages::VERTEX,
        });
        let has_sheets = batches.iter().any(|b| b.sheet);
        let sky = scene.sky_picture().map(|picture| SkyGpu::new(gpu, sky_layout, &picture));
        SceneGpu { vertex_buffer, batches, has_sheets, sky, vertex_count: vertices.len() as u32 }
    }
}

fn address_mode(w: WrapMode) -> wgpu::AddressMode {
    match w {
        WrapMode::Repeat => wgpu::AddressMode::Repeat,
        WrapMode::MirroredRepeat => wgpu::AddressMode::MirrorRepeat,
        WrapMode::ClampToEdge => wgpu::AddressMode::ClampToEdge,
    }
}

/// A material texture on the GPU (sRGB-decoded by the sampler when the texture is sRGB, so
/// filtering happens on linear values as on the CPU). `None` (with a warning) when it is
/// empty or larger than the adapter allows: the material then shows its factor alone.
fn upload_texture(gpu: &GpuContext, t: &Texture) -> Option<wgpu::TextureView> {
    let max = gpu.device.limits().max_texture_dimension_2d;
    if t.width == 0
        || t.height == 0
        || t.width > max
        || t.height > max
        || t.rgba8.len() != (t.width * t.height) as usize
    {
        tracing::warn!(texture = %t.name, width = t.width, height = t.height, "texture not shown (empty or above the GPU's {max} limit)");
        return None;
    }
    Some(create_texture(gpu, t))
}

/// The texture's mip chain, tightly packed level after level: each level a 2×2 box filter of
/// the one above, averaged in linear values and re-encoded as the texture is (sRGB or not).
fn mip_chain(t: &Texture) -> (u32, Vec<[u8; 4]>) {
    let encode = |c: Vec4| {
        let channel = |v: f32| {
            let v = v.clamp(0.0, 1.0);
            let e = if !t.srgb || v <= 0.003_130_8 {
                if t.srgb { 12.92 * v } else { v }
            } else {
                1.055 * v.powf(1.0 / 2.4) - 0.055
            };
            (e * 255.0 + 0.5) as u8
        };
        [channel(c.x), channel(c.y), channel(c.z), (c.w.clamp(0.0, 1.0) * 255.0 + 0.5) as u8]
    };
    let mut data = t.rgba8.to_vec();
    let mut level: Vec<Vec4> = (0..t.height).flat_map(|y| (0..t.width).map(move |x| t.texel(x, y))).collect();
    let (mut w, mut h, mut count) = (t.width, t.height, 1);
    while w > 1 || h > 1 {
        let (nw, nh) = ((w / 2).max(1), (h / 2).max(1));
        let prev = &level;
        let next: Vec<Vec4> = (0..nh)
            .flat_map(|y| {
                (0..nw).map(move |x| {
                    let (x0, x1) = ((2 * x).min(w - 1), (2 * x + 1).min(w - 1));
                    let (y0, y1) = ((2 * y).min(h - 1), (2 * y + 1).min(h - 1));
                    let at = |x: u32, y: u32| prev[(y * w + x) as usize];
                    (at(x0, y0) + at(x1, y0) + at(x0, y1) + at(x1, y1)) * 0.25
                })
            })
            .collect();
        data.extend(next.iter().map(|&c| encode(c)));
        (level, w, h, count) = (next, nw, nh, count + 1);
    }
    (count, data)
}

fn create_texture(gpu: &GpuContext, t: &Texture) -> wgpu::TextureView {
    let format = if t.srgb { wgpu::TextureFormat::Rgba8UnormSrgb } else { wgpu::TextureFormat::Rgba8Unorm };
    let (mip_level_count, data) = mip_chain(t);
    let texture = gpu.device.create_texture_with_data(
        &gpu.queue,
        &wgpu::TextureDescriptor {
            label: Some(&t.name),
            size: wgpu::Extent3d { width: t.width, height: t.height, depth_or_array_layers: 1 },
            mip_level_count,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        },
        wgpu::util::TextureDataOrder::LayerMajor,
        bytemuck::cast_slice(&data),
    );
    texture.create_view(&wgpu::TextureViewDescriptor::default())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Mips average linear values: a black/white checker becomes mid-grey in linear light,
    /// which is sRGB 188, not 128; the chain ends at 1×1 and is packed level after level.
    #[test]
    fn mip_chain_averages_linear_light() {
        let checker = Texture {
            name: "c".into(),
            width: 4,
            height: 2,
            rgba8: (0..8).map(|i| if (i + i / 4) % 2 == 0 { [255, 255, 255, 255] } else { [0, 0, 0, 255] }).collect(),
            srgb: true,
            wrap_s: WrapMode::Repeat,
            wrap_t: WrapMode::Repeat,
        };
        let (levels, data) = mip_chain(&checker);
        assert_eq!((levels, data.len()), (3, 8 + 2 + 1));
        assert_eq!(data[8], [188, 188, 188, 255]);
        assert_eq!(data[10], [188, 188, 188, 255]);
    }
}
