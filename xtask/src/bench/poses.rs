//! `cargo xtask bench poses`: what noisy training poses cost and what camera refinement buys
//! back, against the exact poses. For every scene it renders the dataset at a preset (resumed
//! when it exists), then per noise level `L` (rotation `L` degrees, translation `L` % of the
//! scene size, `train --pose-noise L,L/100`; level 0 trains on the exact poses), camera
//! refinement off and `se3` (`train --camera-opt se3`) and seed, trains one run under the same
//! wall-clock budget and evaluates it on the test views with the mesh (`cargo xtask eval`,
//! test views posed through the alignment of the training centres, and refined per view with
//! `--test-pose-opt N` when given). It writes `<out>/bench-poses.md` (per scene a table of
//! means ± two standard errors over the seeds: the training poses' median rotation and centre
//! error before and after refinement, test PSNR and its difference from the noise-free run
//! without refinement, depth MAE, Chamfer-L1; then the targets checked),
//! `<out>/bench-poses.json` (every run's figures) and per scene `poses.png` (pose error and
//! test PSNR against the noise level, with and without refinement). Finished runs with the same
//! config are kept, so a re-run resumes. A benchmark, not a test: its figures depend on the
//! machine and its load.

use super::auto::{comma_list, parse_seeds, scene_names};
use super::supervision::{Figures, figures, mean_2se, scene_dataset, train_and_eval, write_report};
use anyhow::Context;
use nerf::camera_opt::CameraOptConfig;
use nerf::poses::PoseNoise;
use nerf::train::TrainConfig;
use pathtracer::dataset_render::Preset;
use std::path::{Path, PathBuf};

/// Options of `bench poses`.
#[derive(clap::Args, Clone, Debug)]
pub struct PosesBenchArgs {
    /// Scenes (names in `scenes/`), comma-separated; default every scene.
    #[arg(long)]
    pub scenes: Option<String>,
    /// Render preset of the datasets.
    #[arg(long, default_value = "standard")]
    pub preset: Preset,
    /// Training budget of every run (wall-clock training time: 90s, 2m, 5m).
    #[arg(long, default_value = "5m")]
    pub budget: String,
    /// Train every run for this many steps instead of `--budget` (quality at equal steps: for
    /// a machine whose load would make equal time unfair; the table lists each run's time).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Model: fast, auto or paper.
    #[arg(long, default_value = "fast")]
    pub model: String,
    /// Noise levels L, comma-separated: rotation L degrees and translation L % of the scene
    /// size (0: the exact poses).
    #[arg(long, default_value = "0,0.25,0.5,1,2,5")]
    pub levels: String,
    /// Camera refinement modes, comma-separated (off, se3).
    #[arg(long, default_value = "off,se3")]
    pub camera_opt: String,
    /// Camera refinement's learning rate (default: `CameraOptConfig`'s).
    #[arg(long)]
    pub camera_lr: Option<f64>,
    /// Rays a view's gradient sums before its update (default: `CameraOptConfig`'s).
    #[arg(long)]
    pub camera_rays: Option<u32>,
    /// Training seeds, comma-separated.
    #[arg(long, default_value = "0,1,2")]
    pub seeds: String,
    /// Evaluate the first N test views of every run (default all).
    #[arg(long)]
    pub max_views: Option<usize>,
    /// Refine each test view's pose for N steps with the model frozen before it is measured
    /// (`eval --test-pose-opt N`; not for the noise-free runs without refinement).
    #[arg(long)]
    pub test_pose_opt: Option<u64>,
    /// Output folder: `<out>/<scene>/{dataset,<run>,poses.png}` and
    /// `<out>/bench-poses.{md,json}`.
    #[arg(long, default_value = "out/bench-poses")]
    pub out: PathBuf,
}

/// One run's figures: the common ones and the training poses' errors.
#[derive(Clone, Debug, Default, serde::Serialize)]
struct PoseFigures {
    level: f64,
    refine: bool,
    #[serde(flatten)]
    base: Figures,
    /// Median rotation error of the poses trained on, degrees (`None` for exact poses).
    rotation_before_deg: Option<f64>,
    /// ... after refinement (`None` without).
    rotation_after_deg: Option<f64>,
    /// Median centre error, % of the scene size, before and after.
    centre_before_pct: Option<f64>,
    centre_after_pct: Option<f64>,
}

