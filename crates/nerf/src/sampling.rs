//! Ray samplers over slices: a counter-based RNG ([`rng`]), ray–box clipping
//! ([`ray_aabb`], [`ray_aabb_bounds`]), stratified samples ([`stratified`]) and inverse-CDF
//! importance sampling from coarse weights ([`sample_pdf`], the NeRF paper's hierarchical
//! sampling).
//!
//! Samples are **intervals** `[t_start, t_end]` along the ray (nerfstudio's bins); the field is
//! evaluated at the midpoint ([`RaySamples::positions`]) and [`crate::volrend`] composites with
//! `delta = t_end − t_start`. A batch is ragged: ray `r` owns `offsets[r]..offsets[r + 1]`.
//! A ray with no valid range (`!(far > near)`, NaN, a miss) gets no sample.

// `!(a < b)` is deliberate throughout: it is true for NaN, which must count as invalid.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use serde::{Deserialize, Serialize};

/// Counter-based random numbers: every number is a pure function of its key, so results never
/// depend on thread count or evaluation order (DESIGN.md, "Randomness").
///
/// ```text
/// let k = rng::key(&[seed, step, ray, sample]);
/// let u = rng::uniform_f32(k);   // in [0, 1)
/// ```
pub mod rng {
    const GOLDEN: u64 = 0x9E37_79B9_7F4A_7C15;

