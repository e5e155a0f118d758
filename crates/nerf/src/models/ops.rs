//! Plain-Rust kernels the models need, with hand-written backward passes: counter-based
//! random numbers, density activations, ragged volume compositing, spherical harmonics,
//! positional encoding, the multiresolution hash grid with a sparse Adam, stratified and
//! importance sampling, ray–box clipping and the occupancy grid.
//!
//! These are the models' private minimal versions, written because the shared kernels
//! (`volrend`, `encoding`, `sampling`, `occupancy`) had not landed when the models were
//! written; they follow the same formulas and shapes so the models can switch over.
//!
//! Every loop that runs in parallel writes disjoint outputs in a fixed order, so results are
//! bit-identical whatever the thread count.

use rayon::prelude::*;

// ---------------------------------------------------------------------------------------------
// Counter-based random numbers
// ---------------------------------------------------------------------------------------------

/// SplitMix64's finaliser: a bijective 64-bit mix.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A uniform number in [0, 1) that depends only on `(seed, stream, a, b)`.
#[inline]
pub fn uniform(seed: u64, stream: u64, a: u64, b: u64) -> f32 {
    let h = mix64(seed ^ mix64(stream.wrapping_add(0x9e37_79b9_7f4a_7c15) ^ mix64(a ^ mix64(b.wrapping_add(1)))));
    (h >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
}

/// Random streams (the `stream` key of [`uniform`]).
pub mod stream {
    /// Which training pixel a ray of the batch uses.
    pub const PIXEL: u64 = 1;
    /// Stratified jitter along rays.
    pub const STRATIFIED: u64 = 2;
    /// Importance-sampling jitter.
    pub const PDF: u64 = 3;
    /// Random background colours.
    pub const BACKGROUND: u64 = 4;
    /// Occupancy-grid update points.
    pub const OCCUPANCY: u64 = 5;
    /// Parameter initialisation.
    pub const INIT: u64 = 6;
    /// Validation pixel subset.
    pub const VAL: u64 = 7;
    /// Marching start offset.
    pub const MARCH: u64 = 8;
}

// ---------------------------------------------------------------------------------------------
// Activations
// ---------------------------------------------------------------------------------------------

/// Density activation, applied in Rust to the network's raw density output.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DensityActivation {
    /// `max(x, 0)` (the NeRF paper).
    Relu,
    /// `ln(1 + e^x)` (smooth; mip-NeRF and nerfstudio).
    Softplus,
    /// `exp(min(x, 15))` with the gradient clamped the same way (instant-ngp).
    TruncExp,
}

