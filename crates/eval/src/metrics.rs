//! Ground-truth metrics: small pure functions over flat `f32` slices, computed in `f64`.
//!
//! Images are row-major `H x W x C` (row 0 on top), colour is display colour in `[0, 1]`,
//! depth is z-depth in scene units (see the dataset crate's conventions). Every function
//! checks the lengths of its inputs and returns a [`MetricError`] instead of panicking.
//!
//! Foreground: a pixel (or ray) counts as foreground when its ground-truth alpha is at
//! least [`FOREGROUND_ALPHA`] (`0.999`), i.e. its centre ray hits geometry. The renderer
//! writes alpha at the pixel centre ray exactly (0 or 1), so the threshold only guards
//! against rounding in files; partially covered pixels never enter depth metrics.

use crate::error::MetricError;

/// Ground-truth alpha at or above which a pixel is foreground for depth and surface metrics.
pub const FOREGROUND_ALPHA: f32 = 0.999;

/// SSIM constant `K1` (Wang et al. 2004).
pub const SSIM_K1: f64 = 0.01;
/// SSIM constant `K2` (Wang et al. 2004).
pub const SSIM_K2: f64 = 0.03;
/// Standard deviation of the SSIM Gaussian window, in pixels.
pub const SSIM_SIGMA: f64 = 1.5;
/// The Gaussian is truncated at this many standard deviations (scikit-image passes 3.5).
pub const SSIM_TRUNCATE: f64 = 3.5;

fn check_len(what: &'static str, expected: usize, got: usize) -> Result<(), MetricError> {
    if expected == got {
        Ok(())
    } else {
        Err(MetricError::Length { what, expected, got })
    }
}

/// Mean squared error over all values (all pixels and channels).
///
/// `MSE = (1/N) Σ_i (pred_i − gt_i)²`
///
/// # Shapes
/// `pred`, `gt`: `[N]` (any layout, the same for both).
pub fn mse(pred: &[f32], gt: &[f32]) -> Result<f64, MetricError> {
    check_len("gt", pred.len(), gt.len())?;
    if pred.is_empty() {
        return Err(MetricError::Empty("mse"));
    }
    let sum: f64 = pred
        .iter()
        .zip(gt)
        .map(|(&p, &g)| {
            let d = f64::from(p) - f64::from(g);
            d * d
        })
        .sum();
    Ok(sum / pred.len() as f64)
}

/// Peak signal-to-noise ratio of display colour with peak 1, in dB.
///
/// `PSNR = 10 log10(1 / MSE) = −10 log10(MSE)`, MSE over all pixels and channels
/// (see [`mse`]). Identical images have MSE 0 and PSNR `+∞` (returned as
/// `f64::INFINITY`; no cap). The report serialises a non-finite PSNR as the JSON
/// string `"inf"` because JSON numbers cannot hold infinity.
///
/// Example: every value off by 0.1 gives MSE 0.01 and PSNR 20 dB.
///
/// # Shapes
/// `pred`, `gt`: `[H * W * C]`, values in `[0, 1]`.
pub fn psnr(pred: &[f32], gt: &[f32]) -> Result<f64, MetricError> {
    let m = mse(pred, gt)?;
    if m == 0.0 {
        Ok(f64::INFINITY)
    } else {
        Ok(-10.0 * m.log10())
    }
}

/// Normalised 1-D Gaussian taps as `scipy.ndimage.gaussian_filter` builds them:
/// radius `r = int(truncate * sigma + 0.5)`, taps `exp(−x² / (2σ²))` for `x = −r..=r`,
/// divided by their sum. For σ = 1.5, truncate = 3.5: r = 5, 11 taps.
///
/// # Shapes
/// returns `[2r + 1]`.
pub fn gaussian_kernel(sigma: f64, truncate: f64) -> Vec<f64> {
    let radius = (truncate * sigma + 0.5) as i64;
    let taps: Vec<f64> = (-radius..=radius)
        .map(|x| (-0.5 * (x * x) as f64 / (sigma * sigma)).exp())
        .collect();
    let sum: f64 = taps.iter().sum();
    taps.into_iter().map(|v| v / sum).collect()
}

/// Index into `0..n` for position `i` under scipy's `mode='reflect'`
/// (`d c b a | a b c d | d c b a`: the edge value is repeated), periodic with period `2n`.
/// `n` must be at least 1.
pub fn reflect_index(i: isize, n: usize) -> usize {
    let period = 2 * n as isize;
    let k = i.rem_euclid(period);
    if k >= n as isize {
        (period - 1 - k) as usize
    } else {
        k as usize
    }
}

/// Separable correlation of a single-channel image with `kernel` along rows and then
/// columns, scipy `reflect` boundary (as `scipy.ndimage.gaussian_filter` on a 2-D array).
///
/// `out[y][x] = Σ_j k_j Σ_i k_i img[reflect(y + j − r)][reflect(x + i − r)]`
///
/// # Shapes
/// `img`: `[H * W]`, `kernel`: `[2r + 1]`; returns `[H * W]`.
pub fn filter_separable(img: &[f64], width: usize, height: usize, kernel: &[f64]) -> Vec<f64> {
    let r = (kernel.len() / 2) as isize;
    // scipy filters axis 0 (vertical) first, then axis 1. Vertical pass: whole rows at a time.
    let mut tmp = vec![0.0; width * height];
    for y in 0..height {
        let out_row = &mut tmp[y * width..(y + 1) * width];
        for (j, k) in kernel.iter().enumerate() {
            let yy = reflect_index(y as isize + j as isize - r, height);
            let src = &img[yy * width..(yy + 1) * width];
            for (o, v) in out_row.iter_mut().zip(src) {
                *o += k * v;
            }
        }
    }
    // Horizontal pass over a reflect-padded copy of each row.
    let mut out = vec![0.0; width * height];
    let mut padded = vec![0.0; width + 2 * r as usize];
    for y in 0..height {
        let row = &tmp[y * width..(y + 1) * width];
        for (i, p) in padded.iter_mut().enumerate() {
            *p = row[reflect_index(i as isize - r, width)];
        }
        let out_row = &mut out[y * width..(y + 1) * width];
        for (i, k) in kernel.iter().enumerate() {
            for (o, v) in out_row.iter_mut().zip(&padded[i..i + width]) {
                *o += k * v;
            }
        }
    }
    out
}

