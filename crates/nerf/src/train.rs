//! The trainer: one [`TrainConfig`] holds every setting (model, data, schedule, logging) and
//! is written to `<run>/config.json` before step 0, so a run is reproducible from that file
//! alone; [`Trainer`] owns the data, the model and the run folder and advances one step at a
//! time.
//!
//! Run folder: `config.json`, `metrics.jsonl` (one JSON object per line: training lines every
//! `log_interval_steps` with `step`, `wall_s`, `loss`, `train_psnr`, `rays_per_s`,
//! `samples_per_ray`, `marched_per_ray` (as far as compaction reached), `lr`, `skipped_nonfinite`; validation lines with `val_psnr` and, when the
//! dataset has ground truth, `val_depth_mae`), `checkpoints/step-*.ckpt`.
//!
//! Clock: `wall_s` counts training time only (steps, checkpoints excluded too): validation
//! runs outside it. Validation happens every `val_interval_s` of that training clock (default:
//! a tenth of the time budget, or 30 s without one) and at the end, on a fixed subset of the
//! val views' pixels (at most `val_max_views` views, `val_max_pixels` pixels drawn once from
//! the seed) so curves over time compare like with like.
//!
//! Randomness is counter-based on (seed, step): batches, jitter and grid updates do not depend
//! on what ran before, and a checkpoint holds the whole optimiser and grid state, so a resumed
//! run reproduces an uninterrupted one exactly (when both stop on a step count).
//!
//! (Over 800 lines by choice: the config, the validation set and the [`Trainer`]'s step,
//! validate, checkpoint and resume cycle share private state and read best top to bottom;
//! the model-specific work lives in [`crate::models`] and `--model auto`'s decisions in
//! [`crate::auto`].)

