//! A sun and its sky from the sun's direction and the air's turbidity: the Preetham, Shirley and
//! Smits (1999) clear-sky model, as the two lights the engine already has, a directional sun with
//! shadows and an order-2 SH sky. A day-night cycle is a sequence of such light sets.
//!
//! **Sky.** Luminance `Y` and chromaticity `x, y` of the sky in the direction at angle `θ` from
//! the zenith and `γ` from the sun are each Perez's function, scaled to the zenith's value:
//!
//! ```text
//! F(θ, γ) = (1 + A e^(B / cos θ)) (1 + C e^(D γ) + E cos² γ),    v(θ, γ) = v_zenith F(θ, γ) / F(0, θs)
//! ```
//!
//! with the paper's coefficients linear in the turbidity `T` and its zenith luminance and
//! chromaticity polynomials in `T` and the sun's zenith angle `θs`. `Y` is in kcd/m²; `xyY` goes
//! to CIE XYZ and then linear sRGB (Rec. 709 primaries, D65). Below the horizon the sky gives
//! nothing (the ground is the scene's own geometry). The radiance is then projected onto order-2
//! SH over a grid of the upper hemisphere ([`crate::environment::project_equirect`]'s weights).
//!
//! **Sun.** A directional light towards `-direction`, its illuminance the extraterrestrial
//! 128 klux through the air mass of its elevation (Kasten and Young's air mass, Meinel's
//! `0.7^(AM^0.678)` transmittance), its colour the sky model's chromaticity at the sun (warmer as
//! it sets), normalised to unit luminance.
//!
//! **Units.** Both in thousands (kcd/m² and klux) times `scale`, so a midday scene with
//! `scale = 1` has a sun near 90 and a sky near 10 on a floor: pick `scale` to put them in the
//! scene's own light units (the Cornell box's point light is 10 cd).
//!
//! What this does not do: night (the sun below the horizon is refused: give a dim sky colour
//! instead), the sun's disc in the SH (it is the directional light), clouds, or the ground's own
//! bounce below the horizon.

use bounce_types::light::{Light, LightSet};
use bounce_types::sh::SH_COEFFICIENTS;
use glam::DVec3;

/// Turbidity the model was fitted over.
pub const TURBIDITY: std::ops::RangeInclusive<f64> = 1.7..=10.0;
/// Extraterrestrial solar illuminance, klux.
const SUN_KLUX: f64 = 128.0;

/// Why a sun and sky cannot be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SunSkyError {
    #[error("the sun's direction {0:?} is not a finite, non-zero vector")]
    Direction([f32; 3]),
    #[error(
        "the sun is {0:.1}° below the horizon: the model is a daytime sky (for night, a dim \
         sky colour)"
    )]
    Night(f64),
    #[error("turbidity {0} is outside the model's 1.7 to 10 (2 clear, 3 typical, 6+ hazy)")]
    Turbidity(f64),
    #[error("scale {0} must be finite and not negative")]
    Scale(f64),
}

/// Perez's five coefficients.
#[derive(Debug, Clone, Copy)]
struct Perez([f64; 5]);

impl Perez {
    fn f(&self, cos_theta: f64, gamma: f64) -> f64 {
        let [a, b, c, d, e] = self.0;
        (1.0 + a * (b / cos_theta.max(1e-3)).exp())
            * (1.0 + c * (d * gamma).exp() + e * gamma.cos().powi(2))
    }
}

/// The sky model for one sun and turbidity.
#[derive(Debug, Clone)]
pub struct Sky {
    /// Unit vector towards the sun, +Y up.
    sun: DVec3,
    theta_s: f64,
    zenith: [f64; 3],
    perez: [Perez; 3],
}

