//! The glTF transmissive dielectric (`KHR_materials_transmission`, `_volume`, `_ior`):
//! [`Dielectric`], a GGX microfacet interface that reflects and refracts (Walter et al. 2007,
//! "Microfacet Models for Refraction through Rough Surfaces"), and [`Transmissive`], its
//! mixture with the metallic-roughness BRDF for a transmission factor below 1 or metallic > 0.
//!
//! `wo` (the viewer) is always above the shading frame (`wo.z > 0`); `η = n_t / n_i` is the
//! relative index of the side below (`ior` seen from outside, `1/ior` from inside a volume).
//! With `c = wo·h`, exact unpolarised Fresnel:
//!
//! ```text
//! c_t² = 1 − (1 − c²)/η²   (total internal reflection: F = 1 where c_t² ≤ 0)
//! F(c) = ½ [((c − η c_t)/(c + η c_t))² + ((η c − c_t)/(η c + c_t))²]   (F(1) = ((η−1)/(η+1))²)
//! ```
//!
//! Smooth (`roughness = 0`, delta lobes, `pdf = ∞`): reflection `wi = (−wo.x, −wo.y, wo.z)`
//! with probability `F(wo.z)`, weight 1; refraction `wi = −wo/η + (wo.z/η − c_t) z` otherwise,
//! weight `tint / η²` (radiance is compressed by `η²` into the denser side).
//! Rough (`α = max(roughness², MIN_ALPHA)`, GGX `D`, separable Smith `G = G1(wo) G1(wi)`):
//!
//! ```text
//! reflection   (wi.z > 0, h = normalize(wo + wi)):     f = F(wo·h) D G / (4 wo.z wi.z)
//! transmission (wi.z < 0, h = ±normalize(wo + η wi)):  f = tint (1 − F(wo·h)) D G |wo·h| |wi·h|
//!                                                           / (wo.z |wi.z| (wo·h + η wi·h)²)
//! ```
//!
//! Sampling draws a visible normal `h` (Heitz 2018), then reflects with probability
//! `F(wo·h)` and refracts otherwise (no sample where that lands on the other lobe's side): `pdf_r = F D_v / (4 wo·h)`, `pdf_t = (1 − F) D_v η² |wi·h|
//! / (wo·h + η wi·h)²` with `D_v = G1(wo) D (wo·h) / wo.z`; the weights are `G1(wi)` and
//! `tint G1(wi)`. Thin-walled (no volume): the slab's two interfaces at once, rays pass
//! straight: `R = 2F/(1 + F)` with `F` at `η = ior`, `T = 1 − R`; smooth transmission is
//! `wi = −wo`, rough transmission is the reflected lobe mirrored below the surface
//! (`wi = (x, y, −z)` of a reflected direction), with `1 − R` in place of `F`.
//!
//! Energy: the smooth lobes conserve it exactly (`R + T = 1` before the tint); the rough
//! ones lose what single-scattering GGX loses at high roughness (tests: `material::tests`).
//!
//! [`Transmissive`] (glTF: `f = (1 − m)[(1 − t) dielectric_brdf + t (Fresnel-weighted
//! btdf)] + m metal`): weight `w = (1 − m) t` on the [`Dielectric`], `1 − w` on the
//! metallic-roughness BRDF with metallic `m / (1 − w)` (the same mixture); the lobe is chosen
//! with probability `w` (one-sample MIS where both are smooth-free). Evaluation and sampling
//! are scalar only: the lane loops never see it (`integrator::LaneMaterials` refuses it).

// Negated comparisons (`!(x > 0.0)`) are deliberate: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::{BsdfSample, MIN_ALPHA, MetallicRoughness, metallic_roughness::visible_normal};
use crate::sampler::splitmix64;
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// Exact unpolarised Fresnel reflectance for `cos_i = wo·h ≥ 0` and relative index `η`, with
/// the cosine of the refracted direction (`0` under total internal reflection, where `F = 1`).
pub fn fresnel_dielectric(cos_i: f32, eta: f32) -> (f32, f32) {
    let c = cos_i.clamp(0.0, 1.0);
    let ct2 = 1.0 - (1.0 - c * c) / (eta * eta);
    if !(ct2 > 0.0) {
        return (1.0, 0.0);
    }
    let ct = ct2.sqrt();
    let rs = (c - eta * ct) / (c + eta * ct);
    let rp = (eta * c - ct) / (eta * c + ct);
    (0.5 * (rs * rs + rp * rp), ct)
}

/// A GGX dielectric interface (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dielectric {
    /// `KHR_materials_ior` (≥ 1).
    pub ior: f32,
    /// Whether the viewer is inside the volume (then `η = 1/ior`).
    pub inside: bool,
    /// GGX α, or 0 for the smooth (delta) interface.
    pub alpha: f32,
    /// Transmission tint (the base colour, linear RGB in [0, 1]).
    pub tint: Vec3,
    /// Thin-walled (no `KHR_materials_volume`): rays pass straight through.
    pub thin: bool,
}