use crate::auto::{AutoConfig, PlateauStop};
use crate::checkpoint::{self, CheckpointError, StateDict};
use crate::data::{Background, DataError, SceneBounds, TrainData, ViewPixels, pixel_ray};
use crate::kernels::{stream, uniform};
use crate::models::fast::FastModel;
use crate::models::{Model, ModelConfig, StepStats, StepTimings};
use crate::supervision::SupervisionConfig;
use burn::config::Config;
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Errors of training.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// Data problems.
    #[error(transparent)]
    Data(#[from] DataError),
    /// Checkpoint problems.
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    /// File problems.
    #[error(transparent)]
    Io(#[from] dataset::DatasetError),
    /// A file operation failed.
    #[error("{path}: {source}")]
    File {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// Anything else, with its explanation.
    #[error("{0}")]
    Invalid(String),
}

/// Every setting of a training run.
#[derive(Config, Debug)]
pub struct TrainConfig {
    /// The dataset folder.
    pub dataset: PathBuf,
    /// The model and its settings.
    pub model: ModelConfig,
    /// Seed of every random choice (initialisation, batches, jitter, grid updates).
    #[config(default = 0)]
    pub seed: u64,
    /// Stop after this many steps (at least one of `steps`, `time_budget_s`).
    #[config(default = "None")]
    pub steps: Option<u64>,
    /// Stop after this much training time (seconds, validation excluded).
    #[config(default = "None")]
    pub time_budget_s: Option<f64>,
    /// Rays per batch; with `batch_samples` set, the rays of the first step only.
    pub batch_rays: usize,
    /// Target samples per step (instant-ngp's batching): when set, step `k > 0` draws
    /// `batch_samples / s̄` rays, where `s̄` is a running mean (weight 0.2 on the latest step)
    /// of the samples per ray the model took, clamped to `[64, max_batch_rays]`; so the cost
    /// of a step stays constant as the occupancy grid empties space.
    #[config(default = "None")]
    pub batch_samples: Option<usize>,
    /// Most rays per step when batching by samples.
    #[config(default = 65536)]
    pub max_batch_rays: usize,
    /// Initial learning rate.
    pub lr_init: f64,
    /// Final learning rate, reached at `lr_decay_steps` by exponential decay and kept after.
    pub lr_final: f64,
    /// Steps of the learning-rate decay.
    pub lr_decay_steps: u64,
    /// Integer image downscale factor.
    #[config(default = 1)]
    pub downscale: u32,
    /// Background for transparent pixels.
    #[config(default = "Background::White")]
    pub background: Background,
    /// Scene bounds; resolved from the dataset before step 0 and recorded here.
    #[config(default = "None")]
    pub bounds: Option<SceneBounds>,
    /// Padding of the scene-facts box, as a fraction of its largest side.
    #[config(default = 0.05)]
    pub bounds_padding: f32,
    /// Scene radius assumed around the cameras' look-at point when the dataset has no facts
    /// (√3: the half-diagonal of the [−1, 1]³ cube of the Blender scenes).
    #[config(default = 1.732_050_8)]
    pub assumed_scene_radius: f32,
    /// Steps between training metric lines.
    #[config(default = 25)]
    pub log_interval_steps: u64,
    /// Steps between checkpoints.
    #[config(default = 500)]
    pub checkpoint_interval_steps: u64,
    /// Checkpoints kept.
    #[config(default = 2)]
    pub checkpoints_kept: usize,
    /// Training seconds between validations (None: a tenth of the time budget, or 30 s).
    #[config(default = "None")]
    pub val_interval_s: Option<f64>,
    /// Most val views used for validation during training.
    #[config(default = 4)]
    pub val_max_views: usize,
    /// Most val pixels used for validation during training.
    #[config(default = 4096)]
    pub val_max_pixels: usize,
    /// Stop early when the val PSNR plateaus (see [`crate::auto::plateau_reached`]).
    #[config(default = "None")]
    pub plateau_stop: Option<PlateauStop>,
    /// Content hash of the dataset the run trains on ([`dataset_hash`]: its transforms files and
    /// every train and validation view's files), recorded when the run starts; resuming on a
    /// dataset whose views or poses changed since is refused. `None` in configs written before.
    #[config(default = "None")]
    pub dataset_hash: Option<String>,
    /// `--model auto`: the sizing rules' settings; the model, bounds and stopping rule are
    /// resolved from the dataset before step 0 ([`crate::auto::decide`]).
    #[config(default = "None")]
    pub auto: Option<AutoConfig>,
    /// One line per decision `auto` made, with its reason (`None` until resolved; a resolved
    /// config is used as recorded, so a resumed run rebuilds the same model).
    #[config(default = "None")]
    pub auto_reasons: Option<Vec<String>>,
    /// Pending decision of `auto` on a dataset without scene facts and ground-truth depth: the
    /// step after which the trainer tests view dependence on the depth the model has learned
    /// ([`crate::auto::view_dependence_from_model`]); `None` once decided (or never needed).
    #[config(default = "None")]
    pub view_test_at: Option<u64>,
    /// Supervision beyond colour from the dataset's ground truth ([`crate::supervision`]:
    /// depth and empty-space terms); `None`: colour only.
    #[config(default = "None")]
    pub supervision: Option<SupervisionConfig>,
    /// Seeded noise on the training views' poses ([`crate::poses`]); `None`: the exact poses.
    #[config(default = "None")]
    pub pose_noise: Option<crate::poses::PoseNoise>,
    /// Camera refinement: one SE(3) correction per training view learned with the field
    /// ([`crate::camera_opt`]); `None`: the poses as given.
    #[config(default = "None")]
    pub camera_opt: Option<crate::camera_opt::CameraOptConfig>,
}

impl TrainConfig {
    /// The published defaults of a model kind ([`ModelConfig::names`]) with its training preset
    /// ([`crate::models::ModelKind::preset`]).
    ///
    /// `"auto"` is the `fast` preset whose model is sized from the dataset when the trainer
    /// starts ([`crate::auto`]).
    pub fn preset(kind: &str, dataset: PathBuf) -> Result<Self, String> {
        if kind == "auto" {
            return Ok(Self::preset("fast", dataset)?.with_auto(Some(AutoConfig::new())));
        }
        let model = ModelConfig::named(kind).ok_or_else(|| format!("unknown model '{kind}' ({} or auto)", ModelConfig::names().join(", ")))?;
        let p = model.kind().preset();
        Ok(TrainConfig::new(dataset, model, p.batch_rays, p.lr_init, p.lr_final, p.lr_decay_steps)
            .with_batch_samples(p.batch_samples)
            .with_background(p.background))
    }

    /// The model's name as chosen: `"auto"` for an auto-sized run, else the model kind.
    pub fn model_label(&self) -> &'static str {
        if self.auto.is_some() { "auto" } else { self.model.name() }
    }

    /// Rays of the next step given the running mean of samples per ray (0 before any step).
    pub fn rays_for(&self, samples_per_ray: f64) -> usize {
        match self.batch_samples {
            Some(target) if samples_per_ray > 0.0 => {
                ((target as f64 / samples_per_ray).round() as usize).clamp(64, self.max_batch_rays.max(64))
            }
            _ => self.batch_rays,
        }
    }

    /// Learning rate at `step`: lr_init · (lr_final / lr_init)^min(step / decay_steps, 1).
    pub fn lr(&self, step: u64) -> f64 {
        let f = (step as f64 / self.lr_decay_steps.max(1) as f64).min(1.0);
        self.lr_init * (self.lr_final / self.lr_init).powf(f)
    }

    /// Validation interval in training seconds.
    pub fn val_interval(&self) -> f64 {
        self.val_interval_s.unwrap_or_else(|| self.time_budget_s.map_or(30.0, |t| t / 10.0)).max(1e-3)
    }

    /// Refuses settings no run can use (before anything is written), naming the field: no
    /// budget, a zero or negative budget, empty or impossibly large batches, a learning rate
    /// that is not positive, a zero downscale factor, logging or checkpoint interval, bounds
    /// ([`SceneBounds::check`]) or model settings ([`ModelConfig::check`]) out of range.
    pub fn check(&self) -> Result<(), String> {
        if let Some(n) = self.pose_noise {
            format!("{},{}", n.rotation_deg, n.translation_rel).parse::<crate::poses::PoseNoise>().map_err(|e| format!("pose_noise: {e}"))?;
        }
        if let Some(c) = &self.camera_opt {
            c.check()?;
        }
        if self.supervision.as_ref().is_some_and(SupervisionConfig::uses_normals) && matches!(self.model, ModelConfig::Paper(_)) {
            return Err("the normal loss (--normal-loss) is built for the hash-grid models (fast, auto), not the paper model".into());
        }
        if self.steps.is_none() && self.time_budget_s.is_none() {
            return Err("give a step count or a time budget".into());
        }
        if self.steps == Some(0) {
            return Err("steps must be positive (0 steps train nothing)".into());
        }
        if let Some(t) = self.time_budget_s
            && !(t.is_finite() && t > 0.0)
        {
            return Err(format!("the time budget must be a positive number of seconds, not {t}"));
        }
        if self.downscale == 0 {
            return Err("downscale must be a positive integer factor".into());
        }
        if self.log_interval_steps == 0 || self.checkpoint_interval_steps == 0 || self.checkpoints_kept == 0 {
            return Err("log_interval_steps, checkpoint_interval_steps and checkpoints_kept must be positive".into());
        }
        for (name, v) in [("lr_init", self.lr_init), ("lr_final", self.lr_final)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{name} must be a finite learning rate > 0, not {v}"));
            }
        }
        // Beyond these a step's buffers alone exceed any machine this runs on (out-of-memory
        // kills instead of an error).
        const MOST_RAYS: usize = 1 << 22;
        const MOST_SAMPLES: usize = 1 << 26;
        for (name, v, most) in [
            ("batch_rays", self.batch_rays, MOST_RAYS),
            ("max_batch_rays", self.max_batch_rays, MOST_RAYS),
            ("batch_samples", self.batch_samples.unwrap_or(1), MOST_SAMPLES),
        ] {
            if v == 0 || v > most {
                return Err(format!("{name} must be 1..={most}, not {v}"));
            }
        }
        if !(self.bounds_padding.is_finite() && self.bounds_padding >= 0.0) {
            return Err(format!("bounds_padding must be a finite fraction ≥ 0, not {}", self.bounds_padding));
        }
        if !(self.assumed_scene_radius.is_finite() && self.assumed_scene_radius > 0.0) {
            return Err(format!("assumed_scene_radius must be a finite length > 0, not {}", self.assumed_scene_radius));
        }
        if let Some(v) = self.val_interval_s
            && !(v.is_finite() && v > 0.0)
        {
            return Err(format!("val_interval_s must be a positive number of seconds, not {v}"));
        }
        if let Some(b) = &self.bounds {
            b.check()?;
        }
        self.model.check()?;
        if let Some(s) = &self.supervision {
            s.check()?;
        }
        Ok(())
    }

    /// Refuses a downscale factor that does not divide every view of `ds` into whole blocks
    /// ([`dataset::check_downscale`]: zero, larger than an image, or not a divisor of its size).
    pub fn check_image_sizes(&self, ds: &dataset::Dataset) -> Result<(), String> {
        for f in ds.train.iter().chain(&ds.val).chain(&ds.test) {
            dataset::check_downscale("downscale", self.downscale, &f.camera.intrinsics)
                .map_err(|e| format!("{e} ({})", f.image_path.display()))?;
        }
        Ok(())
    }

    /// Reads a config written by a run.
    pub fn read(path: &Path) -> Result<Self, TrainError> {
        let bytes = dataset::io::read(path)?;
        serde_json::from_slice(&bytes).map_err(|e| TrainError::Invalid(format!("{}: {e}", path.display())))
    }
}

