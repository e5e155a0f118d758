//! Exporting the render scene exactly as the renderer loaded it, for an external renderer
//! (the Mitsuba 3 cross-check in `tests/mitsuba/`), and reference renders with per-pixel
//! noise estimates to compare against.
//!
//! # The export folder ([`export_scene`])
//! - `scene.json`: the [`ExportManifest`] — format version, scene name, origin, array
//!   shapes, resolved materials, textures, punctual lights in physical units, the
//!   environment, the cameras and the render settings.
//! - Little-endian `.npy` arrays (NumPy format 1.0):
//!   `positions.npy` `<f8 (V, 3)` **world** positions (`scene.origin + local`, in `f64`);
//!   `normals.npy` `<f4 (V, 3)`; `tangents.npy` `<f4 (V, 4)`; `uv0.npy`, `uv1.npy` `<f4 (V, 2)`;
//!   `colors.npy` `<f4 (V, 4)` (COLOR_0, linear); `indices.npy` `<u4 (T, 3)` (counter-clockwise
//!   front faces); `material.npy` `<u4 (T,)`; `texture_<k>.npy` `<f4 (H, W, 4)` texels as the
//!   renderer samples them (colour textures already linear, row 0 the top row, so glTF UV
//!   (0, 0) is texel (0, 0)); `corner_tangents.npy` `<f4 (T, 3, 4)`: per triangle corner, the
//!   normal-mapping tangent (xyz, handedness w) the renderer uses there
//!   ([`crate::integrator::tangent_at`]: the asset's TANGENT, or the per-triangle tangent from
//!   the UVs; linear over the triangle, so interpolating the corners reproduces it), zero for
//!   triangles whose material has no normal map (the base's, else the clear coat's);
//!   `environment_map.npy` `<f4 (H, W, 3)` (only with an environment map): the equirectangular
//!   map's linear texels as the renderer loaded them (row 0 the top row = +Y; see
//!   [`crate::light::EnvironmentMap::direction`]), sampled nearest, scaled by `environment`.
//!
//! Missing per-vertex attributes are written with the renderer's defaults (normal: the face
//! normal is used by the renderer when the interpolated normal vanishes; UV 0; colour white).
//!
//! # Reference renders ([`render_reference`])
//! The renderer does not keep per-pixel sample variance, so a reference view at `spp` samples
//! is the average of `groups` independent renders of `spp / groups` samples each (seeds
//! `seed, seed + 1, …`); the spread of the groups gives the variance of the mean:
//! `var(mean) = Σ (xᵍ − x̄)² / (G (G − 1))`. With one sample per group (`groups = spp`) this
//! is the usual sample variance over `spp` samples divided by `spp`.

use crate::PathTracerError;
use crate::render::{RenderSettings, Renderer};
use crate::scene::{AlphaMode, Filter, Light, Scene, TextureRef, Wrap};
use dataset::{Camera, GroundTruth};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Version of the export folder layout, written into `scene.json`.
pub const EXPORT_FORMAT_VERSION: u32 = 3;

/// The manifest file's name inside an export folder.
pub const MANIFEST_FILE: &str = "scene.json";

/// A camera as the dataset defines it: the 4×4 camera-to-world matrix written row by row
/// (OpenGL frame: +X right, +Y up, looking down −Z) and pinhole intrinsics in pixels
/// (pixel (i, j) has its centre at (i + 0.5, j + 0.5)).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExportCamera {
    /// Camera-to-world, row-major.
    pub c2w: [[f64; 4]; 4],
    /// Focal length along x, pixels.
    pub fl_x: f64,
    /// Focal length along y, pixels.
    pub fl_y: f64,
    /// Principal point x, pixels from the left edge.
    pub cx: f64,
    /// Principal point y, pixels from the top edge.
    pub cy: f64,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
}

impl From<&Camera> for ExportCamera {
    fn from(c: &Camera) -> Self {
        let k = c.intrinsics;
        Self { c2w: c.rows(), fl_x: k.fl_x, fl_y: k.fl_y, cx: k.cx, cy: k.cy, width: k.width, height: k.height }
    }
}

/// A material's texture reference: `texture_<texture>.npy`, sampled with `tex_coord`'s UV
/// set, glTF wrap modes (`repeat`, `mirrored_repeat`, `clamp_to_edge`) and filter
/// (`nearest` or `linear`, bilinear with texel centres at half-integers, no mipmaps), after
/// the `KHR_texture_transform` `transform` if any.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExportTextureRef {
    /// Texture index.
    pub texture: u32,
    /// UV set (0 or 1).
    pub tex_coord: u32,
    /// Wrap along U.
    pub wrap_s: String,
    /// Wrap along V.
    pub wrap_t: String,
    /// Filter.
    pub filter: String,
    /// `KHR_texture_transform` as the 2×3 matrix `[[a, b, c], [d, e, f]]` (row by row):
    /// `u' = a u + b v + c`, `v' = d u + e v + f` (`T · R · S`, see
    /// [`crate::scene::UvTransform`]); `None`: identity. `tex_coord` already holds the
    /// extension's `texCoord` override.
    #[serde(default)]
    pub transform: Option<[[f32; 3]; 2]>,
}

