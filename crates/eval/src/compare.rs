//! Comparing runs: one summary per run (`report.json`), a table marking the Pareto front,
//! and `compare.png` with every run's validation PSNR curve.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::curve::{MetricsRecord, time_to_psnr, val_psnr_points};
use crate::error::EvalError;
use crate::evaluate::{EvalReport, nonfinite};
use crate::plot::{Curve, compare_png};

/// The summary numbers of one run: the content of `report.json`, and one row of a comparison.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunSummary {
    /// Run name (legend and table label).
    pub name: String,
    /// Wall-clock seconds to reach 25 dB validation PSNR (`null`: never reached).
    #[serde(with = "nonfinite::option", default)]
    pub time_to_25db_s: Option<f64>,
    /// Wall-clock seconds to reach 30 dB validation PSNR (`null`: never reached).
    #[serde(with = "nonfinite::option", default)]
    pub time_to_30db_s: Option<f64>,
    /// Mean test-view PSNR of the final model, dB.
    #[serde(with = "nonfinite")]
    pub final_psnr: f64,
    /// Mean test-view SSIM (NaN, written `null`, for views smaller than its window).
    #[serde(with = "nonfinite")]
    pub ssim: f64,
    /// Mean test-view depth MAE, scene units (absent without ground-truth depth).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_mae: Option<f64>,
    /// Mean off-surface mass (absent without ground-truth distance or samples).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub off_surface_mass: Option<f64>,
    /// Its part in front of the surface (absent where the mass is, and in summaries written
    /// before it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub off_surface_front: Option<f64>,
    /// Mean mask IoU (absent without ground-truth alpha).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mask_iou: Option<f64>,
    /// Trainable parameters.
    pub parameters: u64,
    /// Wall-clock training time, seconds (a scored method's stated time; NaN, written `null`,
    /// when not stated).
    #[serde(with = "nonfinite")]
    pub train_wall_s: f64,
    /// Optimiser steps.
    pub train_steps: u64,
    /// Mean seconds to render one test view (NaN, written `null`, for a scored method).
    #[serde(with = "nonfinite")]
    pub render_s_per_view: f64,
    /// Validation PSNR curve `[wall_s, dB]`, for `compare.png`.
    #[serde(default)]
    pub val_psnr_curve: Vec<[f64; 2]>,
    /// The resolution the test views were evaluated at (absent in summaries written before it
    /// was recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resolution: Option<crate::evaluate::EvalResolution>,
    /// Chamfer-L1 of the extracted mesh against the scene's visible triangles, m (absent
    /// without the scene or the mesh).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub chamfer_l1: Option<f64>,
    /// Its F-score at 1 % of the scene box's diagonal.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub f_score_1pct: Option<f64>,
    /// For a method scored by `score` (another tool's predictions), the tool detected; absent
    /// for our runs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tool: Option<String>,
}

impl RunSummary {
    /// The validation PSNR curve as `(wall_s, dB)` points (what [`crate::value_at`] and
    /// the plots take).
    pub fn val_psnr_points(&self) -> Vec<(f64, f64)> {
        self.val_psnr_curve.iter().map(|p| (p[0], p[1])).collect()
    }

    /// Summarise a run from its evaluation report and its training curve.
    pub fn from_report(name: &str, report: &EvalReport, curve: &[MetricsRecord]) -> Self {
        Self {
            name: name.to_string(),
            time_to_25db_s: time_to_psnr(curve, 25.0),
            time_to_30db_s: time_to_psnr(curve, 30.0),
            final_psnr: report.mean.psnr,
            ssim: report.mean.ssim,
            depth_mae: report.mean.depth_mae,
            off_surface_mass: report.mean.off_surface_mass,
            off_surface_front: report.mean.off_surface_front,
            mask_iou: report.mean.mask_iou,
            parameters: report.parameters,
            train_wall_s: report.train_wall_s,
            train_steps: report.train_steps,
            render_s_per_view: report.mean.render_s_per_view,
            val_psnr_curve: val_psnr_points(curve).into_iter().map(|(t, p)| [t, p]).collect(),
            resolution: report.resolution,
            chamfer_l1: report.mesh.as_ref().map(|m| m.metrics.chamfer_l1),
            f_score_1pct: report.mesh.as_ref().and_then(|m| m.metrics.f_scores.iter().find(|f| (f.fraction - 0.01).abs() < 1e-12).map(|f| f.f_score)),
            tool: report.method.as_ref().map(|m| m.tool.clone()),
        }
    }

