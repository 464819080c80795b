//! The surface pass: every scene triangle, depth-tested, shaded as albedo × E/π + emission
//! (or a debug view), into one or two viewports (stereo).

use super::device::GpuContext;
use super::layout::{FrameUniforms, SurfaceVertex};
use super::lightmap::LightmapGpu;
use super::scene::SceneGpu;
use super::shader::{self, ShaderError};

pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// One view drawn in a frame: its uniforms and its viewport (x, y, width, height in pixels).
#[derive(Clone, Copy, Debug)]
pub struct EyeView {
    pub frame: FrameUniforms,
    pub viewport: [f32; 4],
}

pub struct SurfacePass {
    /// Per `[cut out][double-sided]`: `fs_main` or `fs_cut_out`, back faces culled or not.
    pipelines: [[wgpu::RenderPipeline; 2]; 2],
    /// One uniform buffer and bind group per eye (at most two).
    eyes: Vec<(wgpu::Buffer, wgpu::BindGroup)>,
    pub color_format: wgpu::TextureFormat,
}

impl SurfacePass {
    pub fn new(
        gpu: &GpuContext,
        color_format: wgpu::TextureFormat,
        lightmap_layout: &wgpu::BindGroupLayout,
        material_layout: &wgpu::BindGroupLayout,
    ) -> Result<SurfacePass, ShaderError> {
        let device = &gpu.device;
        let frame_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("frame"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX | wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            }],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("surface"),
            bind_group_layouts: &[Some(&frame_layout), Some(lightmap_layout), Some(material_layout)],
            immediate_size: 0,
        });
        let module = shader::module(device, "surface.wgsl")?;
        let pipeline = |entry_point: &str, cull_mode| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some("surface"),
                layout: Some(&layout),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some("vs_main"),
                    compilation_options: Default::default(),
                    buffers: &[Some(SurfaceVertex::buffer_layout())],
                },
                primitive: wgpu::PrimitiveState {
                    topology: wgpu::PrimitiveTopology::TriangleList,
                    front_face: wgpu::FrontFace::Ccw,
                    cull_mode,
                    ..Default::default()
                },
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: DEPTH_FORMAT,
                    depth_write_enabled: Some(true),
                    depth_compare: Some(wgpu::CompareFunction::Less),
                    stencil: Default::default(),
                    bias: Default::default(),
                }),
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some(entry_point),
                    compilation_options: Default::default(),
                    targets: &[Some(wgpu::ColorTargetState {
                        format: color_format,
                        blend: None,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let eyes = (0..2)
            .map(|_| {
                let buffer = device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("frame uniforms"),
                    size: size_of::<FrameUniforms>() as u64,
                    usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                });
                let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("frame"),
                    layout: &frame_layout,
                    entries: &[wgpu::BindGroupEntry { binding: 0, resource: buffer.as_entire_binding() }],
                });
                (buffer, group)
            })
            .collect();
        let pipelines =
            ["fs_main", "fs_cut_out"].map(|entry| [pipeline(entry, Some(wgpu::Face::Back)), pipeline(entry, None)]);
        Ok(SurfacePass { pipelines, eyes, color_format })
    }

    /// Clears `color` and `depth` and draws `scene` once per eye (one or two).
    #[allow(clippy::too_many_arguments)]
    pub fn draw(
        &self,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        color: &wgpu::TextureView,
        depth: &wgpu::TextureView,
        scene: &SceneGpu,
        lightmap: &LightmapGpu,
        eyes: &[EyeView],
    ) {
        for (view, (buffer, _)) in eyes.iter().zip(&self.eyes) {
            gpu.queue.write_buffer(buffer, 0, bytemuck::bytes_of(&view.frame));
        }
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("surface"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: color,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color { r: 0.02, g: 0.02, b: 0.025, a: 1.0 }),
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: depth,
                depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(1.0), store: wgpu::StoreOp::Store }),
                stencil_ops: None,
            }),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_vertex_buffer(0, scene.vertex_buffer.slice(..));
        pass.set_bind_group(1, lightmap.bind_group(), &[]);
        for (view, (_, group)) in eyes.iter().zip(&self.eyes) {
            let [x, y, w, h] = view.viewport;
            pass.set_viewport(x, y, w, h, 0.0, 1.0);
            pass.set_bind_group(0, group, &[]);
            for batch in &scene.batches {
                pass.set_pipeline(&self.pipelines[batch.cut_out as usize][batch.double_sided as usize]);
                pass.set_bind_group(2, &batch.bind_group, &[]);
                pass.draw(batch.vertices.clone(), 0..1);
            }
        }
    }
}