/// Validation pixels: fixed views and pixels, their rays, targets and ground truth.
#[derive(Debug, Default)]
struct ValSet {
    origins: Vec<[f32; 3]>,
    dirs: Vec<[f32; 3]>,
    target: Vec<[f32; 3]>,
    /// (camera index, pixel x + 0.5, y + 0.5, gt z-depth) for pixels with gt alpha 1.
    depth: Vec<(usize, f64, f64, f32)>,
    cameras: Vec<dataset::Camera>,
    pixel_of: Vec<usize>,
}

impl ValSet {
    fn load(frames: &[dataset::Frame], cfg: &TrainConfig) -> Result<Self, TrainError> {
        let mut set = ValSet::default();
        if frames.is_empty() || cfg.val_max_views == 0 {
            return Ok(set);
        }
        let nv = cfg.val_max_views.min(frames.len());
        let picks: Vec<usize> = (0..nv).map(|k| k * frames.len() / nv).collect();
        let bg = cfg.background.eval_color();
        let per_view = cfg.val_max_pixels.div_ceil(nv);
        for (vi, &f) in picks.iter().enumerate() {
            let view = ViewPixels::load(&frames[f], cfg.downscale, true)?;
            let n = view.pixels();
            let w = view.camera.intrinsics.width as usize;
            set.cameras.push(view.camera);
            let mut chosen: Vec<usize> = if per_view >= n {
                (0..n).collect()
            } else {
                let mut v: Vec<(u64, usize)> = (0..n)
                    .map(|p| ((uniform(cfg.seed, stream::VAL, f as u64, p as u64) * 16_777_216.0) as u64, p))
                    .collect();
                v.sort_unstable();
                v.into_iter().take(per_view).map(|(_, p)| p).collect()
            };
            chosen.sort_unstable();
            for p in chosen {
                let (o, d) = pixel_ray(&view.camera, p);
                set.origins.push(o);
                set.dirs.push(d);
                set.target.push(view.color(p, bg));
                set.pixel_of.push(vi);
                if let Some((depth, alpha)) = &view.gt
                    && alpha[p] >= 0.999
                {
                    set.depth.push((set.origins.len() - 1, (p % w) as f64 + 0.5, (p / w) as f64 + 0.5, depth[p]));
                }
            }
        }
        Ok(set)
    }
}

/// Results of a validation pass.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ValMetrics {
    /// PSNR over the validation pixels (display values, peak 1).
    pub val_psnr: f64,
    /// Mean |z-depth − gt z-depth| over validation pixels with gt alpha 1, when available.
    pub val_depth_mae: Option<f64>,
    /// Seconds the pass took (not on the training clock).
    pub eval_s: f64,
}

/// A progress report after each step.
#[derive(Clone, Debug)]
pub struct Progress {
    /// Steps done.
    pub step: u64,
    /// Training seconds so far.
    pub wall_s: f64,
    /// The step's loss.
    pub loss: f32,
    /// The step's train PSNR.
    pub train_psnr: f64,
    /// Rays per second of training (running average over the logging window).
    pub rays_per_s: f64,
    /// Fraction of the run done (by steps or by time, whichever is nearer its end).
    pub fraction: f64,
    /// Latest validation PSNR.
    pub val_psnr: Option<f64>,
}

/// How a [`Trainer::run`] ended.
#[derive(Clone, Debug)]
pub struct Summary {
    /// Steps done.
    pub steps: u64,
    /// Training seconds.
    pub wall_s: f64,
    /// Stopped by the stop flag (Ctrl-C) rather than by reaching the budget.
    pub interrupted: bool,
    /// Final validation, if any val views.
    pub val: Option<ValMetrics>,
    /// Steps skipped for non-finite values.
    pub skipped_nonfinite: u64,
    /// Stopped by the plateau rule ([`TrainConfig::plateau_stop`]) before the budget.
    pub plateaued: bool,
}

#[derive(Clone, Debug, Default)]
struct Window {
    loss: f64,
    mse: f64,
    steps: u64,
    time: f64,
    rays: u64,
    samples: u64,
    /// Samples marched (the fast model's [`StepStats::marched`], as far along each ray as its
    /// compaction reached; the paper model's samples).
    marched: u64,
}

