//! The engine interface: a device ([`Engine`]), a baked scene made ready on it ([`Scene`]), and
//! [`Engine::relight`], which turns a batch of light configurations into direct and indirect
//! irradiance per patch.
//!
//! A relight is docs/design.md §1 end to end: per light set, direct irradiance with shadows,
//! `B0 = L_e + ρ ⊙ E_direct`, then `E_ind = T · B0` for the whole batch in one product, on the GPU
//! or the CPU. The batch is where a GPU wins: one pass over the matrix serves every light set.
//!
//! With a near field (`bounce_core::nearfield`) the first bounce gains `ΔE`, the light near
//! landings gather where they land rather than as their element's mean. The later bounces carry
//! it too: a receiver re-emits the first bounce it really gathered, so the product takes
//! `T · (B0 + ρ ⊙ ΔE)` and adds `ΔE` ([`Scene::near_carried`]), in the same one product.
//!
//! Direct light runs where its shadows can. The GPU engine computes it with
//! [`GpuSurfaceDirect`] for a surface-geometry bake (shadow rays from the stored sample points
//! through a BVH of the original triangles) and with [`GpuDirect`] for a voxel-face bake with
//! occupancy (shadow rays walk the voxel grid); both are twins of `bounce_core::direct`. A scene
//! over a kernel's limits (a binding, the BVH traversal stack) and a file without occupancy or
//! surface geometry (shadows from the patches alone, a BVH of quads the GPU kernels do not have)
//! are lit on the CPU on either engine. [`Scene::direct_engine`] says which, and
//! [`Scene::direct_fallback`] why.
//!
//! A sky is no punctual light: each row's share of it, `E_sky = Σ c_lm L_lm` from the row's
//! baked sky view (`bounce_core::sky`), is added to the row's direct light on the host, after
//! either engine's direct light and before `B0`, so both engines light by it alike (it costs
//! `O(rows)` a light set). How it varies over a row, through the samples' own views, joins the
//! punctual lights' near-field correction in the same pass, on the device for the GPU engine
//! (`NearField::correction_with`). A file without a sky view ([`Scene::has_sky_view`]) gets
//! nothing from a sky. Its share is also kept apart ([`Irradiance::sky`]): a viewer draws the punctual lights
//! itself but not a sky, so what is streamed is `E_ind` with the sky's direct light
//! ([`Irradiance::streamed`]).

use std::fmt;
use std::str::FromStr;
use std::time::Instant;

use bounce_core::codec::{self, MatrixOp};
use bounce_core::direct::{
    DEFAULT_SAMPLES, ShadowScene, ShadowSource, direct_irradiance, direct_with_samples,
    exitance_b0, exitance_with,
};
use bounce_core::element::Elements;
use bounce_core::emitter::{Emitters, check_names};
use bounce_core::format::Baked;
use bounce_core::light::{LightError, LightSet};
use bounce_core::meta::Bounces;
use bounce_core::nearfield::{NearField, Reflect};
use bounce_core::patch::PatchLayout;
use bounce_core::probe::Probes;
use bounce_core::sky::SkyVisibility;

use crate::EngineError;
use crate::gpu::{GpuContext, GpuDirect, GpuError, GpuMatrix, GpuSurfaceDirect};

/// Which engine a user asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum EngineChoice {
    /// The GPU when an adapter exists, else the CPU.
    #[default]
    Auto,
    Gpu,
    Cpu,
}

impl FromStr for EngineChoice {
    type Err = EngineError;
    fn from_str(s: &str) -> Result<Self, EngineError> {
        match s {
            "auto" => Ok(EngineChoice::Auto),
            "gpu" => Ok(EngineChoice::Gpu),
            "cpu" => Ok(EngineChoice::Cpu),
            other => Err(EngineError::UnknownEngine(other.to_string())),
        }
    }
}

/// Which engine runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EngineKind {
    Gpu,
    Cpu,
}

impl fmt::Display for EngineKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            EngineKind::Gpu => "gpu",
            EngineKind::Cpu => "cpu",
        })
    }
}

/// A device that relights scenes: one per GPU, or the CPU.
pub struct Engine {
    gpu: Option<GpuContext>,
    description: String,
    /// Why `auto` fell back to the CPU, when it did.
    fallback: Option<String>,
    /// Direct-light samples per patch: `None` takes every sample point a surface bake stores
    /// (what its near field is built on) and [`DEFAULT_SAMPLES`] for voxel faces; a count here
    /// is clamped to what a surface bake stores.
    pub samples: Option<u32>,
}

