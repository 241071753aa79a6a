//! `bounce-reference`: an independent Monte-Carlo reference for the indirect irradiance the
//! pipeline computes, to measure the pipeline's error against.
//!
//! It owns a path tracer of diffuse transport on the **original triangles** (a BVH over the full
//! mesh, not the patches), its own light evaluation, random numbers and sampling, and the
//! placement of reference points on the surfaces patches stand for. It shares nothing with the
//! bake's form factors, transport or direct light but the scene and light *types* and the BVH
//! crate, so a bug in one cannot hide in the other. How a pipeline's answer is measured against
//! the reference, and the error split by its source, is [`compare`]: arrays in, a report out,
//! for `bounce verify` and `bounce bench tradeoff` alike.
//!
//! Every value comes with its standard error, and a value depends only on the seed, the point's
//! index and the sample count, not on the thread count.

pub mod compare;
mod estimate;
mod footprint;
mod lights;
mod mesh;
mod rng;

use bounce_core::light::LightSet;
use bounce_core::meta::Bounces;
use bounce_core::patch::PatchLayout;
use bounce_core::scene::Scene;
use glam::Vec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::lights::Illumination;
use crate::mesh::Mesh;
use crate::rng::{Pcg32, mix};

/// Rays a point's direct light from a sky is averaged over in [`Reference::direct`]: a standard
/// error under 1.6% of the unoccluded value (a cosine-weighted escape is a Bernoulli draw).
pub const SKY_DIRECT_RAYS: u32 = 1024;

#[derive(Debug, Error)]
pub enum ReferenceError {
    #[error("the scene has no triangle with an area to trace")]
    EmptyScene,
    #[error("point {index}: {reason}")]
    BadPoint { index: usize, reason: String },
    #[error("--spp must be at least 2 (a standard error needs two samples)")]
    TooFewSamples,
    /// An emissive change reaches no emissive surface of the scene.
    #[error("lights[{index}]: the scene has no {what}")]
    UnknownEmitter { index: usize, what: String },
}

/// Where to estimate: a point on a surface and the side it faces.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Point {
    pub position: [f32; 3],
    pub normal: [f32; 3],
}

/// An estimate of linear RGB indirect irradiance and its standard error (one sigma of the mean).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    pub mean: [f64; 3],
    pub stderr: [f64; 3],
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Options {
    /// Sample paths per point.
    pub spp: u32,
    /// Light bounces carried, in the design's sense (`T_k`): 1 is light reflected once before it
    /// reaches the point.
    pub bounces: Bounces,
    pub seed: u64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            spp: 1024,
            bounces: Bounces::All,
            seed: 1,
        }
    }
}

/// The traced scene: build once, estimate many light configurations.
pub struct Reference {
    mesh: Mesh,
    /// The scene's materials: names, emission and strength, for emissive changes.
    materials: Vec<bounce_core::scene::MaterialInfo>,
}

/// How [`Reference::snap_patches`] placed each point.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SnapReport {
    /// Moved onto the nearest surface along the patch normal.
    pub snapped: usize,
    /// Left at the recorded centroid: no surface within half a voxel along the normal.
    pub kept: usize,
}

impl Reference {
    pub fn new(scene: &Scene) -> Result<Reference, ReferenceError> {
        Ok(Reference {
            mesh: Mesh::new(scene).ok_or(ReferenceError::EmptyScene)?,
            materials: scene.materials.clone(),
        })
    }

    /// Triangles traced (zero-area ones are left out).
    pub fn triangles(&self) -> usize {
        self.mesh.tris.len()
    }