impl DensityActivation {
    /// σ = f(x).
    #[inline]
    pub fn forward(self, x: f32) -> f32 {
        match self {
            Self::Relu => x.max(0.0),
            Self::Softplus => {
                if x > 20.0 { x } else { x.exp().ln_1p() }
            }
            Self::TruncExp => x.min(15.0).exp(),
        }
    }
    /// df/dx.
    #[inline]
    pub fn derivative(self, x: f32) -> f32 {
        match self {
            Self::Relu => {
                if x > 0.0 { 1.0 } else { 0.0 }
            }
            Self::Softplus => 1.0 / (1.0 + (-x).exp()),
            Self::TruncExp => x.min(15.0).exp(),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Volume rendering
// ---------------------------------------------------------------------------------------------

/// Samples of a batch of rays, ragged: ray `r` owns samples `offsets[r]..offsets[r + 1]`.
///
/// # Shapes
/// `offsets`: rays + 1; `t`, `t_start`, `t_end`: samples. `t` is where the field is evaluated,
/// `[t_start, t_end]` the interval it stands for (δ = `t_end − t_start`).
#[derive(Clone, Debug, Default)]
pub struct RaySamples {
    /// Prefix offsets into the sample arrays.
    pub offsets: Vec<u32>,
    /// Evaluation distance along the ray.
    pub t: Vec<f32>,
    /// Interval start.
    pub t_start: Vec<f32>,
    /// Interval end.
    pub t_end: Vec<f32>,
}

impl RaySamples {
    /// Number of rays.
    pub fn rays(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t.len()
    }
    /// Whether there are no samples.
    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }
    /// Sample range of ray `r`.
    pub fn range(&self, r: usize) -> std::ops::Range<usize> {
        self.offsets[r] as usize..self.offsets[r + 1] as usize
    }
    /// World positions of all samples.
    pub fn points(&self, origins: &[[f32; 3]], dirs: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let mut out = vec![[0.0; 3]; self.len()];
        for r in 0..self.rays() {
            let (o, d) = (origins[r], dirs[r]);
            for s in self.range(r) {
                let t = self.t[s];
                out[s] = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
            }
        }
        out
    }
    /// The direction of each sample's ray.
    pub fn sample_dirs(&self, dirs: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let mut out = vec![[0.0; 3]; self.len()];
        for r in 0..self.rays() {
            for s in self.range(r) {
                out[s] = dirs[r];
            }
        }
        out
    }
}

/// Per-ray results of [`composite_forward`].
#[derive(Clone, Debug, Default)]
pub struct Composite {
    /// Colour with the background composited by (1 − opacity).
    pub rgb: Vec<[f32; 3]>,
    /// Σ w.
    pub opacity: Vec<f32>,
    /// Σ w t / Σ w (0 where opacity is 0): the expected distance of the visible surface.
    pub distance: Vec<f32>,
    /// Per-sample weights w.
    pub weights: Vec<f32>,
}

/// Volume rendering of ragged samples (NeRF's quadrature):
/// αᵢ = 1 − exp(−σᵢδᵢ), Tᵢ = exp(−Σ_{j<i} σⱼδⱼ), wᵢ = Tᵢαᵢ, C = Σ wᵢcᵢ + (1 − Σ wᵢ)·bg.
///
/// Example: one sample with σδ = ln 2 gives α = ½, so C = ½c + ½bg.
pub fn composite_forward(
    samples: &RaySamples,
    sigma: &[f32],
    rgb: &[[f32; 3]],
    background: &[[f32; 3]],
) -> Composite {
    let n_rays = samples.rays();
    let mut out = Composite {
        rgb: vec![[0.0; 3]; n_rays],
        opacity: vec![0.0; n_rays],
        distance: vec![0.0; n_rays],
        weights: vec![0.0; samples.len()],
    };
    for r in 0..n_rays {
        let mut acc = 0.0f32; // Σ σδ so far
        let (mut c, mut o, mut d) = ([0.0f32; 3], 0.0f32, 0.0f32);
        for s in samples.range(r) {
            let sd = sigma[s] * (samples.t_end[s] - samples.t_start[s]);
            let t0 = (-acc).exp();
            acc += sd;
            let w = t0 - (-acc).exp();
            out.weights[s] = w;
            for k in 0..3 {
                c[k] += w * rgb[s][k];
            }
            o += w;
            d += w * samples.t[s];
        }
        let bg = background[r];
        out.rgb[r] = [c[0] + (1.0 - o) * bg[0], c[1] + (1.0 - o) * bg[1], c[2] + (1.0 - o) * bg[2]];
        out.opacity[r] = o;
        out.distance[r] = if o > 1e-6 { d / o } else { 0.0 };
    }
    out
}

/// Gradients of a loss L through [`composite_forward`]'s colour, given `d_rgb` = ∂L/∂C per ray.
///
/// With Sᵢ = σᵢδᵢ and T_N the final transmittance:
/// ∂C/∂Sᵢ = T_{i+1}cᵢ − Σ_{k>i} w_k c_k − T_N·bg, ∂C/∂cᵢ = wᵢ, ∂C/∂bg = T_N.
/// Returns (∂L/∂σ, ∂L/∂c) per sample.
pub fn composite_backward(
    samples: &RaySamples,
    sigma: &[f32],
    rgb: &[[f32; 3]],
    background: &[[f32; 3]],
    weights: &[f32],
    d_rgb: &[[f32; 3]],
) -> (Vec<f32>, Vec<[f32; 3]>) {
    let mut d_sigma = vec![0.0f32; samples.len()];
    let mut d_c = vec![[0.0f32; 3]; samples.len()];
    for r in 0..samples.rays() {
        let range = samples.range(r);
        let g = d_rgb[r];
        let total: f32 = range.clone().map(|s| sigma[s] * (samples.t_end[s] - samples.t_start[s])).sum();
        let t_final = (-total).exp();
        let bg = background[r];
        // suffix = Σ_{k>i} w_k c_k, walked from the back.
        let mut suffix = [0.0f32; 3];
        let mut acc_after = total; // Σ_{j≤i} S_j, decreasing as we walk back
        for s in range.rev() {
            let sd = sigma[s] * (samples.t_end[s] - samples.t_start[s]);
            let t_next = (-acc_after).exp(); // T_{i+1}
            let mut ds = 0.0;
            for k in 0..3 {
                ds += g[k] * (t_next * rgb[s][k] - suffix[k] - t_final * bg[k]);
                d_c[s][k] = g[k] * weights[s];
                suffix[k] += weights[s] * rgb[s][k];
            }
            d_sigma[s] = ds * (samples.t_end[s] - samples.t_start[s]);
            acc_after -= sd;
        }
    }
    (d_sigma, d_c)
}

// ---------------------------------------------------------------------------------------------
// Direction and position encodings
// ---------------------------------------------------------------------------------------------

/// Number of real spherical-harmonic coefficients of degree < `degree` (degree 4 → 16).
pub fn sh_dims(degree: usize) -> usize {
    degree * degree
}

/// Real spherical harmonics of a unit direction, bands 0..`degree` (≤ 4), as instant-ngp.
pub fn sh_encode(d: [f32; 3], degree: usize, out: &mut [f32]) {
    let [x, y, z] = d;
    let (xx, yy, zz) = (x * x, y * y, z * z);
    let (xy, yz, xz) = (x * y, y * z, x * z);
    let all = [
        0.282_094_8,
        -0.488_602_5 * y,
        0.488_602_5 * z,
        -0.488_602_5 * x,
        1.092_548_4 * xy,
        -1.092_548_4 * yz,
        0.946_174_7 * zz - 0.315_391_57,
        -1.092_548_4 * xz,
        0.546_274_2 * (xx - yy),
        0.590_043_6 * y * (-3.0 * xx + yy),
        2.890_611_4 * xy * z,
        0.457_045_8 * y * (1.0 - 5.0 * zz),
        0.373_176_3 * z * (5.0 * zz - 3.0),
        0.457_045_8 * x * (1.0 - 5.0 * zz),
        1.445_305_7 * z * (xx - yy),
        0.590_043_6 * x * (-xx + 3.0 * yy),
    ];
    let n = sh_dims(degree.min(4));
    out[..n].copy_from_slice(&all[..n]);
}

/// Width of NeRF's positional encoding with `freqs` frequencies of a 3-vector, input included:
/// 3 + 3·2·freqs.
pub fn frequency_dims(freqs: usize) -> usize {
    3 + 6 * freqs
}

/// NeRF's positional encoding γ(p) = (p, sin(2⁰πp), cos(2⁰πp), …, sin(2^{L−1}πp), cos(2^{L−1}πp)).
/// The original code omits π (its inputs lie in about [−1.5, 1.5]); we keep it out too and feed
/// positions normalised to [−1, 1].
pub fn frequency_encode(p: [f32; 3], freqs: usize, out: &mut [f32]) {
    out[..3].copy_from_slice(&p);
    let mut k = 3;
    for l in 0..freqs {
        let f = (1u32 << l) as f32;
        for c in 0..3 {
            out[k + c] = (f * p[c]).sin();
            out[k + 3 + c] = (f * p[c]).cos();
        }
        k += 6;
    }
}

// ---------------------------------------------------------------------------------------------
// Multiresolution hash encoding
// ---------------------------------------------------------------------------------------------

/// Settings of the multiresolution hash encoding (Müller et al. 2022).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct HashGridSettings {
    /// Number of levels L.
    pub levels: usize,
    /// Features per level F.
    pub features_per_level: usize,
    /// log2 of the maximum entries per level T.
    pub log2_table_size: u32,
    /// Coarsest resolution N_min.
    pub base_resolution: u32,
    /// Finest resolution N_max.
    pub finest_resolution: u32,
}

/// The hash grid's parameters: one table per level, `entries[l] × F` floats.
#[derive(Clone, Debug)]
pub struct HashGrid {
    /// Settings.
    pub settings: HashGridSettings,
    /// Resolution per level.
    pub resolutions: Vec<u32>,
    /// Entries per level.
    pub entries: Vec<usize>,
    /// Offset of each level's table in `params` (in floats).
    pub level_offset: Vec<usize>,
    /// All tables, flat.
    pub params: Vec<f32>,
}

const PRIMES: [u32; 3] = [1, 2_654_435_761, 805_459_861];

impl HashGrid {
    /// A grid with entries drawn uniformly from [−1e-4, 1e-4] (instant-ngp), keyed by `seed`.
    pub fn new(settings: HashGridSettings, seed: u64) -> Self {
        let l = settings.levels.max(1);
        let growth = if l > 1 {
            ((settings.finest_resolution as f64).ln() - (settings.base_resolution as f64).ln()) / (l as f64 - 1.0)
        } else {
            0.0
        }
        .exp();
        let max_entries = 1usize << settings.log2_table_size;
        let mut resolutions = Vec::new();
        let mut entries = Vec::new();
        let mut level_offset = Vec::new();
        let mut total = 0;
        for level in 0..l {
            let res = (settings.base_resolution as f64 * growth.powi(level as i32)).floor() as u32;
            let dense = (res as usize + 1).pow(3);
            let n = dense.min(max_entries);
            resolutions.push(res);
            entries.push(n);
            level_offset.push(total);
            total += n * settings.features_per_level;
        }
        let params = (0..total)
            .map(|k| (uniform(seed, stream::INIT, 0xabcd, k as u64) * 2.0 - 1.0) * 1e-4)
            .collect();
        Self { settings, resolutions, entries, level_offset, params }
    }

