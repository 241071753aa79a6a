use super::GpuError;

/// Which adapter a context runs on, for logs and for callers that treat software adapters
/// differently (lavapipe is correct but no faster than the CPU engine).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AdapterSummary {
    pub name: String,
    pub backend: String,
    pub driver: String,
    /// A CPU implementation (lavapipe, WARP, SwiftShader).
    pub software: bool,
    /// BC texture sampling, which the `bc1` / `bc4` kernels need.
    pub bc_textures: bool,
}

impl std::fmt::Display for AdapterSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ({}, {}", self.name, self.backend, self.driver)?;
        if self.software {
            write!(f, ", software")?;
        }
        write!(f, ")")
    }
}

/// A device and queue for the compute kernels.
pub struct GpuContext {
    pub(super) device: wgpu::Device,
    pub(super) queue: wgpu::Queue,
    summary: AdapterSummary,
}

impl GpuContext {
    /// The best adapter wgpu finds (a discrete GPU first, a software one last), with the adapter's
    /// own limits, so matrices as large as the hardware allows fit, and BC texture compression
    /// when the adapter has it.
    pub fn new() -> Result<GpuContext, GpuError> {
        let desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        let backends = desc.backends & wgpu::Instance::enabled_backend_features();
        let instance = wgpu::Instance::new(desc);
        let request = |fallback: bool| {
            pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
                power_preference: wgpu::PowerPreference::HighPerformance,
                force_fallback_adapter: fallback,
                compatible_surface: None,
                apply_limit_buckets: false,
            }))
        };
        let adapter =
            request(false)
                .or_else(|_| request(true))
                .map_err(|_| GpuError::NoAdapter {
                    backends: format!("{backends:?}"),
                })?;
        // Timestamp queries time the products on the device itself (see
        // `GpuMatrix::last_kernel_seconds`); they cost nothing where unused.
        let features = adapter.features()
            & (wgpu::Features::TEXTURE_COMPRESSION_BC | wgpu::Features::TIMESTAMP_QUERY);
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("bounce-engine"),
            required_features: features,
            required_limits: adapter.limits(),
            ..Default::default()
        }))
        .map_err(|source| GpuError::RequestDevice {
            adapter: adapter.get_info().name,
            source,
        })?;
        Ok(GpuContext::from_device(device, queue, &adapter.get_info()))
    }

    /// A context on a device the caller opened (e.g. a renderer's, or a test's software one).
    pub fn from_device(
        device: wgpu::Device,
        queue: wgpu::Queue,
        info: &wgpu::AdapterInfo,
    ) -> GpuContext {
        let summary = AdapterSummary {
            name: info.name.clone(),
            backend: info.backend.to_string(),
            driver: format!("{} {}", info.driver, info.driver_info)
                .trim()
                .to_string(),
            software: info.device_type == wgpu::DeviceType::Cpu,
            bc_textures: device
                .features()
                .contains(wgpu::Features::TEXTURE_COMPRESSION_BC),
        };
        GpuContext {
            device,
            queue,
            summary,
        }
    }

    pub fn adapter(&self) -> &AdapterSummary {
        &self.summary
    }

    pub fn device(&self) -> &wgpu::Device {
        &self.device
    }

    pub fn queue(&self) -> &wgpu::Queue {
        &self.queue
    }
}