    /// The points the patches of `layout` stand for: each patch's recorded centroid (the
    /// area-weighted centroid of its triangles), moved along its normal onto the nearest original
    /// surface within half a voxel. A centroid of triangles that meet at an angle (a corner, a
    /// curve) lies off every surface, in the air or inside the solid; irradiance there is not what
    /// the patch stands for. The normal is the surface's, turned to the patch's side.
    pub fn snap_patches(&self, layout: &PatchLayout) -> (Vec<Point>, SnapReport) {
        let reach = layout.voxel_size * 0.5;
        let mut report = SnapReport::default();
        let points = layout
            .patches
            .iter()
            .map(|p| {
                let c = Vec3::from(p.centroid);
                let n = Vec3::from(p.normal)
                    .try_normalize()
                    .unwrap_or(p.face.normal());
                // Start each probe just behind the centroid so a surface through it is found.
                let back = self.mesh.epsilon * 2.0;
                let nearest = [n, -n]
                    .into_iter()
                    .filter_map(|d| {
                        let hit = self.mesh.closest(c - d * back, d)?;
                        let t = hit.t - back;
                        (t <= reach).then_some((t.abs(), hit.tri))
                    })
                    .min_by(|a, b| a.0.total_cmp(&b.0));
                match nearest {
                    Some((_, tri)) => {
                        let tri = &self.mesh.tris[tri as usize];
                        // The exact foot of the perpendicular onto the triangle's plane.
                        let foot = c - tri.normal * (c - tri.p0).dot(tri.normal);
                        let side = if tri.normal.dot(n) >= 0.0 {
                            tri.normal
                        } else {
                            -tri.normal
                        };
                        report.snapped += 1;
                        Point {
                            position: foot.to_array(),
                            normal: side.to_array(),
                        }
                    }
                    None => {
                        report.kept += 1;
                        Point {
                            position: p.centroid,
                            normal: n.to_array(),
                        }
                    }
                }
            })
            .collect();
        (points, report)
    }

    /// The patches' recorded centroids and normals as they are, not moved onto a surface.
    pub fn patch_centroids(layout: &PatchLayout) -> Vec<Point> {
        layout
            .patches
            .iter()
            .map(|p| Point {
                position: p.centroid,
                normal: Vec3::from(p.normal)
                    .try_normalize()
                    .unwrap_or(p.face.normal())
                    .to_array(),
            })
            .collect()
    }

    /// Indirect irradiance at every point under `lights`, in parallel; `progress` is called with
    /// the number of points finished since its last call.
    pub fn estimate(
        &self,
        lights: &LightSet,
        points: &[Point],
        options: &Options,
        progress: &(dyn Fn(u64) + Sync),
    ) -> Result<Vec<Estimate>, ReferenceError> {
        if options.spp < 2 {
            return Err(ReferenceError::TooFewSamples);
        }
        for (index, p) in points.iter().enumerate() {
            let bad = |reason: &str| ReferenceError::BadPoint {
                index,
                reason: reason.to_string(),
            };
            if !Vec3::from(p.position).is_finite() {
                return Err(bad("position is not finite"));
            }
            if Vec3::from(p.normal).try_normalize().is_none() {
                return Err(bad("normal is zero or not finite"));
            }
        }
        let sources = self.illumination(lights)?;
        Ok(points
            .par_iter()
            .enumerate()
            .map(|(i, p)| {
                let e = self.point(&sources, p, i as u64, options);
                progress(1);
                e
            })
            .collect())
    }

    /// Direct irradiance at every point, shadowed by the full mesh: from the punctual lights
    /// exact (one shadow ray per light), so it has no standard error; from a sky, the mean of
    /// [`SKY_DIRECT_RAYS`] cosine-weighted rays (seeded by the point, so the same point gets the
    /// same value). With the patches' albedo it gives the pipeline's `B0` as the original
    /// surfaces would have it, which separates the error of lighting a voxel patch from the
    /// error of its transport.
    pub fn direct(&self, lights: &LightSet, points: &[Point]) -> Vec<[f64; 3]> {
        self.direct_with(&Illumination::new(lights), points, SKY_DIRECT_RAYS)
    }

