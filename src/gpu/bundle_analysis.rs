//! The analysis pass of the GPU bundle backend (paper Sect. 4.1–4.2): an orthographic raster
//! of one direction's R×R window whose fragment stage takes the max of the triangle's
//! importance (`atomicMax` on positive f32 bits) and counts fragments (`atomicAdd`), then a
//! compute pass marking the centroid pixel of triangles that covered no pixel centre. The
//! twin of `cpu::analysis::Analysis` (its maps, not its triangle bins: the GPU backend does
//! not gather per tile on the host). The mips follow in [`super::bundle_mips`].
//!
//! **Agreement with the CPU.** Both snap corners to 1/256 pixel and sample pixel centres with
//! the top-left fill rule (Vulkan's, and `bundle::raster`'s). The shader snaps the corners
//! itself and draws into a viewport V×V pixels wide ([`view_side`], the device's texture
//! limit) centred on the attachment's corner, so the viewport transform is exact, the
//! rasteriser's own 8-bit snap is exact, and corners within V/2 pixels of the window are not
//! clipped (a clipper makes new corners off the 1/256 grid and moves edges). What remains is
//! the corners' grid positions themselves: CPU and GPU compute `(p·t − origin)/pixel` in f32,
//! possibly rounded differently (fused multiply-adds), so a corner within an ulp of a
//! 1/512-pixel rounding boundary can snap one 1/256 step apart, and a pixel centre within that
//! step of the edge then changes sides. The tests measure this on the bundled Cornell box.

use glam::Vec3;
use wgpu::util::DeviceExt;

use super::GpuError;
use super::bundle_mips::AnalysisMaps;
use super::device::GpuContext;
use super::layout::AnalysisParams;
use super::pass::{self, READ, UNIFORM, WRITE};
use super::shader;
use crate::bundle::raster::{BundleFrame, Viewport};

/// The scene's triangles on the GPU, for every bundle pass: corners and per-triangle
/// importance (rays per m², set per target).
pub struct GpuTriangles {
    pub corners: wgpu::Buffer,
    pub importance: wgpu::Buffer,
    /// Every triangle index 0..count (what a whole-scene window draws).
    pub all: wgpu::Buffer,
    pub count: u32,
}

impl GpuTriangles {
    pub fn new(gpu: &GpuContext, corners: &[[Vec3; 3]]) -> GpuTriangles {
        let device = &gpu.device;
        let count = corners.len() as u32;
        // Bindings may not be empty: a scene without triangles still gets one dummy entry.
        let mut flat: Vec<[f32; 4]> = corners.iter().flatten().map(|p| [p.x, p.y, p.z, 1.0]).collect();
        if flat.is_empty() {
            flat.push([0.0; 4]);
        }
        let corners = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("bundle corners"),
            contents: bytemuck::cast_slice(&flat),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let importance = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bundle importance"),
            size: 4 * count.max(1) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let all: Vec<u32> = (0..count.max(1)).collect();
        let all = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("bundle triangle ids"),
            contents: bytemuck::cast_slice(&all),
            usage: wgpu::BufferUsages::STORAGE,
        });
        GpuTriangles { corners, importance, all, count }
    }

    /// Uploads per-triangle importance (rays per m²; 0 outside the target).
    pub fn set_importance(&self, gpu: &GpuContext, importance: &[f32]) {
        debug_assert_eq!(importance.len(), self.count as usize);
        if !importance.is_empty() {
            gpu.queue.write_buffer(&self.importance, 0, bytemuck::cast_slice(importance));
        }
    }
}

/// Which triangles a direction draws.
#[derive(Clone, Copy)]
pub enum Drawn<'a> {
    /// Every triangle (a whole-scene window).
    All,
    /// These triangle ids (a cell window's candidates), uploaded for this pass.
    Some(&'a [u32]),
    /// Triangle ids uploaded once for several passes (one direction's window).
    Uploaded(&'a DrawnIds),
}

/// Triangle ids on the GPU: what a direction's passes draw.
pub struct DrawnIds {
    buffer: wgpu::Buffer,
    count: u32,
}

impl DrawnIds {
    pub fn new(gpu: &GpuContext, ids: &[u32]) -> DrawnIds {
        // Bindings may not be empty.
        let contents: Vec<u32> = if ids.is_empty() { vec![0] } else { ids.to_vec() };
        let buffer = gpu.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("bundle drawn triangles"),
            contents: bytemuck::cast_slice(&contents),
            usage: wgpu::BufferUsages::STORAGE,
        });
        DrawnIds { buffer, count: ids.len() as u32 }
    }
}