    /// Output width L·F.
    pub fn output_dims(&self) -> usize {
        self.settings.levels * self.settings.features_per_level
    }

    #[inline]
    fn corners(&self, level: usize, p: [f32; 3]) -> ([usize; 8], [f32; 8]) {
        let res = self.resolutions[level];
        let n = self.entries[level];
        let dense = (res as usize + 1).pow(3) <= n;
        let mut base = [0u32; 3];
        let mut frac = [0f32; 3];
        for c in 0..3 {
            let x = p[c].clamp(0.0, 1.0) * res as f32;
            let f = x.floor().min(res as f32 - 1.0).max(0.0);
            base[c] = f as u32;
            frac[c] = x - f;
        }
        let mut idx = [0usize; 8];
        let mut w = [0f32; 8];
        for k in 0..8 {
            let mut wk = 1.0;
            let mut g = [0u32; 3];
            for c in 0..3 {
                let bit = (k >> c) & 1;
                g[c] = base[c] + bit as u32;
                wk *= if bit == 1 { frac[c] } else { 1.0 - frac[c] };
            }
            idx[k] = if dense {
                let r = res as usize + 1;
                g[0] as usize + r * (g[1] as usize + r * g[2] as usize)
            } else {
                let h = g[0].wrapping_mul(PRIMES[0]) ^ g[1].wrapping_mul(PRIMES[1]) ^ g[2].wrapping_mul(PRIMES[2]);
                // Hashed levels have a power-of-two table (dense ones index directly).
                h as usize & (n - 1)
            };
            w[k] = wk;
        }
        (idx, w)
    }

