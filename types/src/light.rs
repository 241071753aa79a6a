//! Lights in the one JSON form shared by the CLI, the baked file and the server.
//!
//! Names and units of the punctual lights follow glTF `KHR_lights_punctual`: point and spot
//! intensity in candela, directional in lux, cone angles in radians. Unlike glTF, placement is
//! explicit (`position`, `direction`) rather than taken from a node, so a light configuration is
//! self-contained.
//!
//! A **sky** is the light arriving from outside the scene, from every direction a surface sees
//! no geometry in: `{"type": "sky", "color": [r, g, b]}` is a uniform radiance (an open, level
//! surface under it gets irradiance `π · color`), `{"type": "sky", "sh": [[r, g, b], ...]}` an
//! environment given by its 9 order-2 spherical-harmonic radiance coefficients
//! ([`crate::sh`], world axes). A set holds at most one sky.
//!
//! An **emissive** entry changes, for this light set only, the emission of the scene's emissive
//! surfaces made of one glTF material, or placed by one glTF node, named as the file names them:
//! `{"type": "emissive", "material": "Lamp", "color": [1, 0.2, 0.2], "strength": 40}`, or
//! `{"type": "emissive", "node": "DeskLamp", "strength": 0}` for one lamp of many that share a
//! material (both names: that material on that node). Its emission becomes `color × strength`
//! (glTF's `emissiveFactor` × `KHR_materials_emissive_strength`); either may be left out to keep
//! the file's value, so `{"strength": 0}` switches a lamp off and keeps its colour for later.
//! Whether the scene has such an emitter is the scene's business (a baked file lists its
//! emitters): this module checks the values alone. A set names a (material, node) pair at most
//! once; where two of its changes reach one surface (a material, and a node made of it), the
//! later change wins.
//!
//! This module owns the types, their JSON form and their validation ([`LightSet::from_json`],
//! [`LightSet::validate`]): whatever reaches a light engine has passed these checks. What a light
//! does to a surface is `bounce_core::direct`'s business.

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::sh::{SH_COEFFICIENTS, uniform_sh};

/// A set of lights, as read from or written to `{"lights": [...]}`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightSet {
    pub lights: Vec<Light>,
}

/// One light: punctual, the sky, or a change to an emissive material.
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
    /// Light from outside the scene: exactly one of `color` and `sh`.
    Sky {
        /// A uniform radiance, linear RGB.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        color: Option<[f32; 3]>,
        /// Radiance as order-2 real spherical harmonics: 9 RGB coefficients `L_lm` in the order
        /// of [`crate::sh`].
        #[serde(default, skip_serializing_if = "Option::is_none")]
        sh: Option<Vec<[f32; 3]>>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
    },
    /// The scene's surfaces of one emissive glTF material, at a new colour or strength (or
    /// both): their emission becomes `color × strength`, each defaulting to the file's.
    Emissive {
        /// The glTF material's name, as the baked file lists it among its emitters.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        material: Option<String>,
        /// The glTF node's name (`node #i` for an unnamed one), as the baked file lists it
        /// among its emitters' nodes.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        node: Option<String>,
        /// Linear RGB, as glTF's `emissiveFactor`.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        color: Option<[f32; 3]>,
        /// As `KHR_materials_emissive_strength`'s `emissiveStrength`.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        strength: Option<f32>,
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

/// The most lights one configuration may hold. Every light costs a visibility ray per sample per
/// patch, so a configuration far beyond this is a mistake or an attack, not a lighting setup.
pub const MAX_LIGHTS: usize = 256;

/// Bytes a light's `name` may hold: a name labels a light in a viewer's list, and every stored
/// session and every reply carries it, so a client cannot grow them without bound.
pub const MAX_NAME_BYTES: usize = 256;

/// Refuses a configuration of more than [`MAX_LIGHTS`] lights. Every reader (the JSON form, the
/// proto messages) calls it before converting a single light, so a huge list costs no more than
/// its parse.
pub fn check_count(count: usize) -> Result<(), LightError> {
    if count > MAX_LIGHTS {
        return Err(LightError::TooMany {
            count,
            max: MAX_LIGHTS,
        });
    }
    Ok(())
}

/// Why a light configuration was refused. Messages name the offending field by its JSON path
/// (`lights[2].intensity`), so a server can hand them to the client as they are.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum LightError {
    #[error("light configuration is not valid JSON: {0}")]
    Json(String),
    #[error("{path}: {reason}")]
    Invalid { path: String, reason: String },
    #[error("lights: {count} lights, more than the {max} a configuration may hold")]
    TooMany { count: usize, max: usize },
}

