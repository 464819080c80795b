//! Per-tile linked-list build of the GPU bundle backend (paper Sect. 4.4): the tile's bundle
//! pixels are rasterised into a head buffer (at most W×W pixels) and a node buffer of capacity
//! N with an atomic counter. The counter counts every fragment, stored or not, so an overflow
//! is seen exactly (count > N); the tile's pixel grid is then split in four
//! (`Viewport::split`, the same parts the CPU backend redoes) and each part redone, so no
//! sample is lost. A single pixel deeper than N cannot be split and is reported.
//!
//! Today the host reads the 4-byte counter after each tile to decide on a split (one small
//! read-back per tile); a GPU-side split (indirect draws of the parts) would remove it.

use wgpu::util::DeviceExt;

use super::GpuError;
use super::bundle_analysis::{Drawn, GpuTriangles, set_view, view_side};
use super::device::GpuContext;
use super::layout::ListParams;
use super::pass::{self, READ, UNIFORM, WRITE};
use super::shader;
use crate::bundle::raster::{BundleFrame, Viewport};

/// One node: depth along ω (f32 bits) and the triangle.
const NODE_BYTES: u64 = 8;

/// The list-build pipeline.
pub struct ListPass {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::RenderPipeline,
}

/// Head, node and link buffers for tiles of at most W×W pixels and N fragments.
pub struct ListBuffers {
    pub head_side: u32,
    pub capacity: u32,
    pub heads: wgpu::Buffer,
    pub nodes: wgpu::Buffer,
    pub links: wgpu::Buffer,
    pub counter: wgpu::Buffer,
    target: wgpu::TextureView,
    readback: wgpu::Buffer,
}

/// A tile rectangle rasterised into the buffers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BuiltTile {
    pub viewport: Viewport,
    /// Its fragments (all stored: ≤ N, or a single pixel beyond N, see `overflowed`).
    pub fragments: u64,
}

/// What building one planned tile took.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BuildReport {
    /// Tiles whose count exceeded N (each split and redone, or unsplittable).
    pub overflowed: usize,
    /// Fragments over N, summed over the overflowed tiles.
    pub overflow_fragments: u64,
    /// Single pixels deeper than N: built anyway, their nodes beyond N dropped.
    pub unsplittable: usize,
}

/// Errors of the list build.
#[derive(Debug, thiserror::Error)]
pub enum ListError {
    #[error("node capacity {0} exceeds what the device's storage bindings hold")]
    Capacity(u64),
    #[error("head-pointer side {0} exceeds the device's texture or storage limits")]
    HeadSide(u32),
    #[error(transparent)]
    Gpu(#[from] GpuError),
}

impl ListPass {
    pub fn new(gpu: &GpuContext) -> Result<ListPass, GpuError> {
        gpu.require_fragment_storage()?;
        let device = &gpu.device;
        let both = wgpu::ShaderStages::VERTEX | wgpu::ShaderStages::FRAGMENT;
        let fragment = wgpu::ShaderStages::FRAGMENT;
        let layout = pass::buffer_layout(
            device,
            "bundle lists",
            &[
                (both, UNIFORM),
                (both, READ),
                (both, READ),
                (fragment, WRITE),
                (fragment, WRITE),
                (fragment, WRITE),
                (fragment, WRITE),
            ],
        );
        let pipeline_layout = pass::single_group(device, "bundle lists", &layout);
        let module = shader::module(device, "bundle_lists.wgsl")?;
        let pipeline = pass::bundle_raster(device, "bundle lists", &pipeline_layout, &module);
        gpu.take_error()?;
        Ok(ListPass { layout, pipeline })
    }

