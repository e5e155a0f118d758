//! `render-nerf --camera-path P --video out.mp4 [--layout side-by-side --gt GTDIR]`: feeds each
//! rendered frame, beside the path tracer's frame of the same camera when the layout asks for
//! it, to the MP4 writer (`eval::path_video` lays the frame out, `eval::video` encodes it).

use anyhow::Context;
use eval::path_video::{FrameImages, Layout, compose, frame_size};
use std::path::{Path, PathBuf};

/// A progress bar of `len` steps saying `what`.
pub fn bar(len: u64, what: &str) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(len);
    bar.set_style(
        indicatif::ProgressStyle::with_template(&format!("{what} {{pos}}/{{len}} {{bar:30}} {{elapsed}} ETA {{eta}}"))
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar
}

/// A video being written along a camera path.
pub struct PathVideo {
    path: PathBuf,
    layout: Layout,
    truth: Vec<dataset::Frame>,
    background: [f32; 3],
    depth_range: f64,
    writer: eval::video::VideoWriter,
}

impl PathVideo {
    /// Checks the options and starts the video at `path`; `camera_path` is the path file (its
    /// fps), `cameras` the frames about to be rendered.
    pub fn start(
        path: &Path,
        camera_path: &Path,
        layout: Layout,
        gt: Option<&Path>,
        cameras: &[(String, dataset::Camera)],
        background: [f32; 3],
        allow_outside: bool,
    ) -> anyhow::Result<Self> {
        crate::guard::check_output_files("--video", path, &[path.to_path_buf()], &[camera_path.to_path_buf()])?;
        let fps = dataset::CameraPathFile::read(camera_path)?.fps;
        let (mut truth, mut depth_range) = (Vec::new(), 0.1);
        match (layout, gt) {
            (Layout::SideBySide, None) => anyhow::bail!("--layout side-by-side needs --gt: the folder `render SCENE --camera-path` wrote"),
            (Layout::SideBySide, Some(dir)) => {
                let ds = dataset::Dataset::load_with(dir, &dataset::LoadOptions { allow_outside }).with_context(|| format!("--gt {}", dir.display()))?;
                anyhow::ensure!(
                    ds.train.len() == cameras.len(),
                    "--gt {}: {} frames, but the camera path has {}: render the same path",
                    dir.display(),
                    ds.train.len(),
                    cameras.len()
                );
                for (k, (f, (_, c))) in ds.train.iter().zip(cameras).enumerate() {
                    let same = f.camera.intrinsics.width == c.intrinsics.width
                        && f.camera.intrinsics.height == c.intrinsics.height
                        && f.camera.c2w.to_cols_array().iter().zip(c.c2w.to_cols_array()).all(|(a, b)| (a - b).abs() < 1e-6);
                    anyhow::ensure!(same, "--gt {}: frame {k} is not the camera path's frame {k} (another path or size)", dir.display());
                    anyhow::ensure!(f.gt_path.is_some(), "--gt {}: frame {k} has no ground-truth file", dir.display());
                }
                if let Some(facts) = &ds.facts {
                    let diag = (0..3).map(|i| (facts.aabb_max[i] - facts.aabb_min[i]).powi(2)).sum::<f64>().sqrt();
                    depth_range = 0.02 * diag;
                }
                truth = ds.train;
            }
            (Layout::Nerf, Some(_)) => anyhow::bail!("--gt is for --layout side-by-side"),
            (Layout::Nerf, None) => {}
        }
        let first = cameras.first().context("the camera path has no frames")?.1.intrinsics;
        let (w, h) = frame_size(layout, first.width, first.height);
        let writer = eval::video::VideoWriter::create(path, w, h, fps)?;
        Ok(Self { path: path.to_path_buf(), layout, truth, background, depth_range, writer })
    }

    /// Adds frame `k`, the NeRF's view `v`.
    pub fn push(&mut self, k: usize, v: &nerf::render::RenderedView) -> anyhow::Result<()> {
        let truth = match self.truth.get(k) {
            Some(f) => Some(eval::truth::load_truth(f, self.background, 1, &eval::truth::GroundTruthSource::File, &|m| eval::EvalError::Input(m))?),
            None => None,
        };
        let empty: &[f32] = &[];
        let gt = truth.as_ref().and_then(|t| t.gt.as_ref());
        let images = FrameImages {
            width: v.width,
            height: v.height,
            nerf_rgb: &v.rgb,
            nerf_depth: &v.depth,
            gt_rgb: truth.as_ref().map_or(empty, |t| t.gt_rgb.as_slice()),
            gt_depth: gt.map_or(empty, |g| g.depth.as_slice()),
            gt_alpha: gt.map_or(empty, |g| g.alpha.as_slice()),
        };
        let rgb = compose(self.layout, &images, self.depth_range, &self.path)?;
        self.writer.push(&rgb)?;
        Ok(())
    }

    /// Completes the file; returns its path and frame count.
    pub fn finish(self) -> anyhow::Result<(PathBuf, u64)> {
        let frames = self.writer.finish()?;
        Ok((self.path, frames))
    }
}
