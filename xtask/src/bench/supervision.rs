//! `cargo xtask bench supervision`: what depth, normal and empty-space supervision buy, at equal
//! wall-clock time. For every scene (default: all of `scenes/`) it renders the dataset at a
//! preset (resumed when it exists), trains one run per configuration and seed under the same
//! budget (validating every twentieth of it), evaluates each on the test views with the mesh
//! (`cargo xtask eval`), and writes `<out>/bench-supervision.md` (per scene a table of means
//! ± two standard errors over the seeds: test PSNR, SSIM, depth MAE, δ < 1.25, off-surface
//! mass, mesh Chamfer-L1 and F-score at 1 % of the diagonal, time to 30 dB; and each
//! configuration's difference from `off`, marked as inside the seeds' noise where it is below
//! two standard errors of the difference), `<out>/bench-supervision.json` (every run's
//! figures) and per scene `compare.png` (the validation curves overlaid). Configurations (the
//! options of `train`, formulas in the `nerf` crate's `supervision` module):
//! `off`, `expected` and `termination` on exact depth, `noisy1` (`noisy:0.01`), `sparse1`
//! (`sparse:0.01`), `holes30` (`holes:0.3`), each with the `expected` term, `empty`
//! (`--empty-loss` alone), `normal` (`--normal-loss` alone) and `expected+normal`. Finished runs with the same config are kept, so a re-run resumes.
//! A benchmark, not a test: its figures depend on the machine and its load.

use super::auto::{comma_list, older_dataset, parse_seeds, scene_names};
use anyhow::Context;
use nerf::supervision::{DepthLoss, DepthSource, SupervisionConfig};
use nerf::train::TrainConfig;
use pathtracer::dataset_render::Preset;
use std::path::{Path, PathBuf};

/// Options of `bench supervision`.
#[derive(clap::Args, Clone, Debug)]
pub struct SupervisionBenchArgs {
    /// Scenes (names in `scenes/`), comma-separated; default every scene.
    #[arg(long)]
    pub scenes: Option<String>,
    /// Render preset of the datasets.
    #[arg(long, default_value = "standard")]
    pub preset: Preset,
    /// Training budget of every run (wall-clock training time: 90s, 2m, 5m).
    #[arg(long, default_value = "2m")]
    pub budget: String,
    /// Model: fast, auto or paper.
    #[arg(long, default_value = "fast")]
    pub model: String,
    /// Configurations, comma-separated (of off, expected, termination, noisy1, sparse1,
    /// holes30, empty, normal, expected+normal).
    #[arg(long, default_value = "off,expected,termination,noisy1,sparse1,holes30")]
    pub configs: String,
    /// Training seeds, comma-separated.
    #[arg(long, default_value = "0,1,2")]
    pub seeds: String,
    /// Weight of the depth term (`--depth-weight`).
    #[arg(long, default_value_t = 0.2)]
    pub depth_weight: f32,
    /// Weight of the `empty` configuration's empty-space term (`--empty-loss`).
    #[arg(long, default_value_t = 0.05)]
    pub empty_weight: f32,
    /// Weight of the `normal` configurations' normal term (`--normal-loss`).
    #[arg(long, default_value_t = 0.01)]
    pub normal_weight: f32,
    /// Evaluate the first N test views of every run (default all).
    #[arg(long)]
    pub max_views: Option<usize>,
    /// Output folder: `<out>/<scene>/{dataset,<config>-seed<S>,compare.md}` and
    /// `<out>/bench-supervision.{md,json}`.
    #[arg(long, default_value = "out/bench-supervision")]
    pub out: PathBuf,
}

/// Every configuration, with what it sets.
const CONFIGS: [(&str, &str); 9] = [
    ("off", "colour only"),
    ("expected", "--depth-loss expected, exact depth"),
    ("termination", "--depth-loss termination, exact depth"),
    ("noisy1", "--depth-loss expected --depth-source noisy:0.01"),
    ("sparse1", "--depth-loss expected --depth-source sparse:0.01"),
    ("holes30", "--depth-loss expected --depth-source holes:0.3"),
    ("empty", "--empty-loss alone"),
    ("normal", "--normal-loss alone, exact depth and normals"),
    ("expected+normal", "--depth-loss expected --normal-loss, exact depth and normals"),
];

