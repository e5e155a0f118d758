//! glTF materials → [`Material`]: factors, textures with their samplers, emissive strength,
//! `KHR_materials_specular`, `KHR_materials_ior`, `KHR_materials_transmission`,
//! `KHR_materials_volume`, `KHR_materials_clearcoat`, `KHR_materials_sheen` and
//! `KHR_texture_transform` (on every texture read). The extensions
//! are read from the raw JSON (the gltf crate is built without them), with an error naming the
//! material and the field for any malformed value (an `ior` below 1 with transmission, an
//! `attenuationDistance` ≤ 0). The volume's `thicknessTexture` is a rasteriser's hint: the
//! path tracer measures the distance travelled inside, so it is not read (a warning).

use glam::{Vec2, Vec3, Vec4};
use gltf::texture::{MagFilter, WrappingMode};
use serde_json::Value;

use super::Importer;
use crate::error::PathTracerError;
use crate::scene::{AlphaMode, Clearcoat, Filter, Material, Sheen, TextureRef, UvTransform, Volume, Wrap};

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
    /// A [`TextureRef`] for glTF texture `texture` read through UV set `tex_coord`, with the
    /// `KHR_texture_transform` of the texture info `info` (its raw JSON; `slot` names it,
    /// e.g. `baseColorTexture`), whose `texCoord` overrides `tex_coord`.
    fn texture_ref(
        &mut self,
        texture: gltf::Texture<'_>,
        tex_coord: u32,
        srgb: bool,
        what: &str,
        slot: &str,
        info: &Value,
    ) -> Result<TextureRef, PathTracerError> {
        let sampler = texture.sampler();
        let image = texture.source().index();
        let index = self.texture_for_image(image, srgb)?;
        let (transform, tex_coord_override) = match info.get("extensions").and_then(|e| e.get("KHR_texture_transform")) {
            Some(t) => texture_transform(t).map_err(|e| self.error(format!("{what}: {slot}.extensions.KHR_texture_transform: {e}")))?,
            None => (None, None),
        };
        let tex_coord = tex_coord_override.unwrap_or(tex_coord);
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
            transform,
        })
    }

    /// The [`TextureRef`] of a texture info inside an extension object (`ext`, raw JSON, at
    /// key `slot`), which the gltf crate does not parse: `index` must name a texture.
    fn extension_texture_ref(
        &mut self,
        ext: &Value,
        slot: &str,
        srgb: bool,
        what: &str,
        ext_name: &str,
    ) -> Result<Option<TextureRef>, PathTracerError> {
        let Some(info) = ext.get(slot) else { return Ok(None) };
        let field = format!("{what}: {ext_name}.{slot}");
        if !info.is_object() {
            return Err(self.error(format!("{field} must be a textureInfo object")));
        }
        let index = info.get("index").and_then(Value::as_u64).ok_or_else(|| self.error(format!("{field}.index must be a texture index")))?;
        let tex_coord = match info.get("texCoord") {
            None => 0,
            Some(v) => v
                .as_u64()
                .and_then(|t| u32::try_from(t).ok())
                .ok_or_else(|| self.error(format!("{field}.texCoord must be a non-negative integer")))?,
        };
        let doc = std::rc::Rc::clone(&self.doc);
        let count = doc.textures().len();
        let texture = usize::try_from(index)
            .ok()
            .and_then(|i| doc.textures().nth(i))
            .ok_or_else(|| self.error(format!("{field}.index: texture {index} does not exist ({count} textures)")))?;
        self.texture_ref(texture, tex_coord, srgb, what, &format!("{ext_name}.{slot}"), info).map(Some)
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
        let raw = self.raw.get("materials").and_then(|m| m.get(i)).cloned().unwrap_or(Value::Null);
        let raw_pbr = raw.get("pbrMetallicRoughness").cloned().unwrap_or(Value::Null);
        let info_json = |parent: &Value, key: &str| parent.get(key).cloned().unwrap_or(Value::Null);
        let pbr = material.pbr_metallic_roughness();
        let base_color_texture = match pbr.base_color_texture() {
            Some(info) => Some(self.texture_ref(info.texture(), info.tex_coord(), true, &what, "baseColorTexture", &info_json(&raw_pbr, "baseColorTexture"))?),
            None => None,
        };
        let metallic_roughness_texture = match pbr.metallic_roughness_texture() {
            Some(info) => Some(self.texture_ref(
                info.texture(),
                info.tex_coord(),
                false,
                &what,
                "metallicRoughnessTexture",
                &info_json(&raw_pbr, "metallicRoughnessTexture"),
            )?),
            None => None,
        };
        let normal_texture = match material.normal_texture() {
            Some(n) => Some((
                self.texture_ref(n.texture(), n.tex_coord(), false, &what, "normalTexture", &info_json(&raw, "normalTexture"))?,
                finite_or(n.scale(), 1.0),
            )),
            None => None,
        };
        let occlusion_texture = match material.occlusion_texture() {
            Some(o) => Some((
                self.texture_ref(o.texture(), o.tex_coord(), false, &what, "occlusionTexture", &info_json(&raw, "occlusionTexture"))?,
                finite_or(o.strength(), 1.0),
            )),
            None => None,
        };
        let emissive_texture = match material.emissive_texture() {
            Some(info) => Some(self.texture_ref(info.texture(), info.tex_coord(), true, &what, "emissiveTexture", &info_json(&raw, "emissiveTexture"))?),
            None => None,
        };
        let extensions = raw.get("extensions").cloned().unwrap_or(Value::Null);
        let specular = self.specular(&extensions, &what)?;
        let ior = match extensions.get("KHR_materials_ior") {
            None => 1.5,
            Some(ext) => ior(ext).map_err(|e| self.error(format!("{what}: KHR_materials_ior.{e}")))?,
        };
        let (transmission_factor, transmission_texture) = self.transmission(&extensions, &what)?;
        if transmission_factor > 0.0 && ior < 1.0 {
            return Err(self.error(format!("{what}: KHR_materials_ior.ior {ior} is below 1, which a transmissive material (KHR_materials_transmission) cannot have")));
        }
        let volume = self.volume(&extensions, &what)?;
        let clearcoat = self.clearcoat(&extensions, &what)?;
        let sheen = self.sheen(&extensions, &what)?;
        if transmission_factor > 0.0 && (clearcoat.is_some() || sheen.is_some()) {
            self.warn(format!("{what}: KHR_materials_clearcoat and _sheen are not rendered over a transmissive material (KHR_materials_transmission)"));
        }
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
            specular_factor: specular.factor,
            specular_texture: specular.texture,
            specular_color_factor: specular.color_factor,
            specular_color_texture: specular.color_texture,
            ior,
            transmission_factor,
            transmission_texture,
            volume,
            clearcoat,
            sheen,
        })
    }

    /// `KHR_materials_clearcoat` of a material's raw `extensions` object: `Some` where
    /// `clearcoatFactor` is > 0 (0, the default, disables the layer).
    fn clearcoat(&mut self, extensions: &Value, what: &str) -> Result<Option<Clearcoat>, PathTracerError> {
        const EXT: &str = "KHR_materials_clearcoat";
        let Some(ext) = extensions.get(EXT) else { return Ok(None) };
        if !ext.is_object() {
            return Err(self.error(format!("{what}: {EXT} must be an object")));
        }
        let factor = self.unit_number(ext, "clearcoatFactor", 0.0, what, EXT)?;
        let roughness_factor = self.unit_number(ext, "clearcoatRoughnessFactor", 0.0, what, EXT)?;
        let texture = self.extension_texture_ref(ext, "clearcoatTexture", false, what, EXT)?;
        let roughness_texture = self.extension_texture_ref(ext, "clearcoatRoughnessTexture", false, what, EXT)?;
        let normal_texture = match self.extension_texture_ref(ext, "clearcoatNormalTexture", false, what, EXT)? {
            None => None,
            Some(r) => {
                let scale = match ext.get("clearcoatNormalTexture").and_then(|t| t.get("scale")) {
                    None => 1.0,
                    Some(v) => number(v).ok_or_else(|| self.error(format!("{what}: {EXT}.clearcoatNormalTexture.scale must be a finite number, got {v}")))?,
                };
                Some((r, scale))
            }
        };
        Ok((factor > 0.0).then_some(Clearcoat { factor, texture, roughness_factor, roughness_texture, normal_texture }))
    }

    /// `KHR_materials_sheen` of a material's raw `extensions` object: `Some` where
    /// `sheenColorFactor` is not black (black, the default, disables the layer).
    fn sheen(&mut self, extensions: &Value, what: &str) -> Result<Option<Sheen>, PathTracerError> {
        const EXT: &str = "KHR_materials_sheen";
        let Some(ext) = extensions.get(EXT) else { return Ok(None) };
        if !ext.is_object() {
            return Err(self.error(format!("{what}: {EXT} must be an object")));
        }
        let color_factor = match ext.get("sheenColorFactor") {
            None => Vec3::ZERO,
            Some(v) => numbers::<3>(v)
                .filter(|c| c.iter().all(|x| (0.0..=1.0).contains(x)))
                .map(Vec3::from)
                .ok_or_else(|| self.error(format!("{what}: {EXT}.sheenColorFactor must be three numbers in [0, 1], got {v}")))?,
        };
        let roughness_factor = self.unit_number(ext, "sheenRoughnessFactor", 0.0, what, EXT)?;
        // sheenColorTexture: sRGB colour (its RGB); sheenRoughnessTexture: data (its A channel).
        let color_texture = self.extension_texture_ref(ext, "sheenColorTexture", true, what, EXT)?;
        let roughness_texture = self.extension_texture_ref(ext, "sheenRoughnessTexture", false, what, EXT)?;
        Ok((color_factor.max_element() > 0.0).then_some(Sheen { color_factor, color_texture, roughness_factor, roughness_texture }))
    }

    /// The number at `key` of an extension object (`default` without it), which must be
    /// finite and in [0, 1]: the error names the material, the extension and the field.
    fn unit_number(&mut self, ext: &Value, key: &str, default: f32, what: &str, ext_name: &str) -> Result<f32, PathTracerError> {
        match ext.get(key) {
            None => Ok(default),
            Some(v) => number(v)
                .filter(|f| (0.0..=1.0).contains(f))
                .ok_or_else(|| self.error(format!("{what}: {ext_name}.{key} must be a number in [0, 1], got {v}"))),
        }
    }

    /// `KHR_materials_transmission` of a material's raw `extensions` object: the factor
    /// (default 0) and the texture (its R channel), `(0, None)` without it.
    fn transmission(&mut self, extensions: &Value, what: &str) -> Result<(f32, Option<TextureRef>), PathTracerError> {
        const EXT: &str = "KHR_materials_transmission";
        let Some(ext) = extensions.get(EXT) else { return Ok((0.0, None)) };
        if !ext.is_object() {
            return Err(self.error(format!("{what}: {EXT} must be an object")));
        }
        let factor = match ext.get("transmissionFactor") {
            None => 0.0,
            Some(v) => number(v)
                .filter(|f| (0.0..=1.0).contains(f))
                .ok_or_else(|| self.error(format!("{what}: {EXT}.transmissionFactor must be a number in [0, 1], got {v}")))?,
        };
        let texture = self.extension_texture_ref(ext, "transmissionTexture", false, what, EXT)?;
        Ok((factor, texture))
    }

    /// `KHR_materials_volume` of a material's raw `extensions` object: `Some` where the
    /// thickness factor is > 0 (0, the default, is thin-walled).
    fn volume(&mut self, extensions: &Value, what: &str) -> Result<Option<Volume>, PathTracerError> {
        const EXT: &str = "KHR_materials_volume";
        let Some(ext) = extensions.get(EXT) else { return Ok(None) };
        if !ext.is_object() {
            return Err(self.error(format!("{what}: {EXT} must be an object")));
        }
        let thickness = match ext.get("thicknessFactor") {
            None => 0.0,
            Some(v) => number(v).filter(|&t| t >= 0.0).ok_or_else(|| self.error(format!("{what}: {EXT}.thicknessFactor must be a finite number ≥ 0, got {v}")))?,
        };
        let attenuation_distance = match ext.get("attenuationDistance") {
            None => f32::INFINITY,
            Some(v) => number(v).filter(|&d| d > 0.0).ok_or_else(|| {
                self.error(format!("{what}: {EXT}.attenuationDistance must be a finite number > 0 (omit it for no absorption), got {v}"))
            })?,
        };
        let attenuation_color = match ext.get("attenuationColor") {
            None => Vec3::ONE,
            Some(v) => numbers::<3>(v)
                .filter(|c| c.iter().all(|&x| (0.0..=1.0).contains(&x)))
                .map(Vec3::from)
                .ok_or_else(|| self.error(format!("{what}: {EXT}.attenuationColor must be three numbers in [0, 1], got {v}")))?,
        };
        if ext.get("thicknessTexture").is_some() {
            self.warn(format!("{what}: {EXT}.thicknessTexture is not read (the path tracer measures the distance travelled inside)"));
        }
        Ok((thickness > 0.0).then_some(Volume { attenuation_color, attenuation_distance }))
    }

    /// `KHR_materials_specular` of a material's raw `extensions` object (defaults without it).
    fn specular(&mut self, extensions: &Value, what: &str) -> Result<Specular, PathTracerError> {
        const EXT: &str = "KHR_materials_specular";
        let Some(ext) = extensions.get(EXT) else {
            return Ok(Specular { factor: 1.0, texture: None, color_factor: Vec3::ONE, color_texture: None });
        };
        if !ext.is_object() {
            return Err(self.error(format!("{what}: {EXT} must be an object")));
        }
        let factor = match ext.get("specularFactor") {
            None => 1.0,
            Some(v) => number(v)
                .filter(|f| (0.0..=1.0).contains(f))
                .ok_or_else(|| self.error(format!("{what}: {EXT}.specularFactor must be a number in [0, 1], got {v}")))?,
        };
        let color_factor = match ext.get("specularColorFactor") {
            None => Vec3::ONE,
            Some(v) => numbers::<3>(v)
                .filter(|c| c.iter().all(|&x| x >= 0.0))
                .map(Vec3::from)
                .ok_or_else(|| self.error(format!("{what}: {EXT}.specularColorFactor must be three finite non-negative numbers, got {v}")))?,
        };
        // specularTexture: data (its A channel); specularColorTexture: sRGB colour (its RGB).
        let texture = self.extension_texture_ref(ext, "specularTexture", false, what, EXT)?;
        let color_texture = self.extension_texture_ref(ext, "specularColorTexture", true, what, EXT)?;
        Ok(Specular { factor, texture, color_factor, color_texture })
    }
}

