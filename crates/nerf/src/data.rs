//! Training data: the views of a dataset split as pixel arrays, batches of rays drawn from them
//! with a counter-based generator keyed by (seed, step), and the scene bounds a model needs.
//!
//! Colour space: the models learn the **display (sRGB-encoded) values as stored in the PNGs**,
//! the convention of the NeRF paper and its Blender loaders; straight-alpha RGBA is composited
//! onto the background in that space: `c = a·rgb + (1 − a)·bg`.

use crate::kernels::{stream, uniform};
use crate::supervision::{RaySupervision, SupervisionConfig, clamp_target};
use dataset::{Camera, Dataset, Frame, SceneFacts};
use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Errors while preparing training data.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    /// The dataset could not be read.
    #[error(transparent)]
    Dataset(#[from] dataset::DatasetError),
    /// The dataset is unusable for training.
    #[error("{0}")]
    Invalid(String),
}

/// The background that transparent pixels are composited onto.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Background {
    /// White (the Blender-synthetic convention).
    White,
    /// Black.
    Black,
    /// A random colour per ray and step during training (keeps the model from explaining the
    /// background with density); white for evaluation.
    Random,
}

impl Background {
    /// The fixed colour used for evaluation and rendering.
    pub fn eval_color(self) -> [f32; 3] {
        match self {
            Background::Black => [0.0; 3],
            Background::White | Background::Random => [1.0; 3],
        }
    }
}

impl std::str::FromStr for Background {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "white" => Ok(Self::White),
            "black" => Ok(Self::Black),
            "random" => Ok(Self::Random),
            _ => Err(format!("unknown background '{s}' (white, black or random)")),
        }
    }
}

/// A view's ground truth at some resolution: (z-depth, alpha), row-major from the top.
pub type DepthAlpha = (Vec<f32>, Vec<f32>);

/// One view as pixels: straight-alpha RGBA display values, row-major from the top.
#[derive(Clone, Debug)]
pub struct ViewPixels {
    /// The camera (already downscaled).
    pub camera: Camera,
    /// RGBA per pixel.
    pub rgba: Vec<[f32; 4]>,
    /// Ground truth (z-depth, alpha) when the dataset has it, downscaled by taking the pixel
    /// whose centre matches (nearest), so depth stays exact at the pixel-centre ray only for
    /// `downscale` 1.
    pub gt: Option<(Vec<f32>, Vec<f32>)>,
}

impl ViewPixels {
    /// Loads a frame, box-filtering its image by `downscale` with the colour premultiplied by
    /// alpha ([`dataset::RgbaImage::downscaled`], the filter the evaluation applies to its
    /// ground truth), so a downscaled pixel composited onto a background is the mean of its
    /// block's composited pixels.
    pub fn load(frame: &Frame, downscale: u32, with_gt: bool) -> Result<Self, DataError> {
        let k = downscale.max(1);
        let camera = frame.camera.downscaled(k);
        let img = dataset::read_png_rgba(&frame.image_path)?.downscaled(k);
        let (w, h) = (camera.intrinsics.width as usize, camera.intrinsics.height as usize);
        if (img.width as usize, img.height as usize) != (w, h) {
            return Err(DataError::Invalid(format!(
                "{}: the image downscaled by {k} is {}x{}, its camera downscaled is {w}x{h}",
                frame.image_path.display(),
                img.width,
                img.height
            )));
        }
        let rgba = img.data.chunks_exact(4).map(|p| [p[0], p[1], p[2], p[3]]).collect();
        let gt = if with_gt { Self::load_ground_truth(frame, k)? } else { None };
        Ok(Self { camera, rgba, gt })
    }

    /// The frame's ground truth (z-depth, alpha) at `downscale` (see [`Self::gt`]), without
    /// reading its image; `None` when the frame has none.
    pub fn load_ground_truth(frame: &Frame, downscale: u32) -> Result<Option<DepthAlpha>, DataError> {
        Ok(Self::ground_truth_at(frame, downscale)?.map(|g| (g.depth, g.alpha)))
    }

    /// Every channel of the frame's ground truth at `downscale`, checked against the camera's
    /// size there; `None` when the frame has none.
    fn ground_truth_at(frame: &Frame, downscale: u32) -> Result<Option<dataset::GroundTruth>, DataError> {
        let Some(p) = &frame.gt_path else { return Ok(None) };
        let k = downscale.max(1);
        let camera = frame.camera.downscaled(k);
        let (w, h) = (camera.intrinsics.width as usize, camera.intrinsics.height as usize);
        let g = dataset::read_ground_truth(p)?.nearest_at_downscale(k);
        if (g.width as usize, g.height as usize) != (w, h) {
            return Err(DataError::Invalid(format!("{}: ground truth downscaled by {k} is {}x{}, the camera {w}x{h}", p.display(), g.width, g.height)));
        }
        Ok(Some(g))
    }

