//! The surface pass: every scene triangle, depth-tested, shaded as albedo × E/π + emission
//! (or a debug view), into one or two viewports (stereo). A scene with see-through sheets is
//! drawn into a linear HDR target ([`RADIANCE_FORMAT`]; [`super::tone_map`] puts it on screen),
//! the sheets last, farthest first, each composited over what lies behind it; any other
//! scene straight onto the screen's format, tone-mapped in the shader (one pass, no HDR
//! target to write and read: ~20 ms of a 60–90 ms frame on lavapipe).

use super::device::GpuContext;
use super::layout::{FrameUniforms, SurfaceVertex};
use super::lightmap::LightmapGpu;
use super::scene::{Batch, SceneGpu};
use super::shader::{self, ShaderError};
use super::sky::SkyGpu;
use crate::output::{srgb_encode, tone_curve};
use glam::Vec3;

pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// The surface pass's target: exposed linear radiance, composited before the tone curve.
pub const RADIANCE_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;

/// One view drawn in a frame: its uniforms and its viewport (x, y, width, height in pixels).
#[derive(Clone, Copy, Debug)]
pub struct EyeView {
    pub frame: FrameUniforms,
    pub viewport: [f32; 4],
}

pub struct SurfacePass {
    /// Per `[cut out][double-sided]`: `fs_main` or `fs_cut_out`, back faces culled or not.
    pipelines: [[wgpu::RenderPipeline; 2]; 2],
    /// Into the HDR target only: per `[double-sided]`, a sheet's two draws,
    /// `fs_sheet_filter` (what lies behind × the light it lets through) then `fs_sheet_light`
    /// (plus its own). Without them (a pass drawing on screen) sheets are drawn opaque, which
    /// [`Renderer`](crate::viewer::Renderer) never asks for.
    sheet_pipelines: Option<[[wgpu::RenderPipeline; 2]; 2]>,
    /// `vs_sky`/`fs_sky`: the sky where no surface is, after the opaque surfaces.
    sky_pipeline: wgpu::RenderPipeline,
    /// One uniform buffer and bind group per eye (at most two).
    eyes: Vec<(wgpu::Buffer, wgpu::BindGroup)>,
    pub color_format: wgpu::TextureFormat,
    /// surface.wgsl's `OUTPUT` for this format.
    output: Output,
}

/// What the pass writes (surface.wgsl's `OUTPUT`).
#[derive(Clone, Copy, Debug, PartialEq)]
enum Output {
    /// Exposed linear radiance (the HDR target).
    Radiance = 0,
    /// The tone-mapped colour, which an sRGB target encodes.
    Toned = 1,
    /// The tone-mapped colour sRGB-encoded (any other target).
    Encoded = 2,
}

