//! The tone-map pass: the surface pass's exposed linear radiance ([`RADIANCE_FORMAT`]) through
//! the tone curve onto the frame's colour target (the window's or an offscreen one), pixel for
//! pixel. Reads the radiance target; writes the colour target.

use super::device::GpuContext;
use super::pass::single_group;
use super::shader::{self, ShaderError};
use super::sky::loaded_texture_layout;
use super::surface::RADIANCE_FORMAT;

/// The surface pass's target and what the tone-map pass reads it through, for one frame size.
pub struct RadianceTarget {
    pub view: wgpu::TextureView,
    bind_group: wgpu::BindGroup,
    pub width: u32,
    pub height: u32,
}

pub struct ToneMapPass {
    layout: wgpu::BindGroupLayout,
    pipeline_layout: wgpu::PipelineLayout,
    module: wgpu::ShaderModule,
    /// One pipeline per colour format drawn to.
    pipelines: Vec<(wgpu::TextureFormat, wgpu::RenderPipeline)>,
}

impl ToneMapPass {
    pub fn new(gpu: &GpuContext) -> Result<ToneMapPass, ShaderError> {
        let device = &gpu.device;
        let layout = loaded_texture_layout(device, "tone map");
        let pipeline_layout = single_group(device, "tone map", &layout);
        let module = shader::module(device, "tone_map.wgsl")?;
        Ok(ToneMapPass { layout, pipeline_layout, module, pipelines: Vec::new() })
    }

    /// A radiance target of `width × height` pixels.
    pub fn target(&self, gpu: &GpuContext, width: u32, height: u32) -> RadianceTarget {
        let texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("radiance"),
            size: wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: RADIANCE_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        });
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        let bind_group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("tone map"),
            layout: &self.layout,
            entries: &[wgpu::BindGroupEntry { binding: 0, resource: wgpu::BindingResource::TextureView(&view) }],
        });
        RadianceTarget { view, bind_group, width, height }
    }

    /// The pipeline for `format`, made the first time it is drawn to: an sRGB format is
    /// encoded by the hardware, any other by the shader.
    fn pipeline(&mut self, gpu: &GpuContext, format: wgpu::TextureFormat) -> &wgpu::RenderPipeline {
        let i = match self.pipelines.iter().position(|(f, _)| *f == format) {
            Some(i) => i,
            None => {
                let pipeline = gpu.device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                    label: Some("tone map"),
                    layout: Some(&self.pipeline_layout),
                    vertex: wgpu::VertexState {
                        module: &self.module,
                        entry_point: Some("vs_main"),
                        compilation_options: Default::default(),
                        buffers: &[],
                    },
                    primitive: Default::default(),
                    depth_stencil: None,
                    multisample: Default::default(),
                    fragment: Some(wgpu::FragmentState {
                        module: &self.module,
                        entry_point: Some(if format.is_srgb() { "fs_main" } else { "fs_encode" }),
                        compilation_options: Default::default(),
                        targets: &[Some(wgpu::ColorTargetState {
                            format,
                            blend: None,
                            write_mask: wgpu::ColorWrites::ALL,
                        })],
                    }),
                    multiview_mask: None,
                    cache: None,
                });
                self.pipelines.push((format, pipeline));
                self.pipelines.len() - 1
            }
        };
        &self.pipelines[i].1
    }

    /// Draws `radiance` tone-mapped onto `color` (of `format` and the same size).
    pub fn draw(
        &mut self,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        radiance: &RadianceTarget,
        format: wgpu::TextureFormat,
        color: &wgpu::TextureView,
    ) {
        let pipeline = self.pipeline(gpu, format);
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("tone map"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: color,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations { load: wgpu::LoadOp::Clear(wgpu::Color::BLACK), store: wgpu::StoreOp::Store },
            })],
            depth_stencil_attachment: None,
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &radiance.bind_group, &[]);
        pass.draw(0..3, 0..1);
    }
}
