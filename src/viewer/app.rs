//! The viewer window (winit 0.30): the window and its surface are created in
//! `ApplicationHandler::resumed`; every frame takes the source's light, draws, presents,
//! and updates the title's stats.

use std::collections::HashSet;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::Vec3;
use image::RgbaImage;
use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::{DeviceEvent, ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{KeyCode, PhysicalKey};
use winit::window::{Window, WindowId};

use super::camera::Camera;
use super::render::{DrawSettings, Renderer, eye_views};
use super::source::LightSource;
use crate::gpu::layout::ViewMode;
use crate::gpu::target::{depth_texture, read_texture};
use crate::gpu::{GpuContext, GpuError};
use crate::runtime::shown::Layer;

#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    #[error("cannot open a window (is there a display? `livebake run` works without one): {0}")]
    EventLoop(#[from] winit::error::EventLoopError),
    #[error("cannot create the window: {0}")]
    Window(#[from] winit::error::OsError),
    /// The window, its surface or its GPU device could not be set up (nothing was drawn).
    #[error("{0}")]
    Open(Box<ViewerError>),
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error("the window's surface offers no configuration for this adapter")]
    Surface,
    #[error("no light to show: {0}")]
    Source(String),
    #[error("cannot write the screenshot {path}: {source}")]
    Screenshot { path: PathBuf, source: image::ImageError },
}

#[derive(Clone, Debug)]
pub struct ViewerOptions {
    /// Start pose (eye, target); default: the file's camera or a framing view.
    pub pose: Option<(Vec3, Vec3)>,
    pub settings: DrawSettings,
    /// Window inner size in pixels.
    pub size: (u32, u32),
    /// Exit after this many lit frames (frames drawn once the source has shown light:
    /// a screenshot of the room before its first light would show only its lamps).
    pub frames: Option<u32>,
    /// Write the last frame here (PNG) before exiting.
    pub screenshot: Option<PathBuf>,
    /// When the program started: the first-lit-frame time counts from here.
    pub launched: Instant,
    /// Set the exposure from the first light map shown (`settings.exposure` until then).
    pub auto_exposure: bool,
    /// Most light-map pages the GPU pool may hold (`None`: what the device's largest texture
    /// holds); the source keeps its map within it.
    pub gpu_pages: Option<u32>,
}

impl Default for ViewerOptions {
    fn default() -> Self {
        ViewerOptions {
            pose: None,
            settings: DrawSettings::default(),
            size: (1280, 720),
            frames: None,
            screenshot: None,
            launched: Instant::now(),
            auto_exposure: false,
            gpu_pages: None,
        }
    }
}

/// What a viewer run measured.
#[derive(Clone, Debug, Default)]
pub struct ViewerReport {
    pub frames: u32,
    /// Frames drawn with the source's light.
    pub lit_frames: u32,
    /// Interval between successive frames, seconds.
    pub frame_seconds: Vec<f64>,
    /// The intervals between two successive lit frames (frames before the first light are
    /// paced, see `UNLIT_FRAME_INTERVAL`), seconds.
    pub lit_frame_seconds: Vec<f64>,
    /// From `launched` to the first presented frame that showed the source's light.
    pub first_lit_frame_seconds: Option<f64>,
    pub adapter: String,
    /// Bytes uploaded to the light map's GPU mirror over the run.
    pub lightmap_bytes_uploaded: u64,
    /// Most pages the GPU pool held, and the pages left out of it (a coarser level shown
    /// there) or given up for coarser ones, over the run.
    pub gpu_page_cap: u32,
    pub gpu_pages_left_out: u64,
    pub gpu_pages_given_up: u64,
}

impl ViewerReport {
    /// The `q`-quantile (0..1, nearest rank) of the lit frame times, milliseconds.
    pub fn lit_frame_ms(&self, q: f64) -> Option<f64> {
        let mut v = self.lit_frame_seconds.clone();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        let i = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
        Some(1e3 * v[i])
    }

    /// The figures as JSON (what `livebake view --stats` writes and the bench reads).
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "adapter": self.adapter,
            "frames": self.frames,
            "lit_frames": self.lit_frames,
            "lit_frame_ms": { "median": self.lit_frame_ms(0.5), "p99": self.lit_frame_ms(0.99) },
            "first_lit_frame_seconds": self.first_lit_frame_seconds,
            "lightmap_bytes_uploaded": self.lightmap_bytes_uploaded,
            "gpu_page_cap": self.gpu_page_cap,
            "gpu_pages_left_out": self.gpu_pages_left_out,
            "gpu_pages_given_up": self.gpu_pages_given_up,
        })
    }
}

