//! `cargo xtask train` and `cargo xtask render-nerf`: argument parsing, the progress bar and
//! Ctrl-C; the work is in the `nerf` crate.

use anyhow::Context;
use nerf::data::Background;
use nerf::render::RunModel;
use nerf::train::{Start, TrainConfig, Trainer};
use std::path::PathBuf;

/// Arguments of `train`.
#[derive(clap::Args)]
pub struct TrainArgs {
    /// Dataset folder (ours, or a Blender-synthetic one).
    pub dataset: Option<PathBuf>,
    /// Run folder (config.json, metrics.jsonl, checkpoints/).
    #[arg(long)]
    pub out: PathBuf,
    /// Model: paper, fast, or auto (fast sized from the scene and its cameras; the reasons go
    /// into config.json). Default fast.
    #[arg(long)]
    pub model: Option<String>,
    /// Stop after this many steps.
    #[arg(long)]
    pub steps: Option<u64>,
    /// Stop after this much training time: 90s, 5m, 1h.
    #[arg(long, allow_hyphen_values = true)]
    pub time: Option<String>,
    /// Continue the run in --out from its latest checkpoint, with its recorded config
    /// (--steps and --time may extend its budget; flags that would change other settings are
    /// refused).
    #[arg(long)]
    pub resume: bool,
    /// With --resume: when the latest checkpoint is damaged, continue from the newest one that
    /// loads; the damaged ones are renamed `<name>.damaged` (kept, never deleted).
    #[arg(long, requires = "resume")]
    pub fallback: bool,
    /// Replace a run already in --out (its config, metrics, checkpoints and the outputs of
    /// eval, mesh and render-nerf are removed first; other files stay); without it such a run is
    /// refused, so that a new run never mixes with an old one's checkpoints and outputs.
    #[arg(long, conflicts_with = "resume")]
    pub force: bool,
    /// Seed of every random choice.
    #[arg(long)]
    pub seed: Option<u64>,
    /// A config.json (e.g. from an earlier run) to start from; other flags override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Integer image downscale factor.
    #[arg(long)]
    pub downscale: Option<u32>,
    /// Background of transparent pixels: white, black or random.
    #[arg(long)]
    pub background: Option<Background>,
    /// Rays per batch (fixed: turns off batching by samples).
    #[arg(long)]
    pub batch_rays: Option<usize>,
    /// Target samples per batch (rays adapted to the samples per ray, as instant-ngp).
    #[arg(long)]
    pub batch_samples: Option<usize>,
    /// Precision of the fast (and auto) model's network products in training: fp32 (default)
    /// or bf16 (inputs of each product rounded to bf16, summed in fp32; weights stay fp32;
    /// about twice the networks' rate, on CPUs with AVX512-BF16 only).
    #[arg(long, value_parser = ["fp32", "bf16"])]
    pub mlp_precision: Option<String>,
    /// Read dataset files (transforms `file_path`, `gt_file_path`, `exr_file_path`) that lie
    /// outside the dataset folder (`../`, an absolute path, a symbolic link leading out); refused
    /// by default.
    #[arg(long)]
    pub allow_outside: bool,
    #[command(flatten)]
    pub supervision: SupervisionArgs,
    /// Noise on the training views' poses, ROT_DEG,TRANS_REL: each pose turned about its
    /// centre by an angle of that standard deviation (degrees) and its centre moved by that
    /// fraction of the scene size (RMS), seeded per view; val and test poses stay exact. The
    /// poses trained on are written to train_poses.json, and `eval` reports their error.
    #[arg(long, value_parser = parse_pose_noise, allow_hyphen_values = true)]
    pub pose_noise: Option<nerf::poses::PoseNoise>,
    /// Camera refinement: off (default) or se3, one SE(3) correction per training view learned
    /// with the field (settings in config.json's `camera_opt`). The
    /// refined poses go to train_poses.json and cameras_refined.json; `eval` reports their
    /// error against the exact poses.
    #[arg(long, value_parser = ["off", "se3"])]
    pub camera_opt: Option<String>,
}