    /// The alpha channel.
    pub fn alpha(&self) -> Vec<f32> {
        self.rgba.iter().map(|p| p[3]).collect()
    }

    /// Width × height.
    pub fn pixels(&self) -> usize {
        self.rgba.len()
    }

    /// Colour of pixel `p` composited onto `bg`.
    pub fn color(&self, p: usize, bg: [f32; 3]) -> [f32; 3] {
        let [r, g, b, a] = self.rgba[p];
        [a * r + (1.0 - a) * bg[0], a * g + (1.0 - a) * bg[1], a * b + (1.0 - a) * bg[2]]
    }
}

/// World-space centre ray of pixel index `p` of a camera, as f32 (origin, unit direction).
pub fn pixel_ray(camera: &Camera, p: usize) -> ([f32; 3], [f32; 3]) {
    let w = camera.intrinsics.width as usize;
    let r = camera.pixel_center_ray((p % w) as u32, (p / w) as u32);
    (r.origin.as_vec3().to_array(), r.direction.as_vec3().to_array())
}

/// Every pixel's centre ray of a camera ([`pixel_ray`]), in pixel order: origins and
/// directions, built in parallel (for a full view, one pass over freshly faulted pages per
/// core instead of a serial, growing `unzip`).
pub fn pixel_rays(camera: &Camera) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    use rayon::prelude::*;
    let n = camera.intrinsics.width as usize * camera.intrinsics.height as usize;
    (0..n).into_par_iter().map(|p| pixel_ray(camera, p)).unzip()
}

/// A batch of training rays.
///
/// # Shapes
/// Every vector has one entry per ray.
#[derive(Clone, Debug, Default)]
pub struct RayBatch {
    /// Ray origins.
    pub origins: Vec<[f32; 3]>,
    /// Unit directions.
    pub dirs: Vec<[f32; 3]>,
    /// Target colours (composited onto `background`).
    pub target: Vec<[f32; 3]>,
    /// Background colour per ray.
    pub background: Vec<[f32; 3]>,
    /// A global id per ray (view · 2³² + pixel) that keys per-ray random numbers.
    pub ids: Vec<u64>,
    /// Whether each ray's pixel is a mixed pixel ([`mixed_pixels`]); empty when the data
    /// carries no such masks (then no ray counts as mixed).
    pub mixed: Vec<bool>,
    /// Depth and empty-space targets of the rays and this step's weights, when the run is
    /// supervised beyond colour ([`TrainData::set_supervision`]).
    pub supervision: Option<RaySupervision>,
}

/// Alpha below which a pixel is background and above which it is fully covered (the
/// translucency test of `auto` and [`mixed_pixels`]).
pub const ALPHA_EDGE: f32 = 0.02;

/// Which pixels are *mixed*: their footprint straddles more than one surface, so their colour
/// (the average over the pixel's area) is a blend that the single ray through the pixel centre
/// can reproduce only with its weight split between depths. A pixel is mixed when
/// - its alpha is partial (`ALPHA_EDGE < α < 1 − ALPHA_EDGE`): a silhouette against the
///   background or a sub-pixel structure crosses it; or
/// - with z-depth (`depth`, 0 or non-finite where the centre ray hits nothing), it hits a
///   surface and the depths of the surfaces hit in its 3 × 3 neighbourhood span more than
///   `footprints` pixel footprints at its own depth (footprint = z / `focal`, `focal` in
///   pixels): a depth discontinuity crosses it or a neighbour. A plane seen at incidence θ spans
///   2 tan θ footprints over the neighbourhood, so 16 flags planes steeper than 83°, and every
///   occlusion edge.
///
/// `alpha` and `depth` are row-major `width × height` (a slice of another length gives no
/// mixed pixels from it).
pub fn mixed_pixels(width: usize, height: usize, alpha: &[f32], depth: Option<&[f32]>, focal: f64, footprints: f64) -> Vec<bool> {
    let n = width * height;
    let mut mixed: Vec<bool> = if alpha.len() == n { alpha.iter().map(|&a| a > ALPHA_EDGE && a < 1.0 - ALPHA_EDGE).collect() } else { vec![false; n] };
    let Some(depth) = depth.filter(|d| d.len() == n) else { return mixed };
    let hit = |z: f32| z.is_finite() && z > 0.0;
    let per_footprint = footprints / focal.max(1e-12);
    for j in 0..height {
        for i in 0..width {
            let z = depth[j * width + i];
            if !hit(z) || mixed[j * width + i] {
                continue;
            }
            let (mut lo, mut hi) = (z, z);
            for y in j.saturating_sub(1)..(j + 2).min(height) {
                for x in i.saturating_sub(1)..(i + 2).min(width) {
                    let q = depth[y * width + x];
                    if hit(q) {
                        lo = lo.min(q);
                        hi = hi.max(q);
                    }
                }
            }
            if (hi - lo) as f64 > per_footprint * z as f64 {
                mixed[j * width + i] = true;
            }
        }
    }
    mixed
}