/// A training run in progress.
#[derive(Debug)]
pub struct Trainer {
    /// The settings (bounds resolved).
    pub config: TrainConfig,
    /// The run folder.
    pub run_dir: PathBuf,
    /// The model.
    pub model: Model,
    /// The training views (public so that tests can plant faults, e.g. a NaN target pixel).
    pub data: TrainData,
    val: ValSet,
    /// Steps done.
    pub step: u64,
    /// Training seconds so far.
    pub wall_s: f64,
    /// Steps skipped for non-finite loss or gradients.
    pub skipped_nonfinite: u64,
    /// Running mean of the samples per ray (drives the rays per step with `batch_samples`).
    pub samples_per_ray: f64,
    next_val_at: f64,
    window: Window,
    last_val: Option<f64>,
    /// (training seconds, val PSNR) of every validation so far (the plateau rule's input).
    val_history: Vec<(f64, f64)>,
    /// Accumulated time split over all steps of this process.
    pub timings: StepTimings,
    /// What [`Trainer::start`] has to write: a fresh run's config, or a resumed run's
    /// checkpoints to set aside (`--fallback`) and history to cut back to its checkpoint.
    pending: Pending,
    /// The damaged checkpoints a fallback resume skipped, each with why it did not load.
    pub skipped_checkpoints: Vec<(PathBuf, String)>,
    /// Camera refinement's corrections, when the run refines its cameras.
    pub camera: Option<crate::camera_opt::CameraOpt>,
    /// The training poses' record ([`crate::poses::POSES_FILE`]), with noise or refinement.
    poses: Option<crate::poses::PoseRecord>,
}

/// How [`Trainer::prepare`] starts: a new run, or continuing the run in the folder.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Start {
    /// A new run: `config.json` and an empty `metrics.jsonl` are written.
    Fresh,
    /// Continue from the newest checkpoint; refused when it does not load.
    Resume,
    /// Continue from the newest checkpoint that loads; newer damaged ones are renamed
    /// `<name>.damaged` (never deleted) so that the run goes on from the good one.
    ResumeFallback,
}

/// The writes [`Trainer::start`] makes, decided by [`Trainer::prepare`].
#[derive(Debug, Default)]
struct Pending {
    /// Write `config.json` and an empty `metrics.jsonl` (a fresh run).
    fresh: bool,
    /// Damaged checkpoints to rename `<name>.damaged`.
    set_aside: Vec<PathBuf>,
    /// The metrics history up to the resumed checkpoint, written with the first new line (so a
    /// resume that fails or stops at once leaves the history as it was).
    history: Option<String>,
}

/// The file name of the config inside a run folder.
pub const CONFIG_FILE: &str = "config.json";
/// The file name of the metrics log inside a run folder.
pub const METRICS_FILE: &str = "metrics.jsonl";

/// Decides `auto` for `config` (whose model must be `fast`) with [`crate::auto::decide`] and
/// writes the decisions and their reasons into it. Does nothing when `config.auto` is `None`
/// or already resolved (`auto_reasons` set, e.g. a resumed run).
fn apply_auto(config: &mut TrainConfig, ds: &dataset::Dataset, data: &mut TrainData) -> Result<(), String> {
    let Some(auto) = config.auto.clone() else { return Ok(()) };
    if config.auto_reasons.is_some() {
        return Ok(());
    }
    let ModelConfig::Fast(fast) = config.model.clone() else {
        return Err("auto sizes the fast model; the config's model is not fast".into());
    };
    let run = crate::auto::RunSettings {
        bounds: config.bounds.clone(),
        bounds_padding: config.bounds_padding,
        assumed_scene_radius: config.assumed_scene_radius,
        downscale: config.downscale,
        seed: config.seed,
        time_budget_s: config.time_budget_s,
        val_interval_s: config.val_interval_s,
    };
    let d = crate::auto::decide(&auto, fast, &run, ds, data)?;
    config.model = ModelConfig::Fast(d.fast);
    config.bounds = Some(d.bounds);
    if d.view_test_at.is_some() {
        config.view_test_at = d.view_test_at;
    }
    config.val_interval_s = Some(d.val_interval_s);
    config.plateau_stop = Some(d.plateau_stop);
    config.auto_reasons = Some(d.reasons);
    Ok(())
}

impl Trainer {
    /// Prepares a run: loads the data, resolves the bounds and writes `config.json` (fresh
    /// runs), or reads the latest checkpoint (`resume`): [`Trainer::prepare`] then
    /// [`Trainer::start`]. The dataset's files must lie inside its folder
    /// ([`dataset::LoadOptions`]' default; [`Trainer::with_load_options`] takes others).
    pub fn new(config: TrainConfig, run_dir: &Path, resume: bool) -> Result<Self, TrainError> {
        Self::with_load_options(config, run_dir, resume, &dataset::LoadOptions::default())
    }

    /// [`Trainer::new`], loading the dataset with `load` (e.g. frame files admitted outside
    /// its folder).
    pub fn with_load_options(config: TrainConfig, run_dir: &Path, resume: bool, load: &dataset::LoadOptions) -> Result<Self, TrainError> {
        let mut t = Self::prepare(config, run_dir, if resume { Start::Resume } else { Start::Fresh }, load)?;
        t.start()?;
        Ok(t)
    }

