//! Rendering views from a trained run: [`RunModel::load`] reads `config.json` and the latest
//! checkpoint; [`RunModel::render_view`] gives colour (display sRGB, the space the models are
//! trained in), opacity, expected z-depth and distance, and every ray's samples and weights.

use crate::checkpoint;
use crate::data::SceneBounds;
use crate::models::Model;
use crate::train::{CONFIG_FILE, TrainConfig, TrainError};
use dataset::Camera;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// The samples behind each pixel, for off-surface-mass metrics.
///
/// # Shapes
/// `offsets`: pixels + 1; `t`, `w`: samples. Pixel `p` owns `offsets[p]..offsets[p + 1]`.
#[derive(Clone, Debug, Default)]
pub struct RaySamplesOut {
    /// Prefix offsets per pixel.
    pub offsets: Vec<u32>,
    /// Each sample's expected termination distance within its interval (the midpoint where the
    /// density is low): distance along the (unit-direction) ray.
    pub t: Vec<f32>,
    /// Volume-rendering weights.
    pub w: Vec<f32>,
}

/// One rendered view.
///
/// # Shapes
/// `rgb`: H×W×3; `opacity`, `depth`, `distance`: H×W; row 0 at the top.
#[derive(Clone, Debug)]
pub struct RenderedView {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Display (sRGB-encoded) colour in [0, 1], background composited by (1 − opacity).
    pub rgb: Vec<f32>,
    /// Σ w per pixel.
    pub opacity: Vec<f32>,
    /// Expected z-depth of the visible surface: `Camera::z_depth_from_distance` of
    /// [`Self::distance`]; 0 where opacity is 0.
    pub depth: Vec<f32>,
    /// Expected Euclidean distance Σwt / Σw along the pixel-centre ray; 0 where opacity is 0.
    pub distance: Vec<f32>,
    /// Per-pixel samples.
    pub samples: RaySamplesOut,
}

/// A trained run ready to render.
#[derive(Debug)]
pub struct RunModel {
    /// The run's config.
    pub config: TrainConfig,
    /// The model with the latest checkpoint's parameters.
    pub model: Model,
    /// The checkpoint loaded.
    pub checkpoint: PathBuf,
    steps: u64,
    wall_s: f64,
}

impl RunModel {
    /// Loads a run folder: its config and latest checkpoint.
    pub fn load(run_dir: &Path) -> Result<Self, TrainError> {
        let config_path = run_dir.join(CONFIG_FILE);
        let config = TrainConfig::read(&config_path)?;
        // Every setting a reader uses (downscale, bounds, the model's sizes) as training checks it.
        config.check().map_err(|e| TrainError::Invalid(format!("{}: {e}", config_path.display())))?;
        let bounds: SceneBounds = config
            .bounds
            .clone()
            .ok_or_else(|| TrainError::Invalid("config.json has no resolved bounds".into()))?;
        let (path, state) = checkpoint::load_latest(run_dir)?;
        let mut model = config.model.init(&bounds, config.seed).map_err(TrainError::Invalid)?;
        model.load_state(&state).map_err(|e| {
            TrainError::Invalid(format!("{}: {e} (the checkpoint does not hold the model {} describes)", path.display(), CONFIG_FILE))
        })?;
        let steps = if state.scalars.contains_key("trainer.step") {
            state.count("trainer.step").map_err(|e| TrainError::Invalid(format!("{}: {e}", path.display())))?
        } else {
            0
        };
        let wall_s = state.scalars.get("trainer.wall_s").copied().unwrap_or(0.0);
        Ok(Self { config, model, checkpoint: path, steps, wall_s })
    }

    /// The dataset folder the run was trained on.
    pub fn dataset_dir(&self) -> &Path {
        &self.config.dataset
    }

    /// Trainable parameters.
    pub fn parameters(&self) -> usize {
        self.model.parameters()
    }

    /// Training steps of the loaded checkpoint.
    pub fn train_steps(&self) -> u64 {
        self.steps
    }

    /// Training seconds of the loaded checkpoint (validation excluded).
    pub fn train_wall_s(&self) -> f64 {
        self.wall_s
    }

    /// The background the run was trained with, as used for evaluation.
    pub fn eval_background(&self) -> [f32; 3] {
        self.config.background.eval_color()
    }

    /// Renders every pixel-centre ray of `camera`.
    pub fn render_view(&self, camera: &Camera, background: [f32; 3]) -> RenderedView {
        let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
        let n = w as usize * h as usize;
        let (origins, dirs) = crate::data::pixel_rays(camera);
        let out = self.model.render_rays(&origins, &dirs, background);
        let depth = (0..n)
            .into_par_iter()
            .map(|p| {
                let (px, py) = ((p % w as usize) as f64 + 0.5, (p / w as usize) as f64 + 0.5);
                camera.z_depth_from_distance(px, py, out.distance[p] as f64) as f32
            })
            .collect();
        RenderedView {
            width: w,
            height: h,
            rgb: out.rgb.iter().flatten().copied().collect(),
            opacity: out.opacity,
            depth,
            distance: out.distance,
            samples: RaySamplesOut { offsets: out.offsets, t: out.t, w: out.w },
        }
    }
}

/// `n` cameras on a horizontal circle around `center` at the height and horizontal distance of
/// `first` (e.g. the first training camera), all with its intrinsics, looking at `center`.
pub fn orbit_cameras(first: &Camera, center: [f32; 3], n: usize) -> Vec<Camera> {
    let c = glam::DVec3::from(center.map(f64::from));
    let e = first.origin() - c;
    let (r, h) = ((e.x * e.x + e.z * e.z).sqrt().max(1e-6), e.y);
    (0..n)
        .filter_map(|k| {
            let a = std::f64::consts::TAU * k as f64 / n as f64;
            let eye = c + glam::DVec3::new(r * a.cos(), h, r * a.sin());
            Camera::new(first.intrinsics, Camera::look_at(eye, c, glam::DVec3::Y)).ok()
        })
        .collect()
}
