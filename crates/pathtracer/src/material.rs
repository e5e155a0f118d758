//! Materials: turning a glTF [`Material`] at a surface point into a BSDF plus emission, and
//! the BSDF verbs `evaluate` / `sample` / `pdf` (Mitsuba's interface).
//!
//! Conventions: directions `wo` (towards the viewer, glTF's `V`) and `wi` (towards the light,
//! glTF's `L`) point away from the surface and are expressed in the local shading [`Frame`]
//! whose `n` (z axis) is the shading normal already flipped to the side the ray came from.
//! `evaluate` returns `f(wo, wi) · |cos θᵢ|` (the cosine-weighted BSDF), `sample` returns the
//! weight `f · |cos θᵢ| / pdf`, and `pdf` is per unit solid angle. Every BSDF here is
//! reflection-only: `f = 0` unless `wo.z > 0` and `wi.z > 0`.
//!
//! Every glTF material is shaded with [`Bsdf::MetallicRoughness`], the glTF 2.0
//! metallic-roughness BRDF of the specification's Appendix B (see [`MetallicRoughness`] for
//! the exact formulas, which the Mitsuba cross-check re-implements). [`Bsdf::Diffuse`] is the
//! pure Lambertian BRDF; `resolve` produces it only when the glTF BRDF reduces to it exactly
//! (metallic 0 and `KHR_materials_specular` `specular` 0, see [`Material::specular_factor`]).
//!
//! Textures: base colour = factor × texture × COLOR_0; metallic = factor × texture B,
//! roughness = factor × texture G (glTF §3.9.2); specular weight = factor × texture A,
//! specular colour = factor × texture RGB (`KHR_materials_specular`); normal maps perturb
//! the shading normal in [`normal_mapped`] (tangents from the asset, or generated per
//! triangle from the UVs, untransformed: a `KHR_texture_transform` moves where the normal
//! map is read, not the tangent frame). Every lookup goes through the reference's UV set and
//! `KHR_texture_transform` ([`crate::texture::ref_uv`]).
//!
//! Alpha: `Mask` keeps a surface where alpha ≥ cutoff; `Blend` is stochastic coverage, a
//! surface present with probability alpha decided by a hash of (ray, triangle)
//! (see `integrator::alpha_test`). Sidedness: a single-sided triangle hit from behind is not
//! hit at all (glTF back-face culling), so it neither occludes nor emits from behind;
//! double-sided triangles shade with the normal flipped towards the incoming ray and emit
//! from both sides.

// Negated comparisons (`!(x > 0.0)`) are deliberate: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use crate::geometry::Frame;
use crate::light::luminance;
use crate::sampler::{sample_cosine_hemisphere, sin_cos};
use crate::scene::{Material, Scene, Texture};
use crate::texture::sample_ref;
use glam::{Vec2, Vec3, Vec4};
use std::f32::consts::{FRAC_1_PI, PI};

/// Smallest GGX `α` used: `α = max(roughness², MIN_ALPHA)`. Roughness 0 (a mirror) is
/// rendered as an extremely narrow GGX lobe (peak `D = 1/(π·10⁻⁶) ≈ 3·10⁵`), which keeps
/// every value finite in `f32` and keeps the three verbs consistent; no delta lobe is used.
pub const MIN_ALPHA: f32 = 1e-3;

/// Normal-incidence reflectance of glTF's dielectric, `((1 − ior)/(1 + ior))²` with ior 1.5.
pub const DIELECTRIC_F0: f32 = 0.04;

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

/// Smallest `cos` between `wo` and a shading normal: [`shading_frame`] bends shading normals
/// (interpolated or normal-mapped) that face away from the viewer to this value.
pub const MIN_SHADING_COS: f32 = 1e-3;

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
/// [`Bsdf::Diffuse`]). `max(F_d)` is the largest channel (`max_value` in the extension).
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
    fn smith_den(&self, c: f32) -> f32 {
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
fn visible_normal(a: f32, wo: Vec3, u: Vec2) -> (Vec3, bool) {
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

/// A BSDF at one surface point. A closed set of models, dispatched with `match`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Bsdf {
    /// Lambertian diffuse reflection: `f(wo, wi) = ρ / π` for `wi` in the upper hemisphere,
    /// 0 below; cosine-weighted sampling with `pdf = cos θᵢ / π`, so the sample weight is
    /// exactly `ρ`. Parameter: albedo `ρ` (linear RGB, base colour).
    Diffuse {
        /// Albedo ρ.
        albedo: Vec3,
    },
    /// The glTF metallic-roughness BRDF; formulas, sampling and parameters on
    /// [`MetallicRoughness`].
    MetallicRoughness(MetallicRoughness),
}

/// A direction drawn from a BSDF.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BsdfSample {
    /// Sampled incident direction (local frame).
    pub wi: Vec3,
    /// `f · |cos θᵢ| / pdf`.
    pub weight: Vec3,
    /// Solid-angle density of `wi`.
    pub pdf: f32,
}

/// A [`Bsdf`] seen from a fixed `wo` ([`Bsdf::at`]): the specular-lobe probability `P_s`
/// and the Smith term of `wo` are computed once. Its verbs return exactly (bit for bit) what
/// the [`Bsdf`] verbs return for the same `wo`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BsdfAt {
    bsdf: Bsdf,
    wo: Vec3,
    /// `P_s(wo)` (metallic-roughness only).
    ps: f32,
    /// `N·V + √(α² + (1 − α²)(N·V)²)` (metallic-roughness only).
    sd_wo: f32,
}

impl BsdfAt {
    /// The outgoing direction this was prepared for.
    pub fn wo(&self) -> Vec3 {
        self.wo
    }

    /// [`Bsdf::evaluate`] and [`Bsdf::pdf`] at `wi` (one lane of [`evaluate_many`]).
    #[inline(always)]
    pub fn evaluate_pdf(&self, wi: Vec3) -> (Vec3, f32) {
        evaluate_pdf_lane::<false>(&self.lane(Vec2::ZERO), wi)
    }

    /// [`Bsdf::sample`] with two uniform numbers (one lane of [`sample_many`]).
    #[inline(always)]
    pub fn sample(&self, u: Vec2) -> Option<BsdfSample> {
        let (wi, weight, pdf, ok) = sample_lane::<false>(self.lane(u));
        ok.then_some(BsdfSample { wi, weight, pdf })
    }

    /// What [`sample_lane`] and [`evaluate_pdf_lane`] read of this BSDF, with the numbers `u`.
    #[inline(always)]
    pub(crate) fn lane(&self, u: Vec2) -> SampleLane {
        match &self.bsdf {
            Bsdf::Diffuse { albedo } => SampleLane {
                diffuse: true,
                rho: *albedo,
                metallic: 0.0,
                alpha: 1.0,
                f0: Vec3::ZERO,
                f90: 0.0,
                wo: self.wo,
                ps: 0.0,
                sd_wo: 1.0,
                u,
            },
            Bsdf::MetallicRoughness(mr) => SampleLane {
                diffuse: false,
                rho: mr.base_color,
                metallic: mr.metallic,
                alpha: mr.alpha,
                f0: mr.fresnel.f0,
                f90: mr.fresnel.f90,
                wo: self.wo,
                ps: self.ps,
                sd_wo: self.sd_wo,
                u,
            },
        }
    }
}

/// `(ps, sd_wo)` of the lane `x` seen from `x.wo`: what [`Bsdf::at`] computes and
/// [`BsdfAt::lane`] passes on (`(0, 1)` for the Lambertian model; for the metallic-roughness
/// BRDF `P_s(wo)` and the Smith denominator where `wo` is above the surface, else `(0, 0)`),
/// with no branch on the data, so that a loop over lanes vectorises.
#[inline(always)]
pub(crate) fn wo_terms(x: &SampleLane) -> (f32, f32) {
    let mr = MetallicRoughness { base_color: x.rho, metallic: x.metallic, alpha: x.alpha, fresnel: DielectricFresnel { f0: x.f0, f90: x.f90 } };
    let up = x.wo.z > 0.0;
    let ps = if up { mr.specular_probability(x.wo) } else { 0.0 };
    let sd = if up { mr.smith_den(x.wo.z) } else { 0.0 };
    if x.diffuse { (0.0, 1.0) } else { (ps, sd) }
}

/// One BSDF sample's inputs as plain numbers (a lane of [`sample_many`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct SampleLane {
    /// [`Bsdf::Diffuse`] (albedo `rho`), else [`Bsdf::MetallicRoughness`].
    pub(crate) diffuse: bool,
    pub(crate) rho: Vec3,
    pub(crate) metallic: f32,
    pub(crate) alpha: f32,
    pub(crate) f0: Vec3,
    pub(crate) f90: f32,
    pub(crate) wo: Vec3,
    pub(crate) ps: f32,
    pub(crate) sd_wo: f32,
    pub(crate) u: Vec2,
}

/// [`BsdfAt::evaluate_pdf`] of one lane: `(f · cos θᵢ, pdf)`. Both models are computed and
/// the lane's own selected, with no branch on the data, so that a loop over lanes vectorises
/// ([`evaluate_many`]).
#[inline(always)]
fn evaluate_pdf_lane<const ALL_DIFFUSE: bool>(x: &SampleLane, wi: Vec3) -> (Vec3, f32) {
    let wo = x.wo;
    let below = (wo.z <= 0.0) | (wi.z <= 0.0);
    let lambert = (x.rho * (FRAC_1_PI * wi.z), wi.z * FRAC_1_PI);
    // Lanes that are all Lambertian compute that model alone.
    let value = if ALL_DIFFUSE || x.diffuse {
        lambert
    } else {
        let mr = MetallicRoughness { base_color: x.rho, metallic: x.metallic, alpha: x.alpha, fresnel: DielectricFresnel { f0: x.f0, f90: x.f90 } };
        let (f_mr, d) = mr.f_cos_and_d(wo, wi, x.sd_wo);
        let ps = x.ps;
        (f_mr, ps * (d / (2.0 * x.sd_wo)) + (1.0 - ps) * wi.z * FRAC_1_PI)
    };
    if below { (Vec3::ZERO, 0.0) } else { value }
}