/// SSIM of one channel: the sum of the SSIM map over the interior positions `keep` accepts
/// (row, column) and their count, see [`ssim`].
fn ssim_channel(x: &[f64], y: &[f64], width: usize, height: usize, kernel: &[f64], keep: &(dyn Fn(usize, usize) -> bool + Sync)) -> (f64, usize) {
    let c1 = SSIM_K1 * SSIM_K1;
    let c2 = SSIM_K2 * SSIM_K2;
    let pad = (kernel.len() - 1) / 2;
    let xx: Vec<f64> = x.iter().map(|v| v * v).collect();
    let yy: Vec<f64> = y.iter().map(|v| v * v).collect();
    let xy: Vec<f64> = x.iter().zip(y).map(|(a, b)| a * b).collect();
    let ux = filter_separable(x, width, height, kernel);
    let uy = filter_separable(y, width, height, kernel);
    let uxx = filter_separable(&xx, width, height, kernel);
    let uyy = filter_separable(&yy, width, height, kernel);
    let uxy = filter_separable(&xy, width, height, kernel);
    let mut sum = 0.0;
    let mut count = 0usize;
    for row in pad..height - pad {
        for col in pad..width - pad {
            if !keep(row, col) {
                continue;
            }
            let i = row * width + col;
            let vx = uxx[i] - ux[i] * ux[i];
            let vy = uyy[i] - uy[i] * uy[i];
            let vxy = uxy[i] - ux[i] * uy[i];
            let a1 = 2.0 * ux[i] * uy[i] + c1;
            let a2 = 2.0 * vxy + c2;
            let b1 = ux[i] * ux[i] + uy[i] * uy[i] + c1;
            let b2 = vx + vy + c2;
            sum += (a1 * a2) / (b1 * b2);
            count += 1;
        }
    }
    (sum, count)
}

/// Structural similarity (Wang et al. 2004), exactly as scikit-image computes
/// `structural_similarity(pred, gt, gaussian_weights=True, sigma=1.5,
/// use_sample_covariance=False, data_range=1, channel_axis=-1)`.
///
/// Per channel, with `G*` the Gaussian filter of [`gaussian_kernel`]`(1.5, 3.5)`
/// (11x11, scipy `reflect` boundary, see [`filter_separable`]):
/// `μx = G*x`, `μy = G*y`, `σx² = G*(x²) − μx²`, `σy² = G*(y²) − μy²`, `σxy = G*(xy) − μx μy`,
/// `C1 = (K1 L)²`, `C2 = (K2 L)²` with `K1 = 0.01`, `K2 = 0.03`, `L = 1`;
/// `S = (2 μx μy + C1)(2 σxy + C2) / ((μx² + μy² + C1)(σx² + σy² + C2))`.
/// The SSIM of a channel is the mean of `S` over the interior that skimage keeps after
/// cropping `pad = (11 − 1) / 2 = 5` pixels from each side; the result is the mean over
/// channels. Identical images give exactly 1.
///
/// # Shapes
/// `pred`, `gt`: `[H * W * C]` row-major, channels last; `H, W >= 11`.
pub fn ssim(
    pred: &[f32],
    gt: &[f32],
    width: usize,
    height: usize,
    channels: usize,
) -> Result<f64, MetricError> {
    let n = width * height * channels;
    if n == 0 {
        return Err(MetricError::Empty("ssim"));
    }
    check_len("pred", n, pred.len())?;
    check_len("gt", n, gt.len())?;
    let kernel = gaussian_kernel(SSIM_SIGMA, SSIM_TRUNCATE);
    let win = kernel.len();
    if width < win || height < win {
        return Err(MetricError::TooSmall { width, height, window: win });
    }
    let per_channel = ssim_channels(pred, gt, width, height, channels, &kernel, &|_, _| true);
    let total: f64 = per_channel.iter().map(|(s, n)| s / *n as f64).sum();
    Ok(total / channels as f64)
}