impl Engine {
    /// Open the engine asked for. `Auto` takes the GPU when a hardware adapter opens and the CPU
    /// otherwise (no adapter, or only a software one), and says which (see [`Engine::describe`],
    /// [`Engine::fallback`]); `Gpu` takes any adapter, software included, and without one is an
    /// error.
    pub fn new(choice: EngineChoice) -> Result<Engine, EngineError> {
        let cpu = |fallback: Option<String>| Engine {
            gpu: None,
            description: format!("cpu ({} threads)", rayon::current_num_threads()),
            fallback,
            samples: None,
        };
        match choice {
            EngineChoice::Cpu => Ok(cpu(None)),
            EngineChoice::Gpu | EngineChoice::Auto => match GpuContext::new() {
                // A software rasteriser (lavapipe) runs on the same cores as the CPU engine,
                // 5–40× slower (`bounce bench engines`): auto does not take it; `gpu` still does,
                // which is how CI tests the kernels.
                Ok(ctx) if choice == EngineChoice::Auto && ctx.adapter().software => {
                    Ok(cpu(Some(format!(
                        "the only adapter is a software one ({}); the CPU engine is faster",
                        ctx.adapter().name
                    ))))
                }
                Ok(ctx) => {
                    let a = ctx.adapter();
                    let description = format!(
                        "gpu ({}, {}{}{})",
                        a.name,
                        a.backend,
                        if a.software { ", software" } else { "" },
                        if a.tensor_cores { ", tensor cores" } else { "" }
                    );
                    Ok(Engine {
                        gpu: Some(ctx),
                        description,
                        fallback: None,
                        samples: None,
                    })
                }
                Err(e) if choice == EngineChoice::Auto => Ok(cpu(Some(e.to_string()))),
                Err(e) => Err(EngineError::NoGpu(e)),
            },
        }
    }

    pub fn kind(&self) -> EngineKind {
        if self.gpu.is_some() {
            EngineKind::Gpu
        } else {
            EngineKind::Cpu
        }
    }

    /// The GPU engine's adapter; `None` on the CPU engine.
    pub fn adapter(&self) -> Option<&crate::gpu::AdapterSummary> {
        self.gpu.as_ref().map(GpuContext::adapter)
    }

    /// What runs: the engine kind and, for the GPU, the adapter.
    pub fn describe(&self) -> &str {
        &self.description
    }

    /// Why this engine's GPU can no longer be trusted, if it cannot (an error no scope caught,
    /// or the device lost): its owner should stop using it and open another engine. Always
    /// `None` on the CPU engine.
    pub fn device_fault(&self) -> Option<String> {
        self.gpu.as_ref().and_then(GpuContext::fault)
    }

    /// Why `auto` chose the CPU, if it did.
    pub fn fallback(&self) -> Option<&str> {
        self.fallback.as_deref()
    }

