//! `bounce-render`: the headless renderer of issue 7, one image of an imported scene offscreen.
//!
//! It owns the shading every bounce viewer uses (`shade.wgsl`): per fragment
//! `albedo / π · (E_direct + E_indirect)` plus emission, with `E_direct` from the lights with a
//! shadow map each (directional: orthographic over the scene's bounds; spot: perspective; point:
//! six perspective faces), `E_indirect` from the six-direction irradiance volume
//! ([`bounce_client::Volume`], sampled as its module doc says), and the tonemap: radiance times
//! [`RenderOptions::exposure`], then Reinhard `x / (1 + x)` per channel, then sRGB encoding.
//!
//! Not here: relighting (`bounce_engine`), the volume's contents (`bounce_client`), windows and
//! file formats (the CLI writes the PNG).

mod gpu_types;
mod math;
mod renderer;

pub use gpu_types::{Globals, GpuLight, Vertex};
pub use renderer::{
    Camera, Image, MAX_SHADOW_VIEWS, MAX_SIDE, RenderError, RenderOptions, Renderer, SHADER,
    volume_from_baked,
};