    /// [`Reference::direct`] with `sky_rays` rays a point for the sky.
    fn direct_with(&self, lights: &Illumination, points: &[Point], sky_rays: u32) -> Vec<[f64; 3]> {
        points
            .par_iter()
            .map(|p| {
                let n = Vec3::from(p.normal).normalize_or_zero();
                let x = Vec3::from(p.position);
                let mut e = estimate::direct(&self.mesh, &lights.sources, x, n)
                    .to_array()
                    .map(f64::from);
                if let Some(sky) = &lights.sky {
                    let key = p
                        .position
                        .iter()
                        .chain(&p.normal)
                        .fold(0u64, |h, v| mix(h ^ u64::from(v.to_bits())));
                    let mut rng = Pcg32::new(key, mix(key));
                    let mut sum = [0.0f64; 3];
                    for _ in 0..sky_rays {
                        let s = estimate::sky_direct(&self.mesh, sky, x, n, &mut rng);
                        for c in 0..3 {
                            sum[c] += f64::from(s[c]);
                        }
                    }
                    for c in 0..3 {
                        e[c] += sum[c] / f64::from(sky_rays.max(1));
                    }
                }
                e
            })
            .collect()
    }

    /// Indirect irradiance averaged over each patch's footprint on the original surfaces (the
    /// pieces of triangles in its voxel that face its way, weighted by projected area): what a
    /// patch's value stands for. `points_per_patch` footprint points share the `spp` samples; a
    /// patch with no footprint found falls back to its snapped point ([`Self::snap_patches`]).
    /// Also returns the first footprint point of each patch (or the fallback), for reports.
    pub fn estimate_footprints(
        &self,
        lights: &LightSet,
        layout: &PatchLayout,
        points_per_patch: usize,
        options: &Options,
        progress: &(dyn Fn(u64) + Sync),
    ) -> Result<(Vec<Estimate>, Vec<Point>, usize), ReferenceError> {
        if options.spp < 2 {
            return Err(ReferenceError::TooFewSamples);
        }
        let mut sets =
            footprint::footprints(&self.mesh, layout, points_per_patch.max(1), options.seed);
        let (snapped, _) = self.snap_patches(layout);
        let mut fallbacks = 0;
        for (set, point) in sets.iter_mut().zip(&snapped) {
            if set.is_empty() {
                set.push(*point);
                fallbacks += 1;
            }
        }
        let sources = self.illumination(lights)?;
        let estimates = sets
            .par_iter()
            .enumerate()
            .map(|(i, set)| {
                let e = self.average(&sources, set, i as u64, options);
                progress(1);
                e
            })
            .collect();
        Ok((estimates, sets.iter().map(|s| s[0]).collect(), fallbacks))
    }

    /// Direct irradiance averaged over each patch's footprint (the same points
    /// [`Self::estimate_footprints`] draws for this seed; the snapped centroid where there are
    /// none). A sky's share takes [`SKY_DIRECT_RAYS`] rays a patch, spread over its points.
    pub fn footprint_direct(
        &self,
        lights: &LightSet,
        layout: &PatchLayout,
        points_per_patch: usize,
        seed: u64,
    ) -> Vec<[f64; 3]> {
        let sets = footprint::footprints(&self.mesh, layout, points_per_patch.max(1), seed);
        let (snapped, _) = self.snap_patches(layout);
        let lights = Illumination::new(lights);
        sets.iter()
            .zip(snapped)
            .map(|(set, fallback)| {
                let set = if set.is_empty() {
                    std::slice::from_ref(&fallback)
                } else {
                    set.as_slice()
                };
                let sky_rays = SKY_DIRECT_RAYS.div_ceil(set.len() as u32).max(1);
                let sum = self
                    .direct_with(&lights, set, sky_rays)
                    .into_iter()
                    .fold([0.0; 3], |a, d| [a[0] + d[0], a[1] + d[1], a[2] + d[2]]);
                sum.map(|v| v / set.len() as f64)
            })
            .collect()
    }