    /// Make a baked scene ready: shadow geometry built (CPU) or uploaded (GPU: the triangles'
    /// BVH and sample points of a surface bake, else patches and occupancy), the transport
    /// decoded (CPU) or uploaded (GPU).
    ///
    /// On the GPU engine a scene too large for the direct kernel (its bindings, or for surface
    /// geometry a BVH deeper than its traversal stack) is lit on the CPU instead (see
    /// [`Scene::direct_fallback`]); any other GPU error is an error.
    pub fn load(&self, baked: &Baked) -> Result<Scene, EngineError> {
        let cpu_direct =
            |why: Option<String>| DirectLight::Cpu(Box::new(ShadowScene::of_baked(baked)), why);
        let near = baked.near_field.clone().map(|mut field| {
            // A sky lights nothing in a file without the rows' view, so it has nothing to
            // correct through the samples' either.
            if baked.sky.is_none() {
                field.sky = None;
            }
            NearRows {
                albedo: row_albedo(baked),
                sample_albedo: baked.surface.as_ref().and_then(|s| s.albedo.clone()),
                field,
                carried: carries_near_field(baked.meta.settings.bounces),
            }
        });
        let direct = match (&self.gpu, &baked.surface, baked.occupancy.as_deref()) {
            (Some(ctx), Some(surface), _) => {
                let uploaded = GpuSurfaceDirect::upload(ctx, surface).and_then(|d| {
                    match &near {
                        // The correction needs every sample's light, which stays on the device.
                        Some(near) => d.with_near_field(&near.field, near.reflect()),
                        None => Ok(d),
                    }
                });
                match uploaded {
                    Ok(d) => DirectLight::GpuSurface(Box::new(d)),
                    Err(e @ GpuError::TooLarge { .. }) => cpu_direct(Some(e.to_string())),
                    Err(e) => return Err(e.into()),
                }
            }
            (Some(ctx), None, Some(occupied)) => {
                match GpuDirect::upload(ctx, baked.transport_layout(), occupied) {
                    Ok(d) => DirectLight::Gpu(Box::new(d)),
                    Err(e @ GpuError::TooLarge { .. }) => cpu_direct(Some(e.to_string())),
                    Err(e) => return Err(e.into()),
                }
            }
            (Some(_), None, None) => cpu_direct(Some(
                "no occupancy in the baked file: shadows from the patches alone, on the CPU".into(),
            )),
            (None, ..) => cpu_direct(None),
        };
        let shadow_source = if baked.surface.is_some() {
            ShadowSource::Triangles
        } else if baked.occupancy.is_some() {
            ShadowSource::Occupancy
        } else {
            ShadowSource::PatchesOnly
        };
        // A matrix the device cannot hold (more tiles than a texture array has, no BC textures,
        // out of memory) keeps this scene's product on the CPU; other scenes stay on the GPU.
        let (transport, transport_fallback) = match &self.gpu {
            Some(ctx) => match GpuMatrix::upload(ctx, &baked.transport) {
                Ok(m) => (Transport::Gpu(Box::new(m)), None),
                Err(
                    e @ (GpuError::TooLarge { .. }
                    | GpuError::MissingFeature { .. }
                    | GpuError::OutOfMemory { .. }),
                ) => (
                    Transport::Cpu(codec::decode(&baked.transport)?),
                    Some(e.to_string()),
                ),
                Err(e) => return Err(e.into()),
            },
            None => (Transport::Cpu(codec::decode(&baked.transport)?), None),
        };
        Ok(Scene {
            layout: baked.layout.clone(),
            rows: baked.transport_layout().clone(),
            near,
            sky: baked.sky.clone(),
            emitters: baked.emitters.clone(),
            probes: baked.probes.clone(),
            stored_samples: baked.surface.as_ref().map(|s| s.per_patch),
            area_samples: baked.surface.as_ref().map(|s| s.area_samples),
            elements: baked.elements.clone(),
            direct,
            shadow_source,
            transport,
            transport_fallback,
            codec: baked.transport.codec.clone(),
            matrix_bytes: baked.transport.payload.len(),
        })
    }

    /// Direct and indirect irradiance for every light set of the batch; each is validated first.
    pub fn relight(
        &self,
        scene: &Scene,
        lights: &[LightSet],
    ) -> Result<Vec<Irradiance>, EngineError> {
        Ok(self.relight_timed(scene, lights)?.0)
    }

    /// [`Engine::relight`] with the time each half took.
    pub fn relight_timed(
        &self,
        scene: &Scene,
        lights: &[LightSet],
    ) -> Result<(Vec<Irradiance>, Timing), EngineError> {
        for (index, set) in lights.iter().enumerate() {
            set.validate()
                .and_then(|()| match &scene.emitters {
                    Some(e) => e.resolve(set).map(|_| ()),
                    None => check_names(None, set),
                })
                .map_err(|error| EngineError::Lights { index, error })?;
        }
        let n = scene.rows.len();
        let start = Instant::now();
        let (mut direct, near) = self.sampled_direct(scene, lights, true)?;
        let skies = sky_rows(scene.sky.as_ref(), lights);
        add_sky(&skies, &mut direct);
        let mut b0: Vec<[f32; 3]> = Vec::with_capacity(n * lights.len());
        for (index, (set, e)) in lights.iter().zip(&direct).enumerate() {
            b0.extend(
                scene
                    .exitance(set, e)
                    .map_err(|error| EngineError::Lights { index, error })?,
            );
        }
        let direct_s = start.elapsed().as_secs_f64();
        let start = Instant::now();
        let indirect = self.indirect_with_near(scene, &b0, near.as_deref())?;
        let out = direct
            .into_iter()
            .zip(skies)
            .zip(lights)
            .zip(indirect.chunks(n.max(1)).zip(b0.chunks(n.max(1))))
            .map(|(((direct, sky), set), (ind, b0))| {
                let probes = scene.probe_irradiance(b0, ind, set);
                let sky = sky.unwrap_or_default();
                match &scene.elements {
                    // What a patch streams is its elements' light over its surface.
                    Some(e) => Irradiance {
                        direct: e.restrict_sampled(&scene.layout, &direct),
                        indirect: e.restrict(&scene.layout, ind),
                        sky: if sky.is_empty() {
                            sky
                        } else {
                            // Direct light, averaged over the surface it was sampled on.
                            e.restrict_sampled(&scene.layout, &sky)
                        },
                        probes,
                    },
                    None => Irradiance {
                        direct,
                        indirect: ind.to_vec(),
                        sky,
                        probes,
                    },
                }
            })
            .collect();
        let indirect_s = start.elapsed().as_secs_f64();
        Ok((
            out,
            Timing {
                direct_s,
                indirect_s,
            },
        ))
    }

