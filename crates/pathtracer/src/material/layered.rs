//! The glTF layers over the metallic-roughness BRDF ([`super::Bsdf::Layered`]):
//! `KHR_materials_sheen` (Charlie sheen, Estevez & Kulla 2017, "Production Friendly Microfacet
//! Sheen BRDF") under `KHR_materials_clearcoat` (a GGX coat), layered as the extensions' READMEs
//! write it. With `V = wo`, `L = wi`, `N = z` (the base's shading normal), `Nc` the coat's normal,
//! `S` the sheen colour, `c` the clearcoat weight, `f_base` the [`MetallicRoughness`] BRDF:
//!
//! ```text
//! α_s   = max(sheenRoughness, 0.07)²,  H = normalize(V + L)
//! D_s   = (2 + 1/α_s) (1 − (N·H)²)^(1/(2 α_s)) / (2π)                 Charlie distribution
//! λ(x)  = exp(l(x)) for x < 0.5, exp(2 l(0.5) − l(1 − x)) otherwise     Charlie's Λ fit
//! l(x)  = a/(1 + b x^c) + d x + e,  (a..e) = mix(p₀, p₁, (1 − α_s)²)   (the README's numbers)
//! V_s   = 1 / ((1 + λ(N·V) + λ(N·L)) 4 N·V N·L)
//! E(μ)  = ∫ D_s V_s N·L dL at N·V = μ,  Ê = min(E, 1)                  the sheen lobe's albedo
//! under = S D_s V_s Ê/E + f_base (1 − max(S) Ê)                          (all at N·V)
//! Fc    = 0.04 + 0.96 (1 − Nc·V)⁵,  α_c = max(clearcoatRoughness², MIN_ALPHA)
//! coat  = D(α_c, Nc·H) Vis(α_c, Nc·L, Nc·V)                           the base's GGX, F = 1
//! f cos = (1 − c Fc) under N·L + c Fc coat Nc·L
//! ```
//!
//! The coat's Fresnel reads `Nc·V`, not `V·H` (the clearcoat README's `fresnel_coat`): the
//! base's attenuation is then one number per `V`, so the albedo is `(1 − c Fc) E_under +
//! c Fc E_coat ≤ 1` since GGX without Fresnel reflects at most 1; with `V·H` the attenuation
//! would vary over `L` and no such bound holds. Likewise the sheen's albedo scaling reads `N·V`
//! only (the README's simplified form), so `E_under ≤ max(S) Ê + (1 − max(S) Ê) = 1`. `Ê/E`
//! divides the lobe by its albedo where the fitted `Λ` makes it exceed 1 (grazing views at sheen
//! roughness below ≈ 0.25: `E = 2.9` at μ = 0.001, r = 0.07), else it is 1. The coat
//! lobe carries its own cosine `Nc·L` (it is a surface with its own normal); both are 0 below
//! their horizons, and `f = 0` unless `N·V > 0` and `N·L > 0`. `E` is a table of 32 `μ` × 24
//! roughnesses integrated once ([`sheen_albedo`]), bilinearly interpolated. With `c = 0` and `S =
//! 0` every verb returns the base's values (evaluation bit for bit).
//!
//! Sampling: one-sample MIS over three lobes chosen with `u.x` (re-scaled): the coat's GGX
//! visible normals in the coat's frame with probability `P_c ∝ c Fc`, the sheen by uniform
//! hemisphere (`pdf 1/(2π)`) with `P_s ∝ (1 − c Fc) max(S) E`, the base's own sampling with
//! `P_b ∝ (1 − c Fc)(1 − max(S) E) max(A_b, 0.05)` (`A_b` its Fresnel-weighted albedo
//! estimate); `pdf = Σ P_i p_i` and the weight is `f cos / pdf`. Scalar only, like
//! [`super::Transmissive`].

// Negated comparisons (`!(x > 0.0)`) are deliberate: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::metallic_roughness::{CLEARCOAT_F0, visible_normal};
use super::{BsdfSample, MIN_ALPHA, MetallicRoughness};
use crate::geometry::Frame;
use glam::{Vec2, Vec3};
use std::f64::consts::PI;
use std::sync::OnceLock;