    /// Its points in `compare.png`: a run's validation PSNR curve; a scored method's test PSNR
    /// as one point at its stated training time (none without one).
    pub fn plot_points(&self) -> Vec<(f64, f64)> {
        match &self.tool {
            None => self.val_psnr_points(),
            Some(_) if self.train_wall_s.is_finite() => vec![(self.train_wall_s, self.final_psnr)],
            Some(_) => Vec::new(),
        }
    }
}

/// Which cost the Pareto front trades against final PSNR.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParetoAxis {
    /// Time to 30 dB validation PSNR (used when every run reaches 30 dB).
    TimeTo30Db,
    /// Total wall-clock training time (used when some run never reaches 30 dB, so that all
    /// runs are placed on the same axis).
    TrainWall,
}

/// Pareto-optimal points when minimising `x` and maximising `y`: point `i` is on the front
/// unless some `j` has `x_j <= x_i` and `y_j >= y_i` with at least one strict. Points with a
/// NaN coordinate are never on the front (and dominate nothing).
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<bool> {
    let valid = |p: &(f64, f64)| !p.0.is_nan() && !p.1.is_nan();
    points
        .iter()
        .map(|pi| {
            valid(pi)
                && !points.iter().any(|pj| {
                    valid(pj) && pj.0 <= pi.0 && pj.1 >= pi.1 && (pj.0 < pi.0 || pj.1 > pi.1)
                })
        })
        .collect()
}

/// The axis and the Pareto mask for a set of runs (see [`ParetoAxis`]).
pub fn pareto_runs(runs: &[RunSummary]) -> (ParetoAxis, Vec<bool>) {
    let axis = if runs.iter().all(|r| r.time_to_30db_s.is_some()) {
        ParetoAxis::TimeTo30Db
    } else {
        ParetoAxis::TrainWall
    };
    let pts: Vec<(f64, f64)> = runs
        .iter()
        .map(|r| {
            let x = match axis {
                ParetoAxis::TimeTo30Db => r.time_to_30db_s.unwrap_or(f64::NAN),
                ParetoAxis::TrainWall => r.train_wall_s,
            };
            (x, r.final_psnr)
        })
        .collect();
    (axis, pareto_front(&pts))
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("—".into(), |v| format!("{v:.digits$}"))
}

/// Off-surface mass with its part in front of the surface in brackets, when known.
pub fn off_surface(r: &RunSummary) -> String {
    match (r.off_surface_mass, r.off_surface_front) {
        (Some(m), Some(f)) => format!("{m:.4} ({f:.4})"),
        (m, _) => opt(m, 4),
    }
}