/// Handed to a frame hook after each presented frame.
pub struct FrameContext<'a> {
    /// Frames presented so far (1 for the first).
    pub frame: u32,
    pub renderer: &'a mut Renderer,
    pub source: &'a mut dyn LightSource,
    pub camera: &'a Camera,
    pub settings: &'a DrawSettings,
    pub size: (u32, u32),
    /// The presented pixels of this frame, when the previous call set `capture_next`.
    pub window_image: Option<RgbaImage>,
    pub capture_next: bool,
}

/// Inspects or changes things after each frame (tests); `false` closes the viewer.
pub type FrameHook<'h> = dyn FnMut(&mut FrameContext) -> Result<bool, GpuError> + 'h;

/// Until the first light there is little to see: a frame this often, so that a software
/// rasteriser (45–70 ms a frame on lavapipe) leaves the cores to the first-light bake.
const UNLIT_FRAME_INTERVAL: Duration = Duration::from_millis(500);
/// How often the viewer looks for the first light between unlit frames: the first lit frame
/// is drawn as soon as the light is there, not at the next unlit frame's time.
const LIGHT_POLL: Duration = Duration::from_millis(10);

const HELP: &str = "WASD/QE move, drag look, wheel speed, Tab orbit, 1-5 views, +/- exposure, P screenshot, Esc quit";

struct WindowState {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    depth: wgpu::TextureView,
    renderer: Renderer,
}

struct App<'a, 'h> {
    source: &'a mut dyn LightSource,
    options: ViewerOptions,
    hook: Option<&'a mut FrameHook<'h>>,
    camera: Camera,
    state: Option<WindowState>,
    error: Option<ViewerError>,
    report: ViewerReport,
    held: HashSet<KeyCode>,
    looking: bool,
    last_frame: Option<Instant>,
    last_frame_lit: bool,
    last_title: Instant,
    capture_next: bool,
    screenshot_key: Option<PathBuf>,
    shots: u32,
}

impl ViewerError {
    /// The viewer could not open at all (no display server reachable, no window, no GPU for
    /// its surface): a front end may do without it. Anything else happened while showing.
    pub fn is_open_failure(&self) -> bool {
        matches!(self, ViewerError::EventLoop(_) | ViewerError::Window(_) | ViewerError::Open(_))
    }
}

/// The viewer's connection to the display server, made before anything else so that a
/// front end learns whether a window can open before it starts work for one. winit allows
/// one per process.
pub struct ViewerLoop {
    event_loop: EventLoop<()>,
}

impl ViewerLoop {
    /// Connects to the display server (X11: `DISPLAY`).
    pub fn open() -> Result<ViewerLoop, ViewerError> {
        let mut builder = EventLoop::builder();
        // Tests drive the viewer from a test thread; X11 allows any thread.
        winit::platform::x11::EventLoopBuilderExtX11::with_any_thread(&mut builder, true);
        let event_loop = builder.build()?;
        event_loop.set_control_flow(ControlFlow::Poll);
        Ok(ViewerLoop { event_loop })
    }

    /// Opens the window on `source` and runs until it closes, `options.frames` frames were
    /// drawn, or the hook says stop.
    pub fn run(
        self,
        source: &mut dyn LightSource,
        options: ViewerOptions,
        hook: Option<&mut FrameHook>,
    ) -> Result<ViewerReport, ViewerError> {
        run_loop(self.event_loop, source, options, hook)
    }
}

/// Opens the viewer on `source` and runs until the window closes, `options.frames` frames
/// were drawn, or the hook says stop.
pub fn run(
    source: &mut dyn LightSource,
    options: ViewerOptions,
    hook: Option<&mut FrameHook>,
) -> Result<ViewerReport, ViewerError> {
    ViewerLoop::open()?.run(source, options, hook)
}

