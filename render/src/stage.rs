//! [`Stage`]: one scene resident on the GPU, ready to be drawn any number of times.
//!
//! The mesh and its albedo maps are uploaded once; lights and the irradiance volume are
//! replaced when they change, in place where the sizes allow; the vertices again only when a
//! light set changes an emissive material's colour or strength. Shadow maps are drawn again only
//! after the lights changed: the geometry is static, so a camera move costs one main pass.

use bounce_client::{Face, Volume};
use bounce_core::light::LightSet;
use bounce_core::scene::Scene;
use bounce_engine::gpu::GpuLight;
use glam::{Mat4, UVec3, Vec3};
use wgpu::util::DeviceExt;

use crate::error::RenderError;
use crate::gpu_types::{Object, Vertex};
use crate::lights::prepare_lights;
use crate::mesh::{AlbedoMaps, mesh};
use crate::object::ProbeSphere;
use crate::resources::{DEPTH_FORMAT, MAX_SHADOW_VIEWS, Resources, SHADOW_SIZE, bind_group};

/// A scene's GPU resources: see the module doc.
pub struct Stage {
    pub(crate) bounds: (Vec3, Vec3),
    pub(crate) vertices: wgpu::Buffer,
    pub(crate) vertex_count: u32,
    pub(crate) globals: wgpu::Buffer,
    /// `Object` for the probe-lit sphere.
    object: wgpu::Buffer,
    /// The probe-lit sphere drawn after the scene, if any.
    pub(crate) sphere: Option<ProbeSphere>,
    albedo: wgpu::TextureView,
    pub(crate) lights: LightsGpu,
    pub(crate) volume: VolumeGpu,
    pub(crate) main_group: wgpu::BindGroup,
    pub(crate) shadow_group: wgpu::BindGroup,
    /// The vertices as uploaded, three a triangle in the scene's order, and the scene's
    /// triangles and materials: what a light set's emissive changes rewrite.
    cpu_vertices: Vec<Vertex>,
    emissive_source: Scene,
    /// The emissive changes the uploaded vertices carry.
    emissive_applied: Vec<bounce_core::light::Light>,
    /// The lights changed since the shadow maps were last drawn.
    pub(crate) shadows_stale: bool,
}

pub(crate) struct LightsGpu {
    pub count: u32,
    lights: wgpu::Buffer,
    views: wgpu::Buffer,
    array: wgpu::TextureView,
    /// One depth view a shadow-map layer, for the shadow passes.
    pub layers: Vec<wgpu::TextureView>,
}

pub(crate) struct VolumeGpu {
    pub origin: Vec3,
    pub voxel_size: f32,
    pub dims: UVec3,
    textures: Vec<wgpu::Texture>,
    views: Vec<wgpu::TextureView>,
    /// `Volume::separators`, an R8Uint grid.
    separators: wgpu::Texture,
    separators_view: wgpu::TextureView,
}