impl Drawn<'_> {
    /// The id buffer and count to bind: `owned` keeps a buffer made for [`Drawn::Some`].
    pub fn binding<'b>(
        self,
        gpu: &GpuContext,
        triangles: &'b GpuTriangles,
        owned: &'b mut Option<DrawnIds>,
    ) -> (&'b wgpu::Buffer, u32)
    where
        Self: 'b,
    {
        match self {
            Drawn::All => (&triangles.all, triangles.count),
            Drawn::Some(list) => {
                let ids = owned.insert(DrawnIds::new(gpu, list));
                (&ids.buffer, ids.count)
            }
            Drawn::Uploaded(ids) => (&ids.buffer, ids.count),
        }
    }
}

/// The analysis raster and its centroid touch.
pub struct AnalysisPass {
    layout: wgpu::BindGroupLayout,
    raster: wgpu::RenderPipeline,
    touch: wgpu::ComputePipeline,
}

impl AnalysisPass {
    pub fn new(gpu: &GpuContext) -> Result<AnalysisPass, GpuError> {
        gpu.require_fragment_storage()?;
        let device = &gpu.device;
        let all = wgpu::ShaderStages::VERTEX | wgpu::ShaderStages::FRAGMENT | wgpu::ShaderStages::COMPUTE;
        let written = wgpu::ShaderStages::FRAGMENT | wgpu::ShaderStages::COMPUTE;
        let layout = pass::buffer_layout(
            device,
            "bundle analysis",
            &[
                (all, UNIFORM),
                (all, READ),
                (all, READ),
                (all, READ),
                (written, WRITE),
                (written, WRITE),
                (written, WRITE),
            ],
        );
        let pipeline_layout = pass::single_group(device, "bundle analysis", &layout);
        let module = shader::module(device, "bundle_analysis.wgsl")?;
        let raster = pass::bundle_raster(device, "bundle analysis raster", &pipeline_layout, &module);
        let touch = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("bundle analysis touch"),
            layout: Some(&pipeline_layout),
            module: &module,
            entry_point: Some("touch"),
            compilation_options: Default::default(),
            cache: None,
        });
        gpu.take_error()?;
        Ok(AnalysisPass { layout, raster, touch })
    }

    /// Records the analysis of one direction into `maps` (level 0 of both chains: importance
    /// bits and fragment counts; run the mip passes of `bundle_mips` after it): clears, raster, touch.
    #[allow(clippy::too_many_arguments)]
    pub fn encode(
        &self,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        triangles: &GpuTriangles,
        drawn: Drawn,
        frame: &BundleFrame,
        viewport: &Viewport,
        maps: &AnalysisMaps,
    ) {
        let device = &gpu.device;
        let res = maps.side();
        debug_assert_eq!(viewport.width, res);
        let mut owned = None;
        let (ids, count) = drawn.binding(gpu, triangles, &mut owned);
        let corner = viewport.corner();
        let params = AnalysisParams {
            t: frame.t.to_array(),
            pixel: viewport.pixel,
            b: frame.b.to_array(),
            res,
            origin: corner.to_array(),
            drawn_count: count,
            view_side: view_side(gpu),
        };
        let params = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("bundle analysis params"),
            contents: bytemuck::bytes_of(&params),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let covered = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bundle covered triangles"),
            size: 4 * count.max(1) as u64,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("bundle analysis"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: params.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: triangles.corners.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 2, resource: triangles.importance.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 3, resource: ids.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 4, resource: maps.importance.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 5, resource: maps.fragments.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 6, resource: covered.as_entire_binding() },
            ],
        });
        let level0 = 4 * res as u64 * res as u64;
        encoder.clear_buffer(&maps.importance, 0, Some(level0));
        encoder.clear_buffer(&maps.fragments, 0, Some(level0));
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("bundle analysis raster"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &maps.target,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Discard,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            if count > 0 {
                set_view(&mut pass, gpu);
                pass.set_pipeline(&self.raster);
                pass.set_bind_group(0, &group, &[]);
                pass.draw(0..3 * count, 0..1);
            }
        }
        if count > 0 {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("bundle analysis touch"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.touch);
            pass.set_bind_group(0, &group, &[]);
            pass.dispatch_workgroups(count.div_ceil(64), 1, 1);
        }
    }
}

