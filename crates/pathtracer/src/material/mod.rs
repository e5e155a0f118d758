//! Materials: a glTF [`Material`](crate::scene::Material) at a surface point turned into a BSDF plus emission
//! ([`resolve`]), and the BSDF verbs `evaluate` / `sample` / `pdf` (Mitsuba's interface).
//!
//! Conventions: directions `wo` (towards the viewer, glTF's `V`) and `wi` (towards the light,
//! glTF's `L`) point away from the surface and are expressed in the local shading [`Frame`](crate::geometry::Frame)
//! whose `n` (z axis) is the shading normal already flipped to the side the ray came from.
//! `evaluate` returns `f(wo, wi) · |cos θᵢ|` (the cosine-weighted BSDF), `sample` returns the
//! weight `f · |cos θᵢ| / pdf`, and `pdf` is per unit solid angle (`∞` for a delta lobe,
//! whose `evaluate` is 0). Every BSDF but [`Bsdf::Transmissive`] is reflection-only: `f = 0`
//! unless `wo.z > 0` and `wi.z > 0`.
//!
//! [`Bsdf`] is a closed set of models, one file each, dispatched with `match`:
//! - `lambert`: [`Bsdf::Diffuse`], `f = ρ/π`, cosine-weighted sampling;
//! - `metallic_roughness`: [`Bsdf::MetallicRoughness`], the glTF 2.0 metallic-roughness BRDF
//!   of the specification's Appendix B (GGX specular + diffuse, formulas on
//!   [`MetallicRoughness`], which the Mitsuba cross-check re-implements). `resolve` produces
//!   [`Bsdf::Diffuse`] only where this BRDF reduces to it exactly (metallic 0 and
//!   `KHR_materials_specular` `specular` 0);
//! - `dielectric`: [`Bsdf::Transmissive`], `KHR_materials_transmission` (with `_volume`): a
//!   GGX dielectric that reflects and refracts, mixed with the metallic-roughness BRDF
//!   (formulas on the module; scalar only, the lane loops hand it to its scalar verbs);
//! - `layered`: [`Bsdf::Layered`], `KHR_materials_sheen` and `_clearcoat` over the
//!   metallic-roughness BRDF (formulas on the module; scalar only, like the dielectric).
//!
//! Each model's file owns its scalar verbs and its *lane* form: the same operations on one
//! lane of a structure-of-arrays record, with no branch on the data, which `lanes` runs over
//! eight BSDFs at a time ([`evaluate_many`], [`sample_many`], and the path loop in lanes) and
//! which [`BsdfAt`] runs on one: both give the scalar verbs' bits. A new model is one variant
//! here and one file with those forms.
//!
//! The rest: `gltf` (the material's factors × textures at a point, [`resolve`], and questions
//! about a material as a whole such as view dependence) and `shading` (normals, tangents,
//! normal maps, the shading frame). Alpha: `Mask` keeps a surface where alpha ≥ cutoff; `Blend`
//! is stochastic coverage decided by a hash of (ray, triangle) (see `integrator::alpha_test`).
//! Sidedness: a single-sided triangle hit from behind is not hit at all (glTF back-face
//! culling); double-sided ones shade with the normal flipped towards the ray and emit from
//! both sides.

// Negated comparisons (`!(x > 0.0)`) are deliberate: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

mod dielectric;
mod gltf;
mod lambert;
mod lanes;
mod layered;
mod metallic_roughness;
mod shading;
#[cfg(test)]
mod dielectric_tests;
#[cfg(test)]
mod layered_tests;
#[cfg(test)]
mod tests;

pub use gltf::{
    SurfaceAttributes, SurfaceMaterial, VIEW_DEPENDENT_ROUGHNESS, base_color, layers, dielectric_fresnel, emission, is_view_dependent,
    is_view_dependent_textured, max_dielectric_f0, metallic_roughness, min_roughness_texel, resolve, scene_is_view_dependent,
    uniform_surface,
};
pub(crate) use lanes::{BsdfLanes, SampledLanes, evaluate_lanes, sample_lanes};
pub use lanes::{evaluate_many, sample_many};
pub use dielectric::{Dielectric, Transmissive, fresnel_dielectric};
pub use layered::{Layered, SHEEN_MIN_ROUGHNESS, charlie_d, charlie_vis, sheen_albedo, sheen_albedo_integral};
pub use metallic_roughness::{CLEARCOAT_F0, DIELECTRIC_F0, DielectricFresnel, MIN_ALPHA, MetallicRoughness, SpecularLobe, f0_from_ior};
pub use shading::{MIN_SHADING_COS, facing_normals, normal_mapped, normal_mapped_by, shading_frame, triangle_tangent};

