//! The dataset's ground truth at the resolution a view is evaluated at, shared by `eval` (our
//! runs) and `score` (other tools' predictions), so both measure against the same pixels.
//!
//! - Colour: the dataset's PNG (display sRGB, straight alpha) box-filtered over whole `D × D`
//!   blocks with alpha-premultiplied colour (`dataset::RgbaImage::downscaled`, the trainer's
//!   filter), then composited onto the evaluation background: `rgb·a + bg·(1 − a)`
//!   ([`composite_straight`], the same formula for a prediction that carries alpha).
//! - Depth, distance, normal and alpha are exact at the downscaled pixel-centre rays and never
//!   averaged ([`GroundTruthSource`]): for odd `D` read from the ground-truth file, for even `D`
//!   cast through the scene the dataset was rendered from, or, without it, the nearest
//!   full-resolution pixel's values with a note saying so.
//! - The off-surface tolerance ([`surface_options`]): 1 % of the diagonal of the scene facts'
//!   box, or of the box around the evaluated views' ground-truth surface points when the dataset
//!   carries no facts.

use crate::EvalError;
use crate::evaluate::EvalOptions;
use dataset::{Dataset, Frame, GroundTruth};
use pathtracer::ground_truth::{SceneLookup, scene_of_dataset};
use std::path::Path;

/// How an error about a dataset file is reported: `eval` names the run, `score` the dataset.
pub type ErrorContext<'a> = &'a dyn Fn(String) -> EvalError;

/// Where a view's depth / distance / normal / alpha ground truth at the evaluated resolution
/// comes from.
pub enum GroundTruthSource {
    /// Read from the ground-truth file: the full-resolution centre ray of an odd factor's block
    /// is the downscaled centre ray.
    File,
    /// Cast exactly through the scene (even factors).
    Scene(Box<pathtracer::render::Renderer>),
    /// The nearest full-resolution pixel (even factors without the scene).
    Nearest,
}

/// One view's ground truth at the evaluated resolution.
#[derive(Clone, Debug)]
pub struct TruthView {
    /// The frame's name (`r_0`).
    pub name: String,
    /// Width in pixels at the evaluated resolution.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Colour composited on the background, `[H * W * 3]`.
    pub gt_rgb: Vec<f32>,
    /// Depth, distance, normal and alpha, when the dataset has them.
    pub gt: Option<GroundTruth>,
}

/// Straight-alpha RGBA composited onto `background`: `rgb·a + bg·(1 − a)` per channel, in `f32`,
/// the formula the ground truth is composited with.
///
/// # Shapes
/// `rgba`: `[N * 4]`; returns `[N * 3]`.
pub fn composite_straight(rgba: &[f32], background: [f32; 3]) -> Vec<f32> {
    rgba.chunks_exact(4)
        .flat_map(|p| {
            let a = p[3];
            [0, 1, 2].map(|c| p[c] * a + background[c] * (1.0 - a))
        })
        .collect()
}

/// The frame's ground truth at `downscale`: colour composited on `background`, and depth,
/// distance, normal and alpha from `source`.
pub fn load_truth(frame: &Frame, background: [f32; 3], downscale: u32, source: &GroundTruthSource, err: ErrorContext<'_>) -> Result<TruthView, EvalError> {
    let full = frame.camera.intrinsics;
    let png = dataset::read_png_rgba(&frame.image_path)?;
    if (png.width, png.height) != (full.width, full.height) {
        return Err(err(format!(
            "{}: image is {}x{}, camera says {}x{}",
            frame.image_path.display(),
            png.width,
            png.height,
            full.width,
            full.height
        )));
    }
    let k = frame.camera.downscaled(downscale).intrinsics;
    let png = png.downscaled(downscale);
    Ok(TruthView {
        name: frame.name.clone(),
        width: k.width as usize,
        height: k.height as usize,
        gt_rgb: composite_straight(&png.data, background),
        gt: ground_truth_at(frame, downscale, source, err)?,
    })
}

/// The frame's depth / distance / normal / alpha ground truth at `downscale` (see
/// [`GroundTruthSource`]); `None` when the frame has none.
pub fn ground_truth_at(frame: &Frame, downscale: u32, source: &GroundTruthSource, err: ErrorContext<'_>) -> Result<Option<GroundTruth>, EvalError> {
    let Some(p) = &frame.gt_path else { return Ok(None) };
    let full = frame.camera.intrinsics;
    let g = dataset::read_ground_truth(p)?;
    if (g.width, g.height) != (full.width, full.height) {
        return Err(err(format!("{}: ground truth is {}x{}, camera says {}x{}", p.display(), g.width, g.height, full.width, full.height)));
    }
    Ok(Some(match (g.at_downscale(downscale), source) {
        (Some(exact), _) => exact,
        (None, GroundTruthSource::Scene(r)) => r.ground_truth(&frame.camera.downscaled(downscale)),
        (None, _) => g.nearest_at_downscale(downscale),
    }))
}