impl Stage {
    /// Uploads `scene` with no lights and `volume`'s current contents.
    pub fn new(
        renderer: &Resources<'_>,
        scene: &Scene,
        volume: &Volume,
    ) -> Result<Stage, RenderError> {
        let bounds = scene.bounds().ok_or(RenderError::EmptyScene)?;
        let device = renderer.ctx.device();
        let mesh = mesh(scene);
        let vertices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("vertices"),
            contents: bytemuck::cast_slice(&mesh.vertices),
            usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
        });
        let globals = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("globals"),
            size: std::mem::size_of::<crate::Globals>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let object = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("object"),
            size: std::mem::size_of::<Object>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let albedo = upload_maps(renderer, &mesh.maps)?;
        let lights = LightsGpu::new(renderer, &[], &[]);
        let volume = VolumeGpu::new(renderer, volume);
        let (main_group, shadow_group) =
            groups(renderer, [&globals, &object], &albedo, &lights, &volume);
        Ok(Stage {
            bounds,
            vertices,
            vertex_count: mesh.vertices.len() as u32,
            globals,
            object,
            sphere: None,
            albedo,
            lights,
            volume,
            main_group,
            shadow_group,
            shadows_stale: true,
            cpu_vertices: mesh.vertices,
            emissive_source: Scene {
                triangles: scene.triangles.clone(),
                materials: scene.materials.clone(),
                ..Scene::default()
            },
            emissive_applied: Vec::new(),
        })
    }

    /// The scene's axis-aligned bounds.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.bounds
    }

    /// Replaces the lights; their shadow maps are drawn with the next image.
    pub fn set_lights(
        &mut self,
        renderer: &Resources<'_>,
        lights: &LightSet,
    ) -> Result<(), RenderError> {
        let (gpu_lights, views) = prepare_lights(lights, self.bounds);
        let max =
            MAX_SHADOW_VIEWS.min(renderer.ctx.device().limits().max_texture_array_layers as usize);
        if views.len() > max {
            return Err(RenderError::TooManyShadows {
                views: views.len(),
                max,
            });
        }
        self.set_emission(renderer, lights)?;
        self.lights = LightsGpu::new(renderer, &gpu_lights, &views);
        self.rebind(renderer);
        self.shadows_stale = true;
        Ok(())
    }

    /// The surfaces' emission as `lights`' emissive changes leave it
    /// (`bounce_core::emitter::apply_to_scene`), uploaded only when the changes differ from
    /// those drawn: moving a light costs no vertex upload. A change reaching no emitter of this
    /// scene is left out: the engine refuses such lights, and a viewer drawing a scene
    /// other than the one a server relights draws what it can rather than stop.
    fn set_emission(
        &mut self,
        renderer: &Resources<'_>,
        lights: &LightSet,
    ) -> Result<(), RenderError> {
        let materials = &self.emissive_source.materials;
        let changes: Vec<bounce_core::light::Light> = lights
            .lights
            .iter()
            .filter(|l| {
                bounce_core::light::EmissiveChange::of(l).is_some_and(|change| {
                    materials.iter().any(|m| {
                        change.reaches(&m.name, m.node.as_deref())
                            && m.emission.iter().any(|&c| c > 0.0)
                    })
                })
            })
            .cloned()
            .collect();
        if changes == self.emissive_applied {
            return Ok(());
        }
        let known = LightSet {
            lights: changes.clone(),
        };
        let mut scene = self.emissive_source.clone();
        bounce_core::emitter::apply_to_scene(&mut scene, &known)?;
        for (tri, vertices) in scene
            .triangles
            .iter()
            .zip(self.cpu_vertices.chunks_exact_mut(3))
        {
            for v in vertices {
                v.emission = tri.emission.to_array();
            }
        }
        renderer.ctx.queue().write_buffer(
            &self.vertices,
            0,
            bytemuck::cast_slice(&self.cpu_vertices),
        );
        self.emissive_applied = changes;
        Ok(())
    }

    /// Copies `volume`'s texels in; a volume of another grid replaces the textures.
    pub fn set_volume(&mut self, renderer: &Resources<'_>, volume: &Volume) {
        let v = &self.volume;
        if v.dims == volume.dims()
            && v.origin == volume.origin()
            && v.voxel_size == volume.voxel_size()
        {
            v.write(renderer, volume);
        } else {
            self.volume = VolumeGpu::new(renderer, volume);
            self.rebind(renderer);
        }
    }

    /// The probe-lit sphere drawn after the scene from now on (its position and ambient cube
    /// as given), or none.
    pub fn set_probe_sphere(&mut self, renderer: &Resources<'_>, sphere: Option<ProbeSphere>) {
        if let Some(s) = &sphere {
            renderer
                .ctx
                .queue()
                .write_buffer(&self.object, 0, bytemuck::bytes_of(&s.gpu()));
        }
        self.sphere = sphere;
    }

    /// The probe-lit sphere drawn after the scene, if any.
    pub fn probe_sphere(&self) -> Option<&ProbeSphere> {
        self.sphere.as_ref()
    }

    fn rebind(&mut self, renderer: &Resources<'_>) {
        (self.main_group, self.shadow_group) = groups(
            renderer,
            [&self.globals, &self.object],
            &self.albedo,
            &self.lights,
            &self.volume,
        );
    }
}

impl LightsGpu {
    fn new(renderer: &Resources<'_>, lights: &[GpuLight], views: &[Mat4]) -> LightsGpu {
        let device = renderer.ctx.device();
        // wgpu binds no empty buffer: no lights still get one (unread) entry.
        let padded: Vec<GpuLight> = if lights.is_empty() {
            vec![GpuLight::default()]
        } else {
            lights.to_vec()
        };
        let lights_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("lights"),
            contents: bytemuck::cast_slice(&padded),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let mut matrices: Vec<[[f32; 4]; 4]> = views.iter().map(|m| m.to_cols_array_2d()).collect();
        if matrices.is_empty() {
            matrices.push(Mat4::IDENTITY.to_cols_array_2d());
        }
        let views_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("shadow views"),
            contents: bytemuck::cast_slice(&matrices),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let maps = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("shadow maps"),
            size: wgpu::Extent3d {
                width: SHADOW_SIZE,
                height: SHADOW_SIZE,
                depth_or_array_layers: matrices.len() as u32,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: DEPTH_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        });
        let array = maps.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        });
        let layers = (0..views.len() as u32)
            .map(|layer| {
                maps.create_view(&wgpu::TextureViewDescriptor {
                    dimension: Some(wgpu::TextureViewDimension::D2),
                    base_array_layer: layer,
                    array_layer_count: Some(1),
                    ..Default::default()
                })
            })
            .collect();
        LightsGpu {
            count: lights.len() as u32,
            lights: lights_buf,
            views: views_buf,
            array,
            layers,
        }
    }
}

