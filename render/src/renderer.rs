//! [`Renderer`]: the pipelines on one device, and drawing a [`Stage`] into any colour target
//! (a window's surface texture or an offscreen image read back to memory).

use std::sync::{Mutex, MutexGuard, mpsc};

use bounce_client::{Layout, Volume};
use bounce_core::light::LightSet;
use bounce_core::patch::PatchLayout;
use bounce_core::scene::Scene;
use bounce_engine::gpu::{GpuContext, light};
use glam::Vec3;
use wgpu::util::DeviceExt;

use crate::camera::Camera;
pub use crate::error::{MAX_SIDE, RenderError};
use crate::gpu_types::{FLAG_LINEAR, FLAG_NO_EMISSION, Globals, Vertex};
use crate::object::unit_sphere;
use crate::resources::{DEPTH_FORMAT, bind_group};
pub use crate::resources::{MAX_SHADOW_VIEWS, Resources};
use crate::stage::{Stage, VolumeGpu};

/// The shading module (see the crate doc): the engine's light model (`bounce_engine::gpu::light`),
/// then `shade.wgsl`, which lights with it.
pub fn shade_source() -> String {
    [light::WGSL, include_str!("shade.wgsl")].concat()
}

/// The offscreen images' format.
pub const IMAGE_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;
/// The format of offscreen images of linear radiance ([`Renderer::render_linear`]): drawn with
/// neither exposure nor tonemap.
pub const LINEAR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderOptions {
    pub width: u32,
    pub height: u32,
    /// Radiance is multiplied by this before the Reinhard curve (tonemapped images only).
    pub exposure: f32,
    /// Add the volume's indirect irradiance.
    pub indirect: bool,
    /// Add the lights' direct irradiance and the surfaces' emission. Off, with `indirect` on,
    /// an image is `albedo / π · E_indirect` alone.
    pub direct: bool,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            width: 640,
            height: 480,
            exposure: 1.0,
            indirect: true,
            direct: true,
        }
    }
}

/// What the direct and indirect terms contribute to an image: the viewer's toggles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Terms {
    pub direct: bool,
    pub indirect: bool,
}

/// RGBA8 pixels (sRGB), rows top to bottom, no padding.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<u8>,
}

/// Linear RGB radiance (the lights' units per m² and steradian), before exposure and
/// tonemap: rows top to bottom, no padding. Pixels no surface covers are 0.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearImage {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<[f32; 3]>,
}

/// Where a draw goes: a colour view of a format the renderer has a pipeline for, and a depth
/// view of the same size ([`Renderer::depth_view`]).
pub struct Target<'t> {
    pub color: &'t wgpu::TextureView,
    pub format: wgpu::TextureFormat,
    pub depth: &'t wgpu::TextureView,
    pub width: u32,
    pub height: u32,
}

/// Pipelines and samplers on one device.
pub struct Renderer<'a> {
    /// What stages are built with; the renderer derefs to it, so a stage takes `&renderer`.
    resources: Resources<'a>,
    module: wgpu::ShaderModule,
    mains: Vec<(wgpu::TextureFormat, wgpu::RenderPipeline)>,
    shadow: wgpu::RenderPipeline,
    /// A unit sphere's triangles, drawn as the probe-lit object ([`Stage::set_probe_sphere`]).
    sphere: wgpu::Buffer,
    sphere_count: u32,
}

impl<'a> std::ops::Deref for Renderer<'a> {
    type Target = Resources<'a>;

    fn deref(&self) -> &Resources<'a> {
        &self.resources
    }
}