/// The weights of the configurations' terms.
#[derive(Clone, Copy, Debug)]
struct Weights {
    depth: f32,
    empty: f32,
    normal: f32,
}

/// The supervision of a configuration (`None`: colour only).
fn supervision_of(name: &str, w: Weights) -> anyhow::Result<Option<SupervisionConfig>> {
    let depth = |l: DepthLoss, s: DepthSource| Some(SupervisionConfig::new().with_depth_loss(l).with_depth_weight(w.depth).with_depth_source(s));
    Ok(match name {
        "off" => None,
        "expected" => depth(DepthLoss::Expected, DepthSource::Exact),
        "termination" => depth(DepthLoss::Termination, DepthSource::Exact),
        "noisy1" => depth(DepthLoss::Expected, DepthSource::Noisy(0.01)),
        "sparse1" => depth(DepthLoss::Expected, DepthSource::Sparse(0.01)),
        "holes30" => depth(DepthLoss::Expected, DepthSource::Holes(0.3)),
        "empty" => Some(SupervisionConfig::new().with_empty_weight(w.empty)),
        "normal" => Some(SupervisionConfig::new().with_normal_weight(w.normal)),
        "expected+normal" => depth(DepthLoss::Expected, DepthSource::Exact).map(|s| s.with_normal_weight(w.normal)),
        other => anyhow::bail!("--configs: unknown configuration '{other}' ({})", CONFIGS.map(|c| c.0).join(", ")),
    })
}

/// One run's figures (`None`: not measured on this dataset).
#[derive(Clone, Debug, Default, serde::Serialize)]
pub(super) struct Figures {
    pub(super) config: String,
    pub(super) seed: u64,
    pub(super) psnr: f64,
    pub(super) ssim: f64,
    pub(super) depth_mae: Option<f64>,
    pub(super) delta_1_25: Option<f64>,
    pub(super) off_surface_mass: Option<f64>,
    pub(super) chamfer_l1: Option<f64>,
    pub(super) f_score_1pct: Option<f64>,
    pub(super) time_to_30db_s: Option<f64>,
    pub(super) steps: u64,
    pub(super) train_s: f64,
}

/// The columns of the table: (header, figure, decimals).
type Column = (&'static str, fn(&Figures) -> Option<f64>, usize);
const COLUMNS: [Column; 8] = [
    ("PSNR (dB)", |f| Some(f.psnr), 2),
    ("SSIM", |f| Some(f.ssim), 4),
    ("depth MAE (m)", |f| f.depth_mae, 4),
    ("δ<1.25", |f| f.delta_1_25, 4),
    ("off-surface mass", |f| f.off_surface_mass, 4),
    ("Chamfer-L1 (m)", |f| f.chamfer_l1, 4),
    ("F-score 1 %", |f| f.f_score_1pct, 3),
    ("time to 30 dB (s)", |f| f.time_to_30db_s, 1),
];

/// Mean and two standard errors of the mean (`None` for the spread with one value; the
/// figure only when every seed has it).
pub(super) fn mean_2se(v: &[Option<f64>]) -> Option<(f64, Option<f64>)> {
    let v: Vec<f64> = v.iter().copied().collect::<Option<Vec<f64>>>()?;
    if v.is_empty() {
        return None;
    }
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let se = (v.len() > 1).then(|| 2.0 * (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0) / n).sqrt());
    Some((m, se))
}

