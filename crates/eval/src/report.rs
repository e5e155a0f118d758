//! Writing a run's report folder: `eval.json`, `report.json`, `report.md`,
//! `speed_vs_error.png` and one `grid_<view>.png` per test view.

use std::path::{Path, PathBuf};

use crate::compare::RunSummary;
use crate::curve::{MetricsRecord, val_depth_points, val_psnr_points};
use crate::error::EvalError;
use crate::evaluate::{EvalReport, ViewInput, ViewMetrics};
use crate::grid::{grid_file_name, view_grid_png};
use crate::io::{write_atomic, write_json_atomic};
use crate::plot::{SpeedVsError, speed_vs_error_png};

/// Human-readable name and unit of each report key.
fn describe(key: &str) -> (&'static str, &'static str) {
    match key {
        "psnr" => ("PSNR", "dB"),
        "ssim" => ("SSIM", ""),
        "depth_mae" => ("depth MAE", "m"),
        "depth_rmse" => ("depth RMSE", "m"),
        "depth_abs_rel" => ("depth abs. rel.", ""),
        "depth_delta_1_25" => ("δ < 1.25", "fraction"),
        "depth_delta_1_01" => ("δ < 1.01", "fraction"),
        "mask_iou" => ("mask IoU", ""),
        "off_surface_mass" => ("off-surface mass", "fraction"),
        "off_surface_front" => ("off-surface mass in front of the surface", "fraction"),
        "render_s_per_view" => ("render time per view", "s"),
        _ => ("?", ""),
    }
}

fn fmt(key: &str, v: f64) -> String {
    match key {
        "psnr" => format!("{v:.2}"),
        "render_s_per_view" => format!("{v:.3}"),
        _ => format!("{v:.4}"),
    }
}

/// A one-line description of a view's metrics (the grid header).
pub fn metrics_line(name: &str, m: &ViewMetrics) -> String {
    let mut s = format!("view {name}: PSNR {:.2} dB, SSIM {:.4}", m.psnr, m.ssim);
    if let Some(d) = m.depth_mae {
        s.push_str(&format!(", depth MAE {d:.4} m"));
    }
    if let Some(o) = m.off_surface_mass {
        s.push_str(&format!(", off-surface mass {o:.3}"));
    }
    s
}

/// The report's geometry section: the extracted mesh against the scene's visible triangles.
pub fn mesh_section(b: &crate::mesh_eval::MeshBlock) -> String {
    let m = &b.metrics;
    let what = match (&b.input, &b.level, b.resolution) {
        (Some(g), _, _) => g.describe(),
        (None, Some(level), Some(resolution)) => format!(
            "The mesh extracted at density level {:.3} /m ({}) on a grid of {resolution} cells along the box's longest side",
            level.level, level.source
        ),
        (None, _, _) => "The mesh".to_string(),
    };
    let mut s = format!(
        "\n## Geometry\n\n{what}, against the scene's triangles seen by the {} train and test cameras ({:.1} % of the scene's area), {} points sampled on each:\n\n",
        b.reference.cameras, 100.0 * b.reference.visible_area_fraction, m.samples
    );
    s.push_str("| metric | value |\n|---|---:|\n");
    s.push_str(&format!("| accuracy (m) | {:.4} |\n| completeness (m) | {:.4} |\n| Chamfer-L1 (m) | {:.4} |\n", m.accuracy, m.completeness, m.chamfer_l1));
    for f in &m.f_scores {
        s.push_str(&format!("| F-score at {:.1} % of the diagonal ({:.4} m) | {:.3} (P {:.3}, R {:.3}) |\n", 100.0 * f.fraction, f.threshold, f.f_score, f.precision, f.recall));
    }
    match m.normal_consistency {
        Some(v) => s.push_str(&format!("| normal consistency | {v:.3} |\n")),
        None => s.push_str("| normal consistency | absent |\n"),
    }
    if let Some(level) = &b.level {
        s.push_str(&format!("\nLevel: {}.\n", level.reason));
    }
    for note in b.input.iter().flat_map(|g| &g.notes) {
        s.push_str(&format!("\n{note}\n"));
    }
    if let Some(p) = &b.picture {
        s.push_str(&format!("\n![the mesh from the first test camera, coloured by its distance to the scene (0 to 2 % of the diagonal, {:.4} m)]({p})\n", 0.02 * m.diagonal));
    }
    s
}