impl Sky {
    /// The model with the sun towards `towards_sun` (any length; +Y up) and turbidity `t`.
    pub fn new(towards_sun: [f32; 3], t: f64) -> Result<Sky, SunSkyError> {
        let sun = DVec3::from(towards_sun.map(f64::from))
            .try_normalize()
            .ok_or(SunSkyError::Direction(towards_sun))?;
        if !TURBIDITY.contains(&t) {
            return Err(SunSkyError::Turbidity(t));
        }
        if sun.y <= 0.0 {
            return Err(SunSkyError::Night(sun.y.asin().to_degrees().abs()));
        }
        let theta_s = sun.y.clamp(-1.0, 1.0).acos();
        let chi = (4.0 / 9.0 - t / 120.0) * (std::f64::consts::PI - 2.0 * theta_s);
        let y_z = (4.0453 * t - 4.9710) * chi.tan() - 0.2155 * t + 2.4192;
        let poly = |m: [[f64; 4]; 3]| {
            let th = [theta_s.powi(3), theta_s.powi(2), theta_s, 1.0];
            let row = |r: [f64; 4]| r.iter().zip(th).map(|(a, b)| a * b).sum::<f64>();
            t * t * row(m[0]) + t * row(m[1]) + row(m[2])
        };
        let x_z = poly([
            [0.00166, -0.00375, 0.00209, 0.0],
            [-0.02903, 0.06377, -0.03202, 0.00394],
            [0.11693, -0.21196, 0.06052, 0.25886],
        ]);
        let y_cz = poly([
            [0.00275, -0.00610, 0.00317, 0.0],
            [-0.04214, 0.08970, -0.04153, 0.00516],
            [0.15346, -0.26756, 0.06670, 0.26688],
        ]);
        let perez = [
            Perez([
                0.1787 * t - 1.4630,
                -0.3554 * t + 0.4275,
                -0.0227 * t + 5.3251,
                0.1206 * t - 2.5771,
                -0.0670 * t + 0.3703,
            ]),
            Perez([
                -0.0193 * t - 0.2592,
                -0.0665 * t + 0.0008,
                -0.0004 * t + 0.2125,
                -0.0641 * t - 0.8989,
                -0.0033 * t + 0.0452,
            ]),
            Perez([
                -0.0167 * t - 0.2608,
                -0.0950 * t + 0.0092,
                -0.0079 * t + 0.2102,
                -0.0441 * t - 1.6537,
                -0.0109 * t + 0.0529,
            ]),
        ];
        Ok(Sky {
            sun,
            theta_s,
            zenith: [y_z, x_z, y_cz],
            perez,
        })
    }

    /// The sky's `Y` (kcd/m²), `x`, `y` towards unit `d`; `None` below the horizon.
    pub fn xy_y(&self, d: DVec3) -> Option<[f64; 3]> {
        if d.y <= 0.0 {
            return None;
        }
        let gamma = d.dot(self.sun).clamp(-1.0, 1.0).acos();
        Some(std::array::from_fn(|k| {
            self.zenith[k] * self.perez[k].f(d.y, gamma) / self.perez[k].f(1.0, self.theta_s)
        }))
    }

    /// Linear sRGB radiance towards unit `d` (kcd/m² in luminance), zero below the horizon.
    pub fn radiance(&self, d: DVec3) -> [f64; 3] {
        self.xy_y(d).map_or([0.0; 3], |[y, x, yc]| rgb_of(x, yc, y))
    }

    /// The sky's order-2 SH, its radiance summed over a `2n × n` grid of the sphere.
    pub fn sh(&self, n: u32) -> [[f32; 3]; SH_COEFFICIENTS] {
        let (w, h) = (2 * n, n);
        let mut pixels = Vec::with_capacity((w * h) as usize);
        for y in 0..h {
            let theta = std::f64::consts::PI * (f64::from(y) + 0.5) / f64::from(h);
            for x in 0..w {
                let phi = 2.0 * std::f64::consts::PI * ((f64::from(x) + 0.5) / f64::from(w) - 0.5);
                let d = DVec3::new(
                    theta.sin() * phi.cos(),
                    theta.cos(),
                    theta.sin() * phi.sin(),
                );
                pixels.push(self.radiance(d).map(|v| v as f32));
            }
        }
        // The grid is the environment map's, so the projection is the same code.
        crate::environment::project_equirect(w, h, &pixels)
            .expect("a finite, non-negative sky on a grid of the right size")
    }

    /// The sun's illuminance (klux) on a surface facing it, through the air mass of its
    /// elevation, and its colour (unit luminance).
    pub fn sun(&self) -> (f64, [f64; 3]) {
        let z = self.theta_s.to_degrees();
        let air_mass = 1.0 / (self.theta_s.cos() + 0.50572 * (96.07995 - z).powf(-1.6364));
        let klux = SUN_KLUX * 0.7f64.powf(air_mass.powf(0.678));
        let [_, x, y] = self.xy_y(self.sun).unwrap_or([1.0, 0.3127, 0.3290]);
        (klux, rgb_of(x, y, 1.0))
    }
}

/// CIE `xyY` to linear sRGB (Rec. 709, D65), negative components clipped.
fn rgb_of(x: f64, y: f64, lum: f64) -> [f64; 3] {
    if y <= 0.0 {
        return [0.0; 3];
    }
    let cx = x / y * lum;
    let cz = (1.0 - x - y) / y * lum;
    let cy = lum;
    [
        3.240_454_2 * cx - 1.537_138_5 * cy - 0.498_531_4 * cz,
        -0.969_266 * cx + 1.876_010_8 * cy + 0.041_556 * cz,
        0.055_643_4 * cx - 0.204_025_9 * cy + 1.057_225_2 * cz,
    ]
    .map(|v| v.max(0.0))
}

