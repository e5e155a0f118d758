//! Volume rendering of ragged ray batches: compositing forward and its exact backward, and the
//! density activations the fields use (nerfacc's `volrend.py`, in plain Rust over slices).
//!
//! # Layout
//! Ray `r` owns the samples `offsets[r]..offsets[r + 1]` (`offsets[0] == 0`, non-decreasing,
//! last = `n_samples`; a ray may own none). Per sample: the density `sigma` (after activation,
//! ≥ 0), the colour `rgb` (in [0, 1]) and the interval `[t_start, t_end]` (`delta` its length).
//!
//! # Formula
//! ```text
//! x_i = sigma_i · delta_i,   alpha_i = 1 − exp(−x_i),   T_i = exp(−Σ_{j<i} x_j),   w_i = T_i · alpha_i
//! opacity  = Σ_i w_i
//! colour   = Σ_i w_i c_i + T_N · background      (T_N = exp(−Σ_i x_i) = 1 − opacity)
//! s_i      = t_start_i + delta_i · (1/x_i − 1/(e^{x_i} − 1))
//! distance = Σ_i w_i · s_i                 (NOT normalised by the opacity)
//! ```
//! `T_i` is an exclusive cumulative sum, never `Π (1 − alpha_j)`. `distance` counts the
//! background as distance 0 (as the ground truth does); [`normalized_distance`] divides by the
//! opacity, and the caller multiplies by the ray's z-factor for z-depth. `s_i`
//! ([`termination_distance`]) is the mean termination distance within interval `i` under its
//! constant density (the midpoint when transparent, `t_start + 1/sigma` when opaque), so an
//! opaque surface is not placed half a step behind where its density begins.
//!
//! # Worked example
//! One ray, `sigma = [1, 2]`, intervals `[1, 1.5]`, `[1.5, 2]`, red then green, black background:
//! `x = [0.5, 1]`, `w = [0.393469, 0.383400]`, `s = [1.229253, 1.709012]`,
//! `opacity = 0.776870`, `colour = (0.393469, 0.383400, 0)`, `distance = 1.138909`.
//!
//! # Robustness
//! A NaN or negative `sigma` counts as 0 (gradient 0); `+inf` and values above [`SIGMA_MAX`]
//! are clamped to it, as is `x_i`. A NaN or negative `delta` counts as 0; a NaN colour,
//! `t_start`, `t_end` or background channel counts as 0. Each sample or background holding a
//! NaN is counted in [`CompositeOutput::n_nan`]. Outputs and gradients are finite for densities
//! and intervals 0 … 1e30 and any number of samples per ray.
//!
//! # Determinism
//! Each ray is processed sequentially by one thread: bit-identical for any thread count.

use rayon::prelude::*;

/// Largest density and optical thickness the compositor works with; larger values, `+inf`
/// included, are clamped to it (`exp(−1e30)` is already exactly 0 in f32).
pub const SIGMA_MAX: f32 = 1e30;

/// Rays per rayon task.
const RAY_BLOCK: usize = 64;

/// One batch of samples to composite (see the module doc's layout).
///
/// # Shapes
/// - `offsets`: `[n_rays + 1]`
/// - `sigma`, `t_start`, `t_end`: `[n_samples]`; `rgb`: `[n_samples]`
/// - `background`: `[n_rays]`
#[derive(Clone, Copy, Debug)]
pub struct CompositeInputs<'a> {
    /// Ray `r` owns the samples `offsets[r]..offsets[r + 1]`.
    pub offsets: &'a [u32],
    /// Density after activation.
    pub sigma: &'a [f32],
    /// Colour in [0, 1].
    pub rgb: &'a [[f32; 3]],
    /// Interval start along the ray.
    pub t_start: &'a [f32],
    /// Interval end along the ray.
    pub t_end: &'a [f32],
    /// Background colour per ray.
    pub background: &'a [[f32; 3]],
}

/// Gradients of the loss with respect to [`composite_forward`]'s outputs, for
/// [`composite_backward`].
///
/// # Shapes
/// `d_rgb`, `d_opacity`, `d_distance`: `[n_rays]`; `d_weights`: `[n_samples]`.
#[derive(Clone, Copy, Debug)]
pub struct OutputGrads<'a> {
    /// ∂L/∂colour per ray.
    pub d_rgb: &'a [[f32; 3]],
    /// ∂L/∂opacity per ray.
    pub d_opacity: &'a [f32],
    /// ∂L/∂distance per ray.
    pub d_distance: &'a [f32],
    /// ∂L/∂w_i where the loss depends on the weights directly, else `None`.
    pub d_weights: Option<&'a [f32]>,
}

/// Options of [`composite_forward_with`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CompositeOptions {
    /// Stop accumulating a ray once its transmittance `T_i` drops below this value (instant-ngp
    /// uses 1e-4 for inference): the remaining samples get weight 0 and the remaining mass
    /// `T_i` goes to the background. The colour error this introduces is at most
    /// `min_transmittance · max|c − background|`, the opacity error at most `min_transmittance`.
    /// `0.0` disables early termination (exact; required for training).
    pub min_transmittance: f32,
}

impl CompositeOptions {
    /// Exact compositing of every sample (training).
    pub const EXACT: Self = Self { min_transmittance: 0.0 };
    /// Inference: stop once `T < 1e-4`.
    pub const INFERENCE: Self = Self { min_transmittance: 1e-4 };
}

/// What [`composite_forward`] returns.
///
/// # Shapes
/// - `rgb`, `opacity`, `distance`: `[n_rays]`
/// - `weights`: `[n_samples]`
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CompositeOutput {
    /// Composited colour including the background term.
    pub rgb: Vec<[f32; 3]>,
    /// `Σ w_i`, in [0, 1].
    pub opacity: Vec<f32>,
    /// Expected distance `Σ w_i t_mid_i`, not normalised (see the module doc).
    pub distance: Vec<f32>,
    /// Per-sample weights `w_i = T_i alpha_i`.
    pub weights: Vec<f32>,
    /// Number of samples (and backgrounds) in which a NaN was met and replaced by 0.
    pub n_nan: usize,
}

/// What [`composite_backward`] returns.
///
/// # Shapes
/// - `d_sigma`: `[n_samples]`, `d_rgb`: `[n_samples]`, `d_background`: `[n_rays]`
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CompositeGrads {
    /// dL/dsigma_i.
    pub d_sigma: Vec<f32>,
    /// dL/dc_i.
    pub d_rgb: Vec<[f32; 3]>,
    /// dL/dbackground per ray.
    pub d_background: Vec<[f32; 3]>,
}

