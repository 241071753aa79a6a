use std::sync::{Mutex, MutexGuard, mpsc};

use bounce_client::{Face, Layout, PatchFace, Volume};
use bounce_core::direct::{LightKind, PreparedLight};
use bounce_core::light::LightSet;
use bounce_core::patch::PatchLayout;
use bounce_core::scene::Scene;
use bounce_engine::gpu::GpuContext;
use glam::{Mat4, UVec3, Vec3};
use thiserror::Error;
use wgpu::util::DeviceExt;

use crate::gpu_types::{Globals, GpuLight, KIND_DIRECTIONAL, KIND_POINT, KIND_SPOT, Vertex};
use crate::math::{look_at_rh, orthographic_rh, perspective_rh};

/// The shading module (see the crate doc).
pub const SHADER: &str = include_str!("shade.wgsl");

const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
const SHADOW_SIZE: u32 = 1024;
/// Most shadow-map layers one image may use (a directional or spot light takes one, a point
/// light six): 4 MiB each.
pub const MAX_SHADOW_VIEWS: usize = 64;
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
    #[error("irradiance volume: {0}")]
    Volume(String),
    #[error("reading the image back: {0}")]
    Readback(String),
}

/// A pinhole camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub eye: Vec3,
    pub target: Vec3,
    /// Vertical field of view, radians.
    pub fov_y: f32,
}

impl Camera {
    /// Looking at the whole of `bounds` from +Z, with a 45° vertical field of view.
    pub fn framing(bounds: (Vec3, Vec3)) -> Camera {
        let (lo, hi) = bounds;
        let centre = (lo + hi) / 2.0;
        let fov_y = 45f32.to_radians();
        let half = (hi - lo) / 2.0;
        // Far enough that the front face's larger half-extent fits the field of view.
        let reach = (half.x.max(half.y) / (fov_y / 2.0).tan()).max(1e-3);
        Camera {
            eye: centre + Vec3::Z * (half.z + reach * 1.1),
            target: centre,
            fov_y,
        }
    }

    /// World to clip space for an image of this aspect ratio, with depth planes that hold
    /// `bounds`.
    pub fn view_proj(&self, aspect: f32, bounds: (Vec3, Vec3)) -> Result<Mat4, RenderError> {
        let view = self.view()?;
        let (lo, hi) = bounds;
        let radius = ((hi - lo).length() / 2.0).max(1e-3);
        let distance = (self.eye - (lo + hi) / 2.0).length();
        let far = distance + radius * 2.0;
        let near = (far / 2000.0).max(1e-4);
        Ok(perspective_rh(self.fov_y, aspect, near, far) * view)
    }

    fn view(&self) -> Result<Mat4, RenderError> {
        let dir = self.target - self.eye;
        if !(dir.length() > 0.0 && dir.is_finite()) {
            return Err(RenderError::Camera(
                "the eye and the target must be distinct finite points".into(),
            ));
        }
        if !(self.fov_y > 0.0 && self.fov_y < std::f32::consts::PI) {
            return Err(RenderError::Camera(format!(
                "field of view {}° is not within (0°, 180°)",
                self.fov_y.to_degrees()
            )));
        }
        Ok(look_at_rh(self.eye, self.target, up_for(dir)))
    }
}

/// Y up, unless the view runs along Y.
fn up_for(dir: Vec3) -> Vec3 {
    if dir.normalize().y.abs() > 0.99 {
        Vec3::Z
    } else {
        Vec3::Y
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderOptions {
    pub width: u32,
    pub height: u32,
    /// Radiance is multiplied by this before the Reinhard curve.
    pub exposure: f32,
    /// Add the volume's indirect irradiance.
    pub indirect: bool,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            width: 640,
            height: 480,
            exposure: 1.0,
            indirect: true,
        }
    }
}

/// RGBA8 pixels (sRGB), rows top to bottom, no padding.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<u8>,
}

/// Pipelines on one device; a render uploads the scene, the lights and the volume each time.
pub struct Renderer<'a> {
    ctx: &'a GpuContext,
    module: wgpu::ShaderModule,
    main: wgpu::RenderPipeline,
    shadow: wgpu::RenderPipeline,
}