impl From<&TextureRef> for ExportTextureRef {
    fn from(r: &TextureRef) -> Self {
        let wrap = |w: Wrap| match w {
            Wrap::Repeat => "repeat",
            Wrap::MirroredRepeat => "mirrored_repeat",
            Wrap::ClampToEdge => "clamp_to_edge",
        };
        Self {
            texture: r.texture,
            tex_coord: r.tex_coord,
            wrap_s: wrap(r.wrap_s).into(),
            wrap_t: wrap(r.wrap_t).into(),
            filter: match r.filter {
                Filter::Nearest => "nearest",
                Filter::Linear => "linear",
            }
            .into(),
            transform: r.transform.map(|t| {
                let (m, o) = (t.matrix.matrix2, t.matrix.translation);
                [[m.x_axis.x, m.y_axis.x, o.x], [m.x_axis.y, m.y_axis.y, o.y]]
            }),
        }
    }
}

/// A material with every parameter the renderer resolves (see [`crate::material`] for how
/// they combine): base colour = `base_color_factor × base_color_texture × COLOR_0`,
/// emission = `emissive × emissive_texture` (radiance, W·m⁻²·sr⁻¹).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExportMaterial {
    /// glTF name.
    pub name: Option<String>,
    /// Linear RGBA factor.
    pub base_color_factor: [f32; 4],
    /// Base colour texture (linear texels).
    pub base_color_texture: Option<ExportTextureRef>,
    /// Metallic factor.
    pub metallic: f32,
    /// Perceptual roughness factor.
    pub roughness: f32,
    /// `KHR_materials_specular` specular weight (1 for plain glTF; with metallic 0 and
    /// specular 0 the renderer shades exactly Lambertian).
    pub specular: f32,
    /// `KHR_materials_specular` specularTexture (its A multiplies `specular`).
    #[serde(default)]
    pub specular_texture: Option<ExportTextureRef>,
    /// `KHR_materials_specular` specularColorFactor (linear RGB).
    #[serde(default = "ones3")]
    pub specular_color: [f32; 3],
    /// `KHR_materials_specular` specularColorTexture (linear texels; RGB multiplies
    /// `specular_color`).
    #[serde(default)]
    pub specular_color_texture: Option<ExportTextureRef>,
    /// `KHR_materials_ior` ior: the dielectric's `F0 = min(((ior − 1)/(ior + 1))² ·
    /// specular colour, 1) · specular`, `F90 = specular` ([`crate::material::DielectricFresnel`]).
    #[serde(default = "default_ior")]
    pub ior: f32,
    /// Metallic (B) / roughness (G) texture.
    pub metallic_roughness_texture: Option<ExportTextureRef>,
    /// Tangent-space normal map.
    pub normal_texture: Option<ExportTextureRef>,
    /// Normal map scale.
    pub normal_scale: f32,
    /// Emitted radiance factor (emissive factor × strength).
    pub emissive: [f32; 3],
    /// Emissive texture (linear texels).
    pub emissive_texture: Option<ExportTextureRef>,
    /// `opaque`, `mask` or `blend` (blend is rendered opaque).
    pub alpha_mode: String,
    /// Alpha cutoff for `mask`.
    pub alpha_cutoff: f32,
    /// Whether back faces are rendered; single-sided back faces are not hit at all.
    pub double_sided: bool,
    /// Whether the scene facts count this material as view-dependent
    /// ([`crate::material::is_view_dependent`]); informative only: every material is shaded
    /// with the glTF BRDF unless metallic and specular are both 0.
    pub view_dependent: bool,
    /// `KHR_materials_transmission` transmissionFactor (absent: 0, opaque).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub transmission: f32,
    /// `KHR_materials_transmission` transmissionTexture (its R multiplies `transmission`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transmission_texture: Option<ExportTextureRef>,
    /// `KHR_materials_volume` with a thickness > 0 (absent: thin-walled).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub volume: Option<ExportVolume>,
    /// `KHR_materials_clearcoat` (absent: no coat).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clearcoat: Option<ExportClearcoat>,
    /// `KHR_materials_sheen` (absent: no sheen).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sheen: Option<ExportSheen>,
}

/// A material's clear coat ([`crate::scene::Clearcoat`], [`crate::material::Layered`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExportClearcoat {
    /// `clearcoatFactor`.
    pub factor: f32,
    /// `clearcoatTexture` (its R multiplies `factor`).
    pub texture: Option<ExportTextureRef>,
    /// `clearcoatRoughnessFactor`.
    pub roughness: f32,
    /// `clearcoatRoughnessTexture` (its G multiplies `roughness`).
    pub roughness_texture: Option<ExportTextureRef>,
    /// `clearcoatNormalTexture`.
    pub normal_texture: Option<ExportTextureRef>,
    /// Its scale.
    pub normal_scale: f32,
}

