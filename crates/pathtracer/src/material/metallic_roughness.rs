//! The glTF 2.0 metallic-roughness model ([`super::Bsdf::MetallicRoughness`]): a GGX specular
//! lobe (dielectric and conductor Fresnel) over a diffuse lobe, with `KHR_materials_specular`
//! and `KHR_materials_ior`; formulas, sampling and parameters on [`MetallicRoughness`]. Also
//! its lane forms (the same operations on one lane of [`SampleLane`], see the [`super`] module
//! docs) and the narrowest, brightest lobe a glTF material can have ([`SpecularLobe`], what the
//! caustic light tracer asks).

// Negated comparisons (`!(x > 0.0)`) are deliberate: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::gltf::{max_dielectric_f0, min_roughness_texel};
use super::SampleLane;
use crate::light::luminance;
use crate::sampler::sin_cos;
use crate::scene::{Material, Texture};
use glam::{Vec2, Vec3};
use std::f32::consts::{FRAC_1_PI, PI};

/// Smallest GGX `α` used: `α = max(roughness², MIN_ALPHA)`. Roughness 0 (a mirror) is
/// rendered as an extremely narrow GGX lobe (peak `D = 1/(π·10⁻⁶) ≈ 3·10⁵`), which keeps
/// every value finite in `f32` and keeps the three verbs consistent; no delta lobe is used.
pub const MIN_ALPHA: f32 = 1e-3;

/// Normal-incidence reflectance of glTF's dielectric, `((1 − ior)/(1 + ior))²` with ior 1.5.
pub const DIELECTRIC_F0: f32 = 0.04;

/// Normal-incidence reflectance of `KHR_materials_clearcoat`'s coat (ior 1.5; see
/// [`super::Layered`]).
pub const CLEARCOAT_F0: f32 = 0.04;

/// The dielectric layer's Fresnel endpoints (`KHR_materials_specular` with
/// `KHR_materials_ior`, as the extensions' READMEs write them):
///
/// ```text
/// F0  = min(((ior − 1)/(ior + 1))² · specularColorFactor · specularColorTexture.rgb, 1)
///         · specularFactor · specularTexture.a
/// F90 = specularFactor · specularTexture.a
/// ```
///
/// `ior` 1.5 (glTF's default) gives exactly [`DIELECTRIC_F0`]; `ior` 0 gives `F0 = 1`
/// (`KHR_materials_ior`'s specular-glossiness conversion). Plain glTF is
/// `F0 = (0.04, 0.04, 0.04)`, `F90 = 1`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DielectricFresnel {
    /// F0 per channel, in [0, 1].
    pub f0: Vec3,
    /// F90 (the specular weight), in [0, 1].
    pub f90: f32,
}

impl DielectricFresnel {
    /// Plain glTF's dielectric: ior 1.5, specular 1, specular colour 1.
    pub const GLTF: Self = Self { f0: Vec3::splat(DIELECTRIC_F0), f90: 1.0 };

    /// The endpoints for `ior`, the specular colour (factor × texture RGB) and the specular
    /// weight (factor × texture A); see the type docs. Out-of-range inputs are clamped
    /// (weight and colour to [0, 1] and ≥ 0, a non-finite `ior` is taken as 1.5).
    pub fn new(ior: f32, specular_color: Vec3, specular: f32) -> Self {
        let weight = if specular.is_finite() { specular.clamp(0.0, 1.0) } else { 1.0 };
        let color = if specular_color.is_finite() { specular_color.max(Vec3::ZERO) } else { Vec3::ONE };
        Self { f0: (f0_from_ior(ior) * color).min(Vec3::ONE) * weight, f90: weight }
    }
}

/// `((ior − 1)/(ior + 1))²`, computed in `f64` (so that 1.5 rounds to exactly
/// [`DIELECTRIC_F0`]); 1 for ior 0, [`DIELECTRIC_F0`] for a non-finite or negative ior.
pub fn f0_from_ior(ior: f32) -> f32 {
    if !(ior >= 0.0) || !ior.is_finite() {
        return DIELECTRIC_F0;
    }
    let r = (f64::from(ior) - 1.0) / (f64::from(ior) + 1.0);
    (r * r) as f32
}