    /// Direct irradiance on the transport's rows ([`Scene::rows`]), per light set, before it is
    /// restricted to the patches: what `B0` and so `T · B0` are computed from. The light sets
    /// are not validated here ([`Engine::relight`] does).
    pub fn direct_on_rows(
        &self,
        scene: &Scene,
        lights: &[LightSet],
    ) -> Result<Vec<Vec<[f32; 3]>>, EngineError> {
        Ok(self.direct(scene, lights, false)?.0)
    }

    /// [`Engine::direct_on_rows`] and, for a scene with a near field that this engine's sample
    /// count can use ([`Engine::near_field`]), the near-field first bounce per light set and row
    /// (`bounce_core::nearfield`).
    #[allow(clippy::type_complexity)]
    pub fn direct_and_near(
        &self,
        scene: &Scene,
        lights: &[LightSet],
    ) -> Result<(Vec<Vec<[f32; 3]>>, Option<Vec<Vec<[f32; 3]>>>), EngineError> {
        self.direct(scene, lights, true)
    }

    /// Direct light with the sky's share, and the near field's correction when `near` asks for
    /// it and the scene's can be applied.
    #[allow(clippy::type_complexity)]
    fn direct(
        &self,
        scene: &Scene,
        lights: &[LightSet],
        near: bool,
    ) -> Result<(Vec<Vec<[f32; 3]>>, Option<Vec<Vec<[f32; 3]>>>), EngineError> {
        let (mut direct, near) = self.sampled_direct(scene, lights, near)?;
        add_sky(&sky_rows(scene.sky.as_ref(), lights), &mut direct);
        Ok((direct, near))
    }

    /// Direct light from the punctual lights, on the engine's device or the CPU (the rows' sky
    /// is none of theirs: [`add_sky`]), and with `near` the near-field correction of the
    /// punctual lights and the sky together.
    #[allow(clippy::type_complexity)]
    fn sampled_direct(
        &self,
        scene: &Scene,
        lights: &[LightSet],
        near: bool,
    ) -> Result<(Vec<Vec<[f32; 3]>>, Option<Vec<Vec<[f32; 3]>>>), EngineError> {
        let in_use = self.near_in_use(scene).filter(|_| near);
        if let (Some(_), DirectLight::GpuSurface(gpu)) = (in_use, &scene.direct) {
            return Ok(gpu.irradiance_near(lights, self.samples_for(scene))?);
        }
        if let (Some(near), DirectLight::Cpu(shadow, _)) = (in_use, &scene.direct) {
            let mut direct = Vec::with_capacity(lights.len());
            let mut corrections = Vec::with_capacity(lights.len());
            for set in lights {
                let Some(sampled) =
                    direct_with_samples(shadow, &scene.rows, set, self.samples_for(scene))
                else {
                    break;
                };
                let sky = set.sky_sh().and_then(|sky| {
                    near.field
                        .sky_samples_averaging(&sky, scene.area_samples.unwrap_or(u32::MAX))
                });
                corrections.push(near.field.correction_with(
                    near.reflect(),
                    &sampled.mean,
                    &sampled.samples,
                    sky.as_ref(),
                ));
                direct.push(sampled.mean);
            }
            if direct.len() == lights.len() {
                return Ok((direct, Some(corrections)));
            }
        }
        let direct = match &scene.direct {
            DirectLight::Gpu(gpu) => gpu.irradiance(lights, self.samples_for(scene))?,
            DirectLight::GpuSurface(gpu) => gpu.irradiance(lights, self.samples_for(scene))?,
            DirectLight::Cpu(shadow, _) => lights
                .iter()
                .map(|set| direct_irradiance(shadow, &scene.rows, set, self.samples_for(scene)))
                .collect(),
        };
        Ok((direct, None))
    }

    /// Direct-light samples a row of `scene` takes ([`Engine::samples`]).
    pub fn samples_for(&self, scene: &Scene) -> u32 {
        match (self.samples, scene.stored_samples) {
            // A file stores at least one sample a row (the reader checks).
            (Some(n), Some(stored)) => n.max(1).min(stored.max(1)),
            (Some(n), None) => n,
            (None, Some(stored)) => stored,
            (None, None) => DEFAULT_SAMPLES,
        }
    }

