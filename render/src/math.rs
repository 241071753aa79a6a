//! Right-handed view and projection matrices with wgpu's `[0, 1]` depth range (the glam in this
//! workspace is built without its own).

use glam::{Mat4, Vec3, Vec4};

pub fn look_at_rh(eye: Vec3, target: Vec3, up: Vec3) -> Mat4 {
    let f = (target - eye).normalize();
    let s = f.cross(up).normalize();
    let u = s.cross(f);
    Mat4::from_cols(
        Vec4::new(s.x, u.x, -f.x, 0.0),
        Vec4::new(s.y, u.y, -f.y, 0.0),
        Vec4::new(s.z, u.z, -f.z, 0.0),
        Vec4::new(-eye.dot(s), -eye.dot(u), eye.dot(f), 1.0),
    )
}

pub fn perspective_rh(fov_y: f32, aspect: f32, near: f32, far: f32) -> Mat4 {
    let h = 1.0 / (fov_y / 2.0).tan();
    let w = h / aspect;
    let r = far / (near - far);
    Mat4::from_cols(
        Vec4::new(w, 0.0, 0.0, 0.0),
        Vec4::new(0.0, h, 0.0, 0.0),
        Vec4::new(0.0, 0.0, r, -1.0),
        Vec4::new(0.0, 0.0, r * near, 0.0),
    )
}

pub fn orthographic_rh(half: f32, near: f32, far: f32) -> Mat4 {
    let d = 1.0 / (near - far);
    Mat4::from_cols(
        Vec4::new(1.0 / half, 0.0, 0.0, 0.0),
        Vec4::new(0.0, 1.0 / half, 0.0, 0.0),
        Vec4::new(0.0, 0.0, d, 0.0),
        Vec4::new(0.0, 0.0, d * near, 1.0),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_land_where_wgpu_expects_them() {
        let view = look_at_rh(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y);
        let proj = perspective_rh(90f32.to_radians(), 2.0, 1.0, 10.0);
        let m = proj * view;
        // The target at the centre, on the near plane at depth 0, on the far plane at 1.
        let c = m.project_point3(Vec3::ZERO);
        assert!(c.x.abs() < 1e-6 && c.y.abs() < 1e-6);
        assert!(m.project_point3(Vec3::new(0.0, 0.0, 4.0)).z.abs() < 1e-6);
        assert!((m.project_point3(Vec3::new(0.0, 0.0, -5.0)).z - 1.0).abs() < 1e-6);
        // Up is up and right is right; at distance 5 with 90° the half-height is 5, the
        // half-width 10.
        let p = m.project_point3(Vec3::new(5.0, 2.5, 0.0));
        assert!((p.x - 0.5).abs() < 1e-6 && (p.y - 0.5).abs() < 1e-6, "{p}");
        let o = orthographic_rh(2.0, 0.0, 8.0) * look_at_rh(Vec3::Z * 4.0, Vec3::ZERO, Vec3::Y);
        let q = o.project_point3(Vec3::new(1.0, -2.0, 0.0));
        assert!((q - Vec3::new(0.5, -1.0, 0.5)).length() < 1e-6, "{q}");
    }
}