/// Smallest sheen roughness used: below it the Charlie lobe is narrower than the albedo table
/// resolves (the README leaves the clamp to implementations).
pub const SHEEN_MIN_ROUGHNESS: f32 = 0.07;

/// A metallic-roughness BRDF under a sheen and a clear coat (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Layered {
    /// The base BRDF.
    pub base: MetallicRoughness,
    /// Clearcoat weight `c` ∈ [0, 1].
    pub clearcoat: f32,
    /// The coat's GGX `α_c = max(clearcoatRoughness², MIN_ALPHA)`.
    pub coat_alpha: f32,
    /// The coat's unit normal in the local shading frame (`z` unless a normal map bends one of
    /// the two normals).
    pub coat_normal: Vec3,
    /// Sheen colour `S` (linear RGB in [0, 1]).
    pub sheen: Vec3,
    /// Sheen roughness, in [[`SHEEN_MIN_ROUGHNESS`], 1].
    pub sheen_roughness: f32,
}

impl Layered {
    /// The layers for clearcoat weight and roughness, sheen colour and roughness over `base`
    /// (each clamped to its range; non-finite values disable their layer).
    pub fn new(base: MetallicRoughness, clearcoat: f32, clearcoat_roughness: f32, sheen: Vec3, sheen_roughness: f32) -> Self {
        let unit = |x: f32, bad: f32| if x.is_finite() { x.clamp(0.0, 1.0) } else { bad };
        let r = unit(clearcoat_roughness, 1.0);
        let sheen = if sheen.is_finite() { sheen.clamp(Vec3::ZERO, Vec3::ONE) } else { Vec3::ZERO };
        Self {
            base,
            clearcoat: unit(clearcoat, 0.0),
            coat_alpha: (r * r).max(MIN_ALPHA),
            coat_normal: Vec3::Z,
            sheen,
            sheen_roughness: unit(sheen_roughness, 1.0).max(SHEEN_MIN_ROUGHNESS),
        }
    }

    /// The coat's GGX lobe (a metallic-roughness BRDF lends its `D`, `Vis` and sampling).
    fn coat(&self) -> MetallicRoughness {
        MetallicRoughness { alpha: self.coat_alpha, ..self.base }
    }

    /// `c Fc` at `wo`: the coat's share (0 where `Nc·V ≤ 0`).
    fn coat_share(&self, wo: Vec3) -> f32 {
        let ov = self.coat_normal.dot(wo);
        if !(self.clearcoat > 0.0) || !(ov > 0.0) {
            return 0.0;
        }
        let x = 1.0 - ov.min(1.0);
        let x2 = x * x;
        self.clearcoat * (CLEARCOAT_F0 + (1.0 - CLEARCOAT_F0) * x * x2 * x2)
    }

    /// `(max(S) Ê, Ê/E)` at `wo`: the sheen's share and the lobe's scale (see the module docs).
    fn sheen_share(&self, wo: Vec3) -> (f32, f32) {
        let s = self.sheen.max_element();
        if !(s > 0.0) {
            return (0.0, 1.0);
        }
        let e = sheen_albedo(wo.z, self.sheen_roughness);
        if e > 1.0 { (s, 1.0 / e) } else { (s * e, 1.0) }
    }

    /// Lobe probabilities `(P_c, P_s, P_b)` at `wo` and the shares `(c Fc, max(S) Ê)`.
    fn lobes(&self, wo: Vec3) -> ([f32; 3], f32, f32) {
        let (cf, (se, _)) = (self.coat_share(wo), self.sheen_share(wo));
        let wc = cf;
        let ws = (1.0 - cf) * se;
        let wb = (1.0 - cf) * (1.0 - se) * self.base.albedo_estimate(wo).max(0.05);
        let sum = wc + ws + wb;
        if !(sum > 0.0) || !sum.is_finite() {
            return ([0.0, 0.0, 1.0], cf, se);
        }
        ([wc / sum, ws / sum, wb / sum], cf, se)
    }