impl LightError {
    fn invalid(path: impl Into<String>, reason: impl Into<String>) -> LightError {
        LightError::Invalid {
            path: path.into(),
            reason: reason.into(),
        }
    }

    /// The JSON path of the offending field (`lights[2].intensity`), or `""` for a document that
    /// is not JSON at all.
    pub fn path(&self) -> &str {
        match self {
            LightError::Json(_) => "",
            LightError::Invalid { path, .. } => path,
            LightError::TooMany { .. } => "lights",
        }
    }
}

impl LightSet {
    /// Parses and validates `{"lights": [...]}`. Each light is deserialised on its own, so a
    /// missing field or an unknown type names the light it belongs to.
    pub fn from_json(json: &str) -> Result<LightSet, LightError> {
        let value: serde_json::Value =
            serde_json::from_str(json).map_err(|e| LightError::Json(e.to_string()))?;
        let serde_json::Value::Object(mut top) = value else {
            return Err(LightError::invalid(
                "(root)",
                "must be an object of the form {\"lights\": [...]}",
            ));
        };
        let lights = top
            .remove("lights")
            .ok_or_else(|| LightError::invalid("lights", "missing"))?;
        if let Some(unknown) = top.keys().next() {
            return Err(LightError::invalid(
                unknown.as_str(),
                "unknown field (expected only \"lights\")",
            ));
        }
        let serde_json::Value::Array(items) = lights else {
            return Err(LightError::invalid("lights", "must be an array"));
        };
        // Before deserialising any light, so a huge array costs no more work than its parse.
        check_count(items.len())?;
        let lights = items
            .into_iter()
            .enumerate()
            .map(|(i, item)| {
                serde_json::from_value::<Light>(item)
                    .map_err(|e| LightError::invalid(format!("lights[{i}]"), e.to_string()))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let set = LightSet { lights };
        set.validate()?;
        Ok(set)
    }

    /// Checks every value a light engine relies on: finite numbers, non-negative intensity and
    /// colour, usable directions, positive ranges, spot cones with `0 ≤ inner < outer ≤ π/2`,
    /// and at most one sky, given one way.
    pub fn validate(&self) -> Result<(), LightError> {
        if self.lights.len() > MAX_LIGHTS {
            return Err(LightError::TooMany {
                count: self.lights.len(),
                max: MAX_LIGHTS,
            });
        }
        let mut sky: Option<usize> = None;
        for (i, light) in self.lights.iter().enumerate() {
            light.validate().map_err(|(field, reason)| {
                LightError::invalid(format!("lights[{i}].{field}"), reason)
            })?;
            if let Light::Emissive { material, node, .. } = light
                && let Some(first) = self.lights[..i].iter().position(|l| {
                    matches!(l, Light::Emissive { material: m, node: n, .. } if m == material && n == node)
                })
            {
                let (field, what) = match (material, node) {
                    (Some(m), None) => ("material", format!("'{m}'")),
                    (None, Some(n)) => ("node", format!("node '{n}'")),
                    (Some(m), Some(n)) => ("node", format!("'{m}' on node '{n}'")),
                    (None, None) => ("material", "nothing".to_string()),
                };
                return Err(LightError::invalid(
                    format!("lights[{i}].{field}"),
                    format!("{what} is already changed by lights[{first}]"),
                ));
            }
            if matches!(light, Light::Sky { .. }) {
                if let Some(first) = sky {
                    return Err(LightError::invalid(
                        format!("lights[{i}]"),
                        format!("a light set holds at most one sky, and lights[{first}] is one"),
                    ));
                }
                sky = Some(i);
            }
        }
        Ok(())
    }

    /// The set's changes to emissive surfaces, in order.
    pub fn emissive(&self) -> impl Iterator<Item = EmissiveChange<'_>> {
        self.lights.iter().filter_map(EmissiveChange::of)
    }

    /// The set's changes to emissive surfaces with their index among its lights (the `i` of
    /// `lights[i]` in an error), in order.
    pub fn emissive_indexed(&self) -> impl Iterator<Item = (usize, EmissiveChange<'_>)> {
        self.lights
            .iter()
            .enumerate()
            .filter_map(|(i, l)| Some((i, EmissiveChange::of(l)?)))
    }

    /// The set's sky as radiance coefficients ([`Light::sky_sh`]), if it has one.
    pub fn sky_sh(&self) -> Option<[[f32; 3]; SH_COEFFICIENTS]> {
        self.lights.iter().find_map(Light::sky_sh)
    }
}

/// One emissive change of a light set: which emitters it names (a material, a node, or that
/// material on that node) and its new colour and strength, each `None` where the file's value
/// stays.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EmissiveChange<'a> {
    pub material: Option<&'a str>,
    pub node: Option<&'a str>,
    pub color: Option<[f32; 3]>,
    pub strength: Option<f32>,
}