fn run_loop(
    event_loop: EventLoop<()>,
    source: &mut dyn LightSource,
    options: ViewerOptions,
    hook: Option<&mut FrameHook>,
) -> Result<ViewerReport, ViewerError> {
    let state = source.scene();
    let camera = match options.pose {
        Some((eye, target)) => {
            let size = state.scene.bounds().map_or(2.0, |(lo, hi)| (hi - lo).length());
            Camera::look_at(eye, target, 50f32.to_radians(), size)
        }
        None => Camera::initial(&state.scene),
    };
    let mut app = App {
        source,
        options,
        hook,
        camera,
        state: None,
        error: None,
        report: ViewerReport::default(),
        held: HashSet::new(),
        looking: false,
        last_frame: None,
        last_frame_lit: false,
        last_title: Instant::now(),
        capture_next: false,
        screenshot_key: None,
        shots: 0,
    };
    let result = event_loop.run_app(&mut app);
    let stopped = app.source.shutdown();
    if let Some(e) = app.error.take() {
        return Err(e);
    }
    stopped.map_err(ViewerError::Source)?;
    result?;
    if let Some(s) = &app.state {
        let total = &s.renderer.lightmap.total;
        app.report.lightmap_bytes_uploaded = total.bytes_uploaded;
        app.report.gpu_page_cap = s.renderer.lightmap.page_cap();
        app.report.gpu_pages_left_out = total.pages_left_out;
        app.report.gpu_pages_given_up = total.pages_given_up;
    }
    Ok(app.report)
}

impl App<'_, '_> {
    fn fail(&mut self, event_loop: &ActiveEventLoop, e: ViewerError) {
        tracing::error!("{e}");
        self.error.get_or_insert(e);
        event_loop.exit();
    }

    fn open(&mut self, event_loop: &ActiveEventLoop) -> Result<(), ViewerError> {
        let (w, h) = self.options.size;
        let attributes = Window::default_attributes()
            .with_title("livebake")
            .with_inner_size(PhysicalSize::new(w, h))
            .with_resizable(self.options.frames.is_none());
        let window = Arc::new(event_loop.create_window(attributes)?);
        let (gpu, surface) = GpuContext::for_window(Box::new(event_loop.owned_display_handle()), window.clone())?;
        self.report.adapter = gpu.info.name.clone();
        let size = window.inner_size();
        let caps = surface.get_capabilities(&gpu.adapter);
        let mut config = surface
            .get_default_config(&gpu.adapter, size.width.max(1), size.height.max(1))
            .ok_or(ViewerError::Surface)?;
        config.format = caps.formats.iter().copied().find(|f| f.is_srgb()).unwrap_or(config.format);
        // Read-back of the presented image (screenshots) needs COPY_SRC.
        if caps.usages.contains(wgpu::TextureUsages::COPY_SRC) {
            config.usage |= wgpu::TextureUsages::COPY_SRC;
        }
        config.present_mode = wgpu::PresentMode::AutoVsync;
        surface.configure(&gpu.device, &config);
        let depth = depth_texture(&gpu.device, config.width, config.height);
        let mut renderer = Renderer::new(gpu, &self.source.scene())?;
        if let Some(cap) = self.options.gpu_pages {
            renderer.lightmap.set_page_cap(cap);
        }
        self.source.set_page_limit(renderer.lightmap.page_cap() as u64);
        self.state = Some(WindowState { window, surface, config, depth, renderer });
        Ok(())
    }

    fn resize(&mut self, size: PhysicalSize<u32>) {
        let Some(s) = &mut self.state else { return };
        if size.width == 0 || size.height == 0 {
            return;
        }
        s.config.width = size.width;
        s.config.height = size.height;
        s.surface.configure(&s.renderer.gpu.device, &s.config);
        s.depth = depth_texture(&s.renderer.gpu.device, size.width, size.height);
    }

    fn key(&mut self, event_loop: &ActiveEventLoop, code: KeyCode, pressed: bool) {
        if !pressed {
            self.held.remove(&code);
            return;
        }
        self.held.insert(code);
        let settings = &mut self.options.settings;
        match code {
            KeyCode::Escape => event_loop.exit(),
            KeyCode::Tab => self.camera.toggle_mode(),
            KeyCode::Digit1 | KeyCode::Digit2 | KeyCode::Digit3 | KeyCode::Digit4 | KeyCode::Digit5 => {
                let i = [KeyCode::Digit1, KeyCode::Digit2, KeyCode::Digit3, KeyCode::Digit4, KeyCode::Digit5]
                    .iter()
                    .position(|&k| k == code)
                    .unwrap_or(0);
                settings.view_mode = ViewMode::ALL[i];
            }
            KeyCode::Equal | KeyCode::NumpadAdd => settings.exposure *= 1.25,
            KeyCode::Minus | KeyCode::NumpadSubtract => settings.exposure /= 1.25,
            // The sun: azimuth (or a sun study's time of day) and elevation (or its day).
            KeyCode::BracketLeft => self.source.move_sun(-1, 0),
            KeyCode::BracketRight => self.source.move_sun(1, 0),
            KeyCode::PageUp => self.source.move_sun(0, 1),
            KeyCode::PageDown => self.source.move_sun(0, -1),
            KeyCode::KeyP | KeyCode::F12 => {
                self.shots += 1;
                self.screenshot_key = Some(PathBuf::from(format!("livebake-screenshot-{}.png", self.shots)));
                self.capture_next = true;
            }
            _ => {}
        }
    }