/// How the ground truth at `downscale` is obtained, and the report's note saying so (`None`
/// when it is read exactly from the files, or there is none).
pub fn ground_truth_source(
    dataset: &Dataset,
    frames: &[&Frame],
    downscale: u32,
    scene: Option<&Path>,
    import: &pathtracer::import::ImportOptions,
) -> Result<(GroundTruthSource, Option<String>), EvalError> {
    if downscale % 2 == 1 || frames.iter().all(|f| f.gt_path.is_none()) {
        return Ok((GroundTruthSource::File, None));
    }
    let pt = |e: pathtracer::PathTracerError| EvalError::Input(e.to_string());
    Ok(match scene_of_dataset(&dataset.root, scene, import).map_err(pt)? {
        SceneLookup::Found { renderer, path } => (
            GroundTruthSource::Scene(renderer),
            Some(format!(
                "depth, distance, normal and alpha ground truth at downscale {downscale} are cast exactly through {} at the downscaled pixel centres",
                path.display()
            )),
        ),
        SceneLookup::Missing(why) => (
            GroundTruthSource::Nearest,
            Some(format!(
                "depth, distance, normal and alpha ground truth at the even downscale {downscale} are those of the nearest full-resolution pixel centre (half a full-resolution pixel off the evaluated ray), because {why}; give the scene (`--scene`) for exact values or evaluate at an odd downscale"
            )),
        ),
    })
}

/// The box around ground-truth surface points (each covered pixel-centre ray, alpha at least
/// [`crate::metrics::FOREGROUND_ALPHA`], lifted by its true distance), grown view by view: the
/// scene's extent for the off-surface tolerance when the dataset has no scene facts but has
/// ground truth.
#[derive(Clone, Copy, Debug)]
struct SurfaceBox {
    lo: [f64; 3],
    hi: [f64; 3],
}

impl SurfaceBox {
    fn empty() -> Self {
        Self { lo: [f64::INFINITY; 3], hi: [f64::NEG_INFINITY; 3] }
    }

    /// Adds the surface points of `g`, seen by `camera` (of `g`'s resolution).
    fn extend(&mut self, camera: &dataset::Camera, g: &GroundTruth) {
        let w = g.width as usize;
        for (p, (&d, &a)) in g.distance.iter().zip(&g.alpha).enumerate() {
            if a < crate::metrics::FOREGROUND_ALPHA || !(d > 0.0 && d.is_finite()) {
                continue;
            }
            let ray = camera.pixel_center_ray((p % w) as u32, (p / w) as u32);
            let x = ray.origin + ray.direction * d as f64;
            for k in 0..3 {
                self.lo[k] = self.lo[k].min(x[k]);
                self.hi[k] = self.hi[k].max(x[k]);
            }
        }
    }

    /// `None` without any surface point.
    fn bounds(&self) -> Option<([f32; 3], [f32; 3])> {
        self.lo[0].is_finite().then(|| (self.lo.map(|v| v as f32), self.hi.map(|v| v as f32)))
    }
}

/// The evaluation's options (the off-surface tolerance) and the note that says where the
/// tolerance came from: the scene facts' box, or a first pass over the evaluated views' ground
/// truth.
pub fn surface_options(dataset: &Dataset, frames: &[&Frame], downscale: u32, source: &GroundTruthSource, err: ErrorContext<'_>) -> Result<(EvalOptions, Option<String>), EvalError> {
    let surface = match &dataset.facts {
        Some(_) => None,
        None => {
            let mut b = SurfaceBox::empty();
            for f in frames {
                if let Some(g) = ground_truth_at(f, downscale, source, err)? {
                    b.extend(&f.camera.downscaled(downscale), &g);
                }
            }
            b.bounds()
        }
    };
    Ok(match (&dataset.facts, surface) {
        (Some(f), _) => (EvalOptions::for_scene_bbox(f.aabb_min.map(|v| v as f32), f.aabb_max.map(|v| v as f32)), None),
        (None, Some((lo, hi))) => {
            let o = EvalOptions::for_scene_bbox(lo, hi);
            let note = format!(
                "the dataset carries no scene facts: the off-surface tolerance ({:.4}) is 1 % of the diagonal of the box around the ground-truth surface points of the evaluated views",
                o.surface_tol
            );
            (o, Some(note))
        }
        (None, None) => (
            EvalOptions::with_surface_tol(0.0),
            Some("the dataset carries no scene facts (e.g. Blender synthetic): no bounding box for the off-surface tolerance".to_string()),
        ),
    })
}
