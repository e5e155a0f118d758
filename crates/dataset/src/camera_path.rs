//! nerfstudio's `camera_path.json`: the file its viewer exports and `ns-render camera-path`
//! reads, read and written with nerfstudio's keys so a path goes both ways.
//!
//! Layout (every key nerfstudio writes; unknown top-level and per-frame keys are kept, so a
//! file read and written again keeps them):
//! - `camera_path`: the frames, each `{camera_to_world, fov, aspect}`: `camera_to_world` is
//!   the 4×4 camera-to-world matrix, 16 numbers **row by row**, OpenGL camera frame (+X right,
//!   +Y up, looking down −Z), as our `transform_matrix`; `fov` is the **vertical** field of
//!   view in **degrees** (nerfstudio: `fl = 0.5 · render_height / tan(0.5 · fov)`); `aspect`
//!   is width / height.
//! - `render_width`, `render_height` (pixels), `fps`, `seconds`, `camera_type`
//!   (`perspective`), `smoothness_value`, `is_cycle`, `crop` (null), `keyframes` (the
//!   viewer's control points: `matrix` in the same convention, `fov`, `aspect`, … kept as
//!   they are: nerfstudio renders `camera_path` alone, and so do we).
//!
//! The poses are in the world frame of the dataset the path belongs to (our `transforms`
//! files' frame). nerfstudio's own exports are in the frame its dataparser made
//! (`dataparser_transforms.json`), which is ours only when that transform is the identity.
//!
//! [`CameraPathFile::cameras`] checks a path before anything renders it: no frames, a
//! `camera_to_world` that is not 16 finite numbers of a rigid, invertible transform, a `fov`
//! outside (0°, 180°), a size of 0 or over [`MAX_PATH_SIZE`] pixels, another camera type:
//! each refused in one sentence naming the file, the key and the frame index.

use crate::{Camera, DatasetError, Intrinsics};
use glam::DMat4;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The largest `render_width` or `render_height` accepted, pixels.
pub const MAX_PATH_SIZE: u32 = 8192;

/// One frame of `camera_path`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PathFrame {
    /// Camera-to-world, 16 numbers row by row.
    pub camera_to_world: Vec<f64>,
    /// Vertical field of view, degrees.
    pub fov: f64,
    /// Width / height.
    pub aspect: f64,
    /// Keys nerfstudio may add (`render_time`), kept.
    #[serde(flatten)]
    pub extra: serde_json::Map<String, serde_json::Value>,
}

/// A `camera_path.json` file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraPathFile {
    /// The viewer's control points, kept as written.
    #[serde(default)]
    pub keyframes: Vec<serde_json::Value>,
    /// `perspective` (the only type rendered here).
    #[serde(default = "perspective")]
    pub camera_type: String,
    /// Image height, pixels.
    pub render_height: u32,
    /// Image width, pixels.
    pub render_width: u32,
    /// The frames.
    pub camera_path: Vec<PathFrame>,
    /// Frames per second of the video.
    pub fps: f64,
    /// Length of the path, seconds.
    pub seconds: f64,
    /// The viewer's spline tension.
    #[serde(default)]
    pub smoothness_value: f64,
    /// Whether the path loops.
    #[serde(default)]
    pub is_cycle: bool,
    /// The viewer's crop box (null: none).
    #[serde(default)]
    pub crop: serde_json::Value,
    /// Other keys (`default_fov`, `default_transition_sec`, `camera_model`), kept.
    #[serde(flatten)]
    pub extra: serde_json::Map<String, serde_json::Value>,
}

fn perspective() -> String {
    "perspective".into()
}

/// The `fov` (degrees) to write for `intr`: its vertical field of view, nudged by up to 256
/// units in the last place to one whose read-back focal length (`0.5 · height / tan(0.5 ·
/// fov)`) is `intr`'s exactly when there is one; otherwise the nearest (within 1e-12).
pub fn fov_degrees(intr: &Intrinsics) -> f64 {
    let fov = intr.camera_angle_y().to_degrees();
    let exact = |f: f64| Intrinsics::from_fov_y(intr.width, intr.height, f.to_radians()).fl_y == intr.fl_y;
    let (mut up, mut down) = (fov, fov);
    for _ in 0..256 {
        if exact(up) {
            return up;
        }
        if exact(down) {
            return down;
        }
        (up, down) = (up.next_up(), down.next_down());
    }
    fov
}

/// A pose as nerfstudio's 16 row-major numbers.
pub fn matrix_to_row_major(c2w: &DMat4) -> Vec<f64> {
    c2w.transpose().to_cols_array().to_vec()
}