    /// `(f · cos θᵢ, pdf)` at `wi` (zero unless `wo.z > 0` and `wi.z > 0`).
    pub fn evaluate_pdf(&self, wo: Vec3, wi: Vec3) -> (Vec3, f32) {
        if !(wo.z > 0.0) || !(wi.z > 0.0) {
            return (Vec3::ZERO, 0.0);
        }
        let ([pc, ps, pb], cf, se) = self.lobes(wo);
        let mut under = self.base.f(wo, wi);
        if se > 0.0 {
            let h = (wo + wi).normalize();
            let lobe = charlie_d(f64::from(h.z), self.sheen_roughness) * charlie_vis(f64::from(wo.z), f64::from(wi.z), self.sheen_roughness);
            under = self.sheen * (lobe as f32 * self.sheen_share(wo).1) + under * (1.0 - se);
        }
        let mut f = under * wi.z;
        let mut pdf = pb * self.base.pdf(wo, wi);
        if ps > 0.0 {
            pdf += ps * (0.5 / std::f32::consts::PI);
        }
        if cf > 0.0 {
            f *= 1.0 - cf;
            let frame = Frame::from_normal(self.coat_normal);
            let (vo, vi) = (frame.to_local(wo), frame.to_local(wi));
            if vo.z > 0.0 && vi.z > 0.0 {
                let coat = self.coat();
                let h = (vo + vi).normalize();
                f += Vec3::splat(cf * coat.d(h) * coat.vis(vi.z, vo.z) * vi.z);
                pdf += pc * coat.pdf_specular(vo, vi);
            }
        }
        (f, pdf)
    }

    /// Draws `wi` with two uniform numbers (see the module docs).
    pub fn sample(&self, wo: Vec3, u: Vec2) -> Option<BsdfSample> {
        if !(wo.z > 0.0) {
            return None;
        }
        let ([pc, ps, pb], _, _) = self.lobes(wo);
        let wi = if u.x < pc {
            let frame = Frame::from_normal(self.coat_normal);
            let vo = frame.to_local(wo);
            let (h, ok) = visible_normal(self.coat_alpha, vo, Vec2::new(u.x / pc, u.y));
            if !ok {
                return None;
            }
            frame.to_world(2.0 * vo.dot(h) * h - vo).normalize()
        } else if u.x < pc + ps {
            let z = ((u.x - pc) / ps).min(1.0);
            let r = (1.0 - z * z).max(0.0).sqrt();
            let (sin, cos) = (2.0 * std::f32::consts::PI * u.y).sin_cos();
            Vec3::new(r * cos, r * sin, z)
        } else {
            let x = ((u.x - pc - ps) / pb).clamp(0.0, 1.0 - f32::EPSILON);
            super::Bsdf::MetallicRoughness(self.base).sample(wo, Vec2::new(x, u.y))?.wi
        };
        let (f, pdf) = self.evaluate_pdf(wo, wi);
        (wi.z > 0.0 && pdf > 0.0 && pdf.is_finite() && f.is_finite()).then(|| BsdfSample { wi, weight: f / pdf, pdf })
    }
}

/// The Charlie distribution `D_s(N·H)` for sheen roughness `r` (see the module docs).
pub fn charlie_d(nh: f64, r: f32) -> f64 {
    let a = f64::from(r.max(SHEEN_MIN_ROUGHNESS)).powi(2);
    let sin2 = (1.0 - nh * nh).max(0.0);
    (2.0 + 1.0 / a) * sin2.powf(0.5 / a) / (2.0 * PI)
}

/// Charlie's fitted `Λ`: `λ(x)` of the module docs for sheen roughness `r`.
fn charlie_lambda(x: f64, r: f32) -> f64 {
    let a = f64::from(r.max(SHEEN_MIN_ROUGHNESS)).powi(2);
    let t = (1.0 - a) * (1.0 - a);
    let mix = |p0: f64, p1: f64| p0 + (p1 - p0) * t;
    let l = |x: f64| {
        mix(21.5473, 25.3245) / (1.0 + mix(3.82987, 3.32435) * x.powf(mix(0.19823, 0.16801))) + mix(-1.97760, -1.27393) * x + mix(-4.32054, -4.85967)
    };
    if x < 0.5 { l(x).exp() } else { (2.0 * l(0.5) - l(1.0 - x)).exp() }
}