/// The Markdown report (summary table, notes, pictures linked relatively).
pub fn report_markdown(name: &str, report: &EvalReport, summary: &RunSummary, grids: &[String]) -> String {
    if let Some(m) = &report.method {
        return scored_markdown(m, report, grids);
    }
    let mut s = format!("# Evaluation: {name}\n\n");
    if let Some(r) = &report.resolution {
        s.push_str(&format!("Evaluated at {}.\n\n", r.label()));
    }
    s.push_str("## Summary\n\n| metric | value |\n|---|---:|\n");
    for (key, v) in report.mean.entries() {
        let (label, unit) = describe(key);
        let unit = if unit.is_empty() { String::new() } else { format!(" ({unit})") };
        s.push_str(&format!("| {label}{unit} | {} |\n", fmt(key, v)));
    }
    let never = |t: Option<f64>| t.map_or("never".to_string(), |t| format!("{t:.1}"));
    s.push_str(&format!("| time to 25 dB val. PSNR (s) | {} |\n", never(summary.time_to_25db_s)));
    s.push_str(&format!("| time to 30 dB val. PSNR (s) | {} |\n", never(summary.time_to_30db_s)));
    s.push_str(&format!("| training time (s) | {:.1} |\n", report.train_wall_s));
    s.push_str(&format!("| training steps | {} |\n", report.train_steps));
    s.push_str(&format!("| parameters | {} |\n", report.parameters));
    s.push_str(&format!(
        "\nMeans over {} test views. Depth is z-depth in scene units (m) over foreground pixels (ground-truth alpha ≥ 0.999); off-surface tolerance {:.4} m.\n",
        report.views.len(),
        report.surface_tol
    ));
    geometry_and_notes(&mut s, report);
    s.push_str("\n## Speed versus error\n\n![validation PSNR against wall-clock training time](speed_vs_error.png)\n");
    per_view_and_grids(&mut s, report, grids, "NeRF");
    s
}

/// The mesh section (when measured) and the notes.
fn geometry_and_notes(s: &mut String, report: &EvalReport) {
    if let Some(m) = &report.mesh {
        s.push_str(&mesh_section(m));
    }
    if let Some(o) = &report.objects {
        s.push('\n');
        s.push_str(&crate::objects::markdown(o, 20));
    }
    if !report.notes.is_empty() {
        s.push_str("\n## Notes\n\n");
        for n in &report.notes {
            s.push_str(&format!("- {n}\n"));
        }
    }
}