impl<'a> Renderer<'a> {
    pub fn new(ctx: &'a GpuContext) -> Result<Renderer<'a>, RenderError> {
        let device = ctx.device();
        let _one = compiling();
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("shade"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let attributes = wgpu::vertex_attr_array![
            0 => Float32x3, 1 => Float32x3, 2 => Float32x3, 3 => Float32x3
        ];
        let buffers = [Some(wgpu::VertexBufferLayout {
            array_stride: std::mem::size_of::<Vertex>() as u64,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &attributes,
        })];
        let main = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("main"),
            layout: None,
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_main"),
                compilation_options: Default::default(),
                buffers: &buffers,
            },
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Less),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_main"),
                compilation_options: Default::default(),
                targets: &[Some(COLOR_FORMAT.into())],
            }),
            multiview_mask: None,
            cache: None,
        });
        let shadow = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("shadow"),
            layout: None,
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_shadow"),
                compilation_options: Default::default(),
                buffers: &buffers,
            },
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Less),
                stencil: Default::default(),
                // Slope-scaled bias against acne on surfaces grazing the light.
                bias: wgpu::DepthBiasState {
                    constant: 2,
                    slope_scale: 2.0,
                    clamp: 0.0,
                },
            }),
            multisample: Default::default(),
            fragment: None,
            multiview_mask: None,
            cache: None,
        });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(RenderError::Shader(e.to_string()));
        }
        Ok(Renderer {
            ctx,
            module,
            main,
            shadow,
        })
    }

    /// One image of `scene` from `camera` under `lights`, with `volume`'s indirect light unless
    /// `options.indirect` is off.
    pub fn render(
        &self,
        scene: &Scene,
        camera: &Camera,
        lights: &LightSet,
        volume: &Volume,
        options: &RenderOptions,
    ) -> Result<Image, RenderError> {
        let (width, height) = (options.width, options.height);
        if !(1..=MAX_SIDE).contains(&width) || !(1..=MAX_SIDE).contains(&height) {
            return Err(RenderError::Size { width, height });
        }
        let bounds = scene.bounds().ok_or(RenderError::EmptyScene)?;
        let device = self.ctx.device();
        let queue = self.ctx.queue();

        let vertices = vertices(scene);
        let vertex_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("vertices"),
            contents: bytemuck::cast_slice(&vertices),
            usage: wgpu::BufferUsages::VERTEX,
        });
        let (gpu_lights, shadow_views) = prepare_lights(lights, bounds);
        let max = MAX_SHADOW_VIEWS.min(device.limits().max_texture_array_layers as usize);
        if shadow_views.len() > max {
            return Err(RenderError::TooManyShadows {
                views: shadow_views.len(),
                max,
            });
        }

        let view_proj = camera.view_proj(width as f32 / height as f32, bounds)?;
        let (lo, hi) = bounds;
        let radius = ((hi - lo).length() / 2.0).max(1e-3);
        let globals = Globals {
            view_proj: view_proj.to_cols_array_2d(),
            eye: camera.eye.to_array(),
            exposure: options.exposure,
            volume_origin: volume.origin().to_array(),
            voxel_size: volume.voxel_size(),
            volume_dims: volume.dims().as_vec3().to_array(),
            light_count: gpu_lights.len() as u32,
            indirect: u32::from(options.indirect),
            normal_offset: radius * 0.004,
            pad0: 0,
            pad1: 0,
        };
        let resources = self.resources(&globals, &gpu_lights, &shadow_views, volume);

        let mut encoder = device.create_command_encoder(&Default::default());
        for (layer, _) in shadow_views.iter().enumerate() {
            let target = resources
                .shadow_maps
                .create_view(&wgpu::TextureViewDescriptor {
                    dimension: Some(wgpu::TextureViewDimension::D2),
                    base_array_layer: layer as u32,
                    array_layer_count: Some(1),
                    ..Default::default()
                });
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("shadow"),
                color_attachments: &[],
                depth_stencil_attachment: Some(depth_attachment(&target)),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.shadow);
            pass.set_bind_group(0, &resources.shadow_group, &[]);
            pass.set_vertex_buffer(0, vertex_buf.slice(..));
            let layer = layer as u32;
            pass.draw(0..vertices.len() as u32, layer..layer + 1);
        }

        let size = wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        };
        let color = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("color"),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: COLOR_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        let depth = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("depth"),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: DEPTH_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            view_formats: &[],
        });
        let color_view = color.create_view(&Default::default());
        let depth_view = depth.create_view(&Default::default());
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("main"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &color_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: Some(depth_attachment(&depth_view)),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.main);
            pass.set_bind_group(0, &resources.main_group, &[]);
            pass.set_vertex_buffer(0, vertex_buf.slice(..));
            pass.draw(0..vertices.len() as u32, 0..1);
        }
        let row = width * 4;
        let padded = row.next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: u64::from(padded) * u64::from(height),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        encoder.copy_texture_to_buffer(
            color.as_image_copy(),
            wgpu::TexelCopyBufferInfo {
                buffer: &readback,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(padded),
                    rows_per_image: Some(height),
                },
            },
            size,
        );
        queue.submit([encoder.finish()]);
        let bytes = read_buffer(device, &readback)?;
        let mut pixels = Vec::with_capacity((row * height) as usize);
        for r in bytes.chunks(padded as usize).take(height as usize) {
            pixels.extend_from_slice(&r[..row as usize]);
        }
        Ok(Image {
            width,
            height,
            pixels,
        })
    }

    /// `Volume::sample`'s shader twin run on the GPU at each point: for tests and tools.
    pub fn probe_volume(
        &self,
        volume: &Volume,
        points: &[(Vec3, Vec3)],
    ) -> Result<Vec<[f32; 3]>, RenderError> {
        let device = self.ctx.device();
        if points.is_empty() {
            return Ok(Vec::new());
        }
        let one = compiling();
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("probe"),
            layout: None,
            module: &self.module,
            entry_point: Some("cs_probe"),
            compilation_options: Default::default(),
            cache: None,
        });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(RenderError::Shader(e.to_string()));
        }
        drop(one);
        let globals = Globals {
            volume_origin: volume.origin().to_array(),
            voxel_size: volume.voxel_size(),
            volume_dims: volume.dims().as_vec3().to_array(),
            ..Default::default()
        };
        let res = self.resources(&globals, &[], &[Mat4::IDENTITY], volume);
        let mut bindings = vec![(0, res.globals.as_entire_binding())];
        bindings.push((5, wgpu::BindingResource::Sampler(&res.volume_sampler)));
        for (i, v) in res.volume_views.iter().enumerate() {
            bindings.push((6 + i as u32, wgpu::BindingResource::TextureView(v)));
        }
        let group0 = bind_group(device, &pipeline.get_bind_group_layout(0), bindings);
        let vec4s = |f: &dyn Fn(&(Vec3, Vec3)) -> Vec3| -> Vec<[f32; 4]> {
            points.iter().map(|p| f(p).extend(0.0).to_array()).collect()
        };
        let storage = |label, data: &[[f32; 4]], usage| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: bytemuck::cast_slice(data),
                usage,
            })
        };
        let positions = storage(
            "probe points",
            &vec4s(&|p| p.0),
            wgpu::BufferUsages::STORAGE,
        );
        let normals = storage(
            "probe normals",
            &vec4s(&|p| p.1),
            wgpu::BufferUsages::STORAGE,
        );
        let zeros = vec![[0.0f32; 4]; points.len()];
        let out = storage(
            "probe out",
            &zeros,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        );
        let group1 = bind_group(
            device,
            &pipeline.get_bind_group_layout(1),
            vec![
                (0, positions.as_entire_binding()),
                (1, normals.as_entire_binding()),
                (2, out.as_entire_binding()),
            ],
        );
        let bytes = (points.len() * 16) as u64;
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("probe readback"),
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_pipeline(&pipeline);
            pass.set_bind_group(0, &group0, &[]);
            pass.set_bind_group(1, &group1, &[]);
            pass.dispatch_workgroups((points.len() as u32).div_ceil(64), 1, 1);
        }
        encoder.copy_buffer_to_buffer(&out, 0, &readback, 0, bytes);
        self.ctx.queue().submit([encoder.finish()]);
        let data = read_buffer(device, &readback)?;
        let values: &[[f32; 4]] = bytemuck::cast_slice(&data);
        Ok(values.iter().map(|v| [v[0], v[1], v[2]]).collect())
    }

    fn resources(
        &self,
        globals: &Globals,
        lights: &[GpuLight],
        shadow_views: &[Mat4],
        volume: &Volume,
    ) -> Resources {
        let device = self.ctx.device();
        let queue = self.ctx.queue();
        let globals_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("globals"),
            contents: bytemuck::bytes_of(globals),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        // wgpu binds no empty buffer: a scene without lights still gets one (unread) entry.
        let lights: Vec<GpuLight> = if lights.is_empty() {
            vec![GpuLight::default()]
        } else {
            lights.to_vec()
        };
        let lights_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("lights"),
            contents: bytemuck::cast_slice(&lights),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let mut views: Vec<[[f32; 4]; 4]> =
            shadow_views.iter().map(|m| m.to_cols_array_2d()).collect();
        if views.is_empty() {
            views.push(Mat4::IDENTITY.to_cols_array_2d());
        }
        let views_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("shadow views"),
            contents: bytemuck::cast_slice(&views),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let shadow_maps = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("shadow maps"),
            size: wgpu::Extent3d {
                width: SHADOW_SIZE,
                height: SHADOW_SIZE,
                depth_or_array_layers: views.len() as u32,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: DEPTH_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        });
        let shadow_view = shadow_maps.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        });
        let shadow_sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("shadow"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            compare: Some(wgpu::CompareFunction::LessEqual),
            ..Default::default()
        });
        let volume_sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("volume"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            address_mode_w: wgpu::AddressMode::ClampToEdge,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        let dims = volume.dims();
        let extent = wgpu::Extent3d {
            width: dims.x,
            height: dims.y,
            depth_or_array_layers: dims.z,
        };
        let volume_views: Vec<wgpu::TextureView> = Face::ALL
            .iter()
            .map(|&face| {
                let texture = device.create_texture(&wgpu::TextureDescriptor {
                    label: Some("volume"),
                    size: extent,
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D3,
                    format: wgpu::TextureFormat::Rgba16Float,
                    usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                    view_formats: &[],
                });
                queue.write_texture(
                    texture.as_image_copy(),
                    volume.texel_bytes(face),
                    wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(8 * dims.x),
                        rows_per_image: Some(dims.y),
                    },
                    extent,
                );
                texture.create_view(&Default::default())
            })
            .collect();
        let mut entries = vec![
            (0, globals_buf.as_entire_binding()),
            (1, lights_buf.as_entire_binding()),
            (2, views_buf.as_entire_binding()),
            (3, wgpu::BindingResource::TextureView(&shadow_view)),
            (4, wgpu::BindingResource::Sampler(&shadow_sampler)),
            (5, wgpu::BindingResource::Sampler(&volume_sampler)),
        ];
        for (i, v) in volume_views.iter().enumerate() {
            entries.push((6 + i as u32, wgpu::BindingResource::TextureView(v)));
        }
        let main_group = bind_group(device, &self.main.get_bind_group_layout(0), entries);
        let shadow_group = bind_group(
            device,
            &self.shadow.get_bind_group_layout(0),
            vec![(2, views_buf.as_entire_binding())],
        );
        Resources {
            globals: globals_buf,
            shadow_maps,
            volume_sampler,
            volume_views,
            main_group,
            shadow_group,
        }
    }
}