/// The glTF 2.0 metallic-roughness BRDF (glTF 2.0 specification, Appendix B), with
/// `KHR_materials_specular` and `KHR_materials_ior` (the dielectric's Fresnel endpoints
/// `F0`, `F90` of [`DielectricFresnel`]; `fresnel_mix` of `KHR_materials_specular`'s
/// Implementation section).
///
/// Parameters: `ρ` = `base_color` (linear RGB, in [0, 1]), `m` = `metallic` ∈ [0, 1],
/// `α = max(roughness², MIN_ALPHA)` = `alpha`, `F0` = `fresnel.f0` (RGB), `F90` =
/// `fresnel.f90` (plain glTF: `F0 = 0.04`, `F90 = 1`).
/// With `V = wo`, `L = wi`, `N = z`, `H = normalize(V + L)`, all cosines taken in the local
/// frame, and `f = 0` unless `N·V > 0` and `N·L > 0`:
///
/// ```text
/// D(H)      = α² / (π ((N·H)² (α² − 1) + 1)²)                        Trowbridge–Reitz (GGX)
/// Vis(L, V) = 1 / ((N·L + √(α² + (1 − α²)(N·L)²)) (N·V + √(α² + (1 − α²)(N·V)²)))
///                     (the spec's V_GGX: separable Smith, Vis = G / (4 N·L N·V))
/// spec      = D · Vis                                                  specular_brdf(α)
/// w5        = (1 − V·H)⁵
/// F_d       = F0 + (F90 − F0) w5           (RGB)                       dielectric Schlick
/// F_m       = ρ + (1 − ρ) w5                                           conductor Schlick
/// dielectric = (1 − max(F_d)) ρ/π + F_d spec                           fresnel_mix(…)
/// metal      = F_m spec                                                conductor_fresnel(ρ, …)
/// f(V, L)    = (1 − m) dielectric + m metal
/// ```
///
/// `evaluate` returns `f · N·L`. The BRDF is reciprocal (D, Vis and `V·H = L·H` are
/// symmetric). `F90 = 0` (so `F0 = 0`), `m = 0` is exactly Lambertian (`resolve` then uses
/// [`super::Bsdf::Diffuse`]). `max(F_d)` is the largest channel (`max_value` in the extension).
///
/// Sampling: a two-lobe mixture chosen with `u.x` (re-scaled for reuse):
/// - specular with probability `P_s`: the GGX distribution of visible normals (Heitz 2018,
///   "Sampling the GGX Distribution of Visible Normals"), `L = reflect(V, H)`, density
///   `p_s(L) = G1(V) D(H) / (4 N·V) = D(H) / (2 (N·V + √(α² + (1 − α²)(N·V)²)))` with
///   `G1(V) = 2 N·V / (N·V + √(α² + (1 − α²)(N·V)²))`;
/// - diffuse with probability `1 − P_s`: cosine-weighted, `p_d(L) = N·L / π`.
///
/// `pdf = P_s p_s + (1 − P_s) p_d` and the sample weight is `f · N·L / pdf` (one-sample MIS
/// over the two lobes). `P_s` is the Fresnel-weighted albedo estimate at `V`, with
/// `w5ᵥ = (1 − N·V)⁵` and `Fᵥ = max(F0 + (F90 − F0) w5ᵥ)` (largest channel):
/// `E_s = (1 − m) Fᵥ + m Y(ρ + (1 − ρ) w5ᵥ)`, `E_d = (1 − m)(1 − Fᵥ) Y(ρ)` (Y = Rec. 709
/// luminance), `P_s = clamp(E_s / (E_s + E_d), 0.1, 0.9)`; `P_s = 1` when the diffuse lobe
/// vanishes (`m = 1` or `ρ = 0`) and `0` when the specular one does (`m = 0`, `F90 = 0`). VNDF samples
/// reflected below the horizon return `None` (their `f` is 0), so the pdf integrates over the
/// upper hemisphere to the probability that `sample` returns `Some`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MetallicRoughness {
    /// Base colour ρ (linear RGB, clamped to [0, 1]).
    pub base_color: Vec3,
    /// Metallic m ∈ [0, 1].
    pub metallic: f32,
    /// GGX α = max(roughness², [`MIN_ALPHA`]).
    pub alpha: f32,
    /// The dielectric's Fresnel endpoints ([`DielectricFresnel::GLTF`] for plain glTF).
    pub fresnel: DielectricFresnel,
}