    /// The scene's near field when this engine's direct light evaluates the sample points its
    /// columns name (the first `per_row` of each row).
    fn near_in_use<'a>(&self, scene: &'a Scene) -> Option<&'a NearRows> {
        scene
            .near
            .as_ref()
            .filter(|n| self.samples_for(scene) == n.field.per_row)
    }

    /// Whether relights of `scene` on this engine add the near-field first bounce, and if not
    /// why: `Ok(false)` for a file without one, `Err(reason)` where it has one this engine does
    /// not apply.
    pub fn near_field(&self, scene: &Scene) -> Result<bool, String> {
        match &scene.near {
            None => Ok(false),
            Some(n) if self.samples_for(scene) != n.field.per_row => Err(format!(
                "the near field names {} samples a row, direct light uses {}",
                n.field.per_row,
                self.samples_for(scene)
            )),
            Some(_) => Ok(true),
        }
    }

    /// Which engine computes `scene`'s direct light: this one's kind, but the CPU for a scene
    /// the GPU direct kernel cannot take (see [`Scene::direct_fallback`]).
    pub fn direct_engine(&self, scene: &Scene) -> EngineKind {
        scene.direct_engine()
    }

    /// `E_ind` per row (`batch × rows`) from a batch's `B0` and, where the scene has a near
    /// field, its corrections `ΔE` (per set, per row: [`Engine::direct_and_near`]), as
    /// [`Engine::relight`] finishes it before restricting to the patches: `T · (B0 + ρ ⊙ ΔE) + ΔE`
    /// when the later bounces carry the correction ([`Scene::near_carried`]), else
    /// `T · B0 + ΔE`, clamped at zero and kept finite.
    pub fn indirect_with_near(
        &self,
        scene: &Scene,
        b0: &[[f32; 3]],
        near: Option<&[Vec<[f32; 3]>]>,
    ) -> Result<Vec<[f32; 3]>, EngineError> {
        let mut indirect = vec![[0.0f32; 3]; b0.len()];
        if b0.is_empty() {
            return Ok(indirect);
        }
        match (near, scene.near_carried()) {
            (Some(corrections), true) => {
                let source = carried_source(b0, corrections, &scene.rows);
                scene.transport.apply(&source, &mut indirect)?;
            }
            _ => scene.transport.apply(b0, &mut indirect)?,
        }
        for (v, d) in indirect
            .iter_mut()
            .zip(near.into_iter().flatten().flatten())
        {
            // The near rays' element-mean share is part of `T · B0`, so the exact first bounce
            // stays at or above zero, and so does every later bounce re-emitting it; the carried
            // correction's one extra bounce (`carried_source`) and a lossy codec's product may
            // fall a little short of it.
            *v = std::array::from_fn(|c| (v[c] + d[c]).max(0.0));
        }
        // Direct light is clamped to f32::MAX, but `T · B0` sums many such terms and can
        // overflow: keep E_ind finite too (a frame then clamps it to its format's largest and
        // flags it). NaN is left alone: it would be a bug to see, not light to clamp.
        for v in indirect.iter_mut().flatten() {
            if *v == f32::INFINITY {
                *v = f32::MAX;
            }
        }
        Ok(indirect)
    }

    /// `E_ind = T · B0` alone, for a batch of given `B0` vectors (`batch × rows`, the
    /// transport's rows: [`Scene::rows`]), per row, not restricted to the patches.
    pub fn indirect(
        &self,
        scene: &Scene,
        b0: &[[f32; 3]],
        out: &mut [[f32; 3]],
    ) -> Result<(), EngineError> {
        scene.transport.apply(b0, out)
    }
}

/// Per light set, its sky's direct irradiance on each row through the rows' sky view: `None`
/// for a set without a sky, and for every set without a view.
fn sky_rows(view: Option<&SkyVisibility>, lights: &[LightSet]) -> Vec<Option<Vec<[f32; 3]>>> {
    lights
        .iter()
        .map(|set| Some(view?.irradiance(&set.sky_sh()?)))
        .collect()
}

/// Adds each set's sky ([`sky_rows`]) to its rows' direct light (`direct[set][row]`), the row's
/// mean; how it varies over the row is the near field's ([`NearField::sky_samples`]).
fn add_sky(skies: &[Option<Vec<[f32; 3]>>], direct: &mut [Vec<[f32; 3]>]) {
    for (sky, rows) in skies.iter().zip(direct.iter_mut()) {
        let Some(sky) = sky else { continue };
        for (d, e) in rows.iter_mut().zip(sky) {
            // Kept finite as the punctual lights' sums are.
            *d = std::array::from_fn(|c| (d[c] + e[c]).min(f32::MAX));
        }
    }
}