/// A material's sheen ([`crate::scene::Sheen`], [`crate::material::Layered`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExportSheen {
    /// `sheenColorFactor` (linear RGB).
    pub color: [f32; 3],
    /// `sheenColorTexture` (linear texels; RGB multiplies `color`).
    pub color_texture: Option<ExportTextureRef>,
    /// `sheenRoughnessFactor`.
    pub roughness: f32,
    /// `sheenRoughnessTexture` (its A multiplies `roughness`).
    pub roughness_texture: Option<ExportTextureRef>,
}

/// A material's interior ([`crate::scene::Volume`]): Beer–Lambert absorption
/// `σ_a = −ln(attenuation_color) / attenuation_distance`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExportVolume {
    /// `attenuationColor` (linear RGB).
    pub attenuation_color: [f32; 3],
    /// `attenuationDistance`; `None`: infinite (no absorption).
    pub attenuation_distance: Option<f32>,
}

fn is_zero(x: &f32) -> bool {
    *x == 0.0
}

fn ones3() -> [f32; 3] {
    [1.0; 3]
}

fn default_ior() -> f32 {
    1.5
}

/// A punctual light in world coordinates and physical units.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum ExportLight {
    /// Point light: intensity in W/sr (candela), irradiance `I / r²` at normal incidence.
    Point {
        /// World position.
        position: [f64; 3],
        /// Colour × candela.
        intensity: [f32; 3],
        /// Hard cutoff distance, if any.
        range: Option<f32>,
    },
    /// Spot light: a point light times glTF's falloff
    /// `clamp((cos θ − cos outer) / max(1e-3, cos inner − cos outer), 0, 1)²`.
    Spot {
        /// World position.
        position: [f64; 3],
        /// Unit direction the light shines along.
        direction: [f32; 3],
        /// Colour × candela.
        intensity: [f32; 3],
        /// Inner cone angle, radians.
        inner_cone_angle: f32,
        /// Outer cone angle, radians.
        outer_cone_angle: f32,
        /// Hard cutoff distance, if any.
        range: Option<f32>,
    },
    /// Directional light: irradiance (lux) on a surface facing it.
    Directional {
        /// Unit direction the light travels along.
        direction: [f32; 3],
        /// Colour × lux.
        illuminance: [f32; 3],
    },
}

/// Shape of one exported array.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExportTexture {
    /// File name inside the export folder.
    pub file: String,
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
}

/// `scene.json`: everything about the scene besides the arrays.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExportManifest {
    /// [`EXPORT_FORMAT_VERSION`].
    pub format_version: u32,
    /// The renderer that loaded the scene ([`crate::RENDERER_VERSION`]).
    pub renderer: String,
    /// The scene's source name.
    pub scene: String,
    /// World position of the local frame's origin (already added into `positions.npy`).
    pub origin: [f64; 3],
    /// Number of vertices.
    pub vertices: usize,
    /// Number of triangles.
    pub triangles: usize,
    /// Material table (indexed by `material.npy`).
    pub materials: Vec<ExportMaterial>,
    /// Textures (`texture_<k>.npy`).
    pub textures: Vec<ExportTexture>,
    /// Punctual lights.
    pub lights: Vec<ExportLight>,
    /// Constant environment radiance (linear RGB), or the scale of `environment_map`; lights
    /// the scene, and is what camera misses show unless `settings.transparent_background`.
    pub environment: [f32; 3],
    /// The equirectangular environment map (`environment_map.npy`), if any.
    #[serde(default)]
    pub environment_map: Option<ExportTexture>,
    /// The views to render.
    pub cameras: Vec<ExportCamera>,
    /// The render settings (spp, max_bounces: 0 emitters only, 1 direct light, …).
    pub settings: RenderSettings,
}

/// Little-endian `.npy` (format 1.0) bytes of an array with element type `descr` (e.g.
/// `<f4`) and `shape`, from the raw little-endian element bytes.
pub fn npy_bytes(descr: &str, shape: &[usize], data: &[u8]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape = if dims.len() == 1 { format!("({},)", dims[0]) } else { format!("({})", dims.join(", ")) };
    let mut header = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + data.len());
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    out.extend_from_slice(data);
    out
}

/// Writes a `<f4` array of `shape` (row-major) to `path`.
pub fn write_npy_f32(path: &Path, shape: &[usize], values: &[f32]) -> Result<(), PathTracerError> {
    check_shape(path, shape, values.len())?;
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    dataset::io::atomic_write(path, &npy_bytes("<f4", shape, &bytes))?;
    Ok(())
}