    /// Buffers for tiles of at most `head_side`² pixels and `capacity` nodes.
    pub fn buffers(&self, gpu: &GpuContext, head_side: u32, capacity: u64) -> Result<ListBuffers, ListError> {
        let device = &gpu.device;
        let limits = device.limits();
        let side = head_side.max(1);
        let heads_bytes = 4 * head_side as u64 * head_side as u64;
        if side > limits.max_texture_dimension_2d || heads_bytes > limits.max_storage_buffer_binding_size {
            return Err(ListError::HeadSide(head_side));
        }
        if capacity == 0
            || capacity * NODE_BYTES > limits.max_storage_buffer_binding_size
            || capacity >= u32::MAX as u64
        {
            return Err(ListError::Capacity(capacity));
        }
        let buffer = |label, size, extra| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | extra,
                mapped_at_creation: false,
            })
        };
        let texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("bundle lists target"),
            size: wgpu::Extent3d { width: side, height: side, depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: pass::RASTER_TARGET_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            view_formats: &[],
        });
        Ok(ListBuffers {
            head_side,
            capacity: capacity as u32,
            heads: buffer("bundle heads", heads_bytes, wgpu::BufferUsages::COPY_DST),
            nodes: buffer("bundle nodes", capacity * NODE_BYTES, wgpu::BufferUsages::empty()),
            links: buffer("bundle links", capacity * 4, wgpu::BufferUsages::empty()),
            counter: buffer("bundle node counter", 4, wgpu::BufferUsages::COPY_DST),
            target: texture.create_view(&Default::default()),
            readback: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("bundle node counter read-back"),
                size: 4,
                usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
                mapped_at_creation: false,
            }),
        })
    }

    /// Records the list build of rectangle `vp` (at most W×W pixels) along `frame`, drawing
    /// `drawn`: clears the heads and the counter, rasterises.
    #[allow(clippy::too_many_arguments)]
    pub fn encode(
        &self,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        triangles: &GpuTriangles,
        drawn: Drawn,
        frame: &BundleFrame,
        vp: &Viewport,
        out: &ListBuffers,
    ) {
        debug_assert!(vp.width <= out.head_side && vp.height <= out.head_side);
        let device = &gpu.device;
        let mut owned = None;
        let (ids, count) = drawn.binding(gpu, triangles, &mut owned);
        let params = ListParams {
            t: frame.t.to_array(),
            pixel: vp.pixel,
            b: frame.b.to_array(),
            capacity: out.capacity,
            dir: frame.dir.to_array(),
            width: vp.width,
            origin: vp.origin.to_array(),
            offset: [vp.offset.0, vp.offset.1],
            height: vp.height,
            view_side: view_side(gpu),
            drawn_count: count,
            _pad: 0,
        };
        let params = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("bundle list params"),
            contents: bytemuck::bytes_of(&params),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("bundle lists"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: params.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: triangles.corners.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 2, resource: ids.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 3, resource: out.heads.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 4, resource: out.nodes.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 5, resource: out.links.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 6, resource: out.counter.as_entire_binding() },
            ],
        });
        encoder.clear_buffer(&out.heads, 0, Some(4 * vp.width as u64 * vp.height as u64));
        encoder.clear_buffer(&out.counter, 0, None);
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("bundle lists"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &out.target,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations { load: wgpu::LoadOp::Clear(wgpu::Color::BLACK), store: wgpu::StoreOp::Discard },
            })],
            depth_stencil_attachment: None,
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        if count > 0 && vp.width > 0 && vp.height > 0 {
            set_view(&mut pass, gpu);
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &group, &[]);
            pass.set_scissor_rect(0, 0, vp.width, vp.height);
            pass.draw(0..3 * count, 0..1);
        }
    }

    /// Builds rectangle `vp` and returns its fragment count (read back from the counter).
    pub fn build(
        &self,
        gpu: &GpuContext,
        triangles: &GpuTriangles,
        frame: &BundleFrame,
        vp: &Viewport,
        out: &ListBuffers,
    ) -> Result<u64, GpuError> {
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        self.encode(gpu, &mut encoder, triangles, Drawn::All, frame, vp, out);
        out.encode_count_read(&mut encoder);
        gpu.queue.submit([encoder.finish()]);
        out.read_count(gpu)
    }

    /// Builds planned tile `vp`, splitting and redoing every rectangle whose count exceeds N
    /// as the CPU backend does; calls `built` with each rectangle whose lists are complete in
    /// `out` (before the next one overwrites them), in the CPU's order.
    pub fn build_tile(
        &self,
        gpu: &GpuContext,
        triangles: &GpuTriangles,
        frame: &BundleFrame,
        vp: &Viewport,
        out: &ListBuffers,
        mut built: impl FnMut(BuiltTile, &ListBuffers) -> Result<(), GpuError>,
    ) -> Result<BuildReport, GpuError> {
        let mut report = BuildReport::default();
        let mut queue = vec![*vp];
        while let Some(vp) = queue.pop() {
            let count = self.build(gpu, triangles, frame, &vp, out)?;
            if count > out.capacity as u64 {
                report.overflowed += 1;
                report.overflow_fragments += count - out.capacity as u64;
                match vp.split() {
                    Some(parts) => {
                        queue.extend(parts.iter().rev());
                        continue;
                    }
                    None => report.unsplittable += 1,
                }
            }
            built(BuiltTile { viewport: vp, fragments: count }, out)?;
        }
        Ok(report)
    }
}

