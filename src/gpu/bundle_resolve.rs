//! The resolve pass of the GPU bundle backend (paper Sect. 4.4): per pixel of a built
//! rectangle, walk its linked list, rebuild each fragment from its triangle, sort along ω
//! with the estimator's layer rules and credit every target side what it sees. The twin of
//! the CPU's `TileFragments::resolve` + `estimator::exchange` (shaders/bundle_resolve.wgsl
//! says how each step follows the CPU's); in a scene with see-through surfaces or
//! cut-outs, of `cpu::through` (each fragment's transmittance, the walk with the running
//! product: bundle_through.inc.wgsl), which reads the scene's materials and each target
//! texel's triangle.
//!
//! Per-texel sums are 64-bit fixed point in pairs of u32 (no float atomics): exact, so the
//! GPU's sums do not depend on the order threads run in. [`FixedPoint`] picks the scales
//! from a bound on what one batch can add to a texel; an addition that would reach 2^63 is
//! counted as saturated, and the backend then redoes the batch with smaller scales.

use wgpu::util::DeviceExt;

use super::GpuError;
use super::bundle_analysis::GpuTriangles;
use super::bundle_lists::ListBuffers;
use super::device::GpuContext;
use super::layout::{ResolveParams, ResolveTriangle, TableHeader};
use super::pass::{self, READ, WRITE};
use super::shader;
use super::surface_radiance::{ForeignBindings, ForeignRadiance, SceneSurfaces};
use crate::atlas::Atlas;
use crate::bundle::estimator::Coincidence;
use crate::bundle::raster::{BundleFrame, Viewport};
use crate::bundle::sky::SkySeen;
use crate::bundle::target::{BakeTarget, BundleScene};
use crate::scene::{Rgb, Side};

/// `NO_CHART` in the shader: a side that is not a lit face, or the whole-LOD table.
const NO_CHART: u32 = u32::MAX;
/// u32 words per texel: (lo, hi) of r, g, b and the weight.
const WORDS_PER_TEXEL: u64 = 8;
/// Status words after the sums (`STATUS_*` in the shader).
const STATUS_WORDS: u64 = 5;

/// The resolve pipelines: the groups of 8 pixels with fragments are listed
/// (bundle_groups.wgsl), then resolved, an invocation per pixel of a listed group.
pub struct ResolvePass {
    layout: wgpu::BindGroupLayout,
    /// Groups 1 and 2: what foreign sides show, the scene's materials (or placeholders).
    pub foreign: ForeignBindings,
    /// Whether the scene lets light through surfaces (`PASSING` in every pipeline).
    passing: bool,
    /// The resolve without a foreign source, and with one (`FOREIGN_SOURCE`; made at the
    /// first bake that has one).
    pipeline: wgpu::ComputePipeline,
    foreign_pipeline: Option<wgpu::ComputePipeline>,
    pipeline_layout: wgpu::PipelineLayout,
    module: wgpu::ShaderModule,
    groups_layout: wgpu::BindGroupLayout,
    groups_pipeline: wgpu::ComputePipeline,
    /// 1 + each listed group's index (room for every group of a W×W rectangle, and a
    /// workgroup's worth past it).
    groups: wgpu::Buffer,
    /// The resolve's indirect dispatch (x, y, z) and the count of listed groups, reset from
    /// `dispatch_reset` before each rectangle's listing (in the command stream, so that many
    /// rectangles can share one submission).
    dispatch: wgpu::Buffer,
    dispatch_reset: wgpu::Buffer,
}

/// Every triangle's front normal and faces (charts and atlas UVs), uploaded once per scene.
pub struct SceneSides {
    pub buffer: wgpu::Buffer,
}