/// Writes a `<f8` array of `shape` (row-major) to `path`.
pub fn write_npy_f64(path: &Path, shape: &[usize], values: &[f64]) -> Result<(), PathTracerError> {
    check_shape(path, shape, values.len())?;
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    dataset::io::atomic_write(path, &npy_bytes("<f8", shape, &bytes))?;
    Ok(())
}

/// Writes a `<u4` array of `shape` (row-major) to `path`.
pub fn write_npy_u32(path: &Path, shape: &[usize], values: &[u32]) -> Result<(), PathTracerError> {
    check_shape(path, shape, values.len())?;
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    dataset::io::atomic_write(path, &npy_bytes("<u4", shape, &bytes))?;
    Ok(())
}

fn check_shape(path: &Path, shape: &[usize], len: usize) -> Result<(), PathTracerError> {
    let n: usize = shape.iter().product();
    if n != len {
        return Err(PathTracerError::Config(format!("{}: shape {shape:?} needs {n} values, got {len}", path.display())));
    }
    Ok(())
}

/// The manifest of `scene` rendered from `cameras` with `settings` (no arrays).
pub fn manifest(scene: &Scene, cameras: &[Camera], settings: &RenderSettings) -> ExportManifest {
    let o = scene.origin;
    let world = |p: glam::Vec3| [o.x + p.x as f64, o.y + p.y as f64, o.z + p.z as f64];
    let materials = scene
        .materials
        .iter()
        .map(|m| {
            let (alpha_mode, alpha_cutoff) = match m.alpha_mode {
                AlphaMode::Opaque => ("opaque", 0.5),
                AlphaMode::Mask { cutoff } => ("mask", cutoff),
                AlphaMode::Blend => ("blend", 0.5),
            };
            ExportMaterial {
                name: m.name.clone(),
                base_color_factor: m.base_color_factor.to_array(),
                base_color_texture: m.base_color_texture.as_ref().map(Into::into),
                metallic: m.metallic_factor,
                roughness: m.roughness_factor,
                specular: m.specular_factor,
                specular_texture: m.specular_texture.as_ref().map(Into::into),
                specular_color: m.specular_color_factor.to_array(),
                specular_color_texture: m.specular_color_texture.as_ref().map(Into::into),
                ior: m.ior,
                metallic_roughness_texture: m.metallic_roughness_texture.as_ref().map(Into::into),
                normal_texture: m.normal_texture.as_ref().map(|(r, _)| r.into()),
                normal_scale: m.normal_texture.map(|(_, s)| s).unwrap_or(1.0),
                emissive: m.emissive.to_array(),
                emissive_texture: m.emissive_texture.as_ref().map(Into::into),
                alpha_mode: alpha_mode.into(),
                alpha_cutoff,
                double_sided: m.double_sided,
                view_dependent: crate::material::is_view_dependent(m),
                transmission: m.transmission_factor,
                transmission_texture: m.transmission_texture.as_ref().map(Into::into),
                volume: m.volume.map(|v| ExportVolume {
                    attenuation_color: v.attenuation_color.to_array(),
                    attenuation_distance: v.attenuation_distance.is_finite().then_some(v.attenuation_distance),
                }),
                clearcoat: m.clearcoat.map(|c| ExportClearcoat {
                    factor: c.factor,
                    texture: c.texture.as_ref().map(Into::into),
                    roughness: c.roughness_factor,
                    roughness_texture: c.roughness_texture.as_ref().map(Into::into),
                    normal_texture: c.normal_texture.as_ref().map(|(r, _)| r.into()),
                    normal_scale: c.normal_texture.map(|(_, s)| s).unwrap_or(1.0),
                }),
                sheen: m.sheen.map(|h| ExportSheen {
                    color: h.color_factor.to_array(),
                    color_texture: h.color_texture.as_ref().map(Into::into),
                    roughness: h.roughness_factor,
                    roughness_texture: h.roughness_texture.as_ref().map(Into::into),
                }),
            }
        })
        .collect();
    let lights = scene
        .lights
        .iter()
        .map(|l| match *l {
            Light::Point { position, intensity, range } => {
                ExportLight::Point { position: world(position), intensity: intensity.to_array(), range }
            }
            Light::Spot { position, direction, intensity, inner_cone_angle, outer_cone_angle, range } => ExportLight::Spot {
                position: world(position),
                direction: direction.normalize_or_zero().to_array(),
                intensity: intensity.to_array(),
                inner_cone_angle,
                outer_cone_angle,
                range,
            },
            Light::Directional { direction, illuminance } => {
                ExportLight::Directional { direction: direction.normalize_or_zero().to_array(), illuminance: illuminance.to_array() }
            }
        })
        .collect();
    let textures = scene
        .textures
        .iter()
        .enumerate()
        .map(|(k, t)| ExportTexture { file: format!("texture_{k}.npy"), width: t.width, height: t.height })
        .collect();
    ExportManifest {
        format_version: EXPORT_FORMAT_VERSION,
        renderer: crate::version::renderer_version().to_string(),
        scene: scene.name.clone(),
        origin: o.to_array(),
        vertices: scene.mesh.positions.len(),
        triangles: scene.mesh.indices.len(),
        materials,
        textures,
        lights,
        environment: settings.environment,
        environment_map: None,
        cameras: cameras.iter().map(Into::into).collect(),
        settings: settings.clone(),
    }
}

