//! `cargo xtask bench auto`: does `--model auto` size the fast model well? For every scene
//! (default: all of `scenes/`), renders the dataset at a preset (`cargo xtask render`, resumed
//! when it exists), trains `auto`, three fixed `fast` sizes and `paper` under the same
//! wall-clock budget (all validating every twentieth of it), evaluates each on the test views
//! (`cargo xtask eval`) and compares them (`cargo xtask compare`: table and overlaid
//! speed-versus-error curves per scene). Writes `<out>/bench-auto.md` with every table and a
//! check of issue #6's targets, and prints it. A benchmark, not a test: its figures depend on
//! the machine and its load. Finished runs (with `report.json` and the same budget) are kept,
//! so a re-run resumes.

use anyhow::Context;
use nerf::models::ModelConfig;
use nerf::models::fast::FastConfig;
use nerf::train::TrainConfig;
use pathtracer::dataset_render::Preset;
use std::path::{Path, PathBuf};

/// Options of `bench auto`.
#[derive(clap::Args, Clone, Debug)]
pub struct AutoBenchArgs {
    /// Scenes (names in `scenes/`), comma-separated; default every scene (also for `bench render`).
    #[arg(long, help_heading = "bench auto")]
    pub scenes: Option<String>,
    /// Render preset of the datasets.
    #[arg(long, default_value = "standard", help_heading = "bench auto")]
    pub preset: Preset,
    /// Training budget of every run (wall-clock training time: 90s, 5m).
    #[arg(long, default_value = "5m", help_heading = "bench auto")]
    pub budget: String,
    /// Output folder: `<out>/<scene>/{dataset,<config>,compare.md}` and `<out>/bench-auto.md`.
    #[arg(long, default_value = "out/bench-auto", help_heading = "bench auto")]
    pub out: PathBuf,
    /// Evaluate the first N test views of every run (default all). The paper
    /// model needs minutes per standard-preset view on a CPU.
    #[arg(long, help_heading = "bench auto")]
    pub max_views: Option<usize>,
    /// Configurations, comma-separated (of auto, fast-small, fast-medium, fast-large, paper).
    #[arg(long, default_value = "auto,fast-small,fast-medium,fast-large,paper", help_heading = "bench auto")]
    pub configs: String,
}

/// The fixed sizes the benchmark compares `auto` with.
const FIXED: [(&str, &str); 4] = [
    ("fast-small", "8 levels × 2^15 entries, finest 256, 32³ grid, 256 steps per diagonal"),
    ("fast-medium", "the fast preset: 16 levels × 2^17, finest 512, 64³ grid, 512 steps"),
    ("fast-large", "instant-ngp's: 16 levels × 2^19, finest 2048, 128³ grid, 1024 steps"),
    ("paper", "the NeRF paper's MLP"),
];

/// The training config of a benchmark configuration.
fn config_of(name: &str, dataset: &Path, budget_s: f64) -> anyhow::Result<TrainConfig> {
    let fast = |f: FastConfig| -> anyhow::Result<TrainConfig> {
        let mut c = TrainConfig::preset("fast", dataset.to_path_buf()).map_err(anyhow::Error::msg)?;
        c.model = ModelConfig::Fast(f);
        Ok(c)
    };
    let mut cfg = match name {
        "auto" => TrainConfig::preset("auto", dataset.to_path_buf()).map_err(anyhow::Error::msg)?,
        "fast-small" => fast(
            FastConfig::new()
                .with_levels(8)
                .with_log2_table_size(15)
                .with_finest_resolution(256)
                .with_grid_resolution(32)
                .with_steps_per_diagonal(256),
        )?,
        "fast-medium" => fast(FastConfig::new())?,
        "fast-large" => fast(
            FastConfig::new()
                .with_log2_table_size(19)
                .with_finest_resolution(2048)
                .with_grid_resolution(128)
                .with_steps_per_diagonal(1024),
        )?,
        "paper" => TrainConfig::preset("paper", dataset.to_path_buf()).map_err(anyhow::Error::msg)?,
        other => anyhow::bail!("unknown configuration '{other}' (auto, fast-small, fast-medium, fast-large, paper)"),
    };
    cfg.time_budget_s = Some(budget_s);
    // Every run validates equally often, so times to 30 dB are measured alike.
    cfg.val_interval_s = Some(budget_s / 20.0);
    Ok(cfg)
}

