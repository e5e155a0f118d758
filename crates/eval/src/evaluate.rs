//! Per-view evaluation and aggregation into the `eval.json` report.

use serde::{Deserialize, Serialize};

use crate::error::{EvalError, MetricError};
use crate::metrics::{self, RaySamples};

/// Default off-surface tolerance as a fraction of the scene bounding-box diagonal (1 %).
pub const DEFAULT_SURFACE_TOL_FRACTION: f32 = 0.01;

/// Settings of an evaluation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EvalOptions {
    /// Off-surface tolerance in scene units: samples farther than this from the true
    /// surface along the ray count as off-surface mass (see [`metrics::off_surface_mass`]).
    pub surface_tol: f32,
}

impl EvalOptions {
    /// Options with an explicit off-surface tolerance in scene units.
    pub fn with_surface_tol(surface_tol: f32) -> Self {
        Self { surface_tol }
    }

    /// Options for a scene with the given axis-aligned bounding box: the off-surface
    /// tolerance is [`DEFAULT_SURFACE_TOL_FRACTION`] (1 %) of the box diagonal.
    pub fn for_scene_bbox(min: [f32; 3], max: [f32; 3]) -> Self {
        let d2: f32 = (0..3).map(|i| (max[i] - min[i]) * (max[i] - min[i])).sum();
        Self { surface_tol: DEFAULT_SURFACE_TOL_FRACTION * d2.sqrt() }
    }
}

/// Everything needed to evaluate one test view: the NeRF's renders and the exact ground truth.
///
/// # Shapes
/// `pred_rgb`, `gt_rgb`: `[H * W * 3]` display colour in `[0, 1]`, row-major, row 0 on top.
/// `pred_depth`, `gt_depth` (z-depth), `gt_distance` (Euclidean along the pixel-centre ray),
/// `gt_alpha`, `pred_opacity`: `[H * W]`.
#[derive(Debug, Clone, Copy)]
pub struct ViewInput<'a> {
    /// View name (frame name, e.g. `r_0`); used in the report and in `grid_<name>.png`.
    pub name: &'a str,
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// The NeRF's colour.
    pub pred_rgb: &'a [f32],
    /// Ground-truth colour.
    pub gt_rgb: &'a [f32],
    /// The NeRF's expected z-depth, if it rendered one.
    pub pred_depth: Option<&'a [f32]>,
    /// Ground-truth z-depth (absent for datasets without depth, e.g. Blender synthetic).
    pub gt_depth: Option<&'a [f32]>,
    /// Ground-truth Euclidean distance along each pixel-centre ray (for off-surface mass).
    pub gt_distance: Option<&'a [f32]>,
    /// Ground-truth alpha (coverage of the pixel-centre ray). When absent and `gt_depth`
    /// is present, foreground is taken as `gt_depth > 0`.
    pub gt_alpha: Option<&'a [f32]>,
    /// The NeRF's accumulated opacity `Σ w` (absent for a method that gave none: mask IoU is
    /// then omitted with a note).
    pub pred_opacity: Option<&'a [f32]>,
    /// Per-ray samples and weights, for off-surface mass.
    pub samples: Option<RaySamples<'a>>,
    /// Seconds the NeRF took to render this view.
    pub render_s: f64,
}

/// Metrics of one view (or their mean over views). Absent metrics are omitted from JSON.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ViewMetrics {
    /// PSNR in dB ([`metrics::psnr`]); `+∞` is written as the string `"inf"`.
    #[serde(with = "nonfinite")]
    pub psnr: f64,
    /// SSIM ([`metrics::ssim`]); NaN (`null` in JSON) for an image smaller than its window.
    #[serde(with = "nonfinite")]
    pub ssim: f64,
    /// Mean absolute z-depth error, scene units.
    #[serde(default, skip_serializing_if = "Option::is_none", with = "nonfinite::option")]
    pub depth_mae: Option<f64>,
    /// Root-mean-square z-depth error, scene units.
    #[serde(default, skip_serializing_if = "Option::is_none", with = "nonfinite::option")]
    pub depth_rmse: Option<f64>,
    /// Mean absolute relative z-depth error.
    #[serde(default, skip_serializing_if = "Option::is_none", with = "nonfinite::option")]
    pub depth_abs_rel: Option<f64>,
    /// Fraction of foreground pixels with `max(d/g, g/d) < 1.25`.
    #[serde(default, skip_serializing_if = "Option::is_none", with = "nonfinite::option")]
    pub depth_delta_1_25: Option<f64>,
    /// Fraction of foreground pixels with `max(d/g, g/d) < 1.01`.
    #[serde(default, skip_serializing_if = "Option::is_none", with = "nonfinite::option")]
    pub depth_delta_1_01: Option<f64>,
    /// IoU of `opacity > 0.5` against `alpha > 0.5`.
    #[serde(default, skip_serializing_if = "Option::is_none", with = "nonfinite::option")]
    pub mask_iou: Option<f64>,
    /// Mean fraction of rendering weight farther than the tolerance from the surface.
    #[serde(default, skip_serializing_if = "Option::is_none", with = "nonfinite::option")]
    pub off_surface_mass: Option<f64>,
    /// The part of `off_surface_mass` more than the tolerance in front of the surface
    /// (floaters, fog); the rest lies behind it ([`metrics::off_surface_split`]).
    #[serde(default, skip_serializing_if = "Option::is_none", with = "nonfinite::option")]
    pub off_surface_front: Option<f64>,
    /// Seconds to render the view.
    #[serde(with = "nonfinite")]
    pub render_s_per_view: f64,
}