impl MetallicRoughness {
    /// The BRDF for base colour, metallic, perceptual roughness and specular weight, with
    /// ior 1.5 and specular colour 1 (each clamped to its range; non-finite values take
    /// glTF's defaults 1).
    pub fn new(base_color: Vec3, metallic: f32, roughness: f32, specular: f32) -> Self {
        Self::with_fresnel(base_color, metallic, roughness, DielectricFresnel::new(1.5, Vec3::ONE, specular))
    }

    /// The BRDF for base colour, metallic, perceptual roughness and the dielectric's Fresnel
    /// endpoints (clamped as in [`MetallicRoughness::new`]).
    pub fn with_fresnel(base_color: Vec3, metallic: f32, roughness: f32, fresnel: DielectricFresnel) -> Self {
        let unit = |x: f32| if x.is_finite() { x.clamp(0.0, 1.0) } else { 1.0 };
        let base_color = if base_color.is_finite() { base_color.clamp(Vec3::ZERO, Vec3::ONE) } else { Vec3::ZERO };
        let r = unit(roughness);
        Self { base_color, metallic: unit(metallic), alpha: (r * r).max(MIN_ALPHA), fresnel }
    }

    /// The dielectric's Fresnel term `F_d = F0 + (F90 − F0) w5` (RGB).
    #[inline(always)]
    fn fresnel_dielectric(&self, w5: f32) -> Vec3 {
        let DielectricFresnel { f0, f90 } = self.fresnel;
        f0 + (Vec3::splat(f90) - f0) * w5
    }

    /// GGX `D(h)` for a unit half vector; `(N·H)²(α² − 1) + 1` is computed as
    /// `hx² + hy² + hz² α²` (equal for unit `h`, without cancellation near the peak).
    #[inline]
    pub fn d(&self, h: Vec3) -> f32 {
        if h.z <= 0.0 {
            return 0.0;
        }
        let a2 = self.alpha * self.alpha;
        let den = h.x * h.x + h.y * h.y + h.z * h.z * a2;
        a2 / (PI * den * den)
    }

    /// `N·X + √(α² + (1 − α²)(N·X)²)` for `c = N·X > 0`.
    #[inline]
    pub(super) fn smith_den(&self, c: f32) -> f32 {
        let a2 = self.alpha * self.alpha;
        c + (a2 + (1.0 - a2) * c * c).sqrt()
    }

    /// Smith masking `G1(c) = 2c / (c + √(α² + (1 − α²)c²))` for `c = N·X`.
    #[inline]
    pub fn g1(&self, c: f32) -> f32 {
        if c <= 0.0 { 0.0 } else { 2.0 * c / self.smith_den(c) }
    }

    /// The spec's `V_GGX(N·L, N·V)` (see the type docs).
    #[inline]
    pub fn vis(&self, nl: f32, nv: f32) -> f32 {
        if nl <= 0.0 || nv <= 0.0 { 0.0 } else { 1.0 / (self.smith_den(nl) * self.smith_den(nv)) }
    }

