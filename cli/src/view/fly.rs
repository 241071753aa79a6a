//! The fly camera: a position and a heading (yaw about +Y, pitch), moved by held keys at a
//! speed scaled to the scene, turned by dragging.

use bounce_render::Camera;
use glam::Vec3;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fly {
    pub eye: Vec3,
    /// Radians about +Y; 0 looks along −Z.
    pub yaw: f32,
    /// Radians above the horizon, kept short of straight up or down.
    pub pitch: f32,
    pub fov_y: f32,
    /// World units a second.
    pub speed: f32,
}

/// Movement asked for this frame, each in −1..=1 (right, up, forward).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Motion {
    pub right: f32,
    pub up: f32,
    pub forward: f32,
}

const PITCH_LIMIT: f32 = 1.55;

impl Fly {
    /// Starts where `camera` is, looking where it looks; a scene of radius `radius` is crossed
    /// in about four seconds.
    pub fn from_camera(camera: &Camera, radius: f32) -> Fly {
        let d = (camera.target - camera.eye).normalize_or(Vec3::NEG_Z);
        Fly {
            eye: camera.eye,
            yaw: (-d.x).atan2(-d.z),
            pitch: d.y.clamp(-1.0, 1.0).asin().clamp(-PITCH_LIMIT, PITCH_LIMIT),
            fov_y: camera.fov_y,
            speed: (radius / 2.0).max(1e-3),
        }
    }

    pub fn forward(&self) -> Vec3 {
        let (sy, cy) = self.yaw.sin_cos();
        let (sp, cp) = self.pitch.sin_cos();
        Vec3::new(-sy * cp, sp, -cy * cp)
    }

    /// Right along the horizon.
    pub fn right(&self) -> Vec3 {
        let (sy, cy) = self.yaw.sin_cos();
        Vec3::new(cy, 0.0, -sy)
    }

    pub fn camera(&self) -> Camera {
        Camera {
            eye: self.eye,
            target: self.eye + self.forward(),
            fov_y: self.fov_y,
        }
    }

    /// Moves for `dt` seconds; `fast` triples the speed.
    pub fn step(&mut self, motion: Motion, dt: f32, fast: bool) {
        let v = self.right() * motion.right + Vec3::Y * motion.up + self.forward() * motion.forward;
        if v != Vec3::ZERO {
            let speed = if fast { self.speed * 3.0 } else { self.speed };
            self.eye += v.normalize() * speed * dt;
        }
    }

    /// Turns by a drag of `dx`, `dy` pixels (right and down positive).
    pub fn turn(&mut self, dx: f32, dy: f32) {
        const RADIANS_PER_PIXEL: f32 = 0.004;
        self.yaw -= dx * RADIANS_PER_PIXEL;
        self.pitch = (self.pitch - dy * RADIANS_PER_PIXEL).clamp(-PITCH_LIMIT, PITCH_LIMIT);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_the_camera_it_starts_from() {
        let c = Camera {
            eye: Vec3::new(1.0, 2.0, 5.0),
            target: Vec3::new(0.0, 1.0, 0.0),
            fov_y: 0.8,
        };
        let fly = Fly::from_camera(&c, 2.0);
        let d = (c.target - c.eye).normalize();
        assert!(
            (fly.forward() - d).length() < 1e-5,
            "{} vs {d}",
            fly.forward()
        );
        let back = fly.camera();
        assert_eq!(back.eye, c.eye);
        assert!(((back.target - back.eye).normalize() - d).length() < 1e-5);
    }

    #[test]
    fn moves_along_its_heading_and_turns_with_the_drag() {
        let mut fly = Fly::from_camera(
            &Camera {
                eye: Vec3::ZERO,
                target: Vec3::NEG_Z,
                fov_y: 1.0,
            },
            2.0,
        );
        fly.step(
            Motion {
                forward: 1.0,
                ..Default::default()
            },
            1.0,
            false,
        );
        assert!(
            (fly.eye - Vec3::new(0.0, 0.0, -1.0)).length() < 1e-5,
            "{}",
            fly.eye
        );
        fly.step(
            Motion {
                right: 1.0,
                ..Default::default()
            },
            1.0,
            true,
        );
        assert!(
            (fly.eye - Vec3::new(3.0, 0.0, -1.0)).length() < 1e-5,
            "{}",
            fly.eye
        );
        // Dragging right turns right (towards +X from −Z); dragging down looks down.
        fly.turn(100.0, 0.0);
        assert!(fly.forward().x > 0.0);
        fly.turn(0.0, 100.0);
        assert!(fly.forward().y < 0.0);
        // Pitch stops short of straight down.
        fly.turn(0.0, 1e6);
        assert!(fly.forward().y > -1.0 && fly.camera().fov_y == 1.0);
    }
}
