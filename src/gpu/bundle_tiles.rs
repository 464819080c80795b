//! Tile subdivision on the GPU: Program 1 (Tokuyoshi et al. 2013, Appendix A) in one compute
//! pass over the analysis chains of [`super::bundle_mips`], appending tiles with an atomic
//! counter. The twin of `bundle::tiles::TilePlanner` in adaptive mode: same tiles (after
//! sorting by Morton key), same split and undersampling counts.
//!
//! On a device with `SHADER_F64` (lavapipe has it) the pass decides in f64 like the CPU
//! planner, so the plans are equal bit for bit; without it the pass runs in f32 and can only
//! differ where C_I and C_max (Eq. 1, Eq. 3) are within f32 rounding of each other.

use wgpu::util::DeviceExt;

use super::GpuError;
use super::bundle_mips::AnalysisMaps;
use super::device::GpuContext;
use super::layout::{PlannedTile, TilePassParams};
use super::pass::{self, READ, UNIFORM, WRITE};
use super::shader;
use crate::bundle::tiles::{PlanStats, Tile, TileParams, TilePlan};

/// Counters of the pass: tiles, splits for importance, splits for memory, undersampled.
const COUNTERS: u64 = 4;

/// The Program 1 pipeline.
pub struct TilePass {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
    f64: bool,
}

/// Where one direction's plan lands on the GPU.
pub struct TileBuffers {
    pub tiles: wgpu::Buffer,
    /// [tiles, splits for importance, splits for memory, undersampled].
    pub counters: wgpu::Buffer,
    pub capacity: u32,
    params: wgpu::Buffer,
    reals: wgpu::Buffer,
    f64: bool,
}

impl TilePass {
    pub fn new(gpu: &GpuContext) -> Result<TilePass, GpuError> {
        let device = &gpu.device;
        let f64 = gpu.has_f64();
        let c = wgpu::ShaderStages::COMPUTE;
        let layout = pass::buffer_layout(
            device,
            "bundle tiles",
            &[(c, UNIFORM), (c, READ), (c, READ), (c, READ), (c, WRITE), (c, WRITE)],
        );
        let pipeline_layout = pass::single_group(device, "bundle tiles", &layout);
        let name = "bundle_tiles.wgsl";
        let text = if f64 { shader::source_f64(name)? } else { shader::source(name)? };
        let module = shader::module_from(device, name, text);
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("bundle tiles"),
            layout: Some(&pipeline_layout),
            module: &module,
            entry_point: Some("plan"),
            compilation_options: Default::default(),
            cache: None,
        });
        gpu.take_error()?;
        Ok(TilePass { layout, pipeline, f64 })
    }

    /// Whether the pass decides in f64 (bit-equal to the CPU planner).
    pub fn is_f64(&self) -> bool {
        self.f64
    }

    /// Buffers for the plans of `side`×`side` analysis maps: room for one tile per finest
    /// pixel (the most Program 1 can emit), within the storage binding limit.
    pub fn buffers(&self, gpu: &GpuContext, side: u32) -> TileBuffers {
        let device = &gpu.device;
        let limit = device.limits().max_storage_buffer_binding_size / size_of::<PlannedTile>() as u64;
        let capacity = ((side as u64 * side as u64).min(limit)) as u32;
        let tiles = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bundle tiles"),
            size: capacity as u64 * size_of::<PlannedTile>() as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let counters = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bundle tile counters"),
            size: 4 * COUNTERS,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let params = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bundle tile params"),
            size: size_of::<TilePassParams>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let reals = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("bundle tile reals"),
            contents: &[0u8; 24],
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        });
        TileBuffers { tiles, counters, capacity, params, reals, f64: self.f64 }
    }

    /// Records Program 1 over `maps` (their chains complete) into `out` with buffer sizes
    /// `params`. The parameters are written through the queue: one plan per buffer set per
    /// submission.
    pub fn encode(
        &self,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        maps: &AnalysisMaps,
        params: &TileParams,
        out: &TileBuffers,
    ) {
        let side = maps.side();
        let uniform = TilePassParams { side, top_level: maps.top_level(), capacity: out.capacity, _pad: 0 };
        gpu.queue.write_buffer(&out.params, 0, bytemuck::bytes_of(&uniform));
        let reals = [params.pixel_area, params.node_budget(), params.head_buffer_pixels()];
        if out.f64 {
            gpu.queue.write_buffer(&out.reals, 0, bytemuck::cast_slice(&reals));
        } else {
            gpu.queue.write_buffer(&out.reals, 0, bytemuck::cast_slice(&reals.map(|r| r as f32)));
        }
        let group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("bundle tiles"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: out.params.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: out.reals.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 2, resource: maps.importance.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 3, resource: maps.fragments.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 4, resource: out.tiles.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 5, resource: out.counters.as_entire_binding() },
            ],
        });
        encoder.clear_buffer(&out.counters, 0, None);
        let mut pass = encoder
            .begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("bundle tiles"), timestamp_writes: None });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &group, &[]);
        pass.dispatch_workgroups(side.div_ceil(8), side.div_ceil(8), 1);
    }
}

