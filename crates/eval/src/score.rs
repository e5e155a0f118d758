//! Scoring another tool's predictions (`cargo xtask score`): the colour, depth and opacity
//! another method rendered for a split's views, found by [`crate::predictions::detect`] and
//! read by [`crate::prediction_io`], measured against the dataset's exact ground truth by the
//! same code `eval` measures our runs with ([`crate::session`]), into an output folder that
//! `compare` reads beside run folders.
//!
//! - **Resolution**: the dataset's, or `1/D` of it with [`ScoreOptions::downscale`]; the ground
//!   truth is taken at that resolution as `eval` takes it ([`crate::truth`]).
//! - **Colour** is display sRGB. A prediction with alpha is composited on
//!   [`ScoreOptions::background`] exactly as the ground truth is, and its alpha is its opacity;
//!   one without alpha must have been rendered on that background.
//! - **Depth** becomes metres of z-depth: values times [`ScoreOptions::depth_scale`] (or the
//!   layout's unit), and a distance along the ray ([`DepthKind::Distance`]) converted with the
//!   view's camera (`dataset::Camera::z_depth_from_distance`). A 16-bit PNG needs a stated scale.
//! - **Opacity** (mask IoU) from an opacity file or the colour's alpha; without either, mask IoU
//!   is absent with a note. Off-surface mass needs density samples along the rays, which files
//!   do not carry: always absent for scored methods.
//! - **Geometry** ([`ScoreOptions::geometry`], a PLY or OBJ mesh or point cloud) is brought to
//!   the dataset's frame ([`GeometryFrame`]: by default the inverse of what the layout found,
//!   nerfstudio's dataparser transform or instant-ngp's mesh frame) and scored by
//!   [`crate::geometry::score_geometry`] into the `mesh` block, as `eval` scores our mesh.
//! - **Missing views** are an error, or with [`ScoreOptions::allow_missing`] recorded in
//!   `eval.json` (`method.missing_views`) and left out of every mean. Non-finite values are
//!   counted and left out of the metrics they would enter ([`crate::evaluate::evaluate_view`]).
//!
//! The report is `eval.json` (the same keys as a run's, with `method`, [`MethodInfo`]),
//! `report.json`, `report.md` and the grids, written after every view was read, each file
//! atomically. The caller keeps the output out of the dataset and predictions folders.

use crate::evaluate::{DepthConversion, EvalReport, MethodInfo, NonFiniteCounts, RunInfo};
use crate::predictions::{DepthKind, Layout, Tool, detect};
use crate::prediction_io::{Expected, read_colour, read_scalar};
use crate::session::{FrameSettings, Prediction, evaluate_frames, is_eval_output, write_outputs};
use crate::truth::{composite_straight, ground_truth_source, surface_options};
use crate::{EvalError, RunSummary};
use dataset::{Dataset, Frame, SplitKind};
use std::path::PathBuf;

/// What to score and how.
#[derive(Clone, Debug)]
pub struct ScoreOptions {
    /// The dataset folder the method was trained on.
    pub dataset: PathBuf,
    /// The folder holding the method's predictions.
    pub predictions: PathBuf,
    /// Where the report goes (created if missing).
    pub out: PathBuf,
    /// The method's name in the report and in `compare`.
    pub method: String,
    /// The split whose views were predicted (normally `test`).
    pub split: SplitKind,
    /// Training seconds, as the user states them.
    pub train_seconds: Option<f64>,
    /// Hardware, as the user states it.
    pub hardware: Option<String>,
    /// The predictions are at `1/D` of the dataset's resolution (`None`: 1).
    pub downscale: Option<u32>,
    /// What the depth files hold (`None`: the layout's convention).
    pub depth_kind: Option<DepthKind>,
    /// Metres per depth-file unit (`None`: the layout's unit).
    pub depth_scale: Option<f64>,
    /// Score the views that have predictions and record the others.
    pub allow_missing: bool,
    /// Display RGB the ground truth (and predictions with alpha) are composited on.
    pub background: [f32; 3],
    /// The scene file, for exact ground truth at even downscales (`None`: found through the
    /// dataset's `render_config.json`).
    pub scene: Option<PathBuf>,
    /// nerfstudio's `dataparser_transforms.json` (`None`: looked for in the predictions folder).
    pub dataparser_transforms: Option<PathBuf>,
    /// How many views (the first ones scored) get a picture grid.
    pub grid_views: usize,
    /// The method's mesh or point cloud (PLY, OBJ), scored like our extracted mesh.
    pub geometry: Option<PathBuf>,
    /// The frame [`ScoreOptions::geometry`] is in.
    pub geometry_frame: GeometryFrame,
    /// Points sampled on each mesh for the geometry metrics.
    pub geometry_samples: usize,
    /// Admit the dataset's files and the scene's external files outside their folders.
    pub allow_outside: bool,
}