/// Writes the export folder `dir` (created if needed; see the module docs) for `scene`
/// rendered from `cameras` with `settings`, and returns the manifest. The scene is checked
/// with [`crate::render::validate_scene`] first.
pub fn export_scene(scene: &Scene, cameras: &[Camera], settings: &RenderSettings, dir: &Path) -> Result<ExportManifest, PathTracerError> {
    crate::render::validate_scene(scene)?;
    std::fs::create_dir_all(dir).map_err(|e| dataset::DatasetError::write(dir, e))?;
    let m = &scene.mesh;
    let nv = m.positions.len();
    let o = scene.origin;
    let positions: Vec<f64> = m.positions.iter().flat_map(|p| [o.x + p.x as f64, o.y + p.y as f64, o.z + p.z as f64]).collect();
    write_npy_f64(&dir.join("positions.npy"), &[nv, 3], &positions)?;
    let or_default = |len: usize, default: &[f32], values: Vec<f32>| -> Vec<f32> {
        if len == nv { values } else { default.iter().copied().cycle().take(nv * default.len()).collect() }
    };
    let normals = or_default(m.normals.len(), &[0.0; 3], m.normals.iter().flat_map(|v| v.to_array()).collect());
    write_npy_f32(&dir.join("normals.npy"), &[nv, 3], &normals)?;
    let tangents = or_default(m.tangents.len(), &[0.0; 4], m.tangents.iter().flat_map(|v| v.to_array()).collect());
    write_npy_f32(&dir.join("tangents.npy"), &[nv, 4], &tangents)?;
    let uv0 = or_default(m.uv0.len(), &[0.0; 2], m.uv0.iter().flat_map(|v| v.to_array()).collect());
    write_npy_f32(&dir.join("uv0.npy"), &[nv, 2], &uv0)?;
    let uv1 = or_default(m.uv1.len(), &[0.0; 2], m.uv1.iter().flat_map(|v| v.to_array()).collect());
    write_npy_f32(&dir.join("uv1.npy"), &[nv, 2], &uv1)?;
    let colors = or_default(m.colors.len(), &[1.0; 4], m.colors.iter().flat_map(|v| v.to_array()).collect());
    write_npy_f32(&dir.join("colors.npy"), &[nv, 4], &colors)?;
    let nt = m.indices.len();
    let indices: Vec<u32> = m.indices.iter().flatten().copied().collect();
    write_npy_u32(&dir.join("indices.npy"), &[nt, 3], &indices)?;
    write_npy_u32(&dir.join("material.npy"), &[nt], &m.material)?;
    for (k, t) in scene.textures.iter().enumerate() {
        let texels: Vec<f32> = t.texels.iter().flat_map(|v| v.to_array()).collect();
        write_npy_f32(&dir.join(format!("texture_{k}.npy")), &[t.height as usize, t.width as usize, 4], &texels)?;
    }
    let mut corners = vec![0.0f32; nt * 12];
    for (k, tri) in m.indices.iter().enumerate() {
        let mat = m.material.get(k).and_then(|&i| scene.materials.get(i as usize));
        // The base's normal map, else the clear coat's (which the Mitsuba side refuses where
        // both exist on different UV sets).
        let Some((r, _)) = mat.and_then(|mat| mat.normal_texture.or(mat.clearcoat.and_then(|c| c.normal_texture))) else { continue };
        let p = tri.map(|i| m.positions[i as usize]);
        let ng_front = (p[1] - p[0]).cross(p[2] - p[0]).normalize_or_zero();
        for c in 0..3 {
            let mut b = [0.0f32; 3];
            b[c] = 1.0;
            let t = crate::integrator::tangent_at(scene, k as u32, b, r.tex_coord, ng_front);
            corners[k * 12 + c * 4..k * 12 + c * 4 + 4].copy_from_slice(&t.to_array());
        }
    }
    write_npy_f32(&dir.join("corner_tangents.npy"), &[nt, 3, 4], &corners)?;
    let mut man = manifest(scene, cameras, settings);
    if let Some(path) = &settings.environment_map {
        let map = crate::render::load_environment_map(path)?;
        let (w, h) = map.size();
        let texels: Vec<f32> = map.texels().iter().flat_map(|v| v.to_array()).collect();
        let file = "environment_map.npy".to_string();
        write_npy_f32(&dir.join(&file), &[h as usize, w as usize, 3], &texels)?;
        man.environment_map = Some(ExportTexture { file, width: w, height: h });
    }
    dataset::io::atomic_write_json(&dir.join(MANIFEST_FILE), &man)?;
    Ok(man)
}

