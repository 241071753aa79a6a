//! Light edits from the keyboard: move, turn, dim or brighten the selected light.

use bounce_core::light::Light;
use glam::Vec3;

/// Moves a point or spot light by `delta`; tilts a directional light's direction by it (the
/// direction is renormalised, so a step of the scene's size turns it by about 45°).
pub fn nudge(light: &mut Light, delta: Vec3, scene_radius: f32) {
    match light {
        Light::Point { position, .. } | Light::Spot { position, .. } => {
            *position = (Vec3::from_array(*position) + delta).to_array();
        }
        Light::Directional { direction, .. } => {
            let d = Vec3::from_array(*direction).normalize_or(Vec3::NEG_Y);
            let turned = (d + delta / scene_radius.max(1e-6)).normalize_or(d);
            *direction = turned.to_array();
        }
        // Light from everywhere, or a material's surfaces: nothing to move.
        Light::Sky { .. } | Light::Emissive { .. } => {}
    }
}

/// Multiplies the intensity by `factor`.
pub fn scale(light: &mut Light, factor: f32) {
    match light {
        Light::Point { intensity, .. }
        | Light::Spot { intensity, .. }
        | Light::Directional { intensity, .. } => *intensity *= factor,
        Light::Sky { color, sh, .. } => {
            for c in color.iter_mut().chain(sh.iter_mut().flatten()) {
                *c = c.map(|v| v * factor);
            }
        }
        // A change names a strength, a colour or both (the light set's check): the strength
        // where it has one, else the colour.
        Light::Emissive {
            color, strength, ..
        } => match (strength, color) {
            (Some(s), _) => *s *= factor,
            (None, Some(c)) => *c = c.map(|v| v * factor),
            (None, None) => {}
        },
    }
}

/// One overlay line.
pub fn describe(light: &Light) -> String {
    let v = |a: &[f32; 3]| format!("({:.2}, {:.2}, {:.2})", a[0], a[1], a[2]);
    match light {
        Light::Point {
            position,
            intensity,
            ..
        } => format!("point at {} {intensity:.3} cd", v(position)),
        Light::Spot {
            position,
            intensity,
            ..
        } => format!("spot at {} {intensity:.3} cd", v(position)),
        Light::Directional {
            direction,
            intensity,
            ..
        } => format!("sun towards {} {intensity:.3} lx", v(direction)),
        Light::Sky {
            color: Some(color), ..
        } => format!("sky {}", v(color)),
        Light::Sky { .. } => "sky (SH environment)".to_string(),
        Light::Emissive {
            material,
            node,
            color,
            strength,
            ..
        } => {
            let mut out = match (material, node) {
                (Some(m), Some(n)) => format!("emissive '{m}' on node '{n}'"),
                (Some(m), None) => format!("emissive '{m}'"),
                (None, Some(n)) => format!("emissive node '{n}'"),
                (None, None) => "emissive".to_string(),
            };
            if let Some(c) = color {
                out += &format!(" colour {}", v(c));
            }
            if let Some(s) = strength {
                out += &format!(" strength {s:.3}");
            }
            out
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edits_keep_lights_valid() {
        let mut p = Light::Point {
            position: [0.0, 1.0, 0.0],
            color: [1.0; 3],
            intensity: 4.0,
            range: None,
            name: None,
        };
        nudge(&mut p, Vec3::X, 1.0);
        scale(&mut p, 0.5);
        assert!(matches!(
            p,
            Light::Point {
                position: [1.0, 1.0, 0.0],
                intensity: 2.0,
                ..
            }
        ));
        let mut sun = Light::Directional {
            direction: [0.0, -1.0, 0.0],
            color: [1.0; 3],
            intensity: 1.0,
            name: None,
        };
        nudge(&mut sun, Vec3::X * 0.1, 1.0);
        let Light::Directional { direction, .. } = sun else {
            unreachable!()
        };
        let d = Vec3::from_array(direction);
        assert!(
            (d.length() - 1.0).abs() < 1e-5 && d.x > 0.0 && d.y < 0.0,
            "{d}"
        );
        assert!(describe(&sun).starts_with("sun"));
    }
}
