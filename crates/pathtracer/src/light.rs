//! Lights in physical units: the glTF punctual lights (point, spot, directional), emissive
//! triangles, and a constant environment.
//!
//! - Point: intensity `I` (W/sr); at distance `r` the incident radiance is a delta whose
//!   irradiance on a surface with normal `n` is `E = I · cos θ / r²`.
//! - Spot: a point light times glTF's smooth cone falloff
//!   `a(cd) = clamp((cd − cos θ_outer) / (cos θ_inner − cos θ_outer), 0, 1)²`, with `cd` the
//!   cosine between the spot axis and the direction to the point ([`spot_falloff`]).
//! - Directional: illuminance `E` (lux); irradiance `E · cos θ`.
//! - `range` (glTF) is a hard cutoff: no light beyond it.
//! - Emissive triangles: area lights of radiance `Le = emissive × emissiveTexture`, emitting
//!   from the front face (both faces when double-sided). [`EmissiveTriangles`] picks a
//!   triangle with probability proportional to its power proxy `area × luminance(emissive
//!   factor) × sides` (a CDF, binary search), then a uniform point on it; the solid-angle
//!   density at the receiver is `pmf / area · r² / |cos θ_light|`.
//! - [`Environment`]: constant radiance from every direction, sampled uniformly on the
//!   sphere (`pdf = 1/4π`).

// Negated comparisons (`!(x > 0.0)`) are deliberate: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use crate::sampler::{sample_uniform_sphere, sample_uniform_triangle};
use crate::scene::{Light, Scene};
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// Rec. 709 luminance of linear RGB.
#[inline]
pub fn luminance(c: Vec3) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

/// glTF's spot cone attenuation for `cos_angle` between the spot axis and the direction to
/// the lit point: `clamp((cd − cos_outer) / max(1e-3, cos_inner − cos_outer), 0, 1)²`
/// (the formula in the `KHR_lights_punctual` specification).
pub fn spot_falloff(cos_angle: f32, inner_cone_angle: f32, outer_cone_angle: f32) -> f32 {
    let cos_outer = outer_cone_angle.cos();
    let cos_inner = inner_cone_angle.cos();
    let scale = 1.0 / (cos_inner - cos_outer).max(1e-3);
    let a = ((cos_angle - cos_outer) * scale).clamp(0.0, 1.0);
    a * a
}

/// Incident light from a punctual light at a point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PunctualIncidence {
    /// Unit direction from the point towards the light.
    pub wi: Vec3,
    /// Distance to the light (`f32::INFINITY` for directional lights).
    pub distance: f32,
    /// Irradiance at normal incidence: `I · falloff / r²` or the directional illuminance.
    /// Multiply by the cosine-weighted BSDF (which includes `cos θ`) to get radiance.
    pub irradiance: Vec3,
}

/// The light arriving at `p` (local frame) from a punctual light, or `None` when it
/// contributes nothing there (outside the cone or range, at the light's position).
pub fn punctual_incidence(light: &Light, p: Vec3) -> Option<PunctualIncidence> {
    match *light {
        Light::Point { position, intensity, range } => {
            let d = position - p;
            let r2 = d.length_squared();
            let r = r2.sqrt();
            if !(r2 > 0.0) || range.is_some_and(|rg| r > rg) {
                return None;
            }
            Some(PunctualIncidence { wi: d / r, distance: r, irradiance: intensity / r2 })
        }
        Light::Spot { position, direction, intensity, inner_cone_angle, outer_cone_angle, range } => {
            let d = position - p;
            let r2 = d.length_squared();
            let r = r2.sqrt();
            if !(r2 > 0.0) || range.is_some_and(|rg| r > rg) {
                return None;
            }
            let wi = d / r;
            let falloff = spot_falloff(direction.dot(-wi), inner_cone_angle, outer_cone_angle);
            if falloff <= 0.0 {
                return None;
            }
            Some(PunctualIncidence { wi, distance: r, irradiance: intensity * (falloff / r2) })
        }
        Light::Directional { direction, illuminance } => {
            let wi = -direction.normalize_or_zero();
            if wi == Vec3::ZERO {
                return None;
            }
            Some(PunctualIncidence { wi, distance: f32::INFINITY, irradiance: illuminance })
        }
    }
}

/// A constant environment: radiance `radiance` from every direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Environment {
    /// Linear RGB radiance.
    pub radiance: Vec3,
}

impl Environment {
    /// Density of [`Environment::sample`]: `1 / 4π` per steradian.
    pub const PDF: f32 = 1.0 / (4.0 * PI);
    /// Whether the environment emits anything.
    pub fn is_black(&self) -> bool {
        self.radiance.max_element() <= 0.0
    }
    /// A uniformly distributed direction and its density.
    pub fn sample(&self, u: Vec2) -> (Vec3, f32) {
        (sample_uniform_sphere(u), Self::PDF)
    }
}

/// A point sampled on an emissive triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EmitterSample {
    /// Triangle index.
    pub prim: u32,
    /// Barycentrics of the point.
    pub b: [f32; 3],
    /// Probability of having picked this triangle.
    pub pmf: f32,
    /// Area of the triangle.
    pub area: f32,
}