impl SceneSides {
    pub fn new(gpu: &GpuContext, scene: &BundleScene) -> SceneSides {
        let (geom, atlas) = (&scene.geom, &scene.atlas);
        let mut records: Vec<ResolveTriangle> = (0..geom.len())
            .map(|t| {
                let face = |side| atlas.face(t as u32, side).map(|f| &atlas.faces[f as usize]);
                let (front, back) = (face(Side::Front), face(Side::Back));
                let uv = |f: Option<&crate::atlas::AtlasFace>, k: usize| f.map_or([0.0; 2], |f| f.uv[k].to_array());
                ResolveTriangle {
                    normal: geom.normals[t].to_array(),
                    front_chart: front.map_or(NO_CHART, |f| f.chart),
                    corner_uv: std::array::from_fn(|k| {
                        let (a, b) = (uv(front, k), uv(back, k));
                        [a[0], a[1], b[0], b[1]]
                    }),
                    back_chart: back.map_or(NO_CHART, |f| f.chart),
                    _pad0: 0,
                    _pad1: 0,
                    _pad2: 0,
                }
            })
            .collect();
        if records.is_empty() {
            records.push(ResolveTriangle::zeroed());
        }
        let buffer = gpu.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("bundle resolve triangles"),
            contents: bytemuck::cast_slice(&records),
            usage: wgpu::BufferUsages::STORAGE,
        });
        SceneSides { buffer }
    }
}

use bytemuck::Zeroable;

/// Fixed-point scales of one batch: units per m² of weight (`weight`) and per
/// m²·W/(m²·sr) of weighted radiance (`radiance`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FixedPoint {
    pub weight: f32,
    pub radiance: f32,
}

impl FixedPoint {
    /// Scales for a batch of `directions` at texel area `texel_area` (m²) whose sources
    /// are at most `max_radiance`. Per direction a texel's hits add about its projected
    /// area (≤ its area; gutter pixels and pixel rounding can double it): the scales put
    /// 64 texel areas per direction at 2^62, 32× the most a texel was seen to get, so no
    /// addition saturates in practice. Quantisation is then one unit in 2^62 / (64·D) texel
    /// areas: below 10⁻¹⁰ of a single hit, far below the CPU's own f32 rounding.
    pub fn for_batch(directions: usize, texel_area: f32, max_radiance: f32) -> FixedPoint {
        let budget = 64.0 * directions.max(1) as f64 * texel_area.max(f32::MIN_POSITIVE) as f64;
        let weight = (2f64.powi(62) / budget) as f32;
        let radiance = (weight as f64 / (max_radiance as f64).max(1e-30)) as f32;
        FixedPoint { weight, radiance: radiance.min(f32::MAX) }
    }

    /// These scales divided by 2^`bits` (the retry after a saturation).
    pub fn reduced(self, bits: i32) -> FixedPoint {
        let k = 2f32.powi(-bits);
        FixedPoint { weight: self.weight * k, radiance: self.radiance * k }
    }
}

/// What the shader counted over the batch.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ResolveStatus {
    /// Additions that would have carried a sum to 2^63 (the batch must be redone).
    pub saturated: u32,
    /// Foreign sides looked up without a foreign source (black).
    pub lost: u32,
    /// Pixels with at least one fragment.
    pub covered: u32,
    /// Pixels deeper than the resolve's sort holds (skipped).
    pub deep: u32,
    /// Foreign sides looked up and resolved.
    pub foreign: u32,
}

/// One target's texel tables, sources and sums on the GPU.
pub struct TargetBuffers {
    texels: u32,
    table_count: u32,
    whole_table: bool,
    lod: u32,
    tables: wgpu::Buffer,
    entries: wgpu::Buffer,
    own: wgpu::Buffer,
    sums: wgpu::Buffer,
    staging: wgpu::Buffer,
    /// Per texel its face's triangle, in a scene that lets light through surfaces (else a
    /// placeholder word the resolve never reads).
    texel_triangles: wgpu::Buffer,
}