    /// Everything [`Trainer::new`] does before it writes: validates the config and the dataset
    /// (loaded with `load`), loads the data and, resuming, the checkpoint and the metrics
    /// history (refused when a line of it, but a torn last one, is damaged). Nothing in
    /// `run_dir` is written or removed but stale temporaries of a run, so a caller can validate
    /// every input before it replaces an old run (`train --force`), then call
    /// [`Trainer::start`].
    pub fn prepare(mut config: TrainConfig, run_dir: &Path, start: Start, load: &dataset::LoadOptions) -> Result<Self, TrainError> {
        let resume = start != Start::Fresh;
        config.check().map_err(TrainError::Invalid)?;
        let mut ds = crate::data::load_dataset(&config.dataset, load)?;
        config.check_image_sizes(&ds).map_err(TrainError::Invalid)?;
        // Noisy poses replace the training views' before anything reads a camera. Refined runs
        // record the poses too (the given ones, when there is no noise).
        let noise = config.pose_noise.or(config.camera_opt.map(|_| crate::poses::PoseNoise { rotation_deg: 0.0, translation_rel: 0.0 }));
        let poses = noise.map(|n| crate::poses::perturb_training_views(&mut ds, n, config.seed));
        if config.camera_opt.is_some() && ds.train.len() < 3 {
            return Err(TrainError::Invalid(format!(
                "{}: camera refinement (--camera-opt se3) needs at least 3 training views and the dataset has {}: with fewer, the refined poses' errors against the true ones are not defined (no similarity aligns them)",
                config.dataset.display(),
                ds.train.len()
            )));
        }
        let mut data = TrainData::load(&ds.train, config.downscale, config.background, false)?;
        apply_auto(&mut config, &ds, &mut data).map_err(TrainError::Invalid)?;
        // Mixed-pixel masks, unless a fresh `auto` run's resolve built them already.
        if let Some(k) = config.model.kind().mixed_pixel_footprints()
            && !data.has_mixed()
        {
            let depths = crate::data::frame_depths(&ds.train, config.downscale)?;
            data.set_mixed(data.mixed_masks(depths.as_deref(), k))?;
        }
        if config.bounds.is_none() {
            let cams: Vec<_> = ds.train.iter().map(|f| f.camera).collect();
            config.bounds = Some(SceneBounds::for_dataset(
                ds.facts.as_ref(),
                &cams,
                config.bounds_padding,
                config.assumed_scene_radius,
            ));
        }
        let bounds = config.bounds.clone().unwrap_or_else(|| unreachable!());
        if let Some(sup) = &config.supervision {
            if ds.train.iter().any(|f| f.gt_path.is_none()) {
                let what = if sup.uses_depth() {
                    "--depth-loss"
                } else if sup.uses_normals() {
                    "--normal-loss"
                } else {
                    "--empty-loss"
                };
                return Err(TrainError::Invalid(format!(
                    "{}: the dataset has no ground-truth depth and alpha files (gt_file_path, r_<k>_gt.exr) for its train views, which {what} needs: train on a dataset rendered by `cargo xtask render`, or without {what}",
                    config.dataset.display()
                )));
            }
            data.set_supervision(sup, &ds.train, config.downscale, config.seed, bounds.near, bounds.far)?;
        }
        let val_frames = if ds.val.is_empty() { &ds.test } else { &ds.val };
        let val = ValSet::load(val_frames, &config)?;
        let mut model = config.model.init(&bounds, config.seed).map_err(TrainError::Invalid)?;
        let camera = match (&config.camera_opt, &poses) {
            (Some(c), Some(p)) => {
                model.set_ray_gradients(crate::models::RayGradients::Also).map_err(|e| {
                    TrainError::Invalid(format!("camera refinement (--camera-opt se3): {e} (the {} model)", config.model_label()))
                })?;
                Some(crate::camera_opt::CameraOpt::new(*c, ds.train.len(), p.scene_size))
            }
            _ => None,
        };
        std::fs::create_dir_all(run_dir).map_err(|e| dataset::DatasetError::write(run_dir, e))?;
        checkpoint::remove_stale_temporaries(run_dir, &[CONFIG_FILE, METRICS_FILE, crate::poses::POSES_FILE, crate::poses::CAMERA_OPT_EXPORT])?;
        if let Some(p) = &poses {
            dataset::io::atomic_write_json(&run_dir.join(crate::poses::POSES_FILE), p)?;
        }
        let mut t = Self {
            next_val_at: config.val_interval(),
            config,
            run_dir: run_dir.to_path_buf(),
            model,
            data,
            val,
            step: 0,
            wall_s: 0.0,
            skipped_nonfinite: 0,
            samples_per_ray: 0.0,
            window: Window::default(),
            last_val: None,
            val_history: Vec::new(),
            timings: StepTimings::default(),
            pending: Pending::default(),
            skipped_checkpoints: Vec::new(),
            camera,
            poses,
        };
        let have_ckpt = checkpoint::latest(run_dir).is_some();
        let hash = dataset_hash(&ds, val_frames)?;
        if resume && have_ckpt {
            if let Some(recorded) = &t.config.dataset_hash
                && *recorded != hash
            {
                return Err(TrainError::Invalid(format!(
                    "{}: the dataset changed since this run started (content hash {hash}, recorded {recorded}): its views or poses are not the ones the checkpoint learned; train into a new --out, or without --resume to start over",
                    t.config.dataset.display()
                )));
            }
            let (path, s) = if start == Start::ResumeFallback {
                let (path, s, skipped) = checkpoint::load_latest_good(run_dir)?;
                t.pending.set_aside = skipped.iter().map(|(p, _)| p.clone()).collect();
                t.skipped_checkpoints = skipped.into_iter().map(|(p, e)| (p, e.to_string())).collect();
                (path, s)
            } else {
                checkpoint::load_latest(run_dir)?
            };
            t.load_state(&s).map_err(|e| match e {
                TrainError::Invalid(m) => TrainError::Invalid(format!("{}: {m}", path.display())),
                e => e,
            })?;
            let history = metrics_history(&run_dir.join(METRICS_FILE), t.step)?;
            t.reload_val_history(&history);
            t.pending.history = Some(history);
        } else {
            t.config.dataset_hash = Some(hash);
            t.pending.fresh = true;
        }
        Ok(t)
    }

    /// The writes that start the run [`Trainer::prepare`] validated: a fresh run's
    /// `config.json` and empty `metrics.jsonl`; a fallback resume's damaged checkpoints renamed
    /// `<name>.damaged`. (A resumed run's history is cut back with its first new metrics line.)
    pub fn start(&mut self) -> Result<(), TrainError> {
        for p in std::mem::take(&mut self.pending.set_aside) {
            let mut aside = p.clone().into_os_string();
            aside.push(".damaged");
            std::fs::rename(&p, &aside).map_err(|e| TrainError::File { path: p.clone(), source: e })?;
        }
        if std::mem::take(&mut self.pending.fresh) {
            dataset::io::atomic_write_json(&self.run_dir.join(CONFIG_FILE), &self.config)?;
            dataset::io::atomic_write(&self.run_dir.join(METRICS_FILE), b"")?;
        }
        Ok(())
    }