impl SurfacePass {
    /// A pass drawing to `color_format`: [`RADIANCE_FORMAT`] (exposed radiance, sheets
    /// composited) or a screen's format (tone-mapped; encoded in the shader unless sRGB).
    /// `layouts`: groups 1–3 of surface.wgsl (light map, material, sky).
    pub fn new(
        gpu: &GpuContext,
        color_format: wgpu::TextureFormat,
        [lightmap_layout, material_layout, sky_layout]: [&wgpu::BindGroupLayout; 3],
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
        let sky_pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("sky"),
            bind_group_layouts: &[Some(&frame_layout), None, None, Some(sky_layout)],
            immediate_size: 0,
        });
        let module = shader::module(device, "surface.wgsl")?;
        let hdr = color_format == RADIANCE_FORMAT;
        let output = if hdr {
            Output::Radiance
        } else if color_format.is_srgb() {
            Output::Toned
        } else {
            Output::Encoded
        };
        let constants = [("OUTPUT", output as u32 as f64)];
        // Sheets test depth but do not write it: what lies behind another sheet stays drawable.
        let pipeline = |entry_point: &str, cull_mode, blend: Option<wgpu::BlendState>| {
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
                    depth_write_enabled: Some(blend.is_none()),
                    depth_compare: Some(wgpu::CompareFunction::Less),
                    stencil: Default::default(),
                    bias: Default::default(),
                }),
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some(entry_point),
                    compilation_options: wgpu::PipelineCompilationOptions {
                        constants: &constants,
                        ..Default::default()
                    },
                    targets: &[Some(wgpu::ColorTargetState {
                        format: color_format,
                        blend,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let sky_pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("sky"),
            layout: Some(&sky_pipeline_layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_sky"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: Default::default(),
            // At the far plane, where the depth buffer was cleared: ≤ passes only where no
            // surface was drawn.
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(false),
                depth_compare: Some(wgpu::CompareFunction::LessEqual),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_sky"),
                compilation_options: wgpu::PipelineCompilationOptions { constants: &constants, ..Default::default() },
                targets: &[Some(wgpu::ColorTargetState {
                    format: color_format,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        });
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
        let sides = |entry: &str, blend| [pipeline(entry, Some(wgpu::Face::Back), blend), pipeline(entry, None, blend)];
        let pipelines = ["fs_main", "fs_cut_out"].map(|entry| sides(entry, None));
        let blend = |src_factor, dst_factor| {
            let component = wgpu::BlendComponent { src_factor, dst_factor, operation: wgpu::BlendOperation::Add };
            Some(wgpu::BlendState { color: component, alpha: component })
        };
        let sheet_pipelines = hdr.then(|| {
            [
                sides("fs_sheet_filter", blend(wgpu::BlendFactor::Zero, wgpu::BlendFactor::Src)),
                sides("fs_sheet_light", blend(wgpu::BlendFactor::One, wgpu::BlendFactor::One)),
            ]
        });
        Ok(SurfacePass { pipelines, sheet_pipelines, sky_pipeline, eyes, color_format, output })
    }

    /// What the colour target is cleared to: a uniform sky as `fs_sky` would draw it, else
    /// the backdrop (a picture sky is then drawn over it).
    fn clear_colour(&self, scene: &SceneGpu, eyes: &[EyeView]) -> wgpu::Color {
        let exposure = eyes.first().map_or(1.0, |e| e.frame.exposure);
        let colour = |c: [f32; 3]| wgpu::Color { r: c[0] as f64, g: c[1] as f64, b: c[2] as f64, a: 1.0 };
        match (&scene.sky, self.output) {
            (Some(SkyGpu::Uniform(l)), output) => colour((*l * exposure).to_array().map(|v| match output {
                Output::Radiance => v,
                Output::Toned => tone_curve(v),
                Output::Encoded => srgb_encode(tone_curve(v)),
            })),
            (_, Output::Radiance) => BACKDROP_RADIANCE,
            _ => BACKDROP,
        }
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
                    load: wgpu::LoadOp::Clear(self.clear_colour(scene, eyes)),
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
            for batch in scene.batches.iter().filter(|b| !b.sheet || self.sheet_pipelines.is_none()) {
                pass.set_pipeline(&self.pipelines[batch.cut_out as usize][batch.double_sided as usize]);
                pass.set_bind_group(2, &batch.bind_group, &[]);
                pass.draw(batch.vertices.clone(), 0..1);
            }
            if let Some(SkyGpu::Picture(sky)) = &scene.sky {
                pass.set_pipeline(&self.sky_pipeline);
                pass.set_bind_group(3, sky, &[]);
                pass.draw(0..3, 0..1);
                pass.set_bind_group(1, lightmap.bind_group(), &[]);
            }
            let Some(sheet_pipelines) = &self.sheet_pipelines else { continue };
            for batch in sheets_farthest_first(&scene.batches, Vec3::from_array(view.frame.eye)) {
                pass.set_bind_group(2, &batch.bind_group, &[]);
                for pipelines in sheet_pipelines {
                    pass.set_pipeline(&pipelines[batch.double_sided as usize]);
                    pass.draw(batch.vertices.clone(), 0..1);
                }
            }
        }
    }
}

/// The backdrop where no surface is: a dark grey, written as is by a pass drawing on screen.
const BACKDROP: wgpu::Color = wgpu::Color { r: 0.02, g: 0.02, b: 0.025, a: 1.0 };
/// The same in the HDR target: the exposed radiance the tone curve turns into it.
const BACKDROP_RADIANCE: wgpu::Color = wgpu::Color { r: 0.020_203, g: 0.020_203, b: 0.025_318, a: 1.0 };

/// The see-through batches in drawing order: the farthest from `eye` (by the centre of its
/// box) first. Each sheet's draw scales what is behind it, so the nearer must come later.
/// Sheets of one material are one batch, drawn in one go: where two of them overlap on
/// screen the far one's own light is not dimmed by the near one's filter, an error of the
/// far sheet's reflected light times the near one's opacity (nothing for clear glass).
pub fn sheets_farthest_first(batches: &[Batch], eye: Vec3) -> Vec<&Batch> {
    let mut sheets: Vec<&Batch> = batches.iter().filter(|b| b.sheet).collect();
    sheets.sort_by(|a, b| eye.distance_squared(b.centre).total_cmp(&eye.distance_squared(a.centre)));
    sheets
}
