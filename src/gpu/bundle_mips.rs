//! The analysis maps of one direction on the GPU and their mip passes (`bundle::mips` in
//! compute): the importance map max-reduced, the fragment-count map average-reduced with the
//! CPU's summation order `((a + b) + (c + d)) / 4`, so equal level-0 maps give bit-equal
//! chains (f32 adds and the power-of-two scale are correctly rounded in Vulkan).
//!
//! Each chain is one buffer of f32 bits, level 0 first, then each coarser level down to 1×1.
//! The analysis pass writes level 0 (importance bits and u32 fragment counts); `finest`
//! turns the counts into f32 in place and `reduce` runs once per level.

use wgpu::util::DeviceExt;

use super::GpuError;
use super::bundle_analysis::analysis_target;
use super::device::GpuContext;
use super::layout::MipLevel;
use super::shader;

/// Element offset of each level of an R×R chain, and the total length.
pub fn level_offsets(side: u32) -> (Vec<u32>, u32) {
    let mut offsets = Vec::new();
    let mut offset = 0;
    let mut s = side;
    loop {
        offsets.push(offset);
        offset += s * s;
        if s == 1 {
            return (offsets, offset);
        }
        s /= 2;
    }
}

/// Bytes between the per-level uniforms (dynamic offsets need 256 on most devices).
const LEVEL_STRIDE: u64 = 256;

/// One direction's R×R analysis maps with their chains, and the raster's attachment.
pub struct AnalysisMaps {
    side: u32,
    offsets: Vec<u32>,
    len: u32,
    pub importance: wgpu::Buffer,
    pub fragments: wgpu::Buffer,
    pub(super) target: wgpu::TextureView,
    levels: wgpu::Buffer,
    group: Option<wgpu::BindGroup>,
}

impl AnalysisMaps {
    /// Maps of side `side` (a power of two).
    pub fn new(gpu: &GpuContext, side: u32) -> Result<AnalysisMaps, GpuError> {
        if !side.is_power_of_two() {
            return Err(GpuError::Validation(format!("analysis side {side} is not a power of two")));
        }
        let device = &gpu.device;
        let (offsets, len) = level_offsets(side);
        let bytes = 4 * len as u64;
        if bytes > device.limits().max_storage_buffer_binding_size {
            return Err(GpuError::Validation(format!(
                "a {side}×{side} analysis chain exceeds the storage binding limit"
            )));
        }
        let map = |label| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            })
        };
        let importance = map("bundle importance mips");
        let fragments = map("bundle fragment mips");
        // Uniform slot 0: `finest` (level 0 in place); slot k ≥ 1: level k−1 → k.
        let mut slots = vec![0u8; LEVEL_STRIDE as usize * offsets.len()];
        for (k, slot) in slots.chunks_mut(LEVEL_STRIDE as usize).enumerate() {
            let level = if k == 0 {
                MipLevel { src: 0, dst: 0, dst_side: side, _pad: 0 }
            } else {
                MipLevel { src: offsets[k - 1], dst: offsets[k], dst_side: side >> k, _pad: 0 }
            };
            slot[..size_of::<MipLevel>()].copy_from_slice(bytemuck::bytes_of(&level));
        }
        let levels = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("bundle mip levels"),
            contents: &slots,
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let target = analysis_target(gpu, side);
        Ok(AnalysisMaps { side, offsets, len, importance, fragments, target, levels, group: None })
    }

    /// R.
    pub fn side(&self) -> u32 {
        self.side
    }

    /// L = log2 R.
    pub fn top_level(&self) -> u32 {
        self.side.trailing_zeros()
    }

    /// Element offset of each level.
    pub fn offsets(&self) -> &[u32] {
        &self.offsets
    }

    /// Writes level 0 of both maps from the host (f32 values; the fragment map as f32, so run
    /// the mips without `finest`): how the planner is tested on hand-made maps.
    pub fn upload_finest(&self, gpu: &GpuContext, importance: &[f32], fragments: &[f32]) {
        let n = (self.side * self.side) as usize;
        assert!(importance.len() == n && fragments.len() == n, "level 0 is {n} values");
        gpu.queue.write_buffer(&self.importance, 0, bytemuck::cast_slice(importance));
        gpu.queue.write_buffer(&self.fragments, 0, bytemuck::cast_slice(fragments));
    }

    /// Reads both chains back, level by level: (importance, fragments).
    #[allow(clippy::type_complexity)]
    pub fn read(&self, gpu: &GpuContext) -> Result<(Vec<Vec<f32>>, Vec<Vec<f32>>), GpuError> {
        let bytes = 4 * self.len as u64;
        let staging = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bundle mips read-back"),
            size: 2 * bytes,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(&self.importance, 0, &staging, 0, bytes);
        encoder.copy_buffer_to_buffer(&self.fragments, 0, &staging, bytes, bytes);
        gpu.queue.submit([encoder.finish()]);
        let data = gpu.read_buffer(&staging, 2 * bytes)?;
        let values: &[f32] = bytemuck::cast_slice(&data);
        let split = |chain: &[f32]| -> Vec<Vec<f32>> {
            self.offsets
                .iter()
                .enumerate()
                .map(|(k, &o)| {
                    let s = (self.side >> k) as usize;
                    chain[o as usize..o as usize + s * s].to_vec()
                })
                .collect()
        };
        let (i, f) = values.split_at(self.len as usize);
        Ok((split(i), split(f)))
    }
}