/// [`SAMPLE_LANES`] BSDFs as one array per number ([`SampleLane`] without its `u`): what
/// [`sample_many`] and [`evaluate_many`] move their BSDFs into before the loop over the lanes
/// (and what the path loop in lanes keeps its vertices' BSDFs in).
#[derive(Default)]
pub(crate) struct BsdfLanes {
    pub(crate) diffuse: [bool; SAMPLE_LANES],
    rho: [[f32; SAMPLE_LANES]; 3],
    metallic: [f32; SAMPLE_LANES],
    alpha: [f32; SAMPLE_LANES],
    f0: [[f32; SAMPLE_LANES]; 3],
    f90: [f32; SAMPLE_LANES],
    wo: [[f32; SAMPLE_LANES]; 3],
    pub(crate) ps: [f32; SAMPLE_LANES],
    pub(crate) sd_wo: [f32; SAMPLE_LANES],
}

impl BsdfLanes {
    /// Lane `k` := `l`.
    #[inline(always)]
    pub(crate) fn set(&mut self, k: usize, l: &SampleLane) {
        self.diffuse[k] = l.diffuse;
        for c in 0..3 {
            self.rho[c][k] = l.rho[c];
            self.f0[c][k] = l.f0[c];
            self.wo[c][k] = l.wo[c];
        }
        (self.metallic[k], self.alpha[k], self.f90[k], self.ps[k], self.sd_wo[k]) = (l.metallic, l.alpha, l.f90, l.ps, l.sd_wo);
    }

    /// Lane `k`, with the numbers `u`.
    #[inline(always)]
    pub(crate) fn get(&self, k: usize, u: Vec2) -> SampleLane {
        let v3 = |a: &[[f32; SAMPLE_LANES]; 3]| Vec3::new(a[0][k], a[1][k], a[2][k]);
        SampleLane {
            diffuse: self.diffuse[k],
            rho: v3(&self.rho),
            metallic: self.metallic[k],
            alpha: self.alpha[k],
            f0: v3(&self.f0),
            f90: self.f90[k],
            wo: v3(&self.wo),
            ps: self.ps[k],
            sd_wo: self.sd_wo[k],
            u,
        }
    }
}

/// `values[k] = bsdfs(k).evaluate_pdf(wi[k])` for every `k` (the same bits), eight
/// (`SAMPLE_LANES`) at a time: the inputs transposed into one array per number, one vectorised
/// loop over the lanes (`evaluate_pdf_lane`), the results transposed back.
///
/// # Panics
/// If `values` and `wi` differ in length.
#[inline(always)]
pub fn evaluate_many<'a>(bsdfs: impl Fn(usize) -> &'a BsdfAt, wi: &[Vec3], values: &mut [(Vec3, f32)]) {
    const L: usize = SAMPLE_LANES;
    let n = wi.len();
    assert!(values.len() == n, "evaluate_many: slices of different lengths");
    for start in (0..n).step_by(L) {
        let m = (n - start).min(L);
        // Unused lanes hold zeros; their results are dropped.
        let mut x = BsdfLanes::default();
        let mut x_wi = [[0.0f32; L]; 3];
        for (k, w) in wi[start..start + m].iter().enumerate() {
            x.set(k, &bsdfs(start + k).lane(Vec2::ZERO));
            (x_wi[0][k], x_wi[1][k], x_wi[2][k]) = (w.x, w.y, w.z);
        }
        let (mut f, mut pdf) = ([[0.0f32; L]; 3], [0.0f32; L]);
        evaluate_lanes(&x, x.diffuse[..m].iter().all(|&d| d), &x_wi, &mut f, &mut pdf);
        for k in 0..m {
            values[start + k] = (Vec3::new(f[0][k], f[1][k], f[2][k]), pdf[k]);
        }
    }
}

/// `(f[k], pdf[k]) = x.get(k).evaluate_pdf(wi[k])` for the eight lanes ([`evaluate_pdf_lane`]):
/// one loop over the lanes, computing only the Lambertian model where `all_diffuse` (every lane
/// that matters is Lambertian).
#[inline(always)]
pub(crate) fn evaluate_lanes(x: &BsdfLanes, all_diffuse: bool, wi: &[[f32; SAMPLE_LANES]; 3], f: &mut [[f32; SAMPLE_LANES]; 3], pdf: &mut [f32; SAMPLE_LANES]) {
    // `k` indexes the lanes, the inner dimension of every array: the loop over it is what
    // vectorises.
    #[allow(clippy::needless_range_loop)]
    #[inline(always)]
    fn lanes<const ALL_DIFFUSE: bool>(x: &BsdfLanes, wi: &[[f32; SAMPLE_LANES]; 3], f: &mut [[f32; SAMPLE_LANES]; 3], pdf: &mut [f32; SAMPLE_LANES]) {
        for k in 0..SAMPLE_LANES {
            let (v, p) = evaluate_pdf_lane::<ALL_DIFFUSE>(&x.get(k, Vec2::ZERO), Vec3::new(wi[0][k], wi[1][k], wi[2][k]));
            for c in 0..3 {
                f[c][k] = v[c];
            }
            pdf[k] = p;
        }
    }
    if all_diffuse {
        lanes::<true>(x, wi, f, pdf);
    } else {
        lanes::<false>(x, wi, f, pdf);
    }
}

/// The BSDF sample of one lane: `(wi, weight, pdf, valid)`. Both models and both lobes of the
/// metallic-roughness BRDF are computed and the lane's own selected, with no branch on the
/// data, so that a loop over lanes vectorises ([`sample_many`]); the selected values are the
/// operations the model's sampling describes (see [`MetallicRoughness`]).
#[inline(always)]
fn sample_lane<const ALL_DIFFUSE: bool>(x: SampleLane) -> (Vec3, Vec3, f32, bool) {
    let SampleLane { diffuse, rho, metallic, alpha, f0, f90, wo, ps, sd_wo, u } = x;
    if ALL_DIFFUSE {
        // The Lambertian model's values below, alone (for lanes that are all Lambertian).
        let wi_d = sample_cosine_hemisphere(u);
        let pdf_d = wi_d.z * FRAC_1_PI;
        return (wi_d, rho, pdf_d, !(wo.z <= 0.0) & !(pdf_d <= 0.0));
    }
    // Specular lobe: a visible normal, `wi` its reflection.
    let specular = !diffuse & (u.x < ps);
    let (h, h_ok) = visible_normal(alpha, wo, Vec2::new(u.x / ps, u.y));
    let wi_s = (2.0 * wo.dot(h) * h - wo).normalize();
    // Diffuse lobe (or the Lambertian model): cosine-weighted, `u.x` re-scaled for the lobe.
    let u_d = if diffuse { u } else { Vec2::new(((u.x - ps) / (1.0 - ps)).min(1.0 - f32::EPSILON), u.y) };
    let wi_d = sample_cosine_hemisphere(u_d);
    let wi = if specular { wi_s } else { wi_d };
    let mr = MetallicRoughness { base_color: rho, metallic, alpha, fresnel: DielectricFresnel { f0, f90 } };
    let (f, d) = mr.f_cos_and_d(wo, wi, sd_wo);
    let pdf_mr = ps * (d / (2.0 * sd_wo)) + (1.0 - ps) * wi.z * FRAC_1_PI;
    let ok_mr = (!specular | h_ok) & (wi.z > 0.0) & (pdf_mr > 0.0) & pdf_mr.is_finite() & f.is_finite();
    let pdf_d = wi_d.z * FRAC_1_PI;
    let ok = !(wo.z <= 0.0) & if diffuse { !(pdf_d <= 0.0) } else { ok_mr };
    if diffuse { (wi_d, rho, pdf_d, ok) } else { (wi, f / pdf_mr, pdf_mr, ok) }
}

/// Lanes of [`sample_many`]: eight, the `f32` lanes of an AVX2 register.
const SAMPLE_LANES: usize = 8;

/// `out[k] = bsdfs(k).sample(u[k])` for every `k < u.len()` (the same bits), the samples
/// drawn eight (`SAMPLE_LANES`) at a time: the inputs transposed into one array per number,
/// one vectorised loop over the lanes (`sample_lane`), the results transposed back. The
/// BSDFs are read where they lie (as in [`evaluate_many`]), not gathered into a slice first.
///
/// # Panics
/// If the slices differ in length.
#[inline(always)]
pub fn sample_many<'a>(bsdfs: impl Fn(usize) -> &'a BsdfAt, u: &[Vec2], out: &mut [Option<BsdfSample>]) {
    const L: usize = SAMPLE_LANES;
    let n = u.len();
    assert!(out.len() == n, "sample_many: slices of different lengths");
    for start in (0..n).step_by(L) {
        let m = (n - start).min(L);
        // Unused lanes hold zeros; their results are dropped.
        let mut x = BsdfLanes::default();
        let mut x_u = [[0.0f32; L]; 2];
        for (k, &uk) in u[start..start + m].iter().enumerate() {
            x.set(k, &bsdfs(start + k).lane(uk));
            (x_u[0][k], x_u[1][k]) = (uk.x, uk.y);
        }
        let mut y = SampledLanes::default();
        sample_lanes(&x, x.diffuse[..m].iter().all(|&d| d), &x_u, &mut y);
        for k in 0..m {
            out[start + k] = y.ok[k].then(|| BsdfSample {
                wi: Vec3::new(y.wi[0][k], y.wi[1][k], y.wi[2][k]),
                weight: Vec3::new(y.weight[0][k], y.weight[1][k], y.weight[2][k]),
                pdf: y.pdf[k],
            });
        }
    }
}