/// The comparison table (GitHub Markdown) with a Pareto column and a line saying which
/// axes the front uses.
pub fn compare_table(runs: &[RunSummary]) -> String {
    let (axis, front) = pareto_runs(runs);
    let mut s = String::new();
    s.push_str("| run | evaluated at | time to 25 dB (s) | time to 30 dB (s) | final PSNR (dB) | SSIM | depth MAE (m) | off-surface mass (in front) | mesh Chamfer-L1 (m) | mesh F@1 % | parameters | train time (s) | Pareto |\n");
    s.push_str("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|:---:|\n");
    for (r, on) in runs.iter().zip(&front) {
        let never = |t: Option<f64>| t.map_or("never".to_string(), |t| format!("{t:.1}"));
        // A scored method has no training curve, step count or parameter count of ours.
        let scored = r.tool.is_some();
        let unknown = |v: String| if scored { "—".to_string() } else { v };
        let name = match &r.tool {
            Some(tool) => format!("{} ({tool})", r.name),
            None => r.name.clone(),
        };
        s.push_str(&format!(
            "| {} | {} | {} | {} | {:.2} | {:.4} | {} | {} | {} | {} | {} | {} | {} |\n",
            name.replace('|', "\\|"),
            r.resolution.map_or("-".to_string(), |e| format!("{}x{} (/{})", e.width, e.height, e.downscale)),
            unknown(never(r.time_to_25db_s)),
            unknown(never(r.time_to_30db_s)),
            r.final_psnr,
            r.ssim,
            opt(r.depth_mae, 4),
            off_surface(r),
            opt(r.chamfer_l1, 4),
            opt(r.f_score_1pct, 3),
            unknown(r.parameters.to_string()),
            opt(r.train_wall_s.is_finite().then_some(r.train_wall_s), 1),
            if *on { "★" } else { "" },
        ));
    }
    s.push('\n');
    s.push_str(match axis {
        ParetoAxis::TimeTo30Db => "★ = Pareto front of time to 30 dB (lower is better) against final PSNR (higher is better).\n",
        ParetoAxis::TrainWall => "★ = Pareto front of total training time (lower is better) against final PSNR (higher is better); time to 30 dB is not used because not every run reaches 30 dB.\n",
    });
    s.push_str(&scored_notes(runs));
    s
}

/// The lines that explain the scored methods' rows (empty without any): their training time is
/// the user's statement, and one without it is left out of `compare.png` and the Pareto front.
fn scored_notes(runs: &[RunSummary]) -> String {
    let mut s = String::new();
    if runs.iter().any(|r| r.tool.is_some()) {
        s.push_str("Rows with a tool in brackets are other tools' predictions measured by `score`: their training time is as stated (`--train-seconds`), and they are one point (test PSNR) in compare.png.\n");
    }
    for r in runs.iter().filter(|r| r.tool.is_some() && !r.train_wall_s.is_finite()) {
        s.push_str(&format!("{} states no training time: it is in the table but not in compare.png or the Pareto front.\n", r.name));
    }
    s
}

