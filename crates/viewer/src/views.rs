//! The dataset's views as the page sees them (`GET /api/views`), their exact ground truth
//! (`GET /api/gt`) and the depth range every depth picture of a camera is mapped over.
//!
//! Views are numbered across the splits in order: train, then val, then test. Ground truth is
//! read from the dataset's own files at their full resolution (`eval::truth`, the evaluation's
//! reader: colour composited onto the run's evaluation background, depth exact at pixel
//! centres); nothing but the files a loaded frame names is ever read.

use crate::error::{ViewerError, bad};
use dataset::{Camera, Dataset, Frame};
use eval::truth::{GroundTruthSource, TruthView, load_truth};
use nerf::data::SceneBounds;
use serde_json::{Value, json};

/// Every view, numbered train, val, test.
pub fn all(ds: &Dataset) -> Vec<&Frame> {
    ds.train.iter().chain(&ds.val).chain(&ds.test).collect()
}

/// View `k` of parameter `view`, or a 404 naming it.
pub fn frame(ds: &Dataset, k: usize) -> Result<&Frame, ViewerError> {
    let n = all(ds).len();
    all(ds).get(k).copied().ok_or_else(|| ViewerError::NotFound(format!("view {k}: the dataset has {n} views (0 to {})", n.saturating_sub(1))))
}

/// A camera as the page needs it: size, vertical field of view (degrees) and pose row by row.
pub fn camera_json(c: &Camera) -> Value {
    json!({
        "width": c.intrinsics.width,
        "height": c.intrinsics.height,
        "fov": c.intrinsics.camera_angle_y().to_degrees(),
        "c2w": dataset::matrix_to_row_major(&c.c2w),
    })
}

/// The `GET /api/views` body: the scene box's centre and radius (for orbiting) and each view.
pub fn views_json(ds: &Dataset, bounds: Option<&SceneBounds>) -> Value {
    let views: Vec<Value> = all(ds)
        .iter()
        .enumerate()
        .map(|(k, f)| {
            let mut v = camera_json(&f.camera);
            v["index"] = json!(k);
            v["name"] = json!(f.name);
            v["split"] = json!(format!("{:?}", f.split).to_lowercase());
            v["has_depth"] = json!(f.gt_path.is_some());
            v
        })
        .collect();
    let (center, radius) = match bounds {
        Some(b) => (b.center(), b.half_extent() * 3f32.sqrt()),
        None => ([0.0; 3], 1.0),
    };
    json!({ "center": center, "radius": radius, "views": views })
}

/// The z-depth range a camera's depth pictures are mapped over: the distance from the camera
/// to the scene box's bounding sphere, near and far side (so colours hold still while training).
pub fn depth_range(c: &Camera, bounds: Option<&SceneBounds>) -> (f64, f64) {
    let Some(b) = bounds else { return (0.0, 10.0) };
    let d = (c.origin() - glam::DVec3::from(b.center().map(f64::from))).length();
    let r = f64::from(b.half_extent()) * 3f64.sqrt();
    ((d - r).max(0.0), d + r)
}

/// What a ground-truth picture shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GtKind {
    /// The display colour.
    Rgb,
    /// The exact z-depth.
    Depth,
}

impl GtKind {
    /// Parses `rgb` or `depth`.
    pub fn parse(s: &str) -> Result<Self, ViewerError> {
        match s {
            "rgb" => Ok(Self::Rgb),
            "depth" => Ok(Self::Depth),
            _ => Err(bad(format!("parameter 'kind' = '{s}': expected rgb or depth"))),
        }
    }
}

/// A frame's ground truth at full resolution, colour composited on `background`.
pub fn truth(frame: &Frame, background: [f32; 3]) -> Result<TruthView, ViewerError> {
    let err = |m: String| eval::EvalError::Input(m);
    load_truth(frame, background, 1, &GroundTruthSource::File, &err).map_err(|e| ViewerError::Internal(e.to_string()))
}