/// One view's entry in the report: its name, metrics and why any metric is absent.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ViewReport {
    /// View name.
    pub name: String,
    /// The metrics (flattened into the same JSON object as `name`).
    #[serde(flatten)]
    pub metrics: ViewMetrics,
    /// Why metrics are absent, if any are.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub notes: Vec<String>,
    /// Predicted pixels with a non-finite value (absent when every value is finite).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nonfinite: Option<NonFiniteCounts>,
}

/// Facts about the training run that the report carries at the top level.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RunInfo {
    /// Wall-clock training time in seconds.
    pub train_wall_s: f64,
    /// Optimiser steps taken.
    pub train_steps: u64,
    /// Trainable parameters of the model.
    pub parameters: u64,
}

/// The resolution an evaluation measured at.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct EvalResolution {
    /// Width of the evaluated views, pixels.
    pub width: u32,
    /// Height of the evaluated views, pixels.
    pub height: u32,
    /// Integer factor the dataset's images were downscaled by (1: the dataset's full
    /// resolution).
    pub downscale: u32,
    /// The downscale factor the run was trained at (the default evaluation resolution).
    pub train_downscale: u32,
}

impl EvalResolution {
    /// `100x100 (downscale 2, the training resolution)`, or with another factor than the
    /// run's, e.g. `200x200 (full resolution; trained at downscale 2)`.
    pub fn label(&self) -> String {
        let at = if self.downscale == 1 { "full resolution".to_string() } else { format!("downscale {}", self.downscale) };
        if self.downscale == self.train_downscale {
            format!("{}x{} ({at}, the training resolution)", self.width, self.height)
        } else {
            format!("{}x{} ({at}; trained at downscale {})", self.width, self.height, self.train_downscale)
        }
    }
}

/// The content of `eval.json`: per-view metrics, their mean, run facts and notes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    /// Per-view metrics, in input order.
    pub views: Vec<ViewReport>,
    /// Mean of each metric over the views that have it.
    pub mean: ViewMetrics,
    /// Wall-clock training time in seconds (a scored method's stated time; NaN, written
    /// `null`, when not stated).
    #[serde(with = "nonfinite")]
    pub train_wall_s: f64,
    /// Optimiser steps taken (0 for a scored method).
    pub train_steps: u64,
    /// Trainable parameters of the model (0 for a scored method).
    pub parameters: u64,
    /// Off-surface tolerance used, in scene units.
    pub surface_tol: f32,
    /// The resolution the views were evaluated at (absent in reports written before it was
    /// recorded, and from [`evaluate_views`] alone, which does not know the dataset).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resolution: Option<EvalResolution>,
    /// Why metrics are absent or averaged over fewer views.
    #[serde(default)]
    pub notes: Vec<String>,
    /// The extracted mesh against the scene's visible triangles (absent without the scene,
    /// when not asked for, and in reports written before it existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh: Option<crate::mesh_eval::MeshBlock>,
    /// The external method whose predictions `score` read (absent for our runs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub method: Option<MethodInfo>,
    /// Error per object and per material (absent when the dataset has no label files).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub objects: Option<ObjectsBlock>,
    /// The errors of the training poses the run learned from, against the exact ones (runs
    /// trained with `--pose-noise` only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub train_poses: Option<nerf::poses::PoseErrorSummary>,
    /// The errors of the refined training poses (runs trained with `--camera-opt se3`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub refined_poses: Option<nerf::poses::PoseErrorSummary>,
    /// How the test views were posed for the model, for runs whose training poses were noisy
    /// or refined: `aligned` (the exact poses mapped into the model's frame by the similarity
    /// that aligns the training centres) or `aligned+test-pose-opt:N` (then refined for N
    /// steps per view with the model frozen).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pose_protocol: Option<String>,
}

/// What `score` measured: another tool's predictions, how they were found and read
/// (`eval.json`'s `method` block).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MethodInfo {
    /// The method's name, as the user gave it (`--method`).
    pub name: String,
    /// The tool whose output layout was detected: `nerfstudio`, `instant-ngp` or `images`.
    pub tool: String,
    /// Training seconds as the user states them (`null` when not stated).
    #[serde(with = "nonfinite::option")]
    pub train_seconds: Option<f64>,
    /// Hardware as the user states it (`null` when not stated).
    pub hardware: Option<String>,
    /// The layout detected, in words (which folders and file kinds were read).
    pub layout: String,
    /// The predictions folder, as given.
    pub predictions: String,
    /// Every file read, relative to the predictions folder, in view order.
    pub files_read: Vec<String>,
    /// Views of the split without a prediction (only with `--allow-missing`; excluded from
    /// every mean).
    pub missing_views: Vec<String>,
    /// Predicted pixels with a non-finite value, over all views (each left out of the metrics
    /// it would enter).
    pub nonfinite: NonFiniteCounts,
    /// How depth values became metres of z-depth (absent without depth predictions).
    pub depth: Option<DepthConversion>,
    /// The background colour (display RGB) the ground truth and any prediction with alpha were
    /// composited on.
    pub background: [f32; 3],
}

