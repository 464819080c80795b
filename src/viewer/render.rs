//! The viewer's renderer: the scene and the shown light map on the GPU, drawn by the
//! surface pass into a window's frame or an offscreen target (same pipeline, same result).

use std::sync::Arc;

use image::RgbaImage;

use super::camera::Camera;
use super::source::{LightSource, SceneState};
use crate::gpu::layout::{FrameUniforms, ViewMode};
use crate::gpu::lightmap::{self, LightmapGpu, SyncReport};
use crate::gpu::scene::{SceneGpu, material_bind_group_layout};
use crate::gpu::sky::sky_bind_group_layout;
use crate::gpu::surface::{EyeView, RADIANCE_FORMAT, SurfacePass};
use crate::gpu::target::{OFFSCREEN_FORMAT, OffscreenTarget};
use crate::gpu::tone_map::{RadianceTarget, ToneMapPass};
use crate::gpu::{GpuContext, GpuError};
use crate::grid::Grid;
use crate::runtime::shown::ShownLightmap;

/// How a frame is drawn, beyond the camera.
#[derive(Clone, Copy, Debug)]
pub struct DrawSettings {
    pub view_mode: ViewMode,
    /// Radiance scale before the tone curve.
    pub exposure: f32,
    /// Side-by-side stereo with this interpupillary distance (metres).
    pub stereo_ipd: Option<f32>,
}

impl Default for DrawSettings {
    fn default() -> Self {
        DrawSettings { view_mode: ViewMode::Lit, exposure: 1.0, stereo_ipd: None }
    }
}

/// An exposure that shows `shown` well: 1.5 over the 99th-percentile of E/π (the radiance
/// of a white surface) over LOD 0's published pixels (both layers), as the light-map
/// previews do.
pub fn auto_exposure(shown: &ShownLightmap) -> f32 {
    let mut lum: Vec<f32> = match shown.published_rect(0) {
        Some(rect) => shown.level_pixels(0, rect),
        None => Vec::new(),
    }
    .into_iter()
    .filter(|e| e.max_element() > 0.0)
    .map(|e| (0.2126 * e.x + 0.7152 * e.y + 0.0722 * e.z) * std::f32::consts::FRAC_1_PI)
    .filter(|l| l.is_finite())
    .collect();
    if lum.is_empty() {
        return 1.0;
    }
    let i = (lum.len() * 99 / 100).min(lum.len() - 1);
    let (_, p99, _) = lum.select_nth_unstable_by(i, f32::total_cmp);
    if *p99 > 0.0 { 1.5 / *p99 } else { 1.0 }
}

/// The eyes of one frame of `width × height` pixels: one, or two side by side.
pub fn eye_views(camera: &Camera, width: u32, height: u32, settings: &DrawSettings) -> Vec<EyeView> {
    let (w, h) = (width as f32, height as f32);
    let frame = |offset: f32, aspect: f32| FrameUniforms {
        view_proj: camera.view_proj(aspect, offset).to_cols_array_2d(),
        inv_view_proj: camera.view_proj(aspect, offset).inverse().to_cols_array_2d(),
        eye: camera.eye.to_array(),
        exposure: settings.exposure,
        view_mode: settings.view_mode as u32,
        _pad0: 0,
        _pad1: 0,
        _pad2: 0,
    };
    match settings.stereo_ipd {
        None => vec![EyeView { frame: frame(0.0, w / h), viewport: [0.0, 0.0, w, h] }],
        Some(ipd) => {
            let half = (w / 2.0).floor();
            vec![
                EyeView { frame: frame(-0.5 * ipd, half / h), viewport: [0.0, 0.0, half, h] },
                EyeView { frame: frame(0.5 * ipd, half / h), viewport: [half, 0.0, w - half, h] },
            ]
        }
    }
}

/// A map with no pages (before the first light): E = 0 everywhere, emission still shows.
fn unlit_map(atlas_width: u32, atlas_height: u32) -> ShownLightmap {
    let grid = Grid { origin: glam::Vec3::ZERO, cell_size: 1.0, dims: [1, 1, 1] };
    ShownLightmap::new(grid, atlas_width, atlas_height, 1, 0.0)
}

pub struct Renderer {
    pub gpu: GpuContext,
    pub lightmap_layout: wgpu::BindGroupLayout,
    material_layout: wgpu::BindGroupLayout,
    sky_layout: wgpu::BindGroupLayout,
    /// One surface pass per colour format drawn to: the HDR target's, the window's and the
    /// offscreen one.
    passes: Vec<SurfacePass>,
    tone_map: ToneMapPass,
    /// The surface pass's target, of the last frame's size.
    radiance: Option<RadianceTarget>,
    scene_generation: u64,
    pub scene: SceneGpu,
    pub lightmap: LightmapGpu,
    /// The snapshot the GPU mirror holds (`None`: the unlit map).
    pub shown: Option<Arc<ShownLightmap>>,
    /// What the last [`Renderer::update`] uploaded.
    pub last_sync: SyncReport,
}

