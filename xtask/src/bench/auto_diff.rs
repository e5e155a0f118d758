//! `cargo xtask bench auto-diff --before DIR --after DIR`: quality at equal time, before and
//! after a change. Reads two output folders of `bench auto` (the same scenes, configurations,
//! seeds and budget, trained by two builds) and compares every figure of every configuration:
//! training steps and steps per second, final test PSNR and SSIM, time to 30 dB, depth error, off-surface mass,
//! mesh Chamfer-L1 and F-score, and validation PSNR at equal training time (15 s, 30 s, 1, 2,
//! 3, 5 minutes and on, as far as every run trained). Each figure's means over the seeds are compared against the
//! seeds' noise as `bench auto` defines it (two standard errors of the difference of the means,
//! Welch), so a change that a re-run could reverse is not read as a gain or a loss. Writes
//! `bench-auto-diff.md` (default: in the `--after` folder) and prints it; the last section lists
//! every loss beyond the seeds' noise.
//!
//! Runs are paired by name (`<scene>/<config>` and `<scene>/<config>-seed<S>`), so each side
//! contributes the same seeds; a run on one side only is named and left out. The two sides'
//! training settings (`<run>.config.json`, written by `bench auto`) must agree wherever both
//! builds record the same setting: the dataset folder may differ (a note says whether the
//! two resolve to the same folder).

