//! Resolve of built tile rectangles on the GPU (`bundle::estimator::exchange` in compute): per
//! bundle pixel, the linked list's fragments are recomputed from their triangles the CPU's
//! way (snapped corners in the tile's grid → depth and UV planes at the pixel centre → texel
//! table), put in the CPU's build order (ascending triangle) and sorted with its stable
//! insertion sort and coincident-surface rule, and neighbours exchange radiance with the
//! sidedness rules (a side that is not a lit face is black and receives nothing).
//!
//! **Accumulation without float atomics.** Each hit adds `a·L` (rgb) and `a` to its texel in
//! 64-bit unsigned fixed point (two u32 words, the carry added by hand), so sums are exact and
//! independent of the order threads add them in. [`FixedPoint`] picks the scales of a batch
//! from its largest hit: a hit of value x adds ⌊x·S⌋, S = 2^k the largest power of two with
//! (largest hit)·S ≤ 2^32, so each hit loses less than 1/S ≤ 2^-31 × the largest hit, and a
//! texel saturates only after ≥ 2^32 largest hits; saturation pins the texel at the top value
//! and is counted (a test drives a texel there).
//!
//! Scope of this stage: a whole-LOD target served by one whole-LOD texel table, without
//! foreign radiance (a lit face the table misses is black and counted lost, as on the CPU with
//! `SourceRadiance::foreign == None`), global bundles only. The light pass and punctual lights
//! stay on the CPU (see the backend).

use bytemuck::Zeroable;
use wgpu::util::DeviceExt;

use super::GpuError;
use super::bundle_analysis::GpuTriangles;
use super::bundle_lists::ListBuffers;
use super::device::GpuContext;
use super::layout::{ResolveParams, TriangleFaces};
use super::shader;
use crate::atlas::Atlas;
use crate::atlas::lookup::TexelTable;
use crate::bundle::raster::{BundleFrame, Viewport};
use crate::scene::{Rgb, SceneGeometry, Side};

/// Fixed-point scales of one batch: Σ a·L and Σ a are held as integers of 1/`radiance` and
/// 1/`area`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FixedPoint {
    pub radiance: f32,
    pub area: f32,
}

impl FixedPoint {
    /// Scales for hits of at most `max_area` (m², the largest bundle pixel) and radiance at
    /// most `max_radiance` (the brightest source or the sky).
    pub fn for_hits(max_area: f32, max_radiance: f32) -> FixedPoint {
        let scale = |largest: f32| {
            if !(largest > 0.0 && largest.is_finite()) {
                return 1.0;
            }
            // 2^k ≤ 2^32 / largest, clamped to f32's range.
            let k = (32.0 - (largest as f64).log2()).floor().clamp(-120.0, 120.0) as i32;
            2f32.powi(k)
        };
        FixedPoint { radiance: scale(max_area * max_radiance), area: scale(max_area) }
    }
}

/// Flags of a resolve.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ResolveFlags {
    /// Texels whose sums overflowed 64 bits (pinned at the top value).
    pub saturated: u32,
    /// Lit sides the table did not hold (seen as black).
    pub lost_lookups: u32,
    /// Pixels with more fragments than the shader's list (48): their farthest were dropped.
    pub truncated_pixels: u32,
    /// Pixels with at least one fragment.
    pub covered_pixels: u32,
}

/// A whole-LOD target on the GPU: triangles' faces, the texel table, the source radiance and
/// the per-texel sums.
pub struct ResolveTarget {
    lod: u32,
    texels: u32,
    rect: [i32; 4],
    blocks_x: i32,
    normals: wgpu::Buffer,
    faces: wgpu::Buffer,
    table: wgpu::Buffer,
    own: wgpu::Buffer,
    pub sums: wgpu::Buffer,
    pub flags: wgpu::Buffer,
}

/// The resolve pipeline.
pub struct ResolvePass {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
}