/// Error scopes are a stack per device, shared by every thread: two renderers compiling at once
/// would pop each other's scope, so compilation is one at a time.
fn compiling() -> MutexGuard<'static, ()> {
    static COMPILING: Mutex<()> = Mutex::new(());
    COMPILING
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

struct Resources {
    globals: wgpu::Buffer,
    shadow_maps: wgpu::Texture,
    volume_sampler: wgpu::Sampler,
    volume_views: Vec<wgpu::TextureView>,
    main_group: wgpu::BindGroup,
    shadow_group: wgpu::BindGroup,
}

fn bind_group(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    entries: Vec<(u32, wgpu::BindingResource<'_>)>,
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = entries
        .into_iter()
        .map(|(binding, resource)| wgpu::BindGroupEntry { binding, resource })
        .collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout,
        entries: &entries,
    })
}

fn depth_attachment(view: &wgpu::TextureView) -> wgpu::RenderPassDepthStencilAttachment<'_> {
    wgpu::RenderPassDepthStencilAttachment {
        view,
        depth_ops: Some(wgpu::Operations {
            load: wgpu::LoadOp::Clear(1.0),
            store: wgpu::StoreOp::Store,
        }),
        stencil_ops: None,
    }
}

fn read_buffer(device: &wgpu::Device, buffer: &wgpu::Buffer) -> Result<Vec<u8>, RenderError> {
    let slice = buffer.slice(..);
    let (tx, rx) = mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        // The receiver outlives the poll below; a send can only fail after it gave up.
        let _ = tx.send(r);
    });
    device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| RenderError::Readback(e.to_string()))?;
    rx.recv()
        .map_err(|e| RenderError::Readback(e.to_string()))?
        .map_err(|e| RenderError::Readback(e.to_string()))?;
    let bytes = slice
        .get_mapped_range()
        .map_err(|e| RenderError::Readback(e.to_string()))?
        .to_vec();
    buffer.unmap();
    Ok(bytes)
}

