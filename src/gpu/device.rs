//! The one wgpu device every GPU part shares (viewer, offscreen renders, the GPU bundle
//! backend): adapter selection, limits, error capture.
//!
//! Adapter choice: hardware first (discrete, integrated, virtual), then a software adapter
//! (Mesa's lavapipe, `device_type: Cpu`): machines without a GPU run every GPU path on it.
//! Vulkan is the only backend compiled in (see Cargo.toml). A window's instance is created
//! with the event loop's display handle (wgpu asks for it; GL backends need it) and only
//! adapters that can present to the window's surface are considered.
//!
//! Limits: the device gets the adapter's own limits, not WebGPU's defaults, so large
//! storage bindings (the default is 128 MiB) and big textures are available where the
//! hardware has them. Validation errors are logged and kept (see [`GpuContext::take_error`])
//! instead of wgpu's default handler, which panics.

use std::sync::{Arc, Mutex};

use wgpu::{Adapter, AdapterInfo, Backends, DeviceType, Instance, InstanceDescriptor, Surface};

/// The Debian package that provides a software Vulkan adapter (lavapipe).
pub const SOFTWARE_ADAPTER_PACKAGE: &str = "mesa-vulkan-drivers";

#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    #[error(
        "no Vulkan adapter found{for_window}; on a machine without a GPU install Mesa's software adapter \
         (Debian/Ubuntu: `apt-get install {SOFTWARE_ADAPTER_PACKAGE} libvulkan1`)",
        for_window = if *.for_surface { " that can present to the window" } else { "" }
    )]
    NoAdapter { for_surface: bool },
    #[error("cannot create a surface for the window: {0}")]
    Surface(#[from] wgpu::CreateSurfaceError),
    #[error("the adapter {adapter:?} refused a device: {source}")]
    Device { adapter: String, source: wgpu::RequestDeviceError },
    #[error("GPU validation error: {0}")]
    Validation(String),
    #[error("the adapter {adapter:?} cannot run the GPU bundle backend: it lacks {missing}")]
    Unsupported { adapter: String, missing: &'static str },
    #[error("GPU buffer read-back failed: {0}")]
    Readback(String),
    #[error("light map: {0}")]
    Lightmap(String),
    #[error(transparent)]
    Shader(#[from] super::shader::ShaderError),
}

/// Rank of an adapter type: lower is preferred.
fn preference(kind: DeviceType) -> u8 {
    match kind {
        DeviceType::DiscreteGpu => 0,
        DeviceType::IntegratedGpu => 1,
        DeviceType::VirtualGpu => 2,
        DeviceType::Cpu => 3,
        DeviceType::Other => 4,
    }
}

/// Instance, adapter, device and queue. Cheap to clone (wgpu handles are reference counted).
#[derive(Clone)]
pub struct GpuContext {
    pub instance: Instance,
    pub adapter: Adapter,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: AdapterInfo,
    errors: Arc<Mutex<Vec<String>>>,
}

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuContext").field("adapter", &self.info.name).field("type", &self.info.device_type).finish()
    }
}

impl GpuContext {
    /// A device for offscreen work (no window, no display connection).
    pub fn headless() -> Result<GpuContext, GpuError> {
        let instance = Instance::new(vulkan_only(InstanceDescriptor::new_without_display_handle()));
        Self::with_instance(instance, None)
    }

    /// A device that can present to `window`, and the window's surface. `display` is the
    /// event loop's display connection (winit's `OwnedDisplayHandle`).
    pub fn for_window(
        display: Box<dyn wgpu::wgt::WgpuHasDisplayHandle>,
        window: impl Into<wgpu::SurfaceTarget<'static>>,
    ) -> Result<(GpuContext, Surface<'static>), GpuError> {
        let instance = Instance::new(vulkan_only(InstanceDescriptor::new_with_display_handle(display)));
        let surface = instance.create_surface(window)?;
        let context = Self::with_instance(instance, Some(&surface))?;
        Ok((context, surface))
    }

