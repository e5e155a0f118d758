//! Evaluating a trained run end to end: load the run's latest checkpoint (through the `nerf`
//! crate's public rendering API only), render every view of a split **at the resolution the
//! run was trained at** (its downscale factor; [`EvalRunOptions::downscale`] overrides it),
//! compare with the dataset's ground truth at that resolution, and write `eval.json`,
//! `report.md`, `report.json` and the pictures into the run folder.
//!
//! Ground truth at downscale `k`: colour is the dataset's image box-filtered over whole `k × k`
//! blocks with alpha-premultiplied colour (`dataset::RgbaImage::downscaled`, the filter the
//! trainer applies to its targets). Depth, distance, normal and alpha are exact at the
//! downscaled pixel-centre rays and never averaged: for odd `k` each such ray is a
//! full-resolution centre ray, read from the ground-truth file; for even `k` the rays are cast
//! exactly through the scene the dataset was rendered from (found through its
//! `render_config.json` and checked by content hash, or given as [`EvalRunOptions::scene`]);
//! without the scene the nearest full-resolution pixel's values are used and the report says
//! so.
//!
//! Colour is compared in display space (sRGB in [0, 1]), the space the models are trained in:
//! the ground-truth PNG (straight alpha) is composited onto the same background the NeRF
//! renders with (`RunModel::eval_background`). Depth metrics use z-depth; the off-surface mass
//! uses the Euclidean distance along the pixel-centre ray, both from the ground-truth EXR.

use crate::curve::read_metrics_jsonl;
use crate::evaluate::{EvalOptions, EvalReport, RunInfo, ViewInput, evaluate_view};
use crate::metrics::RaySamples;
use crate::report::write_report;
use crate::{EvalError, RunSummary};
use crate::evaluate::EvalResolution;
use dataset::{Dataset, Frame, GroundTruth, SplitKind};
use pathtracer::ground_truth::{SceneLookup, scene_of_dataset};
use nerf::render::{RenderedView, RunModel};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What to evaluate and how.
#[derive(Clone, Debug)]
pub struct EvalRunOptions {
    /// The split whose views are rendered and compared (normally `test`).
    pub split: SplitKind,
    /// How many views get a picture grid in the report (the first ones of the split).
    pub grid_views: usize,
    /// Evaluate at most this many views (all when `None`).
    pub max_views: Option<usize>,
    /// Downscale factor of the dataset's images to evaluate at; `None`: the run's training
    /// downscale (1 compares at the dataset's full resolution). It must divide every view's
    /// size ([`dataset::check_downscale`]).
    pub downscale: Option<u32>,
    /// The scene file the dataset was rendered from, for exact ground truth at even downscale
    /// factors and the mesh reference (`None`: found through the dataset's `render_config.json`).
    pub scene: Option<PathBuf>,
    /// Extract the run's mesh and measure it against the scene's visible triangles (when the
    /// scene is found); `None`: no mesh.
    pub mesh: Option<crate::mesh_eval::MeshEvalOptions>,
    /// Read the dataset's frame files and the scene's external buffers and images also where
    /// they lie outside their folders (`--allow-outside`); `false`: refused.
    pub allow_outside: bool,
}

impl EvalRunOptions {
    /// All views of `split` at the run's training resolution, with grids for the first three,
    /// and the mesh at [`crate::mesh_eval::MeshEvalOptions::standard`].
    pub fn split(split: SplitKind) -> Self {
        Self {
            split,
            grid_views: 3,
            max_views: None,
            downscale: None,
            scene: None,
            mesh: Some(crate::mesh_eval::MeshEvalOptions::standard()),
            allow_outside: false,
        }
    }

    /// How the dataset is loaded ([`EvalRunOptions::allow_outside`]).
    pub fn load_options(&self) -> dataset::LoadOptions {
        dataset::LoadOptions { allow_outside: self.allow_outside }
    }

