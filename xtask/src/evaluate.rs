//! `cargo xtask eval`, `compare` and `demo`: argument parsing and printing; the work is in
//! the `eval`, `nerf` and `pathtracer` crates.

use anyhow::Context;
use dataset::SplitKind;
use std::path::PathBuf;

/// Arguments of `eval`.
#[derive(clap::Args)]
pub struct EvalArgs {
    /// Run folder (from `cargo xtask train`).
    pub run: PathBuf,
    /// Split to evaluate: train, val or test.
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Number of views that get a picture grid in the report.
    #[arg(long, default_value_t = 3)]
    pub grids: usize,
    /// Evaluate only the first N views of the split.
    #[arg(long)]
    pub max_views: Option<usize>,
    /// Evaluate at this downscale of the dataset's images (default: the one the run trained
    /// at; 1 = the dataset's full resolution). Must divide the image size.
    #[arg(long)]
    pub downscale: Option<u32>,
    /// The scene the dataset was rendered from (a file, or the name of a scene in `scenes/`),
    /// for exact depth ground truth at even downscale factors (default: found through the
    /// dataset's render_config.json).
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Grid cells along the scene box's longest side of the mesh measured against the scene's
    /// triangles (1..=2048).
    #[arg(long, default_value_t = 256)]
    pub mesh_resolution: usize,
    /// Skip the mesh and its metrics.
    #[arg(long)]
    pub no_mesh: bool,
    /// Read dataset files (transforms `file_path`, `gt_file_path`, `exr_file_path`) and the
    /// scene's glTF buffers and images that lie outside their folders (`../`, an absolute path,
    /// a symbolic link leading out); refused by default.
    #[arg(long)]
    pub allow_outside: bool,
    /// Also measure the run along a camera path: the folder `render SCENE --camera-path P`
    /// wrote (the path tracer's frames). Writes path_error.csv and path_error.png and adds a
    /// `camera_path` summary to eval.json and the report.
    #[arg(long, value_name = "DIR")]
    pub camera_path: Option<PathBuf>,
    /// For a run trained on noisy or refined poses (`--pose-noise`, `--camera-opt`): optimise
    /// each test view's pose for N steps with the model frozen before rendering it (the
    /// protocol of BARF-style evaluations; named in eval.json's `pose_protocol`).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..=100_000))]
    pub test_pose_opt: Option<u64>,
}

impl EvalArgs {
    /// Every view of `split` at the run's training resolution, with `grids` picture grids.
    pub fn at_training_resolution(run: PathBuf, split: &str, grids: usize, max_views: Option<usize>) -> Self {
        Self { run, split: split.into(), grids, max_views, downscale: None, scene: None, mesh_resolution: 256, no_mesh: false, allow_outside: false, camera_path: None, test_pose_opt: None }
    }
}

/// Arguments of `compare`.
#[derive(clap::Args)]
pub struct CompareArgs {
    /// Evaluated run folders, and `score` output folders (another tool's predictions, placed
    /// at their stated training time).
    #[arg(required = true)]
    pub runs: Vec<PathBuf>,
    /// Where `compare.png` and `compare.md` go (default: the current folder).
    #[arg(long, default_value = ".")]
    pub out: PathBuf,
}

/// Arguments of `demo`.
#[derive(clap::Args)]
pub struct DemoArgs {
    /// Scene name in `scenes/` or a glTF path.
    #[arg(long, default_value = "tabletop")]
    pub scene: String,
    /// Output folder: `<out>/dataset` and `<out>/run-<model>-<time>` (with `--preset P`:
    /// `<out>/dataset-P` and `<out>/run-<model>-<time>-P`).
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// Training time budget (e.g. 90s, 3m).
    #[arg(long, default_value = "3m")]
    pub time: String,
    /// Render preset of the dataset (default: the demo's own dataset, the quick preset with
    /// 100 train views at 128x128 and 8 spp).
    #[arg(long)]
    pub preset: Option<pathtracer::dataset_render::Preset>,
    /// Model to train: `auto` (the hash-grid model sized from the scene), `fast` or `paper`.
    #[arg(long, default_value = "auto")]
    pub model: String,
}

/// How the demo trains into its run folder: continue the run there, start it, or replace it
/// (`train --force`: only the files a run writes are removed). A run folder is named by its model,
/// time budget and dataset, so another `--model`, `--time` or `--preset` trains into a folder of
/// its own and never touches an earlier run; a run there is replaced only when its dataset was
/// rendered again or its checkpoint no longer loads (an older version's).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum DemoRun {
    Resume,
    Fresh,
    Replace,
}