/// The frame a scored geometry file is in, and so how it is brought to the dataset's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GeometryFrame {
    /// The tool's own frame, undone with what the layout found: nerfstudio's
    /// `dataparser_transforms.json` (`ns-export`), instant-ngp's scale and offset
    /// (`--save_mesh`); the dataset's frame for a plain folder of images.
    Tool,
    /// Already the dataset's frame.
    Dataset,
    /// A row-major affine 4x4 from the file's frame to the dataset's (`--to-dataset`).
    Matrix([[f64; 4]; 4]),
}

/// The result of [`score`].
#[derive(Clone, Debug)]
pub struct ScoreOutput {
    /// The content of `eval.json`.
    pub report: EvalReport,
    /// The content of `report.json`.
    pub summary: RunSummary,
    /// Path of `report.md`.
    pub report_md: PathBuf,
    /// The layout the predictions were found in.
    pub layout: Layout,
}

fn invalid(message: impl Into<String>) -> EvalError {
    EvalError::Input(message.into())
}

/// Checks the options that need no file.
fn check_options(o: &ScoreOptions) -> Result<(), EvalError> {
    if o.method.trim().is_empty() {
        return Err(invalid("--method: give the method a name"));
    }
    if let Some(t) = o.train_seconds.filter(|t| !(t.is_finite() && *t >= 0.0)) {
        return Err(invalid(format!("--train-seconds {t}: not a number of seconds (finite, at least 0)")));
    }
    if let Some(k) = o.depth_scale.filter(|k| !(k.is_finite() && *k > 0.0)) {
        return Err(invalid(format!("--depth-scale {k}: not a positive number of metres per unit")));
    }
    if o.geometry.is_some() && o.geometry_samples == 0 {
        return Err(invalid("--geometry-samples 0: at least one point per mesh is needed"));
    }
    if o.geometry.is_none() && o.geometry_frame != GeometryFrame::Tool {
        return Err(invalid("--to-dataset / --geometry-frame given without --geometry"));
    }
    if o.background.iter().any(|c| !(0.0..=1.0).contains(c)) {
        return Err(invalid(format!("--background {:?}: each channel must be in [0, 1]", o.background)));
    }
    Ok(())
}

