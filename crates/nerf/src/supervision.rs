//! Supervision from the dataset's ground truth beyond colour: a depth term on rays whose pixel
//! hits the scene, an empty-space term on rays whose pixel misses it, a normal term on the
//! density's gradient at the target surface point, and the sensor-like degradations of the
//! depth they learn from. The depth and empty-space terms are functions of the compositor's
//! outputs ([`crate::volrend`]) and hand back their gradient with respect to them, so both
//! models reach their parameters through [`crate::volrend::composite_backward`]; the normal
//! term hands back its gradient with respect to six densities ([`normal_loss_and_grads`]).
//!
//! Per ray `r` of a batch of `N`, with `O = Σ w_i`, `D = Σ w_i s_i` (unnormalised) and the
//! target distance `d` along the ray (the dataset's z-depth converted with the pixel-centre
//! ray's direction, [`dataset::Camera::distance_from_z_depth`]):
//! ```text
//! expected:     L_r = ρ((D / max(O, O_MIN) − d) / d),  ρ(e) = √(e² + c²) − c   (Charbonnier, c = 0.01)
//! termination:  L_r = Σ_{t1_i ≤ d − ε} w_i²  +  Σ_{[t0_i, t1_i] ∩ [d − ε, d + ε] ≠ ∅} (w_i − K_i)²
//!               K_i = Φ((t1_i − d)/(ε/2)) − Φ((t0_i − d)/(ε/2)),  ε = BAND · d
//! empty:        L_r = O                                      (rays whose exact alpha is 0)
//! normal:       L_r = 1 − n̂·n*,  n̂ = −g/|g|,  g_a = σ(x + h·e_a) − σ(x − h·e_a)
//!               x = o + d·dir (the target's surface point), h one finest cell, n* the
//!               dataset's normal; rays with |g| < G_MIN (no surface there yet) are left out
//! total:        λ_d(k) · (1/N) Σ_{r with d} L_r  +  λ_e · (1/N) Σ_{r empty} O_r  +  λ_n · (1/N) Σ_{r with d, n*} L_r
//! λ_d(k) = λ_d · 2^(−k / half_life)   (step k; no decay without a half-life)
//! ```
//! `expected` is a robust loss on the relative error of the expected depth (scale-free: the
//! same weight suits scenes of any size); the opacity floor `O_MIN` bounds its gradient on
//! nearly transparent rays. `termination` is Urban Radiance Fields' line-of-sight loss
//! (Rematas et al. 2022) in mass form: the weight in front of the surface is pushed to 0 and
//! the weight in a band of ±ε around it toward the mass of a normal distribution of standard
//! deviation ε/2 over each interval; intervals behind the band are occluded and free.
//! `normal` compares the normal implied by the density field (its gradient by central
//! differences, six density evaluations per ray, [`normal_loss_and_grads`]) with the dataset's
//! shading normal at the pixel's surface point; it needs no second derivatives, only the
//! density network's backward at the six points. Built for the hash-grid models (fast, auto).
//!
//! Depth sources ([`DepthSource`]): `exact`; `noisy:S`, `d · (1 + S·n)` with `n` standard
//! normal (a stereo or time-of-flight camera); `sparse:F`, a fraction `F` of the pixels keep
//! their depth (a LiDAR); `holes:F`, a fraction `F` lose it (no return). The choices are pure
//! functions of (seed, view, pixel) through [`crate::kernels::uniform`]: a run reproduces for
//! any thread count. A target that is not finite or not positive is no target; the others are
//! clamped into `[max(near, far · 1e-6), far]`, where the model can place a surface.
//!
//! Robustness: rays without samples, zero-weight rays and targets at the bounds give finite
//! losses and gradients (tests below); the models skip a step whose loss or gradient is not
//! finite, as for colour.

use crate::kernels::{stream, uniform};
use crate::volrend::CompositeOutput;
use burn::config::Config;
use serde::{Deserialize, Serialize};