fn demo_run_state(run_dir: &std::path::Path, args: &DemoArgs, dataset_rendered_again: bool) -> anyhow::Result<DemoRun> {
    if !run_dir.join(nerf::train::CONFIG_FILE).exists() && nerf::checkpoint::latest(run_dir).is_none() {
        return Ok(DemoRun::Fresh);
    }
    if dataset_rendered_again {
        eprintln!("{} was trained on the dataset before it was rendered again; training it afresh", run_dir.display());
        return Ok(DemoRun::Replace);
    }
    let budget = crate::train::parse_duration("--time", &args.time)?;
    let same = match nerf::render::RunModel::load(run_dir) {
        Ok(m) => m.config.model_label() == args.model && m.config.time_budget_s == Some(budget),
        Err(_) => false,
    };
    if !same {
        eprintln!("{} holds a different or unreadable run; training it afresh", run_dir.display());
        return Ok(DemoRun::Replace);
    }
    Ok(DemoRun::Resume)
}

/// The demo's dataset and run folders under `--out`: `dataset` (the demo's own settings) or
/// `dataset-<preset>`, and `run-<model>-<time>` with the same suffix, the time as given with
/// anything but letters, digits and dots dropped (`3m`, `90s`, `1.5min`).
fn demo_folders(args: &DemoArgs) -> (std::path::PathBuf, std::path::PathBuf) {
    let suffix = args.preset.map_or(String::new(), |p| format!("-{}", serde_json::to_value(p).ok().and_then(|v| v.as_str().map(str::to_owned)).unwrap_or_default()));
    let time: String = args.time.chars().filter(|c| c.is_ascii_alphanumeric() || *c == '.').collect();
    (args.out.join(format!("dataset{suffix}")), args.out.join(format!("run-{}-{time}{suffix}", args.model)))
}

/// The split named `s` (`train`, `val` or `test`).
pub fn parse_split(s: &str) -> anyhow::Result<SplitKind> {
    SplitKind::ALL
        .into_iter()
        .find(|k| k.name() == s)
        .with_context(|| format!("unknown split '{s}' (train, val or test)"))
}

fn fmt_opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("-".into(), |x| format!("{x:.digits$}"))
}

/// Evaluates a run and prints its summary table.
pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.max_views != Some(0), "--max-views 0 evaluates nothing (give at least 1, or leave it out for every view)");
    crate::guard::check_output_folder("the run folder", &args.run, false)?;
    let opts = eval::EvalRunOptions {
        split: parse_split(&args.split)?,
        grid_views: args.grids,
        max_views: args.max_views,
        downscale: args.downscale,
        scene: crate::render::resolve_scene_option(args.scene.as_deref())?,
        mesh: (!args.no_mesh).then_some(eval::mesh_eval::MeshEvalOptions { resolution: args.mesh_resolution, ..eval::mesh_eval::MeshEvalOptions::standard() }),
        allow_outside: args.allow_outside,
        test_pose_opt: args.test_pose_opt,
    };
    anyhow::ensure!(
        args.no_mesh || (1..=eval::mesh_extract::MAX_RESOLUTION).contains(&args.mesh_resolution),
        "--mesh-resolution must be 1..={}, not {}",
        eval::mesh_extract::MAX_RESOLUTION,
        args.mesh_resolution
    );
    let load = dataset::LoadOptions { allow_outside: args.allow_outside };
    let path_truth = match &args.camera_path {
        Some(dir) => {
            let ds = dataset::Dataset::load_with(dir, &load).with_context(|| format!("--camera-path {}", dir.display()))?;
            anyhow::ensure!(ds.has_ground_truth(), "--camera-path {}: no ground-truth files; give the folder `render SCENE --camera-path P` wrote", dir.display());
            Some(ds)
        }
        None => None,
    };
    // A missing run is reported by the evaluation, which reads it first.
    let _lock = args.run.is_dir().then(|| crate::lock_folder(&args.run)).transpose()?;
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template("evaluating {pos}/{len} views {bar:30} {elapsed}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let out = eval::evaluate_run(&args.run, &opts, &mut |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })?;
    bar.finish_and_clear();
    print_summary(&out);
    if let Some(truth) = &path_truth {
        evaluate_path(&args.run, truth, &load)?;
    }
    Ok(())
}