    /// Encodes points in [0, 1]³ (clamped) into `out` (points × L·F, level-major per point).
    pub fn encode(&self, points: &[[f32; 3]], out: &mut [f32]) {
        let f = self.settings.features_per_level;
        let dims = self.output_dims();
        out.par_chunks_mut(dims * 1024).zip(points.par_chunks(1024)).for_each(|(o, pts)| {
            for (i, p) in pts.iter().enumerate() {
                for level in 0..self.settings.levels {
                    let (idx, w) = self.corners(level, *p);
                    let table = &self.params[self.level_offset[level]..];
                    let dst = &mut o[i * dims + level * f..i * dims + (level + 1) * f];
                    dst.fill(0.0);
                    for k in 0..8 {
                        let e = &table[idx[k] * f..idx[k] * f + f];
                        for j in 0..f {
                            dst[j] += w[k] * e[j];
                        }
                    }
                }
            }
        });
    }

    /// Scatters ∂L/∂out into ∂L/∂params (`grad`, same layout as `params`, accumulated) and marks
    /// the touched entries in `touched` (one flag per entry over all levels). Parallel over
    /// levels, each writing its own table.
    pub fn backward(&self, points: &[[f32; 3]], d_out: &[f32], grad: &mut [f32], touched: &mut [bool]) {
        let f = self.settings.features_per_level;
        let dims = self.output_dims();
        let mut grad_levels: Vec<&mut [f32]> = Vec::new();
        let mut touched_levels: Vec<&mut [bool]> = Vec::new();
        let (mut g_rest, mut t_rest) = (grad, touched);
        for level in 0..self.settings.levels {
            let (g, gr) = g_rest.split_at_mut(self.entries[level] * f);
            let (t, tr) = t_rest.split_at_mut(self.entries[level]);
            grad_levels.push(g);
            touched_levels.push(t);
            g_rest = gr;
            t_rest = tr;
        }
        grad_levels.into_par_iter().zip(touched_levels).enumerate().for_each(|(level, (g, t))| {
            for (i, p) in points.iter().enumerate() {
                let d = &d_out[i * dims + level * f..i * dims + (level + 1) * f];
                if d.iter().all(|v| *v == 0.0) {
                    continue;
                }
                let (idx, w) = self.corners(level, *p);
                for k in 0..8 {
                    t[idx[k]] = true;
                    for j in 0..f {
                        g[idx[k] * f + j] += w[k] * d[j];
                    }
                }
            }
        });
    }
}

/// Adam on a flat parameter vector that updates only the entries whose gradient was touched
/// this step (a sparse / lazy Adam: untouched entries keep their moments and values). The step
/// counter for bias correction is global.
#[derive(Clone, Debug)]
pub struct SparseAdam {
    /// β₁.
    pub beta1: f32,
    /// β₂.
    pub beta2: f32,
    /// ε.
    pub eps: f32,
    /// Steps taken.
    pub step: u64,
    /// First moments.
    pub m: Vec<f32>,
    /// Second moments.
    pub v: Vec<f32>,
}

impl SparseAdam {
    /// Zero state for `n` parameters.
    pub fn new(n: usize, beta1: f32, beta2: f32, eps: f32) -> Self {
        Self { beta1, beta2, eps, step: 0, m: vec![0.0; n], v: vec![0.0; n] }
    }

