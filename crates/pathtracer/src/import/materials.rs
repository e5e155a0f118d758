//! glTF materials → [`Material`]: factors, textures with their samplers, emissive strength.

use glam::{Vec3, Vec4};
use gltf::texture::{MagFilter, WrappingMode};

use super::Importer;
use crate::error::PathTracerError;
use crate::scene::{AlphaMode, Filter, Material, TextureRef, Wrap};

fn wrap(mode: WrappingMode) -> Wrap {
    match mode {
        WrappingMode::ClampToEdge => Wrap::ClampToEdge,
        WrappingMode::MirroredRepeat => Wrap::MirroredRepeat,
        WrappingMode::Repeat => Wrap::Repeat,
    }
}

fn finite_or(v: f32, default: f32) -> f32 {
    if v.is_finite() { v } else { default }
}

impl Importer<'_> {
    /// A [`TextureRef`] for glTF texture `texture` read through UV set `tex_coord`.
    fn texture_ref(
        &mut self,
        texture: gltf::Texture<'_>,
        tex_coord: u32,
        srgb: bool,
        what: &str,
    ) -> Result<TextureRef, PathTracerError> {
        let sampler = texture.sampler();
        let image = texture.source().index();
        let index = self.texture_for_image(image, srgb)?;
        let tex_coord = if tex_coord > 1 {
            self.warn(format!("{what}: TEXCOORD_{tex_coord} is not supported; using TEXCOORD_0"));
            0
        } else {
            tex_coord
        };
        Ok(TextureRef {
            texture: index,
            tex_coord,
            wrap_s: wrap(sampler.wrap_s()),
            wrap_t: wrap(sampler.wrap_t()),
            filter: match sampler.mag_filter() {
                Some(MagFilter::Nearest) => Filter::Nearest,
                Some(MagFilter::Linear) | None => Filter::Linear,
            },
        })
    }

    /// Builds [`Importer::materials`] from every glTF material, in file order (so the glTF
    /// index is the scene index).
    pub(super) fn load_materials(&mut self) -> Result<(), PathTracerError> {
        let doc = std::rc::Rc::clone(&self.doc);
        for material in doc.materials() {
            let i = material.index().unwrap_or(self.materials.len());
            let m = self.material(&material, i)?;
            self.materials.push(m);
        }
        Ok(())
    }

    fn material(&mut self, material: &gltf::Material<'_>, i: usize) -> Result<Material, PathTracerError> {
        let what = format!("material {i}{}", material.name().map(|n| format!(" ('{n}')")).unwrap_or_default());
        let pbr = material.pbr_metallic_roughness();
        let base_color_texture = match pbr.base_color_texture() {
            Some(info) => Some(self.texture_ref(info.texture(), info.tex_coord(), true, &what)?),
            None => None,
        };
        let metallic_roughness_texture = match pbr.metallic_roughness_texture() {
            Some(info) => Some(self.texture_ref(info.texture(), info.tex_coord(), false, &what)?),
            None => None,
        };
        let normal_texture = match material.normal_texture() {
            Some(n) => Some((self.texture_ref(n.texture(), n.tex_coord(), false, &what)?, finite_or(n.scale(), 1.0))),
            None => None,
        };
        let occlusion_texture = match material.occlusion_texture() {
            Some(o) => {
                Some((self.texture_ref(o.texture(), o.tex_coord(), false, &what)?, finite_or(o.strength(), 1.0)))
            }
            None => None,
        };
        let emissive_texture = match material.emissive_texture() {
            Some(info) => Some(self.texture_ref(info.texture(), info.tex_coord(), true, &what)?),
            None => None,
        };
        let strength = material.emissive_strength().unwrap_or(1.0);
        if !(strength.is_finite() && strength >= 0.0) {
            return Err(self.error(format!("{what}: emissiveStrength {strength} must be finite and non-negative")));
        }
        let emissive = Vec3::from(material.emissive_factor()) * strength;
        let base_color_factor = Vec4::from(pbr.base_color_factor());
        if !emissive.is_finite() || !base_color_factor.is_finite() {
            return Err(self.error(format!("{what}: non-finite baseColorFactor or emissiveFactor")));
        }
        let alpha_mode = match material.alpha_mode() {
            gltf::material::AlphaMode::Opaque => AlphaMode::Opaque,
            gltf::material::AlphaMode::Mask => AlphaMode::Mask { cutoff: finite_or(material.alpha_cutoff().unwrap_or(0.5), 0.5) },
            gltf::material::AlphaMode::Blend => AlphaMode::Blend,
        };
        Ok(Material {
            name: material.name().map(str::to_string),
            base_color_factor,
            base_color_texture,
            metallic_factor: finite_or(pbr.metallic_factor(), 1.0).clamp(0.0, 1.0),
            roughness_factor: finite_or(pbr.roughness_factor(), 1.0).clamp(0.0, 1.0),
            metallic_roughness_texture,
            normal_texture,
            occlusion_texture,
            emissive,
            emissive_texture,
            alpha_mode,
            double_sided: material.double_sided(),
            specular_factor: 1.0,
        })
    }
}