use super::auto::two_se;
use anyhow::Context;
use eval::RunSummary;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Options of `bench auto-diff`.
#[derive(clap::Args, Clone, Debug)]
pub struct AutoDiffArgs {
    /// `bench auto` output folder of the build before the change.
    #[arg(long)]
    pub before: PathBuf,
    /// `bench auto` output folder of the build after the change.
    #[arg(long)]
    pub after: PathBuf,
    /// Report file [default: `<after>/bench-auto-diff.md`].
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// One compared figure of a run.
struct Figure {
    /// Label in the table.
    name: &'static str,
    /// The run's value (`None`: not measured, or never reached).
    get: fn(&RunSummary) -> Option<f64>,
    /// Whether a larger value is better.
    higher_is_better: bool,
    /// Decimals printed.
    digits: usize,
}

const FIGURES: [Figure; 9] = [
    Figure { name: "training steps", get: |r| Some(r.train_steps as f64), higher_is_better: true, digits: 0 },
    Figure { name: "steps per second", get: |r| (r.train_wall_s > 0.0).then(|| r.train_steps as f64 / r.train_wall_s), higher_is_better: true, digits: 2 },
    Figure { name: "final test PSNR (dB)", get: |r| Some(r.final_psnr), higher_is_better: true, digits: 2 },
    Figure { name: "SSIM", get: |r| Some(r.ssim), higher_is_better: true, digits: 4 },
    Figure { name: "time to 30 dB (s)", get: |r| r.time_to_30db_s, higher_is_better: false, digits: 1 },
    Figure { name: "depth MAE (m)", get: |r| r.depth_mae, higher_is_better: false, digits: 4 },
    Figure { name: "off-surface mass", get: |r| r.off_surface_mass, higher_is_better: false, digits: 4 },
    Figure { name: "mesh Chamfer-L1 (m)", get: |r| r.chamfer_l1, higher_is_better: false, digits: 4 },
    Figure { name: "mesh F@1 %", get: |r| r.f_score_1pct, higher_is_better: true, digits: 3 },
];

/// The configuration a run folder belongs to: its name less a `-seed<S>` suffix.
fn config_of_run(name: &str) -> &str {
    match name.rsplit_once("-seed") {
        Some((config, seed)) if !config.is_empty() && !seed.is_empty() && seed.bytes().all(|b| b.is_ascii_digit()) => config,
        _ => name,
    }
}

/// The evaluated runs of one scene folder (sub-folders with a `report.json`), by name.
fn evaluated_runs(scene_dir: &Path) -> anyhow::Result<BTreeMap<String, RunSummary>> {
    let mut runs = BTreeMap::new();
    let entries = std::fs::read_dir(scene_dir).with_context(|| format!("reading {}", scene_dir.display()))?;
    for e in entries {
        let path = e.with_context(|| format!("reading {}", scene_dir.display()))?.path();
        if !path.join("report.json").is_file() {
            continue;
        }
        let Some(name) = path.file_name().and_then(|n| n.to_str()) else { continue };
        let summary = eval::summarise_run(&path).with_context(|| format!("reading the evaluation of {}", path.display()))?;
        runs.insert(name.to_string(), summary);
    }
    Ok(runs)
}

/// The scene folders of a `bench auto` output folder (those holding at least one evaluated
/// run), by name.
fn scenes(out: &Path) -> anyhow::Result<BTreeMap<String, BTreeMap<String, RunSummary>>> {
    anyhow::ensure!(out.is_dir(), "{} is not a folder (expected a `bench auto` output folder)", out.display());
    let mut scenes = BTreeMap::new();
    for e in std::fs::read_dir(out).with_context(|| format!("reading {}", out.display()))? {
        let path = e.with_context(|| format!("reading {}", out.display()))?.path();
        if !path.is_dir() {
            continue;
        }
        let Some(name) = path.file_name().and_then(|n| n.to_str()) else { continue };
        let runs = evaluated_runs(&path)?;
        if !runs.is_empty() {
            scenes.insert(name.to_string(), runs);
        }
    }
    Ok(scenes)
}

/// The settings on which two JSON configs disagree, as `path: a vs b`, over the keys both
/// have (a setting one build does not know is not compared), leaving out `skip` at the top.
fn differing_settings(a: &serde_json::Value, b: &serde_json::Value, path: &str, skip: &[&str], out: &mut Vec<String>) {
    match (a, b) {
        (serde_json::Value::Object(a), serde_json::Value::Object(b)) => {
            for (k, va) in a {
                if path.is_empty() && skip.contains(&k.as_str()) {
                    continue;
                }
                if let Some(vb) = b.get(k) {
                    let p = if path.is_empty() { k.clone() } else { format!("{path}.{k}") };
                    differing_settings(va, vb, &p, &[], out);
                }
            }
        }
        _ if a != b => out.push(format!("{path}: {a} vs {b}")),
        _ => {}
    }
}

/// What the records of a pair of runs say besides agreeing (see [`check_settings`]).
#[derive(Debug, PartialEq)]
struct PairSettings {
    /// The two dataset folders (before, after), when both runs have a record.
    datasets: Option<(PathBuf, PathBuf)>,
    /// The after-run's seconds between validations: its time to 30 dB is interpolated
    /// between validations (`eval::curve::time_to_psnr`).
    val_interval_s: Option<f64>,
}

/// Checks that the two sides of a pair of runs trained with the same settings, from the
/// configs `bench auto` wrote next to them (`<run>.config.json`, each read once), and returns
/// what else they record. A pair without both records (trained by hand) is compared
/// unchecked.
fn check_settings(before: &Path, after: &Path) -> anyhow::Result<PairSettings> {
    let read = |run: &Path| -> anyhow::Result<Option<serde_json::Value>> {
        let path = run.with_extension("config.json");
        if !path.is_file() {
            return Ok(None);
        }
        let bytes = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
        serde_json::from_slice(&bytes).map(Some).with_context(|| format!("{} is not valid JSON", path.display()))
    };
    let (a, b) = (read(before)?, read(after)?);
    let val_interval_s = b.as_ref().and_then(|v| v.get("val_interval_s")?.as_f64());
    let (Some(a), Some(b)) = (a, b) else { return Ok(PairSettings { datasets: None, val_interval_s }) };
    let mut diffs = Vec::new();
    differing_settings(&a, &b, "", &["dataset"], &mut diffs);
    anyhow::ensure!(
        diffs.is_empty(),
        "{} and {} were trained with different settings ({}): not the same experiment",
        before.with_extension("config.json").display(),
        after.with_extension("config.json").display(),
        diffs.join("; ")
    );
    let dataset = |v: &serde_json::Value| v.get("dataset").and_then(|d| d.as_str()).map(PathBuf::from);
    Ok(PairSettings { datasets: dataset(&a).zip(dataset(&b)), val_interval_s })
}

/// Mean of a non-empty slice.
fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

/// `mean (lo–hi)` with a figure's decimals; the range only for several seeds.
fn mean_and_range(v: &[f64], digits: usize) -> String {
    let m = mean(v);
    if v.len() < 2 {
        return format!("{m:.digits$}");
    }
    let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    format!("{m:.digits$} ({lo:.digits$}–{hi:.digits$})")
}

/// The verdict on one figure: whether the after-build's mean is better, the same or worse,
/// and with several seeds on both sides whether the difference lies beyond the seeds' noise
/// (at least two standard errors of the difference of the means). Returns the words and
/// whether it is a loss beyond the noise; the noise is printed with one decimal more than
/// the figure (`digits`).
fn judge(before: &[f64], after: &[f64], higher_is_better: bool, digits: usize) -> (String, bool) {
    let digits = digits + 1;
    let diff = mean(after) - mean(before);
    let gain = if higher_is_better { diff } else { -diff };
    if gain == 0.0 {
        return ("same".into(), false);
    }
    let word = if gain > 0.0 { "better" } else { "worse" };
    match two_se(before, after) {
        Some(e) if diff.abs() < e => (format!("{word}, inside the seeds' noise (2 SE {e:.digits$})"), false),
        Some(e) if gain > 0.0 => (format!("**better**, beyond the seeds' noise (2 SE {e:.digits$})"), false),
        Some(e) => (format!("**WORSE**, beyond the seeds' noise (2 SE {e:.digits$})"), true),
        None => (format!("{word} (one seed: no noise estimate)"), false),
    }
}

/// One configuration's table rows (`| config | figure | before | after | change | verdict |`)
/// over paired runs `(before, after)`, and its losses beyond the seeds' noise.
fn compare_config(config: &str, pairs: &[(&RunSummary, &RunSummary)]) -> (String, Vec<String>) {
    let mut rows = String::new();
    let mut losses = Vec::new();
    for f in &FIGURES {
        let b: Vec<Option<f64>> = pairs.iter().map(|(b, _)| (f.get)(b)).collect();
        let a: Vec<Option<f64>> = pairs.iter().map(|(_, a)| (f.get)(a)).collect();
        if b.iter().chain(&a).all(Option::is_none) {
            continue; // not measured on this scene (e.g. no mesh)
        }
        let missing = |v: &[Option<f64>]| v.iter().filter(|x| x.is_none()).count();
        let (mb, ma) = (missing(&b), missing(&a));
        if mb > 0 || ma > 0 {
            let n = pairs.len();
            rows.push_str(&format!(
                "| {config} | {} | {} of {n} seeds without a value | {} of {n} seeds without a value | - | not compared |\n",
                f.name, mb, ma
            ));
            continue;
        }
        let b: Vec<f64> = b.into_iter().flatten().collect();
        let a: Vec<f64> = a.into_iter().flatten().collect();
        let d = mean(&a) - mean(&b);
        let pct = if mean(&b) != 0.0 { format!(" ({:+.1} %)", 100.0 * d / mean(&b).abs()) } else { String::new() };
        let digits = f.digits;
        let (verdict, loss) = judge(&b, &a, f.higher_is_better, digits);
        rows.push_str(&format!(
            "| {config} | {} | {} | {} | {d:+.digits$}{pct} | {verdict} |\n",
            f.name,
            mean_and_range(&b, digits),
            mean_and_range(&a, digits)
        ));
        if loss {
            losses.push(format!("{config}: {} {} → {}{pct}, {verdict}", f.name, mean_and_range(&b, digits), mean_and_range(&a, digits)));
        }
    }
    (rows, losses)
}

/// The training times (s) at which the validation curves are compared: of these, those that
/// every run of a configuration, on both sides, spans (from its first validation to its last).
const CURVE_TIMES_S: [f64; 10] = [15.0, 30.0, 60.0, 120.0, 180.0, 300.0, 600.0, 1200.0, 1800.0, 3600.0];

/// One configuration's validation PSNR at equal training time (`| config | t | before |
/// after | change | verdict |`, at each of [`CURVE_TIMES_S`] that every run spans; linear
/// between validations, [`eval::value_at`]), judged against the seeds' noise as the final
/// figures are, and its losses beyond that noise.
fn compare_curves(config: &str, pairs: &[(&RunSummary, &RunSummary)]) -> (String, Vec<String>) {
    // Each run's curve as points once, not once per compared time.
    let curves: Vec<_> = pairs.iter().map(|(b, a)| (b.val_psnr_points(), a.val_psnr_points())).collect();
    let mut rows = String::new();
    let mut losses = Vec::new();
    for t in CURVE_TIMES_S {
        let b: Option<Vec<f64>> = curves.iter().map(|(b, _)| eval::value_at(b, t)).collect();
        let a: Option<Vec<f64>> = curves.iter().map(|(_, a)| eval::value_at(a, t)).collect();
        let (Some(b), Some(a)) = (b, a) else { continue };
        if b.is_empty() {
            continue;
        }
        let (verdict, loss) = judge(&b, &a, true, 2);
        let d = mean(&a) - mean(&b);
        rows.push_str(&format!("| {config} | {t} | {} | {} | {d:+.2} | {verdict} |\n", mean_and_range(&b, 2), mean_and_range(&a, 2)));
        if loss {
            losses.push(format!("{config}: val PSNR at {t} s {} → {} dB, {verdict}", mean_and_range(&b, 2), mean_and_range(&a, 2)));
        }
    }
    (rows, losses)
}

/// Runs the comparison.
pub fn run(args: AutoDiffArgs) -> anyhow::Result<()> {
    let before = scenes(&args.before)?;
    let after = scenes(&args.after)?;
    let common: Vec<&String> = after.keys().filter(|s| before.contains_key(*s)).collect();
    anyhow::ensure!(
        !common.is_empty(),
        "no scene has evaluated runs in both {} ({}) and {} ({})",
        args.before.display(),
        before.keys().cloned().collect::<Vec<_>>().join(", "),
        args.after.display(),
        after.keys().cloned().collect::<Vec<_>>().join(", ")
    );
    let mut md = format!(
        "# bench auto-diff\n\nbefore: {}\nafter: {}\n\nMeans over the seeds, with their range; \"beyond the seeds' noise\": the means differ by at least two standard errors of their difference (Welch), as `bench auto` weighs its targets.\n\n",
        args.before.display(),
        args.after.display()
    );
    let unpaired: Vec<String> = before.keys().chain(after.keys()).filter(|s| !(before.contains_key(*s) && after.contains_key(*s))).cloned().collect();
    if !unpaired.is_empty() {
        md.push_str(&format!("scenes on one side only (left out): {}\n\n", unpaired.join(", ")));
    }
    let mut all_losses = Vec::new();
    for scene in common {
        let (rb, ra) = (&before[scene], &after[scene]);
        md.push_str(&format!("## {scene}\n\n"));
        let mut notes = Vec::new();
        let mut groups: BTreeMap<&str, Vec<(&RunSummary, &RunSummary)>> = BTreeMap::new();
        let mut datasets = Vec::new();
        // Each configuration's validation interval, from its first run (in name order).
        let mut intervals: BTreeMap<&str, f64> = BTreeMap::new();
        for (name, a) in ra {
            let Some(b) = rb.get(name) else {
                notes.push(format!("{name}: after only (left out)"));
                continue;
            };
            let config = config_of_run(name);
            let settings = check_settings(&args.before.join(scene).join(name), &args.after.join(scene).join(name))?;
            datasets.extend(settings.datasets);
            if let Some(v) = settings.val_interval_s {
                intervals.entry(config).or_insert(v);
            }
            groups.entry(config).or_default().push((b, a));
        }
        notes.extend(rb.keys().filter(|n| !ra.contains_key(*n)).map(|n| format!("{n}: before only (left out)")));
        let intervals: Vec<String> = intervals.iter().map(|(c, v)| format!("{c} every {v} s")).collect();
        if !intervals.is_empty() {
            notes.push(format!(
                "time to 30 dB is interpolated between validations ({}), and is the first validation's time where that one already reaches 30 dB: a change smaller than the interval is a weak signal",
                intervals.join(", ")
            ));
        }
        let resolve = |p: &Path| std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf());
        if datasets.iter().any(|(b, a)| resolve(b) != resolve(a)) {
            notes.push("the two sides trained on different dataset folders: their differences include the datasets' Monte Carlo noise".into());
        } else if !datasets.is_empty() {
            notes.push(format!("both sides trained on the same dataset ({})", resolve(&datasets[0].0).display()));
        }
        md.push_str("| config | figure | before | after | change | verdict |\n|---|---|---:|---:|---:|---|\n");
        for (config, pairs) in &groups {
            let (rows, losses) = compare_config(config, pairs);
            md.push_str(&rows);
            all_losses.extend(losses.into_iter().map(|l| format!("{scene} {l}")));
        }
        md.push('\n');
        let curves: Vec<(String, Vec<String>)> = groups.iter().map(|(config, pairs)| compare_curves(config, pairs)).collect();
        if curves.iter().any(|(rows, _)| !rows.is_empty()) {
            md.push_str("Validation PSNR (dB) at equal training time, linear between validations:\n\n| config | t (s) | before | after | change | verdict |\n|---|---:|---:|---:|---:|---|\n");
            for (rows, losses) in curves {
                md.push_str(&rows);
                all_losses.extend(losses.into_iter().map(|l| format!("{scene} {l}")));
            }
            md.push('\n');
        }
        for n in notes {
            md.push_str(&format!("- {n}\n"));
        }
        md.push('\n');
    }
    md.push_str("## Losses beyond the seeds' noise\n\n");
    if all_losses.is_empty() {
        md.push_str("none\n");
    } else {
        for l in &all_losses {
            md.push_str(&format!("- {l}\n"));
        }
    }
    let path = report_path(&args);
    dataset::io::atomic_write(&path, md.as_bytes()).with_context(|| format!("writing {}", path.display()))?;
    println!("{md}");
    println!("report: {}", path.display());
    Ok(())
}

