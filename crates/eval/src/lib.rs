//! Evaluation of NeRF runs against exact ground truth: image metrics (PSNR, SSIM), depth
//! metrics, mask IoU and off-surface mass per test view; aggregation into `eval.json`; the
//! speed-versus-error curve read from a run's `metrics.jsonl` (time to 25 dB and 30 dB);
//! pictures (`speed_vs_error.png`, per-view `grid_<view>.png`, `compare.png`); and Markdown
//! reports; and the same measurements of other tools' renders read from files (`score`). The
//! crate knows nothing about training: it takes plain slices.
//!
//! ```
//! use eval::{EvalOptions, RunInfo, ViewInput, evaluate_views};
//! let (w, h) = (16, 12);
//! let gt_rgb: Vec<f32> = (0..w * h * 3).map(|i| (i % 7) as f32 / 7.0).collect();
//! let pred_rgb: Vec<f32> = gt_rgb.iter().map(|v| v + 0.1).collect();
//! let gt_depth = vec![2.0_f32; w * h];
//! let pred_depth = vec![2.05_f32; w * h];
//! let alpha = vec![1.0_f32; w * h];
//! let view = ViewInput {
//!     name: "r_0", width: w, height: h, pred_rgb: &pred_rgb, gt_rgb: &gt_rgb,
//!     pred_depth: Some(&pred_depth), gt_depth: Some(&gt_depth), gt_distance: None,
//!     gt_alpha: Some(&alpha), pred_opacity: Some(&alpha), samples: None, render_s: 0.2,
//! };
//! let run = RunInfo { train_wall_s: 60.0, train_steps: 1000, parameters: 12345 };
//! let report = evaluate_views(&[view], run, &EvalOptions::with_surface_tol(0.02)).unwrap();
//! assert!((report.mean.psnr - 20.0).abs() < 1e-4); // every value off by 0.1
//! assert!((report.mean.depth_mae.unwrap() - 0.05).abs() < 1e-6);
//! assert!(report.mean.off_surface_mass.is_none()); // no samples given
//! ```

#![warn(missing_docs)]

pub mod colormap;
pub mod compare;
pub mod curve;
pub mod error;
pub mod evaluate;
pub mod geometry;
pub mod grid;
pub mod interop;
pub mod io;
pub mod marching_cubes;
pub mod mesh;
pub mod mesh_eval;
pub mod mesh_extract;
pub mod mesh_metrics;
pub mod metrics;
pub mod objects;
pub mod path_error;
pub mod path_video;
pub mod plot;
pub mod prediction_io;
pub mod predictions;
pub mod report;
pub mod run;
pub mod score;
pub mod session;
pub mod truth;
pub mod video;
pub mod video_probe;

pub use compare::{ParetoAxis, RunSummary, compare_runs, compare_table, pareto_front};
pub use curve::{MetricsRecord, parse_metrics_jsonl, read_metrics_jsonl, time_to_psnr, value_at};
pub use error::{EvalError, MetricError};
pub use evaluate::{EvalOptions, EvalReport, EvalResolution, RunInfo, ViewInput, ViewMetrics, ViewReport, evaluate_view, evaluate_views};
pub use io::read_json;
pub use metrics::RaySamples;
pub use report::write_report;
pub use run::{EvalRunOptions, EvalRunOutput, evaluate_run, summarise_run};
pub use score::{GeometryFrame, ScoreOptions, ScoreOutput, score};