impl Dielectric {
    /// The interface for `ior`, perceptual `roughness` (0: smooth), the tint, thin or not.
    pub fn new(ior: f32, roughness: f32, tint: Vec3, thin: bool) -> Self {
        let r = if roughness.is_finite() { roughness.clamp(0.0, 1.0) } else { 1.0 };
        let alpha = if r > 0.0 { (r * r).max(MIN_ALPHA) } else { 0.0 };
        let ior = if ior.is_finite() && ior >= 1.0 { ior } else { 1.5 };
        let tint = if tint.is_finite() { tint.clamp(Vec3::ZERO, Vec3::ONE) } else { Vec3::ONE };
        Self { ior, inside: false, alpha, tint, thin }
    }

    /// `η = n_below / n_above`: `ior` from outside (and always for a thin wall), `1/ior` from inside.
    #[inline]
    pub fn eta(&self) -> f32 {
        if self.inside && !self.thin { 1.0 / self.ior } else { self.ior }
    }

    /// Whether the interface is smooth (delta lobes only).
    #[inline]
    pub fn is_smooth(&self) -> bool {
        self.alpha <= 0.0
    }

    /// The reflectance at `c = wo·h`: Fresnel, or the thin slab's `2F/(1 + F)`.
    #[inline]
    fn reflectance(&self, c: f32) -> f32 {
        let (f, _) = fresnel_dielectric(c, self.eta());
        if self.thin { 2.0 * f / (1.0 + f) } else { f }
    }

    fn d(&self, h: Vec3) -> f32 {
        let a2 = self.alpha * self.alpha;
        let den = h.x * h.x + h.y * h.y + h.z * h.z * a2;
        if h.z <= 0.0 { 0.0 } else { a2 / (PI * den * den) }
    }

    /// Smith `G1` of direction `v` for the microfacet `h` (0 where `v` is on the wrong side of `h`).
    fn g1(&self, v: Vec3, h: Vec3) -> f32 {
        if v.dot(h) * v.z <= 0.0 {
            return 0.0;
        }
        let c = v.z.abs();
        let a2 = self.alpha * self.alpha;
        2.0 * c / (c + (a2 + (1.0 - a2) * c * c).sqrt())
    }

    /// The microfacet normal (`h.z > 0`) and whether `wi` is a transmission for `(wo, wi)`:
    /// `None` where the pair is not a valid configuration.
    fn half(&self, wo: Vec3, wi: Vec3) -> Option<(Vec3, bool)> {
        let reflect = wi.z > 0.0;
        let h = if reflect || self.thin {
            wo + Vec3::new(wi.x, wi.y, wi.z.abs())
        } else {
            wo + self.eta() * wi
        };
        let h = h.normalize_or_zero();
        let h = if h.z < 0.0 { -h } else { h };
        (h != Vec3::ZERO && h.is_finite() && wo.dot(h) > 0.0).then_some((h, !reflect))
    }

    /// `(f · |cos θᵢ|, pdf)` at `wi` (zero for a smooth interface: its lobes are deltas).
    pub fn evaluate_pdf(&self, wo: Vec3, wi: Vec3) -> (Vec3, f32) {
        if self.is_smooth() || !(wo.z > 0.0) || wi.z == 0.0 || !wi.is_finite() {
            return (Vec3::ZERO, 0.0);
        }
        let Some((h, transmit)) = self.half(wo, wi) else { return (Vec3::ZERO, 0.0) };
        let (c, d) = (wo.dot(h), self.d(h));
        let r = self.reflectance(c);
        let dv = self.g1(wo, h) * d * c / wo.z;
        let wi_m = if self.thin { Vec3::new(wi.x, wi.y, wi.z.abs()) } else { wi };
        let g = self.g1(wo, h) * self.g1(wi_m, h);
        if !transmit || self.thin {
            let (share, tint) = if transmit { (1.0 - r, self.tint) } else { (r, Vec3::ONE) };
            let f = tint * (share * d * g / (4.0 * wo.z));
            return (f, share * dv / (4.0 * c));
        }
        let eta = self.eta();
        let ci = wi.dot(h);
        if !(ci < 0.0) {
            return (Vec3::ZERO, 0.0);
        }
        let den = c + eta * ci;
        let den2 = den * den;
        let f = self.tint * ((1.0 - r) * d * g * c * ci.abs() / (wo.z * den2));
        (f, (1.0 - r) * dv * eta * eta * ci.abs() / den2)
    }