impl<'a> EmissiveChange<'a> {
    /// `light`'s change, if it is an emissive one.
    pub fn of(light: &'a Light) -> Option<EmissiveChange<'a>> {
        match light {
            Light::Emissive {
                material,
                node,
                color,
                strength,
                ..
            } => Some(EmissiveChange {
                material: material.as_deref(),
                node: node.as_deref(),
                color: *color,
                strength: *strength,
            }),
            _ => None,
        }
    }

    /// Whether the change reaches an emitter of material `material` placed by node `node`
    /// (`None`: a file that does not know its emitters' nodes, which no change by node reaches).
    pub fn reaches(&self, material: &str, node: Option<&str>) -> bool {
        self.material.is_none_or(|m| m == material) && self.node.is_none_or(|n| node == Some(n))
    }

    /// What the change names, for messages: `material 'Lamp'`, `node 'Desk'`, or both.
    pub fn describe(&self) -> String {
        match (self.material, self.node) {
            (Some(m), None) => format!("emissive material '{m}'"),
            (None, Some(n)) => format!("emissive node '{n}'"),
            (Some(m), Some(n)) => format!("emissive material '{m}' on node '{n}'"),
            (None, None) => "no emitter".to_string(),
        }
    }

    /// The field an error about what it names points at: `node` when it names one.
    pub fn field(&self) -> &'static str {
        if self.node.is_some() {
            "node"
        } else {
            "material"
        }
    }
}