/// The Markdown table of one scene: a row per configuration, `mean ± 2 SE` per column, and
/// the difference from `off` where both are measured (`~` marks one inside the seeds' noise).
fn scene_table(runs: &[(String, Vec<Figures>)]) -> String {
    let mut s = String::from("| configuration | seeds |");
    for (h, _, _) in COLUMNS {
        s.push_str(&format!(" {h} |"));
    }
    s.push_str("\n|---|---:|");
    s.push_str(&"---:|".repeat(COLUMNS.len()));
    s.push('\n');
    let off = runs.iter().find(|(n, _)| n == "off").map(|(_, r)| r.as_slice());
    for (name, figs) in runs {
        s.push_str(&format!("| {name} | {} |", figs.len()));
        for (_, f, d) in COLUMNS {
            let vals: Vec<Option<f64>> = figs.iter().map(f).collect();
            let cell = match mean_2se(&vals) {
                None => "n/a".to_string(),
                Some((m, se)) => {
                    let mut c = format!("{m:.d$}{}", se.map_or(String::new(), |e| format!(" ± {e:.d$}")));
                    if let (Some(off), false) = (off, name == "off") {
                        let base: Vec<f64> = off.iter().filter_map(f).collect();
                        let mine: Vec<f64> = vals.iter().flatten().copied().collect();
                        if base.len() == off.len() && !base.is_empty() {
                            let diff = m - base.iter().sum::<f64>() / base.len() as f64;
                            let noise = super::auto::two_se(&mine, &base).is_some_and(|e| diff.abs() < e);
                            c.push_str(&format!(" ({diff:+.d$}{})", if noise { " ~" } else { "" }));
                        }
                    }
                    c
                }
            };
            s.push_str(&format!(" {cell} |"));
        }
        s.push('\n');
    }
    s
}

/// A run's figures from its `report.json` and `eval.json`.
pub(super) fn figures(run: &Path, config: &str, seed: u64) -> anyhow::Result<Figures> {
    let r = eval::summarise_run(run)?;
    let ev: serde_json::Value = serde_json::from_slice(&std::fs::read(run.join("eval.json")).with_context(|| format!("reading {}", run.join("eval.json").display()))?)
        .with_context(|| format!("{}: not JSON", run.join("eval.json").display()))?;
    Ok(Figures {
        config: config.into(),
        seed,
        psnr: r.final_psnr,
        ssim: r.ssim,
        depth_mae: r.depth_mae,
        delta_1_25: ev["mean"]["depth_delta_1_25"].as_f64(),
        off_surface_mass: r.off_surface_mass,
        chamfer_l1: r.chamfer_l1,
        f_score_1pct: r.f_score_1pct,
        time_to_30db_s: r.time_to_30db_s,
        steps: r.train_steps,
        train_s: r.train_wall_s,
    })
}

/// Trains (unless a finished, evaluated run of the same config is there) and evaluates one run
/// (`eval --test-pose-opt N` with `test_pose_opt`).
pub(super) fn train_and_eval(cfg: &TrainConfig, run: &Path, budget: &str, max_views: Option<usize>, test_pose_opt: Option<u64>) -> anyhow::Result<()> {
    let cfg_path = run.with_extension("config.json");
    let want = serde_json::to_value(cfg)?;
    let recorded = std::fs::read(&cfg_path).ok().and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok());
    let eval = crate::evaluate::EvalArgs { test_pose_opt, ..crate::evaluate::EvalArgs::at_training_resolution(run.to_path_buf(), "test", 1, max_views) };
    if run.join("report.json").is_file() && recorded.as_ref() == Some(&want) {
        // The test views' pose protocol of the evaluation on record.
        let protocol = std::fs::read(run.join("eval.json")).ok().and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok()).and_then(|v| v["pose_protocol"].as_str().map(String::from));
        if protocol.as_deref().is_some_and(|p| p.contains("test-pose-opt")) == test_pose_opt.is_some()
            && test_pose_opt.is_none_or(|n| protocol.as_deref() == Some(&format!("aligned+test-pose-opt:{n}")))
        {
            eprintln!("{} is evaluated already; kept", run.display());
            return Ok(());
        }
        eprintln!("{} is trained; evaluating it again for another test-pose protocol", run.display());
        return crate::evaluate::run(eval);
    }
    if run.exists() {
        std::fs::remove_dir_all(run).with_context(|| format!("removing the stale run {}", run.display()))?;
    }
    dataset::io::atomic_write_json(&cfg_path, cfg)?;
    let mut args = crate::train::TrainArgs::for_demo(&cfg.dataset, run, "fast", budget, false);
    args.model = None;
    args.config = Some(cfg_path);
    if cfg.time_budget_s.is_none() {
        // A step budget, from the config file.
        args.time = None;
    }
    eprintln!("== training {}", run.display());
    crate::train::run(args)?;
    if crate::stop_flag().load(std::sync::atomic::Ordering::SeqCst) {
        return Err(crate::exit::Stopped("interrupted; re-run the same command to resume".into()).into());
    }
    crate::evaluate::run(eval)
}

