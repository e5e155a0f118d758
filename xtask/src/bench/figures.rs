//! What the benchmarks share: the spread of a figure measured over repeated runs, and the
//! printed report kept to be written beside the JSON.

use anyhow::Context;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Repetitions per figure; the median is reported.
pub(super) const RENDER_RUNS: usize = 5;

/// A measured figure over repeated runs: its median and spread.
#[derive(Clone, Copy, Debug, Serialize)]
pub(super) struct Spread {
    pub(super) median: f64,
    /// First and third quartiles (linear interpolation between order statistics).
    pub(super) q1: f64,
    pub(super) q3: f64,
    pub(super) min: f64,
    pub(super) max: f64,
    /// Number of runs.
    pub(super) n: usize,
}

impl Spread {
    /// The figures of `v` (all zero for an empty list).
    pub(super) fn of(v: &[f64]) -> Spread {
        let mut v = v.to_vec();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        if n == 0 {
            return Spread { median: 0.0, q1: 0.0, q3: 0.0, min: 0.0, max: 0.0, n };
        }
        let at = |q: f64| {
            let x = q * (n - 1) as f64;
            let (i, f) = (x.floor() as usize, x.fract());
            if i + 1 < n { v[i] + f * (v[i + 1] - v[i]) } else { v[i] }
        };
        Spread { median: at(0.5), q1: at(0.25), q3: at(0.75), min: v[0], max: v[n - 1], n }
    }
    /// `x ↦ s·x` applied to every figure (`s > 0`).
    pub(super) fn scaled(self, s: f64) -> Spread {
        Spread { median: self.median * s, q1: self.q1 * s, q3: self.q3 * s, min: self.min * s, max: self.max * s, n: self.n }
    }
    /// The interquartile range as `[q1, q3]` in text with `digits` decimals.
    pub(super) fn iqr(&self, digits: usize) -> String {
        format!("{:.digits$}-{:.digits$}", self.q1, self.q3)
    }
}

/// The printed tables, kept to be written next to the JSON.
#[derive(Default)]
pub(super) struct Report(pub(super) String);

impl Report {
    /// Prints `line` and keeps it.
    pub(super) fn line(&mut self, line: impl AsRef<str>) {
        println!("{}", line.as_ref());
        self.0.push_str(line.as_ref());
        self.0.push('\n');
    }
    /// Writes the tables to `<out>/<stem>.txt` and `json` to `<out>/<stem>.json`, and says where.
    pub(super) fn write(&self, out: &Path, stem: &str, json: &serde_json::Value) -> anyhow::Result<()> {
        std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
        let (txt, js) = (out.join(format!("{stem}.txt")), out.join(format!("{stem}.json")));
        dataset::io::atomic_write(&txt, self.0.as_bytes())?;
        dataset::io::atomic_write_json(&js, json)?;
        println!("wrote {} and {}", js.display(), txt.display());
        Ok(())
    }
}

/// A relative `--out` folder is taken from the repository root (the release re-run starts there).
pub(super) fn out_dir(out: &Path) -> PathBuf {
    if out.is_absolute() { out.to_path_buf() } else { crate::render::repo_root().join(out) }
}