/// `distance / max(opacity, eps)`: the expected distance given that the ray hit something.
///
/// Example: `distance = 1.138909`, `opacity = 0.776870` → `1.466023`.
pub fn normalized_distance(distance: f32, opacity: f32, eps: f32) -> f32 {
    distance / opacity.max(eps)
}

#[inline]
fn clean_sigma(s: f32) -> f32 {
    // NaN > 0 is false: NaN and negatives become 0.
    if s > 0.0 { s.min(SIGMA_MAX) } else { 0.0 }
}

#[inline]
fn clean(v: f32) -> f32 {
    if v.is_nan() { 0.0 } else { v.clamp(-SIGMA_MAX, SIGMA_MAX) }
}

/// Per-sample quantities after sanitising: (optical thickness x, delta, t_start, nan?).
#[inline]
fn sample_terms(sigma: f32, t0: f32, t1: f32) -> (f32, f32, f32, bool) {
    let nan = sigma.is_nan() || t0.is_nan() || t1.is_nan();
    let (t0, t1) = (clean(t0), clean(t1));
    let d = t1 - t0;
    let d = if d > 0.0 { d.min(SIGMA_MAX) } else { 0.0 };
    let x = (clean_sigma(sigma) * d).min(SIGMA_MAX);
    (x, d, t0, nan)
}

/// Below this optical thickness the termination fraction and its derivative use their Taylor
/// series (the closed forms cancel catastrophically near 0); the series' first omitted terms
/// are below 1e-10 here.
const SERIES_BELOW: f32 = 0.5;

/// `f(x) = 1/x − 1/(eˣ − 1)`: the mean of an exponential distribution of rate 1 truncated to
/// `[0, x]`, divided by `x` (where in an interval of optical thickness `x` a ray that terminates
/// in it does so on average, as a fraction of the interval). `f(0) = 1/2`, `f(x) → 1/x`.
#[inline]
fn termination_fraction(x: f32) -> f32 {
    if x < SERIES_BELOW {
        // 1/2 − x/12 + x³/720 − x⁵/30240 + x⁷/1209600 (Bernoulli numbers)
        let x2 = x * x;
        0.5 - x * (1.0 / 12.0 - x2 * (1.0 / 720.0 - x2 * (1.0 / 30240.0 - x2 / 1_209_600.0)))
    } else {
        1.0 / x - 1.0 / x.exp_m1()
    }
}

/// `f'(x) = eˣ/(eˣ − 1)² − 1/x²` of [`termination_fraction`]; `f'(0) = −1/12`.
#[inline]
fn termination_fraction_dx(x: f32) -> f32 {
    if x < SERIES_BELOW {
        // −1/12 + x²/240 − x⁴/6048 + x⁶/172800
        let x2 = x * x;
        -1.0 / 12.0 + x2 * (1.0 / 240.0 - x2 * (1.0 / 6048.0 - x2 / 172_800.0))
    } else {
        let a = -(-x).exp_m1(); // 1 − e^−x ≥ 0.39
        (-x).exp() / (a * a) - 1.0 / (x * x)
    }
}

/// The expected distance at which a ray terminates given that it terminates in the interval
/// `[t_start, t_end]` of constant density `sigma` (the `s_i` of the module doc): the midpoint
/// for `sigma → 0`, `t_start + 1/sigma` for an opaque interval. Inputs are sanitised as in
/// [`composite_forward`].
///
/// Example: `sigma = 2`, interval `[1.5, 2]` → `1.709012`.
pub fn termination_distance(sigma: f32, t_start: f32, t_end: f32) -> f32 {
    let (x, d, t0, _) = sample_terms(sigma, t_start, t_end);
    t0 + d * termination_fraction(x)
}

#[inline]
fn clean3(c: [f32; 3]) -> ([f32; 3], bool) {
    let nan = c.iter().any(|v| v.is_nan());
    (c.map(clean), nan)
}

fn check_layout(offsets: &[u32], n_samples: usize, n_rays_bg: usize) -> usize {
    assert!(!offsets.is_empty(), "offsets must hold n_rays + 1 entries");
    let n_rays = offsets.len() - 1;
    assert_eq!(offsets[0], 0, "offsets[0] must be 0");
    assert_eq!(offsets[n_rays] as usize, n_samples, "offsets[n_rays] must equal the sample count");
    assert!(offsets.windows(2).all(|w| w[0] <= w[1]), "offsets must be non-decreasing");
    assert_eq!(n_rays_bg, n_rays, "one background per ray");
    n_rays
}

/// Splits a per-sample buffer into the contiguous pieces of consecutive blocks of `RAY_BLOCK`
/// rays.
fn split_blocks<'a, T>(mut data: &'a mut [T], offsets: &[u32]) -> Vec<&'a mut [T]> {
    let n_rays = offsets.len() - 1;
    let mut out = Vec::with_capacity(n_rays.div_ceil(RAY_BLOCK));
    let mut r0 = 0;
    while r0 < n_rays {
        let r1 = (r0 + RAY_BLOCK).min(n_rays);
        let len = (offsets[r1] - offsets[r0]) as usize;
        let (head, tail) = std::mem::take(&mut data).split_at_mut(len);
        out.push(head);
        data = tail;
        r0 = r1;
    }
    out
}

/// Composites every ray exactly ([`CompositeOptions::EXACT`]); see the module doc for the
/// formula and a worked example.
///
/// # Panics
/// If the shapes disagree or `offsets` is not a valid ragged layout.
pub fn composite_forward(inputs: &CompositeInputs) -> CompositeOutput {
    composite_forward_with(inputs, CompositeOptions::EXACT)
}

