//! Camera ray generation for path samples: a view's camera converted once into `f32` in the
//! scene's local frame ([`SampleRays`]), then one ray per image point. The map is that of
//! [`dataset::Camera::pixel_ray`]: image point `(px, py)` → camera-frame direction
//! `((px − cx)/f_x, −(py − cy)/f_y, −1)` → `c2w` rotation → normalised once, with the origin
//! moved into the scene's frame by subtracting [`crate::scene::Scene::origin`] in `f64` before the
//! conversion to `f32`. It avoids the `f64` map's two divisions and three normalisations per
//! sample; the ground truth keeps the `f64` pixel-centre ray. The inverse,
//! [`SampleRays::project`], maps a scene point to its image point (the caustic light tracer's
//! camera connections), and [`SampleRays::pixel_density`] gives the density per steradian of a
//! ray uniform over one pixel.

use crate::geometry::Ray;
use dataset::Camera;
use glam::{DVec3, Vec3};

/// The jittered camera rays of one view's path samples, in the scene's local frame and `f32`:
/// image point `(px, py)` → camera-frame direction
/// `((px − cx)/f_x, −(py − cy)/f_y, −1)` → `c2w` rotation → normalised.
#[derive(Clone, Copy, Debug)]
pub struct SampleRays {
    origin: Vec3,
    x: Vec3,
    y: Vec3,
    z: Vec3,
    cx: f32,
    cy: f32,
    inv_fx: f32,
    inv_fy: f32,
    fx: f32,
    fy: f32,
}

impl SampleRays {
    /// The rays of `camera` for a scene whose local frame is centred at `scene_origin`.
    pub fn new(camera: &Camera, scene_origin: DVec3) -> Self {
        let k = &camera.intrinsics;
        let m = camera.c2w;
        Self {
            origin: (camera.origin() - scene_origin).as_vec3(),
            x: m.x_axis.truncate().as_vec3(),
            y: m.y_axis.truncate().as_vec3(),
            z: m.z_axis.truncate().as_vec3(),
            cx: k.cx as f32,
            cy: k.cy as f32,
            inv_fx: (1.0 / k.fl_x) as f32,
            inv_fy: (1.0 / k.fl_y) as f32,
            fx: k.fl_x as f32,
            fy: k.fl_y as f32,
        }
    }

    /// The image point of the (scene-local) point `p` with the cosine between its direction
    /// and the optical axis and its distance from the camera: `(px, py, cos θ, distance)`
    /// such that [`SampleRays::ray`]`(px, py)` points at `p`; `None` behind the camera.
    #[inline]
    #[allow(clippy::neg_cmp_op_on_partial_ord)] // (also rejects NaN)
    pub fn project(&self, p: Vec3) -> Option<(f32, f32, f32, f32)> {
        let v = p - self.origin;
        let (a, b, c) = (v.dot(self.x), v.dot(self.y), -v.dot(self.z));
        let dist = v.length();
        if !(c > 0.0) || !(dist > 0.0) {
            return None;
        }
        Some((self.cx + a / c * self.fx, self.cy - b / c * self.fy, c / dist, dist))
    }

    /// The density per steradian of a camera ray uniform over one pixel, at angle `θ` from
    /// the optical axis (`cos_theta`): `f_x f_y / cos³ θ`.
    #[inline]
    pub fn pixel_density(&self, cos_theta: f32) -> f32 {
        self.fx * self.fy / (cos_theta * cos_theta * cos_theta)
    }

    /// The ray through image point (`px`, `py`) (pixels from the top-left corner).
    #[inline]
    pub fn ray(&self, px: f32, py: f32) -> Ray {
        let (dx, dy) = ((px - self.cx) * self.inv_fx, -(py - self.cy) * self.inv_fy);
        Ray::new(self.origin, (self.x * dx + self.y * dy - self.z).normalize_or_zero())
    }
}