/// The error along a camera path (`eval::path_error`): the CSV, the plot, and the summary added
/// to eval.json and report.md.
fn evaluate_path(run: &std::path::Path, truth: &dataset::Dataset, load: &dataset::LoadOptions) -> anyhow::Result<()> {
    let model = nerf::render::RunModel::load(run).with_context(|| format!("loading {}", run.display()))?;
    let train: Vec<dataset::Camera> = dataset::Dataset::load_with(model.dataset_dir(), load)?.train.iter().map(|f| f.camera).collect();
    let bar = crate::path_video::bar(truth.train.len() as u64, "camera path");
    let rows = eval::path_error::path_errors(&model, truth, &train, &mut |done, _| bar.set_position(done as u64))?;
    bar.finish_and_clear();
    eval::path_error::write_csv(&run.join("path_error.csv"), &rows)?;
    eval::path_error::plot_png(&run.join("path_error.png"), &rows)?;
    let summary = eval::path_error::PathSummary::of(&rows, &truth.root);
    let eval_json = run.join("eval.json");
    let mut value: serde_json::Value = serde_json::from_slice(&dataset::io::read(&eval_json)?).with_context(|| format!("reading {}", eval_json.display()))?;
    value["camera_path"] = serde_json::to_value(&summary)?;
    dataset::io::atomic_write_json(&eval_json, &value)?;
    let report = run.join("report.md");
    if let Ok(mut text) = std::fs::read_to_string(&report) {
        text.push_str(&format!(
            "\n## Along the camera path\n\n{} frames against the path tracer's frames in {}: mean PSNR {:.2} dB (lowest {:.2} dB at frame {}), mean SSIM {}, mean depth MAE {}; the path goes up to {:.3} m and {:.1}° from the nearest training camera. Per frame: `path_error.csv`; PSNR against distance: `path_error.png`.\n\n![error along the path](path_error.png)\n",
            summary.frames,
            summary.truth,
            summary.mean_psnr,
            summary.min_psnr,
            summary.min_psnr_frame,
            summary.mean_ssim.map_or("n/a".into(), |v| format!("{v:.4}")),
            summary.mean_depth_mae.map_or("n/a".into(), |v| format!("{v:.4} m")),
            summary.max_position_distance,
            summary.max_angular_distance,
        ));
        dataset::io::atomic_write(&report, text.as_bytes())?;
    }
    println!(
        "camera path: {} frames, mean PSNR {:.2} dB (lowest {:.2} dB at frame {}); path_error.csv and path_error.png in {}",
        summary.frames,
        summary.mean_psnr,
        summary.min_psnr,
        summary.min_psnr_frame,
        run.display()
    );
    Ok(())
}

fn print_summary(out: &eval::EvalRunOutput) {
    let m = &out.report.mean;
    let s = &out.summary;
    if let Some(r) = &out.report.resolution {
        println!("evaluated at {}", r.label());
    }
    println!("| run | PSNR dB | SSIM | depth MAE | depth δ<1.25 | mask IoU | off-surface mass (in front) | train s | steps | params | to 25 dB s | to 30 dB s |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    println!(
        "| {} | {:.2} | {:.4} | {} | {} | {} | {} | {:.1} | {} | {} | {} | {} |",
        s.name,
        m.psnr,
        m.ssim,
        fmt_opt(m.depth_mae, 4),
        fmt_opt(m.depth_delta_1_25, 3),
        fmt_opt(m.mask_iou, 3),
        eval::compare::off_surface(s),
        s.train_wall_s,
        s.train_steps,
        s.parameters,
        fmt_opt(s.time_to_25db_s, 1),
        fmt_opt(s.time_to_30db_s, 1),
    );
    if let Some(b) = &out.report.mesh {
        crate::mesh::print_metrics(b);
    }
    for note in &out.report.notes {
        println!("note: {note}");
    }
    println!("report: {}", out.report_md.display());
}

/// Compares evaluated runs.
pub fn run_compare(args: CompareArgs) -> anyhow::Result<()> {
    crate::check_out_folder("--out", &args.out)?;
    crate::guard::check_output_folder("--out", &args.out, false)?;
    let mut runs = args.runs.iter().map(|r| eval::summarise_run(r)).collect::<Result<Vec<_>, _>>()?;
    for (dir, summary) in args.runs.iter().zip(&mut runs) {
        if let Some(why) = stale_report(dir, summary) {
            eprintln!("warning: {}: {why}; its row is marked \"stale\": run `cargo xtask eval {}` again", dir.display(), dir.display());
            summary.name.push_str(" (stale)");
        }
    }
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let table = eval::compare_runs(&runs, &args.out)?;
    println!("{table}");
    println!("comparison: {}", args.out.join("compare.md").display());
    Ok(())
}