/// Eight BSDF samples as one array per number ([`sample_lanes`]): the direction (local frame),
/// the weight, the density and whether the sample is valid.
#[derive(Default)]
pub(crate) struct SampledLanes {
    pub(crate) wi: [[f32; SAMPLE_LANES]; 3],
    pub(crate) weight: [[f32; SAMPLE_LANES]; 3],
    pub(crate) pdf: [f32; SAMPLE_LANES],
    pub(crate) ok: [bool; SAMPLE_LANES],
}

/// The eight lanes' BSDF samples with the numbers `u` ([`sample_lane`]): one loop over the
/// lanes, computing only the Lambertian model where `all_diffuse` (every lane that matters is
/// Lambertian).
#[inline(always)]
pub(crate) fn sample_lanes(x: &BsdfLanes, all_diffuse: bool, u: &[[f32; SAMPLE_LANES]; 2], y: &mut SampledLanes) {
    // `k` indexes the lanes, the inner dimension of every array: the loop over it is what
    // vectorises.
    #[allow(clippy::needless_range_loop)]
    #[inline(always)]
    fn lanes<const ALL_DIFFUSE: bool>(x: &BsdfLanes, u: &[[f32; SAMPLE_LANES]; 2], y: &mut SampledLanes) {
        for k in 0..SAMPLE_LANES {
            let (wi, weight, pdf, ok) = sample_lane::<ALL_DIFFUSE>(x.get(k, Vec2::new(u[0][k], u[1][k])));
            for c in 0..3 {
                y.wi[c][k] = wi[c];
                y.weight[c][k] = weight[c];
            }
            y.pdf[k] = pdf;
            y.ok[k] = ok;
        }
    }
    if all_diffuse {
        lanes::<true>(x, u, y);
    } else {
        lanes::<false>(x, u, y);
    }
}

impl Bsdf {
    /// `f(wo, wi) · |cos θᵢ|` in the local frame (see the variant docs for `f`).
    #[inline]
    pub fn evaluate(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return Vec3::ZERO;
        }
        match self {
            Bsdf::Diffuse { albedo } => *albedo * (FRAC_1_PI * wi.z),
            Bsdf::MetallicRoughness(mr) => mr.f(wo, wi) * wi.z,
        }
    }

    /// Draws `wi` given `wo` and two uniform numbers. `None` when no direction can be
    /// produced (e.g. `wo` below the surface, or a microfacet reflection below the horizon).
    #[inline]
    pub fn sample(&self, wo: Vec3, u: Vec2) -> Option<BsdfSample> {
        self.at(wo).sample(u)
    }

    /// `(self.evaluate(wo, wi), self.pdf(wo, wi))`, computed together (bit-identical).
    #[inline]
    pub fn evaluate_pdf(&self, wo: Vec3, wi: Vec3) -> (Vec3, f32) {
        self.at(wo).evaluate_pdf(wi)
    }

    /// The BSDF seen from `wo`, with what depends only on `wo` computed once (for the
    /// several evaluations and the sample of one path vertex).
    #[inline(always)]
    pub fn at(&self, wo: Vec3) -> BsdfAt {
        let (ps, sd_wo) = match self {
            Bsdf::MetallicRoughness(mr) if wo.z > 0.0 => (mr.specular_probability(wo), mr.smith_den(wo.z)),
            _ => (0.0, 0.0),
        };
        BsdfAt { bsdf: *self, wo, ps, sd_wo }
    }

    /// Solid-angle density with which [`Bsdf::sample`] draws `wi`.
    #[inline]
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return 0.0;
        }
        match self {
            Bsdf::Diffuse { .. } => wi.z * FRAC_1_PI,
            Bsdf::MetallicRoughness(mr) => {
                let ps = mr.specular_probability(wo);
                ps * mr.pdf_specular(wo, wi) + (1.0 - ps) * wi.z * FRAC_1_PI
            }
        }
    }

    /// Whether outgoing radiance depends on the viewing direction (false for Lambertian,
    /// true whenever a specular lobe exists; the scene-level rule with its threshold is
    /// [`is_view_dependent`]).
    pub fn is_view_dependent(&self) -> bool {
        match self {
            Bsdf::Diffuse { .. } => false,
            Bsdf::MetallicRoughness(_) => true,
        }
    }
}

/// The material resolved at one surface point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceMaterial {
    /// The BSDF.
    pub bsdf: Bsdf,
    /// Emitted radiance `emissive × emissive texture` (linear RGB, W·m⁻²·sr⁻¹ units).
    pub emission: Vec3,
}

/// Attributes interpolated at a hit that materials read.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceAttributes {
    /// `[TEXCOORD_0, TEXCOORD_1]`.
    pub uv: [Vec2; 2],
    /// COLOR_0 (linear RGBA).
    pub color: Vec4,
}

/// Base colour with alpha: `baseColorFactor × baseColorTexture × COLOR_0` (glTF 2.0 §3.9.2).
#[inline]
pub fn base_color(material: &Material, textures: &[Texture], attr: &SurfaceAttributes) -> Vec4 {
    let mut c = material.base_color_factor * attr.color;
    if let Some(r) = &material.base_color_texture {
        c *= sample_ref(textures, r, attr.uv);
    }
    c
}

/// Emitted radiance: `emissive (× strength) × emissiveTexture`.
#[inline]
pub fn emission(material: &Material, textures: &[Texture], attr: &SurfaceAttributes) -> Vec3 {
    if !material.is_emissive() {
        return Vec3::ZERO;
    }
    let mut e = material.emissive;
    if let Some(r) = &material.emissive_texture {
        e *= sample_ref(textures, r, attr.uv).truncate();
    }
    e
}

/// Metallic and perceptual roughness at a point: `metallicFactor × texture.B`,
/// `roughnessFactor × texture.G` (glTF 2.0 §3.9.2), clamped to [0, 1].
#[inline]
pub fn metallic_roughness(material: &Material, textures: &[Texture], attr: &SurfaceAttributes) -> (f32, f32) {
    let (mut m, mut r) = (material.metallic_factor, material.roughness_factor);
    if let Some(t) = &material.metallic_roughness_texture {
        let s = sample_ref(textures, t, attr.uv);
        m *= s.z;
        r *= s.y;
    }
    let unit = |x: f32| if x.is_finite() { x.clamp(0.0, 1.0) } else { 1.0 };
    (unit(m), unit(r))
}

/// The dielectric's Fresnel endpoints at a point ([`DielectricFresnel::new`]): specular
/// weight = `specular_factor × specularTexture.A`, specular colour =
/// `specular_color_factor × specularColorTexture.RGB`, and `ior`.
#[inline(always)]
pub fn dielectric_fresnel(material: &Material, textures: &[Texture], attr: &SurfaceAttributes) -> DielectricFresnel {
    let mut weight = material.specular_factor;
    if let Some(t) = &material.specular_texture {
        weight *= sample_ref(textures, t, attr.uv).w;
    }
    let mut color = material.specular_color_factor;
    if let Some(t) = &material.specular_color_texture {
        color *= sample_ref(textures, t, attr.uv).truncate();
    }
    DielectricFresnel::new(material.ior, color, weight)
}

/// Resolves a glTF material at a surface point into its BSDF and emission:
/// [`Bsdf::MetallicRoughness`] with base colour, metallic, roughness (factors × textures) and
/// the dielectric's Fresnel endpoints ([`dielectric_fresnel`]), or [`Bsdf::Diffuse`] with the
/// base colour when metallic and the specular weight (`F90`) are both 0 (where the two are
/// identical).
#[inline(always)]
pub fn resolve(material: &Material, textures: &[Texture], attr: &SurfaceAttributes) -> SurfaceMaterial {
    let albedo = base_color(material, textures, attr).truncate().clamp(Vec3::ZERO, Vec3::ONE);
    let albedo = if albedo.is_finite() { albedo } else { Vec3::ZERO };
    let (metallic, roughness) = metallic_roughness(material, textures, attr);
    let fresnel = dielectric_fresnel(material, textures, attr);
    let bsdf = if metallic <= 0.0 && fresnel.f90 <= 0.0 {
        Bsdf::Diffuse { albedo }
    } else {
        Bsdf::MetallicRoughness(MetallicRoughness::with_fresnel(albedo, metallic, roughness, fresnel))
    };
    SurfaceMaterial { bsdf, emission: emission(material, textures, attr) }
}

/// The material resolved once for every point of every triangle that uses it, when nothing
/// [`resolve`] reads varies over the surface: no base-colour, metallic-roughness, specular,
/// specular-colour or emissive texture, and (`vertex_colors` false) no COLOR_0, whose
/// absence [`crate::integrator::surface_attributes`] reports as exactly white. `None` when
/// something varies. Equal, bit for bit, to `resolve` at any point of such a material.
pub fn uniform_surface(material: &Material, vertex_colors: bool) -> Option<SurfaceMaterial> {
    let varies = vertex_colors
        || material.base_color_texture.is_some()
        || material.metallic_roughness_texture.is_some()
        || material.specular_texture.is_some()
        || material.specular_color_texture.is_some()
        || material.emissive_texture.is_some();
    (!varies).then(|| resolve(material, &[], &SurfaceAttributes { uv: [Vec2::ZERO; 2], color: Vec4::ONE }))
}