/// Counts of predicted pixels with a non-finite value.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct NonFiniteCounts {
    /// Pixels with a non-finite colour (or alpha) channel.
    pub colour: u64,
    /// Pixels with a non-finite depth.
    pub depth: u64,
    /// Pixels with a non-finite opacity.
    pub opacity: u64,
}

/// How a method's depth files were read as z-depth in metres.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DepthConversion {
    /// `z` (along the camera's −Z axis) or `distance` (along the ray), as read.
    pub kind: String,
    /// Whether the user stated the kind (`--depth-kind`) or it is the layout's convention.
    pub kind_stated: bool,
    /// Metres per file unit the values were multiplied by.
    pub metres_per_unit: f64,
    /// Where that factor comes from.
    pub unit_source: String,
}

fn metric_err(view: &str) -> impl Fn(MetricError) -> EvalError + '_ {
    move |source| EvalError::Metric { view: view.to_string(), source }
}

/// Turn an empty mask into an absent metric with a note; other errors stay errors.
fn optional<T>(
    r: Result<T, MetricError>,
    view: &str,
    notes: &mut Vec<String>,
) -> Result<Option<T>, EvalError> {
    match r {
        Ok(v) => Ok(Some(v)),
        Err(MetricError::EmptyMask(what)) => {
            notes.push(format!("{what}: no foreground pixel or ray with weight, metric omitted"));
            Ok(None)
        }
        Err(e) => Err(metric_err(view)(e)),
    }
}