impl<'a> Renderer<'a> {
    /// A renderer for offscreen images, tonemapped ([`IMAGE_FORMAT`]) and linear
    /// ([`LINEAR_FORMAT`]).
    pub fn new(ctx: &'a GpuContext) -> Result<Renderer<'a>, RenderError> {
        Renderer::with_formats(ctx, &[IMAGE_FORMAT, LINEAR_FORMAT])
    }

    /// A renderer that can draw into each of `formats` (a window's surface format, say, and
    /// [`IMAGE_FORMAT`] for screenshots).
    pub fn with_formats(
        ctx: &'a GpuContext,
        formats: &[wgpu::TextureFormat],
    ) -> Result<Renderer<'a>, RenderError> {
        let device = ctx.device();
        let _one = compiling();
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("shade"),
            source: wgpu::ShaderSource::Wgsl(shade_source().into()),
        });
        let attributes = wgpu::vertex_attr_array![
            0 => Float32x3, 1 => Float32x3, 2 => Float32x3, 3 => Float32x3,
            4 => Float32x2, 5 => Uint32, 6 => Uint32
        ];
        let buffers = [Some(wgpu::VertexBufferLayout {
            array_stride: std::mem::size_of::<Vertex>() as u64,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &attributes,
        })];
        // One explicit layout, so a stage's bind group fits the pipeline of every format.
        let main_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("shade"),
            entries: &main_layout_entries(),
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("shade"),
            bind_group_layouts: &[Some(&main_layout)],
            immediate_size: 0,
        });
        let mains = formats
            .iter()
            .map(|&format| {
                let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                    label: Some("main"),
                    layout: Some(&pipeline_layout),
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
                        targets: &[Some(format.into())],
                    }),
                    multiview_mask: None,
                    cache: None,
                });
                (format, pipeline)
            })
            .collect();
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
        let shadow_sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("shadow"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            compare: Some(wgpu::CompareFunction::LessEqual),
            ..Default::default()
        });
        let albedo_sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("albedo"),
            address_mode_u: wgpu::AddressMode::Repeat,
            address_mode_v: wgpu::AddressMode::Repeat,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Linear,
            ..Default::default()
        });
        let sphere: Vec<Vertex> = unit_sphere(16, 32)
            .into_iter()
            .map(|p| Vertex {
                position: p,
                normal: p,
                albedo: [1.0; 3],
                ..Vertex::default()
            })
            .collect();
        let sphere_count = sphere.len() as u32;
        let sphere = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("probe sphere"),
            contents: bytemuck::cast_slice(&sphere),
            usage: wgpu::BufferUsages::VERTEX,
        });
        Ok(Renderer {
            resources: Resources {
                ctx,
                main_layout,
                shadow_layout: shadow.get_bind_group_layout(0),
                shadow_sampler,
                albedo_sampler,
            },
            module,
            mains,
            shadow,
            sphere,
            sphere_count,
        })
    }

    pub fn context(&self) -> &'a GpuContext {
        self.ctx
    }

    /// A depth buffer for targets of this size.
    pub fn depth_view(&self, width: u32, height: u32) -> wgpu::TextureView {
        self.ctx
            .device()
            .create_texture(&wgpu::TextureDescriptor {
                label: Some("depth"),
                size: wgpu::Extent3d {
                    width,
                    height,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: DEPTH_FORMAT,
                usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
                view_formats: &[],
            })
            .create_view(&Default::default())
    }

    /// Records one image of `stage` from `camera` into `target`: the shadow maps first if the
    /// lights changed since they were drawn, then the scene, then the stage's probe-lit sphere
    /// if it has one.
    pub fn draw(
        &self,
        stage: &mut Stage,
        encoder: &mut wgpu::CommandEncoder,
        target: &Target<'_>,
        camera: &Camera,
        exposure: f32,
        terms: Terms,
    ) -> Result<(), RenderError> {
        self.draw_flags(stage, encoder, target, camera, exposure, terms, 0)
    }

    /// [`Renderer::draw`] with `Globals::flags`.
    #[allow(clippy::too_many_arguments)]
    fn draw_flags(
        &self,
        stage: &mut Stage,
        encoder: &mut wgpu::CommandEncoder,
        target: &Target<'_>,
        camera: &Camera,
        exposure: f32,
        terms: Terms,
        flags: u32,
    ) -> Result<(), RenderError> {
        let (width, height) = (target.width, target.height);
        if !(1..=MAX_SIDE).contains(&width) || !(1..=MAX_SIDE).contains(&height) {
            return Err(RenderError::Size { width, height });
        }
        let pipeline = self
            .mains
            .iter()
            .find(|(f, _)| *f == target.format)
            .map(|(_, p)| p)
            .ok_or(RenderError::Format(target.format))?;
        let view_proj = camera.view_proj(width as f32 / height as f32, stage.bounds)?;
        let (lo, hi) = stage.bounds;
        let radius = ((hi - lo).length() / 2.0).max(1e-3);
        let globals = Globals {
            view_proj: view_proj.to_cols_array_2d(),
            eye: camera.eye.to_array(),
            exposure,
            volume_origin: stage.volume.origin.to_array(),
            voxel_size: stage.volume.voxel_size,
            volume_dims: stage.volume.dims.as_vec3().to_array(),
            light_count: if terms.direct { stage.lights.count } else { 0 },
            indirect: u32::from(terms.indirect),
            normal_offset: radius * 0.004,
            flags,
            pad1: 0,
        };
        self.ctx
            .queue()
            .write_buffer(&stage.globals, 0, bytemuck::bytes_of(&globals));

        if stage.shadows_stale {
            for (layer, view) in stage.lights.layers.iter().enumerate() {
                let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                    label: Some("shadow"),
                    color_attachments: &[],
                    depth_stencil_attachment: Some(depth_attachment(view)),
                    timestamp_writes: None,
                    occlusion_query_set: None,
                    multiview_mask: None,
                });
                pass.set_pipeline(&self.shadow);
                pass.set_bind_group(0, &stage.shadow_group, &[]);
                pass.set_vertex_buffer(0, stage.vertices.slice(..));
                let layer = layer as u32;
                pass.draw(0..stage.vertex_count, layer..layer + 1);
            }
            stage.shadows_stale = false;
        }

        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("main"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: target.color,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: Some(depth_attachment(target.depth)),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &stage.main_group, &[]);
        pass.set_vertex_buffer(0, stage.vertices.slice(..));
        pass.draw(0..stage.vertex_count, 0..1);
        if stage.sphere.is_some() {
            // Instance 1 is the object (`vs_main`).
            pass.set_vertex_buffer(0, self.sphere.slice(..));
            pass.draw(0..self.sphere_count, 1..2);
        }
        Ok(())
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
        let pixels = self.render_scene(
            scene,
            camera,
            lights,
            volume,
            options,
            options.exposure,
            (IMAGE_FORMAT, 0),
        )?;
        Ok(Image {
            width: options.width,
            height: options.height,
            pixels,
        })
    }

    /// As [`Renderer::render`], but linear radiance in float: no exposure, no tonemap, no sRGB
    /// encoding (`options.exposure` is not used).
    pub fn render_linear(
        &self,
        scene: &Scene,
        camera: &Camera,
        lights: &LightSet,
        volume: &Volume,
        options: &RenderOptions,
    ) -> Result<LinearImage, RenderError> {
        let bytes = self.render_scene(
            scene,
            camera,
            lights,
            volume,
            options,
            1.0,
            (LINEAR_FORMAT, FLAG_LINEAR),
        )?;
        // RGBA f32 texels, as the GPU wrote them (native-endian).
        let floats: Vec<f32> = bytes
            .chunks_exact(4)
            .map(|b| f32::from_ne_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        let pixels = floats.chunks_exact(4).map(|t| [t[0], t[1], t[2]]).collect();
        Ok(LinearImage {
            width: options.width,
            height: options.height,
            pixels,
        })
    }

    /// The shared part of [`Renderer::render`] and [`Renderer::render_linear`]: a stage for
    /// `scene` under `lights`, drawn offscreen into `format` with `extra` flags, read back.
    #[allow(clippy::too_many_arguments)]
    fn render_scene(
        &self,
        scene: &Scene,
        camera: &Camera,
        lights: &LightSet,
        volume: &Volume,
        options: &RenderOptions,
        exposure: f32,
        (format, extra): (wgpu::TextureFormat, u32),
    ) -> Result<Vec<u8>, RenderError> {
        check_size(options.width, options.height)?;
        let mut stage = Stage::new(self, scene, volume)?;
        stage.set_lights(self, lights)?;
        let (terms, flags) = terms_of(options);
        self.offscreen(
            &mut stage,
            camera,
            (options.width, options.height),
            exposure,
            terms,
            (format, flags | extra),
        )
    }

    /// One image of a stage, offscreen, read back.
    pub fn render_stage(
        &self,
        stage: &mut Stage,
        camera: &Camera,
        width: u32,
        height: u32,
        exposure: f32,
        terms: Terms,
    ) -> Result<Image, RenderError> {
        let pixels = self.offscreen(
            stage,
            camera,
            (width, height),
            exposure,
            terms,
            (IMAGE_FORMAT, 0),
        )?;
        Ok(Image {
            width,
            height,
            pixels,
        })
    }

    /// One image of a stage into an offscreen target of `format`, drawn with `flags`: its
    /// pixels' bytes, rows top to bottom, no padding.
    fn offscreen(
        &self,
        stage: &mut Stage,
        camera: &Camera,
        (width, height): (u32, u32),
        exposure: f32,
        terms: Terms,
        (format, flags): (wgpu::TextureFormat, u32),
    ) -> Result<Vec<u8>, RenderError> {
        check_size(width, height)?;
        let device = self.ctx.device();
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
            format,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        let color_view = color.create_view(&Default::default());
        let depth_view = self.depth_view(width, height);
        let mut encoder = device.create_command_encoder(&Default::default());
        let target = Target {
            color: &color_view,
            format,
            depth: &depth_view,
            width,
            height,
        };
        self.draw_flags(stage, &mut encoder, &target, camera, exposure, terms, flags)?;
        let texel = format
            .block_copy_size(None)
            .ok_or(RenderError::Format(format))?;
        let row = width * texel;
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
        self.ctx.queue().submit([encoder.finish()]);
        let bytes = read_buffer(device, &readback)?;
        let mut pixels = Vec::with_capacity((row * height) as usize);
        for r in bytes.chunks(padded as usize).take(height as usize) {
            pixels.extend_from_slice(&r[..row as usize]);
        }
        Ok(pixels)
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
        let globals = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("probe globals"),
            contents: bytemuck::bytes_of(&globals),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let textures = VolumeGpu::new(self, volume);
        let mut bindings = vec![(0, globals.as_entire_binding())];
        for (i, v) in textures.views().iter().enumerate() {
            bindings.push((6 + i as u32, wgpu::BindingResource::TextureView(v)));
        }
        bindings.push((
            14,
            wgpu::BindingResource::TextureView(textures.separators_view()),
        ));
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
}

/// The terms and `Globals::flags` an image of `options` is drawn with: without direct light,
/// emission goes too.
fn terms_of(options: &RenderOptions) -> (Terms, u32) {
    let terms = Terms {
        direct: options.direct,
        indirect: options.indirect,
    };
    let flags = if options.direct { 0 } else { FLAG_NO_EMISSION };
    (terms, flags)
}

fn check_size(width: u32, height: u32) -> Result<(), RenderError> {
    if !(1..=MAX_SIDE).contains(&width) || !(1..=MAX_SIDE).contains(&height) {
        return Err(RenderError::Size { width, height });
    }
    Ok(())
}

/// `shade.wgsl`'s group 0, binding by binding.
fn main_layout_entries() -> Vec<wgpu::BindGroupLayoutEntry> {
    use wgpu::ShaderStages as S;
    let entry = |binding, visibility, ty| wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty,
        count: None,
    };
    let storage = wgpu::BindingType::Buffer {
        ty: wgpu::BufferBindingType::Storage { read_only: true },
        has_dynamic_offset: false,
        min_binding_size: None,
    };
    let texture = |sample_type, view_dimension| wgpu::BindingType::Texture {
        sample_type,
        view_dimension,
        multisampled: false,
    };
    let float = wgpu::TextureSampleType::Float { filterable: true };
    let uniform = wgpu::BindingType::Buffer {
        ty: wgpu::BufferBindingType::Uniform,
        has_dynamic_offset: false,
        min_binding_size: None,
    };
    let mut entries = vec![
        entry(0, S::VERTEX | S::FRAGMENT, uniform),
        entry(1, S::FRAGMENT, storage),
        entry(2, S::VERTEX | S::FRAGMENT, storage),
        entry(
            3,
            S::FRAGMENT,
            texture(
                wgpu::TextureSampleType::Depth,
                wgpu::TextureViewDimension::D2Array,
            ),
        ),
        entry(
            4,
            S::FRAGMENT,
            wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Comparison),
        ),
        entry(5, S::VERTEX | S::FRAGMENT, uniform),
    ];
    for binding in 6..12 {
        entries.push(entry(
            binding,
            S::FRAGMENT,
            texture(float, wgpu::TextureViewDimension::D3),
        ));
    }
    entries.push(entry(
        12,
        S::FRAGMENT,
        texture(float, wgpu::TextureViewDimension::D2Array),
    ));
    entries.push(entry(
        13,
        S::FRAGMENT,
        wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
    ));
    entries.push(entry(
        14,
        S::FRAGMENT,
        texture(
            wgpu::TextureSampleType::Uint,
            wgpu::TextureViewDimension::D3,
        ),
    ));
    entries
}

