//! A run's training curve: reading `metrics.jsonl` and the time to reach a PSNR.

use std::io::BufRead;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::EvalError;

/// One line of a run's `metrics.jsonl`. `step` and `wall_s` are required; the other known
/// keys may be missing or `null`; unknown keys are ignored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MetricsRecord {
    /// Optimiser step.
    pub step: u64,
    /// Wall-clock seconds since training started.
    pub wall_s: f64,
    /// Training loss.
    #[serde(default)]
    pub loss: Option<f64>,
    /// PSNR on the training batch, dB.
    #[serde(default)]
    pub train_psnr: Option<f64>,
    /// Training throughput, rays per second.
    #[serde(default)]
    pub rays_per_s: Option<f64>,
    /// PSNR on the validation views, dB (only on evaluation lines).
    #[serde(default)]
    pub val_psnr: Option<f64>,
    /// Depth MAE on the validation views, scene units (only on evaluation lines, and only
    /// when the dataset has depth).
    #[serde(default)]
    pub val_depth_mae: Option<f64>,
}

/// Parse `metrics.jsonl` content. Blank lines are skipped; `path` only names the source in
/// errors, which give the 1-based line number.
pub fn parse_metrics_jsonl(reader: impl BufRead, path: &Path) -> Result<Vec<MetricsRecord>, EvalError> {
    let mut out = Vec::new();
    for (i, line) in reader.lines().enumerate() {
        let line = line.map_err(|source| EvalError::Io { path: path.to_path_buf(), source })?;
        if line.trim().is_empty() {
            continue;
        }
        let rec: MetricsRecord = serde_json::from_str(&line).map_err(|e| EvalError::Jsonl {
            path: path.to_path_buf(),
            line: i + 1,
            message: e.to_string(),
        })?;
        out.push(rec);
    }
    Ok(out)
}

/// Read a run's `metrics.jsonl` (one JSON object per line). A malformed line is an error
/// naming the file and the line number.
pub fn read_metrics_jsonl(path: &Path) -> Result<Vec<MetricsRecord>, EvalError> {
    let file = std::fs::File::open(path).map_err(|source| EvalError::Io { path: path.to_path_buf(), source })?;
    parse_metrics_jsonl(std::io::BufReader::new(file), path)
}

/// The validation points `(wall_s, val_psnr)` in file order (records without `val_psnr`
/// are skipped).
pub fn val_psnr_points(records: &[MetricsRecord]) -> Vec<(f64, f64)> {
    records.iter().filter_map(|r| r.val_psnr.map(|p| (r.wall_s, p))).collect()
}

/// The validation points `(wall_s, val_depth_mae)` in file order.
pub fn val_depth_points(records: &[MetricsRecord]) -> Vec<(f64, f64)> {
    records.iter().filter_map(|r| r.val_depth_mae.map(|d| (r.wall_s, d))).collect()
}

/// Wall-clock seconds at which validation PSNR first reaches `threshold_db`, or `None` if
/// it never does.
///
/// Walk the evaluations in order; at the first one with `val_psnr >= threshold`, if there is
/// an earlier evaluation (necessarily below the threshold), interpolate linearly between the
/// two bracketing evaluations: `t = t0 + (thr − p0) / (p1 − p0) · (t1 − t0)`. If the very
/// first evaluation already reaches the threshold, its `wall_s` is returned.
pub fn time_to_psnr(records: &[MetricsRecord], threshold_db: f64) -> Option<f64> {
    let pts = val_psnr_points(records);
    let k = pts.iter().position(|&(_, p)| p >= threshold_db)?;
    if k == 0 {
        return Some(pts[0].0);
    }
    let (t0, p0) = pts[k - 1];
    let (t1, p1) = pts[k];
    Some(t0 + (threshold_db - p0) / (p1 - p0) * (t1 - t0))
}

