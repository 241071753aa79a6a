//! Punctual lights evaluated from their definition (`bounce_core::light`: glTF
//! `KHR_lights_punctual` units; radiometric use of the intensity, `radiant = intensity · color`;
//! the range window `clamp(1 − (d/range)⁴, 0, 1)²` and the spot's squared linear cone ramp),
//! written here again rather than called from `bounce_core::direct`: if the pipeline's light code
//! drifts from the definition, the reference does not drift with it.

use bounce_core::light::{Light, LightSet};
use glam::Vec3;

/// What the tracer lights a scene with: the punctual lights, and the sky, if any.
pub(crate) struct Illumination {
    pub sources: Vec<Source>,
    pub sky: Option<Sky>,
    /// Per mesh triangle, its emission where the set changes an emissive material; `None`
    /// where it changes none (each triangle's own then holds).
    pub emission: Option<Vec<Vec3>>,
    /// The emitting triangles, for next-event estimation towards them; `None` where nothing
    /// emits (or for direct light alone, which emission is no part of).
    pub emitters: Option<EmitterSampler>,
}

impl Illumination {
    pub fn new(lights: &LightSet) -> Illumination {
        Illumination {
            sources: lights.lights.iter().filter_map(Source::new).collect(),
            sky: lights.lights.iter().find_map(Sky::new),
            emission: None,
            emitters: None,
        }
    }

    /// What triangle `index` (of the mesh, whose own emission is `own`) emits under this set.
    #[inline]
    pub fn emission(&self, index: u32, own: Vec3) -> Vec3 {
        self.emission
            .as_ref()
            .and_then(|e| e.get(index as usize).copied())
            .unwrap_or(own)
    }
}

/// Emitting triangles picked in proportion to their power (area × the sum of their emission's
/// channels), then a point uniformly on the one picked: the area light a path's vertex samples
/// for the light that surfaces emit.
pub(crate) struct EmitterSampler {
    /// Mesh triangle indices.
    pub tris: Vec<u32>,
    /// Running sums of the weights, the last being their total.
    cdf: Vec<f64>,
    /// Per mesh triangle, the chance it is picked (0 for one that does not emit).
    chance: Vec<f64>,
}

impl EmitterSampler {
    /// The sampler over the mesh's `count` triangles, of which `tris` (index, area, emission)
    /// may emit; `None` when none does.
    pub fn new(
        count: usize,
        tris: impl Iterator<Item = (u32, f32, Vec3)>,
    ) -> Option<EmitterSampler> {
        let mut out = EmitterSampler {
            tris: Vec::new(),
            cdf: Vec::new(),
            chance: vec![0.0; count],
        };
        let mut sum = 0.0f64;
        let mut weights = Vec::new();
        for (i, area, e) in tris {
            let w = f64::from(area) * f64::from(e.x + e.y + e.z);
            if w > 0.0 && w.is_finite() && (i as usize) < count {
                sum += w;
                out.tris.push(i);
                out.cdf.push(sum);
                weights.push(w);
            }
        }
        for (&i, w) in out.tris.iter().zip(weights) {
            out.chance[i as usize] = w / sum;
        }
        (!out.tris.is_empty()).then_some(out)
    }

    /// The chance triangle `index` is picked.
    pub fn chance(&self, index: u32) -> f64 {
        self.chance.get(index as usize).copied().unwrap_or(0.0)
    }

    /// A triangle for `u` in `[0, 1)` and the chance it had.
    pub fn pick(&self, u: f32) -> (u32, f64) {
        let total = *self.cdf.last().unwrap_or(&1.0);
        let target = f64::from(u) * total;
        let k = self
            .cdf
            .partition_point(|&c| c <= target)
            .min(self.tris.len() - 1);
        let below = if k == 0 { 0.0 } else { self.cdf[k - 1] };
        (self.tris[k], (self.cdf[k] - below) / total)
    }
}

/// A triangle's emission `own` when its material's (`baked`: emissive factor × strength) becomes
/// `new`: each channel keeps its share of the material's (the emissive texture's average over
/// the triangle), a channel the material did not emit in taking the others' mean share.
pub(crate) fn rescaled_emission(own: Vec3, baked: Vec3, new: Vec3) -> Vec3 {
    let mut shares = [0.0f32; 3];
    let (mut sum, mut lit) = (0.0f32, 0);
    for c in 0..3 {
        if baked[c] > 0.0 {
            shares[c] = own[c] / baked[c];
            sum += shares[c];
            lit += 1;
        }
    }
    let mean = if lit > 0 { sum / lit as f32 } else { 0.0 };
    for (c, share) in shares.iter_mut().enumerate() {
        if baked[c] <= 0.0 {
            *share = mean;
        }
    }
    (Vec3::from(shares) * new).max(Vec3::ZERO)
}

