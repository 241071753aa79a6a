use std::sync::{Arc, Mutex};

use super::GpuError;

/// Keeps the first fault: later ones are usually its consequences.
fn record(fault: &Mutex<Option<String>>, message: String) {
    let mut f = fault.lock().unwrap_or_else(|e| e.into_inner());
    if f.is_none() {
        *f = Some(message);
    }
}

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
    /// Tensor cores the block codecs' large-batch kernel can use: 16 × 16 × 16 cooperative
    /// matrices with f16 inputs and f32 sums, in subgroups of 32 (see [`tensor_support`]).
    pub tensor_cores: bool,
}

impl std::fmt::Display for AdapterSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ({}, {}", self.name, self.backend, self.driver)?;
        if self.software {
            write!(f, ", software")?;
        }
        if self.tensor_cores {
            write!(f, ", tensor cores")?;
        }
        write!(f, ")")
    }
}

/// A device and queue for the compute kernels.
pub struct GpuContext {
    pub(super) device: wgpu::Device,
    pub(super) queue: wgpu::Queue,
    summary: AdapterSummary,
    /// The first error no scope caught, or the device's loss, on a device this context opened.
    fault: Arc<Mutex<Option<String>>>,
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
        let open = |tensor: bool| {
            let (required_features, experimental_features) = if tensor {
                // SAFETY: wgpu marks cooperative matrices experimental (its implementation may
                // have bugs). bounce uses them in one kernel, whose results its tests compare
                // with the FP32 kernels' on the hardware that runs it; `BOUNCE_GPU_TENSOR=0`
                // leaves them off.
                (features | TENSOR_FEATURES, unsafe {
                    wgpu::ExperimentalFeatures::enabled()
                })
            } else {
                (features, wgpu::ExperimentalFeatures::disabled())
            };
            pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
                label: Some("bounce-engine"),
                required_features,
                required_limits: adapter.limits(),
                experimental_features,
                ..Default::default()
            }))
        };
        // A device with the experimental features that fails to open is retried without them.
        let (device, queue) = match tensor_support(&adapter) {
            true => open(true).or_else(|_| open(false)),
            false => open(false),
        }
        .map_err(|source| GpuError::RequestDevice {
            adapter: adapter.get_info().name,
            source,
        })?;
        let ctx = GpuContext::from_device(device, queue, &adapter.get_info());
        // wgpu's default for an error no scope catches (out of memory in a dispatch, a device
        // lost) is a panic on whichever thread polls. A service records it instead, and its
        // owner reads `fault()` after each batch and moves to another engine.
        let fault = Arc::clone(&ctx.fault);
        ctx.device
            .on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
                record(&fault, format!("uncaptured GPU error: {e}"));
            }));
        let fault = Arc::clone(&ctx.fault);
        ctx.device.set_device_lost_callback(move |reason, message| {
            record(&fault, format!("GPU device lost ({reason:?}): {message}"));
        });
        Ok(ctx)
    }

    /// Why this context's device can no longer be trusted, if it cannot: an error that no error
    /// scope caught, or the device's loss. Only a context from [`GpuContext::new`] records these
    /// (one from [`GpuContext::from_device`] leaves the device's handlers to its owner).
    pub fn fault(&self) -> Option<String> {
        self.fault.lock().unwrap_or_else(|e| e.into_inner()).clone()
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
            tensor_cores: device.features().contains(TENSOR_FEATURES)
                && info.subgroup_min_size == 32
                && info.subgroup_max_size == 32,
        };
        GpuContext {
            device,
            queue,
            summary,
            fault: Arc::new(Mutex::new(None)),
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

/// What the tensor-core kernel (`tensor_block.wgsl`) needs from a device.
const TENSOR_FEATURES: wgpu::Features = wgpu::Features::SHADER_F16
    .union(wgpu::Features::SUBGROUP)
    .union(wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX);

/// Whether `adapter` can run the tensor-core kernel: f16 shaders, subgroups exactly 32 wide (the
/// kernel splits its 256 threads into eight of them), and a 16 × 16 × 16 cooperative matrix
/// product of f16 inputs into f32 sums. `BOUNCE_GPU_TENSOR=0` says no, to measure or rule out
/// the kernel.
pub fn tensor_support(adapter: &wgpu::Adapter) -> bool {
    if std::env::var("BOUNCE_GPU_TENSOR").is_ok_and(|v| v == "0") {
        return false;
    }
    let info = adapter.get_info();
    adapter.features().contains(TENSOR_FEATURES)
        && info.subgroup_min_size == 32
        && info.subgroup_max_size == 32
        && adapter.cooperative_matrix_properties().iter().any(|p| {
            use wgpu::CooperativeScalarType as S;
            (p.m_size, p.n_size, p.k_size, p.ab_type, p.cr_type) == (16, 16, 16, S::F16, S::F32)
        })
}