impl VolumeGpu {
    pub(crate) fn new(renderer: &Resources<'_>, volume: &Volume) -> VolumeGpu {
        let device = renderer.ctx.device();
        let dims = volume.dims();
        let textures: Vec<wgpu::Texture> = Face::ALL
            .iter()
            .map(|_| {
                device.create_texture(&wgpu::TextureDescriptor {
                    label: Some("volume"),
                    size: extent(dims),
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D3,
                    format: wgpu::TextureFormat::Rgba16Float,
                    usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                    view_formats: &[],
                })
            })
            .collect();
        let views = textures
            .iter()
            .map(|t| t.create_view(&Default::default()))
            .collect();
        let separators = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("volume separators"),
            size: extent(dims),
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D3,
            format: wgpu::TextureFormat::R8Uint,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        let separators_view = separators.create_view(&Default::default());
        let gpu = VolumeGpu {
            origin: volume.origin(),
            voxel_size: volume.voxel_size(),
            dims,
            textures,
            views,
            separators,
            separators_view,
        };
        gpu.write(renderer, volume);
        gpu
    }

    fn write(&self, renderer: &Resources<'_>, volume: &Volume) {
        for (texture, &face) in self.textures.iter().zip(Face::ALL.iter()) {
            renderer.ctx.queue().write_texture(
                texture.as_image_copy(),
                volume.texel_bytes(face),
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(8 * self.dims.x),
                    rows_per_image: Some(self.dims.y),
                },
                extent(self.dims),
            );
        }
        // The separators follow from the layout: the same for every frame of it, but a volume
        // of another layout over the same grid may bring others.
        renderer.ctx.queue().write_texture(
            self.separators.as_image_copy(),
            volume.separators(),
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(self.dims.x),
                rows_per_image: Some(self.dims.y),
            },
            extent(self.dims),
        );
    }

    pub(crate) fn views(&self) -> &[wgpu::TextureView] {
        &self.views
    }

    pub(crate) fn separators_view(&self) -> &wgpu::TextureView {
        &self.separators_view
    }
}

fn extent(dims: UVec3) -> wgpu::Extent3d {
    wgpu::Extent3d {
        width: dims.x,
        height: dims.y,
        depth_or_array_layers: dims.z,
    }
}

fn upload_maps(
    renderer: &Resources<'_>,
    maps: &AlbedoMaps,
) -> Result<wgpu::TextureView, RenderError> {
    let device = renderer.ctx.device();
    let limits = device.limits();
    let layers = maps.levels.len() as u32;
    if layers > limits.max_texture_array_layers || maps.side > limits.max_texture_dimension_2d {
        return Err(RenderError::Textures(format!(
            "{layers} albedo maps of {side}² exceed the device's limits",
            side = maps.side
        )));
    }
    let texture = device.create_texture(&wgpu::TextureDescriptor {
        label: Some("albedo maps"),
        size: wgpu::Extent3d {
            width: maps.side,
            height: maps.side,
            depth_or_array_layers: layers,
        },
        mip_level_count: maps.mip_count(),
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba8UnormSrgb,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    for (layer, levels) in maps.levels.iter().enumerate() {
        for (level, texels) in levels.iter().enumerate() {
            let side = (maps.side >> level).max(1);
            renderer.ctx.queue().write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture: &texture,
                    mip_level: level as u32,
                    origin: wgpu::Origin3d {
                        x: 0,
                        y: 0,
                        z: layer as u32,
                    },
                    aspect: wgpu::TextureAspect::All,
                },
                texels,
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(4 * side),
                    rows_per_image: Some(side),
                },
                wgpu::Extent3d {
                    width: side,
                    height: side,
                    depth_or_array_layers: 1,
                },
            );
        }
    }
    Ok(texture.create_view(&wgpu::TextureViewDescriptor {
        dimension: Some(wgpu::TextureViewDimension::D2Array),
        ..Default::default()
    }))
}

/// The main and shadow bind groups; `uniforms` are `Globals` and `Object`.
fn groups(
    renderer: &Resources<'_>,
    [globals, object]: [&wgpu::Buffer; 2],
    albedo: &wgpu::TextureView,
    lights: &LightsGpu,
    volume: &VolumeGpu,
) -> (wgpu::BindGroup, wgpu::BindGroup) {
    let device = renderer.ctx.device();
    let mut entries = vec![
        (0, globals.as_entire_binding()),
        (1, lights.lights.as_entire_binding()),
        (2, lights.views.as_entire_binding()),
        (3, wgpu::BindingResource::TextureView(&lights.array)),
        (4, wgpu::BindingResource::Sampler(&renderer.shadow_sampler)),
        (5, object.as_entire_binding()),
    ];
    for (i, v) in volume.views.iter().enumerate() {
        entries.push((6 + i as u32, wgpu::BindingResource::TextureView(v)));
    }
    entries.push((12, wgpu::BindingResource::TextureView(albedo)));
    entries.push((13, wgpu::BindingResource::Sampler(&renderer.albedo_sampler)));
    entries.push((
        14,
        wgpu::BindingResource::TextureView(&volume.separators_view),
    ));
    let main = bind_group(device, &renderer.main_layout, entries);
    let shadow = bind_group(
        device,
        &renderer.shadow_layout,
        vec![(2, lights.views.as_entire_binding())],
    );
    (main, shadow)
}