impl CameraPathFile {
    /// A path through `cameras` (one intrinsics for all: the first's size and vertical field of
    /// view), played at `fps`; `keyframes` are the control poses it was made from.
    pub fn from_cameras(cameras: &[Camera], keyframes: &[Camera], fps: f64) -> Self {
        let frame = |c: &Camera| PathFrame {
            camera_to_world: matrix_to_row_major(&c.c2w),
            fov: fov_degrees(&c.intrinsics),
            aspect: c.intrinsics.width as f64 / c.intrinsics.height as f64,
            extra: Default::default(),
        };
        let key = |c: &Camera| {
            serde_json::json!({
                "matrix": matrix_to_row_major(&c.c2w),
                "fov": fov_degrees(&c.intrinsics),
                "aspect": c.intrinsics.width as f64 / c.intrinsics.height as f64,
                "override_transition_enabled": false,
                "override_transition_sec": null,
            })
        };
        let (w, h) = cameras.first().map_or((0, 0), |c| (c.intrinsics.width, c.intrinsics.height));
        Self {
            keyframes: keyframes.iter().map(key).collect(),
            camera_type: perspective(),
            render_height: h,
            render_width: w,
            camera_path: cameras.iter().map(frame).collect(),
            fps,
            seconds: cameras.len() as f64 / fps,
            smoothness_value: 0.5,
            is_cycle: false,
            crop: serde_json::Value::Null,
            extra: Default::default(),
        }
    }

    /// Reads and parses `path` (not checked: see [`CameraPathFile::cameras`]).
    pub fn read(path: &Path) -> Result<Self, DatasetError> {
        let bytes = crate::io::read(path)?;
        serde_json::from_slice(&bytes).map_err(|e| DatasetError::Json { path: path.into(), message: e.to_string() })
    }

    /// Writes the file atomically (pretty JSON).
    pub fn write(&self, path: &Path) -> Result<(), DatasetError> {
        crate::io::atomic_write_json(path, self)
    }

