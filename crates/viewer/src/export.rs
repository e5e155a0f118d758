//! `POST /api/camera_path`: the page's keyframes made into nerfstudio's `camera_path.json`, the
//! file `xtask render --camera-path` and `render-nerf --camera-path` read.
//!
//! Body: `{"keyframes": [{"c2w": [16 numbers, row by row], "fov": degrees}, …],
//! "render_width", "render_height", "fps", "seconds", "is_cycle"}`. The frames run through the
//! keyframes on `dataset::path_spline` (frame `i · n` is keyframe `i`, `n` frames per segment
//! chosen so the path lasts about `seconds`); the field of view is interpolated linearly per
//! segment. The answer is checked with [`dataset::CameraPathFile::cameras`], the reader those
//! commands use, before it is returned.

use crate::error::{ViewerError, bad};
use dataset::{Camera, CameraPathFile, Intrinsics, MAX_PATH_SIZE};
use glam::DMat4;
use serde::Deserialize;
use std::path::Path;

/// The most keyframes accepted.
pub const MAX_KEYFRAMES: usize = 1000;
/// The most frames a path may have.
pub const MAX_FRAMES: f64 = 100_000.0;

/// One keyframe of the page.
#[derive(Clone, Debug, Deserialize)]
pub struct Keyframe {
    /// Camera-to-world, 16 numbers row by row.
    pub c2w: Vec<f64>,
    /// Vertical field of view, degrees.
    pub fov: f64,
}

/// The page's export request.
#[derive(Clone, Debug, Deserialize)]
pub struct ExportRequest {
    /// The control poses.
    pub keyframes: Vec<Keyframe>,
    /// Frame width, pixels.
    pub render_width: u32,
    /// Frame height, pixels.
    pub render_height: u32,
    /// Frames per second.
    pub fps: f64,
    /// Length, seconds.
    pub seconds: f64,
    /// Whether the path returns to its first keyframe.
    #[serde(default)]
    pub is_cycle: bool,
}

fn intrinsics(r: &ExportRequest, fov: f64) -> Intrinsics {
    Intrinsics::from_fov_y(r.render_width, r.render_height, fov.to_radians())
}

/// The checked `camera_path.json` for an export request body.
pub fn camera_path(body: &[u8]) -> Result<CameraPathFile, ViewerError> {
    let r: ExportRequest = serde_json::from_slice(body).map_err(|e| bad(format!("camera path request: {e}")))?;
    if r.keyframes.is_empty() || r.keyframes.len() > MAX_KEYFRAMES {
        return Err(bad(format!("keyframes: {} given, 1 to {MAX_KEYFRAMES} needed", r.keyframes.len())));
    }
    for (k, v) in [("render_width", r.render_width), ("render_height", r.render_height)] {
        if v == 0 || v > MAX_PATH_SIZE {
            return Err(bad(format!("{k} {v}: must be 1 to {MAX_PATH_SIZE} pixels")));
        }
    }
    if !(r.fps.is_finite() && r.fps > 0.0 && r.seconds.is_finite() && r.seconds > 0.0 && r.fps * r.seconds <= MAX_FRAMES) {
        return Err(bad(format!("fps {} and seconds {}: both must be positive, at most {MAX_FRAMES} frames in all", r.fps, r.seconds)));
    }
    let keys: Vec<Camera> = r
        .keyframes
        .iter()
        .enumerate()
        .map(|(k, f)| {
            let m: [f64; 16] = f.c2w.as_slice().try_into().map_err(|_| bad(format!("keyframes[{k}].c2w: {} numbers, expected 16", f.c2w.len())))?;
            if m.iter().any(|v| !v.is_finite()) || !(f.fov.is_finite() && f.fov > 0.0 && f.fov < 180.0) {
                return Err(bad(format!("keyframes[{k}]: c2w must be finite and fov strictly between 0 and 180 degrees")));
            }
            Camera::new(intrinsics(&r, f.fov), DMat4::from_cols_array(&m).transpose()).map_err(|e| bad(format!("keyframes[{k}].c2w: {e}")))
        })
        .collect::<Result<_, _>>()?;
    let n_keys = keys.len();
    let segments = if r.is_cycle { n_keys } else { n_keys - 1 };
    let total = (r.fps * r.seconds).round().max(1.0);
    let per = if segments == 0 { 1 } else { ((total / segments as f64).round() as u32).max(1) };
    let poses = dataset::interpolate_poses(&keys.iter().map(|c| c.c2w).collect::<Vec<_>>(), per, r.is_cycle);
    let frames: Vec<Camera> = poses
        .iter()
        .enumerate()
        .map(|(i, pose)| {
            let (seg, t) = (i / per as usize, (i % per as usize) as f64 / per as f64);
            let (a, b) = (r.keyframes[seg % n_keys].fov, r.keyframes[(seg + 1) % n_keys].fov);
            let fov = if segments == 0 { a } else { a + (b - a) * t };
            Camera::new(intrinsics(&r, fov), *pose).map_err(|e| ViewerError::Internal(format!("frame {i} of the path: {e}")))
        })
        .collect::<Result<_, _>>()?;
    let mut file = CameraPathFile::from_cameras(&frames, &keys, r.fps);
    file.is_cycle = r.is_cycle;
    file.cameras(Path::new("camera_path.json")).map_err(|e| bad(e.to_string()))?;
    Ok(file)
}