fn parse_pose_noise(s: &str) -> Result<nerf::poses::PoseNoise, String> {
    s.parse()
}

/// Supervision beyond colour from the dataset's ground truth (formulas in the `nerf` crate's
/// `supervision` module and docs/supervision.md).
#[derive(clap::Args, Default)]
pub struct SupervisionArgs {
    /// Depth term: off (default), expected (Charbonnier on the expected depth's relative
    /// error) or termination (line-of-sight loss on the ray's weights). Needs a dataset with
    /// ground-truth depth.
    #[arg(long, value_parser = parse_depth_loss)]
    pub depth_loss: Option<nerf::supervision::DepthLoss>,
    /// Weight of the depth term at step 0 (default 0.2).
    #[arg(long, value_parser = parse_weight, allow_hyphen_values = true)]
    pub depth_weight: Option<f32>,
    /// Half-life of the depth term's weight in steps (default: constant).
    #[arg(long, value_parser = parse_half_life, allow_hyphen_values = true)]
    pub depth_half_life: Option<u64>,
    /// Depth targets: exact (default), noisy:SIGMA_REL (depth · (1 + SIGMA_REL · normal
    /// noise)), sparse:FRACTION (only that fraction of pixels has depth) or holes:FRACTION
    /// (that fraction has none); seeded per (seed, view, pixel).
    #[arg(long, value_parser = parse_depth_source, allow_hyphen_values = true)]
    pub depth_source: Option<nerf::supervision::DepthSource>,
    /// Weight of the empty-space term: the weight mass along rays whose pixel's exact alpha is
    /// 0 is penalised (default off).
    #[arg(long, value_parser = parse_weight, allow_hyphen_values = true)]
    pub empty_loss: Option<f32>,
    /// Weight of the normal term: the normal implied by the density's gradient at each pixel's
    /// depth target against the dataset's normal (default off; fast and auto models).
    #[arg(long, value_parser = parse_weight, allow_hyphen_values = true)]
    pub normal_loss: Option<f32>,
}

fn parse_depth_loss(s: &str) -> Result<nerf::supervision::DepthLoss, String> {
    s.parse()
}

fn parse_depth_source(s: &str) -> Result<nerf::supervision::DepthSource, String> {
    s.parse()
}

fn parse_weight(s: &str) -> Result<f32, String> {
    match s.trim().parse::<f32>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(v),
        _ => Err(format!("'{s}' is not a weight (a finite number ≥ 0)")),
    }
}

fn parse_half_life(s: &str) -> Result<u64, String> {
    match s.trim().parse::<u64>() {
        Ok(v) if v > 0 => Ok(v),
        _ => Err(format!("'{s}' is not a half-life (a positive number of steps)")),
    }
}

impl SupervisionArgs {
    /// Whether any supervision option is given.
    fn any(&self) -> bool {
        self.depth_loss.is_some() || self.depth_weight.is_some() || self.depth_half_life.is_some() || self.depth_source.is_some() || self.empty_loss.is_some() || self.normal_loss.is_some()
    }

    /// The options applied to `cfg`'s supervision (created when an option is given; a run
    /// without them keeps `None`, colour only). Depth settings without `--depth-loss` are
    /// refused: they would change nothing.
    fn apply(&self, cfg: &mut TrainConfig) -> anyhow::Result<()> {
        if !self.any() {
            return Ok(());
        }
        let s = cfg.supervision.get_or_insert_with(nerf::supervision::SupervisionConfig::new);
        if let Some(l) = self.depth_loss {
            s.depth_loss = l;
        }
        if let Some(w) = self.depth_weight {
            s.depth_weight = w;
        }
        if let Some(h) = self.depth_half_life {
            s.depth_half_life_steps = Some(h);
        }
        if let Some(d) = self.depth_source {
            s.depth_source = d;
        }
        if let Some(e) = self.empty_loss {
            s.empty_weight = e;
        }
        if let Some(w) = self.normal_loss {
            s.normal_weight = w;
        }
        if !s.uses_depth() {
            for (given, name) in [(self.depth_weight.is_some(), "--depth-weight"), (self.depth_half_life.is_some(), "--depth-half-life"), (self.depth_source.is_some(), "--depth-source")] {
                anyhow::ensure!(!given, "{name} sets the depth term, which is off: give --depth-loss expected or termination with it");
            }
        }
        Ok(())
    }
}