    /// How the scene is imported ([`EvalRunOptions::allow_outside`]).
    pub fn import_options(&self) -> pathtracer::import::ImportOptions {
        pathtracer::import::ImportOptions { allow_outside: self.allow_outside, ..Default::default() }
    }
}

/// The result of [`evaluate_run`].
#[derive(Clone, Debug)]
pub struct EvalRunOutput {
    /// The content of `eval.json`.
    pub report: EvalReport,
    /// The content of `report.json`.
    pub summary: RunSummary,
    /// Path of `report.md`.
    pub report_md: PathBuf,
}

struct LoadedView {
    name: String,
    width: usize,
    height: usize,
    gt_rgb: Vec<f32>,
    gt: Option<GroundTruth>,
    pred: RenderedView,
    pixel: Vec<usize>,
    offsets: Vec<usize>,
    render_s: f64,
}

fn run_error(run: &Path, message: impl ToString) -> EvalError {
    EvalError::Run { run: run.to_path_buf(), message: message.to_string() }
}

/// Where a view's depth / distance / normal / alpha ground truth at the evaluated resolution
/// comes from.
enum GroundTruthSource {
    /// Read from the ground-truth file: the full-resolution centre ray of an odd factor's block
    /// is the downscaled centre ray.
    File,
    /// Cast exactly through the scene (even factors).
    Scene(Box<pathtracer::render::Renderer>),
    /// The nearest full-resolution pixel (even factors without the scene).
    Nearest,
}

fn load_view(
    run_dir: &Path,
    model: &RunModel,
    frame: &Frame,
    background: [f32; 3],
    downscale: u32,
    source: &GroundTruthSource,
) -> Result<LoadedView, EvalError> {
    let full = frame.camera.intrinsics;
    let png = dataset::read_png_rgba(&frame.image_path)?;
    if (png.width, png.height) != (full.width, full.height) {
        return Err(run_error(
            run_dir,
            format!("{}: image is {}x{}, camera says {}x{}", frame.image_path.display(), png.width, png.height, full.width, full.height),
        ));
    }
    let camera = frame.camera.downscaled(downscale);
    let k = camera.intrinsics;
    let png = png.downscaled(downscale);
    let gt_rgb: Vec<f32> = png
        .data
        .chunks_exact(4)
        .flat_map(|p| {
            let a = p[3];
            [0, 1, 2].map(|c| p[c] * a + background[c] * (1.0 - a))
        })
        .collect();
    let gt = ground_truth_at(run_dir, frame, downscale, source)?;
    let start = Instant::now();
    let pred = model.render_view(&camera, background);
    let render_s = start.elapsed().as_secs_f64();
    let n = k.width as usize * k.height as usize;
    let offsets = pred.samples.offsets.iter().map(|&o| o as usize).collect();
    Ok(LoadedView {
        name: frame.name.clone(),
        width: k.width as usize,
        height: k.height as usize,
        gt_rgb,
        gt,
        pred,
        pixel: (0..n).collect(),
        offsets,
        render_s,
    })
}

/// The frame's depth / distance / normal / alpha ground truth at `downscale` (see
/// [`GroundTruthSource`]); `None` when the frame has none.
fn ground_truth_at(run_dir: &Path, frame: &Frame, downscale: u32, source: &GroundTruthSource) -> Result<Option<GroundTruth>, EvalError> {
    let Some(p) = &frame.gt_path else { return Ok(None) };
    let full = frame.camera.intrinsics;
    let g = dataset::read_ground_truth(p)?;
    if (g.width, g.height) != (full.width, full.height) {
        return Err(run_error(run_dir, format!("{}: ground truth is {}x{}, camera says {}x{}", p.display(), g.width, g.height, full.width, full.height)));
    }
    Ok(Some(match (g.at_downscale(downscale), source) {
        (Some(exact), _) => exact,
        (None, GroundTruthSource::Scene(r)) => r.ground_truth(&frame.camera.downscaled(downscale)),
        (None, _) => g.nearest_at_downscale(downscale),
    }))
}