/// Evaluate one view against its ground truth.
///
/// Colour metrics always; depth metrics when both depths are present; mask IoU when a
/// ground-truth alpha (or depth) and a predicted opacity are present; off-surface mass when
/// samples, distance and a foreground mask are present. Absent metrics come with a note saying
/// why. A non-finite predicted value (NaN, ±inf) is counted and left out of the metric it would
/// enter, counted in [`ViewReport::nonfinite`] with a note: a pixel with a non-finite colour channel leaves PSNR's
/// mean and every SSIM window that touches it ([`metrics::ssim_masked`]), a non-finite depth
/// leaves the depth metrics' foreground, a non-finite opacity leaves mask IoU; with no finite
/// pixel left PSNR is NaN (`null`). Errors (wrong lengths, images smaller than the SSIM window)
/// name the view.
pub fn evaluate_view(v: &ViewInput<'_>, opts: &EvalOptions) -> Result<ViewReport, EvalError> {
    let err = metric_err(v.name);
    let n = v.width * v.height;
    let len = |what: &'static str, got: usize| -> Result<(), EvalError> {
        if got == n {
            Ok(())
        } else {
            Err(err(MetricError::Length { what, expected: n, got }))
        }
    };
    if let Some(o) = v.pred_opacity {
        len("pred_opacity", o.len())?;
    }
    let mut notes = Vec::new();
    let mut nonfinite = NonFiniteCounts::default();
    // A non-finite predicted value is counted and left out of the metric it would enter (see
    // `finite_pixels`): a NaN never turns a mean into NaN, and the note says how many.
    let colour_ok = finite_pixels(v.pred_rgb, 3);
    let (psnr, ssim) = match &colour_ok {
        None => (metrics::psnr(v.pred_rgb, v.gt_rgb).map_err(&err)?, metrics::ssim(v.pred_rgb, v.gt_rgb, v.width, v.height, 3)),
        Some(ok) => {
            for (what, got) in [("pred_rgb", v.pred_rgb.len()), ("gt_rgb", v.gt_rgb.len())] {
                if got != 3 * n {
                    return Err(err(MetricError::Length { what, expected: 3 * n, got }));
                }
            }
            let bad = ok.iter().filter(|k| !**k).count();
            nonfinite.colour = bad as u64;
            notes.push("pixels with a non-finite colour are left out of PSNR and SSIM".into());
            let keep = |x: &[f32]| -> Vec<f32> { x.chunks_exact(3).zip(ok).filter(|(_, k)| **k).flat_map(|(p, _)| p.iter().copied()).collect() };
            let psnr = if bad == n { f64::NAN } else { metrics::psnr(&keep(v.pred_rgb), &keep(v.gt_rgb)).map_err(&err)? };
            (psnr, metrics::ssim_masked(v.pred_rgb, v.gt_rgb, v.width, v.height, 3, ok))
        }
    };
    // An image smaller than SSIM's window (e.g. a small view evaluated at a high downscale)
    // has no SSIM: NaN (`null` in JSON) with a note, the other metrics still count.
    let ssim = match ssim {
        Err(MetricError::TooSmall { width, height, window }) => {
            notes.push(format!("image of {width}x{height} is smaller than SSIM's {window}x{window} window: SSIM omitted"));
            f64::NAN
        }
        Err(MetricError::EmptyMask(_)) => {
            notes.push("no 11x11 window free of non-finite colour: SSIM omitted".into());
            f64::NAN
        }
        other => other.map_err(&err)?,
    };

    let derived_alpha: Option<Vec<f32>> = match (v.gt_alpha, v.gt_depth) {
        (None, Some(d)) => Some(d.iter().map(|&z| if z > 0.0 { 1.0 } else { 0.0 }).collect()),
        _ => None,
    };
    let alpha: Option<&[f32]> = v.gt_alpha.or(derived_alpha.as_deref());
    if let Some(a) = alpha {
        len("gt_alpha", a.len())?;
    }
    if v.gt_alpha.is_none() && derived_alpha.is_some() {
        notes.push("no ground-truth alpha: foreground taken as gt depth > 0".to_string());
    }

    let depth = match (v.pred_depth, v.gt_depth, alpha) {
        (Some(p), Some(g), Some(a)) => {
            len("pred_depth", p.len())?;
            len("gt_depth", g.len())?;
            len("gt_alpha", a.len())?;
            match finite_pixels(p, 1) {
                None => optional(metrics::depth_metrics(p, g, a), v.name, &mut notes)?,
                Some(ok) => {
                    nonfinite.depth = ok.iter().filter(|k| !**k).count() as u64;
                    notes.push("pixels with a non-finite depth are left out of the depth metrics".into());
                    let a: Vec<f32> = a.iter().zip(&ok).map(|(&a, &k)| if k { a } else { 0.0 }).collect();
                    optional(metrics::depth_metrics(p, g, &a), v.name, &mut notes)?
                }
            }
        }
        (_, None, _) => {
            notes.push("no ground-truth depth (e.g. Blender synthetic): depth metrics omitted".into());
            None
        }
        _ => {
            notes.push("the NeRF rendered no depth: depth metrics omitted".into());
            None
        }
    };
    let mask_iou = match (alpha, v.pred_opacity) {
        (Some(a), Some(o)) => match finite_pixels(o, 1) {
            None => Some(metrics::mask_iou(o, a).map_err(&err)?),
            Some(ok) => {
                nonfinite.opacity = ok.iter().filter(|k| !**k).count() as u64;
                notes.push("pixels with a non-finite opacity are left out of mask_iou".into());
                let keep = |x: &[f32]| -> Vec<f32> { x.iter().zip(&ok).filter(|(_, k)| **k).map(|(v, _)| *v).collect() };
                Some(metrics::mask_iou(&keep(o), &keep(a)).map_err(&err)?)
            }
        },
        (None, _) => {
            notes.push("no ground-truth alpha or depth: mask_iou omitted".into());
            None
        }
        (_, None) => {
            notes.push("the method gave no opacity: mask_iou omitted".into());
            None
        }
    };
    let off_surface = match (v.samples, v.gt_distance, alpha) {
        (Some(s), Some(dist), Some(a)) => {
            len("gt_distance", dist.len())?;
            optional(metrics::off_surface_split(&s, dist, a, opts.surface_tol), v.name, &mut notes)?
        }
        (_, None, _) => {
            notes.push("no ground-truth ray distance: off_surface_mass omitted".into());
            None
        }
        (None, _, _) => {
            notes.push("no per-ray samples given: off_surface_mass omitted".into());
            None
        }
        _ => {
            notes.push("no ground-truth alpha or depth: off_surface_mass omitted".into());
            None
        }
    };
    Ok(ViewReport {
        name: v.name.to_string(),
        metrics: ViewMetrics {
            psnr,
            ssim,
            depth_mae: depth.map(|d| d.mae),
            depth_rmse: depth.map(|d| d.rmse),
            depth_abs_rel: depth.map(|d| d.abs_rel),
            depth_delta_1_25: depth.map(|d| d.delta_1_25),
            depth_delta_1_01: depth.map(|d| d.delta_1_01),
            mask_iou,
            off_surface_mass: off_surface.map(|o| o.total),
            off_surface_front: off_surface.map(|o| o.front),
            render_s_per_view: v.render_s,
        },
        notes,
        nonfinite: (nonfinite != NonFiniteCounts::default()).then_some(nonfinite),
    })
}

/// `None` when every value is finite; otherwise, per pixel of `channels` values, whether all of
/// them are finite.
fn finite_pixels(values: &[f32], channels: usize) -> Option<Vec<bool>> {
    if values.iter().all(|v| v.is_finite()) {
        return None;
    }
    Some(values.chunks_exact(channels).map(|p| p.iter().all(|v| v.is_finite())).collect())
}

