//! What `eval` (views rendered by our run) and `score` (views read from another tool's files)
//! share once a view's prediction exists: the ground truth at the evaluated resolution
//! ([`crate::truth`]), the per-view metrics ([`crate::evaluate::evaluate_view`]), the views kept
//! for picture grids, and the report folder's files (`eval.json`, `report.json`, `report.md`,
//! the grids) with what an earlier report left removed. Both paths go through
//! [`evaluate_frames`] and [`write_outputs`], so a prediction is measured by exactly the same
//! code whichever produced it.

use crate::compare::RunSummary;
use crate::curve::MetricsRecord;
use crate::evaluate::{EvalOptions, EvalResolution, ViewInput, ViewReport, evaluate_view};
use crate::metrics::RaySamples;
use crate::report::write_report;
use crate::truth::{ErrorContext, GroundTruthSource, TruthView, load_truth};
use crate::EvalError;
use dataset::Frame;
use std::path::{Path, PathBuf};

/// Per-ray samples of a prediction, for the off-surface mass (owned; see [`RaySamples`]).
#[derive(Clone, Debug)]
pub struct Samples {
    /// Pixel index of each ray.
    pub pixel: Vec<usize>,
    /// Ray `r`'s samples are `offsets[r]..offsets[r + 1]`.
    pub offsets: Vec<usize>,
    /// Sample distances along the ray.
    pub t: Vec<f32>,
    /// Sample weights.
    pub w: Vec<f32>,
}

/// One view's prediction at the evaluated resolution.
///
/// # Shapes
/// `rgb`: `[H * W * 3]` display colour (composited on the evaluation background); `depth`
/// (z-depth, metres), `opacity`: `[H * W]`.
#[derive(Clone, Debug)]
pub struct Prediction {
    /// Colour.
    pub rgb: Vec<f32>,
    /// z-depth, when the method gave one.
    pub depth: Option<Vec<f32>>,
    /// Accumulated opacity, when the method gave one.
    pub opacity: Option<Vec<f32>>,
    /// Per-ray samples (our runs only).
    pub samples: Option<Samples>,
    /// Seconds the view took to render (NaN when unknown).
    pub render_s: f64,
}

/// The metric inputs of a view: its ground truth and its prediction.
pub fn view_input<'a>(t: &'a TruthView, p: &'a Prediction) -> ViewInput<'a> {
    let samples = p.samples.as_ref().filter(|s| s.offsets.len() == s.pixel.len() + 1).map(|s| RaySamples {
        pixel: &s.pixel,
        offsets: &s.offsets,
        t: &s.t,
        w: &s.w,
    });
    ViewInput {
        name: &t.name,
        width: t.width,
        height: t.height,
        pred_rgb: &p.rgb,
        gt_rgb: &t.gt_rgb,
        pred_depth: t.gt.as_ref().and(p.depth.as_deref()),
        gt_depth: t.gt.as_ref().map(|g| g.depth.as_slice()),
        gt_distance: t.gt.as_ref().map(|g| g.distance.as_slice()),
        gt_alpha: t.gt.as_ref().map(|g| g.alpha.as_slice()),
        pred_opacity: p.opacity.as_deref(),
        samples: t.gt.as_ref().and(samples),
        render_s: p.render_s,
    }
}

/// The settings every view of an evaluation shares.
pub struct FrameSettings<'a> {
    /// Background the ground truth is composited on.
    pub background: [f32; 3],
    /// The evaluated downscale of the dataset's images.
    pub downscale: u32,
    /// The downscale recorded as the method's own (a run's training downscale).
    pub train_downscale: u32,
    /// Where depth / distance / normal / alpha come from.
    pub source: &'a GroundTruthSource,
    /// The off-surface tolerance.
    pub options: &'a EvalOptions,
    /// How many views (the first ones) are kept for picture grids.
    pub grid_views: usize,
    /// How errors about dataset files are reported.
    pub err: ErrorContext<'a>,
}

/// The per-view reports, the views kept for grids and the resolution measured at.
pub struct Evaluated {
    /// One report per frame, in order.
    pub reports: Vec<ViewReport>,
    /// The first [`FrameSettings::grid_views`] views.
    pub kept: Vec<(TruthView, Prediction)>,
    /// The evaluated resolution (`None` without frames).
    pub resolution: Option<EvalResolution>,
    /// Error per object and per material, or why the views have none.
    pub objects: Result<crate::objects::ObjectTally, String>,
}