/// A run's figures from its reports.
fn pose_figures(run: &Path, level: f64, refine: bool, seed: u64) -> anyhow::Result<PoseFigures> {
    let base = figures(run, &run_label(level, refine), seed)?;
    let ev: serde_json::Value = serde_json::from_slice(&std::fs::read(run.join("eval.json")).with_context(|| format!("reading {}", run.join("eval.json").display()))?)
        .with_context(|| format!("{}: not JSON", run.join("eval.json").display()))?;
    let get = |block: &str, key: &str| ev[block][key].as_f64();
    Ok(PoseFigures {
        level,
        refine,
        base,
        // Runs on the exact poses have no pose record: their error is 0.
        rotation_before_deg: get("train_poses", "rotation_median_deg").or((level == 0.0).then_some(0.0)),
        rotation_after_deg: get("refined_poses", "rotation_median_deg"),
        centre_before_pct: get("train_poses", "translation_median_pct").or((level == 0.0).then_some(0.0)),
        centre_after_pct: get("refined_poses", "translation_median_pct"),
    })
}

fn run_label(level: f64, refine: bool) -> String {
    format!("L{level}-{}", if refine { "se3" } else { "off" })
}

/// The columns of the table: (header, figure, decimals).
type Column = (&'static str, fn(&PoseFigures) -> Option<f64>, usize);
const COLUMNS: [Column; 7] = [
    ("rotation error before (°)", |f| f.rotation_before_deg, 3),
    ("rotation error after (°)", |f| f.rotation_after_deg, 3),
    ("centre error after (% size)", |f| f.centre_after_pct, 3),
    ("test PSNR (dB)", |f| Some(f.base.psnr), 2),
    ("SSIM", |f| Some(f.base.ssim), 4),
    ("depth MAE (m)", |f| f.base.depth_mae, 4),
    ("Chamfer-L1 (m)", |f| f.base.chamfer_l1, 4),
];

/// `mean ± 2 SE` of one column over a row's seeds.
fn cell(figs: &[PoseFigures], f: fn(&PoseFigures) -> Option<f64>, d: usize) -> String {
    match mean_2se(&figs.iter().map(f).collect::<Vec<_>>()) {
        None => "n/a".into(),
        Some((m, se)) => format!("{m:.d$}{}", se.map_or(String::new(), |e| format!(" ± {e:.d$}"))),
    }
}

fn mean(figs: &[PoseFigures], f: fn(&PoseFigures) -> Option<f64>) -> Option<f64> {
    mean_2se(&figs.iter().map(f).collect::<Vec<_>>()).map(|m| m.0)
}

/// The Markdown table of one scene, rows in level then mode order, with the PSNR difference
/// from the noise-free run without refinement.
fn scene_table(rows: &[(f64, bool, Vec<PoseFigures>)]) -> String {
    let mut s = String::from("| noise level | refinement | seeds |");
    for (h, _, _) in COLUMNS {
        s.push_str(&format!(" {h} |"));
    }
    s.push_str(" ΔPSNR vs exact poses (dB) | steps | training s |\n|---:|---|---:|");
    s.push_str(&"---:|".repeat(COLUMNS.len() + 3));
    s.push('\n');
    let exact = rows.iter().find(|r| r.0 == 0.0 && !r.1).and_then(|r| mean(&r.2, |f| Some(f.base.psnr)));
    for (level, refine, figs) in rows {
        s.push_str(&format!("| {level} | {} | {} |", if *refine { "se3" } else { "off" }, figs.len()));
        for (_, f, d) in COLUMNS {
            s.push_str(&format!(" {} |", cell(figs, f, d)));
        }
        let delta = match (exact, mean(figs, |f| Some(f.base.psnr))) {
            (Some(e), Some(m)) => format!("{:+.2}", m - e),
            _ => "n/a".into(),
        };
        let join = |v: Vec<String>| v.join("/");
        s.push_str(&format!(" {delta} | {} | {} |\n", join(figs.iter().map(|f| f.base.steps.to_string()).collect()), join(figs.iter().map(|f| format!("{:.0}", f.base.train_s)).collect())));
    }
    s
}

/// The targets on one scene, as sentences: at 1° / 1 %, refinement brings the median
/// rotation error to ≤ 0.1° and the test PSNR within 1 dB of the noise-free run; at 0, it costs
/// at most 0.3 dB.
fn targets(rows: &[(f64, bool, Vec<PoseFigures>)]) -> Vec<String> {
    let find = |l: f64, r: bool| rows.iter().find(|x| x.0 == l && x.1 == r).map(|x| x.2.as_slice());
    let psnr = |f: &[PoseFigures]| mean(f, |x| Some(x.base.psnr));
    let mut out = Vec::new();
    if let (Some(one), Some(exact)) = (find(1.0, true), find(0.0, false)) {
        if let Some(rot) = mean(one, |f| f.rotation_after_deg) {
            out.push(format!("1° / 1 % with refinement: median rotation error {rot:.3}° (target ≤ 0.1°: {})", if rot <= 0.1 { "met" } else { "missed" }));
        }
        if let (Some(a), Some(b)) = (psnr(one), psnr(exact)) {
            out.push(format!("1° / 1 % with refinement: test PSNR {a:.2} dB against {b:.2} dB on exact poses, {:+.2} dB (target within 1 dB: {})", a - b, if b - a <= 1.0 { "met" } else { "missed" }));
        }
    }
    if let (Some(on), Some(off)) = (find(0.0, true), find(0.0, false))
        && let (Some(a), Some(b)) = (psnr(on), psnr(off))
    {
        out.push(format!("exact poses: refinement on costs {:+.2} dB (target at most 0.3 dB lower: {})", a - b, if b - a <= 0.3 { "met" } else { "missed" }));
    }
    out
}

/// `poses.png` of one scene: median rotation error (before and after refinement) and test
/// PSNR (off and se3) against the noise level.
fn plot(path: &Path, scene: &str, rows: &[(f64, bool, Vec<PoseFigures>)]) -> anyhow::Result<()> {
    let series = |label: &str, refine: bool, f: fn(&PoseFigures) -> Option<f64>| eval::plot::ErrorSeries {
        label: label.into(),
        points: rows
            .iter()
            .filter(|r| r.1 == refine)
            .filter_map(|r| mean_2se(&r.2.iter().map(f).collect::<Vec<_>>()).map(|(m, se)| (r.0, m, se.unwrap_or(0.0))))
            .collect(),
    };
    let panels = [
        eval::plot::Panel {
            caption: format!("{scene}: training poses' median rotation error"),
            x_desc: "noise level (° rotation, % translation)".into(),
            y_desc: "degrees".into(),
            series: vec![series("as trained (no refinement)", false, |f| f.rotation_before_deg), series("after se3 refinement", true, |f| f.rotation_after_deg)],
        },
        eval::plot::Panel {
            caption: format!("{scene}: test PSNR"),
            x_desc: "noise level (° rotation, % translation)".into(),
            y_desc: "dB".into(),
            series: vec![series("refinement off", false, |f| Some(f.base.psnr)), series("se3", true, |f| Some(f.base.psnr))],
        },
    ];
    eval::plot::panels_png(path, &panels)?;
    Ok(())
}

/// Runs the benchmark.
pub fn run(args: PosesBenchArgs) -> anyhow::Result<()> {
    let budget_s = crate::train::parse_duration("--budget", &args.budget)?;
    let levels: Vec<f64> = comma_list(&args.levels)
        .iter()
        .map(|l| {
            let v: f64 = l.parse().map_err(|_| anyhow::anyhow!("--levels: '{l}' is not a number"))?;
            format!("{v},{}", v / 100.0).parse::<PoseNoise>().map_err(|e| anyhow::anyhow!("--levels: {e}"))?;
            Ok(v)
        })
        .collect::<anyhow::Result<_>>()?;
    anyhow::ensure!(!levels.is_empty(), "--levels is empty");
    let modes: Vec<bool> = comma_list(&args.camera_opt)
        .iter()
        .map(|m| nerf::camera_opt::parse_mode(m).map(|c| c.is_some()).map_err(|e| anyhow::anyhow!("--camera-opt: {e}")))
        .collect::<anyhow::Result<_>>()?;
    anyhow::ensure!(!modes.is_empty(), "--camera-opt is empty");
    TrainConfig::preset(&args.model, PathBuf::new()).map_err(|e| anyhow::anyhow!("--model {}: {e}", args.model))?;
    anyhow::ensure!(args.max_views != Some(0), "--max-views 0 evaluates nothing");
    anyhow::ensure!(args.test_pose_opt != Some(0), "--test-pose-opt 0 optimises nothing");
    anyhow::ensure!(args.steps != Some(0), "--steps 0 trains nothing");
    if let Some(lr) = args.camera_lr {
        CameraOptConfig { lr, ..Default::default() }.check().map_err(|e| anyhow::anyhow!("--camera-lr: {e}"))?;
    }
    let seeds = parse_seeds(&args.seeds)?;
    let scenes = scene_names(args.scenes.as_deref())?;
    let mut md = format!(
        "# bench poses\n\nmodel {}, preset {}, budget {} per run, seeds {}, test views {}\n\nNoise level L: each training pose turned by N(0, L°) about a random axis and its centre moved by L % of the scene size (RMS), seeded per view. Errors of the training poses are medians over the views after the similarity aligning their centres to the exact ones. Cells: mean ± two standard errors over the seeds.\n\n",
        args.model,
        args.preset.name(),
        args.steps.map_or(args.budget.clone(), |n| format!("{n} steps")),
        seeds.iter().map(u64::to_string).collect::<Vec<_>>().join(", "),
        args.test_pose_opt.map_or("posed through the alignment".to_string(), |n| format!("posed through the alignment, then {n} steps of per-view pose optimisation with the model frozen"))
    );
    let mut all = Vec::new();
    for scene in &scenes {
        let dir = args.out.join(scene);
        let ds = dir.join("dataset");
        scene_dataset(scene, &ds, args.preset, &mut md)?;
        let mut rows = Vec::new();
        for &level in &levels {
            for &refine in &modes {
                let mut per_seed = Vec::new();
                for &seed in &seeds {
                    let mut cfg = TrainConfig::preset(&args.model, ds.clone()).map_err(anyhow::Error::msg)?;
                    cfg.seed = seed;
                    match args.steps {
                        Some(n) => {
                            cfg.steps = Some(n);
                            cfg.time_budget_s = None;
                        }
                        None => {
                            cfg.time_budget_s = Some(budget_s);
                            cfg.val_interval_s = Some(budget_s / 20.0);
                        }
                    }
                    cfg.pose_noise = (level > 0.0).then_some(PoseNoise { rotation_deg: level, translation_rel: level / 100.0 });
                    cfg.camera_opt = refine.then(|| {
                        let d = CameraOptConfig::default();
                        CameraOptConfig { lr: args.camera_lr.unwrap_or(d.lr), rays_per_update: args.camera_rays.unwrap_or(d.rays_per_update), ..d }
                    });
                    let run = dir.join(format!("{}-seed{seed}", run_label(level, refine)));
                    // Runs on the exact poses without refinement have no pose protocol.
                    let test_pose_opt = args.test_pose_opt.filter(|_| level > 0.0 || refine);
                    train_and_eval(&cfg, &run, &args.budget, args.max_views, test_pose_opt)?;
                    per_seed.push(pose_figures(&run, level, refine, seed)?);
                }
                all.extend(per_seed.iter().cloned());
                rows.push((level, refine, per_seed));
            }
        }
        let png = dir.join("poses.png");
        plot(&png, scene, &rows)?;
        md.push_str(&format!("## {scene}\n\n{}\n", scene_table(&rows)));
        for t in targets(&rows) {
            md.push_str(&format!("- {t}\n"));
        }
        md.push_str(&format!("\nplot: {}\n\n", png.display()));
    }
    write_report(&args.out, "bench-poses", &md, &all)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fig(level: f64, refine: bool, psnr: f64, after: Option<f64>) -> PoseFigures {
        PoseFigures { level, refine, base: Figures { psnr, ..Default::default() }, rotation_before_deg: (level > 0.0).then_some(level * 0.8), rotation_after_deg: after, ..Default::default() }
    }

    #[test]
    fn the_table_and_targets_say_what_was_measured() {
        let rows = vec![
            (0.0, false, vec![fig(0.0, false, 33.0, None), fig(0.0, false, 33.2, None)]),
            (0.0, true, vec![fig(0.0, true, 32.6, Some(0.01)), fig(0.0, true, 32.8, Some(0.02))]),
            (1.0, true, vec![fig(1.0, true, 32.5, Some(0.08)), fig(1.0, true, 32.3, Some(0.1))]),
        ];
        let t = scene_table(&rows);
        assert!(t.contains("| 1 | se3 | 2 | 0.800 ± 0.000 | 0.090 ± 0.020 |"), "{t}");
        assert!(t.contains("| -0.70 |"), "{t}");
        let targets = targets(&rows).join("\n");
        assert!(targets.contains("0.090° (target ≤ 0.1°: met)"), "{targets}");
        assert!(targets.contains("-0.70 dB (target within 1 dB: met)"), "{targets}");
        assert!(targets.contains("costs -0.40 dB (target at most 0.3 dB lower: missed)"), "{targets}");
    }
}