/// Arguments of `render-nerf`.
#[derive(clap::Args)]
pub struct RenderNerfArgs {
    /// Run folder.
    pub run: PathBuf,
    /// Render this split of the run's dataset (default test).
    #[arg(long)]
    pub split: Option<String>,
    /// Render N views on a circle around the scene instead.
    #[arg(long)]
    pub orbit: Option<usize>,
    /// Render the frames of this camera path (nerfstudio's camera_path.json) instead, at the
    /// path's size and field of view: `frame_<k>.png`, `_depth.npy`, `_opacity.npy`.
    #[arg(long, value_name = "FILE", conflicts_with_all = ["orbit", "split", "downscale"])]
    pub camera_path: Option<PathBuf>,
    /// Also write the path's frames as an MP4 video (H.264, yuv420p) at the path's fps.
    #[arg(long, value_name = "FILE", requires = "camera_path")]
    pub video: Option<PathBuf>,
    /// The video's frames: nerf (the NeRF alone) or side-by-side (NeRF | ground truth | colour
    /// error | depth error, labelled; needs --gt).
    #[arg(long, default_value = "nerf", requires = "video")]
    pub layout: eval::path_video::Layout,
    /// The path tracer's frames of the same path (the folder `render SCENE --camera-path P`
    /// wrote), for --layout side-by-side.
    #[arg(long, value_name = "DIR", requires = "video")]
    pub gt: Option<PathBuf>,
    /// Output folder (default <run>/renders/<split or orbit>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Render at this downscale of the dataset's images (default: the one the run trained at;
    /// 1 = the dataset's full resolution). Must divide the image size.
    #[arg(long)]
    pub downscale: Option<u32>,
    /// Read dataset files (transforms `file_path`, `gt_file_path`, `exr_file_path`) that lie
    /// outside the dataset folder (`../`, an absolute path, a symbolic link leading out); refused
    /// by default.
    #[arg(long)]
    pub allow_outside: bool,
}

impl TrainArgs {
    /// The arguments `demo` trains with: defaults of `model`, a time budget, resuming when
    /// the run folder already has a checkpoint.
    pub fn for_demo(dataset: &std::path::Path, out: &std::path::Path, model: &str, time: &str, resume: bool) -> Self {
        Self {
            dataset: Some(dataset.to_path_buf()),
            out: out.to_path_buf(),
            // A resumed run keeps its recorded model (a caller's label is only for fresh runs).
            model: (!resume).then(|| model.to_string()),
            steps: None,
            time: Some(time.to_string()),
            resume,
            fallback: false,
            force: false,
            seed: None,
            config: None,
            downscale: None,
            background: None,
            batch_rays: None,
            batch_samples: None,
            mlp_precision: None,
            allow_outside: false,
            supervision: SupervisionArgs::default(),
            pose_noise: None,
            camera_opt: None,
        }
    }
}

/// The longest time budget accepted: longer is a typo (e.g. `1e300h`), not a plan.
const MOST_BUDGET_S: f64 = 1e9;