    /// `f(wo, wi)` without the cosine.
    #[inline]
    pub fn f(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return Vec3::ZERO;
        }
        let h = (wo + wi).normalize();
        let vh = wo.dot(h).clamp(0.0, 1.0);
        let w5 = pow5(1.0 - vh);
        let spec = self.d(h) * self.vis(wi.z, wo.z);
        let rho = self.base_color;
        let fd = self.fresnel_dielectric(w5);
        let dielectric = rho * ((1.0 - fd.max_element()) * FRAC_1_PI) + fd * spec;
        let metal = (rho + (Vec3::ONE - rho) * w5) * spec;
        dielectric * (1.0 - self.metallic) + metal * self.metallic
    }

    /// `(f(wo, wi) · N·L, D(H))` for `wo.z > 0`, `wi.z > 0`, given `sd_wo =
    /// smith_den(wo.z)`: the shared core of evaluation, pdf and sampling (the same
    /// expressions as [`MetallicRoughness::f`] and [`MetallicRoughness::pdf_specular`], so
    /// the values agree bit for bit).
    #[inline(always)]
    fn f_cos_and_d(&self, wo: Vec3, wi: Vec3, sd_wo: f32) -> (Vec3, f32) {
        let h = (wo + wi).normalize();
        let vh = wo.dot(h).clamp(0.0, 1.0);
        let w5 = pow5(1.0 - vh);
        let d = self.d(h);
        let spec = d * (1.0 / (self.smith_den(wi.z) * sd_wo));
        let rho = self.base_color;
        let fd = self.fresnel_dielectric(w5);
        let dielectric = rho * ((1.0 - fd.max_element()) * FRAC_1_PI) + fd * spec;
        let metal = (rho + (Vec3::ONE - rho) * w5) * spec;
        ((dielectric * (1.0 - self.metallic) + metal * self.metallic) * wi.z, d)
    }

    /// Probability `P_s` of sampling the specular lobe at `wo` (see the type docs).
    #[inline(always)]
    pub fn specular_probability(&self, wo: Vec3) -> f32 {
        let (m, rho) = (self.metallic, self.base_color);
        let has_diffuse = m < 1.0 && rho.max_element() > 0.0;
        let has_specular = m > 0.0 || self.fresnel.f90 > 0.0;
        match (has_specular, has_diffuse) {
            (false, _) => 0.0,
            (true, false) => 1.0,
            (true, true) => {
                let w5 = pow5(1.0 - wo.z.clamp(0.0, 1.0));
                let fd = self.fresnel_dielectric(w5).max_element();
                let es = (1.0 - m) * fd + m * luminance(rho + (Vec3::ONE - rho) * w5);
                let ed = (1.0 - m) * (1.0 - fd) * luminance(rho);
                let p = es / (es + ed);
                if p.is_finite() { p.clamp(0.1, 0.9) } else { 0.5 }
            }
        }
    }

    /// The Fresnel-weighted albedo estimate `E_s + E_d` at `wo` that `P_s` is made of (see the
    /// type docs): what a mixture of this BRDF with other lobes weighs it by.
    pub fn albedo_estimate(&self, wo: Vec3) -> f32 {
        let (m, rho) = (self.metallic, self.base_color);
        let w5 = pow5(1.0 - wo.z.clamp(0.0, 1.0));
        let fd = self.fresnel_dielectric(w5).max_element();
        let es = (1.0 - m) * fd + m * luminance(rho + (Vec3::ONE - rho) * w5);
        let ed = (1.0 - m) * (1.0 - fd) * luminance(rho);
        es + ed
    }

    /// Solid-angle density with which the model samples `wi` (for `wo`, `wi` above the
    /// surface): `P_s p_s + (1 − P_s) p_d` (see the type docs).
    #[inline]
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        let ps = self.specular_probability(wo);
        ps * self.pdf_specular(wo, wi) + (1.0 - ps) * wi.z * FRAC_1_PI
    }

    /// Density of the VNDF lobe: `D(H) / (2 (N·V + √(α² + (1 − α²)(N·V)²)))`.
    #[inline]
    pub fn pdf_specular(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return 0.0;
        }
        let h = (wo + wi).normalize();
        self.d(h) / (2.0 * self.smith_den(wo.z))
    }

    /// A visible normal for `wo` (Heitz 2018, isotropic α), or `None` if degenerate.
    #[inline(always)]
    pub fn sample_visible_normal(&self, wo: Vec3, u: Vec2) -> Option<Vec3> {
        let (h, ok) = visible_normal(self.alpha, wo, u);
        ok.then_some(h)
    }
}