/// The sky's radiance by direction: a uniform colour, or order-2 real spherical harmonics in
/// the standard basis (written out here again, so a slip in the bake's basis does not hide).
#[derive(Debug, Clone, Copy)]
pub(crate) enum Sky {
    Uniform(Vec3),
    Harmonics([Vec3; 9]),
}

impl Sky {
    /// `None` for a punctual light or a sky given neither way.
    pub fn new(light: &Light) -> Option<Sky> {
        let Light::Sky { color, sh, .. } = light else {
            return None;
        };
        match (color, sh) {
            (Some(c), _) => Some(Sky::Uniform(Vec3::from(*c))),
            (None, Some(sh)) if sh.len() == 9 => {
                Some(Sky::Harmonics(std::array::from_fn(|k| Vec3::from(sh[k]))))
            }
            _ => None,
        }
    }

    /// Radiance arriving from unit direction `d` (the direction one looks in, towards the sky).
    pub fn radiance(&self, d: Vec3) -> Vec3 {
        match self {
            Sky::Uniform(c) => *c,
            Sky::Harmonics(l) => {
                let (x, y, z) = (d.x, d.y, d.z);
                let pi = std::f32::consts::PI;
                let c0 = 0.5 / pi.sqrt();
                let c1 = (3.0 / (4.0 * pi)).sqrt();
                let c2 = (15.0 / (4.0 * pi)).sqrt();
                let c20 = (5.0 / (16.0 * pi)).sqrt();
                let c22 = (15.0 / (16.0 * pi)).sqrt();
                let basis = [
                    c0,
                    c1 * y,
                    c1 * z,
                    c1 * x,
                    c2 * x * y,
                    c2 * y * z,
                    c20 * (3.0 * z * z - 1.0),
                    c2 * x * z,
                    c22 * (x * x - y * y),
                ];
                basis.iter().zip(l).map(|(b, c)| *c * *b).sum()
            }
        }
    }
}

/// A light in the form the tracer evaluates.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Source {
    /// `toward`: unit vector from the scene towards the light; `irradiance` on a surface facing it.
    Sun { toward: Vec3, irradiance: Vec3 },
    /// `intensity` per steradian; `cone`: for a spot, its unit axis and the cosines of its outer
    /// and inner angles.
    Lamp {
        position: Vec3,
        intensity: Vec3,
        range: Option<f32>,
        cone: Option<(Vec3, f32, f32)>,
    },
}

/// What a light gives a point before visibility: the direction to it, how far that is, and the
/// irradiance on a surface with the given normal.
pub(crate) struct Arrival {
    pub dir: Vec3,
    pub distance: f32,
    pub irradiance: Vec3,
}

impl Source {
    /// `None` for a light that lights nothing (zero power, or no direction).
    pub fn new(light: &Light) -> Option<Source> {
        let colour = |c: [f32; 3], i: f32| Vec3::from(c) * i;
        let source = match *light {
            Light::Directional {
                direction,
                color,
                intensity,
                ..
            } => Source::Sun {
                toward: -Vec3::from(direction).try_normalize()?,
                irradiance: colour(color, intensity),
            },
            Light::Point {
                position,
                color,
                intensity,
                range,
                ..
            } => Source::Lamp {
                position: position.into(),
                intensity: colour(color, intensity),
                range,
                cone: None,
            },
            Light::Spot {
                position,
                direction,
                color,
                intensity,
                range,
                inner_cone_angle,
                outer_cone_angle,
                ..
            } => Source::Lamp {
                position: position.into(),
                intensity: colour(color, intensity),
                range,
                cone: Some((
                    Vec3::from(direction).try_normalize()?,
                    outer_cone_angle.cos(),
                    inner_cone_angle.cos(),
                )),
            },
            // Not a source a shadow ray can find: [`Sky`].
            Light::Sky { .. } => return None,
            // Not a light but a change to the triangles' emission, which the mesh carries
            // (`bounce_core::emitter::apply_to_scene`, applied before the mesh is built).
            Light::Emissive { .. } => return None,
        };
        let power = match source {
            Source::Sun { irradiance, .. } => irradiance,
            Source::Lamp { intensity, .. } => intensity,
        };
        (power.is_finite() && power.max_element() > 0.0).then_some(source)
    }