/// Flat-shaded triangles: the importer resolves materials per triangle and keeps no vertex
/// normals, so each vertex carries its triangle's.
fn vertices(scene: &Scene) -> Vec<Vertex> {
    scene
        .triangles
        .iter()
        .flat_map(|t| {
            let normal = t.cross().normalize_or_zero().to_array();
            t.positions.map(|p| Vertex {
                position: p.to_array(),
                normal,
                albedo: t.albedo.to_array(),
                emission: t.emission.to_array(),
            })
        })
        .collect()
}

/// The lights as the shader reads them, and the shadow views they use (one per directional
/// and spot light, six per point light). Lights that cannot light anything are left out.
fn prepare_lights(lights: &LightSet, bounds: (Vec3, Vec3)) -> (Vec<GpuLight>, Vec<Mat4>) {
    let (lo, hi) = bounds;
    let centre = (lo + hi) / 2.0;
    let radius = ((hi - lo).length() / 2.0).max(1e-3);
    let mut out = Vec::new();
    let mut views = Vec::new();
    for light in &lights.lights {
        let Some(l) = PreparedLight::new(light) else {
            continue;
        };
        let first_view = views.len() as u32;
        // Depth range of a light inside or near the scene: from close by to past its far side.
        let reach = (l.position - centre).length() + radius;
        let near = (reach / 1000.0).max(1e-4);
        let kind = match l.kind {
            LightKind::Directional => {
                let eye = centre - l.axis * radius * 2.0;
                let view = look_at_rh(eye, centre, up_for(l.axis));
                let proj = orthographic_rh(radius, 0.0, radius * 4.0);
                views.push(proj * view);
                KIND_DIRECTIONAL
            }
            LightKind::Spot => {
                // The outer cone plus a margin, short of 180° where perspective breaks down.
                let outer = (l.angle_offset / -l.angle_scale.max(1e-6))
                    .clamp(-1.0, 1.0)
                    .acos();
                let fov = (2.0 * outer + 0.1).min(3.0);
                let view = look_at_rh(l.position, l.position + l.axis, up_for(l.axis));
                views.push(perspective_rh(fov, 1.0, near, reach) * view);
                KIND_SPOT
            }
            LightKind::Point => {
                let faces = [
                    (Vec3::X, Vec3::NEG_Y),
                    (Vec3::NEG_X, Vec3::NEG_Y),
                    (Vec3::Y, Vec3::Z),
                    (Vec3::NEG_Y, Vec3::NEG_Z),
                    (Vec3::Z, Vec3::NEG_Y),
                    (Vec3::NEG_Z, Vec3::NEG_Y),
                ];
                let proj = perspective_rh(std::f32::consts::FRAC_PI_2, 1.0, near, reach);
                for (dir, up) in faces {
                    views.push(proj * look_at_rh(l.position, l.position + dir, up));
                }
                KIND_POINT
            }
        };
        out.push(GpuLight {
            position: l.position.to_array(),
            kind,
            axis: l.axis.to_array(),
            inv_range: l.inv_range,
            radiant: l.radiant.to_array(),
            angle_scale: l.angle_scale,
            angle_offset: l.angle_offset,
            first_view,
            pad0: 0,
            pad1: 0,
        });
    }
    (out, views)
}

