//! Noisy training poses: the hard case of poses estimated by structure-from-motion, made on
//! purpose and recorded, so that what it costs is measured against the exact poses.
//!
//! `--pose-noise ROT_DEG,TRANS_REL` turns every training view's camera-to-world pose about its
//! centre by an angle drawn with standard deviation `ROT_DEG` degrees about a uniform random
//! axis, and moves its centre by a Gaussian vector whose root-mean-square length is
//! `TRANS_REL` × the scene size ([`scene_size`]); [`dataset::pose::perturb`] draws both as a
//! pure function of (seed, view). Validation and test views keep their exact poses. The run
//! folder's [`POSES_FILE`] records, per training view, the pose trained on and the true one;
//! `eval` reports their difference after the similarity that best aligns them
//! ([`dataset::pose::pose_errors`]).

use dataset::{Dataset, Frame};
use glam::DMat4;
use serde::{Deserialize, Serialize};

/// The run folder's record of the training poses ([`PoseRecord`]).
pub const POSES_FILE: &str = "train_poses.json";
/// The refined training poses as nerfstudio's `ns-export cameras` writes them: a list of
/// `{"file_path", "transform"}` with the 3 × 4 camera-to-world rows (the dataset's frame and
/// OpenGL camera axes).
pub const CAMERA_OPT_EXPORT: &str = "cameras_refined.json";

/// The largest rotation noise accepted, degrees (beyond it the poses are not "noisy", they
/// are wrong).
pub const MAX_ROTATION_DEG: f64 = 45.0;
/// The largest translation noise accepted, as a fraction of the scene size.
pub const MAX_TRANSLATION_REL: f64 = 1.0;

/// Pose noise: standard deviation of the rotation angle (degrees) and RMS centre shift as a
/// fraction of the scene size.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseNoise {
    /// Standard deviation of the rotation angle, degrees.
    pub rotation_deg: f64,
    /// RMS length of the centre's shift over the scene size.
    pub translation_rel: f64,
}

impl std::str::FromStr for PoseNoise {
    type Err = String;
    /// `ROT_DEG,TRANS_REL`, e.g. `1,0.01`: finite, non-negative, at most 45° and 1 (100 %).
    fn from_str(s: &str) -> Result<Self, String> {
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        let [rot, trans] = parts.as_slice() else {
            return Err(format!("'{s}' is not ROT_DEG,TRANS_REL (e.g. 1,0.01: 1° rotation, 1 % of the scene size)"));
        };
        let num = |v: &str, what: &str| -> Result<f64, String> {
            match v.parse::<f64>() {
                Ok(x) if x.is_finite() && x >= 0.0 => Ok(x),
                _ => Err(format!("'{s}': the {what} '{v}' is not a finite number ≥ 0")),
            }
        };
        let (rotation_deg, translation_rel) = (num(rot, "rotation")?, num(trans, "translation")?);
        if rotation_deg > MAX_ROTATION_DEG {
            return Err(format!("'{s}': a rotation noise of {rotation_deg}° is over {MAX_ROTATION_DEG}°: such poses are wrong, not noisy"));
        }
        if translation_rel > MAX_TRANSLATION_REL {
            return Err(format!("'{s}': a translation noise of {translation_rel} is over {MAX_TRANSLATION_REL} (100 % of the scene size)"));
        }
        Ok(Self { rotation_deg, translation_rel })
    }
}

/// The scene size translations are relative to: the diagonal of the scene facts' box, or
/// without facts the largest distance between two training camera centres.
pub fn scene_size(ds: &Dataset) -> f64 {
    if let Some(f) = &ds.facts {
        let d = (0..3).map(|k| (f.aabb_max[k] - f.aabb_min[k]).powi(2)).sum::<f64>().sqrt();
        if d > 0.0 && d.is_finite() {
            return d;
        }
    }
    let c: Vec<glam::DVec3> = ds.train.iter().map(|f| f.camera.origin()).collect();
    c.iter().flat_map(|a| c.iter().map(move |b| (*a - *b).length())).fold(0.0, f64::max)
}

/// One training view's pose as trained on and as it truly is (camera-to-world, row by row).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseView {
    /// The frame's name (`r_0`).
    pub name: String,
    /// The pose the run trained on.
    pub trained: [[f64; 4]; 4],
    /// The dataset's exact pose.
    pub truth: [[f64; 4]; 4],
    /// The pose after camera refinement ([`crate::camera_opt`]), when the run refines.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub refined: Option<[[f64; 4]; 4]>,
    /// The refinement's correction `[ω (radians), τ (scene sizes)]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub correction: Option<[f32; 6]>,
}

/// The contents of [`POSES_FILE`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseRecord {
    /// The noise applied.
    pub noise: PoseNoise,
    /// The scene size the translation noise is relative to.
    pub scene_size: f64,
    /// Per training view, in the dataset's order.
    pub views: Vec<PoseView>,
}

fn rows(m: &DMat4) -> [[f64; 4]; 4] {
    let c = m.to_cols_array_2d();
    std::array::from_fn(|r| std::array::from_fn(|k| c[k][r]))
}

/// Row-major `[[f64; 4]; 4]` back to a matrix.
pub fn from_rows(r: &[[f64; 4]; 4]) -> DMat4 {
    DMat4::from_cols_array_2d(&std::array::from_fn(|k| std::array::from_fn(|i| r[i][k])))
}