/// Side V of the bundle rasters' viewport: the largest power of two the device's texture
/// limit allows, at most 2^15 (snapped coordinates up to V/2 keep 8 fractional bits in f32).
pub fn view_side(gpu: &GpuContext) -> u32 {
    let max = gpu.device.limits().max_texture_dimension_2d.clamp(1, 1 << 15);
    1 << (31 - max.leading_zeros())
}

/// Sets the V×V viewport centred on the attachment's corner (pixel (0, 0) of the window is
/// framebuffer pixel (0, 0); the viewport transform has no offset, see bundle_analysis.wgsl).
pub fn set_view(pass: &mut wgpu::RenderPass<'_>, gpu: &GpuContext) {
    let v = view_side(gpu) as f32;
    pass.set_viewport(-v / 2.0, -v / 2.0, v, v, 0.0, 1.0);
}

/// The colour attachment of an R×R analysis raster (nothing is stored in it).
pub fn analysis_target(gpu: &GpuContext, res: u32) -> wgpu::TextureView {
    let texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("bundle analysis target"),
        size: wgpu::Extent3d { width: res, height: res, depth_or_array_layers: 1 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: pass::RASTER_TARGET_FORMAT,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
        view_formats: &[],
    });
    texture.create_view(&wgpu::TextureViewDescriptor::default())
}

#[cfg(test)]
pub(crate) mod tests {
    use std::sync::Arc;

    use glam::Vec2;

    use super::*;
    use crate::atlas::{Atlas, AtlasConfig};
    use crate::bundle::directions::BundleDirections;
    use crate::bundle::mips::MipChain;
    use crate::bundle::{BundleConfig, BundleScene};
    use crate::cpu::CpuScene;
    use crate::cpu::analysis::Analysis;
    use crate::gpu::bundle_mips::MipPass;
    use crate::scene::SceneGeometry;

    pub(crate) fn cornell() -> Arc<CpuScene> {
        bundled("cornell_box/cornellBox-2.79-Cycles-gltf.gltf")
    }

    /// A bundled scene (`assets/PATH`) with default atlas and bundle settings.
    pub(crate) fn bundled(path: &str) -> Arc<CpuScene> {
        let path = format!("{}/assets/{path}", env!("CARGO_MANIFEST_DIR"));
        let scene = Arc::new(crate::scene::load_gltf(path.as_ref(), &Default::default()).expect("bundled scene"));
        let geom = SceneGeometry::new(&scene);
        let atlas = Atlas::build(&scene, &geom, &AtlasConfig::default()).expect("atlas");
        let bundle = BundleScene::new(scene, Arc::new(geom), Arc::new(atlas), BundleConfig::default());
        Arc::new(CpuScene::new(Arc::new(bundle)))
    }

    /// The whole-scene analysis window of direction `i` (as `cpu::direction` makes it).
    pub(crate) fn window(scene: &CpuScene, dirs: &BundleDirections, i: u64, res: u32) -> (BundleFrame, Viewport) {
        let frame = BundleFrame::new(dirs.direction(i));
        let (r, c) = (scene.radius, frame.coords(scene.centre));
        let corner = Vec2::new(c.x - r, c.y - r);
        let pixel = 2.0 * r / (res - 1) as f32;
        (frame, Viewport::square(corner - dirs.jitter(i) * pixel, pixel, res))
    }

    /// GPU analysis + mips of one direction, read back: (importance levels, fragment levels).
    pub(crate) fn gpu_analysis(
        gpu: &GpuContext,
        tris: &GpuTriangles,
        frame: &BundleFrame,
        vp: &Viewport,
    ) -> (Vec<Vec<f32>>, Vec<Vec<f32>>) {
        let pass = AnalysisPass::new(gpu).unwrap();
        let mips = MipPass::new(gpu).unwrap();
        let mut maps = AnalysisMaps::new(gpu, vp.width).unwrap();
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        pass.encode(gpu, &mut encoder, tris, Drawn::All, frame, vp, &maps);
        mips.encode(gpu, &mut encoder, &mut maps, true);
        gpu.queue.submit([encoder.finish()]);
        let levels = maps.read(gpu).unwrap();
        gpu.take_error().unwrap();
        levels
    }

    /// Per-pixel differences of the GPU analysis from the CPU's: (pixels whose fragment count
    /// differs, largest count difference, pixels whose importance differs).
    fn compare(gpu: &(Vec<Vec<f32>>, Vec<Vec<f32>>), cpu: &Analysis) -> (u64, f32, u64) {
        let (gi, gf) = gpu;
        let (mut counts, mut worst, mut importance) = (0, 0f32, 0);
        for p in 0..cpu.fragments.len() {
            let d = (gf[0][p] - cpu.fragments[p]).abs();
            counts += (d > 0.0) as u64;
            worst = worst.max(d);
            importance += (gi[0][p] != cpu.importance[p]) as u64;
        }
        (counts, worst, importance)
    }