impl TargetBuffers {
    /// Uploads `target`'s tables and makes its sums, and in a scene that lets light through
    /// surfaces (`passing`: its atlas) each texel's triangle; an error when a buffer exceeds
    /// the device's binding limit.
    pub fn new(gpu: &GpuContext, target: &BakeTarget, passing: Option<&Atlas>) -> Result<TargetBuffers, GpuError> {
        let device = &gpu.device;
        let limit = device.limits().max_storage_buffer_binding_size;
        let mut headers = Vec::with_capacity(target.tables.len());
        let mut entries: Vec<u32> = Vec::new();
        for t in target.tables {
            let r = t.rect;
            headers.push(TableHeader {
                chart: t.chart.unwrap_or(NO_CHART),
                x0: r.x0 as i32,
                y0: r.y0 as i32,
                x1: r.x1 as i32,
                y1: r.y1 as i32,
                blocks_x: t.blocks_x() as u32,
                first: entries.len() as u32,
                _pad: 0,
            });
            entries.extend_from_slice(&t.dense_entries());
        }
        let whole_table = matches!(target.tables, [t] if t.chart.is_none());
        let n = target.len() as u64;
        let sums_bytes = (n * WORDS_PER_TEXEL + STATUS_WORDS) * 4;
        let mut triangles: Vec<u32> = match passing {
            Some(atlas) => target.face.iter().map(|&f| atlas.faces[f as usize].tri).collect(),
            None => Vec::new(),
        };
        let checked = [
            ("texel tables", entries.len() as u64 * 4),
            ("texel sums", sums_bytes),
            ("texel triangles", triangles.len() as u64 * 4),
        ];
        for (what, bytes) in checked {
            if bytes > limit {
                return Err(GpuError::Validation(format!(
                    "the target's {what} need {bytes} bytes, over the device's storage binding limit of {limit}"
                )));
            }
        }
        let init = |label, data: &[u8]| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: data,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            })
        };
        if headers.is_empty() {
            headers.push(TableHeader::zeroed());
        }
        if entries.is_empty() {
            entries.push(u32::MAX);
        }
        if triangles.is_empty() {
            triangles.push(0);
        }
        let texel_triangles = init("bundle resolve texel triangles", bytemuck::cast_slice(&triangles));
        let tables = init("bundle resolve tables", bytemuck::cast_slice(&headers));
        let entries = init("bundle resolve table entries", bytemuck::cast_slice(&entries));
        let own = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bundle resolve sources"),
            size: (12 * n).max(12),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let sums = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bundle resolve sums"),
            size: sums_bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let staging = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bundle resolve sums read-back"),
            size: sums_bytes,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        Ok(TargetBuffers {
            texels: n as u32,
            table_count: target.tables.len() as u32,
            whole_table,
            lod: target.lod,
            tables,
            entries,
            own,
            sums,
            staging,
            texel_triangles,
        })
    }

    /// Uploads the batch's source radiance (per target texel) and zeroes the sums.
    pub fn start_batch(&self, gpu: &GpuContext, own: &[Rgb]) {
        debug_assert_eq!(own.len(), self.texels as usize);
        if !own.is_empty() {
            let flat: Vec<f32> = own.iter().flat_map(|l| l.to_array()).collect();
            gpu.queue.write_buffer(&self.own, 0, bytemuck::cast_slice(&flat));
        }
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        encoder.clear_buffer(&self.sums, 0, None);
        gpu.queue.submit([encoder.finish()]);
    }

    /// Reads the batch's sums into `out` (Σ a·L rgb, Σ a per texel, in m² and m²·W/(m²·sr))
    /// and returns the status words.
    pub fn read(&self, gpu: &GpuContext, scales: FixedPoint, out: &mut [[f32; 4]]) -> Result<ResolveStatus, GpuError> {
        let size = self.sums.size();
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(&self.sums, 0, &self.staging, 0, size);
        gpu.queue.submit([encoder.finish()]);
        let bytes = gpu.read_buffer(&self.staging, size)?;
        let words: &[u32] = bytemuck::cast_slice(&bytes);
        let n = self.texels as usize;
        let (texels, status) = words.split_at(n * WORDS_PER_TEXEL as usize);
        let inverse = [scales.radiance, scales.radiance, scales.radiance, scales.weight].map(|s| 1.0 / s as f64);
        for (sum, w) in out.iter_mut().zip(texels.chunks_exact(WORDS_PER_TEXEL as usize)) {
            for c in 0..4 {
                let fixed = (w[2 * c + 1] as u64) << 32 | w[2 * c] as u64;
                sum[c] = (fixed as f64 * inverse[c]) as f32;
            }
        }
        Ok(ResolveStatus {
            saturated: status[0],
            lost: status[1],
            covered: status[2],
            deep: status[3],
            foreign: status[4],
        })
    }
}

/// What one rectangle's resolve needs besides the buffers.
pub struct Rectangle<'a> {
    pub frame: &'a BundleFrame,
    pub viewport: &'a Viewport,
    pub coincidence: Coincidence,
    /// What the ends of the direction's lines see.
    pub sky: SkySeen,
    pub scales: FixedPoint,
}

/// Bytes of the group list for rectangles of at most `head_side`² pixels.
pub fn groups_bytes(head_side: u32) -> u64 {
    4 * (head_side.div_ceil(8) as u64 * head_side as u64 + 8)
}