/// Each channel's SSIM map sum and count over the interior positions `keep` accepts.
/// Channels are independent: they are computed on scoped threads and returned in channel
/// order, so the result is the same whatever the thread count.
fn ssim_channels(
    pred: &[f32],
    gt: &[f32],
    width: usize,
    height: usize,
    channels: usize,
    kernel: &[f64],
    keep: &(dyn Fn(usize, usize) -> bool + Sync),
) -> Vec<(f64, usize)> {
    std::thread::scope(|scope| {
        let handles: Vec<_> = (0..channels)
            .map(|c| {
                scope.spawn(move || {
                    let x: Vec<f64> = (0..width * height).map(|i| f64::from(pred[i * channels + c])).collect();
                    let y: Vec<f64> = (0..width * height).map(|i| f64::from(gt[i * channels + c])).collect();
                    ssim_channel(&x, &y, width, height, kernel, keep)
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap_or((f64::NAN, 1))).collect()
    })
}

/// [`ssim`] over the pixels `valid` marks: a pixel that is not valid (e.g. a non-finite
/// prediction) is replaced by the ground truth for filtering, and every position of the SSIM
/// map whose 11x11 window touches one is left out of the mean. With every pixel valid this is
/// [`ssim`] exactly. An [`MetricError::EmptyMask`] when no window is free of invalid pixels.
///
/// # Shapes
/// `pred`, `gt`: `[H * W * C]`; `valid`: `[H * W]`.
pub fn ssim_masked(
    pred: &[f32],
    gt: &[f32],
    width: usize,
    height: usize,
    channels: usize,
    valid: &[bool],
) -> Result<f64, MetricError> {
    let n = width * height * channels;
    if n == 0 {
        return Err(MetricError::Empty("ssim"));
    }
    check_len("pred", n, pred.len())?;
    check_len("gt", n, gt.len())?;
    check_len("valid", width * height, valid.len())?;
    let kernel = gaussian_kernel(SSIM_SIGMA, SSIM_TRUNCATE);
    let win = kernel.len();
    if width < win || height < win {
        return Err(MetricError::TooSmall { width, height, window: win });
    }
    let filled: Vec<f32> = pred.iter().zip(gt).enumerate().map(|(i, (&p, &g))| if valid[i / channels] { p } else { g }).collect();
    // Invalid pixels above and left of each position, for a window's count in four lookups.
    let (w1, r) = (width + 1, win / 2);
    let mut sat = vec![0usize; w1 * (height + 1)];
    for y in 0..height {
        for x in 0..width {
            sat[(y + 1) * w1 + x + 1] = sat[y * w1 + x + 1] + sat[(y + 1) * w1 + x] - sat[y * w1 + x] + usize::from(!valid[y * width + x]);
        }
    }
    let keep = |row: usize, col: usize| {
        let (y0, y1, x0, x1) = (row - r, row + r + 1, col - r, col + r + 1);
        sat[y1 * w1 + x1] + sat[y0 * w1 + x0] - sat[y0 * w1 + x1] - sat[y1 * w1 + x0] == 0
    };
    let per_channel = ssim_channels(&filled, gt, width, height, channels, &kernel, &keep);
    if per_channel.iter().any(|(_, n)| *n == 0) {
        return Err(MetricError::EmptyMask("ssim"));
    }
    let total: f64 = per_channel.iter().map(|(s, n)| s / *n as f64).sum();
    Ok(total / channels as f64)
}

/// Foreground `(pred, gt)` depth pairs: ground-truth alpha `>= FOREGROUND_ALPHA` and a finite
/// ground-truth depth `> 0`.
fn depth_pairs(
    pred: &[f32],
    gt: &[f32],
    gt_alpha: &[f32],
    what: &'static str,
) -> Result<Vec<(f64, f64)>, MetricError> {
    check_len("gt depth", pred.len(), gt.len())?;
    check_len("gt alpha", pred.len(), gt_alpha.len())?;
    let pairs: Vec<(f64, f64)> = pred
        .iter()
        .zip(gt)
        .zip(gt_alpha)
        .filter(|&((_, &g), &a)| a >= FOREGROUND_ALPHA && g.is_finite() && g > 0.0)
        .map(|((&d, &g), _)| (f64::from(d), f64::from(g)))
        .collect();
    if pairs.is_empty() {
        return Err(MetricError::EmptyMask(what));
    }
    Ok(pairs)
}

/// Depth metrics of one view over foreground pixels, all on z-depth in scene units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthMetrics {
    /// Mean absolute error, see [`depth_mae`].
    pub mae: f64,
    /// Root-mean-square error, see [`depth_rmse`].
    pub rmse: f64,
    /// Mean absolute relative error, see [`depth_abs_rel`].
    pub abs_rel: f64,
    /// Fraction within a ratio of 1.25, see [`depth_delta`].
    pub delta_1_25: f64,
    /// Fraction within a ratio of 1.01, see [`depth_delta`].
    pub delta_1_01: f64,
    /// Number of foreground pixels the means run over.
    pub pixels: usize,
}

/// Mean absolute depth error over foreground pixels: `(1/N) Σ |d − g|`.
///
/// Foreground: ground-truth alpha `>= 0.999` and ground-truth depth `> 0`; `d` predicted and
/// `g` ground-truth z-depth in scene units.
///
/// # Shapes
/// `pred`, `gt`, `gt_alpha`: `[H * W]`.
pub fn depth_mae(pred: &[f32], gt: &[f32], gt_alpha: &[f32]) -> Result<f64, MetricError> {
    let p = depth_pairs(pred, gt, gt_alpha, "depth_mae")?;
    Ok(p.iter().map(|(d, g)| (d - g).abs()).sum::<f64>() / p.len() as f64)
}

/// Root-mean-square depth error over foreground pixels: `sqrt((1/N) Σ (d − g)²)`.
///
/// Foreground as in [`depth_mae`].
///
/// # Shapes
/// `pred`, `gt`, `gt_alpha`: `[H * W]`.
pub fn depth_rmse(pred: &[f32], gt: &[f32], gt_alpha: &[f32]) -> Result<f64, MetricError> {
    let p = depth_pairs(pred, gt, gt_alpha, "depth_rmse")?;
    Ok((p.iter().map(|(d, g)| (d - g) * (d - g)).sum::<f64>() / p.len() as f64).sqrt())
}

/// Mean absolute relative depth error over foreground pixels: `(1/N) Σ |d − g| / g`.
///
/// Foreground as in [`depth_mae`] (so `g > 0`).
///
/// # Shapes
/// `pred`, `gt`, `gt_alpha`: `[H * W]`.
pub fn depth_abs_rel(pred: &[f32], gt: &[f32], gt_alpha: &[f32]) -> Result<f64, MetricError> {
    let p = depth_pairs(pred, gt, gt_alpha, "depth_abs_rel")?;
    Ok(p.iter().map(|(d, g)| (d - g).abs() / g).sum::<f64>() / p.len() as f64)
}

/// Threshold accuracy: the fraction of foreground pixels with `max(d/g, g/d) < threshold`.
///
/// A predicted depth `d <= 0` (or NaN) never passes. Foreground as in [`depth_mae`].
///
/// # Shapes
/// `pred`, `gt`, `gt_alpha`: `[H * W]`.
pub fn depth_delta(
    pred: &[f32],
    gt: &[f32],
    gt_alpha: &[f32],
    threshold: f64,
) -> Result<f64, MetricError> {
    let p = depth_pairs(pred, gt, gt_alpha, "depth_delta")?;
    let pass = p
        .iter()
        .filter(|&&(d, g)| d > 0.0 && (d / g).max(g / d) < threshold)
        .count();
    Ok(pass as f64 / p.len() as f64)
}

/// [`depth_delta`] with threshold 1.25 (the usual `δ < 1.25`).
pub fn depth_delta_1_25(pred: &[f32], gt: &[f32], gt_alpha: &[f32]) -> Result<f64, MetricError> {
    depth_delta(pred, gt, gt_alpha, 1.25)
}

/// [`depth_delta`] with threshold 1.01 (within 1 %).
pub fn depth_delta_1_01(pred: &[f32], gt: &[f32], gt_alpha: &[f32]) -> Result<f64, MetricError> {
    depth_delta(pred, gt, gt_alpha, 1.01)
}

/// All depth metrics at once (one pass over the mask), see [`DepthMetrics`].
///
/// # Shapes
/// `pred`, `gt`, `gt_alpha`: `[H * W]`.
pub fn depth_metrics(pred: &[f32], gt: &[f32], gt_alpha: &[f32]) -> Result<DepthMetrics, MetricError> {
    let p = depth_pairs(pred, gt, gt_alpha, "depth")?;
    let n = p.len() as f64;
    let mut abs = 0.0;
    let mut sq = 0.0;
    let mut rel = 0.0;
    let mut d125 = 0usize;
    let mut d101 = 0usize;
    for &(d, g) in &p {
        let e = (d - g).abs();
        abs += e;
        sq += e * e;
        rel += e / g;
        if d > 0.0 {
            let ratio = (d / g).max(g / d);
            d125 += usize::from(ratio < 1.25);
            d101 += usize::from(ratio < 1.01);
        }
    }
    Ok(DepthMetrics {
        mae: abs / n,
        rmse: (sq / n).sqrt(),
        abs_rel: rel / n,
        delta_1_25: d125 as f64 / n,
        delta_1_01: d101 as f64 / n,
        pixels: p.len(),
    })
}

/// Intersection over union of the predicted mask `opacity > 0.5` and the ground-truth
/// mask `alpha > 0.5`: `|P ∩ G| / |P ∪ G|`. When both masks are empty the masks agree
/// perfectly and the IoU is defined as 1.
///
/// # Shapes
/// `pred_opacity`, `gt_alpha`: `[H * W]`.
pub fn mask_iou(pred_opacity: &[f32], gt_alpha: &[f32]) -> Result<f64, MetricError> {
    check_len("gt alpha", pred_opacity.len(), gt_alpha.len())?;
    let mut inter = 0usize;
    let mut union = 0usize;
    for (&o, &a) in pred_opacity.iter().zip(gt_alpha) {
        let p = o > 0.5;
        let g = a > 0.5;
        inter += usize::from(p && g);
        union += usize::from(p || g);
    }
    if union == 0 {
        Ok(1.0)
    } else {
        Ok(inter as f64 / union as f64)
    }
}

/// Per-ray volume-rendering samples as ragged arrays (nerfacc's packed layout).
///
/// Ray `r` owns samples `offsets[r]..offsets[r + 1]`; `t` are the samples' positions (the
/// interval midpoints, or better where the ray terminates on average within each interval) as
/// **Euclidean distance along the unit ray direction** from the camera centre (convert
/// first if the trainer's ray directions are not unit length), `w` their rendering weights
/// `w_i = T_i (1 − exp(−σ_i δ_i))`. `pixel[r]` is the index `row * W + col` of the pixel
/// whose centre ray is ray `r`, so any subset of a view's pixels may be sampled.
///
/// # Shapes
/// `pixel`: `[R]`, `offsets`: `[R + 1]`, `t`, `w`: `[S]` with `S = offsets[R]`.
#[derive(Debug, Clone, Copy)]
pub struct RaySamples<'a> {
    /// Pixel index of each ray (`row * W + col`).
    pub pixel: &'a [usize],
    /// Start of each ray's samples, plus the total sample count at the end.
    pub offsets: &'a [usize],
    /// Sample distances along the ray.
    pub t: &'a [f32],
    /// Sample rendering weights.
    pub w: &'a [f32],
}

impl RaySamples<'_> {
    /// Number of rays.
    pub fn rays(&self) -> usize {
        self.pixel.len()
    }

    /// Check the ragged layout: `offsets` has `R + 1` entries, starts at 0, never decreases
    /// and ends at `t.len() == w.len()`.
    pub fn validate(&self) -> Result<(), MetricError> {
        check_len("ray offsets", self.pixel.len() + 1, self.offsets.len())?;
        check_len("sample weights", self.t.len(), self.w.len())?;
        if self.offsets[0] != 0 {
            return Err(MetricError::Offsets(format!("offsets[0] is {}, not 0", self.offsets[0])));
        }
        if let Some(r) = self.offsets.windows(2).position(|p| p[1] < p[0]) {
            return Err(MetricError::Offsets(format!("offsets decrease at ray {r}")));
        }
        let last = self.offsets[self.offsets.len() - 1];
        if last != self.t.len() {
            return Err(MetricError::Offsets(format!(
                "last offset is {last} but there are {} samples",
                self.t.len()
            )));
        }
        Ok(())
    }
}