/// The irradiance volume of a baked scene filled with in-process indirect irradiance (one RGB
/// triple a patch, in the baked layout's order, as `Engine::relight` gives it).
pub fn volume_from_baked(
    name: &str,
    layout: &PatchLayout,
    indirect: &[[f32; 3]],
) -> Result<Volume, RenderError> {
    let patches = layout
        .patches
        .iter()
        .map(|p| PatchFace {
            voxel: UVec3::from_array(p.voxel),
            face: p.face,
        })
        .collect();
    let layout = Layout::new(
        name,
        Vec3::from_array(layout.origin),
        layout.voxel_size,
        UVec3::from_array(layout.dims),
        patches,
    )
    .map_err(|e| RenderError::Volume(e.to_string()))?;
    let mut volume = Volume::new(&layout).map_err(|e| RenderError::Volume(e.to_string()))?;
    volume
        .apply_irradiance(indirect)
        .map_err(|e| RenderError::Volume(e.to_string()))?;
    Ok(volume)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn framing_looks_at_the_centre_from_plus_z_and_sees_the_front() {
        let bounds = (Vec3::new(-1.0, 0.0, -1.0), Vec3::new(1.0, 2.0, 1.0));
        let c = Camera::framing(bounds);
        assert_eq!(c.target, Vec3::new(0.0, 1.0, 0.0));
        assert!(c.eye.z > 1.0 && c.eye.x == 0.0 && c.eye.y == 1.0, "{c:?}");
        let m = c.view_proj(1.0, bounds).unwrap();
        for corner in [Vec3::new(-1.0, 0.0, 1.0), Vec3::new(1.0, 2.0, 1.0)] {
            let p = m.project_point3(corner);
            assert!(p.x.abs() <= 1.0 && p.y.abs() <= 1.0, "{corner} at {p}");
            assert!((0.0..=1.0).contains(&p.z), "{corner} at {p}");
        }
        // A point scene still gets a camera that works.
        let dot = (Vec3::ONE, Vec3::ONE);
        assert!(Camera::framing(dot).view_proj(1.0, dot).is_ok());
    }

    #[test]
    fn bad_cameras_are_errors() {
        let bounds = (Vec3::ZERO, Vec3::ONE);
        let at = |eye, target, fov_y| Camera { eye, target, fov_y };
        assert!(
            at(Vec3::ONE, Vec3::ONE, 1.0)
                .view_proj(1.0, bounds)
                .is_err()
        );
        assert!(
            at(Vec3::NAN, Vec3::ONE, 1.0)
                .view_proj(1.0, bounds)
                .is_err()
        );
        assert!(at(Vec3::Z, Vec3::ZERO, 0.0).view_proj(1.0, bounds).is_err());
        assert!(at(Vec3::Z, Vec3::ZERO, 3.2).view_proj(1.0, bounds).is_err());
        // Looking straight down (along Y) needs another up vector, not a NaN matrix.
        let m = at(Vec3::Y * 5.0, Vec3::ZERO, 1.0)
            .view_proj(1.0, bounds)
            .unwrap();
        assert!(m.is_finite());
    }
}
