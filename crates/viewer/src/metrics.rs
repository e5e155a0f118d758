//! The run's training curve for the page (`GET /api/metrics`): `metrics.jsonl` read as far as
//! its last complete line (the trainer may be appending to it), as two series of
//! `[step, wall_s, value]`: the training loss and the validation PSNR.

use crate::error::ViewerError;
use serde_json::{Value, json};
use std::path::Path;

/// The body of `GET /api/metrics` for the run folder `run_dir`; empty series when the file is
/// not there yet.
pub fn curves(run_dir: &Path) -> Result<Value, ViewerError> {
    let path = run_dir.join(nerf::train::METRICS_FILE);
    let bytes = match std::fs::read(&path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
        Err(e) => return Err(ViewerError::Internal(format!("{}: {e}", path.display()))),
    };
    let complete = bytes.iter().rposition(|&b| b == b'\n').map_or(&bytes[..0], |end| &bytes[..=end]);
    let records = eval::curve::parse_metrics_jsonl(complete, &path).map_err(|e| ViewerError::Internal(e.to_string()))?;
    let series = |f: fn(&eval::curve::MetricsRecord) -> Option<f64>| -> Vec<[f64; 3]> {
        records.iter().filter_map(|r| f(r).filter(|v| v.is_finite()).map(|v| [r.step as f64, r.wall_s, v])).collect()
    };
    Ok(json!({ "loss": series(|r| r.loss), "val_psnr": series(|r| r.val_psnr) }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_half_written_last_line_is_left_for_later() {
        let tmp = tempfile::tempdir().unwrap();
        assert_eq!(curves(tmp.path()).unwrap()["loss"], json!([]));
        let lines = "{\"step\":10,\"wall_s\":1.5,\"loss\":0.25}\n{\"step\":20,\"wall_s\":3.0,\"val_psnr\":21.5}\n{\"step\":30,\"wa";
        std::fs::write(tmp.path().join("metrics.jsonl"), lines).unwrap();
        let c = curves(tmp.path()).unwrap();
        assert_eq!(c["loss"], json!([[10.0, 1.5, 0.25]]));
        assert_eq!(c["val_psnr"], json!([[20.0, 3.0, 21.5]]));
    }
}