/// Scores the predictions in `opts.predictions` and writes the report into `opts.out`.
/// `progress(done, total)` is called after every view.
pub fn score(opts: &ScoreOptions, progress: &mut dyn FnMut(usize, usize)) -> Result<ScoreOutput, EvalError> {
    check_options(opts)?;
    let dataset = Dataset::load_with(&opts.dataset, &dataset::LoadOptions { allow_outside: opts.allow_outside })?;
    let all: Vec<&Frame> = dataset.split(opts.split).iter().collect();
    if all.is_empty() {
        return Err(invalid(format!("dataset {} has no {} views", dataset.root.display(), opts.split.name())));
    }
    let downscale = opts.downscale.unwrap_or(1);
    for f in &all {
        dataset::check_downscale("--downscale", downscale, &f.camera.intrinsics).map_err(|e| invalid(format!("{e} ({})", f.image_path.display())))?;
    }
    let layout = detect(&opts.predictions, opts.split, &all, opts.dataparser_transforms.as_deref())?;
    let missing: Vec<String> = all.iter().zip(&layout.views).filter(|(_, v)| v.is_none()).map(|(f, _)| f.name.clone()).collect();
    if !missing.is_empty() && (!opts.allow_missing || missing.len() == all.len()) {
        let s = opts.split.name();
        let more = if opts.allow_missing { String::new() } else { "; give --allow-missing to score the others and record these".into() };
        return Err(invalid(format!(
            "{}: {} of the {} {s} views have no prediction ({}{}){more}",
            opts.predictions.display(),
            missing.len(),
            all.len(),
            missing.iter().take(5).cloned().collect::<Vec<_>>().join(", "),
            if missing.len() > 5 { ", …" } else { "" }
        )));
    }
    let present: Vec<(&Frame, &crate::predictions::ViewFiles)> = all.iter().zip(&layout.views).filter_map(|(f, v)| v.as_ref().map(|v| (*f, v))).collect();
    let frames: Vec<&Frame> = present.iter().map(|(f, _)| *f).collect();
    let depth = depth_conversion(opts, &layout, &present)?;

    let (source, gt_note) = ground_truth_source(&dataset, &frames, downscale, opts.scene.as_deref(), &pathtracer::import::ImportOptions { allow_outside: opts.allow_outside, ..Default::default() })?;
    let err = |m: String| invalid(format!("{}: {m}", dataset.root.display()));
    let (options, note) = surface_options(&dataset, &frames, downscale, &source, &err)?;
    let settings = FrameSettings {
        background: opts.background,
        downscale,
        train_downscale: downscale,
        source: &source,
        options: &options,
        grid_views: opts.grid_views,
        err: &err,
    };
    let mut files_read = Vec::new();
    let mut next = 0usize;
    let mut predict = |frame: &Frame| -> Result<Prediction, EvalError> {
        let files = present[next].1;
        next += 1;
        for p in [Some(&files.colour), files.depth.as_ref(), files.opacity.as_ref()].into_iter().flatten() {
            files_read.push(p.strip_prefix(&opts.predictions).unwrap_or(p).display().to_string());
        }
        read_prediction(frame, files, downscale, opts.background, depth.as_ref(), opts.depth_scale.is_some())
    };
    let evaluated = evaluate_frames(&frames, &settings, &mut predict, progress)?;
    let info = RunInfo { train_wall_s: opts.train_seconds.unwrap_or(f64::NAN), train_steps: 0, parameters: 0 };
    let mut report = EvalReport::new(evaluated.reports, info, &options)?;
    report.resolution = evaluated.resolution;
    let mut nonfinite = NonFiniteCounts::default();
    for c in report.views.iter().filter_map(|v| v.nonfinite) {
        nonfinite.colour += c.colour;
        nonfinite.depth += c.depth;
        nonfinite.opacity += c.opacity;
    }
    report.notes.extend(layout.notes.iter().cloned());
    if !missing.is_empty() {
        report.notes.push(format!("{} of {} views have no prediction and are left out of every mean: {}", missing.len(), all.len(), missing.join(", ")));
    }
    if let Some(d) = depth.as_ref().filter(|d| !d.kind_stated) {
        report.notes.push(format!("depth read as {} ({}); give --depth-kind if the tool wrote the other", if d.kind == "z" { "z-depth" } else { "the distance along the ray" }, depth_kind_reason(layout.tool)));
    }
    // Files carry no samples: one note for the report instead of evaluate_view's generic one.
    report.notes.retain(|n| !n.starts_with("no per-ray samples given"));
    report.notes.push("off_surface_mass needs the method's density samples along each ray, which its files do not carry: omitted".into());
    for p in &layout.transforms_checked {
        report.notes.push(format!("{} beside the predictions describes the dataset's {} views (count, size and poses checked)", p.display(), opts.split.name()));
    }
    report.notes.extend(note);
    report.notes.extend(gt_note);
    report.method = Some(MethodInfo {
        name: opts.method.clone(),
        tool: layout.tool.name().to_string(),
        train_seconds: opts.train_seconds,
        hardware: opts.hardware.clone(),
        layout: layout.description.clone(),
        predictions: opts.predictions.display().to_string(),
        files_read,
        missing_views: missing,
        nonfinite,
        depth,
        background: opts.background,
    });
    if let Some(path) = &opts.geometry {
        report.mesh = Some(score_method_geometry(opts, path, &layout, &dataset)?);
    }
    std::fs::create_dir_all(&opts.out).map_err(|e| EvalError::from(dataset::DatasetError::write(&opts.out, e)))?;
    dataset::io::remove_stale_temporaries(&opts.out, is_eval_output)?;
    crate::objects::attach(&mut report, &evaluated.objects, dataset.facts.as_ref(), &opts.out)?;
    let (report_md, summary) = write_outputs(&opts.out, &opts.method, &report, &[], &evaluated.kept)?;
    Ok(ScoreOutput { report, summary, report_md, layout })
}

/// The map from a geometry file's frame to the dataset's, and where it comes from; `None`:
/// the file is in the dataset's frame.
fn geometry_to_dataset(frame: GeometryFrame, layout: &Layout) -> Result<Option<([[f64; 4]; 4], String)>, EvalError> {
    let rows = |m: glam::DMat4| -> [[f64; 4]; 4] { m.transpose().to_cols_array_2d() };
    Ok(match frame {
        GeometryFrame::Dataset => None,
        GeometryFrame::Matrix(m) => Some((m, "the transform given (--to-dataset)".into())),
        GeometryFrame::Tool => match layout.tool {
            Tool::Images => None,
            Tool::Nerfstudio => match &layout.nerfstudio {
                Some(t) => Some((rows(t.to_dataset()), "nerfstudio's frame, undone with dataparser_transforms.json".into())),
                None => {
                    return Err(invalid(
                        "--geometry: nerfstudio exports meshes in its own frame, and no dataparser_transforms.json was found beside the predictions; give --dataparser-transforms (it is beside the run's config.yml), --to-dataset, or --geometry-frame dataset",
                    ));
                }
            },
            Tool::InstantNgp => layout.instant_ngp.map(|t| (rows(t.mesh_to_dataset()), format!("instant-ngp's mesh frame (scale {}, offset {:?}), undone", t.scale, t.offset))),
        },
    })
}