/// Why the report of the run in `dir` is not its latest model's, if it is not: the run trained
/// on (`train --resume`) after it was evaluated, so its latest checkpoint is of another step
/// than the report.
fn stale_report(dir: &std::path::Path, summary: &eval::RunSummary) -> Option<String> {
    let (step, checkpoint) = nerf::checkpoint::latest_with_step(dir)?;
    (step != summary.train_steps).then(|| {
        format!("report.json is of step {}, but the latest checkpoint is of step {step} ({})", summary.train_steps, checkpoint.display())
    })
}

/// The demo's own dataset (no `--preset`): the quick preset's rig, bounces and 4 val and 4
/// test views, with [`DEMO_TRAIN_VIEWS`] train views at [`DEMO_RES`] px and [`DEMO_SPP`] spp.
/// The quick preset's 20 views of 64 px are memorised (validation PSNR flat while the training
/// PSNR climbs); with these the held-out PSNR rises while it trains (docs/experiments.md).
const DEMO_TRAIN_VIEWS: u32 = 100;
/// Width and height of the demo's views.
const DEMO_RES: u32 = 128;
/// Samples per pixel of the demo's views.
const DEMO_SPP: u32 = 8;

/// The render arguments of the demo's dataset: [`DEMO_TRAIN_VIEWS`] etc. without `preset`, the
/// preset's own values with it.
fn demo_render_args(args: &DemoArgs, dataset_dir: &std::path::Path) -> crate::render::RenderArgs {
    use pathtracer::dataset_render::Preset;
    let base = crate::render::RenderArgs::for_demo(&args.scene, dataset_dir, args.preset.unwrap_or(Preset::Quick));
    match args.preset {
        Some(_) => base,
        None => crate::render::RenderArgs { train: Some(DEMO_TRAIN_VIEWS), res: Some(DEMO_RES.to_string()), spp: Some(DEMO_SPP), ..base },
    }
}

/// Whether the dataset folder holds a render with other settings than `want` (an earlier demo's
/// or one with another `--preset`): `false` without a readable record.
fn other_demo_dataset(dir: &std::path::Path, want: &pathtracer::dataset_render::DatasetRenderConfig) -> bool {
    let Ok(bytes) = std::fs::read(dir.join(pathtracer::dataset_render::RENDER_CONFIG_FILE)) else { return false };
    let Ok(record) = serde_json::from_slice::<serde_json::Value>(&bytes) else { return false };
    serde_json::from_value::<pathtracer::dataset_render::DatasetRenderConfig>(record["config"].clone()).is_ok_and(|c| &c != want)
}

