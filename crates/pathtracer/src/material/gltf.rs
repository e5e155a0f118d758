//! A glTF material at a surface point and as a whole. At a point: base colour = factor ×
//! texture × COLOR_0; metallic = factor × texture B, roughness = factor × texture G (glTF
//! §3.9.2); specular weight = factor × texture A, specular colour = factor × texture RGB
//! (`KHR_materials_specular`), each lookup through the reference's UV set and
//! `KHR_texture_transform` ([`crate::texture::sample_ref`]); clearcoat = factor × texture R,
//! its roughness = factor × texture G; sheen colour = factor × texture RGB, its roughness =
//! factor × texture A ([`layers`]); [`resolve`] turns them into the [`Bsdf`] and emission. As a whole: whether a material is view-dependent, its smoothest
//! texel and brightest dielectric layer.

// Negated comparisons (`!(x > 0.0)`) are deliberate: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::{Bsdf, DIELECTRIC_F0, DielectricFresnel, Layered, MetallicRoughness, Transmissive, f0_from_ior};
use crate::scene::{Material, Scene, Texture};
use crate::texture::sample_ref;
use glam::{Vec2, Vec3, Vec4};

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

/// `KHR_materials_transmission` at a point: `transmissionFactor × transmissionTexture.R`,
/// clamped to [0, 1].
#[inline]
pub fn transmission(material: &Material, textures: &[Texture], attr: &SurfaceAttributes) -> f32 {
    let mut t = material.transmission_factor;
    if let Some(r) = &material.transmission_texture {
        t *= sample_ref(textures, r, attr.uv).x;
    }
    if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 }
}

/// `KHR_materials_clearcoat` and `_sheen` at a point: `(clearcoat, clearcoat roughness, sheen
/// colour, sheen roughness)`, each factor × its texture's channel (clearcoat R, its roughness
/// G, sheen colour RGB, its roughness A), clamped to [0, 1]; zeros for an absent layer.
#[inline]
pub fn layers(material: &Material, textures: &[Texture], attr: &SurfaceAttributes) -> (f32, f32, Vec3, f32) {
    let unit = |x: f32| if x.is_finite() { x.clamp(0.0, 1.0) } else { 0.0 };
    let (mut c, mut cr) = (0.0, 0.0);
    if let Some(k) = &material.clearcoat {
        (c, cr) = (k.factor, k.roughness_factor);
        if let Some(r) = &k.texture {
            c *= sample_ref(textures, r, attr.uv).x;
        }
        if let Some(r) = &k.roughness_texture {
            cr *= sample_ref(textures, r, attr.uv).y;
        }
    }
    let (mut s, mut sr) = (Vec3::ZERO, 0.0);
    if let Some(k) = &material.sheen {
        (s, sr) = (k.color_factor, k.roughness_factor);
        if let Some(r) = &k.color_texture {
            s *= sample_ref(textures, r, attr.uv).truncate();
        }
        if let Some(r) = &k.roughness_texture {
            sr *= sample_ref(textures, r, attr.uv).w;
        }
    }
    let s = if s.is_finite() { s.clamp(Vec3::ZERO, Vec3::ONE) } else { Vec3::ZERO };
    (unit(c), unit(cr), s, unit(sr))
}

/// Resolves a glTF material at a surface point into its BSDF and emission:
/// [`Bsdf::MetallicRoughness`] with base colour, metallic, roughness (factors × textures) and
/// the dielectric's Fresnel endpoints ([`dielectric_fresnel`]), or [`Bsdf::Diffuse`] with the
/// base colour when metallic and the specular weight (`F90`) are both 0 (where the two are
/// identical); [`Bsdf::Transmissive`] where the transmission ([`transmission`]) is > 0,
/// thin-walled without `KHR_materials_volume`; [`Bsdf::Layered`] over the opaque ones where
/// a clearcoat or sheen layer ([`layers`]) is non-zero (the importer warns that layers over
/// transmission are not rendered).
#[inline(always)]
pub fn resolve(material: &Material, textures: &[Texture], attr: &SurfaceAttributes) -> SurfaceMaterial {
    let albedo = base_color(material, textures, attr).truncate().clamp(Vec3::ZERO, Vec3::ONE);
    let albedo = if albedo.is_finite() { albedo } else { Vec3::ZERO };
    let (metallic, roughness) = metallic_roughness(material, textures, attr);
    let fresnel = dielectric_fresnel(material, textures, attr);
    let transmission = if material.transmits() { transmission(material, textures, attr) } else { 0.0 };
    let bsdf = if transmission > 0.0 {
        let base = MetallicRoughness::with_fresnel(albedo, metallic, roughness, fresnel);
        Bsdf::Transmissive(Transmissive::new(base, roughness, material.ior, transmission, material.volume.is_none()))
    } else if metallic <= 0.0 && fresnel.f90 <= 0.0 {
        Bsdf::Diffuse { albedo }
    } else {
        Bsdf::MetallicRoughness(MetallicRoughness::with_fresnel(albedo, metallic, roughness, fresnel))
    };
    let bsdf = if transmission <= 0.0 && (material.clearcoat.is_some() || material.sheen.is_some()) {
        let (c, cr, s, sr) = layers(material, textures, attr);
        match bsdf {
            Bsdf::Diffuse { .. } | Bsdf::MetallicRoughness(_) if c > 0.0 || s.max_element() > 0.0 => {
                Bsdf::Layered(Layered::new(MetallicRoughness::with_fresnel(albedo, metallic, roughness, fresnel), c, cr, s, sr))
            }
            other => other,
        }
    } else {
        bsdf
    };
    SurfaceMaterial { bsdf, emission: emission(material, textures, attr) }
}

/// The material resolved once for every point of every triangle that uses it, when nothing
/// [`resolve`] reads varies over the surface: no base-colour, metallic-roughness, specular,
/// specular-colour, transmission, clearcoat, sheen or emissive texture, and (`vertex_colors`
/// false) no COLOR_0, whose
/// absence [`crate::integrator::surface_attributes`] reports as exactly white. `None` when
/// something varies. Equal, bit for bit, to `resolve` at any point of such a material.
pub fn uniform_surface(material: &Material, vertex_colors: bool) -> Option<SurfaceMaterial> {
    let varies = vertex_colors
        || material.base_color_texture.is_some()
        || material.metallic_roughness_texture.is_some()
        || material.specular_texture.is_some()
        || material.specular_color_texture.is_some()
        || material.transmission_texture.is_some()
        || material.clearcoat.is_some_and(|c| c.texture.is_some() || c.roughness_texture.is_some())
        || material.sheen.is_some_and(|s| s.color_texture.is_some() || s.roughness_texture.is_some())
        || material.emissive_texture.is_some();
    (!varies).then(|| resolve(material, &[], &SurfaceAttributes { uv: [Vec2::ZERO; 2], color: Vec4::ONE }))
}

/// Perceptual roughness below which a dielectric's 4 % specular layer counts as
/// view-dependent (see [`is_view_dependent`]).
pub const VIEW_DEPENDENT_ROUGHNESS: f32 = 0.6;

/// Whether a glTF material's outgoing radiance depends noticeably on the viewing direction:
/// true when it transmits (`KHR_materials_transmission`), has a clear coat or a sheen, when it can be metallic (metallic factor > 0: the whole reflection is a GGX lobe),
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
    // What is seen through a transmissive surface moves with the viewer at any roughness; a
    // clear coat and a sheen are view-dependent lobes at any roughness.
    if material.transmits() || material.clearcoat.is_some() || material.sheen.is_some() {
        return true;
    }
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