/// Runs the benchmark.
pub fn run(args: SupervisionBenchArgs) -> anyhow::Result<()> {
    let budget_s = crate::train::parse_duration("--budget", &args.budget)?;
    let configs = comma_list(&args.configs);
    anyhow::ensure!(!configs.is_empty(), "--configs is empty");
    let weights = Weights { depth: args.depth_weight, empty: args.empty_weight, normal: args.normal_weight };
    for c in &configs {
        supervision_of(c, weights)?;
    }
    for (name, w) in [("--depth-weight", args.depth_weight), ("--empty-weight", args.empty_weight), ("--normal-weight", args.normal_weight)] {
        anyhow::ensure!(w.is_finite() && w >= 0.0, "{name} {w}: a weight must be a finite number ≥ 0");
    }
    TrainConfig::preset(&args.model, PathBuf::new()).map_err(|e| anyhow::anyhow!("--model {}: {e}", args.model))?;
    anyhow::ensure!(args.max_views != Some(0), "--max-views 0 evaluates nothing");
    let seeds = parse_seeds(&args.seeds)?;
    let scenes = scene_names(args.scenes.as_deref())?;
    let mut md = format!(
        "# bench supervision\n\nmodel {}, preset {}, budget {} per run, seeds {}, depth weight {}, empty weight {}, normal weight {}\n\nconfigurations: {}\n\nCells: mean ± two standard errors over the seeds, then the difference from `off` (`~`: inside the seeds' noise, under two standard errors of the difference).\n\n",
        args.model,
        args.preset.name(),
        args.budget,
        seeds.iter().map(u64::to_string).collect::<Vec<_>>().join(", "),
        args.depth_weight,
        args.empty_weight,
        args.normal_weight,
        CONFIGS.iter().filter(|c| configs.iter().any(|n| n == c.0)).map(|(n, d)| format!("{n} = {d}")).collect::<Vec<_>>().join("; ")
    );
    let mut all = Vec::new();
    for scene in &scenes {
        let dir = args.out.join(scene);
        let ds = dir.join("dataset");
        scene_dataset(scene, &ds, args.preset, &mut md)?;
        let mut runs: Vec<(String, Vec<Figures>)> = Vec::new();
        let mut summaries = Vec::new();
        for c in &configs {
            let mut per_seed = Vec::new();
            for &seed in &seeds {
                let mut cfg = TrainConfig::preset(&args.model, ds.clone()).map_err(anyhow::Error::msg)?;
                cfg.seed = seed;
                cfg.time_budget_s = Some(budget_s);
                cfg.val_interval_s = Some(budget_s / 20.0);
                cfg.supervision = supervision_of(c, weights)?;
                let run = dir.join(format!("{c}-seed{seed}"));
                train_and_eval(&cfg, &run, &args.budget, args.max_views, None)?;
                per_seed.push(figures(&run, c, seed)?);
                summaries.push(eval::summarise_run(&run)?);
            }
            all.extend(per_seed.iter().cloned());
            runs.push((c.clone(), per_seed));
        }
        eval::compare_runs(&summaries, &dir)?;
        let steps: Vec<String> = runs.iter().map(|(n, f)| format!("{n} {}", f.iter().map(|f| f.steps.to_string()).collect::<Vec<_>>().join("/"))).collect();
        md.push_str(&format!("## {scene}\n\n{}\nsteps at the budget per seed: {}\n\ncurves: {}\n\n", scene_table(&runs), steps.join(", "), dir.join("compare.png").display()));
    }
    write_report(&args.out, "bench-supervision", &md, &all)
}