/// Opacity below which the expected depth is normalised by this floor instead.
pub const O_MIN: f32 = 0.1;
/// Charbonnier's `c` on the relative depth error.
pub const CHARBONNIER_C: f64 = 0.01;
/// Half-width of the termination band, as a fraction of the target distance.
pub const BAND: f32 = 0.02;
/// Smallest central-difference density gradient `|g|` the normal term trains on.
pub const G_MIN: f64 = 1e-2;

/// Which depth term is trained.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DepthLoss {
    /// No depth term.
    Off,
    /// Charbonnier on the expected depth's relative error.
    Expected,
    /// The line-of-sight term on the weights.
    Termination,
}

impl DepthLoss {
    /// The option's value: `off`, `expected` or `termination`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Off => "off",
            Self::Expected => "expected",
            Self::Termination => "termination",
        }
    }
}

impl std::str::FromStr for DepthLoss {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "off" => Ok(Self::Off),
            "expected" => Ok(Self::Expected),
            "termination" => Ok(Self::Termination),
            _ => Err(format!("unknown depth loss '{s}' (off, expected or termination)")),
        }
    }
}

/// Where the depth targets come from (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub enum DepthSource {
    /// The exact z-depth.
    Exact,
    /// Multiplicative normal noise of this relative standard deviation (≥ 0).
    Noisy(f32),
    /// Only this fraction of the pixels, in (0, 1], has depth.
    Sparse(f32),
    /// This fraction of the pixels, in (0, 1], has none.
    Holes(f32),
}

impl std::str::FromStr for DepthSource {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let (kind, arg) = s.split_once(':').unwrap_or((s, ""));
        let num = |what: &str| -> Result<f32, String> {
            arg.trim().parse::<f32>().map_err(|_| format!("'{s}': {kind} needs a number ({what}), as in {kind}:0.01"))
        };
        let fraction = |v: f32| -> Result<f32, String> {
            if v > 0.0 && v <= 1.0 { Ok(v) } else { Err(format!("'{s}': the fraction must be in (0, 1], not {v}")) }
        };
        match kind {
            "exact" if arg.is_empty() => Ok(Self::Exact),
            "noisy" => {
                let v = num("a relative standard deviation")?;
                if v.is_finite() && v >= 0.0 { Ok(Self::Noisy(v)) } else { Err(format!("'{s}': the relative standard deviation must be a finite number ≥ 0, not {v}")) }
            }
            "sparse" => Ok(Self::Sparse(fraction(num("a fraction of pixels")?)?)),
            "holes" => Ok(Self::Holes(fraction(num("a fraction of pixels")?)?)),
            _ => Err(format!("unknown depth source '{s}' (exact, noisy:SIGMA_REL, sparse:FRACTION or holes:FRACTION)")),
        }
    }
}

impl std::fmt::Display for DepthSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Exact => write!(f, "exact"),
            Self::Noisy(v) => write!(f, "noisy:{v}"),
            Self::Sparse(v) => write!(f, "sparse:{v}"),
            Self::Holes(v) => write!(f, "holes:{v}"),
        }
    }
}

impl TryFrom<String> for DepthSource {
    type Error = String;
    fn try_from(s: String) -> Result<Self, String> {
        s.parse()
    }
}

impl From<DepthSource> for String {
    fn from(s: DepthSource) -> String {
        s.to_string()
    }
}

impl DepthSource {
    /// The target z-depth of pixel `pixel` of train view `view` given its exact z-depth `z`
    /// (NaN: no target), a pure function of (seed, view, pixel).
    pub fn degrade(self, z: f32, seed: u64, view: u64, pixel: u64) -> f32 {
        match self {
            Self::Exact => z,
            Self::Noisy(s) => {
                let u1 = uniform(seed, stream::DEPTH_NOISE, view, 2 * pixel) as f64;
                let u2 = uniform(seed, stream::DEPTH_NOISE, view, 2 * pixel + 1) as f64;
                let n = (-2.0 * (1.0 - u1).ln()).sqrt() * (std::f64::consts::TAU * u2).cos();
                (z as f64 * (1.0 + s as f64 * n)) as f32
            }
            Self::Sparse(f) => if uniform(seed, stream::DEPTH_MASK, view, pixel) < f { z } else { f32::NAN },
            Self::Holes(f) => if uniform(seed, stream::DEPTH_MASK, view, pixel) < f { f32::NAN } else { z },
        }
    }
}