fn scene_names(args: &AutoBenchArgs) -> anyhow::Result<Vec<String>> {
    if let Some(s) = &args.scenes {
        let v: Vec<String> = s.split(',').map(|x| x.trim().to_string()).filter(|x| !x.is_empty()).collect();
        anyhow::ensure!(!v.is_empty(), "--scenes is empty");
        return Ok(v);
    }
    let dir = crate::render::repo_root().join("scenes");
    let mut v: Vec<String> = std::fs::read_dir(&dir)
        .with_context(|| format!("reading {}", dir.display()))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "gltf" || e == "glb"))
        .filter_map(|p| p.file_stem().map(|s| s.to_string_lossy().into_owned()))
        .collect();
    v.sort();
    anyhow::ensure!(!v.is_empty(), "no scenes in {} (`cargo xtask gen-scenes` writes them)", dir.display());
    Ok(v)
}

/// The renderer of a finished dataset in `dir` when it is not this one (`None` when there is
/// no finished dataset, or it is this renderer's: then `render` resumes or checks it).
fn older_dataset(dir: &Path) -> Option<String> {
    crate::render::older_renderer(dir).filter(|_| dataset::Dataset::load(dir).is_ok())
}

/// Whether `run` holds a finished, evaluated run with this budget.
fn evaluated(run: &Path, budget_s: f64) -> bool {
    run.join("report.json").is_file()
        && TrainConfig::read(&run.join(nerf::train::CONFIG_FILE)).is_ok_and(|c| c.time_budget_s == Some(budget_s))
}

/// Trains (resuming a run with the same budget) and evaluates one configuration.
fn train_and_eval(name: &str, dataset: &Path, run: &Path, budget: &str, budget_s: f64, max_views: Option<usize>) -> anyhow::Result<()> {
    if evaluated(run, budget_s) {
        eprintln!("{} is evaluated already; kept", run.display());
        return Ok(());
    }
    let resumable = nerf::checkpoint::latest(run).is_some()
        && TrainConfig::read(&run.join(nerf::train::CONFIG_FILE)).is_ok_and(|c| c.time_budget_s == Some(budget_s));
    if run.exists() && !resumable {
        std::fs::remove_dir_all(run).with_context(|| format!("removing the stale run {}", run.display()))?;
    }
    let mut args = crate::train::TrainArgs::for_demo(dataset, run, "fast", budget, resumable);
    if !resumable {
        let cfg_path = run.with_extension("config.json");
        dataset::io::atomic_write_json(&cfg_path, &config_of(name, dataset, budget_s)?)?;
        args.config = Some(cfg_path);
    }
    eprintln!("== {name}: training into {}", run.display());
    crate::train::run(args)?;
    if crate::stop_flag().load(std::sync::atomic::Ordering::SeqCst) {
        anyhow::bail!("interrupted; re-run the same command to resume");
    }
    crate::evaluate::run(crate::evaluate::EvalArgs { run: run.to_path_buf(), split: "test".into(), grids: 1, max_views })
}

/// What the targets say about one scene's runs.
fn targets(scene: &str, runs: &[(String, eval::RunSummary)]) -> Vec<String> {
    let Some((_, auto)) = runs.iter().find(|(n, _)| n == "auto") else { return vec![] };
    let mut out = Vec::new();
    let faster = |r: &eval::RunSummary| match (r.time_to_30db_s, auto.time_to_30db_s) {
        (Some(a), Some(b)) => a < b,
        (Some(_), None) => true,
        _ => false,
    };
    let beaters: Vec<&str> = runs
        .iter()
        .filter(|(n, r)| n != "auto" && faster(r) && r.final_psnr > auto.final_psnr + 0.3)
        .map(|(n, _)| n.as_str())
        .collect();
    out.push(if beaters.is_empty() {
        format!("{scene}: met — no fixed configuration is both faster to 30 dB and > 0.3 dB better than auto")
    } else {
        format!("{scene}: MISSED — {} faster to 30 dB and > 0.3 dB better than auto", beaters.join(", "))
    });
    if let Some((_, large)) = runs.iter().find(|(n, _)| n == "fast-large") {
        out.push(format!(
            "{scene}: auto has {} parameters, fast-large {} ({})",
            auto.parameters,
            large.parameters,
            if auto.parameters < large.parameters { "fewer" } else { "NOT fewer" }
        ));
    }
    let best = runs
        .iter()
        .filter(|(n, _)| n.starts_with("fast-"))
        .max_by(|a, b| a.1.final_psnr.total_cmp(&b.1.final_psnr));
    if let Some((bn, b)) = best {
        let cmp = |x: Option<f64>, y: Option<f64>| match (x, y) {
            (Some(x), Some(y)) => format!("{x:.4} vs {y:.4} ({})", if x <= y { "no worse" } else { "WORSE" }),
            _ => "n/a".into(),
        };
        out.push(format!(
            "{scene}: against the best fixed size ({bn}): depth MAE {}, off-surface mass {}",
            cmp(auto.depth_mae, b.depth_mae),
            cmp(auto.off_surface_mass, b.off_surface_mass)
        ));
    }
    out
}