/// A view rendered by [`render_reference`].
#[derive(Clone, Debug, PartialEq)]
pub struct ReferenceView {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Mean linear RGBA over all `spp` samples, interleaved (`4 · width · height`).
    pub mean: Vec<f32>,
    /// Estimated variance of `mean` per channel, interleaved like `mean`.
    pub variance: Vec<f32>,
    /// Ground truth at the pixel-centre rays (identical for every group).
    pub ground_truth: GroundTruth,
    /// Number of independent groups.
    pub groups: u32,
    /// Samples per group.
    pub spp_per_group: u32,
    /// Radiance samples that were NaN or infinite (replaced by zero by the renderer).
    pub nonfinite_samples: u64,
}

/// The largest divisor of `spp` that is at most `max_groups` (at least 1): the number of
/// independent groups [`render_reference`] splits `spp` into.
pub fn reference_groups(spp: u32, max_groups: u32) -> u32 {
    (1..=max_groups.clamp(1, spp.max(1))).rev().find(|g| spp.is_multiple_of(*g)).unwrap_or(1)
}

/// Renders `camera` at `settings.spp` samples per pixel as `groups` independent renders of
/// `settings.spp / groups` samples (seeds `settings.seed + g`; see the module docs) through
/// [`Renderer::render_view`], and returns their mean with the variance of that mean.
/// `groups` must divide `settings.spp` and be at least 2.
pub fn render_reference(renderer: &Renderer, camera: &Camera, view_index: u32, settings: &RenderSettings, groups: u32) -> Result<ReferenceView, PathTracerError> {
    settings.validate()?;
    if groups < 2 || !settings.spp.is_multiple_of(groups) {
        return Err(PathTracerError::Config(format!("{groups} groups must be at least 2 and divide spp {}", settings.spp)));
    }
    let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
    let n = 4 * w as usize * h as usize;
    let mut sum = vec![0.0f64; n];
    let mut sum2 = vec![0.0f64; n];
    let mut gt = None;
    let mut nonfinite = 0;
    for g in 0..groups {
        let s = RenderSettings { spp: settings.spp / groups, seed: settings.seed.wrapping_add(g as u64), ..settings.clone() };
        let v = renderer.render_view(camera, view_index, &s);
        nonfinite += v.nonfinite_samples;
        for (k, &x) in v.color.data.iter().enumerate() {
            sum[k] += x as f64;
            sum2[k] += x as f64 * x as f64;
        }
        gt.get_or_insert(v.ground_truth);
    }
    let gf = groups as f64;
    let mean: Vec<f32> = sum.iter().map(|s| (s / gf) as f32).collect();
    let variance = sum
        .iter()
        .zip(&sum2)
        .map(|(s, s2)| {
            let m = s / gf;
            (((s2 / gf - m * m) * gf / (gf - 1.0)).max(0.0) / gf) as f32
        })
        .collect();
    let ground_truth = gt.unwrap_or(GroundTruth { width: w, height: h, depth: vec![], distance: vec![], normal: vec![], alpha: vec![] });
    Ok(ReferenceView { width: w, height: h, mean, variance, ground_truth, groups, spp_per_group: settings.spp / groups, nonfinite_samples: nonfinite })
}

