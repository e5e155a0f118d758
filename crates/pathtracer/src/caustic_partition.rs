//! The partition of path space between the path tracer ([`crate::integrator`]) and the caustic
//! light tracer ([`crate::caustics`]): every path is estimated by exactly one of them, so no MIS
//! weights are needed.
//!
//! A *caustic path* `camera → x₁ → … → x_n → punctual light` has `2 ≤ n ≤`
//! [`MAX_CAUSTIC_VERTICES`] scattering vertices, `x_n` of a *caster* material and `x₁ … x_{n−1}`
//! (`x₁` the first surface the camera ray hits) of materials that are not *sharp*:
//! - a caster's specular lobe can be narrow and bright: GGX `α <` [`CASTER_ALPHA`] and
//!   `F0 / α ≥` [`CASTER_F0_PER_ALPHA`] ([`is_caster`]);
//! - a sharp material is a metallic caster ([`is_sharp`]): its whole reflection is that narrow
//!   lobe, which the path tracer samples well and a light tracer could not connect through.
//!   A transmissive material (`KHR_materials_transmission`) is sharp and never a caster:
//!   the light tracer does not refract, and connects through no glass.
//!
//! The path tracer leaves out the punctual lights' next-event estimate at such an `x_n`
//! ([`CausticVertices::is_caustic_vertex`]); the light tracer estimates exactly that term.
//! Everything else (longer paths, emissive triangles, the environment) stays with the path
//! tracer.

use crate::scene::{Material, Scene, Texture};

/// GGX `α` below which a reflecting material can be a caster (roughness ≈ 0.45), see
/// [`is_caster`]. Why not lower: `docs/renderer.md`.
pub const CASTER_ALPHA: f32 = 0.2;
/// Least `F0 / α` of a caster (see [`is_caster`]).
pub const CASTER_F0_PER_ALPHA: f32 = 2.0;
/// Most vertices of a caustic path (the caster included): longer ones stay with the path
/// tracer.
pub const MAX_CAUSTIC_VERTICES: u32 = 4;

/// Whether a material is a caster: its sharpest specular lobe
/// ([`Material::sharpest_specular_lobe`]) can be narrow (GGX `α <` [`CASTER_ALPHA`]) and bright
/// for its width (`F0 / α ≥` [`CASTER_F0_PER_ALPHA`]).
///
/// Why the second rule: the path tracer's variance for a caustic grows like `(F0 / α)²`, the
/// light tracer's cost is the same for every caster (`docs/renderer.md`).
pub fn is_caster(material: &Material, textures: &[Texture]) -> bool {
    !material.transmits()
        && material.sharpest_specular_lobe(textures).is_some_and(|lobe| lobe.alpha < CASTER_ALPHA && lobe.f0 >= CASTER_F0_PER_ALPHA * lobe.alpha)
}

/// Whether a caster is sharp: metallic, so that its whole reflection is the narrow lobe; or
/// whether the material transmits.
pub fn is_sharp(material: &Material, textures: &[Texture]) -> bool {
    material.transmits() || (material.metallic_factor > 0.0 && is_caster(material, textures))
}

/// Which of a scene's materials are casters and which are sharp: the questions the path tracer
/// and the light tracer ask per vertex.
#[derive(Clone, Debug, Default)]
pub struct CausticVertices {
    caster: Vec<bool>,
    sharp: Vec<bool>,
}

impl CausticVertices {
    /// The answers for every material of `scene`.
    pub fn new(scene: &Scene) -> Self {
        let caster = scene.materials.iter().map(|m| is_caster(m, &scene.textures)).collect();
        let sharp = scene.materials.iter().map(|m| is_sharp(m, &scene.textures)).collect();
        Self { caster, sharp }
    }

    /// Whether material `m` is a caster.
    #[inline]
    pub fn is_caster(&self, m: u32) -> bool {
        self.caster.get(m as usize).copied().unwrap_or(false)
    }

    /// Whether material `m` is sharp (a light path stops there; a caustic path has none
    /// before its caster).
    #[inline]
    pub fn is_sharp(&self, m: u32) -> bool {
        self.sharp.get(m as usize).copied().unwrap_or(true)
    }

    /// Whether the path tracer leaves out the punctual lights' estimate at its vertex
    /// `vertex` (1-based: the camera ray's hit is vertex 1) of material `m`, when every vertex
    /// before it is not sharp: a caustic path of `vertex` vertices, which the light tracer
    /// estimates.
    #[inline]
    pub fn is_caustic_vertex(&self, vertex: u32, m: u32) -> bool {
        (2..=MAX_CAUSTIC_VERTICES).contains(&vertex) && self.is_caster(m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn casters_are_narrow_bright_lobes_and_sharp_ones_are_metal() {
        let m = |metallic: f32, roughness: f32| Material { metallic_factor: metallic, roughness_factor: roughness, ..Material::gltf_default() };
        // Metals: narrow enough (α < 0.2, roughness < 0.447) is bright enough.
        assert!(is_caster(&m(1.0, 0.05), &[]) && is_sharp(&m(1.0, 0.05), &[]));
        assert!(is_caster(&m(1.0, 0.44), &[]));
        assert!(!is_caster(&m(1.0, 0.45), &[]));
        // A dark metal's lobe is dim: F0 0.05 needs α ≤ 0.025.
        let dark = Material { base_color_factor: glam::Vec4::new(0.05, 0.05, 0.05, 1.0), ..m(1.0, 0.2) };
        assert!(!is_caster(&dark, &[]));
        // Dielectrics (F0 0.04): only below α = 0.02 (roughness 0.14), and never sharp.
        assert!(is_caster(&m(0.0, 0.05), &[]) && !is_sharp(&m(0.0, 0.05), &[]));
        assert!(!is_caster(&m(0.0, 0.2), &[]));
        // No specular layer, no caster.
        assert!(!is_caster(&Material { specular_factor: 0.0, ..m(0.0, 0.0) }, &[]));
    }
}