/// The share of mixed pixels ([`mixed_pixels`]) among the covered ones (alpha > `ALPHA_EDGE`).
pub fn mixed_share(alphas: &[Vec<f32>], masks: &[Vec<bool>]) -> f64 {
    let (mut covered, mut mixed) = (0usize, 0usize);
    for (a, m) in alphas.iter().zip(masks) {
        for (a, m) in a.iter().zip(m) {
            if *a > ALPHA_EDGE {
                covered += 1;
                mixed += *m as usize;
            }
        }
    }
    if covered == 0 { 0.0 } else { mixed as f64 / covered as f64 }
}

/// Ground-truth z-depth of every frame at `downscale` (nearest pixel, see [`ViewPixels::gt`]),
/// when every frame has it.
pub fn frame_depths(frames: &[Frame], downscale: u32) -> Result<Option<Vec<Vec<f32>>>, DataError> {
    if frames.is_empty() || frames.iter().any(|f| f.gt_path.is_none()) {
        return Ok(None);
    }
    let mut out = Vec::with_capacity(frames.len());
    for f in frames {
        match ViewPixels::load_ground_truth(f, downscale)? {
            Some((depth, _)) => out.push(depth),
            None => return Ok(None),
        }
    }
    Ok(Some(out))
}

/// The training views of a dataset.
#[derive(Clone, Debug)]
pub struct TrainData {
    /// The views.
    pub views: Vec<ViewPixels>,
    /// Background handling.
    pub background: Background,
    cumulative: Vec<usize>,
    /// Per view, which pixels are mixed ([`Self::set_mixed`]); empty: none known.
    mixed: Vec<Vec<bool>>,
    /// The supervision settings and, per view and pixel, the target distance along the
    /// pixel-centre ray (NaN: none), whether the exact alpha is 0 and, with the normal term,
    /// the target normal (NaN where there is no depth target).
    supervision: Option<(SupervisionConfig, Vec<Vec<f32>>, Vec<Vec<bool>>, Vec<Vec<[f32; 3]>>)>,
}

impl TrainData {
    /// Loads the frames of a split.
    pub fn load(frames: &[Frame], downscale: u32, background: Background, with_gt: bool) -> Result<Self, DataError> {
        if frames.is_empty() {
            return Err(DataError::Invalid("the split has no frames".into()));
        }
        let views = frames.iter().map(|f| ViewPixels::load(f, downscale, with_gt)).collect::<Result<Vec<_>, _>>()?;
        let mut cumulative = vec![0];
        for v in &views {
            cumulative.push(cumulative.last().copied().unwrap_or(0) + v.pixels());
        }
        Ok(Self { views, background, cumulative, mixed: Vec::new(), supervision: None })
    }

    /// Every view's alpha channel.
    pub fn alphas(&self) -> Vec<Vec<f32>> {
        self.views.iter().map(ViewPixels::alpha).collect()
    }

    /// Whether mixed-pixel masks are set ([`Self::set_mixed`]).
    pub fn has_mixed(&self) -> bool {
        !self.mixed.is_empty()
    }

    /// Per view, its mixed pixels ([`mixed_pixels`]) from its alpha and, when given (one per
    /// view), its z-depth.
    pub fn mixed_masks(&self, depths: Option<&[Vec<f32>]>, footprints: f64) -> Vec<Vec<bool>> {
        let depths = depths.filter(|d| d.len() == self.views.len());
        self.views
            .iter()
            .enumerate()
            .map(|(k, v)| {
                let i = &v.camera.intrinsics;
                mixed_pixels(i.width as usize, i.height as usize, &v.alpha(), depths.map(|d| d[k].as_slice()), i.fl_x, footprints)
            })
            .collect()
    }

    /// Marks mixed pixels (one mask per view, each of the view's size), which batches then
    /// report per ray ([`RayBatch::mixed`]).
    pub fn set_mixed(&mut self, masks: Vec<Vec<bool>>) -> Result<(), DataError> {
        if masks.len() != self.views.len() || masks.iter().zip(&self.views).any(|(m, v)| m.len() != v.pixels()) {
            return Err(DataError::Invalid("mixed-pixel masks do not match the train views".into()));
        }
        self.mixed = masks;
        Ok(())
    }

