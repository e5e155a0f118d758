//! The error along a camera path: how a radiance field extrapolates away from its training
//! views, measured against the path tracer's exact ground truth along the same path.
//!
//! The ground truth is the folder `render SCENE --camera-path P` writes (a dataset whose train
//! views are the path's frames, [`dataset::Dataset`]); the run is rendered at each frame's
//! camera through [`nerf::render::RunModel`]. Per frame:
//! - `psnr`, `ssim` of the display colour, both composited on the run's evaluation background
//!   (the metrics and compositing of [`crate::metrics`] and [`crate::truth`]);
//! - `depth_mae`: mean |NeRF z-depth − exact z-depth| over pixels whose centre ray hits the
//!   scene (metres);
//! - `position_distance`: the distance from the frame's camera centre to the nearest training
//!   camera's centre (metres); `angular_distance`: the smallest angle between the frame's
//!   viewing direction (−Z) and a training camera's (degrees). Each is its own minimum over
//!   the training cameras.
//!
//! [`write_csv`] writes one line per frame; [`plot_png`] draws PSNR against the distance to the
//! nearest training camera; [`PathSummary`] is the block `eval --camera-path` adds to
//! `eval.json`.

use crate::EvalError;
use crate::metrics::{depth_mae, psnr, ssim};
use crate::plot::{FONT, ensure_font, plot_err};
use crate::truth::{GroundTruthSource, load_truth};
use dataset::{Camera, Dataset, SplitKind};
use nerf::render::RunModel;
use plotters::prelude::*;
use serde::Serialize;
use std::path::Path;

/// One frame's errors and distances.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PathFrameError {
    /// Frame index along the path.
    pub frame: usize,
    /// PSNR of the display colour, dB.
    pub psnr: f64,
    /// SSIM of the display colour (`None` for frames under 11 pixels a side).
    pub ssim: Option<f64>,
    /// Mean absolute z-depth error over the hit pixels, metres (`None` without hits).
    pub depth_mae: Option<f64>,
    /// Distance to the nearest training camera centre, metres.
    pub position_distance: f64,
    /// Smallest angle to a training camera's viewing direction, degrees.
    pub angular_distance: f64,
}

/// The summary `eval --camera-path` adds to `eval.json`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PathSummary {
    /// The ground-truth folder.
    pub truth: String,
    /// Number of frames.
    pub frames: usize,
    /// Mean PSNR, dB.
    pub mean_psnr: f64,
    /// Lowest PSNR and its frame.
    pub min_psnr: f64,
    /// The frame of [`PathSummary::min_psnr`].
    pub min_psnr_frame: usize,
    /// Mean SSIM over the frames that have one.
    pub mean_ssim: Option<f64>,
    /// Mean depth MAE over the frames that have one, metres.
    pub mean_depth_mae: Option<f64>,
    /// Largest distance to the nearest training camera along the path, metres.
    pub max_position_distance: f64,
    /// Largest angle to the nearest training view direction along the path, degrees.
    pub max_angular_distance: f64,
}

/// Distance and angle from `cam` to the nearest of `train` (each minimised on its own).
pub fn nearest_training(cam: &Camera, train: &[Camera]) -> (f64, f64) {
    let dir = |c: &Camera| (-c.c2w.z_axis.truncate()).normalize();
    let d = dir(cam);
    let pos = train.iter().map(|t| (t.origin() - cam.origin()).length()).fold(f64::INFINITY, f64::min);
    let ang = train.iter().map(|t| d.dot(dir(t)).clamp(-1.0, 1.0).acos().to_degrees()).fold(f64::INFINITY, f64::min);
    (pos, ang)
}

/// Renders `model` at every frame of the ground-truth path folder `truth` and measures it;
/// `train` are the run's training cameras. `progress(done, total)` after every frame.
pub fn path_errors(model: &RunModel, truth: &Dataset, train: &[Camera], progress: &mut dyn FnMut(usize, usize)) -> Result<Vec<PathFrameError>, EvalError> {
    let frames = truth.split(SplitKind::Train);
    if frames.is_empty() {
        return Err(EvalError::Input(format!("{}: the path's ground truth has no frames", truth.root.display())));
    }
    let bg = model.eval_background();
    let err = |m: String| EvalError::Input(m);
    let mut out = Vec::with_capacity(frames.len());
    for (k, f) in frames.iter().enumerate() {
        let t = load_truth(f, bg, 1, &GroundTruthSource::File, &err)?;
        let v = model.render_view(&f.camera, bg);
        let (w, h) = (t.width, t.height);
        let metric = |source| EvalError::Metric { view: format!("path frame {k}"), source };
        let ssim = (w >= 11 && h >= 11).then(|| ssim(&v.rgb, &t.gt_rgb, w, h, 3)).transpose().map_err(metric)?;
        let depth_mae = match &t.gt {
            Some(g) if g.alpha.iter().any(|a| *a > 0.0) => Some(depth_mae(&v.depth, &g.depth, &g.alpha).map_err(metric)?),
            _ => None,
        };
        let (position_distance, angular_distance) = nearest_training(&f.camera, train);
        let psnr = psnr(&v.rgb, &t.gt_rgb).map_err(metric)?;
        out.push(PathFrameError { frame: k, psnr, ssim, depth_mae, position_distance, angular_distance });
        progress(k + 1, frames.len());
    }
    Ok(out)
}

fn mean(v: impl Iterator<Item = f64>) -> Option<f64> {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    (n > 0).then(|| s / n as f64)
}