impl ResolvePass {
    pub fn new(gpu: &GpuContext) -> Result<ResolvePass, GpuError> {
        let device = &gpu.device;
        let entry = |binding: u32| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: match binding {
                    0 => wgpu::BufferBindingType::Uniform,
                    9 | 10 => wgpu::BufferBindingType::Storage { read_only: false },
                    _ => wgpu::BufferBindingType::Storage { read_only: true },
                },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let entries: Vec<_> = (0..11).map(entry).collect();
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("bundle resolve"),
            entries: &entries,
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("bundle resolve"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let module = shader::module(device, "bundle_resolve.wgsl")?;
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("bundle resolve"),
            layout: Some(&pipeline_layout),
            module: &module,
            entry_point: Some("resolve"),
            compilation_options: Default::default(),
            cache: None,
        });
        gpu.take_error()?;
        Ok(ResolvePass { layout, pipeline })
    }

    /// The GPU side of a whole-LOD target of LOD `lod` with texel table `table` (of the whole
    /// LOD's map) and `texels` texels.
    pub fn target(
        &self,
        gpu: &GpuContext,
        geom: &SceneGeometry,
        atlas: &Atlas,
        lod: u32,
        table: &TexelTable,
        texels: usize,
    ) -> Result<ResolveTarget, GpuError> {
        let device = &gpu.device;
        if table.chart.is_some() {
            return Err(GpuError::Validation("the GPU resolve serves whole-LOD tables only".into()));
        }
        let r = table.rect;
        let fits = |v: i64| i32::try_from(v).is_ok();
        if ![r.x0, r.y0, r.x1, r.y1, table.blocks_x()].into_iter().all(fits)
            || texels as u64 >= crate::bundle::estimator::FOREIGN as u64
        {
            return Err(GpuError::Validation("texel table too large for the GPU resolve".into()));
        }
        let init = |label, contents: &[u8], usage| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents, usage })
        };
        let normals: Vec<[f32; 4]> =
            geom.normals.iter().map(|n| [n.x, n.y, n.z, 0.0]).chain(std::iter::once([0.0; 4])).collect();
        let uv = |t: u32, side: Side| atlas.face(t, side).map(|f| atlas.faces[f as usize].uv.map(|p| p.to_array()));
        let faces: Vec<TriangleFaces> = (0..geom.len() as u32)
            .map(|t| {
                let (front, back) = (uv(t, Side::Front), uv(t, Side::Back));
                TriangleFaces {
                    front: front.unwrap_or_default(),
                    back: back.unwrap_or_default(),
                    faces: front.is_some() as u32 | (back.is_some() as u32) << 1,
                    _pad0: 0,
                    _pad1: 0,
                    _pad2: 0,
                }
            })
            .chain(std::iter::once(TriangleFaces::zeroed()))
            .collect();
        let storage = wgpu::BufferUsages::STORAGE;
        let entries: &[u32] = if table.entries().is_empty() { &[u32::MAX] } else { table.entries() };
        let sums_bytes = 32 * texels.max(1) as u64;
        if sums_bytes > device.limits().max_storage_buffer_binding_size {
            return Err(GpuError::Validation(format!("{texels} texels exceed the storage binding limit")));
        }
        Ok(ResolveTarget {
            lod,
            texels: texels as u32,
            rect: [r.x0 as i32, r.y0 as i32, r.x1 as i32, r.y1 as i32],
            blocks_x: table.blocks_x() as i32,
            normals: init("bundle normals", bytemuck::cast_slice(&normals), storage),
            faces: init("bundle faces", bytemuck::cast_slice(&faces), storage),
            table: init("bundle texel table", bytemuck::cast_slice(entries), storage),
            own: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("bundle source radiance"),
                size: 16 * texels.max(1) as u64,
                usage: storage | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            sums: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("bundle texel sums"),
                size: sums_bytes,
                usage: storage | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            }),
            flags: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("bundle resolve flags"),
                size: 16,
                usage: storage | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            }),
        })
    }

    /// Records the resolve of the rectangle `vp` whose lists are in `lists` (built along
    /// `frame`), adding to the target's sums. `coincident` is the scene's coincident-depth
    /// tolerance (`CpuScene::coincident_depth`).
    #[allow(clippy::too_many_arguments)]
    pub fn encode(
        &self,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        triangles: &GpuTriangles,
        target: &ResolveTarget,
        frame: &BundleFrame,
        vp: &Viewport,
        lists: &ListBuffers,
        sky: Rgb,
        coincident: f32,
        fixed: FixedPoint,
    ) {
        let device = &gpu.device;
        let params = ResolveParams {
            t: frame.t.to_array(),
            pixel: vp.pixel,
            b: frame.b.to_array(),
            width: vp.width,
            dir: frame.dir.to_array(),
            height: vp.height,
            origin: vp.origin.to_array(),
            offset: [vp.offset.0, vp.offset.1],
            sky: sky.to_array(),
            a_px: vp.pixel_area(),
            rect: target.rect,
            blocks_x: target.blocks_x,
            uv_scale: (1u64 << target.lod) as f32,
            coincident,
            radiance_scale: fixed.radiance,
            area_scale: fixed.area,
            one: 1.0,
            _pad1: 0,
            _pad2: 0,
        };
        let params = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("bundle resolve params"),
            contents: bytemuck::bytes_of(&params),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let buffers = [
            &params,
            &triangles.corners,
            &target.normals,
            &target.faces,
            &target.table,
            &target.own,
            &lists.heads,
            &lists.nodes,
            &lists.links,
            &target.sums,
            &target.flags,
        ];
        let entries: Vec<_> = buffers
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupEntry { binding: i as u32, resource: b.as_entire_binding() })
            .collect();
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("bundle resolve"),
            layout: &self.layout,
            entries: &entries,
        });
        let mut pass = encoder
            .begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("bundle resolve"), timestamp_writes: None });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &group, &[]);
        pass.dispatch_workgroups(vp.width.div_ceil(8), vp.height.div_ceil(8), 1);
    }
}