    fn with_instance(instance: Instance, surface: Option<&Surface<'_>>) -> Result<GpuContext, GpuError> {
        let mut adapters = pollster::block_on(instance.enumerate_adapters(Backends::VULKAN));
        adapters.retain(|a| surface.is_none_or(|s| a.is_surface_supported(s)));
        adapters.sort_by_key(|a| preference(a.get_info().device_type));
        let adapter = adapters.into_iter().next().ok_or(GpuError::NoAdapter { for_surface: surface.is_some() })?;
        let info = adapter.get_info();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("livebake"),
            // f64 where the adapter has it (lavapipe does): the GPU tile planner then decides
            // in the same f64 arithmetic as the CPU's `TilePlanner` (see `bundle_tiles`).
            required_features: adapter.features() & wgpu::Features::SHADER_F64,
            required_limits: adapter.limits(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|source| GpuError::Device { adapter: info.name.clone(), source })?;
        let errors = Arc::new(Mutex::new(Vec::new()));
        let sink = errors.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            tracing::error!("GPU error: {e}");
            if let Ok(mut v) = sink.lock() {
                v.push(e.to_string());
            }
        }));
        tracing::info!(adapter = %info.name, kind = ?info.device_type, driver = %info.driver_info, "GPU device");
        Ok(GpuContext { instance, adapter, device, queue, info, errors })
    }

    /// The first GPU error since the last call, if any (errors are also logged).
    pub fn take_error(&self) -> Result<(), GpuError> {
        let mut v = self.errors.lock().map_err(|_| GpuError::Validation("error log poisoned".into()))?;
        match v.drain(..).next() {
            Some(e) => Err(GpuError::Validation(e)),
            None => Ok(()),
        }
    }

    /// Whether the adapter is a software rasteriser (lavapipe), for reports.
    pub fn is_software(&self) -> bool {
        self.info.device_type == DeviceType::Cpu
    }

    /// `Err(Unsupported)` unless fragment shaders may write storage buffers (the bundle
    /// rasters' atomics and linked lists need it; every Vulkan adapter we know has it).
    pub fn require_fragment_storage(&self) -> Result<(), GpuError> {
        let flags = self.adapter.get_downlevel_capabilities().flags;
        if flags.contains(wgpu::DownlevelFlags::FRAGMENT_WRITABLE_STORAGE) {
            Ok(())
        } else {
            Err(GpuError::Unsupported { adapter: self.info.name.clone(), missing: "fragment-stage writable storage" })
        }
    }

    /// Whether shaders may use `f64` (the device was given `SHADER_F64`).
    pub fn has_f64(&self) -> bool {
        self.device.features().contains(wgpu::Features::SHADER_F64)
    }

    /// Blocks until the GPU has finished all submitted work.
    pub fn wait_idle(&self) -> Result<(), GpuError> {
        self.device.poll(wgpu::PollType::wait_indefinitely()).map(|_| ()).map_err(|e| GpuError::Readback(e.to_string()))
    }

    /// Reads `size` bytes of a `MAP_READ` buffer (after the copy into it was submitted).
    pub fn read_buffer(&self, buffer: &wgpu::Buffer, size: u64) -> Result<Vec<u8>, GpuError> {
        let slice = buffer.slice(..size);
        let (tx, rx) = crossbeam_channel::bounded(1);
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.wait_idle()?;
        rx.recv().map_err(|e| GpuError::Readback(e.to_string()))?.map_err(|e| GpuError::Readback(e.to_string()))?;
        let bytes = slice.get_mapped_range().map_err(|e| GpuError::Readback(e.to_string()))?.to_vec();
        buffer.unmap();
        Ok(bytes)
    }
}

/// Vulkan only, whatever `WGPU_BACKEND` says: it is the only backend compiled in.
fn vulkan_only(desc: InstanceDescriptor) -> InstanceDescriptor {
    InstanceDescriptor { backends: Backends::VULKAN, ..desc.with_env() }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hardware_adapters_rank_before_software_ones() {
        let mut kinds = [DeviceType::Cpu, DeviceType::Other, DeviceType::IntegratedGpu, DeviceType::DiscreteGpu];
        kinds.sort_by_key(|&k| preference(k));
        assert_eq!(kinds, [DeviceType::DiscreteGpu, DeviceType::IntegratedGpu, DeviceType::Cpu, DeviceType::Other]);
    }

    #[test]
    fn lavapipe_runs_the_bundle_rasters() {
        let gpu = GpuContext::headless().expect("a Vulkan adapter (lavapipe: mesa-vulkan-drivers)");
        gpu.require_fragment_storage().unwrap();
        let msg = GpuError::Unsupported { adapter: "x".into(), missing: "fragment-stage writable storage" }.to_string();
        assert!(msg.contains("fragment-stage writable storage"), "{msg}");
    }

    #[test]
    fn missing_adapter_error_names_the_package() {
        let msg = GpuError::NoAdapter { for_surface: false }.to_string();
        assert!(msg.contains(SOFTWARE_ADAPTER_PACKAGE), "{msg}");
    }

    /// Runs on lavapipe here (never skipped): the device gets the adapter's limits.
    #[test]
    fn headless_device_has_the_adapters_limits() {
        let gpu = GpuContext::headless().expect("a Vulkan adapter (lavapipe: mesa-vulkan-drivers)");
        let (got, offered) = (gpu.device.limits(), gpu.adapter.limits());
        assert_eq!(got.max_storage_buffer_binding_size, offered.max_storage_buffer_binding_size);
        assert_eq!(got.max_texture_dimension_2d, offered.max_texture_dimension_2d);
        assert!(got.max_storage_buffer_binding_size >= wgpu::Limits::default().max_storage_buffer_binding_size);
    }
}