impl ListBuffers {
    /// Records the copy of the node counter that [`read_count`](Self::read_count) reads.
    pub fn encode_count_read(&self, encoder: &mut wgpu::CommandEncoder) {
        self.encode_count_copy(encoder, &self.readback, 0);
    }

    /// Records a copy of the node counter (4 bytes) into `dst` at `offset`: the count of the
    /// rectangle last built, kept while the next one is built in the same submission.
    pub fn encode_count_copy(&self, encoder: &mut wgpu::CommandEncoder, dst: &wgpu::Buffer, offset: u64) {
        encoder.copy_buffer_to_buffer(&self.counter, 0, dst, offset, 4);
    }

    /// The fragment count of the last build (after a submitted
    /// [`encode_count_read`](Self::encode_count_read)).
    pub fn read_count(&self, gpu: &GpuContext) -> Result<u64, GpuError> {
        let bytes = gpu.read_buffer(&self.readback, 4)?;
        gpu.take_error()?;
        Ok(u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]) as u64)
    }

    /// Reads the lists of a built `width`×`height` rectangle: per pixel (row-major), its
    /// (depth, triangle) nodes in list order.
    pub fn read_lists(&self, gpu: &GpuContext, width: u32, height: u32) -> Result<Vec<Vec<(f32, u32)>>, GpuError> {
        let device = &gpu.device;
        let pixels = width as u64 * height as u64;
        let sizes = [4 * pixels, self.capacity as u64 * NODE_BYTES, self.capacity as u64 * 4];
        let staging = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bundle lists read-back"),
            size: sizes.iter().sum(),
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut encoder = device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(&self.heads, 0, &staging, 0, sizes[0]);
        encoder.copy_buffer_to_buffer(&self.nodes, 0, &staging, sizes[0], sizes[1]);
        encoder.copy_buffer_to_buffer(&self.links, 0, &staging, sizes[0] + sizes[1], sizes[2]);
        gpu.queue.submit([encoder.finish()]);
        let data = gpu.read_buffer(&staging, sizes.iter().sum())?;
        let words: &[u32] = bytemuck::cast_slice(&data);
        let (heads, rest) = words.split_at(pixels as usize);
        let (nodes, links) = rest.split_at(2 * self.capacity as usize);
        Ok(heads
            .iter()
            .map(|&head| {
                let mut list = Vec::new();
                let mut next = head;
                while next != 0 && list.len() <= self.capacity as usize {
                    let n = (next - 1) as usize;
                    list.push((f32::from_bits(nodes[2 * n]), nodes[2 * n + 1]));
                    next = links[n];
                }
                list
            })
            .collect())
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::bundle::directions::BundleDirections;
    use crate::bundle::mips::MipChain;
    use crate::bundle::raster::{ScreenTriangle, grid_centre};
    use crate::bundle::tiles::{TileParams, TilePlanner, TilingMode};
    use crate::bundle::window::tile_viewport;
    use crate::cpu::CpuScene;
    use crate::cpu::analysis::Analysis;
    use crate::cpu::fragments::TileFragments;
    use crate::gpu::bundle_analysis::tests::{cornell, window};

    /// The CPU raster's lists of rectangle `vp`: per pixel, (depth, triangle) sorted by
    /// triangle, from `bundle::raster` directly.
    fn cpu_lists(scene: &CpuScene, frame: &BundleFrame, vp: &Viewport) -> Vec<Vec<(f32, u32)>> {
        let geom = &scene.bundle.geom;
        let mut lists = vec![Vec::new(); (vp.width * vp.height) as usize];
        for t in 0..geom.len() {
            let Some(screen) = ScreenTriangle::setup(frame, vp, &geom.corners[t], geom.normals[t]) else { continue };
            let planes = screen.planes();
            let depth = planes.depth_coefficients();
            screen.for_each_span(|y, x0, x1| {
                for x in x0..x1 {
                    let d = planes.at(&depth, grid_centre(vp.offset.0, x), grid_centre(vp.offset.1, y));
                    lists[(y * vp.width + x) as usize].push((d, t as u32));
                }
            });
        }
        lists
    }

    /// The planned tiles of direction `i` on the Cornell box (CPU analysis and planner; the
    /// GPU's are equal, see the analysis and tile tests).
    pub(crate) fn planned(scene: &CpuScene, i: u64, w: u32, n: u64) -> (BundleFrame, Vec<Viewport>) {
        let dirs = BundleDirections::new(3);
        let (frame, global) = window(scene, &dirs, i, 64);
        let os = scene.bundle.config.oversampling;
        let importance: Vec<f32> = scene.density.iter().map(|d| d * os * os).collect();
        let mut analysis = Analysis::default();
        analysis.run(scene, &frame, &global, None, &importance);
        let imp = MipChain::max_mips(64, std::mem::take(&mut analysis.importance)).unwrap();
        let frags = MipChain::average_mips(64, std::mem::take(&mut analysis.fragments)).unwrap();
        let params = TileParams { w, n, alpha: 0.9, pixel_area: (global.pixel as f64).powi(2) };
        let plan = TilePlanner::new(&imp, &frags, params).unwrap().plan(TilingMode::Adaptive).unwrap();
        (frame, plan.tiles.iter().map(|t| tile_viewport(&global, t)).collect())
    }

    /// Every pixel's list on the GPU holds exactly the CPU raster's triangles, and every
    /// tile's count equals `TileFragments::prepare`'s exact count, on the planned tiles of
    /// three Cornell-box directions (lavapipe: 469 tiles, 3.8 M fragments, no pixel differs).
    /// Depths are the rasteriser's interpolation, not the CPU's plane evaluation: within
    /// 2⁻¹⁶ m here (measured 1.2·10⁻⁵ m), above the CPU's coincident-surface tolerance
    /// (1e-6 × the scene's scale), so the resolve must order by depths recomputed the CPU's way
    /// from the triangle, never by these.
    #[test]
    fn lists_hold_the_cpu_rasters_fragments() {
        let gpu = GpuContext::headless().expect("a Vulkan adapter (lavapipe: mesa-vulkan-drivers)");
        let scene = cornell();
        let geom = &scene.bundle.geom;
        let tris = GpuTriangles::new(&gpu, &geom.corners);
        let pass = ListPass::new(&gpu).unwrap();
        let out = pass.buffers(&gpu, 128, 1 << 20).unwrap();
        let all: Vec<u32> = (0..geom.len() as u32).collect();
        let mut cpu = TileFragments::default();
        let (mut tiles, mut fragments, mut worst_depth, mut swapped) = (0, 0u64, 0f32, 0u64);
        for i in 0..3 {
            let (frame, viewports) = planned(&scene, i, 128, 1 << 20);
            assert!(viewports.len() > 1, "direction {i} has tiles");
            for vp in viewports.iter() {
                let count = pass.build(&gpu, &tris, &frame, vp, &out).unwrap();
                assert_eq!(count, cpu.prepare(&scene, &frame, vp, &all, None, None), "tile {vp:?}");
                let mut got = out.read_lists(&gpu, vp.width, vp.height).unwrap();
                let want = cpu_lists(&scene, &frame, vp);
                for (p, (g, w)) in got.iter_mut().zip(&want).enumerate() {
                    g.sort_by_key(|&(_, t)| t);
                    let triangles = |l: &[(f32, u32)]| l.iter().map(|&(_, t)| t).collect::<Vec<_>>();
                    // Watertight either way: one fragment per surface crossed.
                    assert_eq!(g.len(), w.len(), "pixel {p} of {vp:?}");
                    if triangles(g) != triangles(w) {
                        swapped += 1;
                        continue;
                    }
                    for (a, b) in g.iter().zip(w) {
                        worst_depth = worst_depth.max((a.0 - b.0).abs());
                    }
                }
                tiles += 1;
                fragments += count;
            }
        }
        eprintln!(
            "list twin: {tiles} tiles, {fragments} fragments, {swapped} pixels with an edge centre given to the \
             other triangle, worst depth difference {worst_depth:e} m"
        );
        assert!(fragments > 10_000);
        assert_eq!(swapped, 0, "pixels whose centre went to the other triangle of an edge");
        assert!(worst_depth <= 2f32.powi(-16), "depth off by {worst_depth}");
    }

    /// A node buffer far too small for the tiles: every overflow is seen from the counter, the
    /// tile is split and redone exactly as the CPU backend splits it (same rectangles, same
    /// counts, in the same order), and the parts hold every fragment of the whole tile.
    #[test]
    fn overflowing_tiles_are_split_and_redone_without_losing_a_sample() {
        let gpu = GpuContext::headless().expect("a Vulkan adapter (lavapipe: mesa-vulkan-drivers)");
        let scene = cornell();
        let geom = &scene.bundle.geom;
        let tris = GpuTriangles::new(&gpu, &geom.corners);
        let pass = ListPass::new(&gpu).unwrap();
        let all: Vec<u32> = (0..geom.len() as u32).collect();
        let mut cpu = TileFragments::default();
        let (frame, viewports) = planned(&scene, 1, 128, 1 << 20);
        let capacity = 700u64;
        let small = pass.buffers(&gpu, 128, capacity).unwrap();
        let big = pass.buffers(&gpu, 128, 1 << 20).unwrap();
        let mut overflowed = 0;
        for vp in viewports.iter().take(12) {
            // The CPU backend's split-and-redo of this tile (cpu::direction::overflowed).
            let mut expected = Vec::new();
            let mut queue = vec![*vp];
            while let Some(part) = queue.pop() {
                let count = cpu.prepare(&scene, &frame, &part, &all, None, None);
                if count > capacity
                    && let Some(parts) = part.split()
                {
                    queue.extend(parts.iter().rev());
                    continue;
                }
                expected.push(BuiltTile { viewport: part, fragments: count });
            }
            // Whole tile's fragments, by grid pixel.
            let whole_count = pass.build(&gpu, &tris, &frame, vp, &big).unwrap();
            let whole = big.read_lists(&gpu, vp.width, vp.height).unwrap();
            let mut seen = vec![Vec::new(); whole.len()];
            let mut got = Vec::new();
            let report = pass
                .build_tile(&gpu, &tris, &frame, vp, &small, |b, lists| {
                    let part = lists.read_lists(&gpu, b.viewport.width, b.viewport.height)?;
                    for (k, list) in part.into_iter().enumerate() {
                        let (x, y) = (k as u32 % b.viewport.width, k as u32 / b.viewport.width);
                        let (gx, gy) = (x + b.viewport.offset.0 - vp.offset.0, y + b.viewport.offset.1 - vp.offset.1);
                        seen[(gy * vp.width + gx) as usize].extend(list);
                    }
                    got.push(b);
                    Ok(())
                })
                .unwrap();
            assert_eq!(got, expected, "tile {vp:?}");
            assert_eq!(got.iter().map(|b| b.fragments).sum::<u64>(), whole_count);
            assert_eq!(report.unsplittable, 0);
            for (a, b) in seen.into_iter().zip(whole) {
                let triangles = |l: Vec<(f32, u32)>| {
                    let mut t: Vec<u32> = l.into_iter().map(|(_, t)| t).collect();
                    t.sort_unstable();
                    t
                };
                assert_eq!(triangles(a), triangles(b), "a part lost or gained a fragment");
            }
            overflowed += report.overflowed;
        }
        eprintln!("split twin: {overflowed} overflowed rectangles split and redone");
        assert!(overflowed >= 5, "the test must overflow");
    }
}