    /// One step with learning rate `lr`; `group` parameters share one `touched` flag.
    pub fn step(&mut self, lr: f32, params: &mut [f32], grad: &[f32], touched: &[bool], group: usize) {
        self.step += 1;
        let bc1 = 1.0 - self.beta1.powi(self.step as i32);
        let bc2 = 1.0 - self.beta2.powi(self.step as i32);
        let (b1, b2, eps) = (self.beta1, self.beta2, self.eps);
        params
            .par_chunks_mut(group * 4096)
            .zip(self.m.par_chunks_mut(group * 4096))
            .zip(self.v.par_chunks_mut(group * 4096))
            .zip(grad.par_chunks(group * 4096))
            .zip(touched.par_chunks(4096))
            .for_each(|((((p, m), v), g), t)| {
                for (e, &hit) in t.iter().enumerate() {
                    if !hit {
                        continue;
                    }
                    for j in e * group..(e + 1) * group {
                        m[j] = b1 * m[j] + (1.0 - b1) * g[j];
                        v[j] = b2 * v[j] + (1.0 - b2) * g[j] * g[j];
                        p[j] -= lr * (m[j] / bc1) / ((v[j] / bc2).sqrt() + eps);
                    }
                }
            });
    }
}

// ---------------------------------------------------------------------------------------------
// Samplers
// ---------------------------------------------------------------------------------------------

/// Entry and exit distance of a ray in an axis-aligned box, or `None` when it misses.
pub fn ray_aabb(o: [f32; 3], d: [f32; 3], lo: [f32; 3], hi: [f32; 3]) -> Option<(f32, f32)> {
    let (mut t0, mut t1) = (f32::NEG_INFINITY, f32::INFINITY);
    for c in 0..3 {
        let inv = 1.0 / d[c];
        let (a, b) = ((lo[c] - o[c]) * inv, (hi[c] - o[c]) * inv);
        let (a, b) = if a <= b { (a, b) } else { (b, a) };
        if a.is_nan() || b.is_nan() {
            if o[c] < lo[c] || o[c] > hi[c] {
                return None;
            }
            continue;
        }
        t0 = t0.max(a);
        t1 = t1.min(b);
    }
    (t1 > t0.max(0.0)).then_some((t0.max(0.0), t1))
}

/// Stratified samples: `n` equal bins over [near, far] per ray, one point per bin, jittered
/// uniformly inside it when `jitter` is `Some((seed, step))` (keyed by ray id), else at bin
/// centres. Each sample's interval is its bin.
pub fn stratified(near: &[f32], far: &[f32], n: usize, jitter: Option<(u64, u64)>, ray_ids: &[u64]) -> RaySamples {
    let rays = near.len();
    let mut s = RaySamples {
        offsets: (0..=rays).map(|r| (r * n) as u32).collect(),
        t: Vec::with_capacity(rays * n),
        t_start: Vec::with_capacity(rays * n),
        t_end: Vec::with_capacity(rays * n),
    };
    for r in 0..rays {
        let dt = (far[r] - near[r]) / n as f32;
        for i in 0..n {
            let a = near[r] + i as f32 * dt;
            let u = match jitter {
                Some((seed, step)) => uniform(seed, stream::STRATIFIED, step, ray_ids[r] * 4096 + i as u64),
                None => 0.5,
            };
            s.t.push(a + u * dt);
            s.t_start.push(a);
            s.t_end.push(a + dt);
        }
    }
    s
}

/// Importance sampling (NeRF's `sample_pdf`): draws `n` distances per ray from the piecewise-
/// constant density given by `weights` over the intervals of `coarse`, merges them with the
/// coarse sample points, sorts, and gives each point the interval between the midpoints to its
/// neighbours (clamped to the coarse range). `jitter` as in [`stratified`].
pub fn importance(coarse: &RaySamples, weights: &[f32], n: usize, jitter: Option<(u64, u64)>, ray_ids: &[u64]) -> RaySamples {
    let mut out = RaySamples { offsets: vec![0], ..Default::default() };
    let mut ts: Vec<f32> = Vec::new();
    let mut cdf: Vec<f32> = Vec::new();
    for r in 0..coarse.rays() {
        let range = coarse.range(r);
        ts.clear();
        cdf.clear();
        let total: f32 = range.clone().map(|s| weights[s] + 1e-5).sum();
        let mut acc = 0.0;
        cdf.push(0.0);
        for s in range.clone() {
            acc += (weights[s] + 1e-5) / total;
            cdf.push(acc);
        }
        let starts: Vec<f32> = range.clone().map(|s| coarse.t_start[s]).collect();
        let ends: Vec<f32> = range.clone().map(|s| coarse.t_end[s]).collect();
        for i in 0..n {
            let u = match jitter {
                Some((seed, step)) => (i as f32 + uniform(seed, stream::PDF, step, ray_ids[r] * 4096 + i as u64)) / n as f32,
                None => (i as f32 + 0.5) / n as f32,
            };
            let u = u.min(cdf[cdf.len() - 1] * 0.999_999);
            let b = cdf.partition_point(|c| *c <= u).saturating_sub(1).min(starts.len() - 1);
            let span = (cdf[b + 1] - cdf[b]).max(1e-12);
            let f = ((u - cdf[b]) / span).clamp(0.0, 1.0);
            ts.push(starts[b] + f * (ends[b] - starts[b]));
        }
        ts.extend(range.clone().map(|s| coarse.t[s]));
        ts.sort_by(f32::total_cmp);
        let (lo, hi) = (starts[0], ends[ends.len() - 1]);
        for k in 0..ts.len() {
            let a = if k == 0 { lo } else { 0.5 * (ts[k - 1] + ts[k]) };
            let b = if k + 1 == ts.len() { hi } else { 0.5 * (ts[k] + ts[k + 1]) };
            out.t.push(ts[k]);
            out.t_start.push(a);
            out.t_end.push(b);
        }
        out.offsets.push(out.t.len() as u32);
    }
    out
}

// ---------------------------------------------------------------------------------------------
// Occupancy grid
// ---------------------------------------------------------------------------------------------

/// A cubic occupancy grid over an axis-aligned box, holding a running maximum of density per
/// cell (decayed by 0.95 per update, as instant-ngp) and the occupied flags derived from it.
#[derive(Clone, Debug)]
pub struct OccupancyGrid {
    /// Cells per axis.
    pub resolution: usize,
    /// Box minimum corner.
    pub lo: [f32; 3],
    /// Box maximum corner.
    pub hi: [f32; 3],
    /// Density estimate per cell (x fastest).
    pub density: Vec<f32>,
    /// Occupied flags per cell.
    pub occupied: Vec<bool>,
}

impl OccupancyGrid {
    /// A grid with every cell occupied.
    pub fn new(resolution: usize, lo: [f32; 3], hi: [f32; 3]) -> Self {
        let n = resolution.pow(3);
        Self { resolution, lo, hi, density: vec![f32::MAX; n], occupied: vec![true; n] }
    }