/// Applies `noise` to the training views of `ds` (seeded by `seed`, keyed by view index) and
/// returns the record of both poses. Zero noise leaves the poses bit for bit.
pub fn perturb_training_views(ds: &mut Dataset, noise: PoseNoise, seed: u64) -> PoseRecord {
    let size = scene_size(ds);
    let views = ds
        .train
        .iter_mut()
        .enumerate()
        .map(|(k, f): (usize, &mut Frame)| {
            let truth = f.camera.c2w;
            f.camera.c2w = dataset::pose::perturb(&truth, seed, k as u64, noise.rotation_deg, noise.translation_rel * size);
            PoseView { name: f.name.clone(), trained: rows(&f.camera.c2w), truth: rows(&truth), refined: None, correction: None }
        })
        .collect();
    PoseRecord { noise, scene_size: size, views }
}

/// Rotation and translation errors of the trained poses against the true ones, after the
/// similarity that best aligns the camera centres ([`dataset::pose::pose_errors`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseErrorSummary {
    /// Training views.
    pub views: usize,
    /// Median rotation error, degrees.
    pub rotation_median_deg: f64,
    /// Largest rotation error, degrees.
    pub rotation_max_deg: f64,
    /// Median centre error, scene units.
    pub translation_median: f64,
    /// Largest centre error, scene units.
    pub translation_max: f64,
    /// The median centre error as a percentage of the scene size.
    pub translation_median_pct: f64,
}

impl PoseRecord {
    /// The record with each view's refined pose `refine(view, trained pose)` and correction.
    pub fn with_refined(&self, refine: impl Fn(usize, &DMat4) -> DMat4, corrections: Vec<[f32; 6]>) -> Self {
        let mut r = self.clone();
        for (k, v) in r.views.iter_mut().enumerate() {
            v.refined = Some(rows(&refine(k, &from_rows(&v.trained))));
            v.correction = corrections.get(k).copied();
        }
        r
    }

    /// The refined poses (else the trained ones) in nerfstudio's camera export layout
    /// ([`CAMERA_OPT_EXPORT`]).
    pub fn nerfstudio_export(&self) -> serde_json::Value {
        serde_json::Value::Array(
            self.views
                .iter()
                .map(|v| {
                    let m = v.refined.unwrap_or(v.trained);
                    serde_json::json!({ "file_path": v.name, "transform": [m[0], m[1], m[2]] })
                })
                .collect(),
        )
    }

    /// Whether the record holds refined poses.
    pub fn is_refined(&self) -> bool {
        self.views.iter().all(|v| v.refined.is_some()) && !self.views.is_empty()
    }

    /// The errors of the poses trained on (`None` with fewer than 3 views, where no similarity
    /// is determined).
    pub fn errors(&self) -> Option<PoseErrorSummary> {
        self.errors_of(|v| v.trained)
    }

    /// The errors of the refined poses (`None` when the run did not refine, or with fewer than
    /// 3 views).
    pub fn refined_errors(&self) -> Option<PoseErrorSummary> {
        if !self.is_refined() {
            return None;
        }
        self.errors_of(|v| v.refined.unwrap_or(v.trained))
    }

    /// The similarity taking the dataset's frame to the frame the model learned in: the inverse
    /// of the one aligning the refined (else trained) centres to the true ones.
    pub fn truth_to_model(&self) -> Option<dataset::pose::Similarity> {
        let est: Vec<glam::DVec3> = self.views.iter().map(|v| from_rows(&v.refined.unwrap_or(v.trained)).w_axis.truncate()).collect();
        let truth: Vec<glam::DVec3> = self.views.iter().map(|v| from_rows(&v.truth).w_axis.truncate()).collect();
        dataset::pose::align_similarity(&truth, &est).ok()
    }

    fn errors_of(&self, pose: impl Fn(&PoseView) -> [[f64; 4]; 4]) -> Option<PoseErrorSummary> {
        let trained: Vec<DMat4> = self.views.iter().map(|v| from_rows(&pose(v))).collect();
        let truth: Vec<DMat4> = self.views.iter().map(|v| from_rows(&v.truth)).collect();
        let e = dataset::pose::pose_errors(&trained, &truth).ok()?;
        let max = |v: &[f64]| v.iter().copied().fold(0.0, f64::max);
        let tm = dataset::pose::median(&e.translation);
        Some(PoseErrorSummary {
            views: self.views.len(),
            rotation_median_deg: dataset::pose::median(&e.rotation_deg),
            rotation_max_deg: max(&e.rotation_deg),
            translation_median: tm,
            translation_max: max(&e.translation),
            translation_median_pct: 100.0 * tm / self.scene_size.max(f64::MIN_POSITIVE),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_parses_and_bad_values_are_refused_naming_the_part() {
        assert_eq!("1,0.01".parse::<PoseNoise>().unwrap(), PoseNoise { rotation_deg: 1.0, translation_rel: 0.01 });
        assert_eq!(" 0 , 0 ".parse::<PoseNoise>().unwrap(), PoseNoise { rotation_deg: 0.0, translation_rel: 0.0 });
        for (bad, says) in [("1", "ROT_DEG,TRANS_REL"), ("-1,0", "rotation"), ("NaN,0", "rotation"), ("1,inf", "translation"), ("46,0", "45"), ("1,1.5", "100 %"), ("1,0,2", "ROT_DEG")] {
            let e = bad.parse::<PoseNoise>().unwrap_err();
            assert!(e.contains(says), "{bad}: {e}");
        }
    }

    #[test]
    fn rows_round_trip() {
        let m = DMat4::from_cols_array(&std::array::from_fn(|k| k as f64 * 0.5 - 3.0));
        assert_eq!(from_rows(&rows(&m)), m);
        assert_eq!(rows(&m)[0][3], m.w_axis.x, "row 0, column 3 is the x translation");
    }
}
