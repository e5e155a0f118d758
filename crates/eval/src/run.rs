//! Evaluating a trained run end to end: load the run's latest checkpoint (through the `nerf`
//! crate's public rendering API only), render every view of a split **at the resolution the
//! run was trained at** (its downscale factor; [`EvalRunOptions::downscale`] overrides it),
//! compare with the dataset's ground truth at that resolution, and write `eval.json`,
//! `report.md`, `report.json` and the pictures into the run folder.
//!
//! The ground truth at that resolution ([`crate::truth`]: colour box-filtered and composited on
//! the run's evaluation background, `RunModel::eval_background`; depth, distance, normal and
//! alpha exact at the downscaled pixel-centre rays) and the per-view metrics and report files
//! ([`crate::session`]) are shared with [`mod@crate::score`], which measures other tools' renders.
//! Colour is compared in display space (sRGB in [0, 1]), the space the models are trained in.
//! Depth metrics use z-depth; the off-surface mass uses the Euclidean distance along the
//! pixel-centre ray, both from the ground-truth EXR.

use crate::curve::read_metrics_jsonl;
use crate::evaluate::{EvalReport, RunInfo};
use crate::session::{FrameSettings, MESH_FILE, Prediction, Samples, evaluate_frames, is_eval_output, write_outputs};
use crate::truth::{ground_truth_source, surface_options};
use crate::{EvalError, RunSummary};
use dataset::{Dataset, Frame, SplitKind};
use nerf::render::RunModel;
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
    /// For runs trained on noisy or refined poses: refine each view's pose for this many steps
    /// with the model frozen before it is rendered ([`nerf::camera_opt::optimise_view`]).
    pub test_pose_opt: Option<u64>,
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
            test_pose_opt: None,
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

fn run_error(run: &Path, message: impl ToString) -> EvalError {
    EvalError::Run { run: run.to_path_buf(), message: message.to_string() }
}

/// Renders `frame` at `downscale` through the run's model.
fn render(model: &RunModel, frame: &Frame, background: [f32; 3], downscale: u32) -> Prediction {
    let camera = frame.camera.downscaled(downscale);
    let start = Instant::now();
    let pred = model.render_view(&camera, background);
    let render_s = start.elapsed().as_secs_f64();
    let n = pred.width as usize * pred.height as usize;
    let samples = Samples {
        pixel: (0..n).collect(),
        offsets: pred.samples.offsets.iter().map(|&o| o as usize).collect(),
        t: pred.samples.t,
        w: pred.samples.w,
    };
    Prediction { rgb: pred.rgb, depth: Some(pred.depth), opacity: Some(pred.opacity), samples: Some(samples), render_s }
}