/// Perceptual roughness below which a dielectric's 4 % specular layer counts as
/// view-dependent (see [`is_view_dependent`]).
pub const VIEW_DEPENDENT_ROUGHNESS: f32 = 0.6;

/// Whether a glTF material's outgoing radiance depends noticeably on the viewing direction:
/// true when it can be metallic (metallic factor > 0: the whole reflection is a GGX lobe),
/// or when it has a dielectric specular layer (`specular_factor > 0`) with a roughness that
/// can fall below [`VIEW_DEPENDENT_ROUGHNESS`] (roughness factor × the smallest G of its
/// metallic-roughness texture).
///
/// Why 0.6: the dielectric's highlight peak at normal incidence is
/// `0.04 · D(0) · Vis = 0.04 / (4 π α²)`: for roughness 1 (α = 1) that is 0.0032 sr⁻¹, about
/// 2 % of the diffuse term of a mid-grey (ρ = 0.5, ρ/π = 0.16) surface, below the noise of a
/// dataset render; at roughness 0.6 (α = 0.36) it is 0.025 sr⁻¹, about 15 %, and it grows as
/// `1/α²` below. A rougher dielectric is treated as Lambertian for the scene facts (the
/// renderer still shades it with the full BRDF). A dielectric whose largest possible F0
/// (`((ior − 1)/(ior + 1))² × max(specular_color_factor)`, capped at 1) exceeds 0.04 has a
/// brighter highlight, `F0 / (4 π α²)`, so the threshold rises to keep the same peak:
/// `0.6 · (F0 / 0.04)^¼` (never below 0.6).
///
/// Without the textures ([`is_view_dependent`]) the rule reads the factors only (metallic
/// factor > 0, or specular > 0 and roughness factor < 0.6); with them
/// ([`is_view_dependent_textured`]) an all-zero metallic channel or a rougher-than-factor
/// texture refines it.
pub fn is_view_dependent(material: &Material) -> bool {
    is_view_dependent_textured(material, &[])
}

/// [`is_view_dependent`] refined by the material's metallic-roughness texture (texture
/// references that `textures` lacks are ignored).
pub fn is_view_dependent_textured(material: &Material, textures: &[Texture]) -> bool {
    if material.metallic_factor > 0.0 {
        let metal_texture_zero = material
            .metallic_roughness_texture
            .and_then(|t| textures.get(t.texture as usize))
            .is_some_and(|t| !t.texels.is_empty() && t.texels.iter().all(|x| x.z <= 0.0));
        if !metal_texture_zero {
            return true;
        }
    }
    if !(material.specular_factor > 0.0) {
        return false;
    }
    let min_g = min_roughness_texel(material, textures);
    let f0_max = max_dielectric_f0(material);
    let threshold = if f0_max > DIELECTRIC_F0 {
        VIEW_DEPENDENT_ROUGHNESS * (f0_max / DIELECTRIC_F0).powf(0.25)
    } else {
        VIEW_DEPENDENT_ROUGHNESS
    };
    material.roughness_factor * min_g.clamp(0.0, 1.0) < threshold
}

/// The smallest G (roughness) channel of a material's metallic-roughness texture, or 1 without
/// one (texture references that `textures` lacks are ignored): the roughness factor times it
/// is the smallest roughness the material can have.
pub fn min_roughness_texel(material: &Material, textures: &[Texture]) -> f32 {
    material
        .metallic_roughness_texture
        .and_then(|t| textures.get(t.texture as usize))
        .map(|t| t.texels.iter().map(|x| x.y).fold(f32::INFINITY, f32::min))
        .filter(|g| g.is_finite())
        .unwrap_or(1.0)
}

/// The largest normal-incidence reflectance of a material's dielectric layer before its
/// specular weight: `((ior − 1)/(ior + 1))² × max(specular colour factor)`, capped at 1.
pub fn max_dielectric_f0(material: &Material) -> f32 {
    (f0_from_ior(material.ior) * material.specular_color_factor.max_element()).min(1.0)
}

/// Whether any material used by some triangle of `scene` is view-dependent
/// ([`is_view_dependent`]); materials no triangle references do not count.
pub fn scene_is_view_dependent(scene: &Scene) -> bool {
    let mut used = vec![false; scene.materials.len()];
    for &m in &scene.mesh.material {
        if let Some(u) = used.get_mut(m as usize) {
            *u = true;
        }
    }
    scene.materials.iter().zip(used).any(|(m, u)| u && is_view_dependent_textured(m, &scene.textures))
}

/// The normals of a hit seen from direction `-ray_dir`: the geometric normal `ng` and the
/// shading normal `ns` (returned unit length), both flipped to face the incoming ray (the
/// shading normal is also made to agree in side with the geometric one).
#[inline]
pub fn facing_normals(ng: Vec3, ns: Vec3, ray_dir: Vec3) -> (Vec3, Vec3) {
    let ng = if ng.dot(ray_dir) > 0.0 { -ng } else { ng };
    let mut ns = if ns.is_finite() && ns.length_squared() > 0.0 { ns.normalize() } else { ng };
    if ns.dot(ng) < 0.0 {
        ns = -ns;
    }
    (ng, ns)
}

/// A per-triangle tangent from positions and UVs (the `uv` set the normal texture reads),
/// for meshes without a TANGENT attribute: `T = ∂p/∂u`, `B = ∂p/∂v'` with `v' = −v` (glTF's
/// UV origin is the image's top-left, a normal map's +Y is the image's up), made orthogonal
/// to the unit normal `n`; `w = sign((n × T)·B)` is the handedness, so that the glTF rule
/// `B = (n × T) w` reproduces the UV bitangent's side. This is MikkTSpace per triangle
/// without the per-vertex averaging. `None` for degenerate UVs.
pub fn triangle_tangent(p: [Vec3; 3], uv: [Vec2; 3], n: Vec3) -> Option<Vec4> {
    let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
    let (d1, d2) = (uv[1] - uv[0], uv[2] - uv[0]);
    let (du1, dv1, du2, dv2) = (d1.x, -d1.y, d2.x, -d2.y);
    let det = du1 * dv2 - du2 * dv1;
    if !(det.abs() > 0.0) || !det.is_finite() {
        return None;
    }
    let t = (e1 * dv2 - e2 * dv1) / det;
    let b = (e2 * du1 - e1 * du2) / det;
    let t = (t - n * n.dot(t)).normalize_or_zero();
    if t == Vec3::ZERO || !t.is_finite() {
        return None;
    }
    let w = if n.cross(t).dot(b) < 0.0 { -1.0 } else { 1.0 };
    Some(t.extend(w))
}

/// The normal-mapped shading normal (glTF 2.0 §3.9.3): the texel `c` (linear, [0, 1]) gives
/// the tangent-space normal `normalize((2c − 1) · (scale, scale, 1))`, mapped to world by
/// `T`, `B = (n × T) · w`, `n`, where `n` is the unit interpolated normal (front side) and
/// `tangent = (T, w)` (the asset's TANGENT or [`triangle_tangent`], orthogonalised to `n`
/// here). Returns `n` unchanged when the material has no normal texture or the tangent is
/// degenerate.
pub fn normal_mapped(material: &Material, textures: &[Texture], attr: &SurfaceAttributes, n: Vec3, tangent: Vec4) -> Vec3 {
    let Some((r, scale)) = &material.normal_texture else { return n };
    let t = tangent.truncate();
    let t = (t - n * n.dot(t)).normalize_or_zero();
    if t == Vec3::ZERO || !t.is_finite() {
        return n;
    }
    let w = if tangent.w < 0.0 { -1.0 } else { 1.0 };
    let b = n.cross(t) * w;
    let c = sample_ref(textures, r, attr.uv).truncate() * 2.0 - Vec3::ONE;
    let c = (c * Vec3::new(*scale, *scale, 1.0)).normalize_or_zero();
    let m = (t * c.x + b * c.y + n * c.z).normalize_or_zero();
    if m == Vec3::ZERO || !m.is_finite() { n } else { m }
}