    pub fn arrive(&self, p: Vec3, n: Vec3) -> Option<Arrival> {
        match *self {
            Source::Sun { toward, irradiance } => {
                let cos = n.dot(toward);
                (cos > 0.0).then(|| Arrival {
                    dir: toward,
                    distance: f32::INFINITY,
                    irradiance: irradiance * cos,
                })
            }
            Source::Lamp {
                position,
                intensity,
                range,
                cone,
            } => {
                let to = position - p;
                let d = to.length();
                // NaN (a non-finite position) and zero both end here.
                if d.is_nan() || d <= 0.0 {
                    return None;
                }
                let dir = to / d;
                let cos = n.dot(dir);
                if cos <= 0.0 {
                    return None;
                }
                let mut falloff = 1.0 / (d * d);
                if let Some(range) = range {
                    let x = d / range;
                    let w = (1.0 - x.powi(4)).clamp(0.0, 1.0);
                    falloff *= w * w;
                }
                if let Some((axis, cos_outer, cos_inner)) = cone {
                    // cos of the angle off the axis, mapped to 0 at the outer and 1 at the inner
                    // angle, squared (KHR_lights_punctual's recommended smooth falloff).
                    let off_axis = axis.dot(-dir);
                    let ramp = ((off_axis - cos_outer) / (cos_inner - cos_outer).max(1e-3))
                        .clamp(0.0, 1.0);
                    falloff *= ramp * ramp;
                }
                (falloff > 0.0).then(|| Arrival {
                    dir,
                    distance: d,
                    irradiance: intensity * (cos * falloff),
                })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reference's own basis against the bake's: the same radiance in every direction.
    #[test]
    fn sky_harmonics_match_the_light_definition() {
        let coeffs: Vec<[f32; 3]> = (0..9)
            .map(|k| [1.0 - 0.1 * k as f32, 0.3 * k as f32, 0.05])
            .collect();
        let light = Light::Sky {
            color: None,
            sh: Some(coeffs.clone()),
            name: None,
        };
        let sky = Sky::new(&light).unwrap();
        let fixed: [[f32; 3]; 9] = coeffs.try_into().unwrap();
        for d in [
            Vec3::X,
            Vec3::NEG_Y,
            Vec3::new(0.3, 0.8, -0.52).normalize(),
            Vec3::new(-0.7, 0.1, 0.7).normalize(),
        ] {
            let mine = sky.radiance(d);
            let theirs = bounce_core::sh::sh_radiance(
                &fixed,
                [f64::from(d.x), f64::from(d.y), f64::from(d.z)],
            );
            for c in 0..3 {
                assert!(
                    (f64::from(mine[c]) - theirs[c]).abs() < 1e-5,
                    "{d}: {mine} {theirs:?}"
                );
            }
        }
        let uniform = Sky::new(&Light::Sky {
            color: Some([0.5, 1.0, 2.0]),
            sh: None,
            name: None,
        })
        .unwrap();
        assert_eq!(uniform.radiance(Vec3::Z), Vec3::new(0.5, 1.0, 2.0));
    }

    #[test]
    fn inverse_square_cosine_and_cone() {
        let point = Source::new(&Light::Point {
            position: [0.0, 2.0, 0.0],
            color: [1.0, 0.5, 0.25],
            intensity: 8.0,
            range: None,
            name: None,
        })
        .unwrap();
        let a = point.arrive(Vec3::ZERO, Vec3::Y).unwrap();
        assert!((a.irradiance - Vec3::new(2.0, 1.0, 0.5)).length() < 1e-6);
        assert_eq!(a.distance, 2.0);
        // 60° off the normal: half.
        let tilted = Vec3::new(3f32.sqrt() / 2.0, 0.5, 0.0);
        let b = point.arrive(Vec3::ZERO, tilted).unwrap();
        assert!((b.irradiance.x - 1.0).abs() < 1e-5);
        assert!(point.arrive(Vec3::ZERO, -Vec3::Y).is_none());

        let spot = Source::new(&Light::Spot {
            position: [0.0, 1.0, 0.0],
            direction: [0.0, -1.0, 0.0],
            color: [1.0; 3],
            intensity: 1.0,
            range: None,
            inner_cone_angle: 0.2,
            outer_cone_angle: 0.4,
            name: None,
        })
        .unwrap();
        assert!((spot.arrive(Vec3::ZERO, Vec3::Y).unwrap().irradiance.x - 1.0).abs() < 1e-6);
        // Outside the outer cone: nothing.
        assert!(spot.arrive(Vec3::new(1.0, 0.0, 0.0), Vec3::Y).is_none());

        let sun = Source::new(&Light::Directional {
            direction: [0.0, -1.0, 0.0],
            color: [1.0; 3],
            intensity: 3.0,
            name: None,
        })
        .unwrap();
        assert_eq!(
            sun.arrive(Vec3::ZERO, Vec3::Y).unwrap().irradiance,
            Vec3::splat(3.0)
        );
    }
}