/// `x⁵` as `x · (x²)²`: the product LLVM expands `powi(x, 5)` into, written out so that it is
/// the same operations in a loop over lanes ([`sample_many`]).
#[inline(always)]
fn pow5(x: f32) -> f32 {
    let x2 = x * x;
    x * (x2 * x2)
}

/// [`MetallicRoughness::sample_visible_normal`] without branches on its data (selects only,
/// so that a loop over lanes vectorises): the normal and whether it is valid.
#[inline(always)]
pub(super) fn visible_normal(a: f32, wo: Vec3, u: Vec2) -> (Vec3, bool) {
    let vh = Vec3::new(a * wo.x, a * wo.y, wo.z).normalize_or_zero();
    let lensq = vh.x * vh.x + vh.y * vh.y;
    let t1 = if lensq > 0.0 { Vec3::new(-vh.y, vh.x, 0.0) / lensq.sqrt() } else { Vec3::X };
    let t2 = vh.cross(t1);
    let r = u.x.sqrt();
    let (sin, cos) = sin_cos(2.0 * PI * u.y);
    let p1 = r * cos;
    let s = 0.5 * (1.0 + vh.z);
    let p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * r * sin;
    let nh = p1 * t1 + p2 * t2 + (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt() * vh;
    let h = Vec3::new(a * nh.x, a * nh.y, nh.z.max(0.0)).normalize_or_zero();
    (h, (vh != Vec3::ZERO) & (h != Vec3::ZERO))
}

/// The lane record of `mr` seen from `wo` (with [`MetallicRoughness::specular_probability`]
/// `ps` and [`MetallicRoughness::smith_den`] `sd_wo` there) with the numbers `u`.
#[inline(always)]
pub(super) fn lane(mr: &MetallicRoughness, wo: Vec3, ps: f32, sd_wo: f32, u: Vec2) -> SampleLane {
    SampleLane { diffuse: false, rho: mr.base_color, metallic: mr.metallic, alpha: mr.alpha, f0: mr.fresnel.f0, f90: mr.fresnel.f90, wo, ps, sd_wo, u }
}

/// The model's BRDF from a lane's numbers.
#[inline(always)]
fn of_lane(x: &SampleLane) -> MetallicRoughness {
    MetallicRoughness { base_color: x.rho, metallic: x.metallic, alpha: x.alpha, fresnel: DielectricFresnel { f0: x.f0, f90: x.f90 } }
}

/// `(P_s(wo), smith_den(wo.z))` of a lane where `wo` is above the surface, else `(0, 0)`:
/// what [`super::Bsdf::at`] computes once, with no branch on the data.
#[inline(always)]
pub(super) fn wo_terms_lane(x: &SampleLane) -> (f32, f32) {
    let mr = of_lane(x);
    let up = x.wo.z > 0.0;
    let ps = if up { mr.specular_probability(x.wo) } else { 0.0 };
    let sd = if up { mr.smith_den(x.wo.z) } else { 0.0 };
    (ps, sd)
}

/// One lane's `(f · cos θᵢ, pdf)` at `wi` above the surface (the caller zeroes it below).
#[inline(always)]
pub(super) fn evaluate_pdf_lane(x: &SampleLane, wi: Vec3) -> (Vec3, f32) {
    let (f_mr, d) = of_lane(x).f_cos_and_d(x.wo, wi, x.sd_wo);
    let ps = x.ps;
    (f_mr, ps * (d / (2.0 * x.sd_wo)) + (1.0 - ps) * wi.z * FRAC_1_PI)
}

/// The numbers of the diffuse lobe's cosine-weighted direction: `u.x` re-scaled past the
/// specular lobe's share `ps`.
#[inline(always)]
pub(super) fn diffuse_lobe_numbers(u: Vec2, ps: f32) -> Vec2 {
    Vec2::new(((u.x - ps) / (1.0 - ps)).min(1.0 - f32::EPSILON), u.y)
}

/// One lane's sample `(wi, weight, pdf, valid)`: both lobes computed and the one `u.x`
/// chooses selected (no branch on the data). `wi_d` is the cosine-weighted direction of
/// [`diffuse_lobe_numbers`].
#[inline(always)]
pub(super) fn sample_lane(x: &SampleLane, wi_d: Vec3) -> (Vec3, Vec3, f32, bool) {
    let SampleLane { alpha, wo, ps, sd_wo, u, .. } = *x;
    // Specular lobe: a visible normal, `wi` its reflection.
    let specular = u.x < ps;
    let (h, h_ok) = visible_normal(alpha, wo, Vec2::new(u.x / ps, u.y));
    let wi_s = (2.0 * wo.dot(h) * h - wo).normalize();
    let wi = if specular { wi_s } else { wi_d };
    let (f, d) = of_lane(x).f_cos_and_d(wo, wi, sd_wo);
    let pdf = ps * (d / (2.0 * sd_wo)) + (1.0 - ps) * wi.z * FRAC_1_PI;
    let ok = (!specular | h_ok) & (wi.z > 0.0) & (pdf > 0.0) & pdf.is_finite() & f.is_finite();
    (wi, f / pdf, pdf, !(wo.z <= 0.0) & ok)
}

/// The narrowest and brightest specular lobe a glTF material can have anywhere on its
/// surface ([`Material::sharpest_specular_lobe`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpecularLobe {
    /// The largest normal-incidence reflectance: the base colour factor's largest channel
    /// where the material can be metallic (or the dielectric layer's, if larger), else the
    /// dielectric layer's ([`max_dielectric_f0`] × the specular factor); a clear coat's
    /// `0.04 × clearcoat` where larger.
    pub f0: f32,
    /// The smallest GGX `α`: `max((roughness factor × the smallest G of its
    /// metallic-roughness texture)², MIN_ALPHA)`, or a clear coat's where smaller.
    pub alpha: f32,
}