/// Writes a [`ReferenceView`] into `dir` as `<prefix>_mean.npy`, `<prefix>_var.npy`
/// (`<f4 (H, W, 4)`), and `<prefix>_depth.npy`, `<prefix>_distance.npy`, `<prefix>_alpha.npy`
/// (`<f4 (H, W)`), `<prefix>_normal.npy` (`<f4 (H, W, 3)`).
pub fn write_reference(dir: &Path, prefix: &str, v: &ReferenceView) -> Result<(), PathTracerError> {
    std::fs::create_dir_all(dir).map_err(|e| dataset::DatasetError::write(dir, e))?;
    let (w, h) = (v.width as usize, v.height as usize);
    write_npy_f32(&dir.join(format!("{prefix}_mean.npy")), &[h, w, 4], &v.mean)?;
    write_npy_f32(&dir.join(format!("{prefix}_var.npy")), &[h, w, 4], &v.variance)?;
    let gt = &v.ground_truth;
    write_npy_f32(&dir.join(format!("{prefix}_depth.npy")), &[h, w], &gt.depth)?;
    write_npy_f32(&dir.join(format!("{prefix}_distance.npy")), &[h, w], &gt.distance)?;
    write_npy_f32(&dir.join(format!("{prefix}_alpha.npy")), &[h, w], &gt.alpha)?;
    write_npy_f32(&dir.join(format!("{prefix}_normal.npy")), &[h, w, 3], &gt.normal)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Aabb, Material, Mesh, Texture};
    use dataset::Intrinsics;
    use glam::{DMat4, DVec3, Vec2, Vec3, Vec4};

    fn npy_payload(bytes: &[u8]) -> (String, &[u8]) {
        assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00");
        let hl = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        assert_eq!((10 + hl) % 64, 0, "header not padded to 64 bytes");
        (String::from_utf8(bytes[10..10 + hl].to_vec()).unwrap(), &bytes[10 + hl..])
    }

    #[test]
    fn npy_header_is_padded_and_names_the_shape() {
        let b = npy_bytes("<u4", &[3], &[0u8; 12]);
        let (h, data) = npy_payload(&b);
        assert!(h.contains("'descr': '<u4'") && h.contains("'shape': (3,)") && h.ends_with('\n'), "{h}");
        assert_eq!(data.len(), 12);
        let (h, _) = npy_payload(&npy_bytes("<f8", &[2, 3], &[0u8; 48]));
        assert!(h.contains("'shape': (2, 3)"), "{h}");
    }

    fn one_triangle_scene() -> Scene {
        let mut mesh = Mesh::default();
        for p in [Vec3::ZERO, Vec3::X, Vec3::Y] {
            mesh.positions.push(p);
            mesh.normals.push(Vec3::Z);
            mesh.tangents.push(Vec4::ZERO);
            mesh.uv0.push(p.truncate());
            mesh.uv1.push(Vec2::ZERO);
            mesh.colors.push(Vec4::ONE);
        }
        mesh.indices.push([0, 1, 2]);
        mesh.material.push(0);
        let mut mat = Material::gltf_default();
        mat.metallic_factor = 0.0;
        mat.specular_factor = 0.0;
        mat.base_color_factor = Vec4::new(0.5, 0.25, 1.0, 1.0);
        mat.emissive = Vec3::new(2.0, 0.0, 0.0);
        Scene {
            name: "tri".into(),
            origin: DVec3::new(100.0, 0.0, -3.0),
            mesh,
            materials: vec![mat],
            textures: vec![Texture { width: 2, height: 1, texels: vec![Vec4::ONE, Vec4::ZERO] }],
            lights: vec![Light::Point { position: Vec3::new(0.0, 1.0, 0.0), intensity: Vec3::splat(3.0), range: None }],
            cameras: vec![],
            bounds: Aabb { min: Vec3::ZERO, max: Vec3::new(1.0, 1.0, 0.0) },
            warnings: vec![],
            objects: vec![],
        }
    }

    #[test]
    fn export_writes_world_positions_and_a_manifest() {
        let scene = one_triangle_scene();
        let cam = Camera::new(Intrinsics::from_fov_y(4, 3, 0.8), DMat4::from_translation(DVec3::new(100.0, 0.0, 5.0))).unwrap();
        let dir = std::env::temp_dir().join(format!("pathtracer_export_test_{}", std::process::id()));
        let settings = RenderSettings::preview(7);
        let man = export_scene(&scene, &[cam], &settings, &dir).unwrap();
        assert_eq!((man.vertices, man.triangles, man.cameras.len()), (3, 1, 1));
        assert_eq!(man.origin, [100.0, 0.0, -3.0]);
        assert_eq!(man.lights, vec![ExportLight::Point { position: [100.0, 1.0, -3.0], intensity: [3.0; 3], range: None }]);
        assert_eq!(man.cameras[0].c2w[0][3], 100.0);
        assert_eq!((man.cameras[0].width, man.cameras[0].cy), (4, 1.5));
        let back: ExportManifest = serde_json::from_slice(&std::fs::read(dir.join(MANIFEST_FILE)).unwrap()).unwrap();
        assert_eq!(back, man);
        let pos = std::fs::read(dir.join("positions.npy")).unwrap();
        let (h, data) = npy_payload(&pos);
        assert!(h.contains("'<f8'") && h.contains("(3, 3)"));
        let v: Vec<f64> = data.chunks(8).map(|c| f64::from_le_bytes(c.try_into().unwrap())).collect();
        assert_eq!(v, vec![100.0, 0.0, -3.0, 101.0, 0.0, -3.0, 100.0, 1.0, -3.0]);
        let tex = std::fs::read(dir.join("texture_0.npy")).unwrap();
        assert!(npy_payload(&tex).0.contains("(1, 2, 4)"));
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn export_writes_corner_tangents_and_the_environment_map() {
        let mut scene = one_triangle_scene();
        // Normal map, no TANGENT attribute: every corner gets the per-triangle tangent.
        scene.materials[0].normal_texture = Some((TextureRef { texture: 0, tex_coord: 0, wrap_s: Wrap::Repeat, wrap_t: Wrap::Repeat, filter: Filter::Nearest, transform: None }, 1.0));
        let dir = std::env::temp_dir().join(format!("pathtracer_export_env_test_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let map = dir.join("sky.exr");
        exr::prelude::write_rgb_file(&map, 4, 2, |x, y| (x as f32, y as f32, 0.5)).unwrap();
        let settings = RenderSettings { environment_map: Some(map), ..RenderSettings::preview(7) };
        let cam = Camera::new(Intrinsics::from_fov_y(4, 3, 0.8), DMat4::from_translation(DVec3::new(100.0, 0.0, 5.0))).unwrap();
        let man = export_scene(&scene, &[cam], &settings, &dir.join("export")).unwrap();
        let env = man.environment_map.clone().unwrap();
        assert_eq!((env.width, env.height, env.file.as_str()), (4, 2, "environment_map.npy"));
        let f32s = |name: &str| -> (String, Vec<f32>) {
            let bytes = std::fs::read(dir.join("export").join(name)).unwrap();
            let (h, data) = npy_payload(&bytes);
            (h, data.chunks(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect())
        };
        let (h, texels) = f32s("environment_map.npy");
        assert!(h.contains("(2, 4, 3)"), "{h}");
        // Texel (x, y) = (x, y, 0.5), row-major from the top row.
        assert_eq!(&texels[3 * 5..3 * 6], &[1.0, 1.0, 0.5]);
        let (h, t) = f32s("corner_tangents.npy");
        assert!(h.contains("(1, 3, 4)"), "{h}");
        // UV = (x, y) on the triangle (0,0,0), (1,0,0), (0,1,0): T = +X, B = ∂p/∂(−v) = −Y.
        let expect = crate::material::triangle_tangent([Vec3::ZERO, Vec3::X, Vec3::Y], [Vec2::ZERO, Vec2::X, Vec2::Y], Vec3::Z).unwrap();
        for c in 0..3 {
            assert_eq!(&t[4 * c..4 * c + 4], &expect.to_array());
        }
        assert!((expect.truncate() - Vec3::X).length() < 1e-6);
        // Without a normal map the tangents are zero, and without a map there is no map file.
        let man = export_scene(&one_triangle_scene(), &[cam], &RenderSettings::preview(7), &dir.join("plain")).unwrap();
        assert!(man.environment_map.is_none() && !dir.join("plain/environment_map.npy").exists());
        let bytes = std::fs::read(dir.join("plain/corner_tangents.npy")).unwrap();
        assert!(npy_payload(&bytes).1.iter().all(|b| *b == 0));
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn reference_groups_divide_spp() {
        assert_eq!(reference_groups(64, 64), 64);
        assert_eq!(reference_groups(256, 64), 64);
        assert_eq!(reference_groups(100, 64), 50);
        assert_eq!(reference_groups(7, 64), 7);
        assert_eq!(reference_groups(1, 64), 1);
    }

    #[test]
    fn reference_variance_matches_the_spread_of_groups() {
        // A lit triangle filling the view: constant emission 2 (no noise) plus light from the
        // constant environment (the point light lies in the triangle's plane).
        let cam = Camera::new(Intrinsics::from_fov_y(2, 2, 0.05), Camera::look_at(DVec3::new(100.3, 0.3, 0.0), DVec3::new(100.3, 0.3, -3.0), DVec3::Y)).unwrap();
        let settings = RenderSettings { spp: 8, max_bounces: 2, seed: 1, environment: [0.5; 3], transparent_background: false, environment_map: None };
        // Lambertian: cosine-sampled rays to a constant environment carry exactly albedo × L
        // (green 0.25 × 0.5), so every group agrees and the variance is 0 up to rounding.
        let r = Renderer::new(one_triangle_scene(), &crate::accel::AccelParams::fast_build()).unwrap();
        let v = render_reference(&r, &cam, 0, &settings, 8).unwrap();
        for px in 0..4 {
            assert_eq!(v.mean[4 * px + 1], 0.125, "{:?}", &v.mean);
            assert!(v.variance[4 * px + 1] < 1e-12, "{:?}", &v.variance);
        }
        // Half metallic: GGX sampling does not follow f·cos exactly, so the groups spread.
        let mut scene = one_triangle_scene();
        scene.materials[0].metallic_factor = 0.5;
        let r = Renderer::new(scene, &crate::accel::AccelParams::fast_build()).unwrap();
        let v = render_reference(&r, &cam, 0, &settings, 8).unwrap();
        assert_eq!((v.groups, v.spp_per_group), (8, 1));
        assert!(v.ground_truth.alpha.iter().all(|a| *a == 1.0));
        // Red channel: emission 2 plus reflected light; alpha constant 1 with zero variance.
        for px in 0..4 {
            assert!(v.mean[4 * px] >= 2.0, "{:?}", &v.mean);
            assert_eq!((v.mean[4 * px + 3], v.variance[4 * px + 3]), (1.0, 0.0));
            assert!(v.variance[4 * px + 1] > 0.0);
        }
        assert!(render_reference(&r, &cam, 0, &settings, 3).is_err());
    }
}