/// Parses the duration given to `option`, such as `90s`, `5m`, `1.5min` or `1h` (no unit:
/// seconds), into seconds; refused unless a positive finite number of seconds.
pub fn parse_duration(option: &str, s: &str) -> anyhow::Result<f64> {
    let t = s.trim();
    let (num, scale) =
        [("min", 60.0), ("s", 1.0), ("m", 60.0), ("h", 3600.0)].into_iter().find_map(|(u, k)| t.strip_suffix(u).map(|n| (n, k))).unwrap_or((t, 1.0));
    let v: f64 = num.trim().parse().map_err(|_| {
        let why = if num.contains(char::is_alphabetic) { "bad duration unit" } else { "not a duration" };
        anyhow::anyhow!("{option} '{s}': {why} (a number and a unit s, m or h: 90s, 5m, 1h)")
    })?;
    let secs = v * scale;
    anyhow::ensure!(!secs.is_nan(), "{option} '{s}': not a number of seconds");
    anyhow::ensure!(secs > 0.0, "{option} '{s}': a time budget must be positive");
    anyhow::ensure!(secs <= MOST_BUDGET_S, "{option} '{s}': at most {MOST_BUDGET_S:e} s (about 31 years)");
    Ok(secs)
}

fn build_config(args: &TrainArgs) -> anyhow::Result<TrainConfig> {
    let mut cfg = match &args.config {
        Some(p) => TrainConfig::read(p)?,
        None => {
            let ds = args.dataset.clone().context("give a dataset folder (or --config)")?;
            TrainConfig::preset(args.model.as_deref().unwrap_or("fast"), ds).map_err(anyhow::Error::msg)?
        }
    };
    if let Some(d) = &args.dataset {
        if args.config.is_some() && *d != cfg.dataset {
            cfg.bounds = None;
            // An auto config sized for another dataset is sized again.
            cfg.auto_reasons = None;
        }
        cfg.dataset = d.clone();
    }
    apply_budget(args, &mut cfg)?;
    if cfg.steps.is_none() && cfg.time_budget_s.is_none() {
        cfg.time_budget_s = Some(300.0);
    }
    if let Some(s) = args.seed {
        cfg.seed = s;
    }
    if let Some(d) = args.downscale {
        cfg.downscale = d;
    }
    if let Some(b) = args.background {
        cfg.background = b;
    }
    if let Some(b) = args.batch_rays {
        cfg.batch_rays = b;
        cfg.batch_samples = None;
    }
    if let Some(b) = args.batch_samples {
        cfg.batch_samples = Some(b);
    }
    if let Some(p) = &args.mlp_precision {
        match &mut cfg.model {
            nerf::models::ModelConfig::Fast(f) => f.mlp_precision = Some(p.clone()),
            _ => anyhow::bail!("--mlp-precision applies to the fast and auto models, not {}", cfg.model_label()),
        }
    }
    args.supervision.apply(&mut cfg)?;
    if let Some(n) = args.pose_noise {
        cfg.pose_noise = Some(n);
    }
    if let Some(m) = &args.camera_opt {
        cfg.camera_opt = nerf::camera_opt::parse_mode(m).map_err(|e| anyhow::anyhow!("--camera-opt: {e}"))?;
    }
    if let Err(e) = cfg.check() {
        match &args.config {
            Some(p) => anyhow::bail!("{}: {e}", p.display()),
            None => anyhow::bail!("{e}"),
        }
    }
    Ok(cfg)
}

/// `--steps` and `--time`, where given, as the budget of `cfg` (a fresh run's or a resumed one's).
fn apply_budget(args: &TrainArgs, cfg: &mut TrainConfig) -> anyhow::Result<()> {
    if let Some(s) = args.steps {
        cfg.steps = Some(s);
    }
    if let Some(t) = &args.time {
        cfg.time_budget_s = Some(parse_duration("--time", t)?);
    }
    Ok(())
}

/// Whether `dir` holds a training run: its `config.json` or a checkpoint.
fn holds_run(dir: &std::path::Path) -> bool {
    dir.join(nerf::train::CONFIG_FILE).exists() || nerf::checkpoint::latest(dir).is_some()
}