impl ResolveTarget {
    /// Uploads the source radiance of the target's texels (what the bundles see of them).
    pub fn set_source(&self, gpu: &GpuContext, own: &[Rgb]) {
        debug_assert_eq!(own.len(), self.texels as usize);
        let data: Vec<[f32; 4]> = own.iter().map(|l| [l.x, l.y, l.z, 0.0]).collect();
        if !data.is_empty() {
            gpu.queue.write_buffer(&self.own, 0, bytemuck::cast_slice(&data));
        }
    }

    /// Records zeroing the sums and flags (before a batch).
    pub fn clear(&self, encoder: &mut wgpu::CommandEncoder) {
        encoder.clear_buffer(&self.sums, 0, None);
        encoder.clear_buffer(&self.flags, 0, None);
    }

    /// Reads the sums back as the CPU backend's per-texel (Σ a·L rgb, Σ a), and the flags.
    pub fn read(&self, gpu: &GpuContext, fixed: FixedPoint) -> Result<(Vec<[f32; 4]>, ResolveFlags), GpuError> {
        let bytes = 32 * self.texels.max(1) as u64;
        let staging = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bundle sums read-back"),
            size: bytes + 16,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(&self.sums, 0, &staging, 0, bytes);
        encoder.copy_buffer_to_buffer(&self.flags, 0, &staging, bytes, 16);
        gpu.queue.submit([encoder.finish()]);
        let data = gpu.read_buffer(&staging, bytes + 16)?;
        let words: &[u32] = bytemuck::cast_slice(&data);
        let value = |w: &[u32], scale: f32| ((w[1] as u64) << 32 | w[0] as u64) as f64 / scale as f64;
        let sums = words[..8 * self.texels as usize]
            .chunks_exact(8)
            .map(|w| {
                [
                    value(&w[0..2], fixed.radiance) as f32,
                    value(&w[2..4], fixed.radiance) as f32,
                    value(&w[4..6], fixed.radiance) as f32,
                    value(&w[6..8], fixed.area) as f32,
                ]
            })
            .collect();
        let f = &words[8 * self.texels.max(1) as usize..];
        let flags = ResolveFlags { saturated: f[0], lost_lookups: f[1], truncated_pixels: f[2], covered_pixels: f[3] };
        Ok((sums, flags))
    }
}

