//! The sky on the GPU: the scene's [`SkyPicture`] as an `Rgba32Float` texture (group 3 of
//! surface.wgsl), which the surface pass shows where no surface is.

use wgpu::util::DeviceExt;

use super::device::GpuContext;
use crate::scene::{Rgb, SkyPicture};

/// Bind group layout of group 3 (the sky picture, surface.wgsl).
pub fn sky_bind_group_layout(device: &wgpu::Device) -> wgpu::BindGroupLayout {
    loaded_texture_layout(device, "sky")
}

/// A bind group layout of one float texture at binding 0 that the fragment stage reads with
/// `textureLoad` (the sky picture, the tone-map pass's radiance).
pub fn loaded_texture_layout(device: &wgpu::Device, label: &str) -> wgpu::BindGroupLayout {
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some(label),
        entries: &[wgpu::BindGroupLayoutEntry {
            binding: 0,
            visibility: wgpu::ShaderStages::FRAGMENT,
            ty: wgpu::BindingType::Texture {
                // Read with textureLoad and blended in the shader: f32 textures are not
                // filterable everywhere.
                sample_type: wgpu::TextureSampleType::Float { filterable: false },
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
            count: None,
        }],
    })
}

/// The sky as the surface pass shows it.
pub enum SkyGpu {
    /// The same radiance every way: the pass clears to it and draws no sky.
    Uniform(Rgb),
    /// The picture, drawn by `fs_sky` where no surface is.
    Picture(wgpu::BindGroup),
}

impl SkyGpu {
    pub fn new(gpu: &GpuContext, layout: &wgpu::BindGroupLayout, picture: &SkyPicture) -> SkyGpu {
        match picture.uniform() {
            Some(l) => SkyGpu::Uniform(l),
            None => SkyGpu::Picture(sky_bind_group(gpu, layout, picture)),
        }
    }
}

/// `picture` uploaded, bound for the surface pass.
fn sky_bind_group(gpu: &GpuContext, layout: &wgpu::BindGroupLayout, picture: &SkyPicture) -> wgpu::BindGroup {
    let texels: Vec<[f32; 4]> = picture.radiance.iter().map(|l| l.extend(1.0).to_array()).collect();
    let texture = gpu.device.create_texture_with_data(
        &gpu.queue,
        &wgpu::TextureDescriptor {
            label: Some("sky picture"),
            size: wgpu::Extent3d { width: picture.width, height: picture.height, depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba32Float,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        },
        wgpu::util::TextureDataOrder::LayerMajor,
        bytemuck::cast_slice(&texels),
    );
    let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
    gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("sky"),
        layout,
        entries: &[wgpu::BindGroupEntry { binding: 0, resource: wgpu::BindingResource::TextureView(&view) }],
    })
}