    /// Draws `wi` with two uniform numbers (see the module docs); a smooth interface's
    /// sample has `pdf = ∞`.
    pub fn sample(&self, wo: Vec3, u: Vec2) -> Option<BsdfSample> {
        if !(wo.z > 0.0) {
            return None;
        }
        let eta = self.eta();
        if self.is_smooth() {
            let (f, ct) = fresnel_dielectric(wo.z, eta);
            let r = if self.thin { 2.0 * f / (1.0 + f) } else { f };
            return Some(if u.x < r {
                BsdfSample { wi: Vec3::new(-wo.x, -wo.y, wo.z), weight: Vec3::ONE, pdf: f32::INFINITY }
            } else if self.thin {
                BsdfSample { wi: -wo, weight: self.tint, pdf: f32::INFINITY }
            } else {
                let wi = Vec3::new(-wo.x / eta, -wo.y / eta, -ct).normalize();
                BsdfSample { wi, weight: self.tint / (eta * eta), pdf: f32::INFINITY }
            });
        }
        let (h, ok) = visible_normal(self.alpha, wo, u);
        if !ok {
            return None;
        }
        let c = wo.dot(h);
        let r = self.reflectance(c);
        let reflected = 2.0 * c * h - wo;
        let reflect = lobe_number(u) < r;
        let wi = if reflect {
            reflected
        } else if self.thin {
            Vec3::new(reflected.x, reflected.y, -reflected.z)
        } else {
            let (_, ct) = fresnel_dielectric(c, eta);
            (-wo / eta + (c / eta - ct) * h).normalize()
        };
        // A microfacet can send either lobe to the wrong side of the macro surface (a
        // reflection below it, a refraction out of a denser medium above it): no sample, as
        // `evaluate` there reads the other lobe.
        if reflect != (wi.z > 0.0) {
            return None;
        }
        let (f, pdf) = self.evaluate_pdf(wo, wi);
        (pdf > 0.0 && pdf.is_finite() && f.is_finite()).then(|| BsdfSample { wi, weight: f / pdf, pdf })
    }
}

/// The number that chooses a rough interface's lobe after `u` drew its visible normal: a hash
/// of both numbers' bits (SplitMix64), uniform and independent of the normal (the low digits
/// of a low-discrepancy `u` are not: they are fixed by the other number's high ones).
#[inline]
fn lobe_number(u: Vec2) -> f32 {
    let h = splitmix64((u64::from(u.x.to_bits()) << 32) | u64::from(u.y.to_bits()));
    (h >> 40) as f32 * (1.0 / 16_777_216.0)
}

/// The glTF transmissive material: a [`Dielectric`] with weight `w`, the metallic-roughness
/// BRDF with `1 − w` (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transmissive {
    /// The refracting interface.
    pub glass: Dielectric,
    /// Its weight `w = (1 − metallic) × transmission` in (0, 1].
    pub weight: f32,
    /// The rest (metallic `m / (1 − w)`), unused where `w = 1`.
    pub base: MetallicRoughness,
}

impl Transmissive {
    /// The mixture for glTF's base colour, metallic, roughness, the dielectric's Fresnel
    /// endpoints of the opaque part, `ior`, the transmission factor and thin-walledness.
    pub fn new(base: MetallicRoughness, roughness: f32, ior: f32, transmission: f32, thin: bool) -> Self {
        let t = if transmission.is_finite() { transmission.clamp(0.0, 1.0) } else { 0.0 };
        let weight = (1.0 - base.metallic) * t;
        let metallic = if weight < 1.0 { (base.metallic / (1.0 - weight)).clamp(0.0, 1.0) } else { 0.0 };
        Self { glass: Dielectric::new(ior, roughness, base.base_color, thin), weight, base: MetallicRoughness { metallic, ..base } }
    }

    /// `(f · |cos θᵢ|, pdf)` at `wi` (either side).
    pub fn evaluate_pdf(&self, wo: Vec3, wi: Vec3) -> (Vec3, f32) {
        let w = self.weight;
        let (fg, pg) = self.glass.evaluate_pdf(wo, wi);
        if w >= 1.0 {
            return (fg, pg);
        }
        let (fb, pb) = if wo.z > 0.0 && wi.z > 0.0 { (self.base.f(wo, wi) * wi.z, self.base.pdf(wo, wi)) } else { (Vec3::ZERO, 0.0) };
        (fg * w + fb * (1.0 - w), pg * w + pb * (1.0 - w))
    }

    /// Draws `wi`: the interface with probability `w`, the BRDF otherwise (the number `u.x`
    /// rescaled for the chosen one's use).
    pub fn sample(&self, wo: Vec3, u: Vec2) -> Option<BsdfSample> {
        let w = self.weight;
        if w >= 1.0 {
            return self.glass.sample(wo, u);
        }
        let glass = u.x < w;
        let s = if glass {
            self.glass.sample(wo, Vec2::new(u.x / w, u.y))?
        } else {
            super::Bsdf::MetallicRoughness(self.base).sample(wo, Vec2::new(((u.x - w) / (1.0 - w)).min(1.0 - f32::EPSILON), u.y))?
        };
        if glass && self.glass.is_smooth() {
            return Some(s);
        }
        let (f, pdf) = self.evaluate_pdf(wo, s.wi);
        (pdf > 0.0 && pdf.is_finite() && f.is_finite()).then(|| BsdfSample { wi: s.wi, weight: f / pdf, pdf })
    }
}
