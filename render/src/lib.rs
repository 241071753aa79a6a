//! `bounce-render`: the renderer every bounce viewer shares, the window's and the headless one.
//!
//! It owns the shading (`shade.wgsl`): per fragment `albedo / π · (E_direct + E_indirect)` plus
//! emission, with `albedo` the triangle's base colour times its albedo map, `E_direct` from the
//! lights with a shadow map each (directional: orthographic over the scene's bounds; spot:
//! perspective; point: six perspective faces) and the light model of the engine's direct-light
//! kernels (`bounce_engine::gpu::light`, prepended to the shader: [`shade_source`]),
//! `E_indirect` from the six-direction irradiance volume ([`bounce_client::Volume`], sampled as
//! its module doc says), and the tonemap: radiance times the exposure, then Reinhard
//! `x / (1 + x)` per channel, then sRGB encoding, or none of that for
//! [`Renderer::render_linear`]'s float images of radiance itself. A [`Stage`] holds one scene on
//! the GPU; [`Renderer::draw`] records it into any target (a window's surface texture or an
//! offscreen image), so the window and `bounce render` run the same code. A stage is built from
//! the renderer's [`Resources`] (device, layouts, samplers), not from the code that draws it.
//! [`Overlay`] draws the viewer's text on top. A stage may also draw one object that is none of
//! the scene's surfaces, a [`ProbeSphere`] lit by the irradiance probes' [`ambient_cube`]
//! (`object.rs`), as an object moving through the scene would be.
//!
//! Not here: relighting (`bounce_engine`), the volume's contents (`bounce_client`), windows,
//! input and file formats (the CLI's viewer and `render` command).

mod camera;
mod error;
mod gpu_types;
mod lights;
mod math;
mod mesh;
mod object;
mod overlay;
mod renderer;
mod resources;
mod stage;

pub use camera::Camera;
pub use gpu_types::{
    FLAG_LINEAR, FLAG_NO_EMISSION, Globals, Object, Vertex, WRAP_REPEAT_U, WRAP_REPEAT_V,
};
pub use object::{BLEND_PROBES, ProbeSphere, ambient_cube, cube_irradiance};
pub use overlay::{OVERLAY_SHADER, Overlay, OverlayParams};
pub use renderer::{
    IMAGE_FORMAT, Image, LINEAR_FORMAT, LinearImage, MAX_SHADOW_VIEWS, MAX_SIDE, RenderError,
    RenderOptions, Renderer, Resources, Target, Terms, layout_from_baked, read_buffer,
    shade_source, volume_from_baked,
};
pub use stage::Stage;