    /// One random point per cell (keyed by `(seed, step, cell)`), in world space.
    pub fn update_points(&self, seed: u64, step: u64) -> Vec<[f32; 3]> {
        let r = self.resolution;
        (0..r * r * r)
            .map(|c| {
                let ijk = [c % r, (c / r) % r, c / (r * r)];
                let mut p = [0.0; 3];
                for k in 0..3 {
                    let u = (ijk[k] as f32 + uniform(seed, stream::OCCUPANCY, step, (c * 3 + k) as u64)) / r as f32;
                    p[k] = self.lo[k] + u * (self.hi[k] - self.lo[k]);
                }
                p
            })
            .collect()
    }

    /// Folds new densities (one per cell, from [`Self::update_points`]) into the grid: the
    /// estimate becomes max(0.95·old, new), and a cell is occupied when its estimate times
    /// `step_size` exceeds `threshold` (nerfacc's `occ_thre` on σ·δ), or exceeds the mean
    /// estimate when that is lower.
    pub fn update(&mut self, new_density: &[f32], step_size: f32, threshold: f32) {
        for (d, n) in self.density.iter_mut().zip(new_density) {
            let old = if *d == f32::MAX { 0.0 } else { *d * 0.95 };
            *d = old.max(*n);
        }
        let mean = self.density.iter().map(|d| *d as f64).sum::<f64>() / self.density.len() as f64;
        let thr = (threshold / step_size).min(mean as f32);
        for (o, d) in self.occupied.iter_mut().zip(&self.density) {
            *o = *d > thr;
        }
    }