/// The mip pipelines.
pub struct MipPass {
    layout: wgpu::BindGroupLayout,
    finest: wgpu::ComputePipeline,
    reduce: wgpu::ComputePipeline,
}

impl MipPass {
    pub fn new(gpu: &GpuContext) -> Result<MipPass, GpuError> {
        let device = &gpu.device;
        let entry = |binding, ty, dynamic| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty,
                has_dynamic_offset: dynamic,
                min_binding_size: (binding == 0).then(|| wgpu::BufferSize::new(size_of::<MipLevel>() as u64)).flatten(),
            },
            count: None,
        };
        let storage = wgpu::BufferBindingType::Storage { read_only: false };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("bundle mips"),
            entries: &[
                entry(0, wgpu::BufferBindingType::Uniform, true),
                entry(1, storage, false),
                entry(2, storage, false),
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("bundle mips"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let module = shader::module(device, "bundle_mips.wgsl")?;
        let pipeline = |entry| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        let (finest, reduce) = (pipeline("finest"), pipeline("reduce"));
        gpu.take_error()?;
        Ok(MipPass { layout, finest, reduce })
    }

    /// The bind group of `maps` (made once per maps).
    fn group<'m>(&self, gpu: &GpuContext, maps: &'m mut AnalysisMaps) -> &'m wgpu::BindGroup {
        maps.group.get_or_insert_with(|| {
            gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("bundle mips"),
                layout: &self.layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                            buffer: &maps.levels,
                            offset: 0,
                            size: wgpu::BufferSize::new(size_of::<MipLevel>() as u64),
                        }),
                    },
                    wgpu::BindGroupEntry { binding: 1, resource: maps.importance.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 2, resource: maps.fragments.as_entire_binding() },
                ],
            })
        })
    }

    /// Records the chains of `maps` from their level 0; `from_counts`: level 0 of the
    /// fragment map holds the analysis pass's u32 counts (converted first).
    pub fn encode(
        &self,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        maps: &mut AnalysisMaps,
        from_counts: bool,
    ) {
        let side = maps.side;
        let levels = maps.offsets.len();
        let group = self.group(gpu, maps).clone();
        let mut pass = encoder
            .begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("bundle mips"), timestamp_writes: None });
        let groups = |s: u32| s.div_ceil(8);
        if from_counts {
            pass.set_pipeline(&self.finest);
            pass.set_bind_group(0, &group, &[0]);
            pass.dispatch_workgroups(groups(side), groups(side), 1);
        }
        pass.set_pipeline(&self.reduce);
        for k in 1..levels {
            pass.set_bind_group(0, &group, &[(k as u64 * LEVEL_STRIDE) as u32]);
            pass.dispatch_workgroups(groups(side >> k), groups(side >> k), 1);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bundle::mips::MipChain;
    use crate::sampling::Rng;

    #[test]
    fn level_offsets_stack_the_levels() {
        assert_eq!(level_offsets(1), (vec![0], 1));
        assert_eq!(level_offsets(4), (vec![0, 16, 20], 21));
        assert_eq!(level_offsets(8).1, 64 + 16 + 4 + 1);
    }

    /// Random level-0 maps (importance over six decades with zeros, fragment counts and
    /// fractional values) give exactly the CPU's `MipChain`s, at every side from 1 to 512;
    /// fragment counts written as u32 (as the analysis leaves them) too.
    #[test]
    fn gpu_mips_equal_the_cpu_chains() {
        let gpu = GpuContext::headless().expect("a Vulkan adapter (lavapipe: mesa-vulkan-drivers)");
        let pass = MipPass::new(&gpu).unwrap();
        let mut rng = Rng::new(5, 5);
        for side in [1u32, 2, 4, 16, 64, 512] {
            let n = (side * side) as usize;
            let importance: Vec<f32> = (0..n)
                .map(|_| if rng.next_f32() < 0.3 { 0.0 } else { 10f32.powf(rng.next_f32() * 6.0 - 3.0) })
                .collect();
            let counts: Vec<u32> = (0..n).map(|_| rng.next_u32() % 50).collect();
            let fractional: Vec<f32> = (0..n).map(|_| rng.next_f32() * 1000.0).collect();
            for (fragments, from_counts) in
                [(counts.iter().map(|&c| c as f32).collect::<Vec<_>>(), true), (fractional, false)]
            {
                let mut maps = AnalysisMaps::new(&gpu, side).unwrap();
                if from_counts {
                    gpu.queue.write_buffer(&maps.importance, 0, bytemuck::cast_slice(&importance));
                    gpu.queue.write_buffer(&maps.fragments, 0, bytemuck::cast_slice(&counts));
                } else {
                    maps.upload_finest(&gpu, &importance, &fragments);
                }
                let mut encoder = gpu.device.create_command_encoder(&Default::default());
                pass.encode(&gpu, &mut encoder, &mut maps, from_counts);
                gpu.queue.submit([encoder.finish()]);
                let (gi, gf) = maps.read(&gpu).unwrap();
                gpu.take_error().unwrap();
                let ci = MipChain::max_mips(side, importance.clone()).unwrap();
                let cf = MipChain::average_mips(side, fragments).unwrap();
                for l in 0..=ci.top_level() {
                    assert_eq!(ci.level(l), &gi[l as usize][..], "side {side} importance level {l}");
                    assert_eq!(cf.level(l), &gf[l as usize][..], "side {side} fragments level {l} ({from_counts})");
                }
            }
        }
    }
}