use glam::{Vec2, Vec3};
use lanes::{evaluate_pdf_lane, sample_lane};

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
    /// A transmissive glTF material (`KHR_materials_transmission`): formulas, sampling and
    /// parameters on [`Transmissive`] and [`Dielectric`].
    Transmissive(Transmissive),
    /// The metallic-roughness BRDF under `KHR_materials_sheen` and `_clearcoat` layers:
    /// formulas, sampling and parameters on [`Layered`].
    Layered(Layered),
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

    /// The BSDF this was prepared from.
    pub fn bsdf(&self) -> &Bsdf {
        &self.bsdf
    }

    /// [`Bsdf::evaluate`] and [`Bsdf::pdf`] at `wi` (one lane of [`evaluate_many`]).
    #[inline(always)]
    pub fn evaluate_pdf(&self, wi: Vec3) -> (Vec3, f32) {
        match &self.bsdf {
            Bsdf::Transmissive(t) => return t.evaluate_pdf(self.wo, wi),
            Bsdf::Layered(l) => return l.evaluate_pdf(self.wo, wi),
            _ => {}
        }
        evaluate_pdf_lane::<false>(&self.lane(Vec2::ZERO), wi)
    }

    /// [`Bsdf::sample`] with two uniform numbers (one lane of [`sample_many`]).
    #[inline(always)]
    pub fn sample(&self, u: Vec2) -> Option<BsdfSample> {
        match &self.bsdf {
            Bsdf::Transmissive(t) => return t.sample(self.wo, u),
            Bsdf::Layered(l) => return l.sample(self.wo, u),
            _ => {}
        }
        let (wi, weight, pdf, ok) = sample_lane::<false>(self.lane(u));
        ok.then_some(BsdfSample { wi, weight, pdf })
    }

    /// Whether this model's verbs are scalar only ([`Bsdf::Transmissive`], [`Bsdf::Layered`]):
    /// the lane loops replace their results by the scalar verbs'.
    #[inline(always)]
    pub(crate) fn is_scalar_only(&self) -> bool {
        matches!(self.bsdf, Bsdf::Transmissive(_) | Bsdf::Layered(_))
    }

    /// The transmissive model this is, if it is one (its verbs are scalar only).
    #[inline(always)]
    pub(crate) fn transmissive(&self) -> Option<&Transmissive> {
        match &self.bsdf {
            Bsdf::Transmissive(t) => Some(t),
            _ => None,
        }
    }

    /// What [`sample_lane`] and [`evaluate_pdf_lane`] read of this BSDF, with the numbers `u`.
    #[inline(always)]
    pub(crate) fn lane(&self, u: Vec2) -> SampleLane {
        match &self.bsdf {
            Bsdf::Diffuse { albedo } => lambert::lane(*albedo, self.wo, u),
            Bsdf::MetallicRoughness(mr) => metallic_roughness::lane(mr, self.wo, self.ps, self.sd_wo, u),
            // Never read: the lane loops replace their results by their scalar verbs'.
            Bsdf::Transmissive(_) | Bsdf::Layered(_) => lambert::lane(Vec3::ZERO, self.wo, u),
        }
    }
}

impl Bsdf {
    /// `f(wo, wi) · |cos θᵢ|` in the local frame (see the variant docs for `f`).
    #[inline]
    pub fn evaluate(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        match self {
            Bsdf::Transmissive(t) => return t.evaluate_pdf(wo, wi).0,
            Bsdf::Layered(l) => return l.evaluate_pdf(wo, wi).0,
            _ => {}
        }
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return Vec3::ZERO;
        }
        match self {
            Bsdf::Diffuse { albedo } => lambert::evaluate(*albedo, wi),
            Bsdf::MetallicRoughness(mr) => mr.f(wo, wi) * wi.z,
            Bsdf::Transmissive(_) | Bsdf::Layered(_) => Vec3::ZERO,
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
        match self {
            Bsdf::Transmissive(t) => return t.evaluate_pdf(wo, wi).1,
            Bsdf::Layered(l) => return l.evaluate_pdf(wo, wi).1,
            _ => {}
        }
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return 0.0;
        }
        match self {
            Bsdf::Diffuse { .. } => lambert::pdf(wi),
            Bsdf::MetallicRoughness(mr) => mr.pdf(wo, wi),
            Bsdf::Transmissive(_) | Bsdf::Layered(_) => 0.0,
        }
    }

    /// Whether this is the Lambertian model (the lane loops compute that model alone where
    /// every lane is).
    #[inline]
    pub fn is_lambertian(&self) -> bool {
        matches!(self, Bsdf::Diffuse { .. })
    }

    /// Whether outgoing radiance depends on the viewing direction (false for Lambertian,
    /// true whenever a specular lobe exists; the scene-level rule with its threshold is
    /// [`is_view_dependent`]).
    pub fn is_view_dependent(&self) -> bool {
        match self {
            Bsdf::Diffuse { .. } => false,
            Bsdf::MetallicRoughness(_) | Bsdf::Transmissive(_) | Bsdf::Layered(_) => true,
        }
    }

    /// This BSDF for a viewer on the back of the surface (`back`): a volume's interface then
    /// sees the inside (`η = 1/ior`); every other model is the same from both sides.
    #[inline(always)]
    pub fn seen_from(self, back: bool) -> Self {
        match self {
            Bsdf::Transmissive(mut t) if back => {
                t.glass.inside = true;
                Bsdf::Transmissive(t)
            }
            other => other,
        }
    }
}

/// One BSDF's inputs as plain numbers (a lane of [`sample_many`]): the union of the models'
/// parameters, each model's file filling its own ([`lambert::lane`],
/// [`metallic_roughness::lane`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct SampleLane {
    /// [`Bsdf::Diffuse`] (albedo `rho`), else [`Bsdf::MetallicRoughness`]
    /// ([`BsdfLanes::is_lambertian`] per lane).
    diffuse: bool,
    rho: Vec3,
    metallic: f32,
    alpha: f32,
    f0: Vec3,
    f90: f32,
    wo: Vec3,
    ps: f32,
    sd_wo: f32,
    u: Vec2,
}

impl SampleLane {
    /// This BSDF seen from `wo` instead, before what depends on `wo` is computed
    /// ([`BsdfLanes::set_wo_terms`]).
    #[inline(always)]
    pub(crate) fn with_wo(self, wo: Vec3) -> Self {
        Self { wo, ..self }
    }
}