    /// Supervises the batches beyond colour ([`crate::supervision`]): reads each frame's ground
    /// truth (`frames` are the views' frames, in order) at `downscale`, degrades its z-depth by
    /// `cfg.depth_source` keyed by (seed, view, pixel), converts it to the distance along the
    /// pixel-centre ray and clamps it into `near..far`; with the normal term, keeps the unit
    /// normal of every pixel with a depth target. Refused when a frame has no ground-truth
    /// file.
    pub fn set_supervision(&mut self, cfg: &SupervisionConfig, frames: &[Frame], downscale: u32, seed: u64, near: f32, far: f32) -> Result<(), DataError> {
        if frames.len() != self.views.len() {
            return Err(DataError::Invalid("supervision: the frames do not match the train views".into()));
        }
        let (mut depths, mut empties, mut normals) = (Vec::with_capacity(frames.len()), Vec::with_capacity(frames.len()), Vec::new());
        for (v, (f, view)) in frames.iter().zip(&self.views).enumerate() {
            let Some(dataset::GroundTruth { depth: z, alpha, normal, .. }) = ViewPixels::ground_truth_at(f, downscale)? else {
                return Err(DataError::Invalid(format!("train view {} has no ground-truth depth and alpha (gt_file_path)", f.name)));
            };
            let w = view.camera.intrinsics.width as usize;
            let depth = (0..z.len())
                .map(|p| {
                    if alpha[p] < 0.999 {
                        return f32::NAN;
                    }
                    let zd = cfg.depth_source.degrade(z[p], seed, v as u64, p as u64);
                    let d = view.camera.distance_from_z_depth((p % w) as f64 + 0.5, (p / w) as f64 + 0.5, zd as f64);
                    clamp_target(d, near, far)
                })
                .collect::<Vec<f32>>();
            if cfg.uses_normals() {
                if normal.len() != 3 * depth.len() {
                    return Err(DataError::Invalid(format!("train view {}: {} ground-truth normal values for {} pixels", f.name, normal.len(), depth.len())));
                }
                normals.push(
                    normal
                        .chunks_exact(3)
                        .zip(&depth)
                        .map(|(n, d)| {
                            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                            if d.is_finite() && len.is_finite() && len > 0.5 { [n[0] / len, n[1] / len, n[2] / len] } else { [f32::NAN; 3] }
                        })
                        .collect(),
                );
            }
            depths.push(depth);
            empties.push(alpha.iter().map(|&a| a == 0.0).collect());
        }
        self.supervision = Some((cfg.clone(), depths, empties, normals));
        Ok(())
    }

    /// The depth targets per view and pixel ([`Self::set_supervision`]), for tests that plant
    /// faults in them; `None` without supervision.
    pub fn depth_targets_mut(&mut self) -> Option<&mut Vec<Vec<f32>>> {
        self.supervision.as_mut().map(|s| &mut s.1)
    }

    /// Total pixels over all views.
    pub fn total_pixels(&self) -> usize {
        self.cumulative.last().copied().unwrap_or(0)
    }

    /// (view, pixel) of a global pixel index.
    pub fn locate(&self, global: usize) -> (usize, usize) {
        let v = self.cumulative.partition_point(|c| *c <= global) - 1;
        (v, global - self.cumulative[v])
    }

    /// The batch of step `step`: `n` pixels drawn uniformly over all training pixels, a pure
    /// function of (seed, step), so a resumed run sees the same batches.
    pub fn batch(&self, seed: u64, step: u64, n: usize) -> RayBatch {
        use rayon::prelude::*;
        let total = self.total_pixels() as u64;
        // Each ray depends only on (seed, step, k), drawn in parallel. Three passes: the
        // pixels and backgrounds; their colours, a tight loop of independent loads that keeps
        // many of its cache misses into the views' pixels in flight at once (interleaved with
        // each ray's camera arithmetic they came one or two at a time, and took most of the
        // batch's time); the camera rays.
        let drawn: Vec<(usize, usize, [f32; 3])> = (0..n)
            .into_par_iter()
            .with_min_len(256)
            .map(|k| {
                let k = k as u64;
                let u = (uniform(seed, stream::PIXEL, step, k) as f64 + uniform(seed, stream::PIXEL, step, k + (1 << 40)) as f64 / (1u64 << 24) as f64).min(0.999_999_999);
                let g = ((u * total as f64) as u64).min(total - 1) as usize;
                let (v, p) = self.locate(g);
                let bg = match self.background {
                    Background::Random => [0, 1, 2].map(|c| uniform(seed, stream::BACKGROUND, step, k * 3 + c)),
                    other => other.eval_color(),
                };
                (v, p, bg)
            })
            .collect();
        let target: Vec<[f32; 3]> = drawn.par_iter().with_min_len(256).map(|&(v, p, bg)| self.views[v].color(p, bg)).collect();
        let (origins, dirs): (Vec<[f32; 3]>, Vec<[f32; 3]>) = drawn.par_iter().with_min_len(256).map(|&(v, p, _)| pixel_ray(&self.views[v].camera, p)).unzip();
        let mut b = RayBatch {
            origins,
            dirs,
            target,
            background: drawn.iter().map(|d| d.2).collect(),
            ids: drawn.iter().map(|&(v, p, _)| ((v as u64) << 32) | p as u64).collect(),
            mixed: Vec::new(),
            supervision: None,
        };
        if self.has_mixed() {
            b.mixed = b.ids.iter().map(|id| self.mixed[(id >> 32) as usize][(id & 0xffff_ffff) as usize]).collect();
        }
        if let Some((cfg, depths, empties, normals)) = &self.supervision {
            let at = |id: &u64| ((id >> 32) as usize, (id & 0xffff_ffff) as usize);
            b.supervision = Some(RaySupervision {
                depth_loss: cfg.depth_loss,
                depth_weight: cfg.depth_weight_at(step),
                empty_weight: cfg.empty_weight,
                depth: b.ids.iter().map(|id| at(id)).map(|(v, p)| depths[v][p]).collect(),
                empty: b.ids.iter().map(|id| at(id)).map(|(v, p)| empties[v][p]).collect(),
                normal_weight: cfg.normal_weight,
                normal: if normals.is_empty() { Vec::new() } else { b.ids.iter().map(|id| at(id)).map(|(v, p)| normals[v][p]).collect() },
            });
        }
        b
    }
}