/// Evaluates `predict(frame)` against each frame's ground truth, one view at a time (a view's
/// data is dropped once its metrics are taken, except for the views kept for grids).
/// `progress(done, total)` is called after every view.
pub fn evaluate_frames(
    frames: &[&Frame],
    s: &FrameSettings<'_>,
    predict: &mut dyn FnMut(&Frame) -> Result<Prediction, EvalError>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Evaluated, EvalError> {
    let mut out = Evaluated { reports: Vec::with_capacity(frames.len()), kept: Vec::new(), resolution: None, objects: Ok(Default::default()) };
    for (k, frame) in frames.iter().enumerate() {
        let truth = load_truth(frame, s.background, s.downscale, s.source, s.err)?;
        let pred = predict(frame)?;
        out.resolution.get_or_insert(EvalResolution {
            width: truth.width as u32,
            height: truth.height as u32,
            downscale: s.downscale,
            train_downscale: s.train_downscale,
        });
        let input = view_input(&truth, &pred);
        out.reports.push(evaluate_view(&input, s.options)?);
        if let Ok(tally) = &mut out.objects {
            if let Err(why) = crate::objects::view_labels(frame, s.downscale, s.source).and_then(|l| tally.add(&l, &input, s.options.surface_tol)) {
                out.objects = Err(why);
            }
        }
        if k < s.grid_views {
            out.kept.push((truth, pred));
        }
        progress(k + 1, frames.len());
    }
    Ok(out)
}

/// The mesh an evaluation writes into the run folder, and its error picture.
pub const MESH_FILE: &str = "mesh.ply";
/// The mesh's error picture.
pub const MESH_PICTURE: &str = "mesh_error.png";

/// Whether `name` is a file an evaluation or a score writes into its folder.
pub fn is_eval_output(name: &str) -> bool {
    ["eval.json", "report.json", "report.md", "speed_vs_error.png", MESH_FILE, MESH_PICTURE, crate::objects::OBJECTS_PICTURE].contains(&name)
        || (name.starts_with("grid_") && name.ends_with(".png"))
}

/// Writes the report of `name` into `out_dir` ([`write_report`]: `eval.json`, `report.json`,
/// `report.md`, the pictures, a grid per kept view) and removes what an earlier report wrote
/// and this one did not; returns `report.md`'s path and the summary.
pub fn write_outputs(
    out_dir: &Path,
    name: &str,
    report: &crate::EvalReport,
    curve: &[MetricsRecord],
    kept: &[(TruthView, Prediction)],
) -> Result<(PathBuf, RunSummary), EvalError> {
    let grids: Vec<ViewInput<'_>> = kept.iter().map(|(t, p)| view_input(t, p)).collect();
    let report_md = write_report(out_dir, name, report, curve, &grids)?;
    let written: Vec<String> = kept.iter().map(|(t, _)| crate::grid::grid_file_name(&t.name)).collect();
    remove_stale_outputs(out_dir, &written, report.mesh.is_some(), report.objects.as_ref().is_some_and(|o| o.picture_psnr.is_some()))?;
    Ok((report_md, RunSummary::from_report(name, report, curve)))
}

/// Removes what an earlier report wrote and this one did not, so that the folder shows only
/// this report's pictures: grids (`grid_<view>.png`) other than `grids`, and without a mesh the
/// mesh's error picture. The mesh itself may be `cargo xtask mesh`'s and is kept.
fn remove_stale_outputs(dir: &Path, grids: &[String], mesh: bool, objects: bool) -> Result<(), EvalError> {
    let entries = std::fs::read_dir(dir).map_err(|source| EvalError::Io { path: dir.to_path_buf(), source })?;
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let stale = (name.starts_with("grid_") && name.ends_with(".png") && !grids.contains(&name))
            || (!mesh && name == MESH_PICTURE)
            || (!objects && name == crate::objects::OBJECTS_PICTURE);
        if stale && e.file_type().is_ok_and(|t| t.is_file()) {
            let p = e.path();
            std::fs::remove_file(&p).map_err(|source| EvalError::Io { path: p.clone(), source })?;
        }
    }
    Ok(())
}
