//! The pinhole camera every image is drawn from, and its framing defaults.

use glam::{Mat4, Vec3};

use crate::error::RenderError;
use crate::math::{look_at_rh, perspective_rh};

/// A pinhole camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub eye: Vec3,
    pub target: Vec3,
    /// Vertical field of view, radians.
    pub fov_y: f32,
}

impl Camera {
    /// Looking at the whole of `bounds` from +Z, with a 45° vertical field of view.
    pub fn framing(bounds: (Vec3, Vec3)) -> Camera {
        let (lo, hi) = bounds;
        let centre = (lo + hi) / 2.0;
        let fov_y = 45f32.to_radians();
        let half = (hi - lo) / 2.0;
        // Far enough that the front face's larger half-extent fits the field of view.
        let reach = (half.x.max(half.y) / (fov_y / 2.0).tan()).max(1e-3);
        Camera {
            eye: centre + Vec3::Z * (half.z + reach * 1.1),
            target: centre,
            fov_y,
        }
    }

    /// World to clip space for an image of this aspect ratio, with depth planes that hold
    /// `bounds` wherever the eye is (inside a level as much as outside it).
    pub fn view_proj(&self, aspect: f32, bounds: (Vec3, Vec3)) -> Result<Mat4, RenderError> {
        let view = self.view()?;
        let (lo, hi) = bounds;
        let radius = ((hi - lo).length() / 2.0).max(1e-3);
        let distance = (self.eye - (lo + hi) / 2.0).length();
        let far = distance + radius * 2.0;
        let near = (far / 2000.0).max(1e-4);
        Ok(perspective_rh(self.fov_y, aspect, near, far) * view)
    }

    fn view(&self) -> Result<Mat4, RenderError> {
        let dir = self.target - self.eye;
        if !(dir.length() > 0.0 && dir.is_finite()) {
            return Err(RenderError::Camera(
                "the eye and the target must be distinct finite points".into(),
            ));
        }
        if !(self.fov_y > 0.0 && self.fov_y < std::f32::consts::PI) {
            return Err(RenderError::Camera(format!(
                "field of view {}° is not within (0°, 180°)",
                self.fov_y.to_degrees()
            )));
        }
        Ok(look_at_rh(self.eye, self.target, up_for(dir)))
    }
}

/// Y up, unless the view runs along Y.
pub(crate) fn up_for(dir: Vec3) -> Vec3 {
    if dir.normalize().y.abs() > 0.99 {
        Vec3::Z
    } else {
        Vec3::Y
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn framing_looks_at_the_centre_from_plus_z_and_sees_the_front() {
        let bounds = (Vec3::new(-1.0, 0.0, -1.0), Vec3::new(1.0, 2.0, 1.0));
        let c = Camera::framing(bounds);
        assert_eq!(c.target, Vec3::new(0.0, 1.0, 0.0));
        assert!(c.eye.z > 1.0 && c.eye.x == 0.0 && c.eye.y == 1.0, "{c:?}");
        let m = c.view_proj(1.0, bounds).unwrap();
        for corner in [Vec3::new(-1.0, 0.0, 1.0), Vec3::new(1.0, 2.0, 1.0)] {
            let p = m.project_point3(corner);
            assert!(p.x.abs() <= 1.0 && p.y.abs() <= 1.0, "{corner} at {p}");
            assert!((0.0..=1.0).contains(&p.z), "{corner} at {p}");
        }
        // A point scene still gets a camera that works.
        let dot = (Vec3::ONE, Vec3::ONE);
        assert!(Camera::framing(dot).view_proj(1.0, dot).is_ok());
    }

    #[test]
    fn bad_cameras_are_errors() {
        let bounds = (Vec3::ZERO, Vec3::ONE);
        let at = |eye, target, fov_y| Camera { eye, target, fov_y };
        assert!(
            at(Vec3::ONE, Vec3::ONE, 1.0)
                .view_proj(1.0, bounds)
                .is_err()
        );
        assert!(
            at(Vec3::NAN, Vec3::ONE, 1.0)
                .view_proj(1.0, bounds)
                .is_err()
        );
        assert!(at(Vec3::Z, Vec3::ZERO, 0.0).view_proj(1.0, bounds).is_err());
        assert!(at(Vec3::Z, Vec3::ZERO, 3.2).view_proj(1.0, bounds).is_err());
        // Looking straight down (along Y) needs another up vector, not a NaN matrix.
        let m = at(Vec3::Y * 5.0, Vec3::ZERO, 1.0)
            .view_proj(1.0, bounds)
            .unwrap();
        assert!(m.is_finite());
    }
}