/// Where a model looks for the scene: an axis-aligned box and the near/far range along rays.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SceneBounds {
    /// Box minimum corner (world).
    pub aabb_min: [f32; 3],
    /// Box maximum corner (world).
    pub aabb_max: [f32; 3],
    /// Nearest distance along rays.
    pub near: f32,
    /// Farthest distance along rays.
    pub far: f32,
    /// Where the numbers came from, for the config file's reader.
    pub source: String,
}

impl SceneBounds {
    /// Refuses bounds no model can use (the config file may come from a user): a box with a
    /// non-finite corner or a side that is not positive, or a near/far range that is not
    /// finite with `0 ≤ near < far`. The error names where the bounds came from (`source`):
    /// bounds derived from a dataset's cameras fail when the cameras are placed absurdly (one
    /// at 10³⁰ m puts their common look-at point where `f32` cannot hold a box of the assumed
    /// radius).
    pub fn check(&self) -> Result<(), String> {
        for k in 0..3 {
            let (lo, hi) = (self.aabb_min[k], self.aabb_max[k]);
            if !(lo.is_finite() && hi.is_finite() && lo < hi && (hi - lo).is_finite()) {
                return Err(format!(
                    "bounds (from {}): the box must have finite corners with aabb_min < aabb_max on every axis, not {lo} .. {hi} on axis {k}",
                    self.source
                ));
            }
        }
        if !(self.near.is_finite() && self.far.is_finite() && self.near >= 0.0 && self.near < self.far) {
            return Err(format!("bounds (from {}): need finite 0 ≤ near < far, not near {} far {}", self.source, self.near, self.far));
        }
        Ok(())
    }

    /// Centre of the box.
    pub fn center(&self) -> [f32; 3] {
        [0, 1, 2].map(|k| 0.5 * (self.aabb_min[k] + self.aabb_max[k]))
    }
    /// Half the largest side: the box is treated as the cube of this half-extent around its
    /// centre when positions are normalised.
    pub fn half_extent(&self) -> f32 {
        (0..3).map(|k| 0.5 * (self.aabb_max[k] - self.aabb_min[k])).fold(0.0, f32::max)
    }
    /// A position mapped to [0, 1]³ over the bounding cube.
    pub fn to_unit(&self, p: [f32; 3]) -> [f32; 3] {
        let (c, h) = (self.center(), self.half_extent());
        [0, 1, 2].map(|k| (p[k] - c[k]) / (2.0 * h) + 0.5)
    }
    /// The bounding cube's corners.
    pub fn cube(&self) -> ([f32; 3], [f32; 3]) {
        let (c, h) = (self.center(), self.half_extent());
        (c.map(|v| v - h), c.map(|v| v + h))
    }

    /// Bounds from the dataset's scene facts (box padded by `padding` of its size on each side,
    /// near/far as suggested) or, without facts, from the cameras: see [`Self::from_cameras`].
    pub fn for_dataset(facts: Option<&SceneFacts>, cameras: &[Camera], padding: f32, assumed_radius: f32) -> Self {
        match facts {
            Some(f) => {
                let size: Vec<f32> = (0..3).map(|k| (f.aabb_max[k] - f.aabb_min[k]) as f32).collect();
                let pad = size.iter().fold(0.0f32, |a, b| a.max(*b)) * padding;
                Self {
                    aabb_min: [0, 1, 2].map(|k| f.aabb_min[k] as f32 - pad),
                    aabb_max: [0, 1, 2].map(|k| f.aabb_max[k] as f32 + pad),
                    near: (f.near as f32 * 0.9).max(1e-3),
                    far: f.far as f32 * 1.1,
                    source: format!("scene facts (box padded by {padding} of its largest side, near ×0.9, far ×1.1)"),
                }
            }
            None => Self::from_cameras(cameras, assumed_radius),
        }
    }