/// How the ground truth at `downscale` is obtained, and the report's note saying so (`None`
/// when it is read exactly from the files, or there is none).
fn ground_truth_source(
    dataset: &Dataset,
    frames: &[&Frame],
    downscale: u32,
    scene: Option<&Path>,
    import: &pathtracer::import::ImportOptions,
) -> Result<(GroundTruthSource, Option<String>), EvalError> {
    if downscale % 2 == 1 || frames.iter().all(|f| f.gt_path.is_none()) {
        return Ok((GroundTruthSource::File, None));
    }
    let pt = |e: pathtracer::PathTracerError| EvalError::Input(e.to_string());
    Ok(match scene_of_dataset(&dataset.root, scene, import).map_err(pt)? {
        SceneLookup::Found { renderer, path } => (
            GroundTruthSource::Scene(renderer),
            Some(format!(
                "depth, distance, normal and alpha ground truth at downscale {downscale} are cast exactly through {} at the downscaled pixel centres",
                path.display()
            )),
        ),
        SceneLookup::Missing(why) => (
            GroundTruthSource::Nearest,
            Some(format!(
                "depth, distance, normal and alpha ground truth at the even downscale {downscale} are those of the nearest full-resolution pixel centre (half a full-resolution pixel off the evaluated ray), because {why}; give the scene (`--scene`) for exact values or evaluate at an odd downscale"
            )),
        ),
    })
}

fn view_input(v: &LoadedView) -> ViewInput<'_> {
    let samples = (v.offsets.len() == v.pixel.len() + 1).then(|| RaySamples {
        pixel: &v.pixel,
        offsets: &v.offsets,
        t: &v.pred.samples.t,
        w: &v.pred.samples.w,
    });
    ViewInput {
        name: &v.name,
        width: v.width,
        height: v.height,
        pred_rgb: &v.pred.rgb,
        gt_rgb: &v.gt_rgb,
        pred_depth: v.gt.as_ref().map(|_| v.pred.depth.as_slice()),
        gt_depth: v.gt.as_ref().map(|g| g.depth.as_slice()),
        gt_distance: v.gt.as_ref().map(|g| g.distance.as_slice()),
        gt_alpha: v.gt.as_ref().map(|g| g.alpha.as_slice()),
        pred_opacity: &v.pred.opacity,
        samples: v.gt.as_ref().and(samples),
        render_s: v.render_s,
    }
}

/// The box around ground-truth surface points (each covered pixel-centre ray, alpha at least
/// [`crate::metrics::FOREGROUND_ALPHA`], lifted by its true distance), grown view by view: the
/// scene's extent for the off-surface tolerance when the dataset has no scene facts but has
/// ground truth.
#[derive(Clone, Copy, Debug)]
struct SurfaceBox {
    lo: [f64; 3],
    hi: [f64; 3],
}

impl SurfaceBox {
    fn empty() -> Self {
        Self { lo: [f64::INFINITY; 3], hi: [f64::NEG_INFINITY; 3] }
    }

    /// Adds the surface points of `g`, seen by `camera` (of `g`'s resolution).
    fn extend(&mut self, camera: &dataset::Camera, g: &GroundTruth) {
        let w = g.width as usize;
        for (p, (&d, &a)) in g.distance.iter().zip(&g.alpha).enumerate() {
            if a < crate::metrics::FOREGROUND_ALPHA || !(d > 0.0 && d.is_finite()) {
                continue;
            }
            let ray = camera.pixel_center_ray((p % w) as u32, (p / w) as u32);
            let x = ray.origin + ray.direction * d as f64;
            for k in 0..3 {
                self.lo[k] = self.lo[k].min(x[k]);
                self.hi[k] = self.hi[k].max(x[k]);
            }
        }
    }

