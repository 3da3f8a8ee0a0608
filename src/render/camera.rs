//! Perspective camera: look-at placement, vertical field of view, optional thin lens for depth of field.

use super::math::{concentric_disk, Ray, Vec3};

#[derive(Clone, Debug)]
pub struct Camera {
    pub eye: Vec3,
    pub forward: Vec3,
    /// Image right, scaled by tan(fov/2)·aspect.
    right: Vec3,
    /// Image up, scaled by tan(fov/2).
    up: Vec3,
    pub width: u32,
    pub height: u32,
    /// Lens radius; 0 = pinhole.
    pub aperture: f32,
    pub focus_distance: f32,
}

impl Camera {
    pub fn new(
        eye: Vec3,
        target: Vec3,
        up: Vec3,
        fov_deg: f32,
        (width, height): (u32, u32),
        aperture: f32,
        focus_distance: f32,
    ) -> Camera {
        let forward = (target - eye).normalize();
        let right = forward.cross(up).normalize();
        let true_up = right.cross(forward);
        let tan = (fov_deg.to_radians() * 0.5).tan();
        let aspect = width as f32 / height as f32;
        Camera {
            eye,
            forward,
            right: right * (tan * aspect),
            up: true_up * tan,
            width,
            height,
            aperture,
            focus_distance,
        }
    }

    /// The ray through image position (`x`, `y`) in pixels (row 0 at the top), with lens sample `lens`.
    /// `dof` is a compile-time constant in the integrator, so a pinhole build has no lens code.
    #[inline(always)]
    pub fn ray(&self, x: f32, y: f32, lens: (f32, f32), dof: bool) -> Ray {
        let sx = 2.0 * x / self.width as f32 - 1.0;
        let sy = 1.0 - 2.0 * y / self.height as f32;
        let d = (self.forward + self.right * sx + self.up * sy).normalize();
        if dof && self.aperture > 0.0 {
            let (lx, ly) = concentric_disk(lens.0, lens.1);
            let r = self.right.normalize() * (lx * self.aperture);
            let u = self.up.normalize() * (ly * self.aperture);
            let focus = self.eye + d * (self.focus_distance / d.dot(self.forward));
            let o = self.eye + r + u;
            Ray {
                o,
                d: (focus - o).normalize(),
            }
        } else {
            Ray { o: self.eye, d }
        }
    }
}
