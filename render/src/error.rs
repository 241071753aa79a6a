//! What can go wrong drawing an image; every module of the renderer answers with it.

use thiserror::Error;

/// Largest image side: wgpu's default `max_texture_dimension_2d`.
pub const MAX_SIDE: u32 = 8192;

#[derive(Debug, Error)]
pub enum RenderError {
    #[error("the scene has no triangles")]
    EmptyScene,
    #[error("image size {width}×{height} is not within 1..={MAX_SIDE} a side")]
    Size { width: u32, height: u32 },
    #[error(
        "the lights need {views} shadow maps, more than the {max} one image may use (a point \
         light takes 6, a spot or directional light 1)"
    )]
    TooManyShadows { views: usize, max: usize },
    #[error("camera: {0}")]
    Camera(String),
    #[error("shader: {0}")]
    Shader(String),
    #[error("no pipeline for colour format {0:?}: create the renderer with it")]
    Format(wgpu::TextureFormat),
    #[error("albedo maps: {0}")]
    Textures(String),
    #[error("irradiance volume: {0}")]
    Volume(String),
    #[error("reading the image back: {0}")]
    Readback(String),
    /// A light set's emissive change names no emissive material of the scene drawn.
    #[error("lights: {0}")]
    Lights(#[from] bounce_core::light::LightError),
}