    /// The frames' cameras, after checking the whole file (see the module documentation);
    /// `path` names the file in errors.
    pub fn cameras(&self, path: &Path) -> Result<Vec<Camera>, DatasetError> {
        let bad = |m: String| DatasetError::invalid(path, m);
        if self.camera_type != "perspective" {
            return Err(bad(format!("camera_type '{}': only perspective paths are rendered", self.camera_type)));
        }
        for (key, v) in [("render_width", self.render_width), ("render_height", self.render_height)] {
            if v == 0 || v > MAX_PATH_SIZE {
                return Err(bad(format!("{key} {v}: must be 1 to {MAX_PATH_SIZE} pixels")));
            }
        }
        for (key, v) in [("fps", self.fps), ("seconds", self.seconds)] {
            if !v.is_finite() || v < 0.0 {
                return Err(bad(format!("{key} {v}: must be finite and not negative")));
            }
        }
        if self.camera_path.is_empty() {
            return Err(bad("camera_path: the path has no frames".into()));
        }
        self.camera_path
            .iter()
            .enumerate()
            .map(|(k, f)| {
                let m: [f64; 16] = f.camera_to_world.as_slice().try_into().map_err(|_| {
                    bad(format!("camera_path[{k}].camera_to_world: {} numbers, expected 16 (a 4x4 matrix row by row)", f.camera_to_world.len()))
                })?;
                if m.iter().any(|v| !v.is_finite()) {
                    return Err(bad(format!("camera_path[{k}].camera_to_world: holds a non-finite number")));
                }
                let c2w = DMat4::from_cols_array(&m).transpose();
                if !(f.fov.is_finite() && f.fov > 0.0 && f.fov < 180.0) {
                    return Err(bad(format!("camera_path[{k}].fov {}: the vertical field of view must lie strictly between 0 and 180 degrees", f.fov)));
                }
                let intr = Intrinsics::from_fov_y(self.render_width, self.render_height, f.fov.to_radians());
                Camera::new(intr, c2w).map_err(|m| bad(format!("camera_path[{k}].camera_to_world: {m}")))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    /// A file as nerfstudio's viewer writes it: every key, its nesting, `crop` null, keyframes
    /// with `matrix` and the transition overrides.
    const NERFSTUDIO: &str = r#"{
  "default_fov": 50.0,
  "default_transition_sec": 2.0,
  "keyframes": [
    {"matrix": [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 4.0, 0.0, 0.0, 0.0, 1.0], "fov": 50.0, "aspect": 1.5, "override_transition_enabled": false, "override_transition_sec": null}
  ],
  "camera_type": "perspective",
  "render_height": 16,
  "render_width": 24,
  "fps": 30.0,
  "seconds": 0.1,
  "is_cycle": false,
  "smoothness_value": 0.5,
  "camera_path": [
    {"camera_to_world": [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 4.0, 0.0, 0.0, 0.0, 1.0], "fov": 50.0, "aspect": 1.5},
    {"camera_to_world": [0.0, 0.0, 1.0, 4.0, 0.0, 1.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], "fov": 50.0, "aspect": 1.5},
    {"camera_to_world": [-1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.5, 0.0, 0.0, -1.0, -4.0, 0.0, 0.0, 0.0, 1.0], "fov": 40.0, "aspect": 1.5, "render_time": 0.5}
  ],
  "crop": null
}"#;

    fn write_fixture(dir: &Path) -> std::path::PathBuf {
        let p = dir.join("camera_path.json");
        std::fs::write(&p, NERFSTUDIO).unwrap();
        p
    }

    #[test]
    fn nerfstudio_file_round_trips_key_for_key() {
        let dir = tempfile_dir("roundtrip");
        let p = write_fixture(&dir);
        let file = CameraPathFile::read(&p).unwrap();
        let cams = file.cameras(&p).unwrap();
        assert_eq!(cams.len(), 3);
        // Row-major: the translation is the fourth number of each row.
        assert_eq!(cams[0].origin(), DVec3::new(0.0, 0.0, 4.0));
        assert_eq!(cams[1].origin(), DVec3::new(4.0, 0.0, 0.0));
        // The second camera looks down world −X... its −Z axis is (−1, 0, 0) in world.
        assert_eq!(-cams[1].c2w.z_axis.truncate(), DVec3::new(-1.0, 0.0, 0.0));
        // nerfstudio's focal length: 0.5 · render_height / tan(0.5 · fov).
        let fl = 0.5 * 16.0 / (25f64.to_radians()).tan();
        assert!((cams[0].intrinsics.fl_y - fl).abs() < 1e-12 && cams[0].intrinsics.fl_x == cams[0].intrinsics.fl_y);
        assert_eq!((cams[0].intrinsics.width, cams[0].intrinsics.height), (24, 16));
        let out = dir.join("again.json");
        file.write(&out).unwrap();
        let a: serde_json::Value = serde_json::from_str(NERFSTUDIO).unwrap();
        let b: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
        assert_eq!(a, b, "every key and value survives a read and a write");
        assert_eq!(CameraPathFile::read(&out).unwrap(), file);
    }

    #[test]
    fn bad_paths_are_refused_naming_the_key_and_frame() {
        let dir = tempfile_dir("bad");
        let p = write_fixture(&dir);
        let good = CameraPathFile::read(&p).unwrap();
        let check = |f: &CameraPathFile, want: &[&str]| {
            let e = f.cameras(&p).unwrap_err().to_string();
            assert!(e.contains("camera_path.json"), "{e}");
            for w in want {
                assert!(e.contains(w), "{e} lacks {w}");
            }
        };
        let mut f = good.clone();
        f.camera_path.clear();
        check(&f, &["camera_path", "no frames"]);
        let mut f = good.clone();
        f.camera_path[2].camera_to_world[5] = f64::NAN;
        check(&f, &["camera_path[2].camera_to_world", "non-finite"]);
        let mut f = good.clone();
        f.camera_path[1].camera_to_world = vec![0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 3.0, 0.0, 0.0, 0.0, 1.0];
        check(&f, &["camera_path[1].camera_to_world", "invertible"]);
        let mut f = good.clone();
        f.camera_path[1].camera_to_world.truncate(12);
        check(&f, &["camera_path[1].camera_to_world", "12 numbers"]);
        for fov in [0.0, 180.0, 200.0, -5.0, f64::INFINITY] {
            let mut f = good.clone();
            f.camera_path[2].fov = fov;
            check(&f, &["camera_path[2].fov", "180"]);
        }
        let mut f = good.clone();
        f.render_width = 8193;
        check(&f, &["render_width 8193", "8192"]);
        let mut f = good.clone();
        f.render_height = 0;
        check(&f, &["render_height 0"]);
        let mut f = good.clone();
        f.camera_type = "fisheye".into();
        check(&f, &["camera_type", "fisheye"]);
        // Not JSON of this shape: the reader names the file.
        std::fs::write(&p, "{\"camera_path\": 3}").unwrap();
        let e = CameraPathFile::read(&p).unwrap_err().to_string();
        assert!(e.contains("camera_path.json") && e.contains("invalid JSON"), "{e}");
    }

    #[test]
    fn cameras_written_read_back_equal() {
        let dir = tempfile_dir("write");
        let intr = Intrinsics::from_fov_x(16, 16, 0.6911);
        let cams: Vec<Camera> = (0..3)
            .map(|k| Camera::new(intr, Camera::look_at(DVec3::new(k as f64, 1.0, 3.0), DVec3::ZERO, DVec3::Y)).unwrap())
            .collect();
        let file = CameraPathFile::from_cameras(&cams, &cams[..1], 24.0);
        let p = dir.join("p.json");
        file.write(&p).unwrap();
        let back = CameraPathFile::read(&p).unwrap().cameras(&p).unwrap();
        for (a, b) in cams.iter().zip(&back) {
            assert!(a.c2w.abs_diff_eq(b.c2w, 1e-15), "{:?} {:?}", a.c2w, b.c2w);
            // serde_json's default float parsing may differ from the shortest representation
            // by a unit in the last place: equal to rounding through JSON.
            assert!((a.intrinsics.fl_y - b.intrinsics.fl_y).abs() < 1e-12 * a.intrinsics.fl_y);
        }
        for (w, h, fov) in [(16, 16, 0.6911), (800, 800, 0.6911), (64, 48, 1.2), (37, 11, 0.05)] {
            let k = Intrinsics::from_fov_x(w, h, fov);
            let back = Intrinsics::from_fov_y(w, h, fov_degrees(&k).to_radians());
            assert!((back.fl_y - k.fl_y).abs() < 1e-12 * k.fl_y, "{w}x{h} {fov}");
        }
    }

    fn tempfile_dir(name: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("dataset_camera_path_{name}_{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }
}