/// The frame BSDFs are evaluated in at a hit: `ns` (a shading normal on the front side, e.g.
/// [`normal_mapped`]) is flipped with the surface when the ray hits its back
/// (`flipped`), then, if it still faces away from the viewer (`wo·n < MIN_SHADING_COS`, which
/// normal maps and interpolated normals at silhouettes produce), bent towards `wo` to
/// `n' = normalize(n + (MIN_SHADING_COS − wo·n) wo)`, so that `wo` is always in the upper
/// hemisphere and every value stays finite.
#[inline]
pub fn shading_frame(ns: Vec3, flipped: bool, wo: Vec3) -> Frame {
    let mut n = if flipped { -ns } else { ns };
    let c = n.dot(wo);
    if !(c >= MIN_SHADING_COS) {
        n = (n + (MIN_SHADING_COS - c) * wo).normalize_or_zero();
        if n == Vec3::ZERO || !n.is_finite() {
            n = wo;
        }
    }
    Frame::from_normal(n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampler::Sampler;
    use crate::scene::{Filter, TextureRef, Wrap};

    fn dir(theta_deg: f32, phi: f32) -> Vec3 {
        let t = theta_deg.to_radians();
        Vec3::new(t.sin() * phi.cos(), t.sin() * phi.sin(), t.cos())
    }

    fn mr(rho: f32, metallic: f32, roughness: f32) -> Bsdf {
        Bsdf::MetallicRoughness(MetallicRoughness::new(Vec3::splat(rho), metallic, roughness, 1.0))
    }

    #[test]
    fn diffuse_eval_is_albedo_cos_over_pi_and_consistent_with_sample_and_pdf() {
        let albedo = Vec3::new(0.2, 0.5, 0.8);
        let b = Bsdf::Diffuse { albedo };
        let wo = Vec3::new(0.3, 0.1, 0.9).normalize();
        for p in 0..1000 {
            let mut s = Sampler::new(5, 0, p, 0);
            let smp = b.sample(wo, s.next_2d()).unwrap();
            let cos = smp.wi.z;
            assert!((b.evaluate(wo, smp.wi) - albedo * cos / std::f32::consts::PI).abs().max_element() < 1e-6);
            assert!((b.pdf(wo, smp.wi) - smp.pdf).abs() < 1e-6);
            assert!((smp.weight * smp.pdf - b.evaluate(wo, smp.wi)).abs().max_element() < 1e-6);
        }
        // Below the surface: zero.
        assert_eq!(b.evaluate(wo, Vec3::new(0.0, 0.0, -1.0)), Vec3::ZERO);
        assert_eq!(b.pdf(wo, Vec3::new(0.0, 0.0, -1.0)), 0.0);
        assert!(b.sample(-wo, Vec2::splat(0.5)).is_none());
        assert!(!b.is_view_dependent());
    }

    #[test]
    fn diffuse_albedo_integrates_to_rho() {
        // ∫ f cos dω over the hemisphere = ρ, estimated with uniform-sphere samples.
        let b = Bsdf::Diffuse { albedo: Vec3::splat(0.7) };
        let wo = Vec3::Z;
        let n = 200_000;
        let mut sum = 0.0f64;
        let mut sum2 = 0.0f64;
        for p in 0..n {
            let mut s = Sampler::new(6, 0, p, 0);
            let wi = crate::sampler::sample_uniform_sphere(s.next_2d());
            let v = (b.evaluate(wo, wi).x * 4.0 * std::f32::consts::PI) as f64;
            sum += v;
            sum2 += v * v;
        }
        let nf = n as f64;
        let mean = sum / nf;
        let sigma = ((sum2 / nf - mean * mean) / nf).sqrt();
        assert!((mean - 0.7).abs() < 4.0 * sigma, "{mean} ± {sigma}");
    }

    #[test]
    fn gltf_brdf_matches_the_spec_formula_at_hand_computed_points() {
        // Normal incidence, mirror configuration (H = N): D = 1/(π α²), Vis = 1/(2·2)·… with
        // N·L = N·V = 1: Vis = 1 / (1 + 1)² = 1/4, w5 = 0.
        let (rho, rough) = (0.5f32, 0.5f32);
        let a = rough * rough;
        let d0 = 1.0 / (PI * a * a);
        let spec = d0 * 0.25;
        let b = MetallicRoughness::new(Vec3::splat(rho), 0.0, rough, 1.0);
        let f = b.f(Vec3::Z, Vec3::Z).x;
        let expect = (1.0 - 0.04) * rho / PI + 0.04 * spec;
        assert!((f - expect).abs() < 1e-6 * expect, "{f} vs {expect}");
        let metal = MetallicRoughness::new(Vec3::splat(rho), 1.0, rough, 1.0).f(Vec3::Z, Vec3::Z).x;
        assert!((metal - rho * spec).abs() < 1e-6 * spec);
        // An off-specular pair, term by term in f64.
        let (wo, wi) = (dir(30.0, 0.0), dir(50.0, 2.0));
        let h = (wo + wi).normalize();
        let (nl, nv, nh, vh) = (wi.z as f64, wo.z as f64, h.z as f64, wo.dot(h) as f64);
        let a = 0.3f64 * 0.3;
        let a2 = a * a;
        let d = a2 / (std::f64::consts::PI * (nh * nh * (a2 - 1.0) + 1.0).powi(2));
        let vis = 1.0 / ((nl + (a2 + (1.0 - a2) * nl * nl).sqrt()) * (nv + (a2 + (1.0 - a2) * nv * nv).sqrt()));
        let w5 = (1.0 - vh).powi(5);
        let (rho, m) = (0.8f64, 0.3f64);
        let fd = 0.04 + 0.96 * w5;
        let diel = (1.0 - fd) * rho / std::f64::consts::PI + fd * d * vis;
        let met = (rho + (1.0 - rho) * w5) * d * vis;
        let expect = (1.0 - m) * diel + m * met;
        let got = MetallicRoughness::new(Vec3::splat(0.8), 0.3, 0.3, 1.0).f(wo, wi).x as f64;
        assert!((got - expect).abs() < 1e-5 * expect, "{got} vs {expect}");
        // Metallic 0 and specular 0 is exactly Lambertian.
        let lam = MetallicRoughness::new(Vec3::splat(0.8), 0.0, 0.3, 0.0).f(wo, wi).x;
        assert!((lam - 0.8 / PI).abs() < 1e-7);
    }

    /// Directional albedo `∫ f cos dω` at `wo`, estimated with the BSDF's own sampling
    /// (mean of the sample weights, `None` counted as 0): mean and standard error.
    fn albedo(b: &Bsdf, wo: Vec3, n: u64, seed: u64) -> (f64, f64) {
        let (mut s1, mut s2) = (0.0f64, 0.0f64);
        for k in 0..n {
            let mut s = Sampler::new(seed, 0, k, 0);
            let v = b.sample(wo, s.next_2d()).map_or(0.0, |x| x.weight.x as f64);
            s1 += v;
            s2 += v * v;
        }
        let mean = s1 / n as f64;
        (mean, ((s2 / n as f64 - mean * mean).max(0.0) / n as f64).sqrt())
    }

    #[test]
    fn white_furnace_albedo_is_at_most_one_and_metal_loses_energy_with_roughness() {
        // 40k importance-sampled directions per (material, roughness, angle); tolerance 4σ
        // (σ ≤ 2.6e-3 here, ≤ 1e-3 for most cells) plus 1e-4.
        let roughs = [0.05f32, 0.2, 0.4, 0.6, 0.8, 1.0];
        for &theta in &[0.0f32, 30.0, 60.0, 80.0, 89.9] {
            let wo = dir(theta, 0.7);
            let mut prev = f64::INFINITY;
            for &r in &roughs {
                // Metal with ρ = 1 (F = 1): ∫ f cos = single-scattering GGX albedo ≤ 1.
                let (a, se) = albedo(&mr(1.0, 1.0, r), wo, 40_000, 11);
                assert!(a.is_finite() && a <= 1.0 + 4.0 * se + 1e-4, "metal r {r} θ {theta}: albedo {a} ± {se}");
                if theta <= 80.0 {
                    // Energy loss grows with roughness (at 89.9° a very smooth lobe is more
                    // masked than a rougher one, so the trend is checked up to 80°), and the
                    // nearly smooth metal keeps all its energy.
                    assert!(a <= prev + 4.0 * se + 1e-4, "metal θ {theta}: albedo rises at r {r}: {a} > {prev}");
                    prev = a;
                    if r == 0.05 {
                        assert!((a - 1.0).abs() < 0.005, "θ {theta}: smooth metal albedo {a}");
                    }
                }
                // The dielectric with ρ = 1 away from grazing. (Towards grazing the spec's
                // fresnel_mix is not energy conserving: it weights the diffuse by 1 − F(V·H)
                // at the diffuse direction's half vector, not by the specular lobe's actual
                // albedo; with ρ = 1, ∫ f cos reaches ≈ 1.03 at 60°, ≈ 1.36 at 80° and ≈ 1.8 at
                // 89.9° for roughness 0.05. That is the glTF model, kept as specified.)
                if theta <= 30.0 {
                    let (a, se) = albedo(&mr(1.0, 0.0, r), wo, 40_000, 13);
                    assert!(a.is_finite() && a <= 1.0 + 4.0 * se + 1e-4, "dielectric r {r} θ {theta}: albedo {a} ± {se}");
                }
            }
        }
        // Closed form: metal, α = 1, normal incidence: D = 1/π, Vis = 1 / (2 (N·L + 1)), so
        // ∫ f cos dω = ∫₀¹ μ / (μ + 1) dμ = 1 − ln 2.
        let (a, se) = albedo(&mr(1.0, 1.0, 1.0), Vec3::Z, 200_000, 12);
        let expect = 1.0 - std::f64::consts::LN_2;
        assert!((a - expect).abs() < 4.0 * se, "{a} ± {se} vs {expect}");
    }

    /// Configurations for the sampling tests: (ρ, metallic, roughness, θ_o).
    const CONFIGS: [(f32, f32, f32, f32); 6] =
        [(0.8, 0.0, 0.5, 30.0), (0.5, 0.0, 0.3, 70.0), (0.9, 1.0, 0.4, 45.0), (0.3, 0.5, 0.7, 10.0), (1.0, 1.0, 1.0, 60.0), (0.6, 0.2, 0.9, 85.0)];

    /// ∫ pdf over a (cos θ, φ) cell by the midpoint rule on `sub × sub` points.
    fn cell_integral(b: &Bsdf, wo: Vec3, z0: f32, z1: f32, p0: f32, p1: f32, sub: u32) -> f64 {
        let mut s = 0.0f64;
        for i in 0..sub {
            for j in 0..sub {
                let z = z0 + (z1 - z0) * (i as f32 + 0.5) / sub as f32;
                let phi = p0 + (p1 - p0) * (j as f32 + 0.5) / sub as f32;
                let r = (1.0 - z * z).max(0.0).sqrt();
                s += b.pdf(wo, Vec3::new(r * phi.cos(), r * phi.sin(), z)) as f64;
            }
        }
        s * ((z1 - z0) * (p1 - p0)) as f64 / (sub * sub) as f64
    }

    #[test]
    fn pdf_integrates_to_the_probability_that_sample_succeeds() {
        for (k, &(rho, m, r, theta)) in CONFIGS.iter().enumerate() {
            let b = mr(rho, m, r);
            let wo = dir(theta, 0.3);
            // Numerical integral over the hemisphere on a 64 × 128 grid, 8 × 8 points per cell.
            let (nz, np) = (64, 128);
            let mut total = 0.0;
            for i in 0..nz {
                for j in 0..np {
                    let (z0, z1) = (i as f32 / nz as f32, (i + 1) as f32 / nz as f32);
                    let (p0, p1) = (2.0 * PI * j as f32 / np as f32, 2.0 * PI * (j + 1) as f32 / np as f32);
                    total += cell_integral(&b, wo, z0, z1, p0, p1, 8);
                }
            }
            let n = 100_000u64;
            let ok = (0..n).filter(|&p| b.sample(wo, Sampler::new(20 + k as u64, 0, p, 0).next_2d()).is_some()).count() as f64 / n as f64;
            let se = (ok * (1.0 - ok) / n as f64).sqrt().max(1e-4);
            assert!(total <= 1.0 + 1e-3, "config {k}: ∫pdf = {total}");
            assert!((total - ok).abs() < 4.0 * se + 2e-3, "config {k}: ∫pdf = {total}, P(Some) = {ok} ± {se}");
        }
        // Normal incidence on a smooth-ish surface: essentially nothing is lost.
        let b = mr(0.5, 0.0, 0.3);
        let n = 20_000u64;
        let ok = (0..n).filter(|&p| b.sample(Vec3::Z, Sampler::new(3, 0, p, 0).next_2d()).is_some()).count();
        assert!(ok as f64 > 0.999 * n as f64);
    }

    /// The regularised upper tail of χ² with `k` degrees of freedom, via the Wilson–Hilferty
    /// normal approximation (accurate to a few % in p for k ≥ 10): returns the z-score.
    fn chi2_z(x: f64, k: f64) -> f64 {
        let c = 2.0 / (9.0 * k);
        ((x / k).powf(1.0 / 3.0) - (1.0 - c)) / c.sqrt()
    }

    #[test]
    fn sampled_directions_follow_the_pdf_chi_square() {
        // Mitsuba's χ² test for BSDFs: histogram of sampled directions on a (cos θ, φ) grid
        // against n·∫cell pdf; cells with expected count < 5 are pooled into one. Reject when
        // the statistic's z-score exceeds 4 (p ≈ 3e-5 per configuration).
        let (nz, np, n) = (16usize, 32usize, 200_000u64);
        for (k, &(rho, m, r, theta)) in CONFIGS.iter().enumerate() {
            let b = mr(rho, m, r);
            let wo = dir(theta, 1.1);
            let mut counts = vec![0u64; nz * np];
            for p in 0..n {
                let Some(s) = b.sample(wo, Sampler::new(40 + k as u64, 0, p, 0).next_2d()) else { continue };
                let zi = ((s.wi.z * nz as f32) as usize).min(nz - 1);
                let phi = s.wi.y.atan2(s.wi.x).rem_euclid(2.0 * PI);
                let pj = ((phi / (2.0 * PI) * np as f32) as usize).min(np - 1);
                counts[zi * np + pj] += 1;
            }
            let (mut chi2, mut dof) = (0.0f64, 0usize);
            let (mut pool_obs, mut pool_exp) = (0.0f64, 0.0f64);
            for i in 0..nz {
                for j in 0..np {
                    let (z0, z1) = (i as f32 / nz as f32, (i + 1) as f32 / nz as f32);
                    let (p0, p1) = (2.0 * PI * j as f32 / np as f32, 2.0 * PI * (j + 1) as f32 / np as f32);
                    let e = n as f64 * cell_integral(&b, wo, z0, z1, p0, p1, 16);
                    let o = counts[i * np + j] as f64;
                    if e < 5.0 {
                        pool_obs += o;
                        pool_exp += e;
                    } else {
                        chi2 += (o - e).powi(2) / e;
                        dof += 1;
                    }
                }
            }
            if pool_exp >= 5.0 {
                chi2 += (pool_obs - pool_exp).powi(2) / pool_exp;
                dof += 1;
            }
            let z = chi2_z(chi2, (dof - 1) as f64);
            assert!(dof > 20 && z < 4.0, "config {k}: χ² = {chi2:.1} with {dof} cells, z = {z:.2}");
        }
    }

    #[test]
    fn sample_weight_equals_eval_over_pdf_and_pdf_matches() {
        for &(rho, m, r, theta) in CONFIGS.iter().chain(&[(0.7, 0.0, 0.0, 40.0), (0.7, 1.0, 0.0, 89.9), (0.7, 0.5, 0.05, 89.9)]) {
            let b = mr(rho, m, r);
            let wo = dir(theta, 0.2);
            for p in 0..2000 {
                let Some(s) = b.sample(wo, Sampler::new(7, 0, p, 0).next_2d()) else { continue };
                let pdf = b.pdf(wo, s.wi);
                let f = b.evaluate(wo, s.wi);
                assert!((pdf - s.pdf).abs() <= 1e-4 * s.pdf, "pdf {pdf} vs {}", s.pdf);
                assert!(((s.weight * s.pdf) - f).abs().max_element() <= 1e-4 * f.max_element() + 1e-12);
                assert!(s.weight.is_finite() && s.weight.min_element() >= 0.0);
            }
        }
    }

    #[test]
    fn sample_many_and_evaluate_many_are_sample_and_evaluate_pdf_bit_for_bit() {
        // Lambertian and glTF BSDFs mixed in one batch (dielectric and metal, mirror to rough,
        // KHR_materials_specular colours and weight 0), `wo` from normal to grazing and below
        // the surface, `u` at the lobes' boundaries and the domain's edges; batches of 0 to 19
        // so that lanes are left over.
        let mut rng = Sampler::new(3, 0, 0, 0);
        let mut total = (0, 0);
        for n in 0..20 {
            let mut bsdfs = Vec::new();
            let mut us = Vec::new();
            for k in 0..n {
                let wo = match k % 5 {
                    0 => Vec3::Z,
                    1 => Vec3::new(1.0, 0.0, 1e-4).normalize(),
                    2 => Vec3::new(0.3, 0.2, -0.9).normalize(),
                    _ => crate::sampler::sample_uniform_sphere(rng.next_2d()),
                };
                let bsdf = match k % 4 {
                    0 => Bsdf::Diffuse { albedo: Vec3::new(rng.next_1d(), 0.5, 0.2) },
                    1 => mr(rng.next_1d(), rng.next_1d(), rng.next_1d()),
                    2 => Bsdf::MetallicRoughness(MetallicRoughness::with_fresnel(Vec3::new(0.9, 0.4, 0.1), 0.0, [0.0, 0.05, 1.0][k % 3], DielectricFresnel::new(1.8, Vec3::new(1.0, 0.5, 0.2), rng.next_1d()))),
                    _ => mr(0.5, [0.0, 1.0][k % 2], 0.3),
                };
                let at = bsdf.at(wo);
                let u = match k % 3 {
                    0 => Vec2::new(at.ps, rng.next_1d()),
                    1 => Vec2::new(1.0 - f32::EPSILON / 2.0, 0.0),
                    _ => rng.next_2d(),
                };
                bsdfs.push(at);
                us.push(u);
            }
            let wis: Vec<Vec3> = (0..n).map(|k| if k % 6 == 5 { -Vec3::Z } else { crate::sampler::sample_uniform_sphere(rng.next_2d()) }).collect();
            let mut out = vec![None; n];
            sample_many(|k| &bsdfs[k], &us, &mut out);
            let mut values = vec![(Vec3::NAN, f32::NAN); n];
            evaluate_many(|k| &bsdfs[k], &wis, &mut values);
            let key = |s: Option<BsdfSample>| s.map(|s| (s.wi.to_array().map(f32::to_bits), s.weight.to_array().map(f32::to_bits), s.pdf.to_bits()));
            let value_bits = |(f, pdf): (Vec3, f32)| (f.to_array().map(f32::to_bits), pdf.to_bits());
            for k in 0..n {
                assert_eq!(key(out[k]), key(bsdfs[k].sample(us[k])), "batch of {n}, lane {k}: {:?} at {:?}", bsdfs[k], us[k]);
                assert_eq!(value_bits(values[k]), value_bits(bsdfs[k].evaluate_pdf(wis[k])), "batch of {n}, lane {k}: {:?} at {:?}", bsdfs[k], wis[k]);
                // The value against the model's own verbs (not through a lane).
                let (f, pdf) = values[k];
                let want = (bsdfs[k].bsdf.evaluate(bsdfs[k].wo, wis[k]), bsdfs[k].bsdf.pdf(bsdfs[k].wo, wis[k]));
                assert!((f - want.0).abs().max_element() <= 1e-5 * want.0.max_element().max(1.0) && (pdf - want.1).abs() <= 1e-5 * want.1.max(1.0), "lane {k}: {f} {pdf} vs {want:?}");
                total.0 += out[k].is_some() as u32;
                total.1 += out[k].is_none() as u32;
            }
        }
        assert!(total.0 > 50 && total.1 > 20, "{total:?} (samples, none)");
    }

    #[test]
    fn evaluate_pdf_is_evaluate_and_pdf_bit_for_bit() {
        let mut rng = crate::sampler::Sampler::new(7, 0, 0, 0);
        for (rho, m, r) in [(0.8, 0.0, 0.5), (0.5, 1.0, 0.05), (0.3, 0.4, 1.0), (0.9, 0.0, 0.0)] {
            for b in [mr(rho, m, r), Bsdf::Diffuse { albedo: Vec3::splat(rho) }] {
                for _ in 0..200 {
                    let wo = crate::sampler::sample_uniform_sphere(rng.next_2d());
                    let wi = crate::sampler::sample_uniform_sphere(rng.next_2d());
                    let (f, pdf) = b.evaluate_pdf(wo, wi);
                    assert_eq!(f, b.evaluate(wo, wi));
                    assert_eq!(pdf.to_bits(), b.pdf(wo, wi).to_bits());
                }
            }
        }
    }

    #[test]
    fn brdf_is_reciprocal() {
        let b = MetallicRoughness::new(Vec3::new(0.9, 0.5, 0.2), 0.4, 0.35, 1.0);
        for p in 0..5000 {
            let mut s = Sampler::new(8, 0, p, 0);
            let a = sample_cosine_hemisphere(s.next_2d());
            let c = sample_cosine_hemisphere(s.next_2d());
            let (f1, f2) = (b.f(a, c), b.f(c, a));
            assert!((f1 - f2).abs().max_element() <= 1e-5 * f1.max_element().max(1e-6), "{f1} vs {f2}");
        }
    }

    #[test]
    fn no_nan_or_inf_at_roughness_zero_grazing_angles_and_bent_normals() {
        for &r in &[0.0f32, 1e-4, 0.05, 1.0] {
            for &m in &[0.0f32, 0.5, 1.0] {
                let b = mr(0.8, m, r);
                for &theta in &[0.0f32, 45.0, 89.0, 89.9, 89.999] {
                    let wo = dir(theta, 0.4);
                    for p in 0..500 {
                        let u = Sampler::new(9, 0, p, 0).next_2d();
                        if let Some(s) = b.sample(wo, u) {
                            assert!(s.weight.is_finite() && s.pdf.is_finite() && s.pdf > 0.0, "r {r} m {m} θ {theta}: {s:?}");
                        }
                        let wi = dir(89.9 * u.x, std::f32::consts::TAU * u.y);
                        assert!(b.evaluate(wo, wi).is_finite() && b.pdf(wo, wi).is_finite());
                    }
                    // Exact mirror direction at roughness 0.
                    let mirror = Vec3::new(-wo.x, -wo.y, wo.z);
                    assert!(b.evaluate(wo, mirror).is_finite() && b.pdf(wo, mirror).is_finite());
                }
            }
        }
        // Shading normals facing away from the viewer are bent back: wo is above, finite.
        let wo = Vec3::new(0.0, 0.6, 0.8);
        for ns in [Vec3::new(0.0, -1.0, 0.0), -wo, Vec3::new(0.0, -0.8, 0.6), Vec3::NAN, wo] {
            let f = shading_frame(ns, false, wo);
            assert!(f.n.is_finite() && (f.n.length() - 1.0).abs() < 1e-5);
            let wl = f.to_local(wo);
            assert!(wl.z >= 0.99 * MIN_SHADING_COS, "{ns}: wo·n = {}", wl.z);
            let b = mr(0.5, 0.5, 0.0);
            let s = b.sample(wl, Vec2::new(0.3, 0.6));
            assert!(s.is_none_or(|s| s.weight.is_finite()));
        }
        // Flipped surfaces flip the mapped normal too.
        assert!(shading_frame(Vec3::Z, true, -Vec3::Z).n.z < -0.99);
    }

    #[test]
    fn base_color_metallic_roughness_and_resolve() {
        let mut m = Material::gltf_default();
        m.base_color_factor = Vec4::new(0.5, 1.0, 1.0, 1.0);
        m.base_color_texture = Some(TextureRef { texture: 0, tex_coord: 1, wrap_s: Wrap::Repeat, wrap_t: Wrap::Repeat, filter: Filter::Nearest, transform: None });
        m.emissive = Vec3::new(2.0, 0.0, 1.0);
        let tex = vec![
            Texture { width: 1, height: 1, texels: vec![Vec4::new(1.0, 0.5, 1.0, 0.25)] },
            Texture { width: 1, height: 1, texels: vec![Vec4::new(0.0, 0.5, 0.25, 1.0)] },
        ];
        let attr = SurfaceAttributes { uv: [Vec2::ZERO, Vec2::new(0.3, 0.3)], color: Vec4::new(1.0, 1.0, 0.5, 1.0) };
        assert_eq!(base_color(&m, &tex, &attr), Vec4::new(0.5, 0.5, 0.5, 0.25));
        // glTF's default is metallic 1, roughness 1.
        let r = resolve(&m, &tex, &attr);
        assert_eq!(r.bsdf, Bsdf::MetallicRoughness(MetallicRoughness::new(Vec3::splat(0.5), 1.0, 1.0, 1.0)));
        assert_eq!(r.emission, Vec3::new(2.0, 0.0, 1.0));
        // Factor × texture: metallic from B, roughness from G.
        m.metallic_factor = 0.8;
        m.roughness_factor = 0.6;
        m.metallic_roughness_texture = Some(TextureRef { texture: 1, tex_coord: 0, wrap_s: Wrap::Repeat, wrap_t: Wrap::Repeat, filter: Filter::Nearest, transform: None });
        assert_eq!(metallic_roughness(&m, &tex, &attr), (0.2, 0.3));
        let Bsdf::MetallicRoughness(b) = resolve(&m, &tex, &attr).bsdf else { panic!() };
        assert!((b.alpha - 0.09).abs() < 1e-7 && b.metallic == 0.2);
        // Metallic 0 and specular 0: the pure Lambertian BSDF.
        m.metallic_roughness_texture = None;
        m.metallic_factor = 0.0;
        m.specular_factor = 0.0;
        assert_eq!(resolve(&m, &tex, &attr).bsdf, Bsdf::Diffuse { albedo: Vec3::splat(0.5) });
    }

    #[test]
    fn view_dependence_rule() {
        let mut m = Material::gltf_default();
        assert!(is_view_dependent(&m), "glTF default is metallic");
        m.metallic_factor = 0.0;
        assert!(!is_view_dependent(&m), "rough dielectric counts as Lambertian");
        m.roughness_factor = 0.5;
        assert!(is_view_dependent(&m));
        m.specular_factor = 0.0;
        assert!(!is_view_dependent(&m));
        // A brighter F0 raises the roughness threshold: ior 0 (F0 = 1) → 0.6 · 25^¼ ≈ 1.34.
        m.specular_factor = 1.0;
        m.roughness_factor = 1.0;
        assert!(!is_view_dependent(&m));
        m.ior = 0.0;
        assert!(is_view_dependent(&m));
        // A metallic-roughness texture can lower the roughness or zero the metal.
        let mut d = Material::gltf_default();
        d.metallic_factor = 0.0;
        d.metallic_roughness_texture = Some(TextureRef { texture: 0, tex_coord: 0, wrap_s: Wrap::Repeat, wrap_t: Wrap::Repeat, filter: Filter::Nearest, transform: None });
        let tex = vec![Texture { width: 2, height: 1, texels: vec![Vec4::new(0.0, 1.0, 0.0, 1.0), Vec4::new(0.0, 0.3, 0.0, 1.0)] }];
        assert!(is_view_dependent_textured(&d, &tex));
        d.metallic_factor = 1.0;
        d.metallic_roughness_texture = Some(TextureRef { texture: 1, ..d.metallic_roughness_texture.unwrap() });
        let tex2 = vec![tex[0].clone(), Texture { width: 1, height: 1, texels: vec![Vec4::new(0.0, 1.0, 0.0, 1.0)] }];
        assert!(!is_view_dependent_textured(&d, &tex2), "metallic texture all zero, rough");
    }

    #[test]
    fn tangents_and_normal_maps_follow_gltf_conventions() {
        // A quad in z = 0 facing +z; u grows along +x, glTF v grows along −y (image top at +y).
        let p = [Vec3::ZERO, Vec3::X, Vec3::Y];
        let uv = [Vec2::new(0.0, 1.0), Vec2::new(1.0, 1.0), Vec2::new(0.0, 0.0)];
        let t = triangle_tangent(p, uv, Vec3::Z).unwrap();
        assert!((t - Vec4::new(1.0, 0.0, 0.0, 1.0)).length() < 1e-6, "{t}");
        // Mirrored UVs (u along −x) flip the handedness so that B still points to image-up (+y).
        let uvm = [Vec2::new(1.0, 1.0), Vec2::new(0.0, 1.0), Vec2::new(1.0, 0.0)];
        let tm = triangle_tangent(p, uvm, Vec3::Z).unwrap();
        assert!((tm - Vec4::new(-1.0, 0.0, 0.0, -1.0)).length() < 1e-6, "{tm}");
        assert!(triangle_tangent(p, [Vec2::ZERO; 3], Vec3::Z).is_none());
        // Texel (1, 0.5, 1) tilts the normal 45° to +T; (0.5, 1, 1) 45° to +B = image up.
        let mut m = Material::gltf_default();
        m.normal_texture = Some((TextureRef { texture: 0, tex_coord: 0, wrap_s: Wrap::Repeat, wrap_t: Wrap::Repeat, filter: Filter::Nearest, transform: None }, 1.0));
        let attr = SurfaceAttributes { uv: [Vec2::splat(0.5); 2], color: Vec4::ONE };
        for (texel, expect) in [(Vec4::new(1.0, 0.5, 1.0, 1.0), Vec3::new(1.0, 0.0, 1.0)), (Vec4::new(0.5, 1.0, 1.0, 1.0), Vec3::new(0.0, 1.0, 1.0))] {
            let tex = vec![Texture { width: 1, height: 1, texels: vec![texel] }];
            for tan in [t, tm] {
                // Tangent-space +X follows +u (world ±x); +Y is image-up (world +y) either way.
                let expect = Vec3::new(expect.x * tan.x, expect.y, expect.z).normalize();
                let n = normal_mapped(&m, &tex, &attr, Vec3::Z, tan);
                assert!((n - expect).length() < 1e-5, "{texel} with {tan}: {n}");
            }
        }
        // Degenerate tangent or no normal texture: unchanged.
        let tex = vec![Texture { width: 1, height: 1, texels: vec![Vec4::new(1.0, 0.5, 0.5, 1.0)] }];
        assert_eq!(normal_mapped(&m, &tex, &attr, Vec3::Z, Vec4::ZERO), Vec3::Z);
        assert_eq!(normal_mapped(&Material::gltf_default(), &tex, &attr, Vec3::Z, t), Vec3::Z);
    }

    #[test]
    fn facing_normals_flip_towards_the_ray() {
        let (ng, n) = facing_normals(Vec3::Z, Vec3::new(0.1, 0.0, 1.0), Vec3::new(0.0, 0.0, 1.0));
        assert_eq!(ng, -Vec3::Z);
        assert!(n.z < 0.0);
    }

    #[test]
    fn dielectric_f0_and_f90_follow_the_extensions_formulas() {
        // ior 1.5 is plain glTF's 0.04 exactly (so plain materials render bit-identically).
        assert_eq!(f0_from_ior(1.5), DIELECTRIC_F0);
        assert_eq!(DielectricFresnel::new(1.5, Vec3::ONE, 1.0), DielectricFresnel::GLTF);
        assert_eq!(f0_from_ior(0.0), 1.0);
        assert_eq!(f0_from_ior(1.0), 0.0);
        assert!((f0_from_ior(2.0) - 1.0 / 9.0).abs() < 1e-7);
        // F0 = min(f0(ior) · colour, 1) · specular; F90 = specular.
        let f = DielectricFresnel::new(2.0, Vec3::new(1.0, 0.5, 12.0), 0.5);
        assert!((f.f0 - Vec3::new(0.5 / 9.0, 0.25 / 9.0, 0.5)).abs().max_element() < 1e-7, "{f:?}");
        assert_eq!(f.f90, 0.5);
        assert_eq!(DielectricFresnel::new(0.0, Vec3::new(0.2, 0.4, 0.6), 1.0).f0, Vec3::new(0.2, 0.4, 0.6));
    }

    #[test]
    fn fresnel_at_normal_incidence_is_f0_and_diffuse_takes_the_rest() {
        // At V = L = N, V·H = 1 and w5 = 0: f = (1 − max F0) ρ/π + F0 D(N) Vis(1, 1).
        for (ior, color, s) in [(1.5, Vec3::ONE, 1.0), (1.33, Vec3::new(1.0, 0.3, 0.0), 0.7), (0.0, Vec3::new(0.9, 0.6, 0.1), 1.0), (2.4, Vec3::splat(20.0), 0.25)] {
            let fr = DielectricFresnel::new(ior, color, s);
            let r = ((ior - 1.0) / (ior + 1.0)) as f64;
            let expect_f0 = (color.as_dvec3() * r * r).min(glam::DVec3::ONE) * s as f64;
            assert!((fr.f0.as_dvec3() - expect_f0).abs().max_element() < 1e-6, "{ior} {color}: {:?}", fr.f0);
            for rho in [Vec3::ZERO, Vec3::new(0.8, 0.5, 0.2)] {
                let b = MetallicRoughness::with_fresnel(rho, 0.0, 0.5, fr);
                let spec = b.d(Vec3::Z) * b.vis(1.0, 1.0);
                let expect = rho * ((1.0 - fr.f0.max_element()) * FRAC_1_PI) + fr.f0 * spec;
                assert!((b.f(Vec3::Z, Vec3::Z) - expect).abs().max_element() < 1e-6 * expect.max_element().max(1.0));
            }
        }
    }

    #[test]
    fn specular_only_dielectric_mirror_in_a_furnace_reflects_f0() {
        // Base colour 0, metallic 0, roughness 0 (α = 10⁻³): under unit radiance from every
        // direction, the radiance reflected at normal incidence is ∫ f cos dω = F0 (the lobe
        // is a near-delta around N where V·H ≈ 1; the GGX energy loss at α = 10⁻³ is ~10⁻⁴).
        for (ior, color, s) in [(1.5, Vec3::ONE, 1.0), (1.8, Vec3::new(1.0, 0.5, 0.25), 1.0), (0.0, Vec3::new(0.9, 0.6, 0.3), 0.8)] {
            let fr = DielectricFresnel::new(ior, color, s);
            let b = Bsdf::MetallicRoughness(MetallicRoughness::with_fresnel(Vec3::ZERO, 0.0, 0.0, fr));
            let n = 20_000u64;
            let mut sum = Vec3::ZERO;
            for p in 0..n {
                if let Some(smp) = b.sample(Vec3::Z, Sampler::new(77, 0, p, 0).next_2d()) {
                    sum += smp.weight;
                }
            }
            let albedo = sum / n as f32;
            assert!((albedo - fr.f0).abs().max_element() < 1e-3 * fr.f0.max_element().max(0.04), "{ior} {color} {s}: {albedo} vs F0 {}", fr.f0);
        }
    }

    #[test]
    fn uniform_surface_is_resolve_at_every_point_or_none() {
        let mut m = Material::gltf_default();
        m.metallic_factor = 0.3;
        m.roughness_factor = 0.4;
        m.base_color_factor = Vec4::new(0.2, 0.6, 0.9, 1.0);
        m.emissive = Vec3::new(1.0, 2.0, 0.5);
        m.specular_factor = 0.7;
        m.specular_color_factor = Vec3::new(1.0, 0.5, 0.25);
        m.ior = 1.8;
        let r = |t| TextureRef { texture: t, tex_coord: 0, wrap_s: Wrap::Repeat, wrap_t: Wrap::Repeat, filter: Filter::Nearest, transform: None };
        // A normal map changes the frame, not the resolved material.
        m.normal_texture = Some((r(0), 1.0));
        let tex = vec![Texture { width: 2, height: 1, texels: vec![Vec4::new(0.1, 0.9, 0.3, 0.5), Vec4::new(0.8, 0.2, 0.6, 1.0)] }];
        let once = uniform_surface(&m, false).expect("untextured");
        let mut rng = Sampler::new(11, 0, 0, 0);
        for _ in 0..64 {
            let attr = SurfaceAttributes { uv: [rng.next_2d() * 4.0, rng.next_2d() * 4.0], color: Vec4::ONE };
            assert_eq!(resolve(&m, &tex, &attr), once);
        }
        // Vertex colours, or any texture resolve reads, make it vary.
        assert!(uniform_surface(&m, true).is_none());
        for slot in 0..5 {
            let mut t = m.clone();
            match slot {
                0 => t.base_color_texture = Some(r(0)),
                1 => t.metallic_roughness_texture = Some(r(0)),
                2 => t.specular_texture = Some(r(0)),
                3 => t.specular_color_texture = Some(r(0)),
                _ => t.emissive_texture = Some(r(0)),
            }
            let (a, b) = ([Vec2::new(0.25, 0.5); 2], [Vec2::new(0.75, 0.5); 2]);
            let at = |uv| resolve(&t, &tex, &SurfaceAttributes { uv, color: Vec4::ONE });
            assert_ne!(at(a), at(b), "slot {slot}: the texture varies");
            assert!(uniform_surface(&t, false).is_none(), "slot {slot}");
        }
    }

    #[test]
    fn resolve_reads_specular_texture_alpha_colour_texture_and_ior() {
        let mut m = Material::gltf_default();
        m.metallic_factor = 0.0;
        m.base_color_factor = Vec4::new(0.5, 0.5, 0.5, 1.0);
        m.specular_factor = 0.5;
        m.specular_color_factor = Vec3::new(1.0, 0.5, 2.0);
        m.ior = 2.0;
        let r = |t| TextureRef { texture: t, tex_coord: 0, wrap_s: Wrap::Repeat, wrap_t: Wrap::Repeat, filter: Filter::Nearest, transform: None };
        m.specular_texture = Some(r(0));
        m.specular_color_texture = Some(r(1));
        let tex = vec![
            Texture { width: 1, height: 1, texels: vec![Vec4::new(0.1, 0.2, 0.3, 0.5)] },
            Texture { width: 1, height: 1, texels: vec![Vec4::new(1.0, 0.5, 0.25, 0.1)] },
        ];
        let attr = SurfaceAttributes { uv: [Vec2::ZERO; 2], color: Vec4::ONE };
        // Weight = 0.5 × A(0.5); colour = (1, 0.5, 2) × RGB (1, 0.5, 0.25).
        let expect = DielectricFresnel::new(2.0, Vec3::new(1.0, 0.25, 0.5), 0.25);
        assert_eq!(dielectric_fresnel(&m, &tex, &attr), expect);
        let Bsdf::MetallicRoughness(b) = resolve(&m, &tex, &attr).bsdf else { panic!() };
        assert_eq!(b.fresnel, expect);
        // A zero specular texture alpha makes the dielectric exactly Lambertian.
        let tex0 = vec![Texture { width: 1, height: 1, texels: vec![Vec4::new(1.0, 1.0, 1.0, 0.0)] }, tex[1].clone()];
        assert_eq!(resolve(&m, &tex0, &attr).bsdf, Bsdf::Diffuse { albedo: Vec3::splat(0.5) });
        // Specular colour 0 keeps F90: still a (grazing) specular layer, not Lambertian.
        m.specular_color_factor = Vec3::ZERO;
        assert!(matches!(resolve(&m, &tex, &attr).bsdf, Bsdf::MetallicRoughness(_)));
        // Default material: plain glTF's Fresnel.
        let Bsdf::MetallicRoughness(d) = resolve(&Material::gltf_default(), &[], &attr).bsdf else { panic!() };
        assert_eq!(d.fresnel, DielectricFresnel::GLTF);
    }
}
