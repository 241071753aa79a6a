//! Light messages of the proto into [`LightSet`] and back ([`to_proto`]), refused with the same field paths as the JSON
//! form (`lights[2].intensity: ...`), so a gRPC client reads the errors a CLI user would.
//!
//! The messages mirror the JSON objects field for field (vectors as three numbers, optional
//! numbers as proto3 `optional`), so the checks here are only those protobuf cannot express:
//! the type's name, vector lengths, required and unused fields. Values are checked by
//! [`LightSet::validate`], the one place that knows what a light engine accepts.

use bounce_types::light::{Light, LightError, LightSet, check_count};

use crate::proto;

/// Converts and validates a light configuration.
pub fn light_set(lights: &[proto::Light]) -> Result<LightSet, LightError> {
    check_count(lights.len())?;
    let lights = lights
        .iter()
        .enumerate()
        .map(|(i, l)| {
            light(l).map_err(|(field, reason)| LightError::Invalid {
                path: if field.is_empty() {
                    format!("lights[{i}]")
                } else {
                    format!("lights[{i}].{field}")
                },
                reason,
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    let set = LightSet { lights };
    set.validate()?;
    Ok(set)
}

/// A field name (empty for the light itself) and why it was refused.
type FieldError = (&'static str, String);

fn light(l: &proto::Light) -> Result<Light, FieldError> {
    let name = l.name.clone();
    if l.r#type == "sky" {
        return sky(l, name);
    }
    if l.r#type == "emissive" {
        return emissive(l, name);
    }
    if matches!(l.r#type.as_str(), "point" | "directional" | "spot") {
        unused(l.sh.is_empty(), "sh", &l.r#type)?;
        unused(l.material.is_none(), "material", &l.r#type)?;
        unused(l.node.is_none(), "node", &l.r#type)?;
        unused(l.strength.is_none(), "strength", &l.r#type)?;
    }
    let intensity = l.intensity.ok_or(("intensity", "missing".to_string()))?;
    let color = match l.color.as_slice() {
        [] => [1.0; 3],
        c => vec3("color", c)?,
    };
    match l.r#type.as_str() {
        "directional" => {
            unused(l.position.is_empty(), "position", "directional")?;
            unused(l.range.is_none(), "range", "directional")?;
            no_cones(l, "directional")?;
            Ok(Light::Directional {
                direction: vec3("direction", &l.direction)?,
                color,
                intensity,
                name,
            })
        }
        "point" => {
            unused(l.direction.is_empty(), "direction", "point")?;
            no_cones(l, "point")?;
            Ok(Light::Point {
                position: vec3("position", &l.position)?,
                color,
                intensity,
                range: l.range,
                name,
            })
        }
        "spot" => Ok(Light::Spot {
            position: vec3("position", &l.position)?,
            direction: vec3("direction", &l.direction)?,
            color,
            intensity,
            range: l.range,
            inner_cone_angle: l.inner_cone_angle.unwrap_or(0.0),
            outer_cone_angle: l.outer_cone_angle.unwrap_or(std::f32::consts::FRAC_PI_4),
            name,
        }),
        "" => Err(("type", "missing".to_string())),
        other => Err((
            "type",
            format!(
                "unknown light type {other:?} (expected point, directional, spot, sky or emissive)"
            ),
        )),
    }
}

/// A sky: a colour or 27 numbers of coefficients, nothing a punctual light has. Which of the two
/// it is (and that it is one of them) is [`LightSet::validate`]'s check, as for the JSON form.
fn sky(l: &proto::Light, name: Option<String>) -> Result<Light, FieldError> {
    unused(l.position.is_empty(), "position", "sky")?;
    unused(l.direction.is_empty(), "direction", "sky")?;
    unused(l.intensity.is_none(), "intensity", "sky")?;
    unused(l.range.is_none(), "range", "sky")?;
    no_cones(l, "sky")?;
    let color = match l.color.as_slice() {
        [] => None,
        c => Some(vec3("color", c)?),
    };
    let sh = match l.sh.as_slice() {
        [] => None,
        v if v.len() % 3 == 0 => Some(v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()),
        v => {
            return Err((
                "sh",
                format!(
                    "must be 27 numbers, 9 coefficients of red, green and blue (got {})",
                    v.len()
                ),
            ));
        }
    };
    unused(l.material.is_none(), "material", "sky")?;
    unused(l.node.is_none(), "node", "sky")?;
    unused(l.strength.is_none(), "strength", "sky")?;
    Ok(Light::Sky { color, sh, name })
}

/// A change to emissive surfaces: a material's name, a node's or both, and a colour, a
/// strength or both (which is [`LightSet::validate`]'s check).
fn emissive(l: &proto::Light, name: Option<String>) -> Result<Light, FieldError> {
    unused(l.position.is_empty(), "position", "emissive")?;
    unused(l.direction.is_empty(), "direction", "emissive")?;
    unused(l.intensity.is_none(), "intensity", "emissive")?;
    unused(l.range.is_none(), "range", "emissive")?;
    unused(l.sh.is_empty(), "sh", "emissive")?;
    no_cones(l, "emissive")?;
    let color = match l.color.as_slice() {
        [] => None,
        c => Some(vec3("color", c)?),
    };
    // That at least one name is given is `Light::validate`'s check, as it is for JSON.
    Ok(Light::Emissive {
        material: l.material.clone(),
        node: l.node.clone(),
        color,
        strength: l.strength,
        name,
    })
}

fn vec3(field: &'static str, v: &[f32]) -> Result<[f32; 3], FieldError> {
    match v {
        [x, y, z] => Ok([*x, *y, *z]),
        [] => Err((field, "missing".to_string())),
        _ => Err((field, format!("must have 3 components (got {})", v.len()))),
    }
}

/// Refuses a field the light's type has no use for, as the JSON form refuses unknown fields: a
/// client that sets it believes it does something.
fn unused(absent: bool, field: &'static str, kind: &str) -> Result<(), FieldError> {
    if absent {
        Ok(())
    } else {
        let article = if kind.starts_with(['a', 'e', 'i', 'o', 'u']) {
            "an"
        } else {
            "a"
        };
        Err((field, format!("not used by {article} {kind} light")))
    }
}

fn no_cones(l: &proto::Light, kind: &str) -> Result<(), FieldError> {
    unused(l.inner_cone_angle.is_none(), "inner_cone_angle", kind)?;
    unused(l.outer_cone_angle.is_none(), "outer_cone_angle", kind)
}

/// The proto form: the same fields, absent ones left out.
pub fn to_proto(set: &LightSet) -> Vec<proto::Light> {
    set.lights.iter().map(light_to_proto).collect()
}

fn light_to_proto(l: &Light) -> proto::Light {
    match l {
        Light::Directional {
            direction,
            color,
            intensity,
            name,
        } => proto::Light {
            r#type: "directional".into(),
            direction: direction.to_vec(),
            color: color.to_vec(),
            intensity: Some(*intensity),
            name: name.clone(),
            ..Default::default()
        },
        Light::Point {
            position,
            color,
            intensity,
            range,
            name,
        } => proto::Light {
            r#type: "point".into(),
            position: position.to_vec(),
            color: color.to_vec(),
            intensity: Some(*intensity),
            range: *range,
            name: name.clone(),
            ..Default::default()
        },
        Light::Spot {
            position,
            direction,
            color,
            intensity,
            range,
            inner_cone_angle,
            outer_cone_angle,
            name,
        } => proto::Light {
            r#type: "spot".into(),
            position: position.to_vec(),
            direction: direction.to_vec(),
            color: color.to_vec(),
            intensity: Some(*intensity),
            range: *range,
            inner_cone_angle: Some(*inner_cone_angle),
            outer_cone_angle: Some(*outer_cone_angle),
            name: name.clone(),
            ..Default::default()
        },
        Light::Sky { color, sh, name } => proto::Light {
            r#type: "sky".into(),
            color: color.map(|c| c.to_vec()).unwrap_or_default(),
            sh: sh.iter().flatten().flatten().copied().collect(),
            name: name.clone(),
            ..Default::default()
        },
        Light::Emissive {
            material,
            node,
            color,
            strength,
            name,
        } => proto::Light {
            r#type: "emissive".into(),
            material: material.clone(),
            node: node.clone(),
            color: color.map(|c| c.to_vec()).unwrap_or_default(),
            strength: *strength,
            name: name.clone(),
            ..Default::default()
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bounce_types::light::MAX_LIGHTS;

    fn point() -> proto::Light {
        proto::Light {
            r#type: "point".into(),
            position: vec![0.0, 1.5, 0.0],
            intensity: Some(10.0),
            ..Default::default()
        }
    }

    fn refused(l: proto::Light) -> String {
        match light_set(&[point(), l]) {
            Ok(set) => panic!("accepted {set:?}"),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn the_design_example_converts_like_its_json() {
        let lights = [
            point(),
            proto::Light {
                r#type: "directional".into(),
                direction: vec![0.3, -1.0, 0.2],
                color: vec![1.0, 0.95, 0.9],
                intensity: Some(3.0),
                ..Default::default()
            },
            proto::Light {
                r#type: "spot".into(),
                position: vec![0.0, 2.0, 0.0],
                direction: vec![0.0, -1.0, 0.0],
                color: vec![1.0, 1.0, 1.0],
                intensity: Some(50.0),
                inner_cone_angle: Some(0.3),
                outer_cone_angle: Some(0.6),
                ..Default::default()
            },
        ];
        let json = LightSet::from_json(
            r#"{"lights": [
            {"type": "point", "position": [0, 1.5, 0], "color": [1, 1, 1], "intensity": 10},
            {"type": "directional", "direction": [0.3, -1, 0.2], "color": [1, 0.95, 0.9], "intensity": 3},
            {"type": "spot", "position": [0, 2, 0], "direction": [0, -1, 0], "color": [1, 1, 1],
             "intensity": 50, "inner_cone_angle": 0.3, "outer_cone_angle": 0.6}]}"#,
        )
        .unwrap();
        assert_eq!(light_set(&lights).unwrap(), json);
    }

    fn sky(color: Vec<f32>, sh: Vec<f32>) -> proto::Light {
        proto::Light {
            r#type: "sky".into(),
            color,
            sh,
            ..Default::default()
        }
    }

    #[test]
    fn a_sky_converts_like_its_json_and_back() {
        let coeffs: Vec<f32> = (0..27).map(|k| 1.0 - k as f32 / 40.0).collect();
        let json = serde_json::json!({"lights": [
            {"type": "point", "position": [0, 1.5, 0], "intensity": 10},
            {"type": "sky", "sh": coeffs.chunks(3).collect::<Vec<_>>()}
        ]});
        let want = LightSet::from_json(&json.to_string()).unwrap();
        let got = light_set(&[point(), sky(vec![], coeffs)]).unwrap();
        assert_eq!(got, want);
        assert_eq!(light_set(&to_proto(&got)).unwrap(), got);
        let uniform = light_set(&[sky(vec![0.2, 0.4, 1.0], vec![])]).unwrap();
        assert_eq!(
            uniform,
            LightSet::from_json(r#"{"lights":[{"type":"sky","color":[0.2,0.4,1]}]}"#).unwrap()
        );
        assert_eq!(light_set(&to_proto(&uniform)).unwrap(), uniform);
    }

    #[test]
    fn bad_skies_are_refused_naming_the_field() {
        assert_eq!(
            refused(sky(vec![1.0; 3], vec![0.5; 26])),
            "lights[1].sh: must be 27 numbers, 9 coefficients of red, green and blue (got 26)"
        );
        assert!(
            refused(sky(vec![], vec![0.5; 24]))
                .starts_with("lights[1].sh: must hold exactly 9 coefficients")
        );
        assert!(refused(sky(vec![], vec![])).starts_with("lights[1].color: missing"));
        assert!(refused(sky(vec![1.0; 3], vec![0.5; 27])).contains("not both"));
        let mut l = sky(vec![1.0; 3], vec![]);
        l.intensity = Some(2.0);
        assert_eq!(refused(l), "lights[1].intensity: not used by a sky light");
        let mut l = sky(vec![1.0; 3], vec![]);
        l.position = vec![0.0; 3];
        assert_eq!(refused(l), "lights[1].position: not used by a sky light");
        assert!(
            light_set(&[sky(vec![1.0; 3], vec![]), sky(vec![0.5; 3], vec![])])
                .unwrap_err()
                .to_string()
                .contains("at most one sky")
        );
    }

    fn emissive(material: Option<&str>, color: Vec<f32>, strength: Option<f32>) -> proto::Light {
        proto::Light {
            r#type: "emissive".into(),
            material: material.map(str::to_owned),
            color,
            strength,
            ..Default::default()
        }
    }

    #[test]
    fn an_emissive_change_converts_like_its_json_and_back() {
        let json = r#"{"lights": [{"type": "point", "position": [0, 1.5, 0], "intensity": 10},
            {"type": "emissive", "material": "Lamp", "strength": 0},
            {"type": "emissive", "material": "Screen", "color": [1, 0.2, 0.2], "strength": 3}]}"#;
        let want = LightSet::from_json(json).unwrap();
        let got = light_set(&[
            point(),
            emissive(Some("Lamp"), vec![], Some(0.0)),
            emissive(Some("Screen"), vec![1.0, 0.2, 0.2], Some(3.0)),
        ])
        .unwrap();
        assert_eq!(got, want);
        assert_eq!(light_set(&to_proto(&got)).unwrap(), got);
        assert!(
            refused(emissive(None, vec![], Some(1.0)))
                .starts_with("lights[1].material: missing: an emissive change names")
        );
        // By node: as its JSON, and back.
        let mut by_node = emissive(None, vec![], Some(0.0));
        by_node.node = Some("Desk".into());
        let got = light_set(&[point(), by_node]).unwrap();
        let want = LightSet::from_json(
            r#"{"lights": [{"type": "point", "position": [0, 1.5, 0], "intensity": 10},
                {"type": "emissive", "node": "Desk", "strength": 0}]}"#,
        )
        .unwrap();
        assert_eq!(got, want);
        assert_eq!(light_set(&to_proto(&got)).unwrap(), got);
        let mut l = point();
        l.node = Some("Desk".into());
        assert_eq!(refused(l), "lights[1].node: not used by a point light");
        assert!(
            refused(emissive(Some("Lamp"), vec![], None))
                .starts_with("lights[1].color: missing: an emissive change needs")
        );
        let mut l = emissive(Some("Lamp"), vec![], Some(1.0));
        l.intensity = Some(2.0);
        assert_eq!(
            refused(l),
            "lights[1].intensity: not used by an emissive light"
        );
        let mut l = point();
        l.material = Some("Lamp".into());
        assert_eq!(refused(l), "lights[1].material: not used by a point light");
        let mut l = sky(vec![1.0; 3], vec![]);
        l.strength = Some(1.0);
        assert_eq!(refused(l), "lights[1].strength: not used by a sky light");
    }

    #[test]
    fn refusals_name_the_field() {
        let mut l = point();
        l.intensity = Some(f32::NAN);
        assert!(refused(l).starts_with("lights[1].intensity: must be finite"));
        let mut l = point();
        l.intensity = None;
        assert_eq!(refused(l), "lights[1].intensity: missing");
        let mut l = point();
        l.r#type = "area".into();
        assert!(refused(l).starts_with("lights[1].type: unknown light type \"area\""));
        let mut l = point();
        l.position = vec![1.0, 2.0];
        assert_eq!(
            refused(l),
            "lights[1].position: must have 3 components (got 2)"
        );
        let mut l = point();
        l.outer_cone_angle = Some(0.5);
        assert_eq!(
            refused(l),
            "lights[1].outer_cone_angle: not used by a point light"
        );
        let mut l = point();
        l.color = vec![1.0, -1.0, 0.0];
        assert!(refused(l).starts_with("lights[1].color:"));
        let mut l = point();
        l.sh = vec![0.0; 27];
        assert_eq!(refused(l), "lights[1].sh: not used by a point light");
        let e = light_set(&vec![point(); MAX_LIGHTS + 1]).unwrap_err();
        assert_eq!(e.path(), "lights");
        assert_eq!(
            light_set(&vec![point(); MAX_LIGHTS]).unwrap().lights.len(),
            MAX_LIGHTS
        );
    }
}