/// The Charlie visibility `V_s(N·V, N·L)` (0 unless both are > 0).
pub fn charlie_vis(nv: f64, nl: f64, r: f32) -> f64 {
    if !(nv > 0.0) || !(nl > 0.0) {
        return 0.0;
    }
    1.0 / ((1.0 + charlie_lambda(nv, r) + charlie_lambda(nl, r)) * 4.0 * nv * nl)
}

/// `∫ D_s V_s N·L dL` over the hemisphere at `N·V = mu`, by the midpoint rule with `n` steps
/// in `cos θ_L` and in `φ` (over `[0, π]`, doubled: the lobe is symmetric about `V`'s plane).
pub fn sheen_albedo_integral(mu: f64, r: f32, n: usize) -> f64 {
    let v = [(1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu];
    let mut sum = 0.0;
    for i in 0..n {
        let z = (i as f64 + 0.5) / n as f64;
        let s = (1.0 - z * z).sqrt();
        for j in 0..n {
            let phi = PI * (j as f64 + 0.5) / n as f64;
            let l = [s * phi.cos(), s * phi.sin(), z];
            let h = [v[0] + l[0], v[1] + l[1], v[2] + l[2]];
            let nh = h[2] / (h[0] * h[0] + h[1] * h[1] + h[2] * h[2]).sqrt();
            sum += charlie_d(nh, r) * charlie_vis(mu, z, r) * z;
        }
    }
    2.0 * sum * PI / (n * n) as f64
}

/// Table size: `N·V = t²` nodes for `t` uniform over [0, 1] (dense at grazing views, where `E`
/// is steep) and roughness nodes spaced evenly in `log r` over [[`SHEEN_MIN_ROUGHNESS`], 1].
const TABLE_MU: usize = 32;
const TABLE_R: usize = 24;
/// Midpoint steps per dimension for each table entry.
const TABLE_STEPS: usize = 64;

/// The sheen albedo table, built once ([`sheen_albedo_integral`] at each node; `μ = 0` takes
/// the value at `μ = 10⁻⁴`).
fn table() -> &'static [[f32; TABLE_MU]; TABLE_R] {
    static TABLE: OnceLock<[[f32; TABLE_MU]; TABLE_R]> = OnceLock::new();
    TABLE.get_or_init(|| {
        let mut t = [[0.0; TABLE_MU]; TABLE_R];
        for (j, row) in t.iter_mut().enumerate() {
            let r = f64::from(SHEEN_MIN_ROUGHNESS).powf(1.0 - j as f64 / (TABLE_R - 1) as f64) as f32;
            for (i, e) in row.iter_mut().enumerate() {
                let x = i as f64 / (TABLE_MU - 1) as f64;
                *e = sheen_albedo_integral((x * x).max(1e-4), r, TABLE_STEPS) as f32;
            }
        }
        t
    })
}

/// `E(μ)` for sheen roughness `r`: the table bilinearly interpolated in (`√μ`, `log r`), both
/// clamped to it.
pub fn sheen_albedo(mu: f32, r: f32) -> f32 {
    let t = table();
    let x = if mu.is_finite() { mu.clamp(0.0, 1.0).sqrt() * (TABLE_MU - 1) as f32 } else { 0.0 };
    let r = if r.is_finite() { r.clamp(SHEEN_MIN_ROUGHNESS, 1.0) } else { 1.0 };
    let y = (1.0 - r.ln() / SHEEN_MIN_ROUGHNESS.ln()) * (TABLE_R - 1) as f32;
    let (i, j) = ((x as usize).min(TABLE_MU - 2), (y.max(0.0) as usize).min(TABLE_R - 2));
    let (fx, fy) = (x - i as f32, y - j as f32);
    let row = |j: usize| t[j][i] + (t[j][i + 1] - t[j][i]) * fx;
    row(j) + (row(j + 1) - row(j)) * fy
}