    /// `None` without any surface point.
    fn bounds(&self) -> Option<([f32; 3], [f32; 3])> {
        self.lo[0].is_finite().then(|| (self.lo.map(|v| v as f32), self.hi.map(|v| v as f32)))
    }
}

/// Evaluates the run in `run_dir` on `opts.split` and writes its report into the run folder.
/// `progress(done, total)` is called after every view.
pub fn evaluate_run(
    run_dir: &Path,
    opts: &EvalRunOptions,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<EvalRunOutput, EvalError> {
    let model = RunModel::load(run_dir).map_err(|e| run_error(run_dir, e))?;
    let dataset = Dataset::load_with(model.dataset_dir(), &opts.load_options())?;
    let mut frames: Vec<&Frame> = dataset.split(opts.split).iter().collect();
    if frames.is_empty() {
        return Err(run_error(
            run_dir,
            format!("dataset {} has no {} views", dataset.root.display(), opts.split.name()),
        ));
    }
    if let Some(m) = opts.max_views {
        frames.truncate(m.max(1));
    }
    let train_downscale = model.config.downscale.max(1);
    let downscale = opts.downscale.unwrap_or(train_downscale);
    for f in &frames {
        dataset::check_downscale("--downscale", downscale, &f.camera.intrinsics)
            .map_err(|e| run_error(run_dir, format!("{e} ({})", f.image_path.display())))?;
    }
    let (source, gt_note) = ground_truth_source(&dataset, &frames, downscale, opts.scene.as_deref(), &opts.import_options())?;
    // The off-surface tolerance's box, and the note that says where it came from: the scene
    // facts' box, or a first pass over the evaluated views' ground truth.
    let surface = match &dataset.facts {
        Some(_) => None,
        None => {
            let mut b = SurfaceBox::empty();
            for f in &frames {
                if let Some(g) = ground_truth_at(run_dir, f, downscale, &source)? {
                    b.extend(&f.camera.downscaled(downscale), &g);
                }
            }
            b.bounds()
        }
    };
    let (options, note) = match (&dataset.facts, surface) {
        (Some(f), _) => (EvalOptions::for_scene_bbox(f.aabb_min.map(|v| v as f32), f.aabb_max.map(|v| v as f32)), None),
        (None, Some((lo, hi))) => {
            let o = EvalOptions::for_scene_bbox(lo, hi);
            let note = format!(
                "the dataset carries no scene facts: the off-surface tolerance ({:.4}) is 1 % of the diagonal of the box around the ground-truth surface points of the evaluated views",
                o.surface_tol
            );
            (o, Some(note))
        }
        (None, None) => (
            EvalOptions::with_surface_tol(0.0),
            Some("the dataset carries no scene facts (e.g. Blender synthetic): no bounding box for the off-surface tolerance".to_string()),
        ),
    };
    // One view at a time: its samples (tens of MB at 800x800) are dropped once its metrics are
    // taken, except for the views that get a picture grid.
    let background = model.eval_background();
    let mut reports = Vec::with_capacity(frames.len());
    let mut kept = Vec::new();
    let mut resolution = None;
    for (k, frame) in frames.iter().enumerate() {
        let view = load_view(run_dir, &model, frame, background, downscale, &source)?;
        resolution.get_or_insert(EvalResolution { width: view.width as u32, height: view.height as u32, downscale, train_downscale });
        reports.push(evaluate_view(&view_input(&view), &options)?);
        if k < opts.grid_views {
            kept.push(view);
        }
        progress(k + 1, frames.len());
    }
    let info = RunInfo {
        train_wall_s: model.train_wall_s(),
        train_steps: model.train_steps(),
        parameters: model.parameters() as u64,
    };
    let mut report = EvalReport::new(reports, info, &options)?;
    report.resolution = resolution;
    report.notes.extend(note);
    report.notes.extend(gt_note);
    // Every input is read before the first output (the mesh's files) is written, so a bad
    // metrics file leaves the run as it was.
    let metrics_path = run_dir.join("metrics.jsonl");
    let curve = if metrics_path.exists() { read_metrics_jsonl(&metrics_path)? } else { Vec::new() };
    dataset::io::remove_stale_temporaries(run_dir, is_eval_output)?;
    if let Some(mesh_opts) = &opts.mesh {
        match crate::mesh_eval::scene_reference(&dataset, opts.scene.as_deref(), &opts.import_options())? {
            Ok(reference) => {
                let camera = frames[0].camera.downscaled(downscale);
                match crate::mesh_eval::evaluate_run_mesh(run_dir, &model, &dataset, reference, &camera, mesh_opts, &mut |_, _, _| {}) {
                    Ok(block) => report.mesh = Some(block),
                    // A field without a surface is a finding, not a failed evaluation.
                    Err(EvalError::Input(why)) => report.notes.push(format!("no mesh metrics: {why}")),
                    Err(e) => return Err(e),
                }
            }
            Err(why) => report.notes.push(format!("no mesh metrics: {why}")),
        }
    }
    if report.mesh.is_none() && run_dir.join(MESH_FILE).is_file() {
        report.notes.push(format!(
            "{MESH_FILE} in the run folder is not this evaluation's (it measured no mesh): an earlier evaluation or `cargo xtask mesh` wrote it"
        ));
    }
    let name = run_name(run_dir);
    let grids: Vec<ViewInput<'_>> = kept.iter().map(view_input).collect();
    let report_md = write_report(run_dir, &name, &report, &curve, &grids)?;
    let written: Vec<String> = kept.iter().map(|v| crate::grid::grid_file_name(&v.name)).collect();
    remove_stale_outputs(run_dir, &written, report.mesh.is_some())?;
    let summary = RunSummary::from_report(&name, &report, &curve);
    Ok(EvalRunOutput { report, summary, report_md })
}

/// The mesh an evaluation writes into the run folder, and its error picture.
const MESH_FILE: &str = "mesh.ply";
const MESH_PICTURE: &str = "mesh_error.png";

/// Whether `name` is a file [`evaluate_run`] writes into the run folder.
fn is_eval_output(name: &str) -> bool {
    ["eval.json", "report.json", "report.md", "speed_vs_error.png", MESH_FILE, MESH_PICTURE].contains(&name)
        || (name.starts_with("grid_") && name.ends_with(".png"))
}

/// Removes what an earlier evaluation wrote and this one did not, so that the folder shows only
/// this report's pictures: grids (`grid_<view>.png`) other than `grids`, and without a mesh the
/// mesh's error picture. The mesh itself may be `cargo xtask mesh`'s and is kept (the report
/// says it is not this evaluation's).
fn remove_stale_outputs(run_dir: &Path, grids: &[String], mesh: bool) -> Result<(), EvalError> {
    let entries = std::fs::read_dir(run_dir).map_err(|source| EvalError::Io { path: run_dir.to_path_buf(), source })?;
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let stale = (name.starts_with("grid_") && name.ends_with(".png") && !grids.contains(&name)) || (!mesh && name == MESH_PICTURE);
        if stale && e.file_type().is_ok_and(|t| t.is_file()) {
            let p = e.path();
            std::fs::remove_file(&p).map_err(|source| EvalError::Io { path: p.clone(), source })?;
        }
    }
    Ok(())
}

/// A run's display name: its folder name.
pub fn run_name(run_dir: &Path) -> String {
    run_dir
        .canonicalize()
        .ok()
        .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .unwrap_or_else(|| run_dir.display().to_string())
}

/// Reads an evaluated run's `report.json` (written by [`evaluate_run`]).
pub fn summarise_run(run_dir: &Path) -> Result<RunSummary, EvalError> {
    let path = run_dir.join("report.json");
    if !path.exists() {
        return Err(run_error(run_dir, "no report.json: run `cargo xtask eval` on it first"));
    }
    crate::io::read_json(&path)
}