/// The brightest of `own` and `sky`: the radiance bound of [`FixedPoint::for_hits`].
pub fn max_radiance(own: &[Rgb], sky: Rgb) -> f32 {
    own.iter().fold(sky.max_element(), |m, l| m.max(l.max_element()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atlas::texels::TexelMap;
    use crate::bundle::estimator::{HitSink, exchange, is_own};
    use crate::bundle::target::{BakeTarget, target_triangles};
    use crate::cpu::CpuScene;
    use crate::cpu::fragments::TileFragments;
    use crate::gpu::bundle_analysis::tests::cornell;
    use crate::gpu::bundle_lists::ListPass;
    use crate::gpu::bundle_lists::tests::planned;
    use crate::sampling::Rng;

    struct Sums<'a>(&'a mut [[f32; 4]], &'a mut [u32]);

    impl HitSink for Sums<'_> {
        fn hit(&mut self, texel: u32, l: Rgb, a: f32) {
            let s = &mut self.0[texel as usize];
            s[0] += l.x;
            s[1] += l.y;
            s[2] += l.z;
            s[3] += a;
            self.1[texel as usize] += 1;
        }
    }

    struct Setup {
        gpu: GpuContext,
        scene: std::sync::Arc<CpuScene>,
        texels: TexelMap,
        tables: Vec<TexelTable>,
        own: Vec<Rgb>,
        sky: Rgb,
    }

    fn setup() -> Setup {
        let gpu = GpuContext::headless().expect("a Vulkan adapter (lavapipe: mesa-vulkan-drivers)");
        let scene = cornell();
        let b = &scene.bundle;
        let texels = TexelMap::build(&b.scene, &b.geom, &b.atlas, 0);
        let tables = vec![TexelTable::of_map(&texels)];
        let mut rng = Rng::new(17, 3);
        let own: Vec<Rgb> =
            (0..texels.face.len()).map(|_| Rgb::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0).collect();
        Setup { gpu, scene, texels, tables, own, sky: Rgb::new(0.3, 0.5, 0.8) }
    }

    /// The GPU resolve of the planned tiles of three Cornell-box directions (LOD 0, every
    /// texel a target, random per-texel source radiance, a coloured sky) against the CPU
    /// backend's `TileFragments::resolve` + `estimator::exchange` of the same tiles.
    ///
    /// Fixed-point bound, per texel and sum of n hits: |GPU − CPU| ≤ n·2⁻²³·Σ (the CPU's f32
    /// additions, each rounding by at most half an ulp of a running sum ≤ Σ; the GPU's integer
    /// sum is exact) + n/S (the GPU truncates each hit to 1/S). It holds for every texel whose
    /// fragments look up the same texels as on the CPU. A lookup lands on the other side of a
    /// texel border where the UV planes, evaluated in f32 by the driver's code, round one ulp
    /// apart from the CPU's: measured on lavapipe 126 texels with other hits (≈ 100 of 3.8 M
    /// hits moved to a neighbouring texel) and 186 sums (≈ 62 texels) that saw a neighbouring
    /// texel's (random) radiance; asserted: at most 1 in 1000 texels, 1 in 10⁴ hits. Not from
    /// the raster (the lists of all 469 tiles are equal to the CPU's) nor the divisions (f64
    /// divisions rounded to f32 gave the same counts) nor fused multiply-adds (forcing every
    /// product to round before its add changed nothing): not located further.
    #[test]
    fn resolve_matches_the_cpu_exchange_on_the_cornell_box() {
        let s = setup();
        let (gpu, scene) = (&s.gpu, &*s.scene);
        let b = &scene.bundle;
        let n_texels = s.texels.face.len();
        let triangles = target_triangles(&b.atlas, &s.texels.face);
        let target = BakeTarget {
            lod: 0,
            face: &s.texels.face,
            emission: &s.texels.emission,
            tables: &s.tables,
            window: None,
            triangles: &triangles,
        };
        let tris = GpuTriangles::new(gpu, &b.geom.corners);
        let lists = ListPass::new(gpu).unwrap();
        let out = lists.buffers(gpu, 128, 1 << 20).unwrap();
        let resolve = ResolvePass::new(gpu).unwrap();
        let gpu_target = resolve.target(gpu, &b.geom, &b.atlas, 0, &s.tables[0], n_texels).unwrap();
        gpu_target.set_source(gpu, &s.own);
        let receiver: Vec<bool> = scene.density.iter().map(|&d| d > 0.0).collect();
        let all: Vec<u32> = (0..b.geom.len() as u32).collect();
        let mut cpu = vec![[0f32; 4]; n_texels];
        let mut hits = vec![0u32; n_texels];
        let mut fragments = TileFragments::default();
        let mut work = Vec::new();
        for i in 0..3 {
            let (frame, viewports) = planned(scene, i, 128, 1 << 20);
            work.extend(viewports.into_iter().map(|vp| (frame, vp)));
        }
        let max_area = work.iter().map(|(_, vp)| vp.pixel_area()).fold(0.0, f32::max);
        let fixed = FixedPoint::for_hits(max_area, max_radiance(&s.own, s.sky));
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        gpu_target.clear(&mut encoder);
        gpu.queue.submit([encoder.finish()]);
        for (frame, vp) in &work {
            fragments.prepare(scene, frame, vp, &all, None, |t| receiver[t as usize]);
            let a_px = vp.pixel_area();
            let mut sink = Sums(&mut cpu, &mut hits);
            let own = &s.own;
            fragments.resolve(scene, &target, |f, _, _, _| {
                exchange(f, a_px, s.sky, |code| if is_own(code) { own[code as usize] } else { Rgb::ZERO }, &mut sink)
            });
            lists.build(gpu, &tris, frame, vp, &out).unwrap();
            let mut encoder = gpu.device.create_command_encoder(&Default::default());
            resolve.encode(
                gpu,
                &mut encoder,
                &tris,
                &gpu_target,
                frame,
                vp,
                &out,
                s.sky,
                scene.coincident_depth,
                fixed,
            );
            gpu.queue.submit([encoder.finish()]);
        }
        let (got, flags) = gpu_target.read(gpu, fixed).unwrap();
        gpu.take_error().unwrap();
        // Per texel: Σa equal within the bound (the same hits), then each Σ a·L within it too
        // (the same neighbours seen); or Σa off by whole hits (a hit's UV on the other side of
        // a texel border, see the test's doc).
        let (mut moved, mut moved_hits, mut other, mut worst, mut worst_e, mut hit_texels) =
            (0, 0f64, 0, 0f64, 0f64, 0);
        let within = |t: usize, c: usize| {
            let n = hits[t] as f64;
            let (g, w) = (got[t][c] as f64, cpu[t][c] as f64);
            let scale = if c == 3 { fixed.area } else { fixed.radiance } as f64;
            let bound = n * 2f64.powi(-23) * w.abs() + n / scale + 1e-30;
            ((g - w).abs() <= bound, (g - w).abs() / bound)
        };
        for t in 0..n_texels {
            hit_texels += (hits[t] > 0) as usize;
            if !within(t, 3).0 {
                moved += 1;
                moved_hits += (got[t][3] as f64 - cpu[t][3] as f64).abs() / max_area as f64;
                continue;
            }
            for c in 0..3 {
                let (ok, ratio) = within(t, c);
                other += !ok as usize;
                worst = worst.max(ratio);
            }
            if cpu[t][3] > 0.0 {
                for c in 0..3 {
                    let (eg, ec) = (got[t][c] as f64 / got[t][3] as f64, cpu[t][c] as f64 / cpu[t][3] as f64);
                    worst_e = worst_e.max((eg - ec).abs() / ec.abs().max(1e-12));
                }
            }
        }
        let total_hits: u64 = hits.iter().map(|&h| h as u64).sum();
        eprintln!(
            "resolve twin: {} tiles, {hit_texels} of {n_texels} texels hit, {total_hits} hits; texels with other hits: \
             {moved} (≈ {moved_hits:.0} largest-pixel hits moved); of the rest, Σa·L beyond the bound: {other}, worst \
             |GPU − CPU| / bound {worst:.3}, worst relative difference of Σa·L/Σa {worst_e:.2e}; {flags:?}; fixed \
             point 1/{} (radiance), 1/{} (area)",
            work.len(),
            fixed.radiance,
            fixed.area
        );
        assert!(hit_texels * 2 > n_texels, "the directions reach most texels");
        assert_eq!(flags.saturated, 0);
        assert_eq!(flags.truncated_pixels, 0);
        assert!(moved * 1000 <= hit_texels, "{moved} texels with other hits");
        assert!(moved_hits * 1e4 <= total_hits as f64, "{moved_hits} hits moved");
        assert!(other * 1000 <= 3 * hit_texels, "{other} radiance sums beyond the rounding bound");
    }

    /// Scales 2³¹ times too fine make each hit about 2⁶³ units: texels hit twice overflow 64
    /// bits, are counted saturated and read back pinned near the top (≥ 2⁶³ units), never
    /// wrapped to a small value.
    #[test]
    fn saturating_sums_are_pinned_and_counted() {
        let s = setup();
        let (gpu, scene) = (&s.gpu, &*s.scene);
        let b = &scene.bundle;
        let n_texels = s.texels.face.len();
        let tris = GpuTriangles::new(gpu, &b.geom.corners);
        let lists = ListPass::new(gpu).unwrap();
        let out = lists.buffers(gpu, 128, 1 << 20).unwrap();
        let resolve = ResolvePass::new(gpu).unwrap();
        let gpu_target = resolve.target(gpu, &b.geom, &b.atlas, 0, &s.tables[0], n_texels).unwrap();
        let bright = vec![Rgb::ONE; n_texels];
        gpu_target.set_source(gpu, &bright);
        let (frame, viewports) = planned(scene, 0, 128, 1 << 20);
        let vp = viewports[viewports.len() / 2];
        let fine = FixedPoint::for_hits(vp.pixel_area(), 1.0);
        let fixed = FixedPoint { radiance: fine.radiance * 2f32.powi(31), area: fine.area * 2f32.powi(31) };
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        gpu_target.clear(&mut encoder);
        gpu.queue.submit([encoder.finish()]);
        lists.build(gpu, &tris, &frame, &vp, &out).unwrap();
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        resolve.encode(
            gpu,
            &mut encoder,
            &tris,
            &gpu_target,
            &frame,
            &vp,
            &out,
            Rgb::ONE,
            scene.coincident_depth,
            fixed,
        );
        gpu.queue.submit([encoder.finish()]);
        let (sums, flags) = gpu_target.read(gpu, fixed).unwrap();
        assert!(flags.saturated > 0, "{flags:?}");
        // A texel hit more than twice (more than 2⁶⁴ units) must read at the top, not wrapped.
        let unit = 1.0 / fixed.area as f64;
        let pinned = sums.iter().filter(|s| s[3] as f64 >= 2f64.powi(63) * unit).count();
        let small = sums.iter().filter(|s| s[3] > 0.0 && (s[3] as f64) < 0.9 * vp.pixel_area() as f64).count();
        eprintln!("saturation: {flags:?}, {pinned} texels pinned at the top, {small} below one hit");
        assert!(pinned > 0);
        assert_eq!(small, 0, "a saturated sum wrapped around");
    }
}