impl TileBuffers {
    /// Reads the plan back, tiles in Morton order (as `TilePlanner` returns them).
    pub fn read(&self, gpu: &GpuContext) -> Result<TilePlan, GpuError> {
        read_plans(gpu, &[self])?.pop().expect("one plan read")
    }
}

/// Reads back the plans of several directions planned in one submission: their counters in
/// one copy and one wait, then their tiles in another (Morton order, as `TilePlanner`
/// returns them). A plan that overran its buffer is an error of its own.
pub fn read_plans(gpu: &GpuContext, plans: &[&TileBuffers]) -> Result<Vec<Result<TilePlan, GpuError>>, GpuError> {
    let device = &gpu.device;
    let staging = |label, size: u64| {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: size.max(4),
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        })
    };
    let counter_bytes = 4 * COUNTERS;
    let all_counters = staging("bundle counters read-back", counter_bytes * plans.len() as u64);
    let mut encoder = device.create_command_encoder(&Default::default());
    for (i, plan) in plans.iter().enumerate() {
        encoder.copy_buffer_to_buffer(&plan.counters, 0, &all_counters, i as u64 * counter_bytes, counter_bytes);
    }
    gpu.queue.submit([encoder.finish()]);
    let bytes = gpu.read_buffer(&all_counters, counter_bytes * plans.len() as u64)?;
    let words: Vec<u32> = bytes.chunks_exact(4).map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]])).collect();
    let counters: Vec<&[u32]> = words.chunks_exact(COUNTERS as usize).collect();
    // Where each plan's tiles go in one staging buffer (none for an overrun or empty plan).
    let tile_bytes = size_of::<PlannedTile>() as u64;
    let mut offsets = Vec::with_capacity(plans.len());
    let mut total = 0u64;
    for (plan, c) in plans.iter().zip(&counters) {
        offsets.push(total);
        if c[0] <= plan.capacity {
            total += c[0] as u64 * tile_bytes;
        }
    }
    let mut data = Vec::new();
    if total > 0 {
        let all_tiles = staging("bundle tiles read-back", total);
        let mut encoder = device.create_command_encoder(&Default::default());
        for ((plan, c), &offset) in plans.iter().zip(&counters).zip(&offsets) {
            if c[0] <= plan.capacity && c[0] > 0 {
                encoder.copy_buffer_to_buffer(&plan.tiles, 0, &all_tiles, offset, c[0] as u64 * tile_bytes);
            }
        }
        gpu.queue.submit([encoder.finish()]);
        data = gpu.read_buffer(&all_tiles, total)?;
    }
    Ok(plans
        .iter()
        .zip(&counters)
        .zip(&offsets)
        .map(|((plan, c), &offset)| {
            let count = c[0];
            if count > plan.capacity {
                return Err(GpuError::Validation(format!("{count} tiles planned for a buffer of {}", plan.capacity)));
            }
            let bytes = &data[offset as usize..(offset + count as u64 * tile_bytes) as usize];
            let mut tiles: Vec<Tile> = bytes
                .chunks_exact(tile_bytes as usize)
                .map(|t| {
                    let t: PlannedTile = bytemuck::pod_read_unaligned(t);
                    Tile { level: t.level as i32, x: t.x, y: t.y, res: t.res }
                })
                .collect();
            tiles.sort_by_key(Tile::morton_key);
            let stats = PlanStats {
                tiles: tiles.len(),
                splits_for_importance: c[1] as usize,
                splits_for_memory: c[2] as usize,
                undersampled_tiles: c[3] as usize,
            };
            Ok(TilePlan { tiles, stats })
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bundle::mips::MipChain;
    use crate::bundle::tiles::{DEFAULT_ALPHA, TilePlanner, TilingMode};
    use crate::gpu::bundle_mips::MipPass;
    use crate::sampling::Rng;

    struct Gpu {
        gpu: GpuContext,
        mips: MipPass,
        tiles: TilePass,
    }

    impl Gpu {
        fn new() -> Gpu {
            let gpu = GpuContext::headless().expect("a Vulkan adapter (lavapipe: mesa-vulkan-drivers)");
            let (mips, tiles) = (MipPass::new(&gpu).unwrap(), TilePass::new(&gpu).unwrap());
            Gpu { gpu, mips, tiles }
        }

        /// GPU mips then GPU Program 1 of level-0 maps.
        fn plan(&self, side: u32, importance: &[f32], fragments: &[f32], params: &TileParams) -> TilePlan {
            let gpu = &self.gpu;
            let mut maps = AnalysisMaps::new(gpu, side).unwrap();
            maps.upload_finest(gpu, importance, fragments);
            let out = self.tiles.buffers(gpu, side);
            let mut encoder = gpu.device.create_command_encoder(&Default::default());
            self.mips.encode(gpu, &mut encoder, &mut maps, false);
            self.tiles.encode(gpu, &mut encoder, &maps, params, &out);
            gpu.queue.submit([encoder.finish()]);
            let plan = out.read(gpu).unwrap();
            gpu.take_error().unwrap();
            plan
        }

        /// Asserts the GPU plan equals the CPU planner's (both of its walks) and returns it.
        fn check(
            &self,
            side: u32,
            importance: Vec<f32>,
            fragments: Vec<f32>,
            params: TileParams,
            case: &str,
        ) -> TilePlan {
            let gpu = self.plan(side, &importance, &fragments, &params);
            let i = MipChain::max_mips(side, importance).unwrap();
            let f = MipChain::average_mips(side, fragments).unwrap();
            let planner = TilePlanner::new(&i, &f, params).unwrap();
            let cpu = planner.plan(TilingMode::Adaptive).unwrap();
            assert_eq!(cpu, planner.plan_adaptive_per_pixel(), "{case}");
            assert_eq!(gpu, cpu, "{case}");
            gpu
        }
    }

    fn tile(level: i32, x: u32, y: u32, res: u32) -> Tile {
        Tile { level, x, y, res }
    }

    fn exact(w: u32, n: u64, pixel_area: f64) -> TileParams {
        TileParams { alpha: 1.0, ..TileParams::new(w, n, pixel_area) }
    }

    /// The planner's hand-made cases (bundle::tiles tests), on the GPU.
    #[test]
    fn program_1_on_the_gpu_plans_the_hand_made_maps() {
        let g = Gpu::new();
        assert!(g.tiles.is_f64(), "lavapipe offers SHADER_F64; the exact twin needs it");
        // Importance beyond the head buffer splits.
        let p = g.check(2, vec![4.0, 1.0, 0.0, 0.25], vec![1.0; 4], exact(2, 1 << 40, 1.0), "importance split");
        assert_eq!(p.tiles, [tile(0, 0, 0, 2), tile(0, 1, 0, 1), tile(0, 1, 1, 1)]);
        assert_eq!(p.stats.splits_for_importance, 1);
        // Exactly at the bound: emitted.
        let p = g.check(2, vec![1.0; 4], vec![1.0; 4], exact(2, 1 << 20, 1.0), "at the bound");
        assert_eq!(p.tiles, [tile(1, 0, 0, 2)]);
        // Both bounds equal: counted for importance.
        let p = g.check(2, vec![3.0; 4], vec![10.0; 4], exact(3, 90, 1.0), "equal bounds");
        assert_eq!((p.stats.splits_for_importance, p.stats.splits_for_memory), (1, 0));
        // Predicted overflow splits; fewer fragments fit.
        let p = g.check(2, vec![3.0; 4], vec![10.0; 4], exact(64, 90, 1.0), "memory split");
        assert_eq!(p.tiles, [tile(0, 0, 0, 2), tile(0, 1, 0, 2), tile(0, 0, 1, 2), tile(0, 1, 1, 2)]);
        assert_eq!(p.stats.splits_for_memory, 1);
        let p = g.check(2, vec![3.0; 4], vec![5.0; 4], exact(64, 90, 1.0), "memory fits");
        assert_eq!(p.tiles, [tile(1, 0, 0, 4)]);
        // A coarse fragment estimate binds a finer tile.
        let mut importance = vec![0.0; 16];
        let mut fragments = vec![100.0; 16];
        for (x, y) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            importance[y * 4 + x] = 4.0;
            fragments[y * 4 + x] = 1.0;
        }
        let p = g.check(4, importance, fragments, exact(64, 900, 1.0), "ancestor bound");
        assert_eq!(p.stats.splits_for_memory, 2);
        assert_eq!(p.tiles.len(), 4);
        // Finest tiles over the bound are undersampled.
        let p = g.check(1, vec![100.0], vec![1.0], exact(4, 1 << 30, 1.0), "undersampled head");
        assert_eq!((p.tiles[0].res, p.stats.undersampled_tiles), (4, 1));
        let p = g.check(1, vec![100.0], vec![50.0], exact(64, 90, 1.0), "undersampled memory");
        assert_eq!((p.tiles[0].res, p.stats.undersampled_tiles), (1, 1));
        // Rounding up never breaks the memory bound.
        let params = TileParams { alpha: 0.5, ..TileParams::new(64, 21, 1.0) };
        let p = g.check(1, vec![10.0], vec![1.0], params, "rounding cap");
        assert_eq!(p.tiles, [tile(0, 0, 0, 3)]);
        // Nothing lit: nothing planned; one lit corner pixel.
        let p = g.check(4, vec![0.0; 16], vec![3.0; 16], exact(8, 100, 1.0), "dark");
        assert_eq!(p, TilePlan::default());
        let mut importance = vec![0.0; 16];
        importance[15] = 1.0;
        let p = g.check(4, importance, vec![1.0; 16], exact(1, 1 << 20, 1.0), "one corner");
        assert_eq!(p.tiles, [tile(0, 3, 3, 1)]);
        // No fragments anywhere (no memory bound at all): the head buffer alone decides.
        let p = g.check(8, vec![1.0; 64], vec![0.0; 64], exact(4, 10, 1.0), "no fragments");
        assert_eq!(p.tiles.len(), 4);
    }

    /// Random maps like the planner's own property tests (importance over six decades, zeros
    /// scattered or in blocks, shallow and deep pixels, empty ones; buffer sizes from 1/100
    /// to 10⁴ head buffers of rays and node buffers from 1/1000 to 10 head buffers deep): the
    /// GPU plan equals the CPU's in every case, sides 1 to 256.
    #[test]
    fn program_1_on_the_gpu_equals_the_planner_on_random_maps() {
        let g = Gpu::new();
        let mut rng = Rng::new(12, 12);
        let (mut tiles, mut splits_memory, mut splits_importance, mut undersampled) = (0, 0, 0, 0);
        for case in 0..120 {
            let side = 1u32 << (rng.next_u32() % 9);
            let zero_share = [0.0, 0.5, 0.9, 0.99][rng.next_u32() as usize % 4];
            let block = 1u32 << (rng.next_u32() % 3).min(side.trailing_zeros());
            let per_row = side / block;
            let zero: Vec<bool> = (0..per_row * per_row).map(|_| rng.next_f32() < zero_share).collect();
            let (mut importance, mut fragments) = (Vec::new(), Vec::new());
            for y in 0..side {
                for x in 0..side {
                    let dark = zero[((y / block) * per_row + x / block) as usize];
                    importance.push(if dark { 0.0 } else { 10f32.powf(rng.next_f32() * 6.0 - 3.0) });
                    fragments.push(match rng.next_u32() % 10 {
                        0 => 0.0,
                        1 => (rng.next_u32() % 2000) as f32,
                        _ => (1 + rng.next_u32() % 20) as f32,
                    });
                }
            }
            let i = MipChain::max_mips(side, importance.clone()).unwrap();
            let f = MipChain::average_mips(side, fragments.clone()).unwrap();
            let top = i.top_level();
            let w = [1u32, 3, 16, 64, 1024][rng.next_u32() as usize % 5];
            let head = w as f64 * w as f64;
            let max_importance = (i.get(top, 0, 0) as f64).max(1e-3);
            let window_rays = head * 10f64.powf(rng.next_f32() as f64 * 6.0 - 2.0);
            let mean_depth = (f.get(top, 0, 0) as f64).max(1.0);
            let nodes = head * mean_depth * 10f64.powf(rng.next_f32() as f64 * 4.0 - 3.0);
            let params = TileParams {
                w,
                n: nodes.max(1.0) as u64,
                alpha: if rng.next_f32() < 0.5 { DEFAULT_ALPHA } else { 0.05 + 0.95 * rng.next_f32() },
                pixel_area: window_rays / (4f64.powi(top as i32) * max_importance),
            };
            let p = g.check(side, importance, fragments, params, &format!("case {case}, side {side}"));
            tiles += p.stats.tiles;
            splits_memory += p.stats.splits_for_memory;
            splits_importance += p.stats.splits_for_importance;
            undersampled += p.stats.undersampled_tiles;
        }
        eprintln!(
            "GPU Program 1: {tiles} tiles, {splits_importance} importance splits, {splits_memory} memory splits, \
             {undersampled} undersampled, all equal to the CPU planner"
        );
        assert!(tiles > 1000 && splits_memory > 50 && splits_importance > 50 && undersampled > 50);
    }
}