/// The light set of a sun towards `towards_sun` and its sky at turbidity `t`, both times
/// `scale` (module doc, "Units").
pub fn sun_and_sky(towards_sun: [f32; 3], t: f64, scale: f64) -> Result<LightSet, SunSkyError> {
    if !(scale.is_finite() && scale >= 0.0) {
        return Err(SunSkyError::Scale(scale));
    }
    let sky = Sky::new(towards_sun, t)?;
    let (klux, colour) = sky.sun();
    let sh = sky.sh(64).map(|c| c.map(|v| (f64::from(v) * scale) as f32));
    let direction = (-sky.sun).as_vec3().to_array();
    Ok(LightSet {
        lights: vec![
            Light::Directional {
                direction,
                color: colour.map(|c| c as f32),
                intensity: (klux * scale) as f32,
                name: Some("sun".into()),
            },
            Light::Sky {
                color: None,
                sh: Some(sh.to_vec()),
                name: Some("sky".into()),
            },
        ],
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use bounce_types::sh::sh_radiance;

    fn up(elevation_deg: f64) -> [f32; 3] {
        let e = elevation_deg.to_radians();
        [e.cos() as f32, e.sin() as f32, 0.0]
    }

    /// The paper's zenith luminance at T = 3 with the sun 30° from the zenith:
    /// `χ = (4/9 − 3/120)(π − π/3) = 0.8785`, `Y = 7.1649 tan χ − 0.6465 + 2.4192 = 10.41` kcd/m².
    #[test]
    fn the_zenith_is_the_papers() {
        let sky = Sky::new(up(60.0), 3.0).unwrap();
        let [y, x, yc] = sky.xy_y(DVec3::Y).unwrap();
        assert!((y - 10.41).abs() < 0.01, "{y}");
        // A clear sky's zenith is bluish-white: x and y a little under D65's.
        assert!(x > 0.2 && x < 0.3127 && yc > 0.2 && yc < 0.3290, "{x} {yc}");
    }

    /// Brighter towards the sun than away from it, bluer overhead than near the sun, nothing
    /// below the horizon; and its SH keeps the first two.
    #[test]
    fn brighter_near_the_sun_and_blue_overhead() {
        let sky = Sky::new(up(35.0), 3.0).unwrap();
        let towards = DVec3::new(0.8, 0.6, 0.0).normalize();
        let away = DVec3::new(-0.8, 0.6, 0.0).normalize();
        let (a, b) = (sky.radiance(towards), sky.radiance(away));
        assert!(a[1] > 1.5 * b[1], "{a:?} {b:?}");
        let zenith = sky.radiance(DVec3::Y);
        assert!(zenith[2] > zenith[0], "{zenith:?}");
        assert_eq!(sky.radiance(DVec3::NEG_Y), [0.0; 3]);
        let sh = sky.sh(64);
        let at = |d: DVec3| sh_radiance(&sh, d.to_array())[1];
        assert!(
            at(towards) > at(away) && at(DVec3::Y) > at(DVec3::NEG_Y),
            "{sh:?}"
        );
        // The horizontal floor's irradiance from it: some thousands of lux at midday.
        let floor = std::f64::consts::PI * f64::from(sh[0][1]) * 0.282_094_8
            + 2.0 * std::f64::consts::PI / 3.0 * f64::from(sh[1][1]) * 0.488_602_5;
        assert!((3.0..40.0).contains(&floor), "{floor} klux");
    }

    /// The sun dims and reddens as it sets.
    #[test]
    fn the_sun_dims_and_warms_as_it_sets() {
        let (high, white) = Sky::new(up(70.0), 3.0).unwrap().sun();
        let (low, warm) = Sky::new(up(5.0), 3.0).unwrap().sun();
        assert!((80.0..120.0).contains(&high), "{high}");
        assert!(low < 0.6 * high, "{low} {high}");
        assert!(
            warm[0] / warm[2] > white[0] / white[2],
            "{warm:?} {white:?}"
        );
    }

    #[test]
    fn a_light_set_or_a_reason() {
        let set = sun_and_sky(up(45.0), 3.0, 0.1).unwrap();
        set.validate().unwrap();
        let Light::Directional {
            direction,
            intensity,
            ..
        } = &set.lights[0]
        else {
            panic!("{set:?}")
        };
        assert!(direction[1] < 0.0 && *intensity > 5.0 && *intensity < 12.0);
        assert!(set.sky_sh().is_some());
        assert!(matches!(
            sun_and_sky(up(-5.0), 3.0, 1.0),
            Err(SunSkyError::Night(_))
        ));
        assert!(matches!(
            sun_and_sky(up(45.0), 20.0, 1.0),
            Err(SunSkyError::Turbidity(_))
        ));
        assert!(matches!(
            sun_and_sky([0.0, f32::NAN, 0.0], 3.0, 1.0),
            Err(SunSkyError::Direction(_))
        ));
        assert!(matches!(
            sun_and_sky(up(45.0), 3.0, -1.0),
            Err(SunSkyError::Scale(_))
        ));
    }
}