/// The report of another tool's predictions measured by `score`: the same metrics, what was
/// read and stated instead of a training curve.
fn scored_markdown(m: &crate::evaluate::MethodInfo, report: &EvalReport, grids: &[String]) -> String {
    let mut s = format!("# Score: {} ({})\n\n", m.name, m.tool);
    if let Some(r) = &report.resolution {
        let at = if r.downscale == 1 { "full resolution".to_string() } else { format!("downscale {}", r.downscale) };
        s.push_str(&format!("Scored at {}x{} ({at}) against the dataset's ground truth.\n\n", r.width, r.height));
    }
    s.push_str("## Summary\n\n| metric | value |\n|---|---:|\n");
    for (key, v) in report.mean.entries() {
        let (label, unit) = describe(key);
        let unit = if unit.is_empty() { String::new() } else { format!(" ({unit})") };
        s.push_str(&format!("| {label}{unit} | {} |\n", fmt(key, v)));
    }
    let stated = |v: Option<String>| v.unwrap_or_else(|| "not stated".into());
    s.push_str(&format!("| training time (s, as stated) | {} |\n", stated(m.train_seconds.map(|t| format!("{t:.1}")))));
    s.push_str(&format!("| hardware (as stated) | {} |\n", stated(m.hardware.clone()).replace('|', "\\|")));
    s.push_str(&format!(
        "\nMeans over {} views. Depth is z-depth in scene units (m) over foreground pixels (ground-truth alpha ≥ 0.999).\n",
        report.views.len()
    ));
    s.push_str(&format!("\n## Predictions read\n\n- layout: {}\n- folder: `{}` ({} files read)\n", m.layout, m.predictions, m.files_read.len()));
    if let Some(d) = &m.depth {
        s.push_str(&format!(
            "- depth: {} ({}), {} m per unit ({})\n",
            if d.kind == "z" { "z-depth" } else { "distance along the ray, converted to z-depth" },
            if d.kind_stated { "as stated" } else { "the layout's convention" },
            d.metres_per_unit,
            d.unit_source
        ));
    }
    let bg = m.background;
    s.push_str(&format!("- background composited: ({:.3}, {:.3}, {:.3})\n", bg[0], bg[1], bg[2]));
    if !m.missing_views.is_empty() {
        s.push_str(&format!("- missing views (left out of every mean): {}\n", m.missing_views.join(", ")));
    }
    let nf = m.nonfinite;
    if nf != crate::evaluate::NonFiniteCounts::default() {
        s.push_str(&format!(
            "- non-finite values (left out of the metrics they would enter): {} colour, {} depth, {} opacity pixels\n",
            nf.colour, nf.depth, nf.opacity
        ));
    }
    geometry_and_notes(&mut s, report);
    per_view_and_grids(&mut s, report, grids, &m.name);
    s
}

/// The per-view table and the grid pictures; `method` names the prediction's column.
fn per_view_and_grids(s: &mut String, report: &EvalReport, grids: &[String], method: &str) {
    s.push_str("\n## Per view\n\n");
    let keys: Vec<&str> = report.mean.entries().iter().map(|(k, _)| *k).collect();
    s.push_str("| view |");
    for k in &keys {
        s.push_str(&format!(" {} |", describe(k).0));
    }
    s.push_str("\n|---|");
    s.push_str(&"---:|".repeat(keys.len()));
    s.push('\n');
    for v in &report.views {
        s.push_str(&format!("| {} |", v.name.replace('|', "\\|")));
        let entries = v.metrics.entries();
        for k in &keys {
            let cell = entries.iter().find(|(ek, _)| ek == k).map_or("—".to_string(), |(_, x)| fmt(k, *x));
            s.push_str(&format!(" {cell} |"));
        }
        s.push('\n');
    }
    if !grids.is_empty() {
        s.push_str(&format!("\n## Views\n\nGround truth | {method} | colour error; ground-truth depth | {method} depth | signed depth error.\n"));
        for g in grids {
            s.push_str(&format!("\n![{g}]({g})\n"));
        }
    }
}