    /// Continues the run in `run_dir` from its latest checkpoint with the config it recorded
    /// (refused when the dataset's content changed since, see [`TrainConfig::dataset_hash`]).
    pub fn resume(run_dir: &Path) -> Result<Self, TrainError> {
        let config = TrainConfig::read(&run_dir.join(CONFIG_FILE))?;
        Self::new(config, run_dir, true)
    }

    /// Whether the budget (steps or time) is used up, or the val PSNR has plateaued.
    pub fn finished(&self) -> bool {
        self.budget_used() || self.plateaued()
    }

    fn budget_used(&self) -> bool {
        self.config.steps.is_some_and(|s| self.step >= s) || self.config.time_budget_s.is_some_and(|t| self.wall_s >= t)
    }

    /// Whether the plateau rule, if any, says stop.
    pub fn plateaued(&self) -> bool {
        self.config.plateau_stop.as_ref().is_some_and(|p| crate::auto::plateau_reached(&self.val_history, p))
    }

    /// Rebuilds the validation history (and the latest val PSNR) from the metrics history, for
    /// a resumed run's plateau rule.
    fn reload_val_history(&mut self, history: &str) {
        self.val_history = history
            .lines()
            .filter_map(|l| {
                let v = serde_json::from_str::<serde_json::Value>(l).ok()?;
                Some((v.get("wall_s")?.as_f64()?, v.get("val_psnr")?.as_f64()?))
            })
            .collect();
        self.last_val = self.val_history.last().map(|p| p.1);
    }

    fn fraction(&self) -> f64 {
        let a = self.config.steps.map_or(0.0, |s| self.step as f64 / s.max(1) as f64);
        let b = self.config.time_budget_s.map_or(0.0, |t| self.wall_s / t.max(1e-9));
        a.max(b).min(1.0)
    }

    /// One training step (batch of step `self.step`), on the training clock.
    pub fn step_once(&mut self) -> StepStats {
        let t0 = Instant::now();
        let lr = self.config.lr(self.step);
        self.model.set_lr(lr);
        let rays = self.config.rays_for(self.samples_per_ray);
        let mut batch = self.data.batch(self.config.seed, self.step, rays);
        if let Some(c) = &self.camera {
            c.apply(&mut batch);
        }
        let batch_s = t0.elapsed().as_secs_f64();
        let mut stats = self.model.train_step(&batch, self.step, self.config.seed);
        stats.timings.phases.batch = batch_s;
        if let (Some(c), Some(g)) = (&mut self.camera, stats.ray_grads.take()) {
            let grads = c.gradients_and_rays(&batch, &g);
            let lr = c.lr(self.step, lr / self.config.lr_init);
            c.accumulate_and_step(&grads, lr);
        }
        if stats.samples > 0 {
            let spr = stats.samples as f64 / rays as f64;
            self.samples_per_ray = if self.samples_per_ray > 0.0 { 0.8 * self.samples_per_ray + 0.2 * spr } else { spr };
        }
        self.step += 1;
        // A non-finite loss is never applied (the models check it before updating), and is
        // counted even where a model had nothing to update (no samples).
        if stats.skipped_nonfinite || !stats.loss.is_finite() {
            self.skipped_nonfinite += 1;
        }
        let dt = t0.elapsed().as_secs_f64();
        self.wall_s += dt;
        self.timings.add(&stats.timings);
        if stats.loss.is_finite() {
            self.window.loss += stats.loss as f64;
            self.window.mse += stats.mse as f64;
            self.window.steps += 1;
        }
        self.window.time += dt;
        self.window.rays += batch.origins.len() as u64;
        self.window.samples += stats.samples as u64;
        self.window.marched += stats.marched.max(stats.samples) as u64;
        stats
    }

    fn rays_per_s(&self) -> f64 {
        self.window.rays as f64 / self.window.time.max(1e-9)
    }

    fn log_window(&mut self) -> Result<(), TrainError> {
        let w = std::mem::take(&mut self.window);
        let n = w.steps.max(1) as f64;
        let line = serde_json::json!({
            "step": self.step,
            "wall_s": self.wall_s,
            "loss": w.loss / n,
            "train_psnr": psnr(w.mse / n),
            "rays_per_s": w.rays as f64 / w.time.max(1e-9),
            "samples_per_ray": w.samples as f64 / w.rays.max(1) as f64,
            "marched_per_ray": w.marched as f64 / w.rays.max(1) as f64,
            "lr": self.config.lr(self.step),
            "skipped_nonfinite": self.skipped_nonfinite,
        });
        self.append_metrics(&line)
    }

    /// A resumed run's history cut back to its checkpoint, once a newer checkpoint exists
    /// (the lines it drops belong to steps that checkpoint replaces).
    fn write_pending_history(&mut self) -> Result<(), TrainError> {
        match self.pending.history.take() {
            Some(history) => Ok(dataset::io::atomic_write(&self.run_dir.join(METRICS_FILE), history.as_bytes())?),
            None => Ok(()),
        }
    }

    fn append_metrics(&mut self, line: &serde_json::Value) -> Result<(), TrainError> {
        let path = self.run_dir.join(METRICS_FILE);
        // A resumed run's first line: the history up to its checkpoint and the line, at once.
        if let Some(mut history) = self.pending.history.take() {
            history.push_str(&format!("{line}\n"));
            return Ok(dataset::io::atomic_write(&path, history.as_bytes())?);
        }
        let mut f = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .map_err(|e| dataset::DatasetError::write(&path, e))?;
        // One write call per line: a process killed mid-line would otherwise leave a torn line.
        f.write_all(format!("{line}\n").as_bytes()).map_err(|e| dataset::DatasetError::write(&path, e))?;
        Ok(())
    }