/// Renders `scene`'s dataset into `ds` at `preset` (resumed when it is there), or keeps one an
/// older build rendered (said in `md`).
pub(super) fn scene_dataset(scene: &str, ds: &Path, preset: Preset, md: &mut String) -> anyhow::Result<()> {
    match older_dataset(ds) {
        Some(old) => md.push_str(&format!("{scene}: dataset rendered by {old} (kept with its runs)\n\n")),
        None => {
            eprintln!("==== {scene}: render ({} preset) into {}", preset.name(), ds.display());
            crate::render::run(crate::render::RenderArgs::for_demo(scene, ds, preset))?;
        }
    }
    Ok(())
}

/// Writes `<out>/<stem>.json` (every run's figures) and `<out>/<stem>.md`, prints the report and
/// says where it went.
pub(super) fn write_report(out: &Path, stem: &str, md: &str, all: &impl serde::Serialize) -> anyhow::Result<()> {
    dataset::io::atomic_write_json(&out.join(format!("{stem}.json")), all)?;
    let path = out.join(format!("{stem}.md"));
    dataset::io::atomic_write(&path, md.as_bytes())?;
    println!("{md}");
    println!("report: {}", path.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fig(config: &str, psnr: f64, depth: Option<f64>) -> Figures {
        Figures { config: config.into(), psnr, ssim: 0.9, depth_mae: depth, ..Default::default() }
    }

    #[test]
    fn configurations_set_their_options() {
        let w = |depth, empty| Weights { depth, empty, normal: 0.02 };
        assert!(supervision_of("off", w(0.05, 0.05)).unwrap().is_none());
        let n = supervision_of("noisy1", w(0.2, 0.05)).unwrap().unwrap();
        assert_eq!((n.depth_loss, n.depth_source, n.depth_weight, n.normal_weight), (DepthLoss::Expected, DepthSource::Noisy(0.01), 0.2, 0.0));
        let e = supervision_of("empty", w(0.2, 0.3)).unwrap().unwrap();
        assert_eq!((e.depth_loss, e.empty_weight), (DepthLoss::Off, 0.3));
        let m = supervision_of("expected+normal", w(0.2, 0.3)).unwrap().unwrap();
        assert_eq!((m.depth_loss, m.depth_weight, m.normal_weight, m.empty_weight), (DepthLoss::Expected, 0.2, 0.02, 0.0));
        let m = supervision_of("normal", w(0.2, 0.3)).unwrap().unwrap();
        assert_eq!((m.depth_loss, m.normal_weight), (DepthLoss::Off, 0.02));
        assert!(supervision_of("lidar", w(0.1, 0.1)).unwrap_err().to_string().contains("unknown configuration 'lidar'"));
    }

    #[test]
    fn the_table_gives_means_spreads_and_differences_against_the_noise() {
        let runs = vec![
            ("off".to_string(), vec![fig("off", 30.0, Some(0.10)), fig("off", 31.0, Some(0.12))]),
            ("expected".to_string(), vec![fig("expected", 30.2, Some(0.05)), fig("expected", 31.0, Some(0.05))]),
        ];
        let t = scene_table(&runs);
        // off: mean 30.5, 2 SE = 2 · √(0.5 / 2) = 1.0
        assert!(t.contains("| off | 2 | 30.50 ± 1.00 |"), "{t}");
        // expected's PSNR is +0.10 inside the noise; its depth −0.0600 beyond it (2 SE 0.02).
        assert!(t.contains("| expected | 2 | 30.60 ± 0.80 (+0.10 ~) |"), "{t}");
        assert!(t.contains("0.0500 ± 0.0000 (-0.0600) |"), "{t}");
        assert!(t.contains("| n/a |"), "figures no run measured");
        assert_eq!(mean_2se(&[Some(1.0), None]), None);
        assert_eq!(mean_2se(&[Some(2.0)]), Some((2.0, None)));
    }
}