/// Write the report of run `name` into `out_dir`: `eval.json` (the [`EvalReport`]),
/// `report.json` (the [`RunSummary`]), `speed_vs_error.png` (from `curve`; not for a scored
/// method, which has no training curve), one `grid_<view>.png` per entry of `grids`, and
/// `report.md`, whose path is returned. Every file is written atomically.
pub fn write_report(
    out_dir: &Path,
    name: &str,
    report: &EvalReport,
    curve: &[MetricsRecord],
    grids: &[ViewInput<'_>],
) -> Result<PathBuf, EvalError> {
    write_json_atomic(&out_dir.join("eval.json"), report)?;
    let summary = RunSummary::from_report(name, report, curve);
    write_json_atomic(&out_dir.join("report.json"), &summary)?;
    if report.method.is_none() {
        speed_vs_error(out_dir, name, &summary, curve)?;
    }
    let mut grid_files = Vec::new();
    for v in grids {
        let file = grid_file_name(v.name);
        let header = match report.views.iter().find(|r| r.name == v.name) {
            Some(r) => metrics_line(v.name, &r.metrics),
            None => format!("view {}", v.name),
        };
        view_grid_png(&out_dir.join(&file), v, &header)?;
        grid_files.push(file);
    }
    let md = report_markdown(name, report, &summary, &grid_files);
    let path = out_dir.join("report.md");
    write_atomic(&path, md.as_bytes())?;
    Ok(path)
}

/// `speed_vs_error.png` from a run's training curve.
fn speed_vs_error(out_dir: &Path, name: &str, summary: &RunSummary, curve: &[MetricsRecord]) -> Result<(), EvalError> {
    let data = SpeedVsError {
        val_psnr: val_psnr_points(curve),
        train_psnr: curve.iter().filter_map(|r| r.train_psnr.map(|p| (r.wall_s, p))).collect(),
        val_depth_mae: val_depth_points(curve),
        t25: summary.time_to_25db_s,
        t30: summary.time_to_30db_s,
        title: name.to_string(),
    };
    speed_vs_error_png(&out_dir.join("speed_vs_error.png"), &data)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compare::{RunSummary, compare_runs};
    use crate::curve::parse_metrics_jsonl;
    use crate::evaluate::{EvalOptions, RunInfo, evaluate_views};
    use crate::metrics::RaySamples;

    /// A synthetic 40x30 view: a sphere-like depth bump in front of a background, colour from
    /// the depth; the "NeRF" is blurred in colour, biased in depth, with a floater.
    #[test]
    fn writes_every_file_and_pictures_are_readable() {
        let (w, h) = (40usize, 30usize);
        let n = w * h;
        let mut gt_rgb = vec![0.0f32; n * 3];
        let mut pred_rgb = vec![0.0f32; n * 3];
        let mut gt_depth = vec![0.0f32; n];
        let mut pred_depth = vec![0.0f32; n];
        let mut alpha = vec![0.0f32; n];
        let mut opacity = vec![0.0f32; n];
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let (dx, dy) = (x as f32 - 20.0, y as f32 - 15.0);
                let r2 = (dx * dx + dy * dy) / 144.0;
                if r2 < 1.0 {
                    alpha[i] = 1.0;
                    gt_depth[i] = 3.0 - (1.0 - r2).sqrt();
                    pred_depth[i] = gt_depth[i] + 0.02 * dx / 12.0;
                }
                opacity[i] = if r2 < 1.1 { 1.0 } else { 0.0 };
                for c in 0..3 {
                    let v = if alpha[i] > 0.0 { 0.3 + 0.2 * c as f32 + 0.1 * (x as f32 * 0.3).sin() } else { 1.0 };
                    gt_rgb[3 * i + c] = v;
                    pred_rgb[3 * i + c] = (v + 0.03 * (y as f32 * 0.7).cos()).clamp(0.0, 1.0);
                }
            }
        }
        let pixel: Vec<usize> = (0..n).collect();
        let mut offsets = vec![0usize];
        let (mut t, mut wts) = (Vec::new(), Vec::new());
        for &d in &gt_depth {
            t.extend([1.0, d]);
            wts.extend([0.1, 0.9]);
            offsets.push(t.len());
        }
        let view = ViewInput {
            name: "r_7",
            width: w,
            height: h,
            pred_rgb: &pred_rgb,
            gt_rgb: &gt_rgb,
            pred_depth: Some(&pred_depth),
            gt_depth: Some(&gt_depth),
            gt_distance: Some(&gt_depth),
            gt_alpha: Some(&alpha),
            pred_opacity: Some(&opacity),
            samples: Some(RaySamples { pixel: &pixel, offsets: &offsets, t: &t, w: &wts }),
            render_s: 0.3,
        };
        let run = RunInfo { train_wall_s: 100.0, train_steps: 2000, parameters: 50_000 };
        let opts = EvalOptions::with_surface_tol(0.05);
        let report = evaluate_views(&[view], run, &opts).unwrap();
        assert!((report.mean.off_surface_mass.unwrap() - 0.1).abs() < 1e-6);
        let mut jsonl = String::new();
        for k in 0..=20 {
            let wall = 5.0 * k as f64;
            let psnr = 15.0 + 17.0 * (1.0 - (-wall / 30.0).exp());
            jsonl.push_str(&format!(
                "{{\"step\":{},\"wall_s\":{wall},\"loss\":0.01,\"train_psnr\":{},\"rays_per_s\":5000}}\n",
                k * 100,
                psnr + 0.5
            ));
            if k % 2 == 0 {
                jsonl.push_str(&format!(
                    "{{\"step\":{},\"wall_s\":{wall},\"loss\":0.01,\"train_psnr\":{},\"rays_per_s\":5000,\"val_psnr\":{psnr},\"val_depth_mae\":{}}}\n",
                    k * 100,
                    psnr + 0.5,
                    0.2 * (-wall / 40.0).exp()
                ));
            }
        }
        let curve = parse_metrics_jsonl(jsonl.as_bytes(), Path::new("metrics.jsonl")).unwrap();
        // EVAL_TEST_OUT=<dir> keeps the pictures for inspection.
        let keep = std::env::var_os("EVAL_TEST_OUT");
        let dir = keep
            .clone()
            .map_or_else(|| std::env::temp_dir().join(format!("eval-report-{}", std::process::id())), Into::into);
        let md_path = write_report(&dir, "demo", &report, &curve, &[view]).unwrap();
        let md = std::fs::read_to_string(&md_path).unwrap();
        assert!(md.contains("![validation PSNR against wall-clock training time](speed_vs_error.png)"));
        assert!(md.contains("![grid_r_7.png](grid_r_7.png)"));
        assert!(md.contains("| depth MAE (m) |"));
        let eval: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("eval.json")).unwrap()).unwrap();
        assert_eq!(eval["views"][0]["name"], "r_7");
        let summary: RunSummary =
            serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap();
        // analytic curve reaches 25 dB at t = -30 ln(1 - 10/17) = 26.6 s, interpolated between evaluations
        let t25 = summary.time_to_25db_s.unwrap();
        assert!(t25 > 20.0 && t25 < 30.0, "{t25}");
        for (file, min_w) in [("speed_vs_error.png", 1000), ("grid_r_7.png", 3 * 256)] {
            let img = image::open(dir.join(file)).unwrap().to_rgb8();
            assert!(img.width() >= min_w, "{file}");
            // not blank: some dark pixels (text, lines) and some white ones
            assert!(img.pixels().any(|p| p.0.iter().all(|&c| c < 60)), "{file} has no dark pixels");
            assert!(img.pixels().any(|p| p.0 == [255, 255, 255]), "{file} has no background");
        }
        // the same run at half speed reaches 30 dB later with the same final PSNR: dominated
        let mut slower = summary.clone();
        slower.name = "slower".into();
        slower.train_wall_s *= 2.0;
        slower.time_to_25db_s = Some(t25 * 2.0);
        slower.time_to_30db_s = summary.time_to_30db_s.map(|t| t * 2.0);
        slower.val_psnr_curve.iter_mut().for_each(|p| p[0] *= 2.0);
        let table = compare_runs(&[summary, slower], &dir).unwrap();
        let row = |name: &str| table.lines().find(|l| l.starts_with(&format!("| {name} |"))).unwrap().to_string();
        assert!(row("demo").ends_with("| ★ |"), "{table}");
        assert!(row("slower").ends_with("|  |"), "{table}");
        assert!(image::open(dir.join("compare.png")).is_ok());
        if keep.is_none() {
            std::fs::remove_dir_all(&dir).unwrap();
        }
    }
}