/// Off-surface mass: how much of the rendering weight a NeRF puts away from the true surface.
///
/// For each foreground ray (ground-truth alpha at its pixel `>= 0.999`) with ground-truth
/// surface distance `g` (Euclidean, along the ray, not z-depth):
/// `f_r = Σ_{i : |t_i − g| > tol} w_i / Σ_i w_i`, and the result is the mean of `f_r` over
/// those rays. Rays whose total weight is zero (or not finite) have no rendered mass at all,
/// so the fraction is undefined: they are **excluded** from the mean (missing opacity is
/// what [`mask_iou`] measures). `tol` is in scene units; the report uses 1 % of the scene
/// bounding-box diagonal by default.
///
/// Example: weights 0.8 at the surface and 0.2 on a floater give 0.2; fog of equal weights
/// at evenly spaced samples over `[near, far]` gives `1 − 2 tol / (far − near)`.
///
/// # Shapes
/// `samples`: see [`RaySamples`]; `gt_distance`, `gt_alpha`: `[H * W]` (indexed by `samples.pixel`).
pub fn off_surface_mass(
    samples: &RaySamples<'_>,
    gt_distance: &[f32],
    gt_alpha: &[f32],
    tol: f32,
) -> Result<f64, MetricError> {
    off_surface_split(samples, gt_distance, gt_alpha, tol).map(|s| s.total)
}