    /// Bounds for a dataset without scene facts: the scene is assumed to lie within
    /// `radius` of the point all cameras look at (the least-squares closest point to their
    /// optical axes); near = (min camera distance to it) − radius, far = (max distance) +
    /// radius, and the box is the cube of half-extent `radius` around it. For the Blender
    /// synthetic scenes (cameras 4.03 from the origin, objects inside [−1, 1]³, radius √3 as
    /// the half-diagonal of that cube) this gives near ≈ 2.3, far ≈ 5.8, close to the official
    /// 2 and 6.
    pub fn from_cameras(cameras: &[Camera], radius: f32) -> Self {
        // Solve Σ (I − d dᵀ) p = Σ (I − d dᵀ) o.
        let mut a = glam::DMat3::ZERO;
        let mut b = DVec3::ZERO;
        for c in cameras {
            let o = c.origin();
            let d = -c.c2w.z_axis.truncate().normalize();
            let m = glam::DMat3::IDENTITY - glam::DMat3::from_cols(d * d.x, d * d.y, d * d.z);
            a += m;
            b += m * o;
        }
        let centre = if a.determinant().abs() > 1e-9 {
            a.inverse() * b
        } else {
            // All axes parallel: fall back to the mean of the cameras' look-at points at unit distance.
            cameras.iter().map(|c| c.origin() - c.c2w.z_axis.truncate()).sum::<DVec3>() / cameras.len().max(1) as f64
        };
        let dists: Vec<f64> = cameras.iter().map(|c| (c.origin() - centre).length()).collect();
        let dmin = dists.iter().copied().fold(f64::INFINITY, f64::min) as f32;
        let dmax = dists.iter().copied().fold(0.0, f64::max) as f32;
        let c = centre.as_vec3().to_array();
        Self {
            aabb_min: c.map(|v| v - radius),
            aabb_max: c.map(|v| v + radius),
            near: (dmin - radius).max(0.05 * dmin).max(1e-3),
            far: dmax + radius,
            source: format!("cameras (no scene facts): scene assumed within {radius} of the point the cameras look at"),
        }
    }
}

/// Loads a dataset folder (our layout or the Blender-synthetic one) with `options` (whether
/// frame files may lie outside the folder).
pub fn load_dataset(dir: &Path, options: &dataset::LoadOptions) -> Result<Dataset, DataError> {
    Ok(Dataset::load_with(dir, options)?)
}

/// A small analytic scene written as a dataset, for tests and benchmarks that need no prior
/// rendering step: three diffuse spheres lit by a fixed directional light, seen from cameras
/// on a sphere of radius 4 (Blender's field of view), transparent background, exact depth and normals.
pub mod synthetic {
    use dataset::{Camera, FrameRecord, GroundTruth, Intrinsics, RgbaImage, SceneFacts, SplitKind};
    use glam::DVec3;
    use std::path::Path;

    const SPHERES: [([f64; 3], f64, [f64; 3]); 3] = [
        ([0.0, 0.0, 0.0], 0.6, [0.85, 0.25, 0.2]),
        ([0.7, 0.3, 0.4], 0.35, [0.2, 0.7, 0.3]),
        ([-0.5, -0.2, 0.6], 0.3, [0.2, 0.35, 0.9]),
    ];

    /// Nearest hit along the ray and its colour: diffuse shading under one distant light,
    /// plus, with `gloss` > 0, a white Fresnel-like sheen `gloss (1 − n·v)²` that brightens
    /// towards grazing views, so every point's colour changes with the view; and the sphere's
    /// outward unit normal there.
    fn trace(o: DVec3, d: DVec3, gloss: f64) -> Option<(f64, [f64; 3], DVec3)> {
        let light = DVec3::new(0.5, 0.8, 0.3).normalize();
        let mut best: Option<(f64, [f64; 3], DVec3)> = None;
        for (c, r, albedo) in SPHERES {
            let oc = o - DVec3::from(c);
            let b = oc.dot(d);
            let disc = b * b - (oc.length_squared() - r * r);
            if disc < 0.0 {
                continue;
            }
            let t = -b - disc.sqrt();
            if t > 1e-6 && best.is_none_or(|(bt, _, _)| t < bt) {
                let n = (o + d * t - DVec3::from(c)) / r;
                let shade = 0.35 + 0.65 * n.dot(light).max(0.0);
                let spec = gloss * (1.0 - n.dot(-d).clamp(0.0, 1.0)).powi(2);
                best = Some((t, albedo.map(|a| (a * shade + spec).min(1.0)), n));
            }
        }
        best
    }

    /// Camera `k` of `n`, on a Fibonacci spiral over the sphere of radius 4 (`phase` shifts
    /// the spiral so splits do not share views).
    fn camera(k: usize, n: usize, phase: f64, size: u32) -> Camera {
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let y = 0.9 - 1.6 * (k as f64 + 0.5) / n as f64;
        let r = (1.0 - y * y).sqrt();
        let a = golden * k as f64 + phase;
        let eye = DVec3::new(r * a.cos(), y, r * a.sin()) * 4.0;
        Camera::new(Intrinsics::from_fov_x(size, size, 0.6911), Camera::look_at(eye, DVec3::ZERO, DVec3::Y))
            .unwrap_or_else(|e| unreachable!("{e}"))
    }