/// The table of emissive triangles, sampled proportionally to power.
#[derive(Clone, Debug, Default)]
pub struct EmissiveTriangles {
    prims: Vec<u32>,
    /// Inclusive normalised CDF over `prims`.
    cdf: Vec<f32>,
    /// Probability of each scene triangle (0 for non-emissive ones).
    pmf_by_prim: Vec<f32>,
    area_by_prim: Vec<f32>,
    total_power: f64,
}

impl EmissiveTriangles {
    /// Collects the emissive triangles of `scene` (indices assumed validated).
    pub fn build(scene: &Scene) -> Self {
        let mesh = &scene.mesh;
        let n = mesh.indices.len();
        let mut prims = Vec::new();
        let mut weights = Vec::new();
        let mut area_by_prim = vec![0.0f32; n];
        for (k, idx) in mesh.indices.iter().enumerate() {
            let Some(m) = mesh.material.get(k).and_then(|&m| scene.materials.get(m as usize)) else { continue };
            if !m.is_emissive() {
                continue;
            }
            let p = idx.map(|i| mesh.positions[i as usize]);
            let area = 0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length();
            if !(area > 0.0) || !area.is_finite() {
                continue;
            }
            area_by_prim[k] = area;
            let sides = if m.double_sided { 2.0 } else { 1.0 };
            let w = area as f64 * luminance(m.emissive.max(Vec3::ZERO)) as f64 * sides * std::f64::consts::PI;
            if w > 0.0 && w.is_finite() {
                prims.push(k as u32);
                weights.push(w);
            }
        }
        let total: f64 = weights.iter().sum();
        let mut cdf = Vec::with_capacity(weights.len());
        let mut pmf_by_prim = vec![0.0f32; n];
        let mut acc = 0.0f64;
        for (i, &w) in weights.iter().enumerate() {
            acc += w;
            cdf.push((acc / total) as f32);
            pmf_by_prim[prims[i] as usize] = (w / total) as f32;
        }
        if let Some(last) = cdf.last_mut() {
            *last = 1.0;
        }
        Self { prims, cdf, pmf_by_prim, area_by_prim, total_power: total }
    }

    /// Whether there are no emissive triangles.
    pub fn is_empty(&self) -> bool {
        self.prims.is_empty()
    }

    /// Number of emissive triangles.
    pub fn len(&self) -> usize {
        self.prims.len()
    }

    /// Sum of the power proxies (W, using the emissive factors, ignoring textures).
    pub fn total_power(&self) -> f64 {
        self.total_power
    }

    /// Probability of picking triangle `prim`.
    pub fn pmf(&self, prim: u32) -> f32 {
        self.pmf_by_prim.get(prim as usize).copied().unwrap_or(0.0)
    }

    /// Area of triangle `prim` (0 for non-emissive ones).
    pub fn area(&self, prim: u32) -> f32 {
        self.area_by_prim.get(prim as usize).copied().unwrap_or(0.0)
    }

    /// Picks a triangle with `u_select` and a uniform point on it with `u_point`.
    pub fn sample(&self, u_select: f32, u_point: Vec2) -> Option<EmitterSample> {
        if self.prims.is_empty() {
            return None;
        }
        let i = self.cdf.partition_point(|&c| c <= u_select).min(self.prims.len() - 1);
        let prim = self.prims[i];
        Some(EmitterSample { prim, b: sample_uniform_triangle(u_point), pmf: self.pmf(prim), area: self.area(prim) })
    }

    /// Solid-angle density at a receiver of sampling point on `prim` at `distance` whose
    /// emitter-side cosine is `cos_light`: `pmf / area · r² / |cos|`.
    pub fn pdf_solid_angle(&self, prim: u32, distance: f32, cos_light: f32) -> f32 {
        let pmf = self.pmf(prim);
        let area = self.area(prim);
        let c = cos_light.abs();
        if pmf <= 0.0 || area <= 0.0 || c <= 0.0 {
            return 0.0;
        }
        pmf / area * distance * distance / c
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spot_falloff_matches_gltf_formula() {
        let (inner, outer) = (0.2f32, 0.5f32);
        assert_eq!(spot_falloff(1.0, inner, outer), 1.0);
        assert_eq!(spot_falloff(0.3f32.cos(), inner, 0.3), 0.0);
        let mid = 0.5 * (inner.cos() + outer.cos());
        assert!((spot_falloff(mid, inner, outer) - 0.25).abs() < 1e-5);
        assert_eq!(spot_falloff(0.6f32.cos(), inner, outer), 0.0);
    }

    #[test]
    fn point_light_is_inverse_square_with_range_cutoff() {
        let l = Light::Point { position: Vec3::new(0.0, 2.0, 0.0), intensity: Vec3::splat(8.0), range: Some(3.0) };
        let s = punctual_incidence(&l, Vec3::ZERO).unwrap();
        assert_eq!(s.wi, Vec3::Y);
        assert!((s.irradiance - Vec3::splat(2.0)).abs().max_element() < 1e-6);
        assert!(punctual_incidence(&l, Vec3::new(0.0, -2.0, 0.0)).is_none());
        let d = Light::Directional { direction: -Vec3::Y, illuminance: Vec3::splat(3.0) };
        let s = punctual_incidence(&d, Vec3::ZERO).unwrap();
        assert_eq!((s.wi, s.distance, s.irradiance), (Vec3::Y, f32::INFINITY, Vec3::splat(3.0)));
    }
}