fn mean(values: impl Iterator<Item = f64>) -> Option<f64> {
    let (sum, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    (n > 0).then(|| sum / n as f64)
}

impl ViewMetrics {
    /// Mean of each metric over the views that have it (an optional metric is absent only
    /// when no view has it; a view without a finite pixel has a NaN PSNR and is left out).
    /// PSNR is the mean of per-view PSNR, as NeRF papers report it (so one identical view
    /// makes the mean `+∞`). `None` for an empty slice.
    pub fn mean(views: &[ViewMetrics]) -> Option<ViewMetrics> {
        if views.is_empty() {
            return None;
        }
        let opt = |f: fn(&ViewMetrics) -> Option<f64>| mean(views.iter().filter_map(f));
        Some(ViewMetrics {
            psnr: mean(views.iter().map(|v| v.psnr).filter(|p| !p.is_nan())).unwrap_or(f64::NAN),
            ssim: mean(views.iter().map(|v| v.ssim).filter(|s| !s.is_nan())).unwrap_or(f64::NAN),
            depth_mae: opt(|v| v.depth_mae),
            depth_rmse: opt(|v| v.depth_rmse),
            depth_abs_rel: opt(|v| v.depth_abs_rel),
            depth_delta_1_25: opt(|v| v.depth_delta_1_25),
            depth_delta_1_01: opt(|v| v.depth_delta_1_01),
            mask_iou: opt(|v| v.mask_iou),
            off_surface_mass: opt(|v| v.off_surface_mass),
            off_surface_front: opt(|v| v.off_surface_front),
            render_s_per_view: mean(views.iter().map(|v| v.render_s_per_view))?,
        })
    }

    /// `(key, value)` for every present metric, in the report's key order.
    pub fn entries(&self) -> Vec<(&'static str, f64)> {
        let mut out = vec![("psnr", self.psnr), ("ssim", self.ssim)];
        let opt = [
            ("depth_mae", self.depth_mae),
            ("depth_rmse", self.depth_rmse),
            ("depth_abs_rel", self.depth_abs_rel),
            ("depth_delta_1_25", self.depth_delta_1_25),
            ("depth_delta_1_01", self.depth_delta_1_01),
            ("mask_iou", self.mask_iou),
            ("off_surface_mass", self.off_surface_mass),
            ("off_surface_front", self.off_surface_front),
        ];
        out.extend(opt.into_iter().filter_map(|(k, v)| v.map(|v| (k, v))));
        // Unknown for a scored method's files.
        if !self.render_s_per_view.is_nan() {
            out.push(("render_s_per_view", self.render_s_per_view));
        }
        out
    }
}

impl EvalReport {
    /// Aggregate per-view reports. The report's notes list each distinct per-view note
    /// with the number of views it applies to, and say when a metric's mean runs over
    /// fewer views than the report has.
    pub fn new(views: Vec<ViewReport>, run: RunInfo, opts: &EvalOptions) -> Result<Self, EvalError> {
        let metrics: Vec<ViewMetrics> = views.iter().map(|v| v.metrics.clone()).collect();
        let mean = ViewMetrics::mean(&metrics)
            .ok_or_else(|| EvalError::Input("no views to evaluate".into()))?;
        let mut notes: Vec<String> = Vec::new();
        let mut counts: Vec<(String, usize)> = Vec::new();
        for note in views.iter().flat_map(|v| &v.notes) {
            match counts.iter_mut().find(|(n, _)| n == note) {
                Some((_, c)) => *c += 1,
                None => counts.push((note.clone(), 1)),
            }
        }
        for (note, c) in counts {
            notes.push(format!("{note} ({c} of {} views)", views.len()));
        }
        let present = |f: fn(&ViewMetrics) -> Option<f64>| metrics.iter().filter(|m| f(m).is_some()).count();
        for (key, k) in [
            ("psnr", metrics.iter().filter(|m| !m.psnr.is_nan()).count()),
            ("depth_mae", present(|m| m.depth_mae)),
            ("mask_iou", present(|m| m.mask_iou)),
            ("off_surface_mass", present(|m| m.off_surface_mass)),
        ] {
            if k > 0 && k < metrics.len() {
                notes.push(format!("mean {key} is over {k} of {} views", metrics.len()));
            }
        }
        if !mean.psnr.is_finite() {
            notes.push("a view matches its ground truth exactly, so PSNR is +inf (written \"inf\")".into());
        }
        Ok(Self {
            views,
            mean,
            train_wall_s: run.train_wall_s,
            train_steps: run.train_steps,
            parameters: run.parameters,
            surface_tol: opts.surface_tol,
            resolution: None,
            notes,
            mesh: None,
            method: None,
            objects: None,
            train_poses: None,
            refined_poses: None,
            pose_protocol: None,
        })
    }
}

/// Evaluate every view and aggregate them into an [`EvalReport`].
pub fn evaluate_views(
    views: &[ViewInput<'_>],
    run: RunInfo,
    opts: &EvalOptions,
) -> Result<EvalReport, EvalError> {
    let reports = views.iter().map(|v| evaluate_view(v, opts)).collect::<Result<Vec<_>, _>>()?;
    EvalReport::new(reports, run, opts)
}

/// Serde for an `f64` that may be infinite: finite values are JSON numbers, `+∞` / `−∞`
/// the strings `"inf"` / `"-inf"`, NaN is `null`. Reading accepts all of these.
pub mod nonfinite {
    use serde::{Deserialize, Deserializer, Serializer};

    /// Write `v` as a number, `"inf"`, `"-inf"` or `null`.
    pub fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        if v.is_finite() {
            s.serialize_f64(*v)
        } else if v.is_nan() {
            s.serialize_none()
        } else if *v > 0.0 {
            s.serialize_str("inf")
        } else {
            s.serialize_str("-inf")
        }
    }

    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Repr {
        Num(f64),
        Str(String),
        Null(()),
    }

    /// Read a number, `"inf"`, `"-inf"` or `null` (NaN).
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        match Repr::deserialize(d)? {
            Repr::Num(v) => Ok(v),
            Repr::Null(()) => Ok(f64::NAN),
            Repr::Str(s) => match s.as_str() {
                "inf" | "+inf" | "Infinity" => Ok(f64::INFINITY),
                "-inf" | "-Infinity" => Ok(f64::NEG_INFINITY),
                other => Err(serde::de::Error::custom(format!("expected a number or \"inf\", got {other:?}"))),
            },
        }
    }

    /// Write an optional value: `None` as `null`, else as [`serialize`].
    pub mod option {
        use serde::{Deserialize, Deserializer, Serializer};

        /// Write `None` as `null`, else as [`super::serialize`].
        pub fn serialize<S: Serializer>(v: &Option<f64>, s: S) -> Result<S::Ok, S::Error> {
            match v {
                Some(v) => super::serialize(v, s),
                None => s.serialize_none(),
            }
        }

        #[derive(Deserialize)]
        struct Wrap(#[serde(with = "super")] f64);

        /// Read `null` as `None`, else as [`super::deserialize`].
        pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
            Ok(Option::<Wrap>::deserialize(d)?.map(|w| w.0))
        }
    }
}