    fn travel(&mut self, seconds: f32) {
        let axis = |plus: KeyCode, minus: KeyCode| {
            (self.held.contains(&plus) as i32 - self.held.contains(&minus) as i32) as f32
        };
        let dir = Vec3::new(
            axis(KeyCode::KeyD, KeyCode::KeyA),
            axis(KeyCode::KeyE, KeyCode::KeyQ),
            axis(KeyCode::KeyW, KeyCode::KeyS),
        );
        if dir != Vec3::ZERO {
            let boost = if self.held.contains(&KeyCode::ShiftLeft) { 4.0 } else { 1.0 };
            self.camera.travel(dir, seconds * boost);
        }
    }

    fn frame(&mut self, event_loop: &ActiveEventLoop) -> Result<(), ViewerError> {
        let now = Instant::now();
        if let Some(last) = self.last_frame {
            let dt = now - last;
            self.report.frame_seconds.push(dt.as_secs_f64());
            if self.last_frame_lit {
                self.report.lit_frame_seconds.push(dt.as_secs_f64());
            }
            self.travel(dt.as_secs_f32().min(0.1));
        }
        self.last_frame = Some(now);
        let Some(s) = &mut self.state else { return Ok(()) };
        let (w, h) = (s.config.width, s.config.height);
        self.source.poll();
        self.source.set_camera(&self.camera, w as f32 / h as f32, h);
        s.renderer.update(&*self.source)?;
        // A capture run (`frames`) waits for light; if the source failed none will come.
        if s.renderer.shown.is_none()
            && self.options.frames.is_some()
            && let Some(e) = self.source.status().last_error
        {
            return Err(ViewerError::Source(e));
        }
        if self.options.auto_exposure
            && let Some(shown) = &s.renderer.shown
        {
            self.options.settings.exposure = super::render::auto_exposure(shown);
            self.options.auto_exposure = false;
        }
        let frame = match s.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t) | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            wgpu::CurrentSurfaceTexture::Timeout | wgpu::CurrentSurfaceTexture::Occluded => return Ok(()),
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                s.surface.configure(&s.renderer.gpu.device, &s.config);
                return Ok(());
            }
            other => return Err(GpuError::Validation(format!("cannot acquire a frame: {other:?}")).into()),
        };
        let view = frame.texture.create_view(&wgpu::TextureViewDescriptor::default());
        let eyes = eye_views(&self.camera, w, h, &self.options.settings);
        let gpu = s.renderer.gpu.clone();
        let mut encoder = gpu.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("frame") });
        s.renderer.draw(&mut encoder, s.config.format, &view, &s.depth, (w, h), &eyes)?;
        gpu.queue.submit([encoder.finish()]);
        let lit = s.renderer.shown.is_some();
        let last = lit && self.options.frames.is_some_and(|n| self.report.lit_frames + 1 >= n);
        let capture = self.capture_next || (last && self.options.screenshot.is_some());
        let window_image = if capture && s.config.usage.contains(wgpu::TextureUsages::COPY_SRC) {
            Some(read_texture(&gpu, &frame.texture)?)
        } else if capture {
            // The surface cannot be read: the same frame drawn offscreen.
            Some(s.renderer.render_offscreen(&self.camera, w, h, &self.options.settings)?)
        } else {
            None
        };
        gpu.queue.present(frame);
        gpu.take_error()?;
        self.report.frames += 1;
        self.last_frame_lit = lit;
        if lit {
            self.report.lit_frames += 1;
            if self.report.first_lit_frame_seconds.is_none() {
                self.report.first_lit_frame_seconds = Some(self.options.launched.elapsed().as_secs_f64());
            }
        }
        if let (Some(path), Some(img)) = (self.screenshot_key.take(), &window_image) {
            img.save(&path).map_err(|source| ViewerError::Screenshot { path: path.clone(), source })?;
            tracing::info!("screenshot {}", path.display());
        }
        self.capture_next = false;
        if last {
            if let (Some(path), Some(img)) = (&self.options.screenshot, &window_image) {
                img.save(path).map_err(|source| ViewerError::Screenshot { path: path.clone(), source })?;
            }
            event_loop.exit();
        }
        if let Some(hook) = self.hook.as_mut() {
            let mut ctx = FrameContext {
                frame: self.report.frames,
                renderer: &mut s.renderer,
                source: &mut *self.source,
                camera: &self.camera,
                settings: &self.options.settings,
                size: (w, h),
                window_image,
                capture_next: false,
            };
            if !hook(&mut ctx)? {
                event_loop.exit();
            }
            self.capture_next |= ctx.capture_next;
        }
        if self.last_title.elapsed() > Duration::from_millis(500) {
            self.last_title = Instant::now();
            let title = self.title();
            if let Some(s) = &self.state {
                s.window.set_title(&title);
            }
        }
        Ok(())
    }

    /// Stats and keys: fps, frame ms, cells per LOD, queue, last reload, last error.
    fn title(&self) -> String {
        let recent: Vec<f64> = self.report.frame_seconds.iter().rev().take(30).copied().collect();
        let mean = if recent.is_empty() { 0.0 } else { recent.iter().sum::<f64>() / recent.len() as f64 };
        let fps = if mean > 0.0 { 1.0 / mean } else { 0.0 };
        let status = self.source.status();
        let mut t = format!("livebake | {} | {fps:.0} fps {:.1} ms", status.state, 1e3 * mean);
        if let Some(shown) = self.state.as_ref().and_then(|s| s.renderer.shown.as_ref()) {
            let mut counts = [0usize; 256];
            for &k in shown.layer(Layer::Bundles).cell_lod.iter() {
                counts[k as usize] += 1;
            }
            let per_lod: Vec<String> =
                counts.iter().enumerate().filter(|(_, n)| **n > 0).map(|(k, n)| format!("L{k}:{n}")).collect();
            t += &format!(" | cells {}", per_lod.join(" "));
        }
        if let Some(q) = status.queued {
            t += &format!(" | queue {q}");
        }
        if let Some(ms) = status.last_reload_ms {
            t += &format!(" | reload {ms:.0} ms");
        }
        if let Some(sun) = &status.sun {
            t += &format!(" | sun {sun} ([ ] PgUp PgDn)");
        }
        if let Some(e) = &status.last_error {
            t += &format!(" | error: {e}");
        }
        t += &format!(
            " | view {} (exposure {:.2}) | {HELP}",
            self.options.settings.view_mode.name(),
            self.options.settings.exposure
        );
        t
    }
}

