//! The Lambertian model ([`super::Bsdf::Diffuse`]): `f(wo, wi) = ρ / π` for `wi` in the upper
//! hemisphere, 0 below; cosine-weighted sampling with `pdf = cos θᵢ / π`, so the sample weight
//! is exactly `ρ`. Parameter: albedo `ρ` (linear RGB, the base colour). Its lane forms are the
//! same operations on one lane of [`SampleLane`] (see the [`super`] module docs).

use super::SampleLane;
use glam::{Vec2, Vec3};
use std::f32::consts::FRAC_1_PI;

/// `f · cos θᵢ = ρ cos θᵢ / π` for `wi` above the surface (the caller tests the sides).
#[inline(always)]
pub(super) fn evaluate(albedo: Vec3, wi: Vec3) -> Vec3 {
    albedo * (FRAC_1_PI * wi.z)
}

/// `pdf = cos θᵢ / π` for `wi` above the surface (the caller tests the sides).
#[inline(always)]
pub(super) fn pdf(wi: Vec3) -> f32 {
    wi.z * FRAC_1_PI
}

/// The lane record of albedo `albedo` seen from `wo` with the numbers `u` (the
/// metallic-roughness numbers of a lane that has no specular lobe).
#[inline(always)]
pub(super) fn lane(albedo: Vec3, wo: Vec3, u: Vec2) -> SampleLane {
    SampleLane { diffuse: true, rho: albedo, metallic: 0.0, alpha: 1.0, f0: Vec3::ZERO, f90: 0.0, wo, ps: 0.0, sd_wo: 1.0, u }
}

/// What the model computes once from `wo` (`(P_s, Smith denominator)` of the
/// metallic-roughness model): none, `(0, 1)`.
pub(super) const WO_TERMS: (f32, f32) = (0.0, 1.0);

/// One lane's `(f · cos θᵢ, pdf)` at `wi` (the caller zeroes it below the surface).
#[inline(always)]
pub(super) fn evaluate_pdf_lane(rho: Vec3, wi: Vec3) -> (Vec3, f32) {
    (evaluate(rho, wi), pdf(wi))
}

/// One lane's sample `(wi, weight, pdf, valid)` for the cosine-weighted direction `wi` its
/// numbers give ([`crate::sampler::sample_cosine_hemisphere`]).
#[inline(always)]
pub(super) fn sample_lane(rho: Vec3, wo: Vec3, wi: Vec3) -> (Vec3, Vec3, f32, bool) {
    let pdf = pdf(wi);
    (wi, rho, pdf, !(wo.z <= 0.0) & !(pdf <= 0.0))
}