/// The supervision settings of a run (`config.json`'s `supervision`; absent: colour only).
#[derive(Config, Debug)]
pub struct SupervisionConfig {
    /// The depth term.
    #[config(default = "DepthLoss::Off")]
    pub depth_loss: DepthLoss,
    /// Its weight λ_d at step 0.
    #[config(default = 0.2)]
    pub depth_weight: f32,
    /// Half-life of λ_d in steps (None: constant).
    #[config(default = "None")]
    pub depth_half_life_steps: Option<u64>,
    /// Where the depth targets come from.
    #[config(default = "DepthSource::Exact")]
    pub depth_source: DepthSource,
    /// Weight λ_e of the empty-space term (0: off).
    #[config(default = 0.0)]
    pub empty_weight: f32,
    /// Weight λ_n of the normal term (0: off).
    #[config(default = 0.0)]
    pub normal_weight: f32,
}

impl SupervisionConfig {
    /// Refuses settings no run can use, naming the field.
    pub fn check(&self) -> Result<(), String> {
        for (name, v) in [("supervision.depth_weight", self.depth_weight), ("supervision.empty_weight", self.empty_weight), ("supervision.normal_weight", self.normal_weight)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("{name} must be a finite weight ≥ 0, not {v}"));
            }
        }
        if self.depth_half_life_steps == Some(0) {
            return Err("supervision.depth_half_life_steps must be a positive number of steps".into());
        }
        // A source given as a struct in a hand-written config is checked as the option is.
        self.depth_source.to_string().parse::<DepthSource>().map_err(|e| format!("supervision.depth_source {e}"))?;
        Ok(())
    }

    /// Whether the depth term is on.
    pub fn uses_depth(&self) -> bool {
        self.depth_loss != DepthLoss::Off
    }

    /// Whether the normal term is on.
    pub fn uses_normals(&self) -> bool {
        self.normal_weight > 0.0
    }

    /// λ_d at step `step`.
    pub fn depth_weight_at(&self, step: u64) -> f32 {
        match self.depth_half_life_steps {
            Some(h) => (self.depth_weight as f64 * 0.5f64.powf(step as f64 / h.max(1) as f64)) as f32,
            None => self.depth_weight,
        }
    }

    /// One line for reports.
    pub fn describe(&self) -> String {
        let decay = self.depth_half_life_steps.map_or("constant".to_string(), |h| format!("half-life {h} steps"));
        let normal = if self.uses_normals() { format!(", normal loss weight {}", self.normal_weight) } else { String::new() };
        format!(
            "depth loss {} (weight {}, {decay}, source {}), empty-space loss weight {}{normal}",
            self.depth_loss.name(),
            self.depth_weight,
            self.depth_source,
            self.empty_weight
        )
    }
}

/// A batch's supervision: this step's weights and each ray's target.
///
/// # Shapes
/// `depth`, `empty`: one entry per ray of the batch.
#[derive(Clone, Debug, PartialEq)]
pub struct RaySupervision {
    /// The depth term.
    pub depth_loss: DepthLoss,
    /// λ_d at this step.
    pub depth_weight: f32,
    /// λ_e.
    pub empty_weight: f32,
    /// Target distance along the ray (NaN: none).
    pub depth: Vec<f32>,
    /// Whether the pixel's exact alpha is 0.
    pub empty: Vec<bool>,
    /// λ_n.
    pub normal_weight: f32,
    /// The dataset's unit normal (world) where the ray has a depth target and the normal term
    /// is on (NaN: none); empty when the term is off.
    pub normal: Vec<[f32; 3]>,
}