/// Runs the benchmark.
pub fn run(args: AutoBenchArgs) -> anyhow::Result<()> {
    let budget_s = crate::train::parse_duration(&args.budget)?;
    let configs: Vec<String> = args.configs.split(',').map(|s| s.trim().to_string()).filter(|s| !s.is_empty()).collect();
    for c in &configs {
        config_of(c, Path::new("."), budget_s)?;
    }
    anyhow::ensure!(args.max_views != Some(0), "--max-views 0 evaluates nothing");
    let scenes = scene_names(&args)?;
    let mut md = format!(
        "# bench auto\n\npreset {}, budget {} per run, configurations: {}\n\nfixed sizes: {}\n\n",
        args.preset.name(),
        args.budget,
        configs.join(", "),
        FIXED.iter().map(|(n, d)| format!("{n} = {d}")).collect::<Vec<_>>().join("; ")
    );
    if let Some(m) = args.max_views {
        md.push_str(&format!("evaluated on the first {m} test view(s) of each scene\n\n"));
    }
    let mut checks = Vec::new();
    for scene in &scenes {
        let dir = args.out.join(scene);
        let dataset = dir.join("dataset");
        // A finished dataset of an older renderer (e.g. another sampler: the same images up to
        // Monte Carlo noise) is kept, with the runs trained on it; the report names its renderer.
        match older_dataset(&dataset) {
            Some(old) => {
                eprintln!("==== {scene}: keeping {} (rendered by {old})", dataset.display());
                md.push_str(&format!("{scene}: dataset rendered by {old} (kept with its runs)\n\n"));
            }
            None => {
                eprintln!("==== {scene}: render ({} preset) into {}", args.preset.name(), dataset.display());
                crate::render::run(crate::render::RenderArgs::for_demo(scene, &dataset, args.preset))?;
            }
        }
        let mut runs = Vec::new();
        for c in &configs {
            let run = dir.join(c);
            train_and_eval(c, &dataset, &run, &args.budget, budget_s, args.max_views)?;
            runs.push((c.clone(), eval::summarise_run(&run)?));
        }
        let summaries: Vec<eval::RunSummary> = runs.iter().map(|(_, r)| r.clone()).collect();
        let table = eval::compare_runs(&summaries, &dir)?;
        if let Ok(cfg) = TrainConfig::read(&dir.join("auto").join(nerf::train::CONFIG_FILE)) {
            md.push_str(&format!("## {scene}\n\n{table}\nauto's decisions:\n\n"));
            for r in cfg.auto_reasons.iter().flatten() {
                md.push_str(&format!("- {r}\n"));
            }
            md.push('\n');
        } else {
            md.push_str(&format!("## {scene}\n\n{table}\n"));
        }
        md.push_str(&format!("curves: {}\n\n", dir.join("compare.png").display()));
        checks.extend(targets(scene, &runs));
    }
    md.push_str("## Targets (issue #6)\n\n");
    for c in &checks {
        md.push_str(&format!("- {c}\n"));
    }
    let path = args.out.join("bench-auto.md");
    dataset::io::atomic_write(&path, md.as_bytes())?;
    println!("{md}");
    println!("report: {}", path.display());
    Ok(())
}