/// Compare several runs: write `compare.png` (their validation PSNR curves, legend = run name)
/// and `compare.md` (the table and the picture) into `out_dir`, and return the table
/// (see [`compare_table`]).
pub fn compare_runs(runs: &[RunSummary], out_dir: &Path) -> Result<String, EvalError> {
    if runs.is_empty() {
        return Err(EvalError::Input("no runs to compare".into()));
    }
    let curves: Vec<Curve> = runs
        .iter()
        .map(|r| Curve { label: r.name.clone(), points: r.plot_points() })
        .collect();
    compare_png(&out_dir.join("compare.png"), &curves)?;
    let table = compare_table(runs);
    let md = format!("# Run comparison\n\n{table}\n![validation PSNR of every run against training time](compare.png)\n");
    crate::io::write_atomic(&out_dir.join("compare.md"), md.as_bytes())?;
    Ok(table)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(name: &str, t30: Option<f64>, psnr: f64, wall: f64) -> RunSummary {
        RunSummary {
            name: name.into(),
            time_to_25db_s: t30.map(|t| t / 2.0),
            time_to_30db_s: t30,
            final_psnr: psnr,
            ssim: 0.9,
            depth_mae: None,
            off_surface_mass: None,
            off_surface_front: None,
            mask_iou: None,
            parameters: 1000,
            train_wall_s: wall,
            train_steps: 100,
            render_s_per_view: 0.5,
            val_psnr_curve: vec![[1.0, 20.0], [wall, psnr]],
            resolution: None,
            chamfer_l1: None,
            f_score_1pct: None,
            tool: None,
        }
    }

    #[test]
    fn pareto_front_of_known_points() {
        // (cost, quality): b dominates c; a and b and d trade off; e duplicates b exactly.
        let pts = [(10.0, 30.0), (20.0, 32.0), (25.0, 31.0), (40.0, 35.0), (20.0, 32.0), (f64::NAN, 50.0)];
        assert_eq!(pareto_front(&pts), vec![true, true, false, true, true, false]);
    }

    #[test]
    fn axis_falls_back_to_train_time_when_30db_is_not_reached_by_all() {
        let runs = vec![run("fast", Some(50.0), 31.0, 100.0), run("slow", Some(80.0), 33.0, 90.0)];
        assert_eq!(pareto_runs(&runs), (ParetoAxis::TimeTo30Db, vec![true, true]));
        let runs = vec![run("fast", Some(50.0), 31.0, 100.0), run("weak", None, 28.0, 200.0)];
        assert_eq!(pareto_runs(&runs), (ParetoAxis::TrainWall, vec![true, false]));
        let mut runs = runs;
        runs[0].resolution = Some(crate::evaluate::EvalResolution { width: 100, height: 80, downscale: 2, train_downscale: 2 });
        let table = compare_table(&runs);
        assert!(table.contains("| weak | - | never | never | 28.00 |"), "{table}");
        assert!(table.contains("| fast | 100x80 (/2) | 25.0 | 50.0 | 31.00 |"), "{table}");
        assert!(table.contains("total training time"));
    }

    /// A scored method's row: its tool named, no curve, steps or parameters of ours, its stated
    /// training time; one point in the plot, or none (and a note) without a stated time.
    #[test]
    fn scored_methods_are_rows_and_single_points() {
        let ours = run("fast", Some(50.0), 31.0, 100.0);
        let mut nerfacto = run("nerfacto", None, 32.0, 90.0);
        (nerfacto.tool, nerfacto.val_psnr_curve, nerfacto.time_to_25db_s) = (Some("nerfstudio".into()), Vec::new(), None);
        let mut ngp = nerfacto.clone();
        (ngp.name, ngp.tool, ngp.train_wall_s) = ("ngp".into(), Some("instant-ngp".into()), f64::NAN);
        assert_eq!(ours.plot_points(), ours.val_psnr_points());
        assert_eq!(nerfacto.plot_points(), vec![(90.0, 32.0)]);
        assert!(ngp.plot_points().is_empty());
        let table = compare_table(&[ours.clone(), nerfacto, ngp.clone()]);
        assert!(table.contains("| nerfacto (nerfstudio) | - | — | — | 32.00 | 0.9000 | — | — | — | — | — | 90.0 | ★ |"), "{table}");
        assert!(table.contains("| ngp (instant-ngp) | - | — | — | 32.00 | 0.9000 | — | — | — | — | — | — |  |"), "{table}");
        assert!(table.contains("ngp states no training time"), "{table}");
        // Without scored methods the table is as it was: no extra lines.
        assert!(!compare_table(std::slice::from_ref(&ours)).contains("score"));
        // A summary with an unstated time reads back.
        let back: RunSummary = serde_json::from_str(&serde_json::to_string(&ngp).unwrap()).unwrap();
        assert!(back.train_wall_s.is_nan() && back.tool.as_deref() == Some("instant-ngp"));
    }

    #[test]
    fn summary_json_roundtrip_with_never_reached() {
        let mut r = run("x", None, f64::INFINITY, 10.0);
        r.val_psnr_curve = vec![[1.0, 20.0], [10.0, 27.5]];
        let text = serde_json::to_string(&r).unwrap();
        assert!(text.contains("\"time_to_30db_s\":null"), "{text}");
        assert!(text.contains("\"final_psnr\":\"inf\""), "{text}");
        assert!(!text.contains("depth_mae"));
        let back: RunSummary = serde_json::from_str(&text).unwrap();
        assert_eq!(back.time_to_30db_s, None);
        assert_eq!(back.final_psnr, f64::INFINITY);
        assert_eq!(back.val_psnr_curve, r.val_psnr_curve);
        assert_eq!(back.parameters, r.parameters);
    }
}