/// Time spent in each half of a relight.
#[derive(Debug, Clone, Copy, Default)]
pub struct Timing {
    /// Direct light with shadows and `B0`, all light sets.
    pub direct_s: f64,
    /// The batched product `T · B0`.
    pub indirect_s: f64,
}

/// Irradiance per patch for one light set (linear RGB).
#[derive(Debug, Clone, PartialEq)]
pub struct Irradiance {
    /// Direct light: the punctual lights' with shadows, and a sky's ([`Irradiance::sky`]).
    pub direct: Vec<[f32; 3]>,
    /// `E_ind`: the light that reached each patch after at least one bounce (emitting surfaces'
    /// light on others included, as it comes through `T`).
    pub indirect: Vec<[f32; 3]>,
    /// The sky's direct irradiance on each patch (part of `direct`), from the bake's sky view:
    /// empty for a light set without a sky or a file without a view.
    pub sky: Vec<[f32; 3]>,
    /// Irradiance at each probe direction (`6 · probe + direction`, [`bounce_core::probe`]):
    /// what an object moving through the scene gathers from its surfaces. Empty for a file
    /// without probes.
    pub probes: Vec<[f32; 3]>,
}

impl Irradiance {
    /// What the service streams to a viewer: the light it cannot draw itself. A viewer draws the
    /// punctual lights with its own shadow maps; everything else reaches a patch through the bake,
    /// so a frame carries `E_ind` plus a sky's direct light (`E_ind` alone without a sky).
    pub fn streamed(&self) -> std::borrow::Cow<'_, [[f32; 3]]> {
        if self.sky.is_empty() {
            return std::borrow::Cow::Borrowed(&self.indirect);
        }
        std::borrow::Cow::Owned(
            self.indirect
                .iter()
                .zip(&self.sky)
                .map(|(i, s)| std::array::from_fn(|c| (i[c] + s[c]).min(f32::MAX)))
                .collect(),
        )
    }
}

/// A baked scene made ready on one engine.
pub struct Scene {
    /// The patches: what a relight returns values for.
    pub layout: PatchLayout,
    /// The transport's rows: the elements of a surface bake that has them, else the patches.
    rows: PatchLayout,
    /// The near-field first bounce, when the file has one.
    near: Option<NearRows>,
    /// Each row's view of the sky, when the file has one.
    sky: Option<SkyVisibility>,
    /// The emissive materials and the rows they cover, when the file lists them.
    emitters: Option<Emitters>,
    /// Irradiance probes and their gather over the rows, when the file has them.
    probes: Option<Probes>,
    /// Sample points a surface bake stores per row.
    stored_samples: Option<u32>,
    /// Of those, how many (the first) are spread by area and make a row's mean.
    area_samples: Option<u32>,
    elements: Option<Elements>,
    direct: DirectLight,
    shadow_source: ShadowSource,
    transport: Transport,
    transport_fallback: Option<String>,
    codec: String,
    matrix_bytes: usize,
}

impl Scene {
    /// The transport's rows (and columns): what [`Engine::indirect`] takes and gives.
    pub fn rows(&self) -> &PatchLayout {
        &self.rows
    }

    /// Whether the file has a sky view, so a sky lights the scene. Without one (a file from
    /// before it) a sky adds nothing: bake the scene again.
    pub fn has_sky_view(&self) -> bool {
        self.sky.is_some()
    }

    /// The emitters a light set may change, by material and node; `None` for a file that lists
    /// none (a voxel-face bake, or one from before format version 6).
    pub fn emitter_names(&self) -> Option<Vec<bounce_core::emitter::EmitterName>> {
        self.emitters.as_ref().map(Emitters::names)
    }

    /// `B0 = L_e + ρ ⊙ E_direct` on the rows for one light set, `L_e` as the set's emissive
    /// changes leave it (`bounce_core::emitter`); refused where a change names no emitter.
    pub fn exitance(
        &self,
        set: &LightSet,
        direct: &[[f32; 3]],
    ) -> Result<Vec<[f32; 3]>, LightError> {
        let changed = match &self.emitters {
            Some(e) => e.emission(self.rows.patches.iter().map(|p| p.emission), set)?,
            None => {
                check_names(None, set)?;
                None
            }
        };
        Ok(match changed {
            Some(emission) => exitance_with(&self.rows, &emission, direct),
            None => exitance_b0(&self.rows, direct),
        })
    }

    /// The probes' positions, when the file has probes.
    pub fn probe_positions(&self) -> Option<&[[f32; 3]]> {
        self.probes.as_ref().map(|p| p.positions.as_slice())
    }