    /// Writes the dataset: `train` / `val` / `test` views of `size`² pixels, with PNGs (2×2
    /// supersampled colour, straight alpha), ground-truth EXRs and scene facts. With
    /// `blender_layout` only `camera_angle_x`, file paths and poses are written (no
    /// intrinsics keys, ground truth or facts), as in the original Blender synthetic folders.
    pub fn write(dir: &Path, size: u32, counts: [usize; 3], blender_layout: bool) -> Result<(), dataset::DatasetError> {
        write_glossy(dir, size, counts, blender_layout, 0.0)
    }

    /// [`write()`] with a white sheen of strength `gloss` on every sphere (view-dependent
    /// colour when `gloss` > 0; the facts say so).
    pub fn write_glossy(dir: &Path, size: u32, counts: [usize; 3], blender_layout: bool, gloss: f64) -> Result<(), dataset::DatasetError> {
        let intr = Intrinsics::from_fov_x(size, size, 0.6911);
        let (mut near, mut far) = (f64::INFINITY, 0.0f64);
        let mut splits = Vec::new();
        for (si, split) in SplitKind::ALL.into_iter().enumerate() {
            let mut recs = Vec::new();
            for k in 0..counts[si] {
                let cam = camera(k, counts[si], si as f64 * 0.9, size);
                let mut img = RgbaImage::new(size, size);
                let n = (size * size) as usize;
                let mut gt = GroundTruth {
                    width: size,
                    height: size,
                    depth: vec![0.0; n],
                    distance: vec![0.0; n],
                    normal: vec![0.0; 3 * n],
                    alpha: vec![0.0; n],
                };
                for j in 0..size {
                    for i in 0..size {
                        let p = (j * size + i) as usize;
                        let mut acc = [0.0f64; 4];
                        for (sx, sy) in [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)] {
                            let ray = cam.pixel_ray(i as f64 + sx, j as f64 + sy);
                            if let Some((_, c, _)) = trace(ray.origin, ray.direction, gloss) {
                                for ch in 0..3 {
                                    acc[ch] += c[ch];
                                }
                                acc[3] += 1.0;
                            }
                        }
                        let a = acc[3] / 4.0;
                        for ch in 0..3 {
                            img.data[4 * p + ch] = if acc[3] > 0.0 { (acc[ch] / acc[3]) as f32 } else { 0.0 };
                        }
                        img.data[4 * p + 3] = a as f32;
                        let ray = cam.pixel_center_ray(i, j);
                        if let Some((t, _, nrm)) = trace(ray.origin, ray.direction, gloss) {
                            gt.distance[p] = t as f32;
                            gt.normal[3 * p..3 * p + 3].copy_from_slice(&[nrm.x as f32, nrm.y as f32, nrm.z as f32]);
                            gt.depth[p] = cam.z_depth_from_distance(i as f64 + 0.5, j as f64 + 0.5, t) as f32;
                            gt.alpha[p] = 1.0;
                            near = near.min(t);
                            far = far.max(t);
                        }
                    }
                }
                let name = format!("r_{k}");
                dataset::write_png_rgba(&dir.join(split.name()).join(format!("{name}.png")), &img)?;
                let gt_rel = format!("./{}/{name}_gt.exr", split.name());
                if !blender_layout {
                    dataset::write_ground_truth(&dir.join(&gt_rel[2..]), &gt)?;
                }
                recs.push(FrameRecord {
                    file_path: format!("./{}/{name}", split.name()),
                    transform_matrix: cam.rows(),
                    depth_file_path: None,
                    gt_file_path: (!blender_layout).then_some(gt_rel),
                    exr_file_path: None,
                });
            }
            splits.push((split, recs));
        }
        let facts = SceneFacts {
            scene: "synthetic-spheres".into(),
            aabb_min: [-0.8, -0.6, -0.6],
            aabb_max: [1.05, 0.65, 0.95],
            near: near * 0.9,
            far: far * 1.1 + 1.0,
            view_dependent: gloss > 0.0,
            render: serde_json::json!({"analytic": true}),
            renderer: "nerf::data::synthetic".into(),
            objects: vec![],
            materials: vec![],
        };
        for (split, recs) in splits {
            if blender_layout {
                let json = serde_json::json!({
                    "camera_angle_x": intr.camera_angle_x(),
                    "frames": recs.iter().map(|r| serde_json::json!({"file_path": r.file_path, "transform_matrix": r.transform_matrix})).collect::<Vec<_>>(),
                });
                dataset::io::atomic_write_json(&dir.join(split.file_name()), &json)?;
            } else {
                dataset::write_split_transforms(dir, split, &intr, recs, Some(facts.clone()))?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Z-depth of a `w × h` pinhole view (focal `f` pixels, centred) of the plane through
    /// (0, 0, −d) whose normal leans `tilt` radians from the optical axis towards +x.
    fn tilted_plane(w: usize, h: usize, f: f64, d: f64, tilt: f64) -> Vec<f32> {
        let (s, c) = tilt.sin_cos();
        let mut z = vec![0.0; w * h];
        for j in 0..h {
            for i in 0..w {
                // Ray (x, y, −1)·t meets n·p = −d c with n = (s, 0, c): t (s x − c) = −d c.
                let x = (i as f64 + 0.5 - w as f64 / 2.0) / f;
                z[j * w + i] = (d * c / (c - s * x)) as f32;
            }
        }
        z
    }

    #[test]
    fn mixed_pixels_are_depth_edges_and_partial_alpha_but_not_steep_planes() {
        let (w, h, f) = (32, 16, 80.0);
        let opaque = vec![1.0f32; w * h];
        // A plane at 60° incidence: neighbouring depths differ by tan 60° · z / d footprints,
        // z / d from 0.75 to 1.5 across this view, so a neighbourhood spans 2.6 to 5.2
        // footprints: no mixed pixel at 16 footprints; at 2 every interior pixel is.
        let plane = tilted_plane(w, h, f, 2.0, 60f64.to_radians());
        assert!(plane.iter().all(|z| *z > 1.45 && *z < 3.05));
        assert!(!mixed_pixels(w, h, &opaque, Some(&plane), f, 16.0).iter().any(|m| *m));
        let interior = |m: &[bool]| (1..h - 1).all(|j| (1..w - 1).all(|i| m[j * w + i]));
        assert!(interior(&mixed_pixels(w, h, &opaque, Some(&plane), f, 2.0)));
        assert!(!mixed_pixels(w, h, &opaque, Some(&plane), f, 6.0).iter().any(|m| *m));

        // A one-pixel vertical wire at depth 1 in front of a wall at depth 2: the wire's
        // column and its two neighbours are mixed, nothing else.
        let mut wall = vec![2.0f32; w * h];
        for j in 0..h {
            wall[j * w + 10] = 1.0;
        }
        let m = mixed_pixels(w, h, &opaque, Some(&wall), f, 16.0);
        for j in 0..h {
            for i in 0..w {
                assert_eq!(m[j * w + i], (9..=11).contains(&i), "pixel ({i}, {j})");
            }
        }
        // The same wall with a miss (depth 0) or NaN next to it: misses are not surfaces.
        let mut holes = vec![2.0f32; w * h];
        holes[5] = 0.0;
        holes[w + 20] = f32::NAN;
        assert!(!mixed_pixels(w, h, &opaque, Some(&holes), f, 16.0).iter().any(|m| *m));

        // Without depth, partial alpha alone: a silhouette pixel is mixed, covered and empty
        // ones are not.
        let mut alpha = vec![0.0f32; w * h];
        alpha[3] = 0.5;
        alpha[4] = 1.0;
        alpha[5] = 0.99;
        alpha[6] = 0.01;
        let m = mixed_pixels(w, h, &alpha, None, f, 16.0);
        assert_eq!(m.iter().enumerate().filter(|(_, m)| **m).map(|(k, _)| k).collect::<Vec<_>>(), vec![3]);
        assert!((mixed_share(&[alpha], &[m]) - 1.0 / 3.0).abs() < 1e-12, "3 covered pixels, 1 mixed");
        // Slices of the wrong length add nothing and do not panic.
        assert!(!mixed_pixels(w, h, &[0.5; 3], Some(&[1.0; 3]), f, 16.0).iter().any(|m| *m));
    }

    /// Bounds derived from cameras placed absurdly (one 10³⁰ m away) are refused, and the error
    /// says they came from the cameras, not from a file the user wrote.
    #[test]
    fn absurd_camera_positions_give_bounds_that_are_refused_naming_the_cameras() {
        let intr = dataset::Intrinsics::from_fov_x(16, 16, 0.7);
        let at = |x: f64| Camera::new(intr, Camera::look_at(DVec3::new(x, 0.0, 4.0), DVec3::ZERO, DVec3::Y)).unwrap();
        let sane = [at(0.0), at(2.0), at(-2.0)];
        assert!(SceneBounds::from_cameras(&sane, 1.0).check().is_ok());
        // The first camera moved 10³⁰ m along x, looking the same way.
        let mut far = at(0.0);
        far.c2w.w_axis.x = 1e30;
        let err = SceneBounds::from_cameras(&[at(0.0), at(2.0), far], 1.0).check().unwrap_err();
        assert!(err.starts_with("bounds (from cameras (no scene facts)"), "{err}");
    }
}