/// What a run and the commands that read it (`eval`, `mesh`, `render-nerf`) write into its
/// folder: what `--force` removes. Other files in the folder are left alone.
const RUN_OUTPUTS: [&str; 11] = [
    nerf::train::CONFIG_FILE,
    nerf::train::METRICS_FILE,
    "eval.json",
    "report.json",
    "report.md",
    "mesh.ply",
    "mesh.json",
    "mesh_error.png",
    "speed_vs_error.png",
    eval::objects::OBJECTS_PICTURE,
    nerf::poses::POSES_FILE,
];

/// Whether `name` in a run folder is a file a run, `eval` or `mesh` writes ([`RUN_OUTPUTS`],
/// the per-view `grid_*.png` pictures, temporaries `.<name>.<pid>.tmp`).
fn run_output(name: &str) -> bool {
    RUN_OUTPUTS.contains(&name) || (name.starts_with("grid_") && name.ends_with(".png")) || (name.starts_with('.') && name.ends_with(".tmp"))
}

/// Whether `name` in `checkpoints/` is a checkpoint or a checkpoint's temporary.
fn checkpoint_file(name: &str) -> bool {
    (name.starts_with("step-") && name.ends_with(".ckpt")) || (name.starts_with(".step-") && name.ends_with(".tmp"))
}

/// Whether `name` in `renders/<split or orbit>/` is a file `render-nerf` writes.
fn render_nerf_file(name: &str) -> bool {
    name.ends_with(".png") || name.ends_with("_opacity.npy") || name.ends_with("_depth.npy")
}

/// `--force`, before anything is removed: the `config.json` in `dir`, if any, is a training
/// run's config (a folder that is not a run is never emptied).
fn check_replaceable(dir: &std::path::Path) -> anyhow::Result<()> {
    let config = dir.join(nerf::train::CONFIG_FILE);
    if config.exists() {
        TrainConfig::read(&config).map_err(|e| {
            anyhow::anyhow!("--force: {} is not a training run's config ({e}); --force replaces a run, not other files", config.display())
        })?;
    }
    Ok(())
}

/// Removes the files in `dir` that `ours` names (never a folder, a link is removed as a link),
/// then `dir` itself if that left it empty.
fn remove_ours(dir: &std::path::Path, ours: fn(&str) -> bool) -> anyhow::Result<()> {
    let Ok(entries) = std::fs::read_dir(dir) else { return Ok(()) };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if ours(&name) && e.file_type().is_ok_and(|t| !t.is_dir()) {
            let path = e.path();
            std::fs::remove_file(&path).with_context(|| format!("removing {} (--force)", path.display()))?;
        }
    }
    let _ = std::fs::remove_dir(dir); // only succeeds when empty
    Ok(())
}

/// `--force`, once the new run is validated and before it writes: removes the old run in `dir`,
/// file by file and only files a run or the commands reading it write (checkpoints first, so
/// that they never stand beside a new config); folders left empty go too, other content stays.
fn remove_run(dir: &std::path::Path) -> anyhow::Result<()> {
    remove_ours(&dir.join("checkpoints"), checkpoint_file)?;
    let renders = dir.join("renders");
    if let Ok(entries) = std::fs::read_dir(&renders) {
        for e in entries.flatten() {
            if e.file_type().is_ok_and(|t| t.is_dir()) {
                remove_ours(&e.path(), render_nerf_file)?;
            }
        }
        let _ = std::fs::remove_dir(&renders);
    }
    let entries = std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))?;
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if run_output(&name) && e.file_type().is_ok_and(|t| !t.is_dir()) {
            let path = e.path();
            std::fs::remove_file(&path).with_context(|| format!("removing {} (--force)", path.display()))?;
        }
    }
    Ok(())
}