/// Reads the method's geometry, brings it to the dataset's frame and scores it against the
/// scene's visible surface; every failure is an error, since the user asked for it.
fn score_method_geometry(opts: &ScoreOptions, path: &std::path::Path, layout: &Layout, dataset: &Dataset) -> Result<crate::mesh_eval::MeshBlock, EvalError> {
    let mut g = crate::geometry::read_geometry(path)?;
    let map = geometry_to_dataset(opts.geometry_frame, layout)?;
    if let Some((m, source)) = &map {
        crate::geometry::transform(&mut g, m)?;
        g.input.notes.push(format!("Frame: {source}."));
    }
    let import = pathtracer::import::ImportOptions { allow_outside: opts.allow_outside, ..Default::default() };
    let reference = match crate::mesh_eval::scene_reference(dataset, opts.scene.as_deref(), &import)? {
        Ok(r) => r,
        Err(why) => return Err(invalid(format!("--geometry {}: no reference surface to score it against: {why}", path.display()))),
    };
    crate::geometry::score_geometry(&g, &reference, opts.geometry_samples)
}

/// Why the layout's depth kind is what it is.
fn depth_kind_reason(tool: Tool) -> &'static str {
    match tool {
        Tool::Nerfstudio => "nerfstudio's ray-marched models such as nerfacto render the distance along unit rays; splatfacto renders z-depth: give --depth-kind z for it",
        Tool::InstantNgp | Tool::Images => "the dataset's own convention",
    }
}

/// How depth files become metres of z-depth (`None` without depth files).
fn depth_conversion(opts: &ScoreOptions, layout: &Layout, present: &[(&Frame, &crate::predictions::ViewFiles)]) -> Result<Option<DepthConversion>, EvalError> {
    if present.iter().all(|(_, v)| v.depth.is_none()) {
        if opts.depth_kind.is_some() || opts.depth_scale.is_some() {
            return Err(invalid(format!("--depth-kind / --depth-scale given, but {} holds no depth predictions ({})", opts.predictions.display(), layout.description)));
        }
        return Ok(None);
    }
    let (metres_per_unit, unit_source) = match opts.depth_scale {
        Some(k) => (k, "stated (--depth-scale)".to_string()),
        None => layout.depth_unit.clone(),
    };
    Ok(Some(DepthConversion {
        kind: opts.depth_kind.unwrap_or(layout.depth_kind).name().to_string(),
        kind_stated: opts.depth_kind.is_some(),
        metres_per_unit,
        unit_source,
    }))
}

/// Reads one view's files into a prediction at the evaluated resolution.
fn read_prediction(
    frame: &Frame,
    files: &crate::predictions::ViewFiles,
    downscale: u32,
    background: [f32; 3],
    depth: Option<&DepthConversion>,
    scale_stated: bool,
) -> Result<Prediction, EvalError> {
    let camera = frame.camera.downscaled(downscale);
    let k = camera.intrinsics;
    let full = frame.camera.intrinsics;
    let want = Expected { size: (k.width, k.height), full: (full.width, full.height) };
    let colour = read_colour(&files.colour, want)?;
    let (rgb, alpha) = if colour.has_alpha {
        (composite_straight(&colour.rgba, background), Some(colour.rgba.chunks_exact(4).map(|p| p[3]).collect::<Vec<f32>>()))
    } else {
        (colour.rgba.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect(), None)
    };
    let opacity = match &files.opacity {
        Some(p) => {
            let o = read_scalar(p, want)?;
            Some(if o.integer_png { o.values.iter().map(|v| v / 65535.0).collect() } else { o.values })
        }
        None => alpha,
    };
    let depth = match (&files.depth, depth) {
        (Some(p), Some(conv)) => {
            let d = read_scalar(p, want)?;
            if d.integer_png && !scale_stated {
                return Err(invalid(format!("{}: a 16-bit PNG holds integers without a unit: give --depth-scale (metres per unit)", p.display())));
            }
            let w = k.width as usize;
            let z = d
                .values
                .iter()
                .enumerate()
                .map(|(i, &v)| {
                    let m = f64::from(v) * conv.metres_per_unit;
                    if conv.kind == "distance" {
                        camera.z_depth_from_distance((i % w) as f64 + 0.5, (i / w) as f64 + 0.5, m) as f32
                    } else {
                        m as f32
                    }
                })
                .collect();
            Some(z)
        }
        _ => None,
    };
    Ok(Prediction { rgb, depth, opacity, samples: None, render_s: f64::NAN })
}
