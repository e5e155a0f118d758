use glam::{DMat4, DVec3, DVec4};
use serde::{Deserialize, Serialize};

/// The narrowest field of view accepted, radians (about 0.006°, a 360 m lens on a 36 mm film):
/// narrower is a unit error or corrupt data, and its rays are parallel to within rounding.
pub const MIN_FIELD_OF_VIEW: f64 = 1e-4;

/// The farthest a camera may stand from the world origin, metres (beyond the Earth's orbit):
/// farther is a unit error or corrupt data, and an `f32` scene frame cannot hold it.
pub const MAX_TRANSLATION: f64 = 1e12;

/// Pinhole intrinsics in pixels (instant-ngp / nerfstudio keys `w h fl_x fl_y cx cy`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length along x, pixels.
    pub fl_x: f64,
    /// Focal length along y, pixels.
    pub fl_y: f64,
    /// Principal point x, pixels from the left edge.
    pub cx: f64,
    /// Principal point y, pixels from the top edge.
    pub cy: f64,
}

impl Intrinsics {
    /// Square pixels and a centred principal point from the horizontal field of view
    /// `camera_angle_x` (radians), as the Blender synthetic datasets define it:
    /// `fl = 0.5 w / tan(0.5 camera_angle_x)`.
    pub fn from_fov_x(width: u32, height: u32, camera_angle_x: f64) -> Self {
        let fl = 0.5 * width as f64 / (0.5 * camera_angle_x).tan();
        Self { width, height, fl_x: fl, fl_y: fl, cx: 0.5 * width as f64, cy: 0.5 * height as f64 }
    }

    /// The same from the vertical field of view (glTF's `yfov`).
    pub fn from_fov_y(width: u32, height: u32, yfov: f64) -> Self {
        let fl = 0.5 * height as f64 / (0.5 * yfov).tan();
        Self { width, height, fl_x: fl, fl_y: fl, cx: 0.5 * width as f64, cy: 0.5 * height as f64 }
    }

    /// Horizontal field of view in radians: `2 atan(w / (2 fl_x))`.
    pub fn camera_angle_x(&self) -> f64 {
        2.0 * (0.5 * self.width as f64 / self.fl_x).atan()
    }

    /// Vertical field of view in radians.
    pub fn camera_angle_y(&self) -> f64 {
        2.0 * (0.5 * self.height as f64 / self.fl_y).atan()
    }

    /// The same camera at `1/factor` of the resolution (downscaling by an integer factor).
    pub fn downscaled(&self, factor: u32) -> Self {
        let f = factor.max(1) as f64;
        Self {
            width: self.width / factor.max(1),
            height: self.height / factor.max(1),
            fl_x: self.fl_x / f,
            fl_y: self.fl_y / f,
            cx: self.cx / f,
            cy: self.cy / f,
        }
    }

    /// The same field of view at `width` pixels wide: every pixel quantity scaled by
    /// `width / self.width`, the height rounded (at least 1).
    pub fn at_width(&self, width: u32) -> Self {
        let s = width as f64 / self.width as f64;
        Self {
            width,
            height: (self.height as f64 * s).round().max(1.0) as u32,
            fl_x: self.fl_x * s,
            fl_y: self.fl_y * s,
            cx: self.cx * s,
            cy: self.cy * s,
        }
    }

    /// Checks that the intrinsics describe a real camera; the message says what is wrong.
    pub fn validate(&self) -> Result<(), String> {
        if self.width == 0 || self.height == 0 {
            return Err(format!("image size {}x{} is empty", self.width, self.height));
        }
        for (name, v) in [("fl_x", self.fl_x), ("fl_y", self.fl_y)] {
            if !v.is_finite() || v <= 0.0 {
                return Err(format!("focal length {name} = {v} must be finite and positive"));
            }
        }
        for (name, v) in [("cx", self.cx), ("cy", self.cy)] {
            if !v.is_finite() {
                return Err(format!("principal point {name} = {v} is not finite"));
            }
        }
        for (name, v, fov) in [("fl_x", self.fl_x, self.camera_angle_x()), ("fl_y", self.fl_y, self.camera_angle_y())] {
            if fov.is_nan() || fov <= MIN_FIELD_OF_VIEW {
                return Err(format!("focal length {name} = {v} gives a field of view of {fov:e} rad, narrower than {MIN_FIELD_OF_VIEW:e} rad"));
            }
        }
        Ok(())
    }
}

/// A ray with a unit direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Origin (the camera centre for camera rays), world space.
    pub origin: DVec3,
    /// Unit direction, world space.
    pub direction: DVec3,
}

/// A posed pinhole camera: intrinsics plus the 4×4 camera-to-world matrix (OpenGL camera
/// frame: +X right, +Y up, looking down −Z).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Pixel intrinsics.
    pub intrinsics: Intrinsics,
    /// Camera-to-world transform (rigid).
    pub c2w: DMat4,
}

impl Camera {
    /// Builds a camera after checking the intrinsics and that `c2w` is a finite rigid
    /// transform (orthonormal rotation within 1e-3, last row 0 0 0 1).
    pub fn new(intrinsics: Intrinsics, c2w: DMat4) -> Result<Self, String> {
        intrinsics.validate()?;
        validate_pose(&c2w)?;
        Ok(Self { intrinsics, c2w })
    }