/// The trainer of `--resume`: the run's recorded config, whose budget `--steps` and `--time`
/// may replace; any flag that would change another setting is refused rather than ignored.
fn resume_trainer(args: &TrainArgs) -> anyhow::Result<Trainer> {
    let out = &args.out;
    let config_path = out.join(nerf::train::CONFIG_FILE);
    anyhow::ensure!(config_path.is_file(), "--resume: {} holds no run to continue (no {})", out.display(), config_path.display());
    let mut cfg = TrainConfig::read(&config_path)?;
    let same_path = |a: &std::path::Path, b: &std::path::Path| match (a.canonicalize(), b.canonicalize()) {
        (Ok(x), Ok(y)) => x == y,
        _ => a == b,
    };
    let changed: Vec<&str> = [
        ("a dataset other than the recorded one", args.dataset.as_deref().is_some_and(|d| !same_path(d, &cfg.dataset))),
        ("--config", args.config.is_some()),
        ("--seed", args.seed.is_some_and(|s| s != cfg.seed)),
        ("--downscale", args.downscale.is_some_and(|d| d != cfg.downscale)),
        ("--background", args.background.is_some_and(|b| b != cfg.background)),
        ("--batch-rays", args.batch_rays.is_some_and(|b| b != cfg.batch_rays)),
        ("--batch-samples", args.batch_samples.is_some_and(|b| Some(b) != cfg.batch_samples)),
        ("--model", args.model.as_deref().is_some_and(|m| m != cfg.model_label())),
        ("--pose-noise", args.pose_noise.is_some_and(|n| Some(n) != cfg.pose_noise)),
        ("--camera-opt", args.camera_opt.as_deref().is_some_and(|m| (m == "se3") != cfg.camera_opt.is_some())),
        ("--depth-loss, --depth-weight, --depth-half-life, --depth-source, --empty-loss or --normal-loss", {
            let mut c = cfg.clone();
            args.supervision.apply(&mut c).is_err() || serde_json::to_value(&c.supervision).ok() != serde_json::to_value(&cfg.supervision).ok()
        }),
        (
            "--mlp-precision",
            args.mlp_precision.as_deref().is_some_and(|p| match &cfg.model {
                nerf::models::ModelConfig::Fast(f) => p != f.mlp_precision.as_deref().unwrap_or("fp32"),
                _ => true,
            }),
        ),
    ]
    .into_iter()
    .filter_map(|(name, differs)| differs.then_some(name))
    .collect();
    anyhow::ensure!(
        changed.is_empty(),
        "--resume continues the run in {} with the settings in {} ({} model, seed {}, downscale {}); {} would change them: leave them out, or train into a new --out",
        out.display(),
        config_path.display(),
        cfg.model_label(),
        cfg.seed,
        cfg.downscale,
        changed.join(", ")
    );
    apply_budget(args, &mut cfg)?;
    cfg.check().map_err(|e| anyhow::anyhow!("{}: {e}", config_path.display()))?;
    let start = if args.fallback { Start::ResumeFallback } else { Start::Resume };
    let mut trainer = Trainer::prepare(cfg, out, start, &dataset::LoadOptions { allow_outside: args.allow_outside }).with_context(|| format!("resuming {}", out.display()))?;
    for (path, why) in &trainer.skipped_checkpoints {
        eprintln!("--fallback: {} does not load ({why}); renamed {}.damaged", path.display(), path.display());
    }
    trainer.start()?;
    Ok(trainer)
}

