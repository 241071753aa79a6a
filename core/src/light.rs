//! Punctual lights in the one JSON form shared by the CLI, the baked file and (later) the server.
//!
//! Names and units follow glTF `KHR_lights_punctual`: point and spot intensity in candela, directional
//! in lux, cone angles in radians. Unlike glTF, placement is explicit (`position`, `direction`) rather
//! than taken from a node, so a light configuration is self-contained.

use serde::{Deserialize, Serialize};

/// A set of lights, as read from or written to `{"lights": [...]}`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightSet {
    pub lights: Vec<Light>,
}

/// One punctual light.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
pub enum Light {
    Directional {
        /// Direction the light travels in (from the light towards the scene), world space.
        direction: [f32; 3],
        #[serde(default = "white")]
        color: [f32; 3],
        /// Illuminance in lux on a surface facing the light.
        intensity: f32,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
    },
    Point {
        position: [f32; 3],
        #[serde(default = "white")]
        color: [f32; 3],
        /// Luminous intensity in candela.
        intensity: f32,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        range: Option<f32>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
    },
    Spot {
        position: [f32; 3],
        direction: [f32; 3],
        #[serde(default = "white")]
        color: [f32; 3],
        /// Luminous intensity in candela along the axis.
        intensity: f32,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        range: Option<f32>,
        #[serde(default)]
        inner_cone_angle: f32,
        #[serde(default = "default_outer_cone")]
        outer_cone_angle: f32,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
    },
}

fn white() -> [f32; 3] {
    [1.0, 1.0, 1.0]
}

/// glTF's default outer cone angle, π/4.
fn default_outer_cone() -> f32 {
    std::f32::consts::FRAC_PI_4
}