    /// Camera-to-world matrix of a camera at `eye` looking at `target` with `up` as the
    /// approximate up direction. Falls back to another up vector when `up` is parallel to the
    /// viewing direction.
    pub fn look_at(eye: DVec3, target: DVec3, up: DVec3) -> DMat4 {
        let back = (eye - target).normalize();
        let mut right = up.cross(back);
        if right.length_squared() < 1e-12 {
            right = DVec3::Z.cross(back);
            if right.length_squared() < 1e-12 {
                right = DVec3::X.cross(back);
            }
        }
        let right = right.normalize();
        let true_up = back.cross(right);
        DMat4::from_cols(right.extend(0.0), true_up.extend(0.0), back.extend(0.0), eye.extend(1.0))
    }

    /// The camera centre in world space.
    pub fn origin(&self) -> DVec3 {
        self.c2w.w_axis.truncate()
    }

    /// Direction through image point (`px`, `py`) (pixels, continuous, origin at the top-left
    /// corner) in the camera frame, normalised. Its z component is negative.
    pub fn direction_camera(&self, px: f64, py: f64) -> DVec3 {
        let k = &self.intrinsics;
        DVec3::new((px - k.cx) / k.fl_x, -(py - k.cy) / k.fl_y, -1.0).normalize()
    }

    /// The ray through image point (`px`, `py`), world space.
    pub fn pixel_ray(&self, px: f64, py: f64) -> Ray {
        let d = self.direction_camera(px, py);
        let dw = self.c2w.transform_vector3(d).normalize();
        Ray { origin: self.origin(), direction: dw }
    }

    /// The ray through the centre of pixel (column `i`, row `j`): image point (i + 0.5, j + 0.5).
    pub fn pixel_center_ray(&self, i: u32, j: u32) -> Ray {
        self.pixel_ray(i as f64 + 0.5, j as f64 + 0.5)
    }

    /// z-depth of a point at Euclidean `distance` along the ray through (`px`, `py`):
    /// `depth = distance · (−d_cam.z)` with `d_cam` the unit camera-frame direction.
    /// This and [`Camera::distance_from_z_depth`] are the project's only depth conversions.
    pub fn z_depth_from_distance(&self, px: f64, py: f64, distance: f64) -> f64 {
        distance * -self.direction_camera(px, py).z
    }

    /// Euclidean distance along the ray through (`px`, `py`) of a point at z-depth `depth`.
    pub fn distance_from_z_depth(&self, px: f64, py: f64, depth: f64) -> f64 {
        depth / -self.direction_camera(px, py).z
    }

    /// The same camera with its image downscaled by an integer factor.
    pub fn downscaled(&self, factor: u32) -> Self {
        Self { intrinsics: self.intrinsics.downscaled(factor), c2w: self.c2w }
    }

    /// The same camera at `width` pixels wide ([`Intrinsics::at_width`]).
    pub fn at_width(&self, width: u32) -> Self {
        Self { intrinsics: self.intrinsics.at_width(width), c2w: self.c2w }
    }

    /// The pose as the row-major 4×4 array written in `transform_matrix`.
    pub fn rows(&self) -> [[f64; 4]; 4] {
        let m = self.c2w.transpose();
        [m.x_axis.to_array(), m.y_axis.to_array(), m.z_axis.to_array(), m.w_axis.to_array()]
    }

    /// The pose from a row-major 4×4 array as written in `transform_matrix`.
    pub fn c2w_from_rows(rows: &[[f64; 4]; 4]) -> DMat4 {
        DMat4::from_cols(
            DVec4::from_array(rows[0]),
            DVec4::from_array(rows[1]),
            DVec4::from_array(rows[2]),
            DVec4::from_array(rows[3]),
        )
        .transpose()
    }
}

