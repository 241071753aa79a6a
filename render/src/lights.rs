//! Lights as the shader reads them, and the shadow views they need.

use bounce_core::direct::{LightKind, PreparedLight};
use bounce_core::light::LightSet;
use bounce_engine::gpu::GpuLight;
use glam::{Mat4, Vec3};

use crate::camera::up_for;
use crate::math::{look_at_rh, orthographic_rh, perspective_rh};

/// The lights as the shader reads them, and the shadow views they use (one per directional
/// and spot light, six per point light). Lights that cannot light anything are left out.
pub(crate) fn prepare_lights(
    lights: &LightSet,
    bounds: (Vec3, Vec3),
) -> (Vec<GpuLight>, Vec<Mat4>) {
    let (lo, hi) = bounds;
    let centre = (lo + hi) / 2.0;
    let radius = ((hi - lo).length() / 2.0).max(1e-3);
    let mut out = Vec::new();
    let mut views = Vec::new();
    for light in &lights.lights {
        let Some(l) = PreparedLight::new(light) else {
            continue;
        };
        let first_view = views.len() as u32;
        // Depth range of a light inside or near the scene: from close by to past its far side.
        let reach = (l.position - centre).length() + radius;
        let near = (reach / 1000.0).max(1e-4);
        match l.kind {
            LightKind::Directional => {
                let eye = centre - l.axis * radius * 2.0;
                let view = look_at_rh(eye, centre, up_for(l.axis));
                let proj = orthographic_rh(radius, 0.0, radius * 4.0);
                views.push(proj * view);
            }
            LightKind::Spot => {
                // The outer cone plus a margin, short of 180° where perspective breaks down.
                let outer = (l.angle_offset / -l.angle_scale.max(1e-6))
                    .clamp(-1.0, 1.0)
                    .acos();
                let fov = (2.0 * outer + 0.1).min(3.0);
                let view = look_at_rh(l.position, l.position + l.axis, up_for(l.axis));
                views.push(perspective_rh(fov, 1.0, near, reach) * view);
            }
            LightKind::Point => {
                let faces = [
                    (Vec3::X, Vec3::NEG_Y),
                    (Vec3::NEG_X, Vec3::NEG_Y),
                    (Vec3::Y, Vec3::Z),
                    (Vec3::NEG_Y, Vec3::NEG_Z),
                    (Vec3::Z, Vec3::NEG_Y),
                    (Vec3::NEG_Z, Vec3::NEG_Y),
                ];
                let proj = perspective_rh(std::f32::consts::FRAC_PI_2, 1.0, near, reach);
                for (dir, up) in faces {
                    views.push(proj * look_at_rh(l.position, l.position + dir, up));
                }
            }
        }
        out.push(GpuLight {
            first_view,
            ..GpuLight::from(&l)
        });
    }
    (out, views)
}