impl PathSummary {
    /// The summary of `rows` (at least one) measured against `truth`.
    pub fn of(rows: &[PathFrameError], truth: &Path) -> Self {
        let worst = rows.iter().min_by(|a, b| a.psnr.total_cmp(&b.psnr));
        Self {
            truth: truth.display().to_string(),
            frames: rows.len(),
            mean_psnr: mean(rows.iter().map(|r| r.psnr)).unwrap_or(f64::NAN),
            min_psnr: worst.map_or(f64::NAN, |r| r.psnr),
            min_psnr_frame: worst.map_or(0, |r| r.frame),
            mean_ssim: mean(rows.iter().filter_map(|r| r.ssim)),
            mean_depth_mae: mean(rows.iter().filter_map(|r| r.depth_mae)),
            max_position_distance: rows.iter().map(|r| r.position_distance).fold(0.0, f64::max),
            max_angular_distance: rows.iter().map(|r| r.angular_distance).fold(0.0, f64::max),
        }
    }
}

/// Writes the rows as CSV (header `frame,psnr,ssim,depth_mae,position_distance,angular_distance`;
/// an absent value is an empty field), atomically.
pub fn write_csv(path: &Path, rows: &[PathFrameError]) -> Result<(), EvalError> {
    let opt = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v}"));
    let mut text = String::from("frame,psnr,ssim,depth_mae,position_distance,angular_distance\n");
    for r in rows {
        text.push_str(&format!("{},{},{},{},{},{}\n", r.frame, r.psnr, opt(r.ssim), opt(r.depth_mae), r.position_distance, r.angular_distance));
    }
    crate::io::write_atomic(path, text.as_bytes())
}

/// PSNR against the distance to the nearest training camera, one point per frame, as a PNG.
pub fn plot_png(path: &Path, rows: &[PathFrameError]) -> Result<(), EvalError> {
    ensure_font(path)?;
    let (w, h) = (720u32, 420u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        let pe = plot_err(path);
        root.fill(&WHITE).map_err(&pe)?;
        let finite: Vec<&PathFrameError> = rows.iter().filter(|r| r.psnr.is_finite()).collect();
        let x_max = finite.iter().map(|r| r.position_distance).fold(0.0, f64::max).max(1e-6) * 1.05;
        let (lo, hi) = finite.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), r| (lo.min(r.psnr), hi.max(r.psnr)));
        let (lo, hi) = if lo.is_finite() { (lo - 1.0, hi + 1.0) } else { (0.0, 1.0) };
        let mut chart = ChartBuilder::on(&root)
            .caption("error along the camera path", (FONT, 20))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..x_max, lo..hi)
            .map_err(&pe)?;
        chart
            .configure_mesh()
            .x_desc("distance to the nearest training camera (m)")
            .y_desc("PSNR (dB)")
            .label_style((FONT, 14))
            .axis_desc_style((FONT, 15))
            .draw()
            .map_err(&pe)?;
        chart
            .draw_series(finite.iter().map(|r| Circle::new((r.position_distance, r.psnr), 3, BLUE.filled())))
            .map_err(&pe)?;
        root.present().map_err(&pe)?;
    }
    crate::io::write_png_atomic(path, w, h, buf)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    #[test]
    fn the_nearest_training_camera_is_found_by_position_and_by_angle() {
        let intr = dataset::Intrinsics::from_fov_x(8, 8, 0.7);
        let at = |eye: DVec3| Camera::new(intr, Camera::look_at(eye, DVec3::ZERO, DVec3::Y)).unwrap();
        let train = [at(DVec3::new(0.0, 0.0, 4.0)), at(DVec3::new(4.0, 0.0, 0.0))];
        let (pos, ang) = nearest_training(&at(DVec3::new(0.0, 0.0, 4.0)), &train);
        assert_eq!((pos, ang), (0.0, 0.0));
        // Twice as far along the same axis: the same direction, 4 m away.
        let (pos, ang) = nearest_training(&at(DVec3::new(0.0, 0.0, 8.0)), &train);
        assert!((pos - 4.0).abs() < 1e-12 && ang.abs() < 1e-6);
        // Halfway round between the two: 45 degrees from either.
        let s = 4.0 / 2f64.sqrt();
        let (_, ang) = nearest_training(&at(DVec3::new(s, 0.0, s)), &train);
        assert!((ang - 45.0).abs() < 1e-9, "{ang}");
    }

    #[test]
    fn csv_and_summary_hold_every_frame() {
        let rows = vec![
            PathFrameError { frame: 0, psnr: 30.0, ssim: Some(0.9), depth_mae: Some(0.01), position_distance: 0.0, angular_distance: 0.0 },
            PathFrameError { frame: 1, psnr: 20.0, ssim: None, depth_mae: None, position_distance: 1.5, angular_distance: 30.0 },
        ];
        let dir = tempfile::tempdir().unwrap();
        write_csv(&dir.path().join("e.csv"), &rows).unwrap();
        let text = std::fs::read_to_string(dir.path().join("e.csv")).unwrap();
        assert_eq!(text.lines().count(), 3);
        assert_eq!(text.lines().nth(2).unwrap(), "1,20,,,1.5,30");
        let s = PathSummary::of(&rows, Path::new("gt"));
        assert_eq!((s.frames, s.mean_psnr, s.min_psnr, s.min_psnr_frame), (2, 25.0, 20.0, 1));
        assert_eq!((s.mean_ssim, s.mean_depth_mae, s.max_position_distance, s.max_angular_distance), (Some(0.9), Some(0.01), 1.5, 30.0));
        plot_png(&dir.path().join("p.png"), &rows).unwrap();
        assert!(image::open(dir.path().join("p.png")).is_ok());
    }
}
