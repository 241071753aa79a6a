use bounce_core::codec::CodecError;
use thiserror::Error;

#[derive(Debug, Error)]
pub enum GpuError {
    #[error(
        "no GPU adapter found (wgpu backends tried: {backends}); for software Vulkan install \
             lavapipe (Debian: mesa-vulkan-drivers)"
    )]
    NoAdapter { backends: String },
    #[error("adapter '{adapter}' refused a device: {source}")]
    RequestDevice {
        adapter: String,
        source: wgpu::RequestDeviceError,
    },
    #[error("adapter '{adapter}' lacks feature {feature}, which codec '{codec}' needs")]
    MissingFeature {
        adapter: String,
        feature: &'static str,
        codec: String,
    },
    #[error(
        "codec '{0}' has no GPU kernel (have: dense-f32, dense-f16, bc1, bc1-resid, bc4, log8)"
    )]
    UnsupportedCodec(String),
    #[error(transparent)]
    Codec(#[from] CodecError),
    #[error("{what} needs {needed}, over the device limit of {limit}")]
    TooLarge {
        what: &'static str,
        needed: u64,
        limit: u64,
    },
    #[error("the device ran out of memory for the {what}: {message}")]
    OutOfMemory { what: &'static str, message: String },
    #[error("kernel {kernel} did not compile: {message}")]
    Shader {
        kernel: &'static str,
        message: String,
    },
    #[error("the near-field matrix does not fit the surface direct light: {0}")]
    NearField(String),
    #[error("GPU readback failed: {0}")]
    Readback(String),
}