/// One object's or material's error over the evaluated views (`eval.json`'s `objects` block).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LabelError {
    /// Object ID (or material ID) as in the label files; 0 = the background.
    pub id: u32,
    /// Node (or material) name from the scene facts.
    pub name: String,
    /// Pixels whose centre ray hit it.
    pub pixels: u64,
    /// Of those, edge pixels (not every image sample hit it).
    pub edge_pixels: u64,
    /// PSNR over all its pixels, dB (capped at 100 dB).
    pub psnr: f64,
    /// PSNR over its interior pixels.
    pub psnr_interior: Option<f64>,
    /// PSNR over its edge pixels.
    pub psnr_edge: Option<f64>,
    /// Mean absolute z-depth error over its foreground pixels, scene units.
    pub depth_mae: Option<f64>,
    /// Mean off-surface weight fraction over its foreground rays.
    pub off_surface_mass: Option<f64>,
    /// The part of it in front of the surface.
    pub off_surface_front: Option<f64>,
    /// Mesh accuracy restricted to this object: the mean distance to the true surface of the
    /// extracted mesh's samples whose closest true triangle is this object's, m (objects only,
    /// when `eval` measured the mesh).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh_accuracy: Option<f64>,
    /// Mesh completeness restricted to this object: the mean distance to the extracted mesh of
    /// the samples of this object's visible true surface, m.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh_completeness: Option<f64>,
}