/// Error scopes are a stack per device, shared by every thread: two renderers compiling at once
/// would pop each other's scope, so compilation is one at a time.
pub(crate) fn compiling() -> MutexGuard<'static, ()> {
    static COMPILING: Mutex<()> = Mutex::new(());
    COMPILING
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
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

/// Waits for the GPU and returns a `MAP_READ` buffer's bytes.
pub fn read_buffer(device: &wgpu::Device, buffer: &wgpu::Buffer) -> Result<Vec<u8>, RenderError> {
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

/// The irradiance volume of a baked scene filled with in-process indirect irradiance (one RGB
/// triple a patch, in the baked layout's order, as `Engine::relight` gives it).
pub fn volume_from_baked(
    name: &str,
    layout: &PatchLayout,
    indirect: &[[f32; 3]],
) -> Result<Volume, RenderError> {
    let mut volume = Volume::new(&layout_from_baked(name, layout)?)
        .map_err(|e| RenderError::Volume(e.to_string()))?;
    volume
        .apply_irradiance(indirect)
        .map_err(|e| RenderError::Volume(e.to_string()))?;
    Ok(volume)
}

/// A baked file's patch layout in the form a client receives it from a server: the server's own
/// conversion, read back as a client reads it.
pub fn layout_from_baked(name: &str, layout: &PatchLayout) -> Result<Layout, RenderError> {
    let wire = bounce_wire::layout::to_proto(
        name,
        layout.origin,
        layout.voxel_size,
        layout.dims,
        layout.patches.iter().map(|p| (p.voxel, p.face)),
        // Probe positions are the caller's to add (`Layout::with_probes`).
        &[],
    );
    Layout::from_proto(&wire).map_err(|e| RenderError::Volume(e.to_string()))
}