    /// The analysis twin on the bundled Cornell box: 8 directions at R = 128 and 256 over the
    /// whole scene, and 8 cell-sized windows (a quarter of the room, R = 64, every triangle
    /// drawn: most reach outside the window and are clipped). Bound for any rasteriser with
    /// 8-bit sub-pixel precision and the top-left rule: fragment counts and importance equal
    /// to the CPU analysis's at all but 1 in 10⁴ pixels, each of those off by at most 2
    /// fragments (a corner snapped one 1/256 step apart moves the edges of the triangles
    /// sharing it). On lavapipe every pixel is equal (asserted there; before the viewport
    /// was widened to keep corners out of the clipper, 2 of the cell windows' 163 840 pixels
    /// gave an edge centre to the other triangle). Mips of the GPU maps equal the CPU's mips
    /// of the same maps exactly.
    #[test]
    fn analysis_matches_the_cpu_on_the_cornell_box() {
        let gpu = GpuContext::headless().expect("a Vulkan adapter (lavapipe: mesa-vulkan-drivers)");
        let scene = cornell();
        let geom = &scene.bundle.geom;
        let os = scene.bundle.config.oversampling;
        let importance: Vec<f32> = scene.density.iter().map(|d| d * os * os).collect();
        let tris = GpuTriangles::new(&gpu, &geom.corners);
        tris.set_importance(&gpu, &importance);
        let dirs = BundleDirections::new(7);
        let mut cpu = Analysis::default();
        let (mut pixels, mut count_diff, mut importance_diff, mut worst) = (0u64, 0u64, 0u64, 0f32);
        // The same over the whole-scene windows only (nothing clipped).
        let (mut whole_counts, mut whole_importance) = (0u64, 0u64);
        let mut windows = Vec::new();
        for res in [128u32, 256] {
            windows.extend((0..8).map(|i| window(&scene, &dirs, i, res)));
        }
        // Cell-sized windows: a quarter of the whole window's side, off centre.
        for i in 8..16 {
            let (frame, whole) = window(&scene, &dirs, i, 64);
            let pixel = whole.pixel / 4.0;
            let corner = whole.origin + Vec2::new(0.3, 0.45) * (whole.pixel * 64.0);
            windows.push((frame, Viewport::square(corner, pixel, 64)));
        }
        for (k, (frame, vp)) in windows.iter().enumerate() {
            let res = vp.width;
            cpu.run(&scene, frame, vp, None, &importance);
            let g = gpu_analysis(&gpu, &tris, frame, vp);
            let total_cpu: f32 = cpu.fragments.iter().sum();
            assert!(total_cpu > (res * res) as f32 * 0.5, "window {k} sees the room");
            let (c, w, i) = compare(&g, &cpu);
            count_diff += c;
            worst = worst.max(w);
            importance_diff += i;
            pixels += (res * res) as u64;
            if k < 16 {
                whole_counts += c;
                whole_importance += i;
            }
            // The mips are exact given the same level 0.
            let (gi, gf) = g;
            let ci = MipChain::max_mips(res, gi[0].clone()).unwrap();
            let cf = MipChain::average_mips(res, gf[0].clone()).unwrap();
            for l in 0..=ci.top_level() {
                assert_eq!(ci.level(l), &gi[l as usize][..], "importance level {l}");
                assert_eq!(cf.level(l), &gf[l as usize][..], "fragment level {l}");
            }
        }
        eprintln!(
            "analysis twin ({}): {pixels} pixels in {} windows, {count_diff} with another fragment count \
             (worst {worst}), {importance_diff} with another importance; whole-scene windows: {whole_counts} and \
             {whole_importance}",
            gpu.info.name,
            windows.len()
        );
        assert!(worst <= 2.0, "a pixel's count differs by {worst}");
        assert!(count_diff * 10_000 <= pixels, "{count_diff} of {pixels} pixels differ in fragment count");
        assert!(importance_diff * 10_000 <= pixels, "{importance_diff} of {pixels} pixels differ in importance");
        if gpu.is_software() {
            assert_eq!((count_diff, importance_diff), (0, 0), "lavapipe rasterises as bundle::raster does");
        }
    }
}