impl Renderer {
    pub fn new(gpu: GpuContext, state: &SceneState) -> Result<Renderer, GpuError> {
        let lightmap_layout = lightmap::bind_group_layout(&gpu.device);
        let material_layout = material_bind_group_layout(&gpu.device);
        let sky_layout = sky_bind_group_layout(&gpu.device);
        let scene = SceneGpu::new(&gpu, &material_layout, &sky_layout, &state.scene, &state.atlas);
        let lightmap = LightmapGpu::new(&gpu, &lightmap_layout, &unlit_map(state.atlas.width, state.atlas.height))?;
        let tone_map = ToneMapPass::new(&gpu)?;
        Ok(Renderer {
            gpu,
            lightmap_layout,
            material_layout,
            sky_layout,
            passes: Vec::new(),
            tone_map,
            radiance: None,
            scene_generation: state.generation,
            scene,
            lightmap,
            shown: None,
            last_sync: SyncReport::default(),
        })
    }

    /// Takes the source's current scene and light map (partial upload of what changed).
    pub fn update(&mut self, source: &dyn LightSource) -> Result<(), GpuError> {
        let state = source.scene();
        if state.generation != self.scene_generation {
            self.scene = SceneGpu::new(&self.gpu, &self.material_layout, &self.sky_layout, &state.scene, &state.atlas);
            self.scene_generation = state.generation;
        }
        self.last_sync = SyncReport::default();
        if let Some(shown) = source.shown() {
            self.show(shown)?;
        }
        Ok(())
    }

    /// Mirrors `shown` on the GPU unless it is the snapshot already held.
    pub fn show(&mut self, shown: Arc<ShownLightmap>) -> Result<(), GpuError> {
        if self.shown.as_ref().is_some_and(|s| Arc::ptr_eq(s, &shown)) {
            return Ok(());
        }
        self.last_sync = self.lightmap.sync(&self.gpu, &self.lightmap_layout, &shown)?;
        self.shown = Some(shown);
        Ok(())
    }

    /// The surface pass for `format` (pipelines are made once per format).
    fn pass_index(&mut self, format: wgpu::TextureFormat) -> Result<usize, GpuError> {
        if let Some(i) = self.passes.iter().position(|p| p.color_format == format) {
            return Ok(i);
        }
        let layouts = [&self.lightmap_layout, &self.material_layout, &self.sky_layout];
        self.passes.push(SurfacePass::new(&self.gpu, format, layouts)?);
        Ok(self.passes.len() - 1)
    }

    /// Records the frame's draw into `encoder`, onto `color` (`format`, `width × height`, as
    /// `depth` is): straight, or for a scene with sheets into the radiance target and then
    /// through the tone-map pass.
    #[allow(clippy::too_many_arguments)]
    pub fn draw(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        format: wgpu::TextureFormat,
        color: &wgpu::TextureView,
        depth: &wgpu::TextureView,
        (width, height): (u32, u32),
        eyes: &[EyeView],
    ) -> Result<(), GpuError> {
        if !self.scene.has_sheets {
            let i = self.pass_index(format)?;
            self.passes[i].draw(&self.gpu, encoder, color, depth, &self.scene, &self.lightmap, eyes);
            return Ok(());
        }
        let i = self.pass_index(RADIANCE_FORMAT)?;
        if self.radiance.as_ref().is_none_or(|r| (r.width, r.height) != (width, height)) {
            self.radiance = Some(self.tone_map.target(&self.gpu, width, height));
        }
        let Some(radiance) = &self.radiance else { return Ok(()) };
        self.passes[i].draw(&self.gpu, encoder, &radiance.view, depth, &self.scene, &self.lightmap, eyes);
        self.tone_map.draw(&self.gpu, encoder, radiance, format, color);
        Ok(())
    }

    /// Renders one frame offscreen and reads it back.
    pub fn render_offscreen(
        &mut self,
        camera: &Camera,
        width: u32,
        height: u32,
        settings: &DrawSettings,
    ) -> Result<RgbaImage, GpuError> {
        let target = OffscreenTarget::new(&self.gpu, width, height);
        let eyes = eye_views(camera, width, height, settings);
        let mut encoder =
            self.gpu.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("offscreen") });
        self.draw(&mut encoder, OFFSCREEN_FORMAT, &target.color_view, &target.depth_view, (width, height), &eyes)?;
        self.gpu.queue.submit([encoder.finish()]);
        let image = target.read(&self.gpu)?;
        self.gpu.take_error()?;
        Ok(image)
    }
}