/// `KHR_materials_specular`'s fields as read.
struct Specular {
    factor: f32,
    texture: Option<TextureRef>,
    color_factor: Vec3,
    color_texture: Option<TextureRef>,
}

/// A finite JSON number as `f32`.
fn number(v: &Value) -> Option<f32> {
    v.as_f64().map(|x| x as f32).filter(|x| x.is_finite())
}

/// An array of exactly `N` finite numbers.
fn numbers<const N: usize>(v: &Value) -> Option<[f32; N]> {
    let a = v.as_array().filter(|a| a.len() == N)?;
    let mut out = [0.0; N];
    for (o, x) in out.iter_mut().zip(a) {
        *o = number(x)?;
    }
    Some(out)
}

/// `KHR_materials_ior`'s `ior` (default 1.5): finite and ≥ 1, or exactly 0 (the extension's
/// schema). The error names the field.
fn ior(ext: &Value) -> Result<f32, String> {
    match ext.get("ior") {
        None if ext.is_object() => Ok(1.5),
        None => Err(format!("ior: the extension must be an object, got {ext}")),
        Some(v) => number(v)
            .filter(|&x| x == 0.0 || x >= 1.0)
            .ok_or_else(|| format!("ior must be a finite number ≥ 1 or exactly 0, got {v}")),
    }
}

/// A `KHR_texture_transform` object → (the transform, the `texCoord` override). Defaults:
/// offset (0, 0), rotation 0, scale (1, 1). The error names the field.
fn texture_transform(t: &Value) -> Result<(Option<UvTransform>, Option<u32>), String> {
    if !t.is_object() {
        return Err(format!("must be an object, got {t}"));
    }
    let pair = |key: &str, default: Vec2| match t.get(key) {
        None => Ok(default),
        Some(v) => numbers::<2>(v).map(Vec2::from).ok_or_else(|| format!("{key} must be two finite numbers, got {v}")),
    };
    let offset = pair("offset", Vec2::ZERO)?;
    let scale = pair("scale", Vec2::ONE)?;
    let rotation = match t.get("rotation") {
        None => 0.0,
        Some(v) => number(v).ok_or_else(|| format!("rotation must be a finite number (radians), got {v}"))?,
    };
    let tex_coord = match t.get("texCoord") {
        None => None,
        Some(v) => Some(v.as_u64().and_then(|x| u32::try_from(x).ok()).ok_or_else(|| format!("texCoord must be a non-negative integer, got {v}"))?),
    };
    Ok((Some(UvTransform::new(offset, rotation, scale)), tex_coord))
}