    /// Evaluates the validation pixels (off the training clock).
    pub fn validate(&self) -> Option<ValMetrics> {
        if self.val.origins.is_empty() {
            return None;
        }
        let t0 = Instant::now();
        let out = self.model.render_rays(&self.val.origins, &self.val.dirs, self.config.background.eval_color());
        let mse = out
            .rgb
            .iter()
            .zip(&self.val.target)
            .map(|(a, b)| (0..3).map(|k| ((a[k] - b[k]) as f64).powi(2)).sum::<f64>())
            .sum::<f64>()
            / (3 * out.rgb.len()).max(1) as f64;
        let depth = (!self.val.depth.is_empty()).then(|| {
            self.val
                .depth
                .iter()
                .map(|&(i, px, py, gt)| {
                    let cam = &self.val.cameras[self.val.pixel_of[i]];
                    (cam.z_depth_from_distance(px, py, out.distance[i] as f64) - gt as f64).abs()
                })
                .sum::<f64>()
                / self.val.depth.len() as f64
        });
        Some(ValMetrics { val_psnr: psnr(mse), val_depth_mae: depth, eval_s: t0.elapsed().as_secs_f64() })
    }

    fn log_val(&mut self) -> Result<Option<ValMetrics>, TrainError> {
        let v = self.validate();
        if let Some(m) = &v {
            let mut line = serde_json::json!({
                "step": self.step,
                "wall_s": self.wall_s,
                "val_psnr": m.val_psnr,
                "eval_s": m.eval_s,
            });
            if let Some(d) = m.val_depth_mae {
                line["val_depth_mae"] = serde_json::json!(d);
            }
            self.append_metrics(&line)?;
            self.last_val = Some(m.val_psnr);
            self.val_history.push((self.wall_s, m.val_psnr));
        }
        Ok(v)
    }

    /// Writes a checkpoint of the current state.
    pub fn save_checkpoint(&self) -> Result<PathBuf, TrainError> {
        let mut s = self.model.state();
        s.scalars.insert("trainer.step".into(), self.step as f64);
        s.scalars.insert("trainer.wall_s".into(), self.wall_s);
        s.scalars.insert("trainer.skipped_nonfinite".into(), self.skipped_nonfinite as f64);
        s.scalars.insert("trainer.next_val_at".into(), self.next_val_at);
        s.scalars.insert("trainer.samples_per_ray".into(), self.samples_per_ray);
        let w = &self.window;
        for (k, v) in [
            ("loss", w.loss),
            ("mse", w.mse),
            ("steps", w.steps as f64),
            ("time", w.time),
            ("rays", w.rays as f64),
            ("samples", w.samples as f64),
            ("marched", w.marched as f64),
        ] {
            s.scalars.insert(format!("trainer.window.{k}"), v);
        }
        if let Some(c) = &self.camera {
            c.save(&mut s);
        }
        let path = checkpoint::save(&self.run_dir, self.step, &s, self.config.checkpoints_kept)?;
        self.write_refined_poses()?;
        Ok(path)
    }

    /// The refined poses so far, into the run folder's pose record (and the nerfstudio-style
    /// export next to it), when the run refines its cameras.
    pub fn write_refined_poses(&self) -> Result<(), TrainError> {
        let (Some(c), Some(p)) = (&self.camera, &self.poses) else { return Ok(()) };
        let record = p.with_refined(|k, pose| c.corrected_pose(k, pose), c.params.clone());
        dataset::io::atomic_write_json(&self.run_dir.join(crate::poses::POSES_FILE), &record)?;
        let ns = record.nerfstudio_export();
        dataset::io::atomic_write_json(&self.run_dir.join(crate::poses::CAMERA_OPT_EXPORT), &ns)?;
        Ok(())
    }

    fn load_state(&mut self, s: &StateDict) -> Result<(), TrainError> {
        self.model.load_state(s).map_err(TrainError::Invalid)?;
        if let Some(c) = &mut self.camera {
            c.load(s).map_err(TrainError::Invalid)?;
        }
        let g = |k: &str| s.scalar(k).map_err(TrainError::Invalid);
        let n = |k: &str| s.count(k).map_err(TrainError::Invalid);
        self.step = n("trainer.step")?;
        self.wall_s = g("trainer.wall_s")?;
        self.skipped_nonfinite = n("trainer.skipped_nonfinite")?;
        self.next_val_at = g("trainer.next_val_at")?;
        self.samples_per_ray = g("trainer.samples_per_ray")?;
        self.window = Window {
            loss: g("trainer.window.loss")?,
            mse: g("trainer.window.mse")?,
            steps: n("trainer.window.steps")?,
            time: g("trainer.window.time")?,
            rays: n("trainer.window.rays")?,
            samples: n("trainer.window.samples")?,
            marched: 0,
        };
        // Checkpoints written before the count was kept hold only the evaluated samples.
        self.window.marched =
            if s.scalars.contains_key("trainer.window.marched") { n("trainer.window.marched")? } else { self.window.samples };
        Ok(())
    }

    /// Trains until the budget is used or `stop` is set (then a checkpoint is written and the
    /// run can be resumed), calling `progress` after every step.
    pub fn run(&mut self, stop: &AtomicBool, progress: &mut dyn FnMut(&Progress)) -> Result<Summary, TrainError> {
        let mut val = None;
        while !self.finished() {
            if stop.load(Ordering::SeqCst) {
                self.save_checkpoint()?;
                self.write_pending_history()?;
                return Ok(self.summary(true, val));
            }
            let stats = self.step_once();
            if self.config.view_test_at.is_some_and(|n| self.step >= n) {
                self.test_view_dependence()?;
            }
            if self.step.is_multiple_of(self.config.log_interval_steps.max(1)) {
                self.log_window()?;
            }
            if self.step.is_multiple_of(self.config.checkpoint_interval_steps.max(1)) {
                self.save_checkpoint()?;
                self.write_pending_history()?;
            }
            if self.wall_s >= self.next_val_at && !self.finished() {
                val = self.log_val()?;
                let iv = self.config.val_interval();
                while self.next_val_at <= self.wall_s {
                    self.next_val_at += iv;
                }
            }
            progress(&Progress {
                step: self.step,
                wall_s: self.wall_s,
                loss: stats.loss,
                train_psnr: psnr(stats.mse as f64),
                rays_per_s: self.rays_per_s(),
                fraction: self.fraction(),
                val_psnr: self.last_val,
            });
        }
        if self.window.steps > 0 {
            self.log_window()?;
        }
        self.save_checkpoint()?;
        val = self.log_val()?;
        Ok(self.summary(false, val))
    }