impl ApplicationHandler for App<'_, '_> {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.state.is_none()
            && let Err(e) = self.open(event_loop)
        {
            self.fail(event_loop, ViewerError::Open(Box::new(e)));
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(size) => self.resize(size),
            WindowEvent::KeyboardInput { event, .. } => {
                if let PhysicalKey::Code(code) = event.physical_key {
                    self.key(event_loop, code, event.state == ElementState::Pressed);
                }
            }
            WindowEvent::MouseInput { button: MouseButton::Left | MouseButton::Right, state, .. } => {
                self.looking = state == ElementState::Pressed;
            }
            WindowEvent::MouseWheel { delta, .. } => {
                let notches = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y,
                    MouseScrollDelta::PixelDelta(p) => (p.y / 40.0) as f32,
                };
                self.camera.change_speed(notches);
            }
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.frame(event_loop) {
                    self.fail(event_loop, e);
                }
            }
            _ => {}
        }
    }

    fn device_event(&mut self, _event_loop: &ActiveEventLoop, _id: winit::event::DeviceId, event: DeviceEvent) {
        if let DeviceEvent::MouseMotion { delta: (dx, dy) } = event
            && self.looking
        {
            self.camera.turn(dx as f32, dy as f32);
        }
    }

    fn about_to_wait(&mut self, event_loop: &ActiveEventLoop) {
        let Some(s) = &self.state else { return };
        // Before the first light: paced unlit frames, and the lit one as soon as it can be.
        if s.renderer.shown.is_none()
            && let Some(last) = self.last_frame
        {
            let (now, next) = (Instant::now(), last + UNLIT_FRAME_INTERVAL);
            if now < next && self.source.shown().is_none() {
                event_loop.set_control_flow(ControlFlow::WaitUntil(next.min(now + LIGHT_POLL)));
                return;
            }
        }
        event_loop.set_control_flow(ControlFlow::Poll);
        s.window.request_redraw();
    }
}