/// [`composite_forward`] with options (early termination for inference).
pub fn composite_forward_with(inputs: &CompositeInputs, options: CompositeOptions) -> CompositeOutput {
    let CompositeInputs { offsets, sigma, rgb, t_start, t_end, background } = *inputs;
    let n = sigma.len();
    assert!(rgb.len() == n && t_start.len() == n && t_end.len() == n, "per-sample lengths differ");
    let n_rays = check_layout(offsets, n, background.len());
    let mut out = CompositeOutput {
        rgb: vec![[0.0; 3]; n_rays],
        opacity: vec![0.0; n_rays],
        distance: vec![0.0; n_rays],
        weights: vec![0.0; n],
        n_nan: 0,
    };
    let t_min = options.min_transmittance;
    let w_blocks = split_blocks(&mut out.weights, offsets);
    out.n_nan = w_blocks
        .into_par_iter()
        .zip(out.rgb.par_chunks_mut(RAY_BLOCK))
        .zip(out.opacity.par_chunks_mut(RAY_BLOCK))
        .zip(out.distance.par_chunks_mut(RAY_BLOCK))
        .enumerate()
        .map(|(b, (((w_blk, rgb_blk), op_blk), dist_blk))| {
            let r0 = b * RAY_BLOCK;
            let base = offsets[r0] as usize;
            let mut n_nan = 0;
            for k in 0..rgb_blk.len() {
                let r = r0 + k;
                let (s0, s1) = (offsets[r] as usize, offsets[r + 1] as usize);
                let mut tau = 0.0f32;
                let mut col = [0.0f32; 3];
                let mut op = 0.0f32;
                let mut dist = 0.0f32;
                for i in s0..s1 {
                    let trans = (-tau).exp();
                    if trans < t_min {
                        break;
                    }
                    let (x, d, t0, nan_t) = sample_terms(sigma[i], t_start[i], t_end[i]);
                    let (c, nan_c) = clean3(rgb[i]);
                    n_nan += usize::from(nan_t || nan_c);
                    let w = trans * -(-x).exp_m1();
                    w_blk[i - base] = w;
                    for ch in 0..3 {
                        col[ch] += w * c[ch];
                    }
                    op += w;
                    dist += w * (t0 + d * termination_fraction(x));
                    tau += x;
                }
                let (bg, nan_bg) = clean3(background[r]);
                n_nan += usize::from(nan_bg);
                let t_final = (-tau).exp();
                rgb_blk[k] = [0, 1, 2].map(|ch| col[ch] + t_final * bg[ch]);
                op_blk[k] = op;
                dist_blk[k] = dist;
            }
            n_nan
        })
        .sum();
    out
}

/// Exact gradients of a scalar loss `L` through [`composite_forward`].
///
/// With `g_i = dL/dw_i = d_rgb·(c_i − background) + d_opacity + d_distance · s_i + d_weights_i`
/// (`s_i = t_start_i + delta_i f(x_i)`, `f(x) = 1/x − 1/(eˣ − 1)`, see the module doc):
///
/// ```text
/// dL/dsigma_k     = delta_k · ( T_{k+1} g_k − Σ_{i>k} w_i g_i + d_distance · w_k delta_k f'(x_k) )
/// dL/dc_k         = w_k · d_rgb
/// dL/dbackground  = T_N · d_rgb
/// ```
///
/// (`T_{k+1} = T_k e^{−x_k}`; the last term of `dL/dsigma_k` is `s_k`'s own dependence on `x_k`.)
///
/// The suffix sum is accumulated in reverse, O(n) per ray. `out` must come from
/// [`composite_forward`] on the same inputs (its `weights` are reused); after an early-stopped
/// forward the gradient is that of the truncated sum.
///
/// Worked example (the module's two-sample ray, `d_opacity = 1`, others 0): `g = [1, 1]`,
/// `dL/dsigma = [0.5 (0.606531 − 0.383400), 0.5 · 0.223130] = [0.111565, 0.111565]`.
///
/// `d_weights` ([`OutputGrads`]) is for a loss that also depends on the weights directly (e.g.
/// [`distortion`]): every term of `g` is `∂L/∂w_i`.
pub fn composite_backward(inputs: &CompositeInputs, out: &CompositeOutput, d: &OutputGrads) -> CompositeGrads {
    let CompositeInputs { offsets, sigma, rgb, t_start, t_end, background } = *inputs;
    let OutputGrads { d_rgb, d_opacity, d_distance, d_weights } = *d;
    let n = sigma.len();
    if let Some(dw) = d_weights {
        assert_eq!(dw.len(), n, "d_weights length differs");
    }
    assert!(rgb.len() == n && t_start.len() == n && t_end.len() == n, "per-sample lengths differ");
    assert_eq!(out.weights.len(), n, "`out` does not match the inputs");
    let n_rays = check_layout(offsets, n, background.len());
    assert!(
        d_rgb.len() == n_rays && d_opacity.len() == n_rays && d_distance.len() == n_rays,
        "per-ray gradient lengths differ"
    );
    let mut grads = CompositeGrads {
        d_sigma: vec![0.0; n],
        d_rgb: vec![[0.0; 3]; n],
        d_background: vec![[0.0; 3]; n_rays],
    };
    let ds_blocks = split_blocks(&mut grads.d_sigma, offsets);
    let dc_blocks = split_blocks(&mut grads.d_rgb, offsets);
    ds_blocks
        .into_par_iter()
        .zip(dc_blocks)
        .zip(grads.d_background.par_chunks_mut(RAY_BLOCK))
        .enumerate()
        .for_each(|(b, ((ds_blk, dc_blk), dbg_blk))| {
            let r0 = b * RAY_BLOCK;
            let base = offsets[r0] as usize;
            // Inclusive prefix sums of the optical thickness: tau[i] = Σ_{j≤i} x_j.
            let mut tau_incl: Vec<f32> = Vec::new();
            for (k, dbg) in dbg_blk.iter_mut().enumerate() {
                let r = r0 + k;
                let (s0, s1) = (offsets[r] as usize, offsets[r + 1] as usize);
                let (bg, _) = clean3(background[r]);
                let dc = d_rgb[r].map(clean);
                let (dop, ddist) = (clean(d_opacity[r]), clean(d_distance[r]));
                tau_incl.clear();
                let mut tau = 0.0f32;
                for i in s0..s1 {
                    let (x, _, _, _) = sample_terms(sigma[i], t_start[i], t_end[i]);
                    tau += x;
                    tau_incl.push(tau);
                }
                let t_final = (-tau).exp();
                *dbg = dc.map(|v| t_final * v);
                let mut suffix = 0.0f32; // Σ_{i>k} w_i g_i
                for i in (s0..s1).rev() {
                    let (x, d, t0, _) = sample_terms(sigma[i], t_start[i], t_end[i]);
                    let (c, _) = clean3(rgb[i]);
                    let w = out.weights[i];
                    let g = dc[0] * (c[0] - bg[0])
                        + dc[1] * (c[1] - bg[1])
                        + dc[2] * (c[2] - bg[2])
                        + dop
                        + ddist * (t0 + d * termination_fraction(x))
                        + d_weights.map_or(0.0, |dw| clean(dw[i]));
                    let t_next = (-tau_incl[i - s0]).exp();
                    // the last term: s_k itself moves with x_k
                    let dx = t_next * g - suffix + ddist * w * d * termination_fraction_dx(x);
                    // NaN / negative densities were replaced by the constant 0: no gradient
                    let valid = sigma[i] >= 0.0;
                    ds_blk[i - base] = if valid { d * dx } else { 0.0 };
                    dc_blk[i - base] = dc.map(|v| w * v);
                    suffix += w * g;
                }
            }
        });
    grads
}