fn validate_pose(m: &DMat4) -> Result<(), String> {
    if !m.is_finite() {
        return Err("pose contains a non-finite value".into());
    }
    let t = m.w_axis.truncate();
    if t.length() > MAX_TRANSLATION {
        return Err(format!("pose's translation {:?} lies {:e} m from the origin, farther than {MAX_TRANSLATION:e} m", t.to_array(), t.length()));
    }
    let last = m.row(3);
    if (last - DVec4::new(0.0, 0.0, 0.0, 1.0)).abs().max_element() > 1e-6 {
        return Err(format!("pose's last row is {last:?}, expected [0, 0, 0, 1]"));
    }
    let (x, y, z) = (m.x_axis.truncate(), m.y_axis.truncate(), m.z_axis.truncate());
    let det = x.cross(y).dot(z);
    if det.abs() < 1e-9 {
        return Err("pose is not invertible (rotation part has zero determinant)".into());
    }
    let tol = 1e-3;
    let unit = [x.length(), y.length(), z.length()];
    let ortho = [x.dot(y).abs(), y.dot(z).abs(), z.dot(x).abs()];
    if unit.iter().any(|l| (l - 1.0).abs() > tol) || ortho.iter().any(|d| *d > tol) || det < 0.0 {
        return Err(format!(
            "pose's rotation is not a proper rotation (axis lengths {unit:?}, determinant {det:.6})"
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        let eye = DVec3::new(1.0, 2.0, 3.0);
        Camera::new(Intrinsics::from_fov_x(40, 30, 0.8), Camera::look_at(eye, DVec3::ZERO, DVec3::Y))
            .unwrap()
    }

    #[test]
    fn centre_ray_looks_at_target() {
        let c = cam();
        let r = c.pixel_ray(20.0, 15.0);
        let expected = (-c.origin()).normalize();
        assert!((r.direction - expected).length() < 1e-12);
    }

    #[test]
    fn top_left_pixel_points_up_and_left() {
        let c = Camera::new(Intrinsics::from_fov_x(40, 30, 0.8), DMat4::IDENTITY).unwrap();
        let d = c.pixel_center_ray(0, 0).direction;
        assert!(d.x < 0.0 && d.y > 0.0 && d.z < 0.0);
        // The horizontal field of view is spanned by the image edges.
        let left = c.pixel_ray(0.0, 15.0).direction;
        let right = c.pixel_ray(40.0, 15.0).direction;
        assert!((left.angle_between(right) - 0.8).abs() < 1e-12);
    }

    #[test]
    fn a_camera_at_another_width_sees_the_same_view() {
        let c = cam();
        for width in [8, 40, 100, 256] {
            let s = c.at_width(width);
            assert_eq!(s.intrinsics.width, width);
            assert_eq!(s.intrinsics.height, (30.0 * width as f64 / 40.0).round() as u32);
            assert!((s.intrinsics.camera_angle_x() - 0.8).abs() < 1e-12, "width {width}");
            // The same fraction of the image is the same ray, the corners included.
            for (u, v) in [(0.0, 0.0), (0.5, 0.5), (1.0, 1.0), (0.25, 0.8)] {
                let (a, b) = (c.pixel_ray(u * 40.0, v * 30.0), s.pixel_ray(u * width as f64, v * 30.0 * width as f64 / 40.0));
                assert!((a.direction - b.direction).length() < 1e-12, "width {width} ({u}, {v})");
                assert_eq!(a.origin, b.origin);
            }
        }
        // A very small width keeps at least one row.
        assert_eq!(c.at_width(1).intrinsics.height, 1);
    }

    #[test]
    fn depth_distance_round_trip() {
        let c = cam();
        for (px, py) in [(0.5, 0.5), (39.5, 29.5), (12.25, 7.0)] {
            let dist = 3.7;
            let z = c.z_depth_from_distance(px, py, dist);
            // z-depth is the projection of the hit point's offset onto the viewing axis.
            let r = c.pixel_ray(px, py);
            let p = r.origin + r.direction * dist;
            let forward = -c.c2w.z_axis.truncate();
            assert!((z - (p - c.origin()).dot(forward)).abs() < 1e-12);
            assert!((c.distance_from_z_depth(px, py, z) - dist).abs() < 1e-12);
        }
    }

    #[test]
    fn rows_round_trip() {
        let c = cam();
        assert_eq!(Camera::c2w_from_rows(&c.rows()), c.c2w);
        // Translation sits in the last column of the row-major matrix.
        assert_eq!(c.rows()[0][3], 1.0);
    }

    #[test]
    fn bad_poses_are_rejected() {
        let k = Intrinsics::from_fov_x(4, 4, 0.5);
        assert!(Camera::new(k, DMat4::ZERO).is_err());
        assert!(Camera::new(k, DMat4::from_scale(DVec3::new(2.0, 1.0, 1.0))).is_err());
        let mut nan = DMat4::IDENTITY;
        nan.w_axis.x = f64::NAN;
        assert!(Camera::new(k, nan).is_err());
        assert!(Camera::new(Intrinsics::from_fov_x(0, 4, 0.5), DMat4::IDENTITY).is_err());
        assert!(Camera::new(Intrinsics::from_fov_x(4, 4, 0.0), DMat4::IDENTITY).is_err());
    }

    #[test]
    fn absurd_fields_of_view_and_translations_are_rejected() {
        let e = Camera::new(Intrinsics::from_fov_x(64, 64, 1e-30), DMat4::IDENTITY).unwrap_err();
        assert!(e.contains("fl_x") && e.contains("field of view"), "{e}");
        let e = Camera::new(Intrinsics::from_fov_y(64, 64, 1e-6), DMat4::IDENTITY).unwrap_err();
        assert!(e.contains("field of view"), "{e}");
        let far = DMat4::from_translation(DVec3::new(0.0, 0.0, 1e300));
        let e = Camera::new(Intrinsics::from_fov_x(4, 4, 0.5), far).unwrap_err();
        assert!(e.contains("translation") && e.contains("1e300"), "{e}");
        // A long lens and a camera a thousand kilometres out are real cameras.
        Camera::new(Intrinsics::from_fov_x(800, 800, 1e-3), DMat4::from_translation(DVec3::new(1e6, 0.0, 0.0))).unwrap();
    }
}