/// Evaluates the run in `run_dir` on `opts.split` and writes its report into the run folder.
/// `progress(done, total)` is called after every view.
pub fn evaluate_run(
    run_dir: &Path,
    opts: &EvalRunOptions,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<EvalRunOutput, EvalError> {
    let mut model = RunModel::load(run_dir).map_err(|e| run_error(run_dir, e))?;
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
    let err = |m: String| run_error(run_dir, m);
    let (options, note) = surface_options(&dataset, &frames, downscale, &source, &err)?;
    let background = model.eval_background();
    let settings = FrameSettings { background, downscale, train_downscale, source: &source, options: &options, grid_views: opts.grid_views, err: &err };
    // Runs trained on noisy or refined poses learned in the frame of those poses: test views
    // are mapped into it by the similarity aligning the training centres to the true ones.
    let poses: Option<nerf::poses::PoseRecord> = if model.config.pose_noise.is_some() || model.config.camera_opt.is_some() {
        Some(crate::io::read_json(&run_dir.join(nerf::poses::POSES_FILE))?)
    } else {
        None
    };
    let align = poses.as_ref().and_then(|p| p.truth_to_model());
    if opts.test_pose_opt.is_some() && align.is_none() {
        return Err(err(
            "--test-pose-opt: the run was trained on its exact poses (no --pose-noise or --camera-opt), so its test views need no pose optimisation".into(),
        ));
    }
    let scene_size = poses.as_ref().map_or(1.0, |p| p.scene_size);
    let evaluated = evaluate_frames(
        &frames,
        &settings,
        &mut |frame| {
            let Some(sim) = align else { return Ok(render(&model, frame, background, downscale)) };
            let mut f = frame.clone();
            f.camera.c2w = sim.apply_pose(&f.camera.c2w);
            if let Some(steps) = opts.test_pose_opt {
                let data = nerf::data::TrainData::load(std::slice::from_ref(&f), downscale, model.config.background, false).map_err(|e| err(e.to_string()))?;
                let opt = nerf::camera_opt::optimise_view(&mut *model.model, &data, scene_size, steps, model.config.seed).map_err(&err)?;
                f.camera.c2w = opt.corrected_pose(0, &f.camera.c2w);
            }
            let mut p = render(&model, &f, background, downscale);
            // Distances in the model's frame are the scale's multiple of the true ones.
            let inv = (1.0 / sim.scale) as f32;
            p.depth.iter_mut().flatten().for_each(|d| *d *= inv);
            p.samples.iter_mut().for_each(|s| s.t.iter_mut().for_each(|t| *t *= inv));
            Ok(p)
        },
        progress,
    )?;
    let info = RunInfo {
        train_wall_s: model.train_wall_s(),
        train_steps: model.train_steps(),
        parameters: model.parameters() as u64,
    };
    let mut report = EvalReport::new(evaluated.reports, info, &options)?;
    report.resolution = evaluated.resolution;
    report.notes.extend(note);
    report.notes.extend(gt_note);
    if let Some(record) = &poses {
        let noise = model.config.pose_noise.map_or("exact poses".to_string(), |n| format!("noisy poses ({}° rotation, {} of the scene size)", n.rotation_deg, n.translation_rel));
        let said = |e: &nerf::poses::PoseErrorSummary| {
            format!(
                "median rotation error {:.3}° (max {:.3}°), median centre error {:.4} ({:.2} % of the scene size, max {:.4})",
                e.rotation_median_deg, e.rotation_max_deg, e.translation_median, e.translation_median_pct, e.translation_max
            )
        };
        report.train_poses = record.errors();
        report.refined_poses = record.refined_errors();
        match (&report.train_poses, &report.refined_poses) {
            (Some(e), None) => report.notes.push(format!("trained on {noise} without camera refinement: after aligning them to the exact ones, {}", said(e))),
            (Some(e), Some(r)) => report.notes.push(format!("trained on {noise} with camera refinement: after aligning to the exact ones, before refinement {}; after, {}", said(e), said(r))),
            _ => report.notes.push(format!("the training poses of {} are too few or too degenerate to align to the exact ones", run_dir.display())),
        }
        let protocol = match opts.test_pose_opt {
            Some(n) => format!("aligned+test-pose-opt:{n}"),
            None => "aligned".to_string(),
        };
        if let Some(sim) = align {
            report.notes.push(format!(
                "test views posed by protocol {protocol}: the exact poses mapped into the model's frame by the similarity aligning the training centres (scale {:.5}){}",
                sim.scale,
                opts.test_pose_opt.map_or(String::new(), |n| format!(", then {n} steps of pose optimisation per view with the model frozen"))
            ));
        }
        report.pose_protocol = Some(protocol);
    }
    if let Some(s) = &model.config.supervision {
        report.notes.push(format!("trained with supervision beyond colour: {}", s.describe()));
    }
    // Every input is read before the first output (the mesh's files) is written, so a bad
    // metrics file leaves the run as it was.
    let metrics_path = run_dir.join("metrics.jsonl");
    let curve = if metrics_path.exists() { read_metrics_jsonl(&metrics_path)? } else { Vec::new() };
    dataset::io::remove_stale_temporaries(run_dir, is_eval_output)?;
    let mut mesh_by_object = Vec::new();
    if let Some(mesh_opts) = &opts.mesh {
        match crate::mesh_eval::scene_reference(&dataset, opts.scene.as_deref(), &opts.import_options())? {
            Ok(reference) => {
                let camera = frames[0].camera.downscaled(downscale);
                match crate::mesh_eval::evaluate_run_mesh(run_dir, &model, &dataset, reference, &camera, mesh_opts, &mut |_, _, _| {}) {
                    Ok((block, per_object)) => {
                        report.mesh = Some(block);
                        mesh_by_object = per_object;
                    }
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
    crate::objects::attach(&mut report, &evaluated.objects, dataset.facts.as_ref(), run_dir)?;
    if let Some(block) = &mut report.objects {
        crate::objects::add_mesh_distances(block, &mesh_by_object);
    }
    let name = run_name(run_dir);
    let (report_md, summary) = write_outputs(run_dir, &name, &report, &curve, &evaluated.kept)?;
    Ok(EvalRunOutput { report, summary, report_md })
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