/// A field name and why its value was refused.
pub type FieldError = (&'static str, String);

impl Light {
    /// A sky's radiance as its 9 spherical-harmonic coefficients (a uniform colour is its `L00`
    /// alone); `None` for a punctual light, or a sky that [`Light::validate`] refuses.
    pub fn sky_sh(&self) -> Option<[[f32; 3]; SH_COEFFICIENTS]> {
        let Light::Sky { color, sh, .. } = self else {
            return None;
        };
        match (color, sh) {
            (Some(c), None) => Some(uniform_sh(*c)),
            (None, Some(sh)) => sh.as_slice().try_into().ok(),
            _ => None,
        }
    }

    /// As [`LightSet::validate`] for one light; the error names the field.
    pub fn validate(&self) -> Result<(), FieldError> {
        let name = match self {
            Light::Directional { name, .. }
            | Light::Point { name, .. }
            | Light::Spot { name, .. }
            | Light::Sky { name, .. }
            | Light::Emissive { name, .. } => name,
        };
        if let Some(name) = name
            && name.len() > MAX_NAME_BYTES
        {
            return Err((
                "name",
                format!(
                    "{} bytes, more than the {MAX_NAME_BYTES} a name may hold",
                    name.len()
                ),
            ));
        }
        match self {
            Light::Directional {
                direction,
                color,
                intensity,
                ..
            } => {
                check_direction("direction", direction)?;
                check_color(color)?;
                check_intensity(*intensity)
            }
            Light::Point {
                position,
                color,
                intensity,
                range,
                ..
            } => {
                check_finite3("position", position)?;
                check_color(color)?;
                check_intensity(*intensity)?;
                check_range(*range)
            }
            Light::Spot {
                position,
                direction,
                color,
                intensity,
                range,
                inner_cone_angle,
                outer_cone_angle,
                ..
            } => {
                check_finite3("position", position)?;
                check_direction("direction", direction)?;
                check_color(color)?;
                check_intensity(*intensity)?;
                check_range(*range)?;
                check_cones(*inner_cone_angle, *outer_cone_angle)
            }
            Light::Sky { color, sh, .. } => check_sky(color.as_ref(), sh.as_deref()),
            Light::Emissive {
                material,
                node,
                color,
                strength,
                ..
            } => check_emissive(
                material.as_deref(),
                node.as_deref(),
                color.as_ref(),
                *strength,
            ),
        }
    }
}

/// A sky is given one way: a uniform colour, or exactly 9 finite coefficients whose mean
/// radiance (`L00`) is not negative. The higher coefficients may be negative: that is how an
/// environment brighter above than below is written.
fn check_sky(color: Option<&[f32; 3]>, sh: Option<&[[f32; 3]]>) -> Result<(), FieldError> {
    match (color, sh) {
        (Some(c), None) => check_color(c),
        (None, Some(sh)) => {
            if sh.len() != SH_COEFFICIENTS {
                return Err((
                    "sh",
                    format!(
                        "must hold exactly {SH_COEFFICIENTS} coefficients (order-2 spherical \
                         harmonics), got {}",
                        sh.len()
                    ),
                ));
            }
            if let Some(k) = sh.iter().position(|c| !c.iter().all(|v| v.is_finite())) {
                return Err((
                    "sh",
                    format!("coefficient {k} is not finite (got {:?})", sh[k]),
                ));
            }
            if sh[0].iter().any(|&v| v < 0.0) {
                return Err((
                    "sh",
                    format!(
                        "coefficient 0 (the mean radiance) must not be negative (got {:?})",
                        sh[0]
                    ),
                ));
            }
            Ok(())
        }
        (Some(_), Some(_)) => Err((
            "sh",
            "a sky is either a uniform color or sh coefficients, not both".to_string(),
        )),
        (None, None) => Err((
            "color",
            "missing: a sky needs a uniform color [r, g, b] or 9 sh coefficients".to_string(),
        )),
    }
}

/// An emissive change names a material and changes something about it.
fn check_emissive(
    material: Option<&str>,
    node: Option<&str>,
    color: Option<&[f32; 3]>,
    strength: Option<f32>,
) -> Result<(), FieldError> {
    if material.is_none() && node.is_none() {
        return Err((
            "material",
            "missing: an emissive change names the material or the node (or both) to change".into(),
        ));
    }
    for (field, name, what) in [
        ("material", material, "the emissive material"),
        ("node", node, "the node"),
    ] {
        match name {
            Some("") => return Err((field, format!("must name {what} to change"))),
            Some(n) if n.len() > MAX_NAME_BYTES => {
                return Err((
                    field,
                    format!(
                        "{} bytes, more than the {MAX_NAME_BYTES} a name may hold",
                        n.len()
                    ),
                ));
            }
            _ => {}
        }
    }
    if color.is_none() && strength.is_none() {
        return Err((
            "color",
            "missing: an emissive change needs a color [r, g, b], a strength, or both".into(),
        ));
    }
    if let Some(c) = color {
        check_color(c)?;
    }
    match strength {
        Some(s) if !(s.is_finite() && s >= 0.0) => Err((
            "strength",
            format!("must be finite and non-negative (got {s})"),
        )),
        _ => Ok(()),
    }
}

fn check_finite3(field: &'static str, v: &[f32; 3]) -> Result<(), FieldError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err((field, format!("must be finite (got {v:?})")))
    }
}

fn check_direction(field: &'static str, v: &[f32; 3]) -> Result<(), FieldError> {
    check_finite3(field, v)?;
    if unit_vector(*v).is_none() {
        return Err((field, format!("must not be zero (got {v:?})")));
    }
    Ok(())
}

fn check_color(c: &[f32; 3]) -> Result<(), FieldError> {
    if c.iter().all(|x| x.is_finite() && *x >= 0.0) {
        Ok(())
    } else {
        Err((
            "color",
            format!("components must be finite and non-negative (got {c:?})"),
        ))
    }
}

fn check_intensity(intensity: f32) -> Result<(), FieldError> {
    if intensity.is_finite() && intensity >= 0.0 {
        Ok(())
    } else {
        Err((
            "intensity",
            format!("must be finite and non-negative (got {intensity})"),
        ))
    }
}

fn check_range(range: Option<f32>) -> Result<(), FieldError> {
    match range {
        Some(r) if !(r.is_finite() && r > 0.0) => Err((
            "range",
            format!("must be finite and positive, or absent for no limit (got {r})"),
        )),
        _ => Ok(()),
    }
}

fn check_cones(inner: f32, outer: f32) -> Result<(), FieldError> {
    let half_pi = std::f32::consts::FRAC_PI_2;
    if !(inner.is_finite() && (0.0..half_pi).contains(&inner)) {
        return Err((
            "inner_cone_angle",
            format!("must be finite, at least 0 and below π/2 (got {inner})"),
        ));
    }
    if !(outer.is_finite() && outer > 0.0 && outer <= half_pi) {
        return Err((
            "outer_cone_angle",
            format!("must be finite, above 0 and at most π/2 (got {outer})"),
        ));
    }
    if inner >= outer {
        return Err((
            "inner_cone_angle",
            format!("must be less than outer_cone_angle (got {inner} ≥ {outer})"),
        ));
    }
    Ok(())
}