    /// Fraction of cells occupied.
    pub fn occupied_fraction(&self) -> f32 {
        self.occupied.iter().filter(|o| **o).count() as f32 / self.occupied.len().max(1) as f32
    }

    #[inline]
    fn is_occupied(&self, p: [f32; 3]) -> bool {
        let r = self.resolution;
        let mut idx = [0usize; 3];
        for k in 0..3 {
            let u = (p[k] - self.lo[k]) / (self.hi[k] - self.lo[k]);
            if !(0.0..1.0).contains(&u) {
                return false;
            }
            idx[k] = ((u * r as f32) as usize).min(r - 1);
        }
        self.occupied[idx[0] + r * (idx[1] + r * idx[2])]
    }

    /// Marches rays through the box with a fixed `step_size`, keeping the points in occupied
    /// cells (at most `max_samples` per ray). The start is offset by a random fraction of a
    /// step when `jitter` is given (keyed by ray id), else by half a step.
    pub fn march(
        &self,
        origins: &[[f32; 3]],
        dirs: &[[f32; 3]],
        step_size: f32,
        max_samples: usize,
        jitter: Option<(u64, u64)>,
        ray_ids: &[u64],
    ) -> RaySamples {
        let per_ray: Vec<Vec<f32>> = origins
            .par_iter()
            .zip(dirs.par_iter())
            .enumerate()
            .map(|(r, (o, d))| {
                let mut ts = Vec::new();
                let Some((t0, t1)) = ray_aabb(*o, *d, self.lo, self.hi) else { return ts };
                let u = match jitter {
                    Some((seed, step)) => uniform(seed, stream::MARCH, step, ray_ids[r]),
                    None => 0.5,
                };
                let mut t = t0 + u * step_size;
                while t < t1 && ts.len() < max_samples {
                    let p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
                    if self.is_occupied(p) {
                        ts.push(t);
                    }
                    t += step_size;
                }
                ts
            })
            .collect();
        let mut out = RaySamples { offsets: vec![0], ..Default::default() };
        for ts in per_ray {
            for t in ts {
                out.t.push(t);
                out.t_start.push(t - 0.5 * step_size);
                out.t_end.push(t + 0.5 * step_size);
            }
            out.offsets.push(out.t.len() as u32);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn composite_backward_matches_finite_differences() {
        let samples = RaySamples {
            offsets: vec![0, 3],
            t: vec![1.0, 1.5, 2.0],
            t_start: vec![0.75, 1.25, 1.75],
            t_end: vec![1.25, 1.75, 2.25],
        };
        let sigma = vec![0.7f32, 1.3, 2.1];
        let rgb = vec![[0.2, 0.5, 0.9], [0.8, 0.1, 0.3], [0.4, 0.6, 0.2]];
        let bg = vec![[1.0, 0.5, 0.25]];
        let g = [[0.3f32, -0.7, 0.5]];
        let loss = |s: &[f32]| {
            let c = composite_forward(&samples, s, &rgb, &bg).rgb[0];
            (0..3).map(|k| g[0][k] * c[k]).sum::<f32>()
        };
        let fwd = composite_forward(&samples, &sigma, &rgb, &bg);
        let (ds, _) = composite_backward(&samples, &sigma, &rgb, &bg, &fwd.weights, &g);
        for i in 0..3 {
            let mut p = sigma.clone();
            p[i] += 1e-3;
            let mut m = sigma.clone();
            m[i] -= 1e-3;
            let fd = (loss(&p) - loss(&m)) / 2e-3;
            assert!((fd - ds[i]).abs() < 1e-3, "{i}: {fd} vs {}", ds[i]);
        }
    }

    #[test]
    fn hash_grid_is_trilinear_and_backward_scatters() {
        let s = HashGridSettings { levels: 2, features_per_level: 2, log2_table_size: 10, base_resolution: 4, finest_resolution: 16 };
        let grid = HashGrid::new(s, 1);
        let pts = vec![[0.3f32, 0.6, 0.2], [0.9, 0.1, 0.5]];
        let mut out = vec![0.0; 2 * grid.output_dims()];
        grid.encode(&pts, &mut out);
        let d_out: Vec<f32> = (0..out.len()).map(|k| k as f32 * 0.1 - 0.2).collect();
        let mut grad = vec![0.0; grid.params.len()];
        let mut touched = vec![false; grid.entries.iter().sum()];
        grid.backward(&pts, &d_out, &mut grad, &mut touched);
        // Linear in params: <d_out, encode(params)> has gradient `grad`.
        let mut g2 = grid.clone();
        let k = grad.iter().position(|g| g.abs() > 0.0).unwrap();
        g2.params[k] += 1.0;
        let mut out2 = vec![0.0; out.len()];
        g2.encode(&pts, &mut out2);
        let diff: f32 = out2.iter().zip(&out).zip(&d_out).map(|((a, b), d)| (a - b) * d).sum();
        assert!((diff - grad[k]).abs() < 1e-4);
    }
}