    /// `auto`'s pending view-dependence test ([`TrainConfig::view_test_at`]), on the training
    /// clock (it is part of what `auto` costs). When the colour turns out constant across
    /// views, the model continues without the direction input
    /// ([`crate::models::fast::FastModel::without_view_dependence`]: everything it learned
    /// carries over) and the view-dependent model's checkpoints are removed before the new
    /// config is written, so a resumed run never pairs one with the other. The decision
    /// replaces the provisional reason line in `config.json`.
    fn test_view_dependence(&mut self) -> Result<(), TrainError> {
        let t0 = Instant::now();
        let auto = self.config.auto.clone().unwrap_or_else(AutoConfig::new);
        let (vd, reason) = crate::auto::view_dependence_from_model(
            &self.model,
            &self.data.views,
            auto.view_spread_threshold,
            auto.spread_points,
            self.config.seed,
            self.step,
        );
        let switch = !vd && matches!(&self.config.model, ModelConfig::Fast(f) if f.is_view_dependent());
        if switch {
            if let Some(m) = self.model.downcast_ref::<FastModel>() {
                self.model = Box::new(m.without_view_dependence().map_err(TrainError::Invalid)?);
            }
            if let ModelConfig::Fast(f) = &mut self.config.model {
                f.view_dependent = Some(false);
            }
            checkpoint::remove_all(&self.run_dir)?;
        }
        let reasons = self.config.auto_reasons.get_or_insert_with(Vec::new);
        match reasons.iter_mut().find(|r| r.starts_with("view_dependent")) {
            Some(r) => *r = reason,
            None => reasons.push(reason),
        }
        self.config.view_test_at = None;
        self.wall_s += t0.elapsed().as_secs_f64();
        dataset::io::atomic_write_json(&self.run_dir.join(CONFIG_FILE), &self.config)?;
        if switch {
            self.save_checkpoint()?;
        }
        Ok(())
    }

    fn summary(&self, interrupted: bool, val: Option<ValMetrics>) -> Summary {
        Summary {
            steps: self.step,
            wall_s: self.wall_s,
            interrupted,
            val,
            skipped_nonfinite: self.skipped_nonfinite,
            plateaued: self.plateaued() && !self.budget_used(),
        }
    }
}

/// The lines of a run's `metrics.jsonl` (missing: none) that a run resumed at `step` keeps:
/// training lines before the step and at it, validation lines before it (a step's validation
/// follows its checkpoint, and the resumed run validates again). Lines past the checkpoint are
/// a killed run's and are dropped; a torn last line (no newline, not a JSON object) is dropped
/// too. Any other line that is not a JSON object with a `step` is refused, naming the file and
/// the line: a damaged history is never silently shortened.
pub fn metrics_history(path: &Path, step: u64) -> Result<String, TrainError> {
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(String::new()),
        Err(e) => return Err(TrainError::File { path: path.into(), source: e }),
    };
    let parse = |line: &[u8]| -> Result<(u64, bool), String> {
        let text = std::str::from_utf8(line).map_err(|e| format!("not UTF-8 ({e})"))?;
        let v: serde_json::Value = serde_json::from_str(text).map_err(|e| format!("not JSON ({e})"))?;
        let s = v.get("step").and_then(|s| s.as_u64()).ok_or("no whole-number \"step\"")?;
        Ok((s, v.get("val_psnr").is_some()))
    };
    let lines: Vec<&[u8]> = bytes.split(|&b| b == b'\n').collect();
    let mut kept = String::new();
    for (i, line) in lines.iter().enumerate() {
        let last = i + 1 == lines.len();
        if line.iter().all(u8::is_ascii_whitespace) {
            continue;
        }
        match parse(line) {
            Ok((s, is_val)) => {
                if s < step || (s == step && !is_val) {
                    // `parse` checked the line is UTF-8.
                    kept.push_str(&String::from_utf8_lossy(line));
                    kept.push('\n');
                }
            }
            Err(why) if last => tracing::warn!("{}: dropping its torn last line ({why})", path.display()),
            Err(why) => {
                return Err(TrainError::Invalid(format!(
                    "{}: line {} is not a metrics record ({why}); the run's history is damaged: repair or remove that line (the checkpoints are intact), or train into a new --out",
                    path.display(),
                    i + 1
                )));
            }
        }
    }
    Ok(kept)
}

/// PSNR of a mean squared error with peak 1.
pub fn psnr(mse: f64) -> f64 {
    -10.0 * mse.max(1e-12).log10()
}

/// FNV-1a 64 (hex) over the dataset's `transforms_*.json` files and every file of the train
/// views and of `val` (image, linear EXR, ground truth), each preceded by its name: what a run
/// learns from and validates on, so that editing a view, a pose or the split is noticed.
pub fn dataset_hash(ds: &dataset::Dataset, val: &[dataset::Frame]) -> Result<String, TrainError> {
    fn fnv(h: u64, bytes: &[u8]) -> u64 {
        bytes.iter().fold(h, |h, b| (h ^ *b as u64).wrapping_mul(0x0100_0000_01b3))
    }
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    let mut add = |path: &Path| -> Result<(), TrainError> {
        let bytes = dataset::paths::read_capped(path, dataset::io::MAX_FILE_BYTES).map_err(|e| TrainError::File { path: path.into(), source: e })?;
        let name = path.strip_prefix(&ds.root).unwrap_or(path).to_string_lossy().into_owned();
        h = fnv(fnv(h, name.as_bytes()), &bytes);
        Ok(())
    };
    for split in dataset::SplitKind::ALL {
        let p = ds.root.join(split.file_name());
        if p.is_file() {
            add(&p)?;
        }
    }
    for f in ds.train.iter().chain(val) {
        add(&f.image_path)?;
        for p in f.exr_path.iter().chain(&f.gt_path) {
            if p.is_file() {
                add(p)?;
            }
        }
    }
    Ok(format!("{h:016x}"))
}