/// `v` scaled to unit length, or `None` when it is zero or not finite. Scales by the largest
/// component first, so directions like `[1e30, 1e30, 0]` do not overflow on the way.
pub fn unit_vector(v: [f32; 3]) -> Option<glam::Vec3> {
    let v = glam::Vec3::from(v);
    let m = v.abs().max_element();
    if !(m.is_finite() && m > 0.0) {
        return None;
    }
    let u = (v / m).normalize();
    u.is_finite().then_some(u)
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"{"lights": [
        {"type": "point", "position": [0, 1.5, 0], "color": [1, 1, 1], "intensity": 10},
        {"type": "directional", "direction": [0.3, -1, 0.2], "color": [1, 0.95, 0.9], "intensity": 3},
        {"type": "spot", "position": [0, 2, 0], "direction": [0, -1, 0], "color": [1, 1, 1],
         "intensity": 50, "inner_cone_angle": 0.3, "outer_cone_angle": 0.6}
    ]}"#;

    /// The message for `GOOD` with light `index` replaced by `light`.
    fn refuse_light(index: usize, light: &str) -> String {
        let mut v: serde_json::Value = serde_json::from_str(GOOD).unwrap();
        v["lights"][index] = serde_json::from_str(light).unwrap();
        match LightSet::from_json(&v.to_string()) {
            Ok(set) => panic!("accepted {set:?}"),
            Err(e) => e.to_string(),
        }
    }

    #[track_caller]
    fn assert_refused(index: usize, light: &str, want: &str) {
        let got = refuse_light(index, light);
        assert!(got.contains(want), "{got:?} does not contain {want:?}");
    }

    #[test]
    fn the_design_example_parses() {
        let set = LightSet::from_json(GOOD).unwrap();
        assert_eq!(set.lights.len(), 3);
        assert!(matches!(
            set.lights[2],
            Light::Spot {
                range: None,
                inner_cone_angle: 0.3,
                ..
            }
        ));
        // And what it writes, it reads.
        let again = LightSet::from_json(&serde_json::to_string(&set).unwrap()).unwrap();
        assert_eq!(again, set);
    }

    #[test]
    fn defaults_follow_gltf() {
        let set = LightSet::from_json(
            r#"{"lights":[{"type":"spot","position":[0,0,0],"direction":[0,0,-1],"intensity":1}]}"#,
        )
        .unwrap();
        let Light::Spot {
            color,
            inner_cone_angle,
            outer_cone_angle,
            ..
        } = set.lights[0]
        else {
            panic!("not a spot");
        };
        assert_eq!(color, [1.0; 3]);
        assert_eq!(inner_cone_angle, 0.0);
        assert_eq!(outer_cone_angle, std::f32::consts::FRAC_PI_4);
        assert_eq!(
            LightSet::from_json(r#"{"lights":[]}"#)
                .unwrap()
                .lights
                .len(),
            0
        );
    }

    #[test]
    fn negative_or_non_finite_intensity() {
        assert_refused(
            2,
            r#"{"type":"spot","position":[0,2,0],"direction":[0,-1,0],"intensity":-1}"#,
            "lights[2].intensity: must be finite and non-negative (got -1)",
        );
        // JSON has no NaN or Inf, but a number beyond f32 becomes Inf.
        assert_refused(
            0,
            r#"{"type":"point","position":[0,0,0],"intensity":1e39}"#,
            "lights[0].intensity: must be finite and non-negative (got inf)",
        );
    }

    #[test]
    fn negative_or_non_finite_colour() {
        assert_refused(
            1,
            r#"{"type":"directional","direction":[0,-1,0],"color":[1,-0.5,0],"intensity":1}"#,
            "lights[1].color: components must be finite and non-negative",
        );
        assert_refused(
            0,
            r#"{"type":"point","position":[0,0,0],"color":[1,1,1e300],"intensity":1}"#,
            "lights[0].color",
        );
    }

    #[test]
    fn non_finite_position() {
        assert_refused(
            0,
            r#"{"type":"point","position":[0,-1e40,0],"intensity":1}"#,
            "lights[0].position: must be finite",
        );
    }

    #[test]
    fn zero_or_non_finite_direction() {
        assert_refused(
            1,
            r#"{"type":"directional","direction":[0,0,0],"intensity":1}"#,
            "lights[1].direction: must not be zero",
        );
        assert_refused(
            2,
            r#"{"type":"spot","position":[0,0,0],"direction":[0,1e39,0],"intensity":1}"#,
            "lights[2].direction: must be finite",
        );
        // Huge but finite is a direction like any other.
        let set = LightSet {
            lights: vec![Light::Directional {
                direction: [3e38, -3e38, 0.0],
                color: [1.0; 3],
                intensity: 1.0,
                name: None,
            }],
        };
        assert_eq!(set.validate(), Ok(()));
    }

    #[test]
    fn non_positive_range() {
        for range in ["0", "-2", "1e39"] {
            assert_refused(
                0,
                &format!(r#"{{"type":"point","position":[0,0,0],"intensity":1,"range":{range}}}"#),
                "lights[0].range: must be finite and positive",
            );
        }
    }

    #[test]
    fn spot_cones_out_of_order_or_range() {
        let spot = |inner: f32, outer: f32| {
            format!(
                r#"{{"type":"spot","position":[0,0,0],"direction":[0,-1,0],"intensity":1,
                    "inner_cone_angle":{inner},"outer_cone_angle":{outer}}}"#
            )
        };
        assert_refused(2, &spot(-0.1, 0.5), "lights[2].inner_cone_angle");
        assert_refused(
            2,
            &spot(0.6, 0.5),
            "lights[2].inner_cone_angle: must be less than",
        );
        assert_refused(
            2,
            &spot(0.5, 0.5),
            "lights[2].inner_cone_angle: must be less than",
        );
        assert_refused(2, &spot(0.1, 1.6), "lights[2].outer_cone_angle");
        assert_refused(2, &spot(0.0, 0.0), "lights[2].outer_cone_angle");
        // The extremes of the valid range.
        let set = LightSet {
            lights: vec![Light::Spot {
                position: [0.0; 3],
                direction: [0.0, -1.0, 0.0],
                color: [1.0; 3],
                intensity: 1.0,
                range: None,
                inner_cone_angle: 0.0,
                outer_cone_angle: std::f32::consts::FRAC_PI_2,
                name: None,
            }],
        };
        assert_eq!(set.validate(), Ok(()));
    }

    #[test]
    fn unknown_type_and_fields_name_the_light() {
        assert_refused(
            1,
            r#"{"type":"area","position":[0,0,0],"intensity":1}"#,
            "lights[1]: unknown variant `area`, expected one of `directional`, `point`, `spot`, `sky`",
        );
        assert_refused(
            0,
            r#"{"type":"point","position":[0,0,0],"intensity":1,"radius":2}"#,
            "lights[0]: unknown field `radius`",
        );
        assert_refused(
            0,
            r#"{"type":"point","position":[0,0,0]}"#,
            "lights[0]: missing field `intensity`",
        );
        assert_refused(
            0,
            r#"{"position":[0,0,0],"intensity":1}"#,
            "lights[0]: missing field `type`",
        );
        assert_refused(
            0,
            r#"{"type":"point","position":[0,0],"intensity":1}"#,
            "lights[0]: invalid length 2",
        );
    }

    #[test]
    fn document_shape() {
        let err = |json: &str| LightSet::from_json(json).unwrap_err();
        assert!(matches!(err("{"), LightError::Json(_)));
        assert_eq!(err("[]").path(), "(root)");
        assert_eq!(err("{}").to_string(), "lights: missing");
        assert_eq!(
            err(r#"{"lights": {}}"#).to_string(),
            "lights: must be an array"
        );
        let e = err(r#"{"lights": [], "ambient": 1}"#);
        assert_eq!(e.path(), "ambient");
        assert!(e.to_string().contains("unknown field"), "{e}");
    }

    /// A light's name is bounded: every stored session and every reply carries it.
    #[test]
    fn long_names_are_refused() {
        let named = |len: usize| {
            format!(
                r#"{{"lights": [{{"type":"point","position":[0,0,0],"intensity":1,"name":"{}"}}]}}"#,
                "é".repeat(len / 2)
            )
        };
        assert!(LightSet::from_json(&named(MAX_NAME_BYTES)).is_ok());
        let e = LightSet::from_json(&named(MAX_NAME_BYTES + 2)).unwrap_err();
        assert_eq!(e.path(), "lights[0].name", "{e}");
        assert!(
            e.to_string().contains("258 bytes, more than the 256"),
            "{e}"
        );
    }

    #[test]
    fn a_sky_reads_as_a_colour_or_as_coefficients() {
        let set = LightSet::from_json(
            r#"{"lights": [{"type": "sky", "color": [0.5, 0.6, 1.0]},
                           {"type": "point", "position": [0, 1, 0], "intensity": 1}]}"#,
        )
        .unwrap();
        let sh = set.sky_sh().unwrap();
        assert_eq!(sh[0], crate::sh::uniform_sh([0.5, 0.6, 1.0])[0]);
        assert!(sh[1..].iter().all(|c| *c == [0.0; 3]));
        let coeffs: Vec<[f32; 3]> = (0..9)
            .map(|k| [1.0, 0.5 * k as f32, 0.2 - 0.1 * k as f32])
            .collect();
        let json = serde_json::json!({"lights": [{"type": "sky", "sh": coeffs, "name": "day"}]});
        let set = LightSet::from_json(&json.to_string()).unwrap();
        assert_eq!(set.sky_sh().unwrap().to_vec(), coeffs);
        // What it writes, it reads; a set without a sky has none.
        let again = LightSet::from_json(&serde_json::to_string(&set).unwrap()).unwrap();
        assert_eq!(again, set);
        assert_eq!(LightSet::from_json(GOOD).unwrap().sky_sh(), None);
    }

    #[test]
    fn bad_skies_are_refused_with_the_reason() {
        let sh = |n: usize| {
            serde_json::json!({"type": "sky", "sh": vec![[0.1f32, 0.1, 0.1]; n]}).to_string()
        };
        assert_refused(
            1,
            &sh(8),
            "lights[1].sh: must hold exactly 9 coefficients (order-2 spherical harmonics), got 8",
        );
        assert_refused(1, &sh(10), "lights[1].sh: must hold exactly 9 coefficients");
        assert_refused(
            0,
            r#"{"type":"sky","color":[1,-1,1]}"#,
            "lights[0].color: components must be finite and non-negative",
        );
        assert_refused(
            0,
            r#"{"type":"sky","color":[1,1,1e39]}"#,
            "lights[0].color: components must be finite",
        );
        assert_refused(
            0,
            r#"{"type":"sky"}"#,
            "lights[0].color: missing: a sky needs a uniform color",
        );
        assert_refused(
            0,
            &serde_json::json!({"type": "sky", "color": [1, 1, 1], "sh": vec![[0.0; 3]; 9]})
                .to_string(),
            "lights[0].sh: a sky is either a uniform color or sh coefficients, not both",
        );
        let mut coeffs = vec![[0.5f32; 3]; 9];
        coeffs[0] = [1.0, -0.5, 1.0];
        assert_refused(
            2,
            &serde_json::json!({"type": "sky", "sh": coeffs}).to_string(),
            "lights[2].sh: coefficient 0 (the mean radiance) must not be negative",
        );
        assert_refused(
            2,
            r#"{"type":"sky","sh":[[1,1,1],[1,1,1e40],[0,0,0],[0,0,0],[0,0,0],[0,0,0],[0,0,0],[0,0,0],[0,0,0]]}"#,
            "lights[2].sh: coefficient 1 is not finite",
        );
        assert_refused(
            0,
            r#"{"type":"sky","sh":[[1,1]]}"#,
            "lights[0]: invalid length 2",
        );
        assert_refused(
            0,
            r#"{"type":"sky","color":[1,1,1],"intensity":2}"#,
            "lights[0]: unknown field `intensity`",
        );
        // One sky a set.
        let e = LightSet::from_json(
            r#"{"lights": [{"type":"sky","color":[1,1,1]},
                           {"type":"point","position":[0,0,0],"intensity":1},
                           {"type":"sky","color":[0,0,1]}]}"#,
        )
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "lights[2]: a light set holds at most one sky, and lights[0] is one"
        );
    }

    #[test]
    fn emissive_changes_read_and_bad_ones_are_refused() {
        let set = LightSet::from_json(
            r#"{"lights": [{"type":"emissive","material":"Lamp","strength":0},
                           {"type":"emissive","material":"Screen","color":[1,0.2,0.2]}]}"#,
        )
        .unwrap();
        let changes: Vec<_> = set
            .emissive()
            .map(|c| (c.material, c.node, c.color, c.strength))
            .collect();
        assert_eq!(
            changes,
            vec![
                (Some("Lamp"), None, None, Some(0.0)),
                (Some("Screen"), None, Some([1.0, 0.2, 0.2]), None)
            ]
        );
        assert_refused(
            1,
            r#"{"type":"emissive","material":"Lamp"}"#,
            "lights[1].color: missing: an emissive change needs a color [r, g, b], a strength, or both",
        );
        assert_refused(
            1,
            r#"{"type":"emissive","material":"","strength":1}"#,
            "lights[1].material: must name the emissive material",
        );
        assert_refused(
            0,
            r#"{"type":"emissive","material":"Lamp","strength":-1}"#,
            "lights[0].strength: must be finite and non-negative (got -1)",
        );
        assert_refused(
            0,
            r#"{"type":"emissive","material":"Lamp","color":[1,-1,0]}"#,
            "lights[0].color: components must be finite and non-negative",
        );
        assert_refused(
            0,
            r#"{"type":"emissive","strength":1}"#,
            "lights[0].material: missing: an emissive change names the material or the node",
        );
        assert_refused(
            0,
            r#"{"type":"emissive","node":"","strength":1}"#,
            "lights[0].node: must name the node",
        );
        assert_refused(
            0,
            r#"{"type":"emissive","material":"Lamp","strength":1,"intensity":1}"#,
            "lights[0]: unknown field `intensity`",
        );
        let long = "m".repeat(MAX_NAME_BYTES + 1);
        assert_refused(
            2,
            &serde_json::json!({"type": "emissive", "material": long, "strength": 1}).to_string(),
            "lights[2].material: 257 bytes",
        );
        let e = LightSet::from_json(
            r#"{"lights": [{"type":"emissive","material":"Lamp","strength":1},
                           {"type":"emissive","material":"Lamp","color":[1,0,0]}]}"#,
        )
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "lights[1].material: 'Lamp' is already changed by lights[0]"
        );
        let e = LightSet::from_json(
            r#"{"lights": [{"type":"emissive","node":"Desk","strength":1},
                           {"type":"emissive","node":"Desk","color":[1,0,0]}]}"#,
        )
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "lights[1].node: node 'Desk' is already changed by lights[0]"
        );
    }

    #[test]
    fn emissive_changes_by_node_reach_what_they_name() {
        // A material, a node, and that material on that node: each a change of its own.
        let set = LightSet::from_json(
            r#"{"lights": [{"type":"emissive","material":"Shade","strength":2},
                           {"type":"emissive","node":"Desk","strength":0},
                           {"type":"emissive","material":"Shade","node":"Hall","color":[1,0,0]}]}"#,
        )
        .unwrap();
        let c: Vec<EmissiveChange<'_>> = set.emissive().collect();
        assert!(c[0].reaches("Shade", Some("Desk")) && c[0].reaches("Shade", None));
        assert!(!c[0].reaches("Bulb", Some("Desk")));
        assert!(c[1].reaches("Bulb", Some("Desk")) && c[1].reaches("Shade", Some("Desk")));
        assert!(!c[1].reaches("Shade", Some("Hall")));
        // A file that does not know its emitters' nodes: no change by node reaches them.
        assert!(!c[1].reaches("Shade", None));
        assert!(c[2].reaches("Shade", Some("Hall")) && !c[2].reaches("Bulb", Some("Hall")));
        assert_eq!(c[2].describe(), "emissive material 'Shade' on node 'Hall'");
        assert_eq!((c[0].field(), c[1].field()), ("material", "node"));
        // Written back as read: no `node` where none was given.
        let json = serde_json::to_string(&set.lights[0]).unwrap();
        assert!(!json.contains("node"), "{json}");
    }

    #[test]
    fn too_many_lights() {
        let one = r#"{"type":"point","position":[0,0,0],"intensity":1}"#;
        let json = |n: usize| format!(r#"{{"lights": [{}]}}"#, vec![one; n].join(","));
        assert_eq!(
            LightSet::from_json(&json(MAX_LIGHTS)).unwrap().lights.len(),
            MAX_LIGHTS
        );
        let e = LightSet::from_json(&json(MAX_LIGHTS + 1)).unwrap_err();
        assert_eq!(
            e,
            LightError::TooMany {
                count: MAX_LIGHTS + 1,
                max: MAX_LIGHTS
            }
        );
        assert!(
            e.to_string().contains("257 lights, more than the 256"),
            "{e}"
        );
        let set = LightSet {
            lights: vec![LightSet::from_json(&json(1)).unwrap().lights[0].clone(); 300],
        };
        assert!(matches!(set.validate(), Err(LightError::TooMany { .. })));
    }
}