/// What [`loss_and_grads`] returns for a group of rays.
///
/// # Shapes
/// `d_opacity`, `d_distance`: one per ray of the group; `d_weights`: one per sample.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SupervisionGrads {
    /// The group's part of the weighted loss (already divided by `N`).
    pub loss: f64,
    /// ∂L/∂opacity.
    pub d_opacity: Vec<f32>,
    /// ∂L/∂distance (the unnormalised `D`).
    pub d_distance: Vec<f32>,
    /// ∂L/∂w_i.
    pub d_weights: Vec<f32>,
}

/// Φ, the standard normal distribution function (Abramowitz & Stegun 7.1.26, error < 1.5e-7).
fn normal_cdf(x: f64) -> f64 {
    let z = x.abs() / std::f64::consts::SQRT_2;
    let t = 1.0 / (1.0 + 0.327_591_1 * z);
    let poly = t * (0.254_829_592 + t * (-0.284_496_736 + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    let erf = 1.0 - poly * (-z * z).exp();
    if x >= 0.0 { 0.5 * (1.0 + erf) } else { 0.5 * (1.0 - erf) }
}

/// The supervision loss of the rays `first..first + n` of a batch (`sup` holds the whole
/// batch's targets; `n_batch` is `N`) and its gradients, given their compositing `out` over the
/// samples `offsets` (local, starting at 0) with intervals `t_start`, `t_end`.
pub fn loss_and_grads(sup: &RaySupervision, first: usize, n_batch: usize, offsets: &[u32], t_start: &[f32], t_end: &[f32], out: &CompositeOutput) -> SupervisionGrads {
    let n = offsets.len() - 1;
    let inv_n = 1.0 / n_batch.max(1) as f64;
    let mut g = SupervisionGrads { loss: 0.0, d_opacity: vec![0.0; n], d_distance: vec![0.0; n], d_weights: vec![0.0; t_start.len()] };
    let (ld, le) = (sup.depth_weight as f64 * inv_n, sup.empty_weight as f64 * inv_n);
    for k in 0..n {
        let r = first + k;
        let o = out.opacity[k] as f64;
        if le > 0.0 && sup.empty[r] {
            g.loss += le * o;
            g.d_opacity[k] += le as f32;
        }
        let d = sup.depth[r] as f64;
        if ld == 0.0 || !(d.is_finite() && d > 0.0) {
            continue;
        }
        match sup.depth_loss {
            DepthLoss::Off => {}
            DepthLoss::Expected => {
                let on = o.max(O_MIN as f64);
                let e = (out.distance[k] as f64 / on - d) / d;
                let h = e.hypot(CHARBONNIER_C);
                g.loss += ld * (h - CHARBONNIER_C);
                let de = ld * e / h / d;
                g.d_distance[k] += (de / on) as f32;
                if o > O_MIN as f64 {
                    g.d_opacity[k] -= (de * out.distance[k] as f64 / (o * o)) as f32;
                }
            }
            DepthLoss::Termination => {
                let eps = BAND as f64 * d;
                let sd = 0.5 * eps;
                for i in offsets[k] as usize..offsets[k + 1] as usize {
                    let (t0, t1, w) = (t_start[i] as f64, t_end[i] as f64, out.weights[i] as f64);
                    if t1 <= d - eps {
                        g.loss += ld * w * w;
                        g.d_weights[i] = (ld * 2.0 * w) as f32;
                    } else if t0 <= d + eps {
                        let target = normal_cdf((t1 - d) / sd) - normal_cdf((t0 - d) / sd);
                        g.loss += ld * (w - target).powi(2);
                        g.d_weights[i] = (ld * 2.0 * (w - target)) as f32;
                    }
                }
            }
        }
    }
    g
}

/// The normal term of one ray ([module doc](self)) from the densities at its six offset points
/// `[x + h·e_x, x − h·e_x, x + h·e_y, x − h·e_y, x + h·e_z, x − h·e_z]`, the target unit
/// normal `target` and the weight `lw = λ_n / N`: the loss and its gradient with respect to the
/// six densities; `None` where `|g| < G_MIN` or an input is not finite.
pub fn normal_loss_and_grads(sigma: &[f32; 6], target: [f32; 3], lw: f64) -> Option<(f64, [f32; 6])> {
    let g = [0, 1, 2].map(|a| sigma[2 * a] as f64 - sigma[2 * a + 1] as f64);
    let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
    if !(len.is_finite() && len >= G_MIN) || !target.iter().all(|x| x.is_finite()) {
        return None;
    }
    let gh = g.map(|x| x / len);
    let t = target.map(|x| x as f64);
    let cos = -(gh[0] * t[0] + gh[1] * t[1] + gh[2] * t[2]);
    // ∂(1 − n̂·n*)/∂g = (I − ĝĝᵀ) n* / |g|, with n̂ = −ĝ.
    let along = gh[0] * t[0] + gh[1] * t[1] + gh[2] * t[2];
    let dg = [0, 1, 2].map(|a| lw * (t[a] - along * gh[a]) / len);
    let d = std::array::from_fn(|i| if i % 2 == 0 { dg[i / 2] as f32 } else { -dg[i / 2] as f32 });
    Some((lw * (1.0 - cos), d))
}

/// Clamps a target distance into what the model can reach (see the module doc); NaN when it
/// is no target.
pub fn clamp_target(d: f64, near: f32, far: f32) -> f32 {
    if !(d.is_finite() && d > 0.0) {
        return f32::NAN;
    }
    let lo = (near as f64).max(far as f64 * 1e-6);
    d.clamp(lo, (far as f64).max(lo)) as f32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volrend::{CompositeInputs, OutputGrads, composite_backward, composite_forward};

    fn rnd(i: u64) -> f64 {
        crate::sampling::rng::uniform_f64(crate::sampling::rng::key(&[91, i]))
    }

    /// Rays of `counts` samples from t = 1 with steps of 0.05 to 0.15 and densities up to
    /// `scale`.
    fn rays(counts: &[usize], seed: u64, scale: f64) -> (Vec<u32>, Vec<f32>, Vec<f32>, Vec<f32>) {
        let (mut offsets, mut sigma, mut t0, mut t1) = (vec![0u32], vec![], vec![], vec![]);
        let mut c = seed * 1_000_000;
        for &n in counts {
            let mut t = 1.0f64;
            for _ in 0..n {
                c += 2;
                t0.push(t as f32);
                t += 0.05 + 0.1 * rnd(c);
                t1.push(t as f32);
                sigma.push((scale * rnd(c + 1)) as f32);
            }
            offsets.push(sigma.len() as u32);
        }
        (offsets, sigma, t0, t1)
    }

    fn sup(kind: DepthLoss, depth: Vec<f32>, empty: Vec<bool>, empty_weight: f32) -> RaySupervision {
        RaySupervision { depth_loss: kind, depth_weight: 0.7, empty_weight, depth, empty, normal_weight: 0.0, normal: Vec::new() }
    }

    /// The supervision loss written directly from the module doc's formulas, in f64, from the
    /// densities (the compositing included).
    fn ref_loss(s: &RaySupervision, offsets: &[u32], sigma: &[f64], t0: &[f32], t1: &[f32]) -> f64 {
        let n = offsets.len() - 1;
        let mut total = 0.0;
        for r in 0..n {
            let (mut tau, mut o, mut dist) = (0.0f64, 0.0f64, 0.0f64);
            let mut w = vec![];
            for i in offsets[r] as usize..offsets[r + 1] as usize {
                let d = t1[i] as f64 - t0[i] as f64;
                let x = sigma[i] * d;
                let wi = (-tau).exp() * (1.0 - (-x).exp());
                let local = if sigma[i] > 0.0 { t0[i] as f64 * (1.0 - (-x).exp()) + (1.0 - (-x).exp() * (1.0 + x)) / sigma[i] } else { 0.0 };
                dist += (-tau).exp() * local;
                o += wi;
                w.push(wi);
                tau += x;
            }
            if s.empty[r] {
                total += s.empty_weight as f64 * o / n as f64;
            }
            let d = s.depth[r] as f64;
            if !(d.is_finite() && d > 0.0) {
                continue;
            }
            let l = match s.depth_loss {
                DepthLoss::Off => 0.0,
                DepthLoss::Expected => {
                    let e = (dist / o.max(O_MIN as f64) - d) / d;
                    (e * e + CHARBONNIER_C * CHARBONNIER_C).sqrt() - CHARBONNIER_C
                }
                DepthLoss::Termination => {
                    let eps = BAND as f64 * d;
                    let phi = |x: f64| normal_cdf(x);
                    (offsets[r] as usize..offsets[r + 1] as usize)
                        .map(|i| {
                            let (a, b, wi) = (t0[i] as f64, t1[i] as f64, w[i - offsets[r] as usize]);
                            if b <= d - eps {
                                wi * wi
                            } else if a <= d + eps {
                                (wi - (phi((b - d) / (0.5 * eps)) - phi((a - d) / (0.5 * eps)))).powi(2)
                            } else {
                                0.0
                            }
                        })
                        .sum()
                }
            };
            total += s.depth_weight as f64 * l / n as f64;
        }
        total
    }

    /// Loss and ∂L/∂σ through the compositor's backward.
    fn loss_and_dsigma(s: &RaySupervision, offsets: &[u32], sigma: &[f32], t0: &[f32], t1: &[f32]) -> (f64, Vec<f32>) {
        let n = offsets.len() - 1;
        let rgb = vec![[0.5; 3]; sigma.len()];
        let bg = vec![[1.0; 3]; n];
        let inputs = CompositeInputs { offsets, sigma, rgb: &rgb, t_start: t0, t_end: t1, background: &bg };
        let out = composite_forward(&inputs);
        let g = loss_and_grads(s, 0, n, offsets, t0, t1, &out);
        let d_rgb = vec![[0.0; 3]; n];
        let back = composite_backward(&inputs, &out, &OutputGrads { d_rgb: &d_rgb, d_opacity: &g.d_opacity, d_distance: &g.d_distance, d_weights: Some(&g.d_weights) });
        (g.loss, back.d_sigma)
    }

    /// Each term's loss matches the f64 reference, and its gradient reaches the densities as
    /// the finite differences of that reference say.
    #[test]
    fn each_term_matches_finite_differences() {
        let counts = [0usize, 1, 4, 12, 30, 30];
        let (offsets, sigma, t0, t1) = rays(&counts, 3, 6.0);
        let n = counts.len();
        // Targets inside, before and behind the samples; one ray without a target.
        let depth = vec![1.3, 1.05, 1.4, 1.9, 2.2, f32::NAN];
        let empty = vec![true, false, true, false, true, true];
        for (kind, ew) in [(DepthLoss::Expected, 0.0), (DepthLoss::Termination, 0.0), (DepthLoss::Off, 0.9)] {
            let s = sup(kind, depth.clone(), if ew > 0.0 { empty.clone() } else { vec![false; n] }, ew);
            let (loss, g) = loss_and_dsigma(&s, &offsets, &sigma, &t0, &t1);
            let s64: Vec<f64> = sigma.iter().map(|&v| v as f64).collect();
            let want = ref_loss(&s, &offsets, &s64, &t0, &t1);
            assert!(want > 1e-4, "{kind:?}: the test must have a loss");
            assert!((loss - want).abs() < 1e-5 * (1.0 + want), "{kind:?}: loss {loss} vs {want}");
            for i in 0..sigma.len() {
                let h = 1e-5 * (1.0 + s64[i]);
                let (mut p, mut m) = (s64.clone(), s64.clone());
                p[i] += h;
                m[i] -= h;
                let fd = (ref_loss(&s, &offsets, &p, &t0, &t1) - ref_loss(&s, &offsets, &m, &t0, &t1)) / (2.0 * h);
                assert!((g[i] as f64 - fd).abs() < 1e-3 * (1.0 + fd.abs()), "{kind:?}: dL/dσ[{i}] {} vs {fd}", g[i]);
            }
        }
    }

    /// The normal term against central differences of its formula in f64, its values at the
    /// target normal and its opposite, and no term where the density is flat or an input is
    /// not finite.
    #[test]
    fn normal_term_matches_finite_differences() {
        let t = [0.36f32, -0.48, 0.8];
        let reference = |s: &[f64; 6]| {
            let g = [s[0] - s[1], s[2] - s[3], s[4] - s[5]];
            let l = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
            0.3 * (1.0 + (0..3).map(|a| g[a] / l * t[a] as f64).sum::<f64>())
        };
        for sigma in [[5.0f32, 1.0, 0.5, 2.0, 40.0, 80.0], [0.0, 0.03, 10.0, 10.0, 0.0, 0.0], [1e4, 2e4, 3e3, 1e3, 7e3, 1e2]] {
            let (loss, d) = normal_loss_and_grads(&sigma, t, 0.3).unwrap();
            let s64 = sigma.map(|x| x as f64);
            assert!((loss - reference(&s64)).abs() < 1e-9, "{loss} vs {}", reference(&s64));
            for i in 0..6 {
                let h = 1e-6 * (1.0 + s64[i].abs());
                let (mut p, mut m) = (s64, s64);
                p[i] += h;
                m[i] -= h;
                let fd = (reference(&p) - reference(&m)) / (2.0 * h);
                assert!((d[i] as f64 - fd).abs() < 1e-4 * (1.0 + fd.abs()), "σ {sigma:?}: ∂L/∂σ[{i}] {} vs {fd}", d[i]);
            }
        }
        // Density rising against n* (n̂ = n*): no loss; rising along it: the largest, 2·λ.
        let along = [0.0, 3.6, 0.0, -4.8, 0.0, 8.0].map(|x: f32| x);
        assert!(normal_loss_and_grads(&along, t, 1.0).unwrap().0.abs() < 1e-6);
        let against = along.map(|x| -x);
        assert!((normal_loss_and_grads(&against, t, 1.0).unwrap().0 - 2.0).abs() < 1e-6);
        assert!(normal_loss_and_grads(&[1.0; 6], t, 1.0).is_none(), "flat density");
        assert!(normal_loss_and_grads(&[f32::NAN, 0.0, 1.0, 0.0, 1.0, 0.0], t, 1.0).is_none());
        assert!(normal_loss_and_grads(&[f32::INFINITY, 0.0, 1.0, 0.0, 1.0, 0.0], t, 1.0).is_none());
        assert!(normal_loss_and_grads(&along, [f32::NAN; 3], 1.0).is_none());
    }

    /// Rays without samples, without weight, with targets at, beyond or far outside the
    /// bounds, NaN and infinite targets: finite losses and gradients.
    #[test]
    fn extreme_rays_and_targets_stay_finite() {
        let (offsets, mut sigma, t0, t1) = rays(&[0, 3, 8, 8, 8, 8, 8, 8, 8], 4, 50.0);
        for v in &mut sigma[3..11] {
            *v = 0.0; // a zero-weight ray
        }
        sigma[20] = f32::INFINITY;
        // Unclamped targets far outside the bounds (a tiny one's relative error has no bound:
        // the trainer clamps those, below).
        let raw = [0.0, 1.0, 1e30, 4.0, f32::MAX, f32::NAN, f32::INFINITY, -3.0, 1e-3];
        let targets = [0.0, 1.0, 1e30, 1e-30, f32::MAX, f32::NAN, f32::INFINITY, -3.0, 1e-45];
        for kind in [DepthLoss::Expected, DepthLoss::Termination] {
            let s = sup(kind, raw.to_vec(), vec![true; raw.len()], 1.0);
            let (loss, g) = loss_and_dsigma(&s, &offsets, &sigma, &t0, &t1);
            assert!(loss.is_finite() && g.iter().all(|v| v.is_finite()), "{kind:?}: {loss} {g:?}");
            // Clamped into the bounds, as the trainer hands them over.
            let clamped: Vec<f32> = targets.iter().map(|&d| clamp_target(d as f64, 0.0, 4.0)).collect();
            assert!(clamped.iter().all(|d| d.is_nan() || (*d > 0.0 && *d <= 4.0)), "{clamped:?}");
            let s = sup(kind, clamped, vec![false; targets.len()], 0.0);
            let (loss, g) = loss_and_dsigma(&s, &offsets, &sigma, &t0, &t1);
            assert!(loss.is_finite() && g.iter().all(|v| v.is_finite() && v.abs() < 1e12), "{kind:?} clamped: {loss} {g:?}");
        }
    }

    #[test]
    fn depth_sources_parse_and_refuse() {
        assert_eq!("exact".parse::<DepthSource>(), Ok(DepthSource::Exact));
        assert_eq!("noisy:0.01".parse::<DepthSource>(), Ok(DepthSource::Noisy(0.01)));
        assert_eq!("sparse:1".parse::<DepthSource>(), Ok(DepthSource::Sparse(1.0)));
        assert_eq!("holes:0.3".parse::<DepthSource>(), Ok(DepthSource::Holes(0.3)));
        for bad in ["sparse:0", "sparse:1.5", "holes:-0.1", "holes:nan", "noisy:-0.01", "noisy:inf", "noisy", "exact:1", "lidar:0.1", "sparse:x"] {
            let e = bad.parse::<DepthSource>().expect_err(bad);
            assert!(e.contains(bad.split(':').next().unwrap_or(bad)), "{bad}: {e}");
        }
        // The recorded form reads back.
        for s in ["exact", "noisy:0.01", "sparse:0.01", "holes:0.3"] {
            let v: DepthSource = s.parse().unwrap();
            assert_eq!(serde_json::from_value::<DepthSource>(serde_json::to_value(v).unwrap()).unwrap(), v);
        }
        assert!(SupervisionConfig::new().with_depth_weight(-1.0).check().unwrap_err().contains("depth_weight"));
        assert!(SupervisionConfig::new().with_depth_half_life_steps(Some(0)).check().unwrap_err().contains("half_life"));
    }

    /// The degradations are pure functions of (seed, view, pixel) with the stated statistics.
    #[test]
    fn depth_sources_are_seeded_with_their_statistics() {
        let n = 20_000u64;
        let noisy = DepthSource::Noisy(0.01);
        let e: Vec<f64> = (0..n).map(|p| noisy.degrade(2.0, 5, 1, p) as f64 / 2.0 - 1.0).collect();
        let mean = e.iter().sum::<f64>() / n as f64;
        let sd = (e.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n as f64).sqrt();
        assert!(mean.abs() < 3e-4 && (sd - 0.01).abs() < 5e-4, "mean {mean} sd {sd}");
        assert_eq!(noisy.degrade(2.0, 5, 1, 7), noisy.degrade(2.0, 5, 1, 7));
        assert_ne!(noisy.degrade(2.0, 5, 1, 7), noisy.degrade(2.0, 6, 1, 7));
        let kept = |s: DepthSource| (0..n).filter(|&p| !s.degrade(1.0, 5, 2, p).is_nan()).count() as f64 / n as f64;
        assert!((kept(DepthSource::Sparse(0.01)) - 0.01).abs() < 0.003);
        assert!((kept(DepthSource::Holes(0.3)) - 0.7).abs() < 0.02);
        assert_eq!(kept(DepthSource::Exact), 1.0);
    }

    #[test]
    fn weight_decays_by_its_half_life() {
        let c = SupervisionConfig::new().with_depth_weight(0.4).with_depth_half_life_steps(Some(100));
        assert_eq!(c.depth_weight_at(0), 0.4);
        assert!((c.depth_weight_at(100) - 0.2).abs() < 1e-7 && (c.depth_weight_at(300) - 0.05).abs() < 1e-7);
        assert_eq!(SupervisionConfig::new().depth_weight_at(1_000_000), 0.2);
    }
}