/// Error per object and per material (`eval.json`'s `objects` block).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ObjectsBlock {
    /// Views the sums run over.
    pub views: usize,
    /// Per object, worst PSNR first.
    pub objects: Vec<LabelError>,
    /// Per material, worst PSNR first.
    pub materials: Vec<LabelError>,
    /// The PSNR range (dB) of the per-object picture's colours, when it was written.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub picture_psnr: Option<[f64; 2]>,
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Fixture {
        w: usize,
        h: usize,
        gt_rgb: Vec<f32>,
        pred_rgb: Vec<f32>,
        gt_depth: Vec<f32>,
        pred_depth: Vec<f32>,
        gt_alpha: Vec<f32>,
        opacity: Vec<f32>,
        pixel: Vec<usize>,
        offsets: Vec<usize>,
        t: Vec<f32>,
        wts: Vec<f32>,
    }

    /// 16x12 view; the left 4 columns are background. Colour off by 0.1 everywhere; depth off
    /// by +0.1 on foreground; every foreground ray has 0.75 of its weight at the surface and
    /// 0.25 on a floater 1 unit in front.
    fn fixture() -> Fixture {
        let (w, h) = (16, 12);
        let n = w * h;
        let gt_rgb: Vec<f32> = (0..n * 3).map(|i| 0.2 + 0.5 * ((i * 13) % 17) as f32 / 17.0).collect();
        let pred_rgb = gt_rgb.iter().map(|v| v + 0.1).collect();
        let fg = |i: usize| i % w >= 4;
        let gt_alpha: Vec<f32> = (0..n).map(|i| if fg(i) { 1.0 } else { 0.0 }).collect();
        let gt_depth: Vec<f32> = (0..n).map(|i| if fg(i) { 2.0 + (i / w) as f32 * 0.1 } else { 0.0 }).collect();
        let pred_depth = gt_depth.iter().map(|d| d + 0.1).collect();
        let mut offsets = vec![0];
        let (mut t, mut wts) = (Vec::new(), Vec::new());
        for &d in &gt_depth {
            t.extend([d - 1.0, d]);
            wts.extend([0.25, 0.75]);
            offsets.push(t.len());
        }
        Fixture {
            w,
            h,
            gt_rgb,
            pred_rgb,
            gt_depth,
            pred_depth,
            opacity: gt_alpha.clone(),
            gt_alpha,
            pixel: (0..n).collect(),
            offsets,
            t,
            wts,
        }
    }

    fn view<'a>(f: &'a Fixture, name: &'a str) -> ViewInput<'a> {
        ViewInput {
            name,
            width: f.w,
            height: f.h,
            pred_rgb: &f.pred_rgb,
            gt_rgb: &f.gt_rgb,
            pred_depth: Some(&f.pred_depth),
            gt_depth: Some(&f.gt_depth),
            // the camera looks straight at the surface in this fixture: distance = depth
            gt_distance: Some(&f.gt_depth),
            gt_alpha: Some(&f.gt_alpha),
            pred_opacity: Some(&f.opacity),
            samples: Some(RaySamples { pixel: &f.pixel, offsets: &f.offsets, t: &f.t, w: &f.wts }),
            render_s: 0.5,
        }
    }

    const RUN: RunInfo = RunInfo { train_wall_s: 12.5, train_steps: 300, parameters: 4096 };

    #[test]
    fn full_view_metrics() {
        let f = fixture();
        let r = evaluate_view(&view(&f, "r_0"), &EvalOptions::with_surface_tol(0.05)).unwrap();
        let m = &r.metrics;
        assert!((m.psnr - 20.0).abs() < 1e-4);
        let s = metrics::ssim(&f.pred_rgb, &f.gt_rgb, f.w, f.h, 3).unwrap();
        assert_eq!(m.ssim, s);
        assert!((m.depth_mae.unwrap() - 0.1).abs() < 1e-6);
        assert!((m.depth_rmse.unwrap() - 0.1).abs() < 1e-6);
        assert_eq!(m.depth_delta_1_25, Some(1.0));
        assert_eq!(m.depth_delta_1_01, Some(0.0));
        assert_eq!(m.mask_iou, Some(1.0));
        assert!((m.off_surface_mass.unwrap() - 0.25).abs() < 1e-7);
        assert!(r.notes.is_empty(), "{:?}", r.notes);
    }

    #[test]
    fn blender_style_view_has_no_depth_keys_and_says_why() {
        let f = fixture();
        let mut v = view(&f, "r_1");
        v.gt_depth = None;
        v.gt_distance = None;
        v.samples = None;
        let report = evaluate_views(&[v], RUN, &EvalOptions::with_surface_tol(0.05)).unwrap();
        assert!(report.mean.depth_mae.is_none());
        assert_eq!(report.mean.mask_iou, Some(1.0)); // alpha still available
        let json = serde_json::to_value(&report).unwrap();
        for key in ["depth_mae", "depth_rmse", "depth_abs_rel", "depth_delta_1_25", "depth_delta_1_01", "off_surface_mass"] {
            assert!(json["mean"].get(key).is_none(), "{key} present");
            assert!(json["views"][0].get(key).is_none(), "{key} present");
        }
        for key in ["psnr", "ssim", "mask_iou", "render_s_per_view"] {
            assert!(json["mean"][key].is_number(), "{key}");
        }
        assert_eq!(json["views"][0]["name"], "r_1");
        assert_eq!(json["train_steps"], 300);
        assert_eq!(json["parameters"], 4096);
        assert_eq!(json["train_wall_s"], 12.5);
        let notes = json["notes"].as_array().unwrap();
        assert!(notes.iter().any(|n| n.as_str().unwrap().contains("no ground-truth depth")), "{notes:?}");
    }

    #[test]
    fn report_json_roundtrip_and_infinite_psnr() {
        let f = fixture();
        let mut exact = view(&f, "exact");
        exact.pred_rgb = &f.gt_rgb;
        let report =
            evaluate_views(&[view(&f, "a"), exact], RUN, &EvalOptions::with_surface_tol(0.05)).unwrap();
        assert_eq!(report.views[1].metrics.psnr, f64::INFINITY);
        assert_eq!(report.mean.psnr, f64::INFINITY);
        let text = serde_json::to_string_pretty(&report).unwrap();
        assert!(text.contains("\"psnr\": \"inf\""), "{text}");
        let back: EvalReport = serde_json::from_str(&text).unwrap();
        // serde_json's default float parsing may differ in the last bit, so compare closely
        assert_eq!(back.views.len(), 2);
        assert_eq!(back.views[1].name, "exact");
        assert_eq!(back.mean.psnr, f64::INFINITY);
        assert!((back.views[0].metrics.psnr - report.views[0].metrics.psnr).abs() < 1e-12);
        assert!((back.mean.ssim - report.mean.ssim).abs() < 1e-12);
        assert_eq!(back.mean.off_surface_mass, report.mean.off_surface_mass);
        assert_eq!(back.notes, report.notes);
        // a NaN metric (a broken NeRF) survives as null instead of failing to serialise
        let mut broken = report.mean.clone();
        broken.ssim = f64::NAN;
        broken.depth_mae = Some(f64::INFINITY);
        let text = serde_json::to_string(&broken).unwrap();
        assert!(text.contains("\"ssim\":null") && text.contains("\"depth_mae\":\"inf\""), "{text}");
        let back: ViewMetrics = serde_json::from_str(&text).unwrap();
        assert!(back.ssim.is_nan());
        assert_eq!(back.depth_mae, Some(f64::INFINITY));
    }

    #[test]
    fn mean_runs_over_views_that_have_the_metric() {
        let f = fixture();
        let mut no_samples = view(&f, "b");
        no_samples.samples = None;
        let report =
            evaluate_views(&[view(&f, "a"), no_samples], RUN, &EvalOptions::with_surface_tol(0.05)).unwrap();
        assert!((report.mean.off_surface_mass.unwrap() - 0.25).abs() < 1e-7);
        assert!(report.notes.iter().any(|n| n.contains("mean off_surface_mass is over 1 of 2 views")), "{:?}", report.notes);
        assert!(report.notes.iter().any(|n| n.contains("no per-ray samples given") && n.contains("(1 of 2 views)")));
    }

    #[test]
    fn depth_without_alpha_uses_depth_as_mask() {
        let f = fixture();
        let mut v = view(&f, "c");
        v.gt_alpha = None;
        let r = evaluate_view(&v, &EvalOptions::with_surface_tol(0.05)).unwrap();
        assert!((r.metrics.depth_mae.unwrap() - 0.1).abs() < 1e-6);
        assert_eq!(r.metrics.mask_iou, Some(1.0));
        assert!(r.notes.iter().any(|n| n.contains("foreground taken as gt depth > 0")));
    }

    #[test]
    fn wrong_lengths_are_errors_naming_the_view() {
        let f = fixture();
        let mut v = view(&f, "bad_view");
        v.pred_depth = Some(&f.pred_depth[1..]);
        let e = evaluate_view(&v, &EvalOptions::with_surface_tol(0.05)).unwrap_err();
        assert!(e.to_string().contains("bad_view") && e.to_string().contains("pred_depth"), "{e}");
        assert!(evaluate_views(&[], RUN, &EvalOptions::with_surface_tol(0.05)).is_err());
    }

    /// A NaN colour, an infinite depth and a NaN opacity are counted and left out of the
    /// metrics they would enter: the rest of the view is still off by exactly 0.1 in colour and
    /// depth, and its masks still agree.
    #[test]
    fn non_finite_predictions_are_counted_and_left_out() {
        let mut f = fixture();
        f.pred_rgb[3 * 17 + 1] = f32::NAN;
        f.pred_depth[40] = f32::INFINITY; // a foreground pixel (column 8)
        f.opacity[5] = f32::NAN;
        let r = evaluate_view(&view(&f, "nan"), &EvalOptions::with_surface_tol(0.05)).unwrap();
        let m = &r.metrics;
        assert!((m.psnr - 20.0).abs() < 1e-4, "{}", m.psnr);
        assert!(m.ssim.is_finite());
        assert!((m.depth_mae.unwrap() - 0.1).abs() < 1e-6);
        assert_eq!(m.mask_iou, Some(1.0));
        assert_eq!(r.nonfinite, Some(NonFiniteCounts { colour: 1, depth: 1, opacity: 1 }));
        assert_eq!(r.notes.len(), 3, "{:?}", r.notes);
        // A view without a finite colour: PSNR and SSIM NaN, left out of the mean with a note.
        let mut g = fixture();
        g.pred_rgb.fill(f32::NAN);
        let report = evaluate_views(&[view(&f, "a"), view(&g, "b")], RUN, &EvalOptions::with_surface_tol(0.05)).unwrap();
        assert!(report.views[1].metrics.psnr.is_nan() && report.views[1].metrics.ssim.is_nan());
        assert!((report.mean.psnr - 20.0).abs() < 1e-4);
        assert!(report.notes.iter().any(|n| n == "mean psnr is over 1 of 2 views"), "{:?}", report.notes);
        let json = serde_json::to_value(&report).unwrap();
        assert_eq!(json["views"][1]["psnr"], serde_json::Value::Null);
        assert_eq!(json["views"][0]["nonfinite"]["colour"], 1);
        // Finite predictions keep the per-view JSON as it was: no nonfinite key.
        let clean = evaluate_views(&[view(&fixture(), "c")], RUN, &EvalOptions::with_surface_tol(0.05)).unwrap();
        assert!(serde_json::to_value(&clean).unwrap()["views"][0].get("nonfinite").is_none());
    }

    #[test]
    fn a_method_without_opacity_has_no_mask_iou_and_says_why() {
        let f = fixture();
        let mut v = view(&f, "rgb-only");
        v.pred_opacity = None;
        v.samples = None;
        let r = evaluate_view(&v, &EvalOptions::with_surface_tol(0.05)).unwrap();
        assert_eq!(r.metrics.mask_iou, None);
        assert!((r.metrics.depth_mae.unwrap() - 0.1).abs() < 1e-6);
        assert!(r.notes.iter().any(|n| n == "the method gave no opacity: mask_iou omitted"), "{:?}", r.notes);
    }

    #[test]
    fn tolerance_from_bbox_is_one_percent_of_diagonal() {
        let o = EvalOptions::for_scene_bbox([-1.0, -2.0, 0.0], [2.0, 2.0, 12.0]);
        assert!((o.surface_tol - 0.13).abs() < 1e-6); // diagonal sqrt(9 + 16 + 144) = 13
    }
}