impl ResolvePass {
    /// The pipelines, for rectangles of at most `head_side`² pixels of a scene that lets
    /// light through surfaces or not (`passing`).
    pub fn new(gpu: &GpuContext, head_side: u32, passing: bool) -> Result<ResolvePass, GpuError> {
        let device = &gpu.device;
        let c = wgpu::ShaderStages::COMPUTE;
        let mut bindings = vec![(c, READ); 10];
        bindings.extend([(c, WRITE), (c, READ), (c, READ)]);
        let needed = bindings.len() as u32;
        if device.limits().max_storage_buffers_per_shader_stage < needed {
            return Err(GpuError::Unsupported {
                adapter: gpu.info.name.clone(),
                missing: "13 storage buffers per shader stage (the bundle resolve)",
            });
        }
        let layout = pass::buffer_layout(device, "bundle resolve", &bindings);
        let foreign = ForeignBindings::new(gpu);
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("bundle resolve"),
            bind_group_layouts: &[Some(&layout), Some(&foreign.lightmap_layout), Some(&foreign.surfaces_layout)],
            immediate_size: 0,
        });
        // Exact division and square root through f64 where the device has it (see the shader).
        let name = "bundle_resolve.wgsl";
        let text = if gpu.has_f64() { shader::source_f64(name)? } else { shader::source(name)? };
        let module = shader::module_from(device, name, text);
        let pipeline = resolve_pipeline(device, &pipeline_layout, &module, false, passing);
        let groups_layout =
            pass::buffer_layout(device, "bundle resolve groups", &[(c, READ), (c, READ), (c, WRITE), (c, WRITE)]);
        let groups_pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("bundle resolve groups"),
            layout: Some(&pass::single_group(device, "bundle resolve groups", &groups_layout)),
            module: &shader::module(device, "bundle_groups.wgsl")?,
            entry_point: Some("list_groups"),
            compilation_options: Default::default(),
            cache: None,
        });
        let buffer = |label, size, usage| {
            device.create_buffer(&wgpu::BufferDescriptor { label: Some(label), size, usage, mapped_at_creation: false })
        };
        let storage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        let groups = buffer("bundle resolve groups", groups_bytes(head_side), storage);
        let dispatch = buffer("bundle resolve dispatch", 16, storage | wgpu::BufferUsages::INDIRECT);
        let dispatch_reset = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("bundle resolve dispatch reset"),
            contents: bytemuck::cast_slice(&[0u32, 1, 1, 0]),
            usage: wgpu::BufferUsages::COPY_SRC,
        });
        gpu.take_error()?;
        Ok(ResolvePass {
            layout,
            foreign,
            passing,
            pipeline,
            foreign_pipeline: None,
            pipeline_layout,
            module,
            groups_layout,
            groups_pipeline,
            groups,
            dispatch,
            dispatch_reset,
        })
    }

    /// Makes the resolve that reads foreign sides (once; before the first [`Self::encode`]
    /// with a foreign source).
    pub fn prepare_foreign(&mut self, gpu: &GpuContext) -> Result<(), GpuError> {
        if self.foreign_pipeline.is_none() {
            let pipeline = resolve_pipeline(&gpu.device, &self.pipeline_layout, &self.module, true, self.passing);
            self.foreign_pipeline = Some(pipeline);
            gpu.take_error()?;
        }
        Ok(())
    }

    /// Records the resolve of the rectangle last built into `lists` (in the same or an
    /// earlier submission). It does nothing when the list build overflowed a splittable
    /// rectangle (the host splits and redoes it). Its parameters go in buffers of its own,
    /// so many rectangles may share a submission. Foreign sides show `foreign`'s radiance (after
    /// [`Self::prepare_foreign`]), or are black and counted lost without one. A pass made
    /// for a scene that lets light through surfaces reads their materials from `surfaces`
    /// (`foreign`'s when it has one).
    #[allow(clippy::too_many_arguments)]
    pub fn encode(
        &self,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        triangles: &GpuTriangles,
        sides: &SceneSides,
        lists: &ListBuffers,
        target: &TargetBuffers,
        foreign: Option<&ForeignRadiance>,
        surfaces: Option<&SceneSurfaces>,
        rect: &Rectangle,
    ) {
        let (vp, frame, c) = (rect.viewport, rect.frame, rect.coincidence);
        let params = ResolveParams {
            t: frame.t.to_array(),
            pixel: vp.pixel,
            b: frame.b.to_array(),
            pixel_area: vp.pixel_area(),
            dir: frame.dir.to_array(),
            capacity: lists.capacity,
            sky_ahead: rect.sky.ahead.to_array(),
            rounding: c.rounding,
            origin: vp.origin.to_array(),
            offset: [vp.offset.0, vp.offset.1],
            width: vp.width,
            height: vp.height,
            stacked: c.stacked,
            snap: c.snap,
            lod_scale: (1u64 << target.lod) as f32,
            table_count: target.table_count,
            whole_table: target.whole_table as u32,
            texel_count: target.texels,
            weight_scale: rect.scales.weight,
            radiance_scale: rect.scales.radiance,
            _pad0: 0,
            _pad1: 0,
            sky_behind: rect.sky.behind.to_array(),
            opaque_zero: 0,
        };
        let device = &gpu.device;
        // The rectangle's parameters in buffers of its own (a storage buffer, not a uniform
        // one: lavapipe compiles a shader variant for each set of the uniform values that
        // branches test; see the shader), so rectangles can share a submission.
        let init = |label, contents: &[u8]| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage: wgpu::BufferUsages::STORAGE,
            })
        };
        let params = init("bundle resolve params", bytemuck::bytes_of(&params));
        let size = init("bundle resolve size", bytemuck::cast_slice(&[vp.width, vp.height]));
        encoder.copy_buffer_to_buffer(&self.dispatch_reset, 0, &self.dispatch, 0, 16);
        let group_count = vp.width.div_ceil(8) as u64 * vp.height as u64;
        encoder.clear_buffer(&self.groups, 0, Some(4 * (group_count + 8)));
        let bind = |layout, buffers: &[&wgpu::Buffer]| {
            let entries: Vec<wgpu::BindGroupEntry> = buffers
                .iter()
                .enumerate()
                .map(|(i, b)| wgpu::BindGroupEntry { binding: i as u32, resource: b.as_entire_binding() })
                .collect();
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("bundle resolve"),
                layout,
                entries: &entries,
            })
        };
        let listing = bind(&self.groups_layout, &[&size, &lists.heads, &self.groups, &self.dispatch]);
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("bundle resolve groups"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.groups_pipeline);
            pass.set_bind_group(0, &listing, &[]);
            pass.dispatch_workgroups(group_count.div_ceil(64) as u32, 1, 1);
        }
        let buffers = [
            &params,
            &triangles.corners,
            &sides.buffer,
            &lists.heads,
            &lists.nodes,
            &lists.links,
            &lists.counter,
            &target.tables,
            &target.entries,
            &target.own,
            &target.sums,
            &self.groups,
            &target.texel_triangles,
        ];
        let group = bind(&self.layout, &buffers);
        let mut pass = encoder
            .begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("bundle resolve"), timestamp_writes: None });
        let (pipeline, foreign) = match (foreign, &self.foreign_pipeline) {
            (Some(f), Some(p)) => (p, Some(f)),
            _ => (&self.pipeline, None),
        };
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &group, &[]);
        let [lightmap, surfaces] = self.foreign.groups(foreign, surfaces);
        pass.set_bind_group(1, lightmap, &[]);
        pass.set_bind_group(2, surfaces, &[]);
        pass.dispatch_workgroups_indirect(&self.dispatch, 0);
    }
}

/// The resolve pipeline, reading foreign sides or not (`FOREIGN_SOURCE`), letting light
/// through surfaces or not (`PASSING`).
fn resolve_pipeline(
    device: &wgpu::Device,
    layout: &wgpu::PipelineLayout,
    module: &wgpu::ShaderModule,
    foreign: bool,
    passing: bool,
) -> wgpu::ComputePipeline {
    let flag = |on: bool| if on { 1.0 } else { 0.0 };
    let constants = [("FOREIGN_SOURCE", flag(foreign)), ("PASSING", flag(passing))];
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(if foreign { "bundle resolve (foreign sides)" } else { "bundle resolve" }),
        layout: Some(layout),
        module,
        entry_point: Some("resolve"),
        compilation_options: wgpu::PipelineCompilationOptions { constants: &constants, ..Default::default() },
        cache: None,
    })
}
