//! A compute pass that evaluates the shown light map's WGSL sampling function
//! (`shown_irradiance`) at given points and reads the results back: how tests hold the GPU
//! twin equal to the CPU's `ShownLightmap::irradiance`, and a way to inspect the GPU mirror.

use glam::{Vec2, Vec3};
use wgpu::util::DeviceExt;

use super::GpuError;
use super::device::GpuContext;
use super::layout::ProbePoint;
use super::lightmap::LightmapGpu;
use super::shader;

pub struct IrradianceProbe {
    pipeline: wgpu::ComputePipeline,
    points_layout: wgpu::BindGroupLayout,
}

impl IrradianceProbe {
    pub fn new(gpu: &GpuContext, lightmap_layout: &wgpu::BindGroupLayout) -> Result<IrradianceProbe, GpuError> {
        let device = &gpu.device;
        let storage = |binding, read_only| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let points_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("probe points"),
            entries: &[storage(0, true), storage(1, false)],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("irradiance probe"),
            bind_group_layouts: &[Some(&points_layout), Some(lightmap_layout)],
            immediate_size: 0,
        });
        let module = shader::module(device, "irradiance_probe.wgsl")?;
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("irradiance probe"),
            layout: Some(&layout),
            module: &module,
            entry_point: Some("cs_main"),
            compilation_options: Default::default(),
            cache: None,
        });
        Ok(IrradianceProbe { pipeline, points_layout })
    }

    /// `shown_irradiance(p, uv)` on the GPU for each `(p, uv)`.
    pub fn run(
        &self,
        gpu: &GpuContext,
        lightmap: &LightmapGpu,
        points: &[(Vec3, Vec2)],
    ) -> Result<Vec<Vec3>, GpuError> {
        if points.is_empty() {
            return Ok(Vec::new());
        }
        let device = &gpu.device;
        let input: Vec<ProbePoint> = points
            .iter()
            .map(|(p, uv)| ProbePoint { position: p.to_array(), _pad0: 0.0, uv: uv.to_array(), _pad1: [0.0; 2] })
            .collect();
        let points_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("probe points"),
            contents: bytemuck::cast_slice(&input),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let size = 16 * points.len() as u64;
        let results = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("probe results"),
            size,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("probe read-back"),
            size,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("probe points"),
            layout: &self.points_layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: points_buffer.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: results.as_entire_binding() },
            ],
        });
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("probe") });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &group, &[]);
            pass.set_bind_group(1, lightmap.bind_group(), &[]);
            pass.dispatch_workgroups((points.len() as u32).div_ceil(64), 1, 1);
        }
        encoder.copy_buffer_to_buffer(&results, 0, &readback, 0, size);
        gpu.queue.submit([encoder.finish()]);
        let bytes = gpu.read_buffer(&readback, size)?;
        gpu.take_error()?;
        Ok(bytemuck::cast_slice::<u8, [f32; 4]>(&bytes).iter().map(|v| Vec3::new(v[0], v[1], v[2])).collect())
    }
}