    /// The light set's sources, and the triangles' emission where it changes an emissive
    /// material (the estimate sees them as area lights, met by the paths).
    fn illumination(&self, lights: &LightSet) -> Result<Illumination, ReferenceError> {
        let mut out = Illumination::new(lights);
        let mut changed: Vec<Option<Vec3>> = vec![None; self.materials.len()];
        for (index, change) in lights.emissive_indexed() {
            let (color, strength) = (change.color, change.strength);
            let mut found = false;
            for (m, info) in self.materials.iter().enumerate() {
                let baked = Vec3::from(info.emission);
                if !change.reaches(&info.name, info.node.as_deref()) || baked.max_element() <= 0.0 {
                    continue;
                }
                let s = if info.emissive_strength > 0.0 {
                    info.emissive_strength
                } else {
                    1.0
                };
                let color = color.map_or(baked / s, Vec3::from);
                changed[m] = Some(color * strength.unwrap_or(s));
                found = true;
            }
            if !found {
                return Err(ReferenceError::UnknownEmitter {
                    index,
                    what: change.describe(),
                });
            }
        }
        let changes = changed.iter().any(Option::is_some);
        if changes {
            out.emission = Some(
                self.mesh
                    .tris
                    .iter()
                    .map(|t| match changed.get(t.material as usize) {
                        Some(Some(new)) => {
                            let baked = Vec3::from(self.materials[t.material as usize].emission);
                            lights::rescaled_emission(t.emission, baked, *new)
                        }
                        _ => t.emission,
                    })
                    .collect(),
            );
        }
        out.emitters = lights::EmitterSampler::new(
            self.mesh.tris.len(),
            self.mesh.tris.iter().enumerate().map(|(i, t)| {
                let i = i as u32;
                (i, t.area(), out.emission(i, t.emission))
            }),
        );
        Ok(out)
    }

    fn point(&self, sources: &Illumination, p: &Point, index: u64, options: &Options) -> Estimate {
        self.average(sources, std::slice::from_ref(p), index, options)
    }

    /// `options.spp` samples spread round-robin over `points` (non-empty): the mean of the
    /// points' means. Where the points are draws from a patch's footprint, the standard error is
    /// taken across the points' means, so it counts how much the value varies over the patch
    /// (how well the points stand for it) as well as the paths' noise; from the paths alone it
    /// would miss the first, which on a patch half in shadow is most of it. With one point, or
    /// as many points as paths, the two agree.
    fn average(
        &self,
        sources: &Illumination,
        points: &[Point],
        index: u64,
        options: &Options,
    ) -> Estimate {
        let mut rng = Pcg32::new(mix(options.seed), mix(index ^ mix(options.seed)));
        let used = points.len().min(options.spp as usize);
        // Per point: its samples' sum and count; Welford over all paths for the one-point case.
        let mut sums = vec![([0.0f64; 3], 0u32); used];
        let mut mean = [0.0f64; 3];
        let mut m2 = [0.0f64; 3];
        for k in 0..options.spp {
            let slot = k as usize % used;
            let p = &points[slot];
            let x = Vec3::from(p.position);
            let n = Vec3::from(p.normal).normalize_or_zero();
            let s = estimate::sample(&self.mesh, sources, x, n, options.bounces, &mut rng);
            let count = f64::from(k + 1);
            for c in 0..3 {
                let v = f64::from(s[c]);
                let delta = v - mean[c];
                mean[c] += delta / count;
                m2[c] += delta * (v - mean[c]);
                sums[slot].0[c] += v;
            }
            sums[slot].1 += 1;
        }
        if used < 2 {
            let n = f64::from(options.spp);
            return Estimate {
                mean,
                stderr: m2.map(|m| (m / (n - 1.0) / n).sqrt()),
            };
        }
        let means: Vec<[f64; 3]> = sums
            .iter()
            .map(|(s, n)| s.map(|v| v / f64::from(*n)))
            .collect();
        let p = used as f64;
        let mean: [f64; 3] = std::array::from_fn(|c| means.iter().map(|m| m[c]).sum::<f64>() / p);
        let stderr = std::array::from_fn(|c| {
            let var = means.iter().map(|m| (m[c] - mean[c]).powi(2)).sum::<f64>() / (p - 1.0);
            (var / p).sqrt()
        });
        Estimate { mean, stderr }
    }
}