    /// SplitMix64's finaliser: a bijective 64-bit mix.
    #[inline]
    pub fn mix(mut z: u64) -> u64 {
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Hashes a tuple of counters (e.g. `(seed, step, ray, sample)`) into one 64-bit key.
    /// Order matters: `key(&[1, 2]) != key(&[2, 1])`.
    #[inline]
    pub fn key(parts: &[u64]) -> u64 {
        extend(GOLDEN, parts)
    }

    /// Continues a key with more parts: `extend(key(a), b) == key(a ++ b)`, so a prefix
    /// shared by many keys (e.g. `(seed, step)`) is hashed once.
    #[inline]
    pub fn extend(mut h: u64, parts: &[u64]) -> u64 {
        for &p in parts {
            h = mix(h.wrapping_add(GOLDEN) ^ mix(p.wrapping_add(GOLDEN)));
        }
        h
    }

    /// A uniform number in [0, 1) from the top 24 bits of a key.
    #[inline]
    pub fn uniform_f32(k: u64) -> f32 {
        (k >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }

    /// A uniform number in [0, 1) from the top 53 bits of a key.
    #[inline]
    pub fn uniform_f64(k: u64) -> f64 {
        (k >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

/// An axis-aligned box.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Aabb {
    pub min: [f32; 3],
    pub max: [f32; 3],
}

impl Aabb {
    /// Maps a point to the box's unit cube, `(p − min) / (max − min)` (the hash grid's input).
    #[inline]
    pub fn normalize(&self, p: [f32; 3]) -> [f32; 3] {
        [0, 1, 2].map(|a| (p[a] - self.min[a]) / (self.max[a] - self.min[a]))
    }
}

/// Random or deterministic placement of samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum SampleMode {
    /// Evaluation: no randomness (bin centres, CDF midpoints).
    Deterministic,
    /// Training: jittered with the counter-based RNG keyed by `(seed, step, ray, sample)`.
    Random { seed: u64, step: u64 },
}

/// Ragged batch of ray intervals.
///
/// # Shapes
/// - `offsets`: `[n_rays + 1]` (`offsets[0] = 0`)
/// - `t_start`, `t_end`, `ray_index`: `[n_samples]`
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RaySamples {
    pub offsets: Vec<u32>,
    pub t_start: Vec<f32>,
    pub t_end: Vec<f32>,
    /// The ray each sample belongs to (redundant with `offsets`; handy for gathers).
    pub ray_index: Vec<u32>,
}

impl RaySamples {
    /// An empty batch of `n_rays` rays.
    pub fn with_rays(n_rays: usize) -> Self {
        let mut s = Self::default();
        s.offsets.reserve(n_rays + 1);
        s.offsets.push(0);
        s
    }

    pub fn n_rays(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    pub fn len(&self) -> usize {
        self.t_start.len()
    }

    pub fn is_empty(&self) -> bool {
        self.t_start.is_empty()
    }

    /// Appends one sample of the ray being built; finish the ray with [`Self::end_ray`].
    #[inline]
    pub fn push(&mut self, t_start: f32, t_end: f32) {
        self.t_start.push(t_start);
        self.t_end.push(t_end);
        self.ray_index.push((self.offsets.len() - 1) as u32);
    }

    /// Closes the ray being built.
    #[inline]
    pub fn end_ray(&mut self) {
        self.offsets.push(self.t_start.len() as u32);
    }

    /// The samples of ray `r` as `(t_start, t_end)` slices.
    pub fn ray(&self, r: usize) -> (&[f32], &[f32]) {
        let (a, b) = (self.offsets[r] as usize, self.offsets[r + 1] as usize);
        (&self.t_start[a..b], &self.t_end[a..b])
    }

    /// Interval midpoints `(t_start + t_end) / 2`.
    pub fn t_mid(&self) -> Vec<f32> {
        self.t_start.iter().zip(&self.t_end).map(|(a, b)| 0.5 * a + 0.5 * b).collect()
    }

    /// Sample positions `origin + t_mid · dir` of each sample's ray.
    ///
    /// # Shapes
    /// `origins`, `dirs`: `[n_rays]` → `[n_samples]`
    pub fn positions(&self, origins: &[[f32; 3]], dirs: &[[f32; 3]]) -> Vec<[f32; 3]> {
        self.ray_index
            .iter()
            .zip(self.t_start.iter().zip(&self.t_end))
            .map(|(&r, (&a, &b))| {
                let (o, d, t) = (origins[r as usize], dirs[r as usize], 0.5 * a + 0.5 * b);
                [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]]
            })
            .collect()
    }
}

/// Slab test: the parameter range `(t0, t1)`, `t0 ≤ t1`, where `origin + t · dir` lies in the
/// box, or `None` for a miss. `t0` may be negative (origin inside or the box behind).
///
/// A zero direction component constrains nothing when the origin lies within that slab and
/// misses otherwise (no `0 · inf` NaN); NaN in the origin or direction is a miss.
///
/// Example: origin `(−2, 0.5, 0.5)`, dir `(1, 0, 0)`, unit box → `Some((2, 3))`.
pub fn ray_aabb(origin: [f32; 3], dir: [f32; 3], aabb: &Aabb) -> Option<(f32, f32)> {
    if origin.iter().chain(&dir).any(|v| v.is_nan()) {
        return None;
    }
    let (mut t0, mut t1) = (f32::NEG_INFINITY, f32::INFINITY);
    for a in 0..3 {
        if dir[a] == 0.0 {
            if origin[a] < aabb.min[a] || origin[a] > aabb.max[a] {
                return None;
            }
            continue;
        }
        let inv = 1.0 / dir[a];
        let (ta, tb) = ((aabb.min[a] - origin[a]) * inv, (aabb.max[a] - origin[a]) * inv);
        t0 = t0.max(ta.min(tb));
        t1 = t1.min(ta.max(tb));
    }
    (t0 <= t1).then_some((t0, t1))
}

/// Per-ray `near = max(t0, min_near)`, `far = min(t1, max_far)` of [`ray_aabb`]; rays that
/// miss the box, or whose range is empty after clipping, get `near = far = 0` (no samples).
///
/// # Shapes
/// `origins`, `dirs`: `[n_rays]` → `(near, far)`: `[n_rays]` each
pub fn ray_aabb_bounds(
    origins: &[[f32; 3]],
    dirs: &[[f32; 3]],
    aabb: &Aabb,
    min_near: f32,
    max_far: f32,
) -> (Vec<f32>, Vec<f32>) {
    assert_eq!(origins.len(), dirs.len());
    origins
        .iter()
        .zip(dirs)
        .map(|(&o, &d)| match ray_aabb(o, d, aabb) {
            Some((t0, t1)) => {
                let (n, f) = (t0.max(min_near), t1.min(max_far));
                if n < f { (n, f) } else { (0.0, 0.0) }
            }
            None => (0.0, 0.0),
        })
        .unzip()
}

#[inline]
fn valid_range(near: f32, far: f32) -> bool {
    near.is_finite() && far.is_finite() && far > near
}

/// Stratified sampling: `n_samples` contiguous intervals covering `[near, far]` per ray.
///
/// Edges `e_0 = near`, `e_n = far`; interior edge `e_i = near + (far − near) · (i − 1/2 + u_i) / n`
/// with `u_i` uniform in [0, 1) keyed by `(seed, step, ray, i)` (nerfstudio's jittered bins),
/// or `u_i = 1/2` in [`SampleMode::Deterministic`] (equal bins). Edges are sorted by
/// construction. Rays with `!(far > near)` or non-finite bounds get no sample.
///
/// Example (deterministic): `near = 2, far = 6, n = 4` → intervals `[2,3] [3,4] [4,5] [5,6]`.
///
/// # Shapes
/// `near`, `far`: `[n_rays]` → `RaySamples` with `n_samples` per valid ray
pub fn stratified(near: &[f32], far: &[f32], n_samples: usize, mode: SampleMode) -> RaySamples {
    assert_eq!(near.len(), far.len());
    let mut out = RaySamples::with_rays(near.len());
    let n = n_samples as f64;
    for (r, (&a, &b)) in near.iter().zip(far).enumerate() {
        if valid_range(a, b) && n_samples > 0 {
            let (a64, len) = (a as f64, b as f64 - a as f64);
            let mut prev = a;
            for i in 1..=n_samples {
                let e = if i == n_samples {
                    b
                } else {
                    let u = match mode {
                        SampleMode::Deterministic => 0.5,
                        SampleMode::Random { seed, step } => rng::uniform_f64(rng::key(&[seed, step, r as u64, i as u64])),
                    };
                    ((a64 + len * (i as f64 - 0.5 + u) / n) as f32).clamp(prev, b)
                };
                out.push(prev, e);
                prev = e;
            }
        }
        out.end_ray();
    }
    out
}

/// Hierarchical (importance) sampling, NeRF's `sample_pdf`: draws `n_importance` new points per
/// ray from the piecewise-constant pdf of the coarse weights and merges them with the coarse
/// edges into one sorted set of intervals.
///
/// Per ray with coarse intervals `[s_i, e_i]`, `i < m`:
/// - `pdf ∝ w_i` constant on each interval (NaN, negative or infinite weights count as 0); if
///   `Σ w_i = 0` the pdf is uniform in `t` (`∝ e_i − s_i`);
/// - `u_j = (j + ξ_j) / n_importance`, `ξ_j` uniform keyed by `(seed, step, ray, j)`, or
///   `ξ_j = 1/2` in [`SampleMode::Deterministic`]; `t_j = CDF⁻¹(u_j)` by linear inversion
///   inside the interval (sorted because the `u_j` are);
/// - the new edges are `{s_0, …, s_{m−1}, e_{m−1}} ∪ {t_j}`, sorted, giving `m + n_importance`
///   intervals inside `[s_0, e_{m−1}]`. Coarse intervals are expected to be contiguous (as
///   from [`stratified`]); a gap between them gets probability 0 but is spanned by the merged
///   interval over it.
///
/// Rays with no coarse sample get none.
///
/// Example (deterministic): coarse `[0,1] [1,2]`, weights `[0, 1]`, `n_importance = 2` →
/// `u = [0.25, 0.75]`, `t = [1.25, 1.75]`, intervals `[0,1] [1,1.25] [1.25,1.75] [1.75,2]`.
///
/// # Shapes
/// `weights`: `[coarse.len()]` → `RaySamples` with `m + n_importance` samples per ray
pub fn sample_pdf(coarse: &RaySamples, weights: &[f32], n_importance: usize, mode: SampleMode) -> RaySamples {
    assert_eq!(weights.len(), coarse.len(), "one weight per coarse sample");
    let n_rays = coarse.n_rays();
    let mut out = RaySamples::with_rays(n_rays);
    let mut cdf: Vec<f64> = Vec::new();
    let mut edges: Vec<f32> = Vec::new();
    for r in 0..n_rays {
        let (a, b) = (coarse.offsets[r] as usize, coarse.offsets[r + 1] as usize);
        let m = b - a;
        if m == 0 {
            out.end_ray();
            continue;
        }
        let (ts, te) = (&coarse.t_start[a..b], &coarse.t_end[a..b]);
        let clean_w = |w: f32| if w.is_finite() && w > 0.0 { w as f64 } else { 0.0 };
        let total: f64 = weights[a..b].iter().map(|&w| clean_w(w)).sum();
        let uniform = !(total > 0.0);
        cdf.clear();
        cdf.push(0.0);
        let mut acc = 0.0f64;
        for i in 0..m {
            let wi = if uniform { (te[i] as f64 - ts[i] as f64).max(0.0) } else { clean_w(weights[a + i]) };
            acc += wi;
            cdf.push(acc);
        }
        edges.clear();
        edges.extend_from_slice(ts);
        edges.push(te[m - 1]);
        if acc > 0.0 {
            let mut i = 0;
            for j in 0..n_importance {
                let xi = match mode {
                    SampleMode::Deterministic => 0.5,
                    SampleMode::Random { seed, step } => rng::uniform_f64(rng::key(&[seed, step, r as u64, j as u64])),
                };
                // target in cumulative-weight units: u · acc, u in [0, 1)
                let target = (j as f64 + xi) / n_importance as f64 * acc;
                while i + 1 < m && cdf[i + 1] <= target {
                    i += 1;
                }
                let width = cdf[i + 1] - cdf[i];
                let frac = if width > 0.0 { ((target - cdf[i]) / width).clamp(0.0, 1.0) } else { 1.0 };
                let t = ts[i] as f64 + frac * (te[i] as f64 - ts[i] as f64);
                edges.push((t as f32).clamp(ts[i].min(te[i]), te[i].max(ts[i])));
            }
        } else {
            // every coarse interval has zero length: the new points coincide with the start
            edges.extend(std::iter::repeat_n(ts[0], n_importance));
        }
        edges.sort_by(f32::total_cmp);
        for k in 0..edges.len() - 1 {
            out.push(edges[k], edges[k + 1]);
        }
        out.end_ray();
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check_sorted_inside(s: &RaySamples, near: &[f32], far: &[f32]) {
        for r in 0..s.n_rays() {
            let (a, b) = s.ray(r);
            let mut prev = near[r];
            for (&x, &y) in a.iter().zip(b) {
                assert!(x >= prev && y >= x && y <= far[r], "ray {r}: [{x}, {y}] after {prev}");
                prev = y;
            }
        }
        assert_eq!(s.ray_index.len(), s.len());
    }

    #[test]
    fn rng_is_uniform_and_keyed() {
        let n = 100_000;
        let mut hist = [0usize; 10];
        for i in 0..n {
            hist[(rng::uniform_f32(rng::key(&[1, 2, i])) * 10.0) as usize] += 1;
        }
        let chi2: f64 = hist.iter().map(|&h| (h as f64 - n as f64 / 10.0).powi(2) / (n as f64 / 10.0)).sum();
        assert!(chi2 < 27.9, "chi2 {chi2} (p = 0.001, 9 dof)");
        assert_ne!(rng::key(&[1, 2]), rng::key(&[2, 1]));
        assert_eq!(rng::key(&[5, 6, 7]), rng::key(&[5, 6, 7]));
        // a prefix hashed once and extended gives the whole tuple's key
        for split in 0..=4 {
            let parts = [3u64, u64::MAX, 0, 17];
            assert_eq!(rng::extend(rng::key(&parts[..split]), &parts[split..]), rng::key(&parts), "split {split}");
        }
        assert!(rng::uniform_f32(u64::MAX) < 1.0 && rng::uniform_f64(u64::MAX) < 1.0);
    }

    #[test]
    fn aabb_slab_test() {
        let b = Aabb { min: [0.0; 3], max: [1.0; 3] };
        assert_eq!(ray_aabb([-2.0, 0.5, 0.5], [1.0, 0.0, 0.0], &b), Some((2.0, 3.0)));
        assert_eq!(ray_aabb([0.5; 3], [0.0, 0.0, -1.0], &b), Some((-0.5, 0.5)));
        assert_eq!(ray_aabb([-2.0, 1.5, 0.5], [1.0, 0.0, 0.0], &b), None); // parallel, outside
        assert_eq!(ray_aabb([-2.0, 1.0, 0.5], [1.0, 0.0, 0.0], &b), Some((2.0, 3.0))); // on the face
        assert_eq!(ray_aabb([-2.0, -2.0, 0.5], [1.0, -1.0, 0.0], &b), None); // diverging
        assert_eq!(ray_aabb([f32::NAN, 0.5, 0.5], [1.0, 0.0, 0.0], &b), None);
        assert_eq!(ray_aabb([0.5; 3], [0.0; 3], &b), Some((f32::NEG_INFINITY, f32::INFINITY)));
        let (n, f) = ray_aabb_bounds(&[[-2.0, 0.5, 0.5], [-2.0, 3.0, 0.5], [0.5; 3]], &[[1.0, 0.0, 0.0]; 3], &b, 0.1, 100.0);
        assert_eq!((n, f), (vec![2.0, 0.0, 0.1], vec![3.0, 0.0, 0.5]));
        // a miss gives no samples
        let s = stratified(&[0.0], &[0.0], 8, SampleMode::Deterministic);
        assert_eq!(s.len(), 0);
        assert_eq!(s.offsets, vec![0, 0]);
    }

    #[test]
    fn stratified_sorted_inside_and_covering() {
        let near = [2.0f32, 0.0, 1.0, 5.0, f32::NAN, 0.1];
        let far = [6.0f32, 1e3, 1.0, 4.0, 3.0, 0.1 + 1e-6];
        let det = stratified(&near, &far, 4, SampleMode::Deterministic);
        assert_eq!(det.ray(0), (&[2.0f32, 3.0, 4.0, 5.0][..], &[3.0f32, 4.0, 5.0, 6.0][..]));
        assert_eq!(det.offsets, vec![0, 4, 8, 8, 8, 8, 12]);
        for step in 0..20 {
            let s = stratified(&near, &far, 64, SampleMode::Random { seed: 3, step });
            check_sorted_inside(&s, &near, &far);
            for r in [0usize, 1, 5] {
                let (a, b) = s.ray(r);
                assert_eq!((a[0], b[63]), (near[r], far[r]));
                assert!(a[1..].iter().zip(b).all(|(x, y)| x == y), "contiguous");
            }
        }
        // jitter changes with the step and is reproducible
        let a = stratified(&near, &far, 8, SampleMode::Random { seed: 3, step: 1 });
        assert_eq!(a, stratified(&near, &far, 8, SampleMode::Random { seed: 3, step: 1 }));
        assert_ne!(a, stratified(&near, &far, 8, SampleMode::Random { seed: 3, step: 2 }));
    }

    #[test]
    fn pdf_worked_example_and_zero_weights() {
        let mut c = RaySamples::with_rays(3);
        c.push(0.0, 1.0);
        c.push(1.0, 2.0);
        c.end_ray();
        c.end_ray(); // an empty ray
        c.push(0.0, 1.0);
        c.push(1.0, 3.0);
        c.end_ray();
        let s = sample_pdf(&c, &[0.0, 1.0, 0.0, 0.0], 2, SampleMode::Deterministic);
        assert_eq!(s.ray(0), (&[0.0f32, 1.0, 1.25, 1.75][..], &[1.0f32, 1.25, 1.75, 2.0][..]));
        assert_eq!(s.ray(1).0.len(), 0);
        // all-zero weights: uniform in t over [0, 3]
        assert_eq!(s.ray(2), (&[0.0f32, 0.75, 1.0, 2.25][..], &[0.75f32, 1.0, 2.25, 3.0][..]));
        for w in [[f32::NAN, -1.0], [f32::INFINITY, 0.0], [0.0, 0.0]] {
            let mut c1 = RaySamples::with_rays(1);
            c1.push(1.0, 2.0);
            c1.push(2.0, 3.0);
            c1.end_ray();
            let s = sample_pdf(&c1, &w, 16, SampleMode::Random { seed: 1, step: 0 });
            assert_eq!(s.len(), 18);
            check_sorted_inside(&s, &[1.0], &[3.0]);
        }
    }

    #[test]
    fn pdf_follows_a_piecewise_constant_density() {
        // 8 coarse bins over [0, 4] with weights 1..8 except two empty bins
        let w_bins = [1.0f32, 0.0, 3.0, 4.0, 0.0, 6.0, 7.0, 8.0];
        let total: f32 = w_bins.iter().sum();
        let n_rays = 200;
        let near = vec![0.0f32; n_rays];
        let far = vec![4.0f32; n_rays];
        let coarse = stratified(&near, &far, 8, SampleMode::Deterministic);
        let weights: Vec<f32> = (0..n_rays).flat_map(|_| w_bins).collect();
        let n_imp = 64;
        let fine = sample_pdf(&coarse, &weights, n_imp, SampleMode::Random { seed: 9, step: 4 });
        check_sorted_inside(&fine, &near, &far);
        // recover the importance points: fine edges minus the coarse edges
        let mut hist = [0usize; 8];
        for r in 0..n_rays {
            let (a, _) = fine.ray(r);
            for &t in &a[1..] {
                let k = t * 2.0;
                if k.fract() != 0.0 {
                    hist[k as usize] += 1;
                }
            }
        }
        let n_total = (n_rays * n_imp) as f64;
        assert_eq!(hist[1] + hist[4], 0, "no sample in an empty bin");
        let observed: usize = hist.iter().sum();
        assert!(observed as f64 > 0.99 * n_total);
        let mut chi2 = 0.0;
        for k in 0..8 {
            if w_bins[k] > 0.0 {
                let e = n_total * (w_bins[k] / total) as f64;
                chi2 += (hist[k] as f64 - e).powi(2) / e;
            }
        }
        // stratified u makes the counts far tighter than multinomial; 5 dof, p = 0.001 → 20.5
        assert!(chi2 < 20.5, "chi2 = {chi2}, hist = {hist:?}");
        // uniform within a bin: KS test of the fractional positions inside bin 7
        let mut fr: Vec<f64> = (0..n_rays)
            .flat_map(|r| fine.ray(r).0.to_vec())
            .filter(|&t| t > 3.5 && (t * 2.0).fract() != 0.0)
            .map(|t| (t as f64 - 3.5) * 2.0)
            .collect();
        fr.sort_by(f64::total_cmp);
        let n = fr.len() as f64;
        let d = fr.iter().enumerate().map(|(i, &x)| ((i as f64 + 1.0) / n - x).abs().max((x - i as f64 / n).abs())).fold(0.0, f64::max);
        assert!(d < 1.95 / n.sqrt(), "KS D = {d} (n = {n})");
    }

    #[test]
    fn positions_use_midpoints() {
        let mut s = RaySamples::with_rays(2);
        s.end_ray();
        s.push(1.0, 3.0);
        s.end_ray();
        assert_eq!(s.positions(&[[0.0; 3], [1.0, 0.0, 0.0]], &[[1.0; 3], [0.0, 0.0, -1.0]]), vec![[1.0, 0.0, -2.0]]);
        assert_eq!(s.t_mid(), vec![2.0]);
    }
}
