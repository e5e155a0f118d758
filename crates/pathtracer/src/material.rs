//! Materials: turning a glTF [`Material`] at a surface point into a BSDF plus emission, and
//! the BSDF verbs `evaluate` / `sample` / `pdf` (Mitsuba's interface).
//!
//! Conventions: directions `wo` (towards the viewer) and `wi` (towards the light) point away
//! from the surface and are expressed in the local shading [`Frame`] whose `n` (z axis) is
//! the shading normal already flipped to the side the ray came from. `evaluate` returns
//! `f(wo, wi) · |cos θᵢ|` (the cosine-weighted BSDF), `sample` returns the weight
//! `f · |cos θᵢ| / pdf`, and `pdf` is per unit solid angle.
//!
//! Current shading (this issue): every material is [`Bsdf::Diffuse`] with its base colour;
//! metallic, roughness, normal and occlusion maps are carried in the scene but ignored. The
//! glTF metallic-roughness BRDF (GGX distribution, Smith masking, Schlick Fresnel, mixed by
//! metallic) is meant to become a second variant of [`Bsdf`], with the same three verbs, at
//! which point [`Bsdf::is_view_dependent`] becomes true for it.
//!
//! Alpha: `Mask` is honoured in intersection (see `accel`); `Blend` is treated as opaque.
//! Sidedness: a single-sided triangle hit from behind is not hit at all (glTF back-face
//! culling), so it neither occludes nor emits from behind; double-sided triangles shade
//! with the normal flipped towards the incoming ray and emit from both sides.

use crate::geometry::Frame;
use crate::sampler::sample_cosine_hemisphere;
use crate::scene::{Material, Texture};
use crate::texture::sample_ref;
use glam::{Vec2, Vec3, Vec4};
use std::f32::consts::FRAC_1_PI;

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

impl Bsdf {
    /// `f(wo, wi) · |cos θᵢ|` in the local frame (see the variant docs for `f`).
    pub fn evaluate(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        match *self {
            Bsdf::Diffuse { albedo } => {
                if wo.z <= 0.0 || wi.z <= 0.0 {
                    Vec3::ZERO
                } else {
                    albedo * (FRAC_1_PI * wi.z)
                }
            }
        }
    }

    /// Draws `wi` given `wo` and two uniform numbers. `None` when no direction can be
    /// produced (e.g. `wo` below the surface).
    pub fn sample(&self, wo: Vec3, u: Vec2) -> Option<BsdfSample> {
        match *self {
            Bsdf::Diffuse { albedo } => {
                if wo.z <= 0.0 {
                    return None;
                }
                let wi = sample_cosine_hemisphere(u);
                let pdf = wi.z * FRAC_1_PI;
                if pdf <= 0.0 {
                    return None;
                }
                Some(BsdfSample { wi, weight: albedo, pdf })
            }
        }
    }

    /// Solid-angle density with which [`Bsdf::sample`] draws `wi`.
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        match *self {
            Bsdf::Diffuse { .. } => {
                if wo.z <= 0.0 || wi.z <= 0.0 { 0.0 } else { wi.z * FRAC_1_PI }
            }
        }
    }

    /// Whether outgoing radiance depends on the viewing direction (false for Lambertian).
    pub fn is_view_dependent(&self) -> bool {
        match self {
            Bsdf::Diffuse { .. } => false,
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
pub fn base_color(material: &Material, textures: &[Texture], attr: &SurfaceAttributes) -> Vec4 {
    let mut c = material.base_color_factor * attr.color;
    if let Some(r) = &material.base_color_texture {
        c *= sample_ref(textures, r, attr.uv);
    }
    c
}

/// Emitted radiance: `emissive (× strength) × emissiveTexture`.
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

/// Resolves a glTF material at a surface point into the BSDF used now (Lambertian with the
/// base colour, clamped to [0, 1]) and its emission.
pub fn resolve(material: &Material, textures: &[Texture], attr: &SurfaceAttributes) -> SurfaceMaterial {
    let albedo = base_color(material, textures, attr).truncate().clamp(Vec3::ZERO, Vec3::ONE);
    let albedo = if albedo.is_finite() { albedo } else { Vec3::ZERO };
    SurfaceMaterial { bsdf: Bsdf::Diffuse { albedo }, emission: emission(material, textures, attr) }
}

/// Whether a glTF material is shaded view-dependently by the current renderer. False for
/// every material while only Lambertian shading exists.
pub fn is_view_dependent(_material: &Material) -> bool {
    false
}

/// The shading frame for a hit seen from direction `-ray_dir`: the geometric normal and the
/// shading normal are both flipped to face the incoming ray (the shading normal is also
/// made to agree in side with the geometric one).
pub fn facing_frame(ng: Vec3, ns: Vec3, ray_dir: Vec3) -> (Vec3, Frame) {
    let ng = if ng.dot(ray_dir) > 0.0 { -ng } else { ng };
    let mut ns = if ns.is_finite() && ns.length_squared() > 0.0 { ns.normalize() } else { ng };
    if ns.dot(ng) < 0.0 {
        ns = -ns;
    }
    (ng, Frame::from_normal(ns))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampler::Sampler;
    use crate::scene::{Filter, TextureRef, Wrap};

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
    fn base_color_is_factor_times_texture_times_vertex_color() {
        let mut m = Material::gltf_default();
        m.base_color_factor = Vec4::new(0.5, 1.0, 1.0, 1.0);
        m.base_color_texture = Some(TextureRef { texture: 0, tex_coord: 1, wrap_s: Wrap::Repeat, wrap_t: Wrap::Repeat, filter: Filter::Nearest });
        m.emissive = Vec3::new(2.0, 0.0, 1.0);
        let tex = vec![Texture { width: 1, height: 1, texels: vec![Vec4::new(1.0, 0.5, 1.0, 0.25)] }];
        let attr = SurfaceAttributes { uv: [Vec2::ZERO, Vec2::new(0.3, 0.3)], color: Vec4::new(1.0, 1.0, 0.5, 1.0) };
        assert_eq!(base_color(&m, &tex, &attr), Vec4::new(0.5, 0.5, 0.5, 0.25));
        let r = resolve(&m, &tex, &attr);
        assert_eq!(r.bsdf, Bsdf::Diffuse { albedo: Vec3::splat(0.5) });
        assert_eq!(r.emission, Vec3::new(2.0, 0.0, 1.0));
    }

    #[test]
    fn facing_frame_flips_towards_the_ray() {
        let (ng, f) = facing_frame(Vec3::Z, Vec3::new(0.1, 0.0, 1.0), Vec3::new(0.0, 0.0, 1.0));
        assert_eq!(ng, -Vec3::Z);
        assert!(f.n.z < 0.0);
    }
}