/// The distortion loss of mip-NeRF 360 (Barron et al. 2022, eq. 15) per ray, with its
/// gradient with respect to the weights: with interval midpoints `m_i`, widths `δ_i` (both
/// multiplied by `scale`, mip-NeRF 360's normalised distance) and weights `w_i`,
///
/// ```text
/// L_dist     = Σ_i Σ_j w_i w_j |m_i − m_j| + (1/3) Σ_i w_i² δ_i
/// ∂L/∂w_k    = 2 Σ_j w_j |m_k − m_j| + (2/3) w_k δ_k
/// ```
///
/// It is small when a ray's weight sits in one short stretch (a surface) and large when it is
/// spread along the ray (fog, floaters). A ray's samples must be ordered along it (as marching
/// gives them; the intervals may have gaps); both sums take O(n) per ray with prefix sums in
/// `f64`. `d_loss[r]` scales ray `r`'s gradient (e.g. `λ / n_rays` for a mean); returns the
/// per-ray losses and `∂(Σ_r d_loss[r] L_r)/∂w` (`[n_samples]`), for
/// [`composite_backward`]'s `d_weights`. NaN inputs count as 0.
///
/// Example: one ray, weights `[0.5, 0.5]`, intervals `[0, 1]` and `[2, 3]`, scale 1:
/// `L = 2 · 0.25 · 2 + (0.25 + 0.25) / 3 = 1.166667`, `∂L/∂w = [2 + 1/3, 2 + 1/3]`.
pub fn distortion(offsets: &[u32], weights: &[f32], t_start: &[f32], t_end: &[f32], scale: f32, d_loss: &[f32]) -> (Vec<f32>, Vec<f32>) {
    let n = weights.len();
    assert!(t_start.len() == n && t_end.len() == n, "per-sample lengths differ");
    let n_rays = check_layout(offsets, n, d_loss.len());
    let mut loss = vec![0.0f32; n_rays];
    let mut grad = vec![0.0f32; n];
    let blocks = split_blocks(&mut grad, offsets);
    blocks.into_par_iter().zip(loss.par_chunks_mut(RAY_BLOCK)).enumerate().for_each(|(b, (g_blk, l_blk))| {
        let r0 = b * RAY_BLOCK;
        let base = offsets[r0] as usize;
        for (k, l) in l_blk.iter_mut().enumerate() {
            let r = r0 + k;
            let (s0, s1) = (offsets[r] as usize, offsets[r + 1] as usize);
            let term = |i: usize| {
                let w = clean(weights[i]) as f64;
                let (a, e) = (clean(t_start[i]) as f64, clean(t_end[i]) as f64);
                (w, 0.5 * (a + e) * scale as f64, (e - a).max(0.0) * scale as f64)
            };
            let (mut w_tot, mut s_tot) = (0.0f64, 0.0f64);
            for i in s0..s1 {
                let (w, m, _) = term(i);
                w_tot += w;
                s_tot += w * m;
            }
            let (mut w_before, mut s_before, mut cross, mut own) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
            let dl = clean(d_loss[r]) as f64;
            for i in s0..s1 {
                let (w, m, d) = term(i);
                let (w_after, s_after) = (w_tot - w_before - w, s_tot - s_before - w * m);
                let spread = (m * w_before - s_before) + (s_after - m * w_after);
                cross += w * (m * w_before - s_before);
                own += w * w * d;
                g_blk[i - base] = (dl * (2.0 * spread + 2.0 / 3.0 * w * d)) as f32;
                w_before += w;
                s_before += w * m;
            }
            *l = (2.0 * cross + own / 3.0) as f32;
        }
    });
    (loss, grad)
}

/// Activation bound of [`trunc_exp`].
pub const TRUNC_EXP_MAX: f32 = 15.0;

/// Truncated exponential density activation (instant-ngp's `trunc_exp`):
/// `exp(min(x, 15))`, NaN → 0.
///
/// The forward clamps at 15 (densities ≤ 3.27e6, never `inf`); the gradient
/// [`trunc_exp_backward`] is `exp(clamp(x, −15, 15))`, so it never vanishes nor explodes.
/// Example: `trunc_exp(1.0) = 2.718282`, `trunc_exp(100.0) = 3269017.4`.
#[inline]
pub fn trunc_exp(x: f32) -> f32 {
    if x.is_nan() { 0.0 } else { x.min(TRUNC_EXP_MAX).exp() }
}

/// Gradient through [`trunc_exp`]: `grad · exp(clamp(x, −15, 15))`; NaN `x` → 0.
#[inline]
pub fn trunc_exp_backward(x: f32, grad: f32) -> f32 {
    if x.is_nan() { 0.0 } else { grad * x.clamp(-TRUNC_EXP_MAX, TRUNC_EXP_MAX).exp() }
}

/// Numerically stable softplus `ln(1 + e^x) = max(x, 0) + ln(1 + e^{−|x|})`; NaN → 0.
///
/// mip-NeRF/nerfstudio apply it to `x − 1`; the shift is the caller's. Example:
/// `softplus(0) = ln 2 = 0.693147`, `softplus(100) = 100`.
#[inline]
pub fn softplus(x: f32) -> f32 {
    if x.is_nan() { 0.0 } else { x.max(0.0) + (-x.abs()).exp().ln_1p() }
}