/// The value at `t` of a curve given by points `(t_i, v_i)` in non-decreasing `t_i`: linear
/// between the two points around `t` (the later point's value where several share a time);
/// `None` before the first point, after the last, or without points.
pub fn value_at(points: &[(f64, f64)], t: f64) -> Option<f64> {
    let k = points.iter().position(|&(ti, _)| ti >= t)?;
    let (t1, v1) = points[k];
    if t1 == t {
        // the last of the points at exactly t
        return points[k..].iter().take_while(|&&(ti, _)| ti == t).last().map(|&(_, v)| v);
    }
    let (t0, v0) = *points.get(k.checked_sub(1)?)?;
    Some(v0 + (t - t0) / (t1 - t0) * (v1 - v0))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(step: u64, wall_s: f64, val: Option<f64>) -> MetricsRecord {
        MetricsRecord {
            step,
            wall_s,
            loss: Some(0.1),
            train_psnr: Some(20.0),
            rays_per_s: Some(1e5),
            val_psnr: val,
            val_depth_mae: None,
        }
    }

    #[test]
    fn parses_lines_with_and_without_val_and_unknown_keys() {
        let text = r#"{"step":0,"wall_s":0.5,"loss":0.3,"train_psnr":10.0,"rays_per_s":1000.0,"lr":0.01}

{"step":100,"wall_s":10.0,"loss":0.01,"train_psnr":22.0,"rays_per_s":2000.0,"val_psnr":21.5,"val_depth_mae":0.04}
"#;
        let recs = parse_metrics_jsonl(text.as_bytes(), Path::new("m.jsonl")).unwrap();
        assert_eq!(recs.len(), 2);
        assert_eq!(recs[0].val_psnr, None);
        assert_eq!(recs[1].step, 100);
        assert_eq!(recs[1].val_depth_mae, Some(0.04));
        assert_eq!(val_psnr_points(&recs), vec![(10.0, 21.5)]);
        assert_eq!(val_depth_points(&recs), vec![(10.0, 0.04)]);
    }

    #[test]
    fn malformed_line_names_file_and_line() {
        let text = "{\"step\":0,\"wall_s\":0.5}\n{\"step\":1,\"wall_s\":\n";
        let err = parse_metrics_jsonl(text.as_bytes(), Path::new("runs/a/metrics.jsonl")).unwrap_err();
        match &err {
            EvalError::Jsonl { line, .. } => assert_eq!(*line, 2),
            other => panic!("wrong error {other:?}"),
        }
        assert!(err.to_string().starts_with("runs/a/metrics.jsonl:2:"), "{err}");
        // a line missing the required wall_s is also malformed
        let err = parse_metrics_jsonl("{\"step\":3}".as_bytes(), Path::new("m")).unwrap_err();
        assert!(matches!(err, EvalError::Jsonl { line: 1, .. }));
    }

    #[test]
    fn missing_file_is_an_io_error_naming_it() {
        let err = read_metrics_jsonl(Path::new("/nonexistent/metrics.jsonl")).unwrap_err();
        assert!(err.to_string().contains("/nonexistent/metrics.jsonl"));
    }

    #[test]
    fn time_to_threshold_interpolates_between_bracketing_evals() {
        let recs = vec![
            rec(0, 1.0, None),
            rec(100, 10.0, Some(20.0)),
            rec(150, 15.0, None),
            rec(200, 20.0, Some(24.0)),
            rec(300, 30.0, Some(28.0)),
            rec(400, 40.0, Some(26.0)),
        ];
        // 25 dB between (20 s, 24 dB) and (30 s, 28 dB): 20 + 1/4 * 10 = 22.5 s
        assert!((time_to_psnr(&recs, 25.0).unwrap() - 22.5).abs() < 1e-12);
        // exactly reached at an evaluation
        assert_eq!(time_to_psnr(&recs, 28.0), Some(30.0));
        // never reached
        assert_eq!(time_to_psnr(&recs, 30.0), None);
        // reached at the first evaluation
        assert_eq!(time_to_psnr(&recs, 15.0), Some(10.0));
        assert_eq!(time_to_psnr(&[], 25.0), None);
    }

    #[test]
    fn values_at_a_time_interpolate_between_the_points_around_it() {
        let pts = val_psnr_points(&[rec(0, 1.0, None), rec(100, 10.0, Some(20.0)), rec(150, 15.0, None), rec(200, 20.0, Some(24.0)), rec(300, 30.0, Some(28.0))]);
        // between (10 s, 20 dB) and (20 s, 24 dB)
        assert!((value_at(&pts, 12.5).unwrap() - 21.0).abs() < 1e-12);
        assert_eq!(value_at(&pts, 10.0), Some(20.0));
        assert_eq!(value_at(&pts, 30.0), Some(28.0));
        // before the first point and after the last: no value
        assert_eq!(value_at(&pts, 9.9), None);
        assert_eq!(value_at(&pts, 30.1), None);
        assert_eq!(value_at(&[], 1.0), None);
        assert_eq!(value_at(&pts, f64::NAN), None);
        // several points at one time: the last one's value there, and the interpolation
        // after it starts from it
        let pts = [(0.0, 1.0), (2.0, 3.0), (2.0, 5.0), (4.0, 9.0)];
        assert_eq!(value_at(&pts, 2.0), Some(5.0));
        assert_eq!(value_at(&pts, 3.0), Some(7.0));
        assert_eq!(value_at(&pts, 1.0), Some(2.0));
    }
}