    /// Irradiance at every probe direction from one set's `B0` and `E_ind` on the rows: the
    /// probes gather the rows' exitance `B = B0 + ρ ⊙ E_ind`, and under `set`'s sky add what
    /// each direction sees of it through the openings (the probes' sky view; nothing in a file
    /// without one). Empty without probes. On the host for both engines: the gather is sparse
    /// (a probe direction meets at most its rays' rows) and small beside `T · B0`.
    pub fn probe_irradiance(
        &self,
        b0: &[[f32; 3]],
        indirect: &[[f32; 3]],
        set: &LightSet,
    ) -> Vec<[f32; 3]> {
        let Some(probes) = &self.probes else {
            return Vec::new();
        };
        let exitance: Vec<[f32; 3]> = self
            .rows
            .patches
            .iter()
            .zip(b0.iter().zip(indirect))
            .map(|(p, (b, e))| std::array::from_fn(|c| b[c] + p.albedo[c] * e[c]))
            .collect();
        let mut out = probes.irradiance(&exitance);
        if let Some(sky) = set.sky_sh().and_then(|sky| probes.sky_irradiance(&sky)) {
            for (e, s) in out.iter_mut().zip(sky) {
                *e = std::array::from_fn(|c| (e[c] + s[c]).min(f32::MAX));
            }
        }
        out
    }

    /// Whether the probes see a sky directly (their view of it is in the file).
    pub fn probes_see_the_sky(&self) -> bool {
        self.probes.as_ref().is_some_and(|p| p.sky.is_some())
    }

    /// Relight without the near-field first bounce from now on: how `bounce verify` shows what
    /// it gains.
    pub fn disable_near_field(&mut self) {
        self.near = None;
    }

    /// Trace every CPU shadow ray from now on, keeping no answers from one light set to the
    /// next (`bounce_core::visibility`): the same values at their full cost, which is how
    /// `bounce bench engines` shows what the kept answers spare. No effect where direct light
    /// runs on the GPU.
    pub fn trace_every_shadow_ray(&mut self) {
        if let DirectLight::Cpu(shadow, _) = &mut self.direct {
            shadow.set_visibility_budget(0);
        }
    }

    /// Forget the CPU shadow-ray answers and blockers kept from earlier light sets, so that the
    /// next set costs what a scene's first does (`bounce bench direct` starts each light's
    /// motion from here). The values do not change. No effect where direct light runs on the
    /// GPU, which keeps no answers between sets.
    pub fn forget_shadow_answers(&mut self) {
        if let DirectLight::Cpu(shadow, _) = &mut self.direct {
            shadow.forget_kept();
        }
    }

    /// Whether the later bounces carry the near field's correction: the product takes
    /// `B0 + ρ ⊙ ΔE` ([`carried_source`]) rather than `B0`. True for a scene with a near field
    /// and a transport of more than one bounce.
    pub fn near_carried(&self) -> bool {
        self.near.as_ref().is_some_and(|n| n.carried)
    }

    /// Keep the near field's correction in the first bounce alone from now on (the relights
    /// before session 27): how `bounce verify` shows what carrying it gains.
    pub fn first_bounce_near_field(&mut self) {
        if let Some(n) = &mut self.near {
            n.carried = false;
        }
    }

    /// The transport's codec.
    pub fn codec(&self) -> &str {
        &self.codec
    }

    /// Bytes of the encoded transport (what a product reads, once per pass).
    pub fn matrix_bytes(&self) -> usize {
        self.matrix_bytes
    }

    /// Whether shadows come from the triangles (surface geometry), the voxel occupancy or, for
    /// old files, the patches alone.
    pub fn shadow_source(&self) -> ShadowSource {
        self.shadow_source
    }

    /// Where direct light is computed: a GPU kernel (surface geometry or voxel occupancy on a
    /// GPU engine) or the CPU (the CPU engine, a file with neither, or a scene over a kernel's
    /// limits).
    pub fn direct_engine(&self) -> EngineKind {
        match self.direct {
            DirectLight::Gpu(_) | DirectLight::GpuSurface(_) => EngineKind::Gpu,
            DirectLight::Cpu(..) => EngineKind::Cpu,
        }
    }

    /// Why a scene on the GPU engine has its direct light on the CPU, if it does.
    pub fn direct_fallback(&self) -> Option<&str> {
        match &self.direct {
            DirectLight::Cpu(_, why) => why.as_deref(),
            DirectLight::Gpu(_) | DirectLight::GpuSurface(_) => None,
        }
    }