/// Trains a model.
pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    crate::check_out_folder("--out", &args.out)?;
    crate::guard::check_output_folder("--out", &args.out, false)?;
    let _lock = crate::lock_folder(&args.out)?;
    let stop = crate::stop_flag();
    let mut trainer = if args.resume {
        resume_trainer(&args)?
    } else {
        let cfg = build_config(&args)?;
        let replacing = holds_run(&args.out);
        if replacing {
            anyhow::ensure!(
                args.force,
                "{} already holds a training run (config.json or checkpoints): continue it with --resume, replace it with --force, or train into a new --out",
                args.out.display()
            );
            check_replaceable(&args.out)?;
        }
        // Every input is validated (the dataset, the config) before the old run is removed, and
        // the new run writes its config only after that.
        let mut trainer = Trainer::prepare(cfg, &args.out, Start::Fresh, &dataset::LoadOptions { allow_outside: args.allow_outside })?;
        if replacing {
            remove_run(&args.out)?;
        }
        trainer.start()?;
        trainer
    };
    for reason in trainer.config.auto_reasons.iter().flatten() {
        eprintln!("auto: {reason}");
    }
    eprintln!(
        "training {} ({} parameters, backend {}) on {} from step {}; run folder {}",
        trainer.config.model_label(),
        trainer.model.parameters(),
        nerf::backend::backend_name(),
        trainer.config.dataset.display(),
        trainer.step,
        args.out.display()
    );
    let bar = indicatif::ProgressBar::new(1000);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:30} {percent:>3}% {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let summary = trainer.run(stop, &mut |p| {
        bar.set_position((p.fraction * 1000.0) as u64);
        let left = if p.fraction > 0.0 { p.wall_s * (1.0 - p.fraction) / p.fraction } else { 0.0 };
        let val = p.val_psnr.map_or(String::new(), |v| format!(" val {v:.2} dB"));
        bar.set_message(format!(
            "step {} loss {:.5} train {:.2} dB{val} {:.0} rays/s {:.0}s left",
            p.step, p.loss, p.train_psnr, p.rays_per_s, left
        ));
    })?;
    bar.finish_and_clear();
    let val = summary.val.as_ref().map_or("no val views".to_string(), |v| {
        format!(
            "val PSNR {:.2} dB{}",
            v.val_psnr,
            v.val_depth_mae.map_or(String::new(), |d| format!(", val depth MAE {d:.4}"))
        )
    });
    eprintln!(
        "{} at step {} after {:.1}s of training: {val}; {} non-finite steps skipped",
        if summary.interrupted {
            "interrupted (checkpoint written; --resume continues)"
        } else if summary.plateaued {
            "stopped early (val PSNR plateaued)"
        } else {
            "done"
        },
        summary.steps,
        summary.wall_s,
        summary.skipped_nonfinite
    );
    let tm = trainer.timings;
    if matches!(trainer.config.model, nerf::models::ModelConfig::Fast(_)) {
        eprintln!(
            "time in steps: encoding {:.1}s, networks with compositing and loss {:.1}s, optimizer and grid updates {:.1}s",
            tm.encoding,
            tm.mlp + tm.render,
            tm.optimizer
        );
    } else {
        eprintln!(
            "time in steps: encoding {:.1}s, MLP {:.1}s, rendering {:.1}s, optimizer and grid updates {:.1}s",
            tm.encoding, tm.mlp, tm.render, tm.optimizer
        );
    }
    eprintln!("outputs in {}", args.out.display());
    if summary.interrupted {
        let how = format!("training {} interrupted at step {}; its checkpoint is written and --resume continues it", args.out.display(), summary.steps);
        return Err(crate::exit::Stopped(how).into());
    }
    Ok(())
}

/// Renders views from a run.
/// The file stem of a camera path's frame `k` in `render-nerf --camera-path`'s output.
pub fn path_frame_name(k: usize) -> String {
    format!("frame_{k:05}")
}