impl Material {
    /// The narrowest and brightest specular lobe this material can have ([`SpecularLobe`]),
    /// or `None` without one (`F0 = 0`). Texture references `textures` lacks are ignored.
    pub fn sharpest_specular_lobe(&self, textures: &[Texture]) -> Option<SpecularLobe> {
        let dielectric = max_dielectric_f0(self) * self.specular_factor.max(0.0);
        let f0 = if self.metallic_factor > 0.0 { self.base_color_factor.truncate().max_element().max(dielectric) } else { dielectric };
        let r = (self.roughness_factor * min_roughness_texel(self, textures)).clamp(0.0, 1.0);
        let base = (f0 > 0.0).then(|| SpecularLobe { f0, alpha: (r * r).max(MIN_ALPHA) });
        // A clear coat is a lobe of its own: `F0 = 0.04 × clearcoat`, α from its roughness
        // factor × the smallest G of its roughness texture.
        let coat = self.clearcoat.map(|c| {
            let min_g = c
                .roughness_texture
                .and_then(|t| textures.get(t.texture as usize))
                .map(|t| t.texels.iter().map(|x| x.y).fold(f32::INFINITY, f32::min))
                .filter(|g| g.is_finite())
                .unwrap_or(1.0);
            let r = (c.roughness_factor * min_g).clamp(0.0, 1.0);
            SpecularLobe { f0: CLEARCOAT_F0 * c.factor, alpha: (r * r).max(MIN_ALPHA) }
        });
        match (base, coat) {
            (Some(b), Some(c)) => Some(SpecularLobe { f0: b.f0.max(c.f0), alpha: b.alpha.min(c.alpha) }),
            (b, c) => b.or(c),
        }
    }
}