    /// Where `T · B0` runs: the engine's own device, or the CPU for a matrix a GPU engine could
    /// not hold.
    pub fn transport_engine(&self) -> EngineKind {
        match self.transport {
            Transport::Gpu(_) => EngineKind::Gpu,
            Transport::Cpu(_) => EngineKind::Cpu,
        }
    }

    /// Why a scene on the GPU engine has its product on the CPU, if it does.
    pub fn transport_fallback(&self) -> Option<&str> {
        self.transport_fallback.as_deref()
    }

    /// Into how many pieces the GPU holds the matrix (row bands or texture tiles); 1 on the CPU.
    pub fn transport_pieces(&self) -> usize {
        match &self.transport {
            Transport::Gpu(m) => m.pieces(),
            Transport::Cpu(_) => 1,
        }
    }

    /// Passes over the matrix a batch of `sets` costs.
    pub fn passes_for(&self, sets: usize) -> usize {
        match self.transport {
            Transport::Gpu(_) => GpuMatrix::passes_for(sets),
            Transport::Cpu(_) => usize::from(sets > 0),
        }
    }
}

/// Whether a transport of `bounces` carries the near field's correction through its later
/// bounces: every one but a one-bounce transport, which has no later bounce to carry it into.
pub fn carries_near_field(bounces: Bounces) -> bool {
    bounces != Bounces::K(1)
}

/// What the product multiplies when the later bounces carry the near field: per light set and
/// row, `B0 + ρ ⊙ ΔE`, the row's own exitance plus what it re-emits of its first bounce's
/// correction (`corrections`, per set, per row; `ρ` the rows' albedo, as in `B0`).
///
/// `T = Σ_{k<b} (F R)^k F` then takes `ΔE` through bounces 2 to `b + 1`: one further than
/// `B0`'s light goes, by `(F R)^b ΔE`, a term of order `ρ^b` of the correction, which a `b`-bounce
/// transport leaves out of `B0`'s light anyway (it is light there is). The exact `b − 1` would
/// need `F`, which a baked file does not keep. A sum may be negative where a row's near
/// landings gather less than its sources' means; the product is linear, and the sum of its
/// parts is what is clamped.
pub fn carried_source(
    b0: &[[f32; 3]],
    corrections: &[Vec<[f32; 3]>],
    rows: &PatchLayout,
) -> Vec<[f32; 3]> {
    debug_assert_eq!(
        corrections.iter().map(Vec::len).sum::<usize>(),
        b0.len(),
        "one correction per set and row"
    );
    let albedo = rows.patches.iter().map(|p| p.albedo).cycle();
    b0.iter()
        .zip(corrections.iter().flatten())
        .zip(albedo)
        .map(|((b, d), a)| std::array::from_fn(|c| b[c] + a[c] * d[c]))
        .collect()
}

/// Per transport row, its albedo: what the near-field correction multiplies by.
fn row_albedo(baked: &Baked) -> Vec<[f32; 3]> {
    baked
        .transport_layout()
        .patches
        .iter()
        .map(|p| p.albedo)
        .collect()
}

/// A scene's near-field matrix with what its correction multiplies by.
struct NearRows {
    field: NearField,
    /// Per transport row.
    albedo: Vec<[f32; 3]>,
    /// Per sample point, when the file keeps them (format version 11).
    sample_albedo: Option<Vec<[f32; 3]>>,
    /// Whether the later bounces carry the correction ([`Scene::near_carried`]).
    carried: bool,
}

impl NearRows {
    fn reflect(&self) -> Reflect<'_> {
        Reflect {
            rows: &self.albedo,
            samples: self.sample_albedo.as_deref(),
        }
    }
}

/// Where a scene's direct light is computed.
enum DirectLight {
    /// Shadow rays traced on the host, with why the GPU engine did not take it (`None` on the
    /// CPU engine).
    Cpu(Box<ShadowScene>, Option<String>),
    /// [`GpuDirect`]: the scene's patches and occupancy resident on the device.
    Gpu(Box<GpuDirect>),
    /// [`GpuSurfaceDirect`]: the scene's triangles (a BVH) and sample points resident on the
    /// device.
    GpuSurface(Box<GpuSurfaceDirect>),
}

enum Transport {
    Cpu(Box<dyn MatrixOp>),
    Gpu(Box<GpuMatrix>),
}

impl Transport {
    fn apply(&self, b0: &[[f32; 3]], out: &mut [[f32; 3]]) -> Result<(), EngineError> {
        match self {
            Transport::Cpu(op) => op.matvec_batch(b0, out)?,
            Transport::Gpu(m) => m.matvec_batch(b0, out)?,
        }
        Ok(())
    }
}