/// Gradient through [`softplus`]: `grad · sigmoid(x)`; NaN `x` → 0.
#[inline]
pub fn softplus_backward(x: f32, grad: f32) -> f32 {
    if x.is_nan() {
        0.0
    } else {
        let s = if x >= 0.0 { 1.0 / (1.0 + (-x).exp()) } else { let e = x.exp(); e / (1.0 + e) };
        grad * s
    }
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;

    /// Counter-based test data.
    fn rnd(i: u64) -> f64 {
        crate::sampling::rng::uniform_f64(crate::sampling::rng::key(&[77, i]))
    }

    struct Batch {
        offsets: Vec<u32>,
        sigma: Vec<f32>,
        rgb: Vec<[f32; 3]>,
        t0: Vec<f32>,
        t1: Vec<f32>,
        bg: Vec<[f32; 3]>,
    }

    impl Batch {
        fn inputs(&self) -> CompositeInputs<'_> {
            CompositeInputs { offsets: &self.offsets, sigma: &self.sigma, rgb: &self.rgb, t_start: &self.t0, t_end: &self.t1, background: &self.bg }
        }
    }

    fn batch(counts: &[usize], seed: u64, sigma_scale: f64) -> Batch {
        let mut b = Batch { offsets: vec![0], sigma: vec![], rgb: vec![], t0: vec![], t1: vec![], bg: vec![] };
        let mut c = seed * 1_000_000;
        let mut next = || {
            c += 1;
            rnd(c)
        };
        for &n in counts {
            let mut t = 0.5 + next();
            for _ in 0..n {
                let d = 0.02 + 0.2 * next();
                b.t0.push(t as f32);
                t += d;
                b.t1.push(t as f32);
                b.sigma.push((sigma_scale * next() * next()) as f32);
                b.rgb.push([next() as f32, next() as f32, next() as f32]);
            }
            b.offsets.push(b.sigma.len() as u32);
            b.bg.push([next() as f32, next() as f32, next() as f32]);
        }
        b
    }

    struct Ref {
        rgb: Vec<[f64; 3]>,
        opacity: Vec<f64>,
        distance: Vec<f64>,
        weights: Vec<f64>,
    }

    /// f64 reference: the formula, written directly.
    fn reference(b: &Batch, sigma: &[f64], rgb: &[[f64; 3]], bg: &[[f64; 3]]) -> Ref {
        let n_rays = b.offsets.len() - 1;
        let mut r = Ref { rgb: vec![], opacity: vec![], distance: vec![], weights: vec![0.0; sigma.len()] };
        for ray in 0..n_rays {
            let (s0, s1) = (b.offsets[ray] as usize, b.offsets[ray + 1] as usize);
            let (mut tau, mut col, mut op, mut dist) = (0.0f64, [0.0f64; 3], 0.0, 0.0);
            for i in s0..s1 {
                let d = (b.t1[i] as f64 - b.t0[i] as f64).max(0.0);
                let x = sigma[i].max(0.0) * d;
                let w = (-tau).exp() * (1.0 - (-x).exp());
                r.weights[i] = w;
                for ch in 0..3 {
                    col[ch] += w * rgb[i][ch];
                }
                op += w;
                // ∫_0^d σ e^{−σu} (t0 + u) du, written out (not through the f32 kernel's f)
                let s = sigma[i].max(0.0);
                let local = if s > 0.0 { b.t0[i] as f64 * (1.0 - (-x).exp()) + (1.0 - (-x).exp() * (1.0 + x)) / s } else { 0.0 };
                dist += (-tau).exp() * local;
                tau += x;
            }
            r.rgb.push([0, 1, 2].map(|ch| col[ch] + (1.0 - op) * bg[ray][ch]));
            r.opacity.push(op);
            r.distance.push(dist);
        }
        r
    }

    fn to64(b: &Batch) -> (Vec<f64>, Vec<[f64; 3]>, Vec<[f64; 3]>) {
        (
            b.sigma.iter().map(|&s| s as f64).collect(),
            b.rgb.iter().map(|c| c.map(|v| v as f64)).collect(),
            b.bg.iter().map(|c| c.map(|v| v as f64)).collect(),
        )
    }

    type LossCoeffs = (Vec<[f32; 3]>, Vec<f32>, Vec<f32>);

    fn loss_coeffs(n_rays: usize) -> LossCoeffs {
        let d_rgb = (0..n_rays).map(|r| [0, 1, 2].map(|c| (rnd(900 + 3 * r as u64 + c) - 0.5) as f32)).collect();
        let d_op = (0..n_rays).map(|r| (rnd(5000 + r as u64) - 0.5) as f32).collect();
        let d_dist = (0..n_rays).map(|r| (rnd(7000 + r as u64) - 0.5) as f32).collect();
        (d_rgb, d_op, d_dist)
    }

    /// L = Σ d_rgb·rgb + d_opacity·opacity + d_distance·distance, in f64.
    fn ref_loss(b: &Batch, sigma: &[f64], rgb: &[[f64; 3]], bg: &[[f64; 3]], lc: &LossCoeffs) -> f64 {
        let r = reference(b, sigma, rgb, bg);
        let mut l = 0.0;
        for ray in 0..r.opacity.len() {
            for ch in 0..3 {
                l += lc.0[ray][ch] as f64 * r.rgb[ray][ch];
            }
            l += lc.1[ray] as f64 * r.opacity[ray] + lc.2[ray] as f64 * r.distance[ray];
        }
        l
    }

    fn forward(b: &Batch) -> CompositeOutput {
        composite_forward(&b.inputs())
    }

    #[test]
    fn worked_example() {
        let out = composite_forward(&CompositeInputs { offsets: &[0, 2], sigma: &[1.0, 2.0], rgb: &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], t_start: &[1.0, 1.5], t_end: &[1.5, 2.0], background: &[[0.0; 3]] });
        let close = |a: f32, b: f32| assert!((a - b).abs() < 1e-6, "{a} vs {b}");
        close(out.weights[0], 0.393469);
        close(out.weights[1], 0.383400);
        close(out.opacity[0], 0.776870);
        close(out.rgb[0][0], 0.393469);
        close(out.rgb[0][1], 0.383400);
        close(out.distance[0], 1.138909);
        close(normalized_distance(out.distance[0], out.opacity[0], 1e-6), 1.466_023);
        close(termination_distance(2.0, 1.5, 2.0), 1.709012);
        let g = composite_backward(&CompositeInputs { offsets: &[0, 2], sigma: &[1.0, 2.0], rgb: &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], t_start: &[1.0, 1.5], t_end: &[1.5, 2.0], background: &[[0.0; 3]] }, &out, &OutputGrads { d_rgb: &[[0.0; 3]], d_opacity: &[1.0], d_distance: &[0.0], d_weights: None });
        close(g.d_sigma[0], 0.111565);
        close(g.d_sigma[1], 0.111565);
    }

    /// The expected termination distance within one interval against a midpoint-rule
    /// integration of `t σ e^{−σ(t − t0)}` in f64, over thicknesses from transparent to opaque,
    /// on both sides of the series/closed-form switch; the derivative against f64 differences.
    #[test]
    fn termination_distance_matches_integration() {
        let integrate = |sigma: f64, t0: f64, t1: f64| {
            let n = 200_000;
            let h = (t1 - t0) / n as f64;
            let (mut num, mut den) = (0.0, 0.0);
            for k in 0..n {
                let t = t0 + (k as f64 + 0.5) * h;
                let p = sigma * (-sigma * (t - t0)).exp();
                num += t * p;
                den += p;
            }
            num / den
        };
        for &x in &[1e-6f64, 1e-3, 0.1, 0.4999, 0.5, 0.5001, 1.0, 3.0, 10.0, 40.0] {
            let (t0, t1) = (2.0f64, 2.25f64);
            let sigma = x / (t1 - t0);
            let got = termination_distance(sigma as f32, t0 as f32, t1 as f32) as f64;
            let want = integrate(sigma, t0, t1);
            assert!((got - want).abs() < 2e-6, "x {x}: {got} vs {want}");
            // f' against a central difference of the f64 closed form
            let f64f = |x: f64| 1.0 / x - 1.0 / x.exp_m1();
            let h = 1e-4 * x.max(1e-2);
            let fd = if x > 1e-2 { (f64f(x + h) - f64f(x - h)) / (2.0 * h) } else { -1.0 / 12.0 + x * x / 240.0 };
            let d = termination_fraction_dx(x as f32) as f64;
            assert!((d - fd).abs() < 1e-5 * (1.0 + fd.abs()), "f'({x}): {d} vs {fd}");
        }
        // limits: transparent → midpoint, opaque → t_start + 1/σ, infinite → t_start
        assert_eq!(termination_distance(0.0, 1.0, 2.0), 1.5);
        assert!((termination_distance(1e4, 1.0, 2.0) - 1.0001).abs() < 1e-6);
        assert_eq!(termination_distance(f32::INFINITY, 1.0, 2.0), 1.0);
        assert_eq!(termination_distance(f32::NAN, 1.0, 2.0), 1.5);
    }

    #[test]
    fn forward_matches_f64_reference() {
        let counts = [0usize, 1, 2, 3, 7, 64, 200, 1, 0, 4096, 5];
        for (seed, scale) in [(1u64, 0.5f64), (2, 5.0), (3, 50.0)] {
            let b = batch(&counts, seed, scale);
            let out = forward(&b);
            let (s64, c64, bg64) = to64(&b);
            let r = reference(&b, &s64, &c64, &bg64);
            assert_eq!(out.n_nan, 0);
            for ray in 0..counts.len() {
                for ch in 0..3 {
                    assert!((out.rgb[ray][ch] as f64 - r.rgb[ray][ch]).abs() < 2e-5, "rgb ray {ray}");
                }
                assert!((out.opacity[ray] as f64 - r.opacity[ray]).abs() < 2e-5);
                let tol = 2e-5 * (1.0 + r.distance[ray].abs());
                assert!((out.distance[ray] as f64 - r.distance[ray]).abs() < tol, "distance ray {ray}");
            }
            for i in 0..b.sigma.len() {
                assert!((out.weights[i] as f64 - r.weights[i]).abs() < 2e-6);
            }
            // zero-sample rays: background, opacity 0
            assert_eq!(out.rgb[0], b.bg[0]);
            assert_eq!(out.opacity[0], 0.0);
            assert_eq!(out.distance[0], 0.0);
        }
    }

    #[test]
    fn backward_matches_finite_differences_of_f64_reference() {
        let counts = [0usize, 1, 2, 5, 17, 40];
        for (seed, scale) in [(4u64, 1.0f64), (5, 20.0)] {
            let mut b = batch(&counts, seed, scale);
            // exact zeros: the gradient there is the one-sided derivative, not 0
            for s in b.sigma.iter_mut().step_by(7) {
                *s = 0.0;
            }
            let lc = loss_coeffs(counts.len());
            let out = forward(&b);
            let g = composite_backward(&b.inputs(), &out, &OutputGrads { d_rgb: &lc.0, d_opacity: &lc.1, d_distance: &lc.2, d_weights: None });
            let (sigma, rgb, bg) = to64(&b);
            let h = 1e-6;
            for i in 0..sigma.len() {
                let (mut sp, mut sm) = (sigma.clone(), sigma.clone());
                sp[i] += h;
                sm[i] = (sm[i] - h).max(0.0);
                let fd = (ref_loss(&b, &sp, &rgb, &bg, &lc) - ref_loss(&b, &sm, &rgb, &bg, &lc)) / (sp[i] - sm[i]);
                assert!((g.d_sigma[i] as f64 - fd).abs() < 1e-4 * (1.0 + fd.abs()), "d_sigma[{i}] {} vs {fd}", g.d_sigma[i]);
                for ch in 0..3 {
                    let (mut cp, mut cm) = (rgb.clone(), rgb.clone());
                    cp[i][ch] += h;
                    cm[i][ch] -= h;
                    let fd = (ref_loss(&b, &sigma, &cp, &bg, &lc) - ref_loss(&b, &sigma, &cm, &bg, &lc)) / (2.0 * h);
                    assert!((g.d_rgb[i][ch] as f64 - fd).abs() < 1e-5, "d_rgb[{i}]");
                }
            }
            for r in 0..counts.len() {
                for ch in 0..3 {
                    let (mut bp, mut bm) = (bg.clone(), bg.clone());
                    bp[r][ch] += h;
                    bm[r][ch] -= h;
                    let fd = (ref_loss(&b, &sigma, &rgb, &bp, &lc) - ref_loss(&b, &sigma, &rgb, &bm, &lc)) / (2.0 * h);
                    assert!((g.d_background[r][ch] as f64 - fd).abs() < 1e-5, "d_bg[{r}]");
                }
            }
        }
    }

    /// The distortion loss written directly (double sum), in f64.
    fn ref_distortion(b: &Batch, w: &[f64], scale: f64) -> Vec<f64> {
        (0..b.offsets.len() - 1)
            .map(|r| {
                let (s0, s1) = (b.offsets[r] as usize, b.offsets[r + 1] as usize);
                let m = |i: usize| 0.5 * (b.t0[i] as f64 + b.t1[i] as f64) * scale;
                let mut l = 0.0;
                for i in s0..s1 {
                    for j in s0..s1 {
                        l += w[i] * w[j] * (m(i) - m(j)).abs();
                    }
                    l += w[i] * w[i] * (b.t1[i] as f64 - b.t0[i] as f64) * scale / 3.0;
                }
                l
            })
            .collect()
    }

    #[test]
    fn distortion_worked_example_and_f64_reference() {
        let (l, g) = distortion(&[0, 2], &[0.5, 0.5], &[0.0, 2.0], &[1.0, 3.0], 1.0, &[1.0]);
        assert!((l[0] - 1.166_667).abs() < 1e-6 && g.iter().all(|g| (g - 7.0 / 3.0).abs() < 1e-6), "{l:?} {g:?}");
        // Losses against the double sum; weight gradients against finite differences of it.
        let counts = [0usize, 1, 2, 3, 17, 64];
        let b = batch(&counts, 8, 3.0);
        let w: Vec<f32> = forward(&b).weights;
        let scale = 0.37;
        let d_loss: Vec<f32> = (0..counts.len()).map(|r| 0.5 + rnd(300 + r as u64) as f32).collect();
        let (l, g) = distortion(&b.offsets, &w, &b.t0, &b.t1, scale, &d_loss);
        let w64: Vec<f64> = w.iter().map(|&v| v as f64).collect();
        let total = |w: &[f64]| ref_distortion(&b, w, scale as f64).iter().zip(&d_loss).map(|(l, d)| l * *d as f64).sum::<f64>();
        for (r, want) in ref_distortion(&b, &w64, scale as f64).iter().enumerate() {
            assert!((l[r] as f64 - want).abs() < 1e-5 * (1.0 + want), "ray {r}: {} vs {want}", l[r]);
        }
        let h = 1e-6;
        for i in 0..w.len() {
            let (mut p, mut m) = (w64.clone(), w64.clone());
            p[i] += h;
            m[i] -= h;
            let fd = (total(&p) - total(&m)) / (2.0 * h);
            assert!((g[i] as f64 - fd).abs() < 1e-4 * (1.0 + fd.abs()), "dL/dw[{i}] {} vs {fd}", g[i]);
        }
    }

    #[test]
    fn distortion_gradient_reaches_densities_exactly() {
        // L = Σ_r c_r L_dist(w(σ)) + the colour/opacity/distance terms: d/dσ through
        // `composite_backward` with `d_weights` against finite differences of the f64 references.
        let counts = [0usize, 1, 3, 9, 30];
        for (seed, scale) in [(11u64, 1.0f64), (12, 15.0)] {
            let b = batch(&counts, seed, scale);
            let lc = loss_coeffs(counts.len());
            let c: Vec<f32> = (0..counts.len()).map(|r| 0.2 + rnd(400 + r as u64) as f32).collect();
            let ds = 0.8f32;
            let out = forward(&b);
            let (_, dw) = distortion(&b.offsets, &out.weights, &b.t0, &b.t1, ds, &c);
            let g = composite_backward(&b.inputs(), &out, &OutputGrads { d_rgb: &lc.0, d_opacity: &lc.1, d_distance: &lc.2, d_weights: Some(&dw) });
            let (sigma, rgb, bg) = to64(&b);
            let total = |s: &[f64]| {
                let w = reference(&b, s, &rgb, &bg).weights;
                ref_loss(&b, s, &rgb, &bg, &lc) + ref_distortion(&b, &w, ds as f64).iter().zip(&c).map(|(l, c)| l * *c as f64).sum::<f64>()
            };
            let h = 1e-6;
            for i in 0..sigma.len() {
                let (mut sp, mut sm) = (sigma.clone(), sigma.clone());
                sp[i] += h;
                sm[i] = (sm[i] - h).max(0.0);
                let fd = (total(&sp) - total(&sm)) / (sp[i] - sm[i]);
                assert!((g.d_sigma[i] as f64 - fd).abs() < 2e-4 * (1.0 + fd.abs()), "d_sigma[{i}] {} vs {fd}", g.d_sigma[i]);
            }
        }
    }

    #[test]
    fn extreme_inputs_stay_finite() {
        let sigmas = [0.0f32, 1e-8, 1.0, 1e4, 1e10, f32::INFINITY, f32::MAX];
        let deltas = [0.0f32, 1e-12, 1e-3, 1.0, 1e3];
        let mut offsets = vec![0u32];
        let (mut sigma, mut t0, mut t1) = (vec![], vec![], vec![]);
        for n in [1usize, 2, 16, 4096] {
            for (k, &s) in sigmas.iter().enumerate() {
                for (m, &d) in deltas.iter().enumerate() {
                    let mut t = 0.0f32;
                    for i in 0..n {
                        // mix the extreme with ordinary samples
                        let (si, di) = if (i + k + m) % 3 == 0 { (s, d) } else { (sigmas[(i + k) % 7], deltas[(i + m) % 5]) };
                        sigma.push(si);
                        t0.push(t);
                        t += di;
                        t1.push(t);
                    }
                    offsets.push(sigma.len() as u32);
                }
            }
        }
        let n_rays = offsets.len() - 1;
        let rgb = vec![[0.3, 0.6, 0.9]; sigma.len()];
        let bg = vec![[1.0; 3]; n_rays];
        let out = composite_forward(&CompositeInputs { offsets: &offsets, sigma: &sigma, rgb: &rgb, t_start: &t0, t_end: &t1, background: &bg });
        let ones = vec![1.0f32; n_rays];
        let g = composite_backward(&CompositeInputs { offsets: &offsets, sigma: &sigma, rgb: &rgb, t_start: &t0, t_end: &t1, background: &bg }, &out, &OutputGrads { d_rgb: &vec![[1.0; 3]; n_rays], d_opacity: &ones, d_distance: &ones, d_weights: None });
        assert!(out.rgb.iter().flatten().all(|v| v.is_finite()));
        assert!(out.opacity.iter().all(|v| v.is_finite() && (0.0..=1.0 + 1e-5).contains(v)));
        assert!(out.distance.iter().all(|v| v.is_finite()));
        assert!(out.weights.iter().all(|v| v.is_finite() && *v >= 0.0));
        assert!(g.d_sigma.iter().all(|v| v.is_finite()));
        assert!(g.d_rgb.iter().flatten().all(|v| v.is_finite()));
        assert!(g.d_background.iter().flatten().all(|v| v.is_finite()));
        assert_eq!(out.n_nan, 0);
    }

    #[test]
    fn nan_inputs_are_zeroed_and_counted() {
        let nan = f32::NAN;
        let offsets = [0u32, 3, 3];
        let sigma = [1.0, nan, 2.0];
        let rgb = [[0.5, nan, 0.5], [1.0; 3], [0.2; 3]];
        let t0 = [0.0, 1.0, 2.0];
        let t1 = [1.0, 2.0, 3.0];
        let bg = [[0.0; 3], [nan, 0.0, 0.0]];
        let out = composite_forward(&CompositeInputs { offsets: &offsets, sigma: &sigma, rgb: &rgb, t_start: &t0, t_end: &t1, background: &bg });
        assert_eq!(out.n_nan, 3);
        // the NaN density behaves as density 0
        let clean = composite_forward(&CompositeInputs { offsets: &offsets, sigma: &[1.0, 0.0, 2.0], rgb: &[[0.5, 0.0, 0.5], [1.0; 3], [0.2; 3]], t_start: &t0, t_end: &t1, background: &[[0.0; 3]; 2] });
        assert_eq!(out.rgb, clean.rgb);
        assert_eq!(out.weights, clean.weights);
        let ones = [1.0f32; 2];
        let g = composite_backward(&CompositeInputs { offsets: &offsets, sigma: &sigma, rgb: &rgb, t_start: &t0, t_end: &t1, background: &bg }, &out, &OutputGrads { d_rgb: &[[1.0; 3]; 2], d_opacity: &ones, d_distance: &ones, d_weights: None });
        assert_eq!(g.d_sigma[1], 0.0);
        assert!(g.d_sigma.iter().chain(g.d_rgb.iter().flatten()).all(|v| v.is_finite()));
    }

    #[test]
    fn early_termination_error_is_below_threshold() {
        let counts = vec![300usize; 64];
        let b = batch(&counts, 9, 40.0);
        let exact = forward(&b);
        let fast = composite_forward_with(&b.inputs(), CompositeOptions::INFERENCE);
        let mut stopped = 0;
        for r in 0..counts.len() {
            for ch in 0..3 {
                assert!((exact.rgb[r][ch] - fast.rgb[r][ch]).abs() < 1e-4);
            }
            assert!((exact.opacity[r] - fast.opacity[r]).abs() < 1e-4);
            stopped += usize::from(fast.weights[b.offsets[r + 1] as usize - 1] == 0.0);
        }
        assert!(stopped > 0, "the test data must exercise early termination");
    }

    #[test]
    fn deterministic_across_thread_counts() {
        let b = batch(&[10, 0, 300, 33, 1000, 2, 77], 11, 10.0);
        let lc = loss_coeffs(7);
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                let o = forward(&b);
                let g = composite_backward(&b.inputs(), &o, &OutputGrads { d_rgb: &lc.0, d_opacity: &lc.1, d_distance: &lc.2, d_weights: None });
                (o, g)
            })
        };
        let (o1, g1) = run(1);
        let (o3, g3) = run(3);
        assert_eq!(o1, o3);
        assert_eq!(g1, g3);
    }

    #[test]
    fn activations() {
        assert!((trunc_exp(1.0) - std::f32::consts::E).abs() < 1e-6);
        assert_eq!(trunc_exp(100.0), 15f32.exp());
        assert!(trunc_exp(1e30).is_finite());
        assert_eq!(trunc_exp(f32::NAN), 0.0);
        assert_eq!(trunc_exp_backward(100.0, 1.0), 15f32.exp());
        assert_eq!(trunc_exp_backward(-100.0, 1.0), (-15f32).exp());
        assert!((trunc_exp_backward(0.5, 2.0) - 2.0 * 0.5f32.exp()).abs() < 1e-6);
        assert!((softplus(0.0) - std::f32::consts::LN_2).abs() < 1e-7);
        assert_eq!(softplus(100.0), 100.0);
        assert!(softplus(-100.0) >= 0.0 && softplus(-100.0) < 1e-40);
        assert!(softplus(1e30).is_finite());
        for x in [-20.0f32, -3.0, -0.1, 0.0, 0.7, 4.0, 30.0] {
            let h = 1e-3f64;
            let sp = |v: f64| v.max(0.0) + (-v.abs()).exp().ln_1p();
            let fd = (sp(x as f64 + h) - sp(x as f64 - h)) / (2.0 * h);
            assert!((softplus_backward(x, 1.0) as f64 - fd).abs() < 1e-5, "x = {x}");
            assert!((softplus(x) as f64 - sp(x as f64)).abs() < 1e-6 * (1.0 + x.abs() as f64));
        }
        assert_eq!(softplus_backward(f32::NAN, 1.0), 0.0);
        assert!(softplus_backward(-1e30, 1.0) == 0.0 && softplus_backward(1e30, 1.0) == 1.0);
    }

    /// `cargo test -p nerf composite_timing -- --ignored --nocapture`
    #[test]
    #[ignore]
    fn composite_timing() {
        let (n_rays, per_ray) = (4096usize, 256usize);
        let b = batch(&vec![per_ray; n_rays], 12, 10.0);
        let lc = loss_coeffs(n_rays);
        let mut best = (f64::MAX, f64::MAX);
        for _ in 0..5 {
            let t0 = std::time::Instant::now();
            let o = forward(&b);
            let t1 = std::time::Instant::now();
            let g = composite_backward(&b.inputs(), &o, &OutputGrads { d_rgb: &lc.0, d_opacity: &lc.1, d_distance: &lc.2, d_weights: None });
            let t2 = std::time::Instant::now();
            assert!(g.d_sigma.iter().all(|v| v.is_finite()));
            best.0 = best.0.min((t1 - t0).as_secs_f64());
            best.1 = best.1.min((t2 - t1).as_secs_f64());
        }
        let n = (n_rays * per_ray) as f64;
        println!(
            "composite {n_rays} rays x {per_ray} samples, {} threads: forward {:.1} ms ({:.0} M samples/s), backward {:.1} ms ({:.0} M samples/s)",
            rayon::current_num_threads(),
            best.0 * 1e3,
            n / best.0 / 1e6,
            best.1 * 1e3,
            n / best.1 / 1e6
        );
    }
}