/// Where the report goes: `--out`, or `bench-auto-diff.md` in the after folder.
pub(super) fn report_path(args: &AutoDiffArgs) -> PathBuf {
    args.out.clone().unwrap_or_else(|| args.after.join("bench-auto-diff.md"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn summary(steps: u64, psnr: f64, t30: Option<f64>, chamfer: Option<f64>) -> RunSummary {
        RunSummary {
            name: String::new(),
            time_to_25db_s: Some(1.0),
            time_to_30db_s: t30,
            final_psnr: psnr,
            ssim: 0.9,
            depth_mae: Some(0.01),
            off_surface_mass: None,
            off_surface_front: None,
            mask_iou: None,
            parameters: 100,
            train_wall_s: 120.0,
            train_steps: steps,
            render_s_per_view: 1.0,
            val_psnr_curve: Vec::new(),
            resolution: None,
            chamfer_l1: chamfer,
            f_score_1pct: None,
            tool: None,
        }
    }

    #[test]
    fn runs_group_by_configuration() {
        assert_eq!(config_of_run("fast-medium-seed12"), "fast-medium");
        assert_eq!(config_of_run("auto"), "auto");
        assert_eq!(config_of_run("auto-seed"), "auto-seed", "no seed number");
        assert_eq!(config_of_run("auto-seedx"), "auto-seedx");
        assert_eq!(config_of_run("-seed1"), "-seed1");
    }

    #[test]
    fn verdicts_weigh_the_difference_against_the_seeds_noise() {
        // Means 10 vs 12, each side ±1 over two seeds (variance 2, of the mean 1): 2 SE = 2 √2.
        let (v, loss) = judge(&[9.0, 11.0], &[11.0, 13.0], true, 2);
        assert!(v.starts_with("better, inside the seeds' noise (2 SE 2.828)") && !loss, "{v}");
        let (v, loss) = judge(&[9.0, 11.0], &[11.0, 13.0], false, 2);
        assert!(v.starts_with("worse, inside") && !loss, "{v}");
        // Spread ±0.1: the same 2.0 difference is beyond the noise.
        let (v, loss) = judge(&[9.9, 10.1], &[11.9, 12.1], false, 2);
        assert!(v.starts_with("**WORSE**, beyond") && loss, "{v}");
        let (v, loss) = judge(&[9.9, 10.1], &[11.9, 12.1], true, 2);
        assert!(v.starts_with("**better**, beyond") && !loss, "{v}");
        assert_eq!(judge(&[1.0, 2.0], &[2.0, 1.0], true, 2).0, "same");
        let (v, loss) = judge(&[1.0], &[2.0], false, 2);
        assert_eq!((v.as_str(), loss), ("worse (one seed: no noise estimate)", false));
    }

    #[test]
    fn a_configuration_is_compared_figure_by_figure() {
        let b = [summary(100, 30.0, Some(20.0), None), summary(110, 30.2, Some(22.0), None), summary(105, 30.1, None, None)];
        let a = [summary(150, 29.0, Some(18.0), None), summary(160, 29.1, Some(19.0), None), summary(155, 29.2, Some(17.0), None)];
        let pairs: Vec<_> = b.iter().zip(&a).collect();
        let (rows, losses) = compare_config("fast", &pairs);
        assert!(rows.contains("| fast | training steps | 105 (100–110) | 155 (150–160) | +50 (+47.6 %) | **better**, beyond"), "{rows}");
        assert!(rows.contains("| fast | final test PSNR (dB) | 30.10 (30.00–30.20) | 29.10 (29.00–29.20) | -1.00 (-3.3 %) | **WORSE**, beyond"), "{rows}");
        assert!(rows.contains("| fast | time to 30 dB (s) | 1 of 3 seeds without a value | 0 of 3 seeds without a value | - | not compared |"), "{rows}");
        assert!(rows.contains("| fast | SSIM | 0.9000 (0.9000–0.9000) | 0.9000 (0.9000–0.9000) | +0.0000 (+0.0 %) | same |"), "{rows}");
        assert!(!rows.contains("Chamfer") && !rows.contains("off-surface"), "figures nobody measured are left out: {rows}");
        assert_eq!(losses.len(), 1, "{losses:?}");
        assert!(losses[0].starts_with("fast: final test PSNR (dB) 30.10 (30.00–30.20) → 29.10 (29.00–29.20) (-3.3 %)"), "{losses:?}");
    }

    #[test]
    fn curves_are_compared_at_times_every_run_spans() {
        let run = |curve: Vec<[f64; 2]>| RunSummary { val_psnr_curve: curve, ..summary(100, 30.0, None, None) };
        // before: 20 dB at 10 s rising to 26 at 70 s, two close seeds; after: faster, two seeds 4 dB apart
        let b = [run(vec![[10.0, 20.0], [70.0, 26.0]]), run(vec![[10.0, 20.2], [70.0, 26.2]])];
        let a = [run(vec![[10.0, 22.0], [40.0, 25.0], [65.0, 30.0]]), run(vec![[10.0, 26.0], [40.0, 29.0], [65.0, 34.0]])];
        let pairs: Vec<_> = b.iter().zip(&a).collect();
        let (rows, losses) = compare_curves("fast", &pairs);
        // 15 s: before 20.5 / 20.7, after 22.5 / 26.5 (2 SE = 2 √(0.01 + 4) ≈ 4.0 > 3.9)
        assert!(rows.contains("| fast | 15 | 20.60 (20.50–20.70) | 24.50 (22.50–26.50) | +3.90 | better, inside the seeds' noise"), "{rows}");
        // 60 s: before 25.0 / 25.2, after 29.0 / 33.0
        assert!(rows.contains("| fast | 60 | 25.10 (25.00–25.20) | 31.00 (29.00–33.00) | +5.90 | **better**, beyond"), "{rows}");
        // 30 s is spanned too; 120 s by nobody (the after-runs end at 65 s)
        assert_eq!(rows.lines().count(), 3, "{rows}");
        assert!(losses.is_empty(), "{losses:?}");
        // swapped sides: the 60 s row is a loss beyond the noise, the others inside it
        let swapped: Vec<_> = a.iter().zip(&b).collect();
        let (_, losses) = compare_curves("fast", &swapped);
        assert_eq!(losses.len(), 1, "{losses:?}");
        assert!(losses[0].starts_with("fast: val PSNR at 60 s 31.00 (29.00–33.00) → 25.10 (25.00–25.20) dB, **WORSE**"), "{losses:?}");
        // a run without validations leaves no row
        let empty = [run(Vec::new())];
        let pairs: Vec<_> = b[..1].iter().zip(&empty).collect();
        assert_eq!(compare_curves("fast", &pairs).0, "");
    }

    #[test]
    fn settings_must_agree_where_both_builds_record_them() {
        let a = serde_json::json!({"dataset": "x", "seed": 1, "model": {"levels": 16, "old": 1}, "time_budget_s": 120.0});
        let b = serde_json::json!({"dataset": "y", "seed": 1, "model": {"levels": 16, "new": 2}, "time_budget_s": 300.0});
        let mut d = Vec::new();
        differing_settings(&a, &b, "", &["dataset"], &mut d);
        assert_eq!(d, vec!["time_budget_s: 120.0 vs 300.0".to_string()]);
        let dir = tempfile::tempdir().unwrap();
        let (rb, ra) = (dir.path().join("b/s/auto"), dir.path().join("a/s/auto"));
        std::fs::create_dir_all(&rb).unwrap();
        std::fs::create_dir_all(&ra).unwrap();
        assert_eq!(check_settings(&rb, &ra).unwrap(), PairSettings { datasets: None, val_interval_s: None }, "no records: unchecked");
        std::fs::write(rb.with_extension("config.json"), a.to_string()).unwrap();
        std::fs::write(ra.with_extension("config.json"), b.to_string()).unwrap();
        let e = check_settings(&rb, &ra).unwrap_err().to_string();
        assert!(e.contains("time_budget_s: 120.0 vs 300.0") && e.contains("not the same experiment"), "{e}");
        let b_same = serde_json::json!({"dataset": "y", "seed": 1, "model": {"levels": 16}, "time_budget_s": 120.0});
        std::fs::write(ra.with_extension("config.json"), b_same.to_string()).unwrap();
        assert_eq!(check_settings(&rb, &ra).unwrap(), PairSettings { datasets: Some((PathBuf::from("x"), PathBuf::from("y"))), val_interval_s: None }, "interval not recorded");
        std::fs::write(ra.with_extension("config.json"), serde_json::json!({"val_interval_s": 6.0}).to_string()).unwrap();
        assert_eq!(check_settings(&rb, &ra).unwrap().val_interval_s, Some(6.0));
        std::fs::write(ra.with_extension("config.json"), "{").unwrap();
        assert!(check_settings(&rb, &ra).unwrap_err().to_string().contains("is not valid JSON"));
    }

    #[test]
    fn missing_folders_and_no_common_scene_are_clear_errors() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("nope");
        let e = run(AutoDiffArgs { before: missing.clone(), after: dir.path().to_path_buf(), out: None }).unwrap_err().to_string();
        assert!(e.contains("nope") && e.contains("is not a folder"), "{e}");
        let e = run(AutoDiffArgs { before: dir.path().to_path_buf(), after: dir.path().to_path_buf(), out: None }).unwrap_err().to_string();
        assert!(e.contains("no scene has evaluated runs in both"), "{e}");
    }
}