pub fn run_render(args: RenderNerfArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.orbit != Some(0), "--orbit 0: at least one view is needed");
    const MOST_ORBIT_VIEWS: usize = 100_000;
    anyhow::ensure!(args.orbit.is_none_or(|n| n <= MOST_ORBIT_VIEWS), "--orbit {}: at most {MOST_ORBIT_VIEWS} views", args.orbit.unwrap_or(0));
    if let Some(out) = &args.out {
        crate::check_out_folder("--out", out)?;
        crate::guard::check_output_folder("--out", out, false)?;
    }
    let model = RunModel::load(&args.run).with_context(|| format!("loading {}", args.run.display()))?;
    let downscale = args.downscale.unwrap_or(model.config.downscale.max(1));
    let load = dataset::LoadOptions { allow_outside: args.allow_outside };
    {
        let ds = dataset::Dataset::load_with(model.dataset_dir(), &load)?;
        for f in ds.train.iter().chain(&ds.val).chain(&ds.test) {
            dataset::check_downscale("--downscale", downscale, &f.camera.intrinsics).map_err(|e| anyhow::anyhow!("{e} ({})", f.image_path.display()))?;
        }
    }
    let (label, cameras): (String, Vec<(String, dataset::Camera)>) = if let Some(path) = &args.camera_path {
        let cams = dataset::CameraPathFile::read(path)?.cameras(path)?;
        ("camera_path".into(), cams.into_iter().enumerate().map(|(k, c)| (path_frame_name(k), c)).collect())
    } else if let Some(n) = args.orbit {
        let ds = dataset::Dataset::load_with(model.dataset_dir(), &load)?;
        let first = ds.train.first().context("dataset has no train views")?.camera.downscaled(downscale);
        let b = model.config.bounds.clone().context("run has no bounds")?;
        let cams = nerf::render::orbit_cameras(&first, b.center(), n)
            .into_iter()
            .enumerate()
            .map(|(k, c)| (format!("orbit_{k:03}"), c))
            .collect();
        ("orbit".into(), cams)
    } else {
        let split = args.split.clone().unwrap_or_else(|| "test".into());
        let kind = match split.as_str() {
            "train" => dataset::SplitKind::Train,
            "val" => dataset::SplitKind::Val,
            "test" => dataset::SplitKind::Test,
            s => anyhow::bail!("unknown split '{s}' (train, val or test)"),
        };
        let ds = dataset::Dataset::load_with(model.dataset_dir(), &load)?;
        let cams = ds.split(kind).iter().map(|f| (f.name.clone(), f.camera.downscaled(downscale))).collect();
        (split, cams)
    };
    anyhow::ensure!(!cameras.is_empty(), "dataset {} has no {label} views", model.dataset_dir().display());
    let out = args.out.clone().unwrap_or_else(|| args.run.join("renders").join(&label));
    if args.out.is_none() {
        crate::check_out_folder("the output folder", &out)?;
        crate::guard::check_output_folder("the output folder", &out, false)?;
    }
    let bg = model.eval_background();
    let mut video = match &args.video {
        Some(path) => Some(crate::path_video::PathVideo::start(path, args.camera_path.as_deref().unwrap_or(path), args.layout, args.gt.as_deref(), &cameras, bg, args.allow_outside)?),
        None => None,
    };
    let _lock = crate::lock_folder(&out)?;
    let bar = crate::path_video::bar(cameras.len() as u64, "rendering");
    for (k, (name, cam)) in cameras.iter().enumerate() {
        let v = model.render_view(cam, bg);
        if let Some(video) = &mut video {
            video.push(k, &v)?;
        }
        let mut img = dataset::RgbaImage::new(v.width, v.height);
        for p in 0..(v.width * v.height) as usize {
            img.data[4 * p..4 * p + 3].copy_from_slice(&v.rgb[3 * p..3 * p + 3]);
            img.data[4 * p + 3] = 1.0;
        }
        dataset::write_png_rgba(&out.join(format!("{name}.png")), &img)?;
        dataset::write_npy_f32(&out.join(format!("{name}_opacity.npy")), v.width, v.height, &v.opacity)?;
        dataset::write_npy_f32(&out.join(format!("{name}_depth.npy")), v.width, v.height, &v.depth)?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    if let Some(video) = video {
        let (path, frames) = video.finish()?;
        eprintln!("video: {} ({frames} frames)", path.display());
    }
    eprintln!(
        "rendered {} views of {} (step {}) at {}x{} (downscale {downscale}): colour PNG, opacity and z-depth .npy in {}",
        cameras.len(),
        args.run.display(),
        model.train_steps(),
        cameras[0].1.intrinsics.width,
        cameras[0].1.intrinsics.height,
        out.display()
    );
    Ok(())
}