/// Renders the default scene, trains, evaluates, prints the summary and says where to look.
pub fn run_demo(args: DemoArgs) -> anyhow::Result<()> {
    let (dataset_dir, run_dir) = demo_folders(&args);
    // Every option is checked before anything is rendered or removed.
    crate::check_out_folder("--out", &args.out)?;
    crate::guard::check_output_folder("--out", &args.out, false)?;
    nerf::train::TrainConfig::preset(&args.model, run_dir.clone()).map_err(|e| anyhow::anyhow!("--model {}: {e}", args.model))?;
    crate::train::parse_duration("--time", &args.time)?;
    let mut render_args = demo_render_args(&args, &dataset_dir);
    let cfg = crate::render::build_config(&render_args)?;
    // A dataset of an older renderer (e.g. another sampler) or of other settings is the demo's
    // own: it is rendered again (`render --force`: only the files a render writes are replaced)
    // instead of refusing to resume, and the run trained on it starts afresh.
    let stale = match crate::render::older_renderer(&dataset_dir) {
        Some(old) => Some(format!("was rendered by {old}")),
        None => other_demo_dataset(&dataset_dir, &cfg).then(|| "holds a dataset with other settings".to_string()),
    };
    if let Some(why) = &stale {
        eprintln!("{} {why}; rendering it again", dataset_dir.display());
        render_args.force = true;
    }
    let what = format!("{} train views at {}x{}, {} spp", cfg.train, cfg.width, cfg.height, cfg.spp);
    eprintln!("== 1/3 render {} ({what}) into {}", args.scene, dataset_dir.display());
    crate::render::run(render_args)?;
    eprintln!("== 2/3 train {} for {} into {}", args.model, args.time, run_dir.display());
    let state = demo_run_state(&run_dir, &args, stale.is_some())?;
    let mut train_args = crate::train::TrainArgs::for_demo(&dataset_dir, &run_dir, &args.model, &args.time, state == DemoRun::Resume);
    train_args.force = state == DemoRun::Replace;
    crate::train::run(train_args)?;
    eprintln!("== 3/3 evaluate on the test views");
    run(EvalArgs::at_training_resolution(run_dir.clone(), "test", 3, None))?;
    println!(
        "demo: a NeRF ({}) trained for {} on {what} path-traced from {}, measured on {} test views it never saw: \
         {} (the table above), {} (per view: truth | NeRF | error), {} (validation PSNR over training time)",
        args.model,
        args.time,
        args.scene,
        cfg.test,
        run_dir.join("report.md").display(),
        run_dir.join("grid_*.png").display(),
        run_dir.join("speed_vs_error.png").display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use pathtracer::dataset_render::{DatasetRenderConfig, Preset};

    fn demo(preset: Option<Preset>) -> DemoArgs {
        DemoArgs { scene: "tabletop".into(), out: "out/demo".into(), time: "3m".into(), preset, model: "auto".into() }
    }

    #[test]
    fn the_demo_renders_its_own_dataset_unless_given_a_preset() {
        let dir = std::path::Path::new("out/demo/dataset");
        let own = crate::render::build_config(&demo_render_args(&demo(None), dir)).unwrap();
        let quick = DatasetRenderConfig::preset(Preset::Quick);
        assert_eq!((own.train, own.width, own.height, own.spp), (DEMO_TRAIN_VIEWS, DEMO_RES, DEMO_RES, DEMO_SPP));
        assert_eq!(DatasetRenderConfig { train: quick.train, width: quick.width, height: quick.height, spp: quick.spp, ..own }, quick);
        for preset in [Preset::Quick, Preset::Standard] {
            let cfg = crate::render::build_config(&demo_render_args(&demo(Some(preset)), dir)).unwrap();
            assert_eq!(cfg, DatasetRenderConfig::preset(preset));
        }
    }

    #[test]
    fn another_time_model_or_preset_trains_into_a_folder_of_its_own() {
        let with = |time: &str, model: &str, preset| DemoArgs { time: time.into(), model: model.into(), ..demo(preset) };
        let (d, r) = demo_folders(&with("3m", "auto", None));
        assert_eq!((d.as_path(), r.as_path()), (std::path::Path::new("out/demo/dataset"), std::path::Path::new("out/demo/run-auto-3m")));
        let (dq, rq) = demo_folders(&with("1.5min", "fast", Some(Preset::Quick)));
        assert_eq!((dq.as_path(), rq.as_path()), (std::path::Path::new("out/demo/dataset-quick"), std::path::Path::new("out/demo/run-fast-1.5min-quick")));
        // Path separators and the like never reach the folder name.
        assert_eq!(demo_folders(&with("../3 m", "auto", None)).1, std::path::Path::new("out/demo/run-auto-..3m"));
        let names: std::collections::HashSet<_> =
            [("3m", "auto"), ("90s", "auto"), ("3m", "fast")].iter().map(|(t, m)| demo_folders(&with(t, m, None)).1).collect();
        assert_eq!(names.len(), 3);
    }

    #[test]
    fn an_empty_run_folder_is_fresh_and_a_rendered_again_dataset_replaces_its_run() {
        let tmp = tempfile::tempdir().unwrap();
        let args = demo(None);
        assert_eq!(demo_run_state(tmp.path(), &args, true).unwrap(), DemoRun::Fresh);
        std::fs::write(tmp.path().join(nerf::train::CONFIG_FILE), b"{}").unwrap();
        assert_eq!(demo_run_state(tmp.path(), &args, true).unwrap(), DemoRun::Replace);
        assert_eq!(demo_run_state(tmp.path(), &args, false).unwrap(), DemoRun::Replace, "an unreadable run is trained afresh");
    }

    #[test]
    fn a_dataset_with_other_settings_is_the_demos_to_render_again() {
        let tmp = tempfile::tempdir().unwrap();
        let quick = DatasetRenderConfig::preset(Preset::Quick);
        assert!(!other_demo_dataset(tmp.path(), &quick), "no record: nothing to replace");
        let record = serde_json::json!({ "renderer": "any", "config": quick });
        std::fs::write(tmp.path().join(pathtracer::dataset_render::RENDER_CONFIG_FILE), record.to_string()).unwrap();
        assert!(!other_demo_dataset(tmp.path(), &quick));
        assert!(other_demo_dataset(tmp.path(), &DatasetRenderConfig { train: 100, ..quick }));
    }
}