/// One ray's fractions of its rendering weight farther than `tol` from the true surface
/// distance `g`, and more than `tol` in front of it (samples `t`, weights `w`); `None` when the
/// ray's total weight is zero or not finite (no rendered mass: excluded, see
/// [`off_surface_mass`]).
pub fn ray_off_surface(t: &[f32], w: &[f32], g: f64, tol: f64) -> Option<(f64, f64)> {
    let (mut total, mut off, mut front) = (0.0, 0.0, 0.0);
    for (&t, &w) in t.iter().zip(w) {
        let w = f64::from(w);
        let d = f64::from(t) - g;
        total += w;
        if d.abs() > tol {
            off += w;
        }
        if d < -tol {
            front += w;
        }
    }
    (total > 0.0 && total.is_finite()).then(|| (off / total, front / total))
}

/// The off-surface mass ([`off_surface_mass`]) and its part in front of the surface.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OffSurface {
    /// Mean over foreground rays of the weight fraction farther than `tol` from the surface.
    pub total: f64,
    /// The same for the weight more than `tol` **in front of** it (`t < g − tol`): floaters
    /// and fog between the camera and the surface. `total − front` lies behind the surface:
    /// a surface too soft or too thin to stop the ray, or one placed too far.
    pub front: f64,
}

/// [`off_surface_mass`] split by where the mass lies: in front of the surface or behind it
/// (same rays, same mean).
///
/// Example: weights 0.1 at `g − 1`, 0.7 at `g` and 0.2 at `g + 1` (tol 0.5) give total 0.3,
/// front 0.1.
pub fn off_surface_split(
    samples: &RaySamples<'_>,
    gt_distance: &[f32],
    gt_alpha: &[f32],
    tol: f32,
) -> Result<OffSurface, MetricError> {
    samples.validate()?;
    check_len("gt alpha", gt_distance.len(), gt_alpha.len())?;
    let tol = f64::from(tol);
    let (mut sum, mut sum_front) = (0.0, 0.0);
    let mut rays = 0usize;
    for (r, &pix) in samples.pixel.iter().enumerate() {
        if pix >= gt_distance.len() {
            return Err(MetricError::Length {
                what: "ray pixel index (must be < H * W)",
                expected: gt_distance.len(),
                got: pix,
            });
        }
        if gt_alpha[pix] < FOREGROUND_ALPHA {
            continue;
        }
        let range = samples.offsets[r]..samples.offsets[r + 1];
        if let Some((off, front)) = ray_off_surface(&samples.t[range.clone()], &samples.w[range], f64::from(gt_distance[pix]), tol) {
            sum += off;
            sum_front += front;
            rays += 1;
        }
    }
    if rays == 0 {
        return Err(MetricError::EmptyMask("off_surface_mass"));
    }
    Ok(OffSurface { total: sum / rays as f64, front: sum_front / rays as f64 })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The deterministic SSIM test pair; the same formula as the Python snippet below.
    fn ssim_pair(h: usize, w: usize, c: usize) -> (Vec<f32>, Vec<f32>) {
        let mut a = Vec::with_capacity(h * w * c);
        let mut b = Vec::with_capacity(h * w * c);
        for y in 0..h {
            for x in 0..w {
                for ch in 0..c {
                    let (x, y, ch) = (x as f64, y as f64, ch as f64);
                    a.push((0.5 + 0.4 * (0.7 * x + 1.3 * y + 0.9 * ch).sin()) as f32);
                    b.push(
                        (0.5 + 0.35 * (0.7 * x + 1.3 * y + 0.9 * ch + 0.3).sin()
                            + 0.1 * (0.37 * x * y + ch).cos()) as f32,
                    );
                }
            }
        }
        (a, b)
    }

    #[test]
    fn psnr_closed_forms() {
        let gt = vec![0.5_f32; 4 * 4 * 3];
        assert_eq!(psnr(&gt, &gt).unwrap(), f64::INFINITY);
        // every value off by 0.1: MSE 0.01 -> 20 dB
        let pred: Vec<f32> = gt.iter().map(|v| v + 0.1).collect();
        assert!((psnr(&pred, &gt).unwrap() - 20.0).abs() < 1e-5);
        // half the values off by 0.2: MSE 0.02 -> 10 log10(50)
        let pred: Vec<f32> =
            gt.iter().enumerate().map(|(i, v)| if i % 2 == 0 { v + 0.2 } else { *v }).collect();
        assert!((psnr(&pred, &gt).unwrap() - 10.0 * 50f64.log10()).abs() < 1e-5);
        assert!(matches!(psnr(&pred[1..], &gt), Err(MetricError::Length { .. })));
        assert!(matches!(psnr(&[], &[]), Err(MetricError::Empty(_))));
    }

    #[test]
    fn gaussian_kernel_matches_scipy_layout() {
        let k = gaussian_kernel(1.5, 3.5);
        assert_eq!(k.len(), 11); // radius int(3.5 * 1.5 + 0.5) = 5
        assert!((k.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        // ratio of neighbouring taps is exp(-(2x+1) / (2 sigma^2))
        assert!((k[6] / k[5] - (-1.0 / 4.5f64).exp()).abs() < 1e-15);
        assert!((k[0] - k[10]).abs() < 1e-18);
    }

    #[test]
    fn reflect_index_is_half_sample_symmetric() {
        // scipy 'reflect' on [a b c]: (c b a | a b c | c b a)
        let got: Vec<usize> = (-3..6).map(|i| reflect_index(i, 3)).collect();
        assert_eq!(got, vec![2, 1, 0, 0, 1, 2, 2, 1, 0]);
        assert_eq!(reflect_index(-1, 1), 0);
        assert_eq!(reflect_index(7, 1), 0);
    }

    #[test]
    fn filter_matches_direct_double_sum() {
        let (w, h) = (7, 5);
        let img: Vec<f64> = (0..w * h).map(|i| ((i * 37) % 11) as f64 / 11.0).collect();
        let k = gaussian_kernel(1.5, 3.5);
        let out = filter_separable(&img, w, h, &k);
        let r = 5isize;
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0;
                for j in -r..=r {
                    for i in -r..=r {
                        let yy = reflect_index(y as isize + j, h);
                        let xx = reflect_index(x as isize + i, w);
                        acc += k[(j + r) as usize] * k[(i + r) as usize] * img[yy * w + xx];
                    }
                }
                assert!((out[y * w + x] - acc).abs() < 1e-12);
            }
        }
        // a constant image stays constant under a normalised kernel with reflection
        let c = filter_separable(&vec![0.3; w * h], w, h, &k);
        assert!(c.iter().all(|v| (v - 0.3).abs() < 1e-14));
    }

    #[test]
    fn ssim_identical_is_one() {
        let (a, _) = ssim_pair(13, 16, 3);
        assert!((ssim(&a, &a, 16, 13, 3).unwrap() - 1.0).abs() < 1e-12);
        let flat = vec![0.25_f32; 12 * 12];
        assert!((ssim(&flat, &flat, 12, 12, 1).unwrap() - 1.0).abs() < 1e-12);
    }

    /// References from scikit-image 0.26.0 (scipy 1.17.1, numpy 2.4.6):
    ///
    /// ```python
    /// import numpy as np
    /// from skimage.metrics import structural_similarity
    /// def pair(h, w, c):
    ///     y, x, ch = np.meshgrid(np.arange(h), np.arange(w), np.arange(c), indexing="ij")
    ///     a = 0.5 + 0.4 * np.sin(0.7 * x + 1.3 * y + 0.9 * ch)
    ///     b = 0.5 + 0.35 * np.sin(0.7 * x + 1.3 * y + 0.9 * ch + 0.3) + 0.1 * np.cos(0.37 * x * y + ch)
    ///     return a.astype(np.float32).astype(np.float64), b.astype(np.float32).astype(np.float64)
    /// for (h, w, c) in [(13, 16, 3), (11, 12, 1), (24, 20, 3)]:
    ///     a, b = pair(h, w, c)
    ///     s = structural_similarity(a, b, gaussian_weights=True, sigma=1.5,
    ///         use_sample_covariance=False, data_range=1, channel_axis=-1)
    ///     print(h, w, c, repr(s))
    /// ```
    #[test]
    fn ssim_matches_scikit_image() {
        for &(h, w, c, reference) in &[
            (13, 16, 3, 0.9136849773787453),
            (11, 12, 1, 0.9209341907157702),
            (24, 20, 3, 0.9145582644386084),
        ] {
            let (a, b) = ssim_pair(h, w, c);
            let s = ssim(&a, &b, w, h, c).unwrap();
            // agrees to rounding (measured: <= 2.3e-16); the required tolerance is 1e-4
            assert!((s - reference).abs() < 1e-9, "{h}x{w}x{c}: {s} vs {reference}");
            // symmetric in its arguments
            assert!((ssim(&b, &a, w, h, c).unwrap() - s).abs() < 1e-12);
        }
    }

    #[test]
    fn ssim_rejects_small_or_mismatched() {
        let a = vec![0.0_f32; 10 * 10];
        assert!(matches!(ssim(&a, &a, 10, 10, 1), Err(MetricError::TooSmall { window: 11, .. })));
        assert!(matches!(ssim(&a, &a[1..], 10, 10, 1), Err(MetricError::Length { .. })));
    }

    /// Masked SSIM: with every pixel valid it is SSIM to the bit; an invalid pixel's value
    /// never matters (the windows touching it are left out); a mask that leaves no window
    /// free is an error, not NaN.
    #[test]
    fn ssim_masked_leaves_out_the_windows_touching_invalid_pixels() {
        let (w, h, c) = (24, 20, 3);
        let (a, b) = ssim_pair(h, w, c);
        let all = vec![true; w * h];
        assert_eq!(ssim_masked(&a, &b, w, h, c, &all).unwrap(), ssim(&a, &b, w, h, c).unwrap());
        let mut valid = all.clone();
        valid[3 * w + 4] = false;
        let mut nan = a.clone();
        nan[(3 * w + 4) * c + 1] = f32::NAN;
        let mut other = a.clone();
        other[(3 * w + 4) * c + 1] = 7.0;
        let m = ssim_masked(&nan, &b, w, h, c, &valid).unwrap();
        assert!(m.is_finite() && m != ssim(&a, &b, w, h, c).unwrap());
        assert_eq!(m, ssim_masked(&other, &b, w, h, c, &valid).unwrap());
        // A pixel far from it changes the masked value: the rest still counts.
        let mut far = a.clone();
        far[(15 * w + 18) * c] += 0.2;
        assert_ne!(m, ssim_masked(&far, &b, w, h, c, &valid).unwrap());
        let none = vec![false; w * h];
        assert!(matches!(ssim_masked(&a, &b, w, h, c, &none), Err(MetricError::EmptyMask("ssim"))));
    }

    /// A `w x h` foreground depth map at `g`, with a background column (alpha 0, depth 0)
    /// whose prediction is wildly wrong and must be ignored.
    fn depth_scene(w: usize, h: usize, g: f32) -> (Vec<f32>, Vec<f32>) {
        let mut depth = vec![g; w * h];
        let mut alpha = vec![1.0; w * h];
        for y in 0..h {
            depth[y * w] = 0.0;
            alpha[y * w] = 0.0;
        }
        (depth, alpha)
    }

    #[test]
    fn depth_constant_offset() {
        let (w, h) = (8, 5);
        let (gt, alpha) = depth_scene(w, h, 2.0);
        let pred: Vec<f32> = gt
            .iter()
            .zip(&alpha)
            .map(|(g, a)| if *a > 0.5 { g + 0.05 } else { 100.0 })
            .collect();
        let m = depth_metrics(&pred, &gt, &alpha).unwrap();
        assert_eq!(m.pixels, 7 * 5);
        assert!((m.mae - 0.05).abs() < 1e-6);
        assert!((m.rmse - 0.05).abs() < 1e-6);
        assert!((m.abs_rel - 0.025).abs() < 1e-6);
        assert_eq!(m.delta_1_25, 1.0); // ratio 1.025
        assert_eq!(m.delta_1_01, 0.0);
        assert_eq!(depth_mae(&pred, &gt, &alpha).unwrap(), m.mae);
        assert_eq!(depth_rmse(&pred, &gt, &alpha).unwrap(), m.rmse);
        assert_eq!(depth_abs_rel(&pred, &gt, &alpha).unwrap(), m.abs_rel);
        assert_eq!(depth_delta_1_25(&pred, &gt, &alpha).unwrap(), m.delta_1_25);
        assert_eq!(depth_delta_1_01(&pred, &gt, &alpha).unwrap(), m.delta_1_01);
    }

    #[test]
    fn depth_known_fraction_of_outliers() {
        // 100 foreground pixels at g = 1.5; 10 predicted at 2g, 90 exact.
        let gt = vec![1.5_f32; 100];
        let alpha = vec![1.0_f32; 100];
        let pred: Vec<f32> = (0..100).map(|i| if i % 10 == 3 { 3.0 } else { 1.5 }).collect();
        let m = depth_metrics(&pred, &gt, &alpha).unwrap();
        assert!((m.mae - 0.15).abs() < 1e-9); // 0.1 * 1.5
        assert!((m.rmse - (0.1 * 1.5f64 * 1.5).sqrt()).abs() < 1e-9);
        assert!((m.abs_rel - 0.1).abs() < 1e-9);
        assert!((m.delta_1_25 - 0.9).abs() < 1e-12);
        assert!((m.delta_1_01 - 0.9).abs() < 1e-12);
    }

    #[test]
    fn depth_rmse_weighs_large_errors() {
        // errors alternate 0.1 and 0.3: MAE 0.2, RMSE sqrt(0.05)
        let gt = vec![4.0_f32; 10];
        let alpha = vec![1.0_f32; 10];
        let pred: Vec<f32> = (0..10).map(|i| if i % 2 == 0 { 4.1 } else { 3.7 }).collect();
        let m = depth_metrics(&pred, &gt, &alpha).unwrap();
        assert!((m.mae - 0.2).abs() < 1e-6);
        assert!((m.rmse - 0.05f64.sqrt()).abs() < 1e-6);
    }

    #[test]
    fn depth_mask_rules() {
        // partial alpha and zero depth are excluded; a non-positive prediction fails delta
        let gt = [1.0_f32, 1.0, 0.0, 2.0];
        let alpha = [1.0_f32, 0.5, 1.0, 1.0];
        let pred = [1.0_f32, 9.0, 9.0, 0.0];
        let m = depth_metrics(&pred, &gt, &alpha).unwrap();
        assert_eq!(m.pixels, 2);
        assert!((m.mae - 1.0).abs() < 1e-12);
        assert!((m.delta_1_25 - 0.5).abs() < 1e-12);
        assert!(matches!(
            depth_mae(&pred, &gt, &[0.0; 4]),
            Err(MetricError::EmptyMask(_))
        ));
        assert!(matches!(depth_mae(&pred, &gt[..3], &alpha), Err(MetricError::Length { .. })));
    }

    #[test]
    fn mask_iou_of_shifted_squares() {
        // 8x8 image, gt square at cols 0..4, pred at cols 2..6, rows 0..4:
        // intersection 2x4 = 8, union 6x4 = 24
        let (w, h) = (8, 8);
        let mut gt = vec![0.0_f32; w * h];
        let mut pred = vec![0.0_f32; w * h];
        for y in 0..4 {
            for x in 0..4 {
                gt[y * w + x] = 1.0;
                pred[y * w + x + 2] = 0.9;
            }
        }
        assert!((mask_iou(&pred, &gt).unwrap() - 1.0 / 3.0).abs() < 1e-12);
        assert_eq!(mask_iou(&gt, &gt).unwrap(), 1.0);
        assert_eq!(mask_iou(&[0.0; 4], &[0.0; 4]).unwrap(), 1.0);
        // opacity exactly 0.5 is not inside
        assert_eq!(mask_iou(&[0.5], &[1.0]).unwrap(), 0.0);
    }

    #[test]
    fn off_surface_all_on_surface_is_zero() {
        let pixel = [0usize, 1];
        let offsets = [0usize, 3, 5];
        let t = [2.0_f32, 2.001, 1.999, 3.0, 3.002];
        let w = [0.3_f32, 0.5, 0.2, 0.6, 0.4];
        let s = RaySamples { pixel: &pixel, offsets: &offsets, t: &t, w: &w };
        let m = off_surface_mass(&s, &[2.0, 3.0], &[1.0, 1.0], 0.01).unwrap();
        assert_eq!(m, 0.0);
    }

    #[test]
    fn off_surface_floater_weight() {
        // ray 0: 0.8 at the surface, 0.2 on a floater at t = 1 -> 0.2
        // ray 1: total weight 0.5 (partly transparent), 0.1 on a floater -> 0.2
        // ray 2: zero total weight -> excluded; ray 3: background -> excluded
        let pixel = [0usize, 1, 2, 3];
        let offsets = [0usize, 2, 4, 5, 7];
        let t = [1.0_f32, 4.0, 4.0, 7.5, 4.0, 4.0, 1.0];
        let w = [0.2_f32, 0.8, 0.4, 0.1, 0.0, 0.3, 0.7];
        let s = RaySamples { pixel: &pixel, offsets: &offsets, t: &t, w: &w };
        let g = [4.0_f32; 4];
        let alpha = [1.0_f32, 1.0, 1.0, 0.0];
        let m = off_surface_mass(&s, &g, &alpha, 0.05).unwrap();
        assert!((m - 0.2).abs() < 1e-7, "{m}");
        // Ray 0's floater lies in front (0.2), ray 1's behind (0 in front): front 0.1.
        let split = off_surface_split(&s, &g, &alpha, 0.05).unwrap();
        assert!((split.total - m).abs() < 1e-12 && (split.front - 0.1).abs() < 1e-7, "{split:?}");
    }

    #[test]
    fn off_surface_uniform_fog_matches_analytic_fraction() {
        // 1000 equal weights at midpoints of [0, 10]; surface at 5, tol 0.5:
        // off-surface fraction = 1 - 2 tol / (far - near) = 0.9
        let n = 1000;
        let t: Vec<f32> = (0..n).map(|i| (i as f32 + 0.5) * 0.01).collect();
        let w = vec![1.0 / n as f32; n];
        let pixel = [0usize];
        let offsets = [0usize, n];
        let s = RaySamples { pixel: &pixel, offsets: &offsets, t: &t, w: &w };
        let m = off_surface_mass(&s, &[5.0], &[1.0], 0.5).unwrap();
        assert!((m - 0.9).abs() < 1e-6, "{m}");
        // In front: [0, 4.5) of [0, 10].
        let front = off_surface_split(&s, &[5.0], &[1.0], 0.5).unwrap().front;
        assert!((front - 0.45).abs() < 1e-6, "{front}");
    }

    #[test]
    fn off_surface_rejects_bad_layout() {
        let t = [1.0_f32, 2.0];
        let w = [0.5_f32, 0.5];
        let bad = RaySamples { pixel: &[0], offsets: &[0, 3], t: &t, w: &w };
        assert!(matches!(off_surface_mass(&bad, &[1.0], &[1.0], 0.1), Err(MetricError::Offsets(_))));
        let dec = RaySamples { pixel: &[0, 0], offsets: &[0, 2, 1], t: &t, w: &w };
        assert!(matches!(off_surface_mass(&dec, &[1.0], &[1.0], 0.1), Err(MetricError::Offsets(_))));
        let oob = RaySamples { pixel: &[5], offsets: &[0, 2], t: &t, w: &w };
        assert!(matches!(off_surface_mass(&oob, &[1.0], &[1.0], 0.1), Err(MetricError::Length { .. })));
        let none = RaySamples { pixel: &[0], offsets: &[0, 2], t: &t, w: &w };
        assert!(matches!(
            off_surface_mass(&none, &[1.0], &[0.0], 0.1),
            Err(MetricError::EmptyMask(_))
        ));
    }
}
