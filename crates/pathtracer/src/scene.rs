//! The flat render scene: every glTF primitive baked into one world-space triangle soup with
//! per-vertex attributes, a material table, textures, lights and cameras. The importer
//! (`import`) builds it; the acceleration structure, integrator and camera rigs read it.
//!
//! Precision: geometry is stored in `f32` relative to [`Scene::origin`] (an `f64` offset, the
//! centre of the scene's bounds), so a scene placed far from the world origin keeps full
//! `f32` precision. Everything in this struct except `origin` and [`SceneCamera::c2w`] is
//! in this local frame: `world = local + origin`.

use glam::{Affine2, DMat4, DVec3, Mat2, Vec2, Vec3, Vec4};

/// Axis-aligned bounding box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Minimum corner.
    pub min: Vec3,
    /// Maximum corner.
    pub max: Vec3,
}

impl Aabb {
    /// The empty box (min = +inf, max = -inf), the identity of [`Aabb::union_point`].
    pub const EMPTY: Aabb = Aabb { min: Vec3::INFINITY, max: Vec3::NEG_INFINITY };
    /// Grows the box to contain `p`.
    pub fn union_point(self, p: Vec3) -> Aabb {
        Aabb { min: self.min.min(p), max: self.max.max(p) }
    }
    /// Whether the box contains nothing.
    pub fn is_empty(&self) -> bool {
        self.min.cmpgt(self.max).any()
    }
    /// Centre point.
    pub fn center(&self) -> Vec3 {
        0.5 * (self.min + self.max)
    }
    /// Length of the diagonal.
    pub fn diagonal(&self) -> f32 {
        (self.max - self.min).length()
    }
}

/// Texture wrap mode (glTF sampler `wrapS` / `wrapT`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wrap {
    /// 10497
    Repeat,
    /// 33648
    MirroredRepeat,
    /// 33071
    ClampToEdge,
}

/// Texture filter (glTF `magFilter`; minification uses the same, without mipmaps for now).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Filter {
    /// Nearest texel.
    Nearest,
    /// Bilinear.
    Linear,
}

/// A decoded image, RGBA `f32`, row-major from the top row (glTF UV (0,0) is the top-left).
/// Colour textures (base colour, emissive) are converted from sRGB to linear at import;
/// data textures (metallic-roughness, normal) are kept as stored, scaled to [0, 1].
#[derive(Clone, Debug)]
pub struct Texture {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// `width * height` texels.
    pub texels: Vec<Vec4>,
}

/// A material's reference to a texture: which image, how to sample it, which UV set.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TextureRef {
    /// Index into [`Scene::textures`].
    pub texture: u32,
    /// UV set: 0 → TEXCOORD_0, 1 → TEXCOORD_1.
    pub tex_coord: u32,
    /// Wrap along U.
    pub wrap_s: Wrap,
    /// Wrap along V.
    pub wrap_t: Wrap,
    /// Filter.
    pub filter: Filter,
    /// `KHR_texture_transform` applied to the UV before the lookup (`None`: identity). The
    /// extension's `texCoord` override is already resolved into [`TextureRef::tex_coord`].
    pub transform: Option<UvTransform>,
}

/// A `KHR_texture_transform`: `uv' = T · R · S · uv` with (the extension's README, column
/// vectors `(u, v, 1)`)
///
/// ```text
/// T = | 1 0 offset.u |   R = |  cos r  sin r  0 |   S = | scale.u 0       0 |
///     | 0 1 offset.v |       | -sin r  cos r  0 |       | 0       scale.v 0 |
///     | 0 0 1        |       |  0      0      1 |       | 0       0       1 |
/// ```
///
/// so `u' = cos r · scale.u · u + sin r · scale.v · v + offset.u` and
/// `v' = −sin r · scale.u · u + cos r · scale.v · v + offset.v`. UV (0, 0) is the image's
/// top-left and v grows downwards, so a positive `rotation` r turns the image
/// counter-clockwise as displayed (the extension's wording).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UvTransform {
    /// `offset` (default (0, 0)).
    pub offset: Vec2,
    /// `rotation` in radians (default 0).
    pub rotation: f32,
    /// `scale` (default (1, 1)).
    pub scale: Vec2,
    /// `T · R · S`, precomputed.
    pub matrix: Affine2,
}

impl UvTransform {
    /// The transform with the extension's three parameters.
    pub fn new(offset: Vec2, rotation: f32, scale: Vec2) -> Self {
        let (s, c) = rotation.sin_cos();
        // Columns of R · S: the images of (1, 0) and (0, 1).
        let linear = Mat2::from_cols(Vec2::new(c * scale.x, -s * scale.x), Vec2::new(s * scale.y, c * scale.y));
        Self { offset, rotation, scale, matrix: Affine2::from_mat2_translation(linear, offset) }
    }

    /// `T · R · S · uv`.
    #[inline]
    pub fn apply(&self, uv: Vec2) -> Vec2 {
        self.matrix.transform_point2(uv)
    }
}

/// glTF alpha mode.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum AlphaMode {
    /// Alpha ignored.
    Opaque,
    /// Surface present where alpha >= cutoff.
    Mask {
        /// The cutoff (glTF default 0.5).
        cutoff: f32,
    },
    /// Stochastic coverage with probability alpha.
    Blend,
}

/// A glTF metallic-roughness material with every factor and texture carried, whether or not
/// the current shading uses it.
#[derive(Clone, Debug)]
pub struct Material {
    /// Name from the glTF, if any.
    pub name: Option<String>,
    /// Linear base colour factor (RGBA).
    pub base_color_factor: Vec4,
    /// Base colour texture (sRGB decoded to linear at import).
    pub base_color_texture: Option<TextureRef>,
    /// Metallic factor.
    pub metallic_factor: f32,
    /// Roughness factor (perceptual roughness).
    pub roughness_factor: f32,
    /// Metallic (B) and roughness (G) texture.
    pub metallic_roughness_texture: Option<TextureRef>,
    /// Tangent-space normal map and its scale.
    pub normal_texture: Option<(TextureRef, f32)>,
    /// Occlusion texture and strength (carried; a path tracer computes occlusion itself).
    pub occlusion_texture: Option<(TextureRef, f32)>,
    /// Emissive factor × `KHR_materials_emissive_strength` (linear radiance scale).
    pub emissive: Vec3,
    /// Emissive texture (sRGB decoded to linear at import).
    pub emissive_texture: Option<TextureRef>,
    /// Alpha mode.
    pub alpha_mode: AlphaMode,
    /// Whether back faces are rendered (single-sided back faces are invisible).
    pub double_sided: bool,
    /// `KHR_materials_specular` `specularFactor` (default 1): the strength of
    /// the dielectric's specular layer, 1 for plain glTF. 0 with metallic 0 makes the BRDF
    /// exactly Lambertian (the extension's "pure diffuse material").
    pub specular_factor: f32,
    /// `KHR_materials_specular` `specularTexture`: its A channel multiplies `specular_factor`.
    pub specular_texture: Option<TextureRef>,
    /// `KHR_materials_specular` `specularColorFactor` (linear RGB, default (1, 1, 1)): scales
    /// the dielectric's normal-incidence reflectance F0.
    pub specular_color_factor: Vec3,
    /// `KHR_materials_specular` `specularColorTexture` (sRGB decoded to linear at import): its
    /// RGB multiplies `specular_color_factor`.
    pub specular_color_texture: Option<TextureRef>,
    /// `KHR_materials_ior` `ior` (default 1.5): the dielectric's F0 is
    /// `((ior − 1)/(ior + 1))²` (0.04 at 1.5; ior 0 gives F0 = 1). See
    /// [`crate::material::DielectricFresnel`].
    pub ior: f32,
    /// `KHR_materials_transmission` `transmissionFactor` (default 0): the share of the
    /// dielectric's refracted light that passes through the surface instead of being
    /// scattered diffusely ([`crate::material::Dielectric`]).
    pub transmission_factor: f32,
    /// `KHR_materials_transmission` `transmissionTexture`: its R channel multiplies
    /// `transmission_factor`.
    pub transmission_texture: Option<TextureRef>,
    /// `KHR_materials_volume` with a thickness factor > 0: the mesh bounds a volume (refraction
    /// bends rays, Beer–Lambert absorption inside); `None`: thin-walled.
    pub volume: Option<Volume>,
    /// `KHR_materials_clearcoat` with a `clearcoatFactor` > 0; `None`: no coat.
    pub clearcoat: Option<Clearcoat>,
    /// `KHR_materials_sheen` with a `sheenColorFactor` other than black; `None`: no sheen.
    pub sheen: Option<Sheen>,
}

/// `KHR_materials_clearcoat`: a GGX specular layer over the material
/// ([`crate::material::Layered`]). At a point: clearcoat = `factor × texture.R`, roughness =
/// `roughness_factor × roughness_texture.G`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Clearcoat {
    /// `clearcoatFactor`, in (0, 1].
    pub factor: f32,
    /// `clearcoatTexture` (its R channel).
    pub texture: Option<TextureRef>,
    /// `clearcoatRoughnessFactor`, in [0, 1].
    pub roughness_factor: f32,
    /// `clearcoatRoughnessTexture` (its G channel).
    pub roughness_texture: Option<TextureRef>,
    /// `clearcoatNormalTexture` and its scale; without it the coat is not normal-mapped, even
    /// where the base is.
    pub normal_texture: Option<(TextureRef, f32)>,
}

/// `KHR_materials_sheen`: a Charlie sheen layer over the material
/// ([`crate::material::Layered`]). At a point: sheen colour = `color_factor ×
/// color_texture.RGB` (sRGB decoded at import), roughness = `roughness_factor ×
/// roughness_texture.A`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sheen {
    /// `sheenColorFactor` (linear RGB in [0, 1], not all 0).
    pub color_factor: Vec3,
    /// `sheenColorTexture` (its RGB).
    pub color_texture: Option<TextureRef>,
    /// `sheenRoughnessFactor`, in [0, 1].
    pub roughness_factor: f32,
    /// `sheenRoughnessTexture` (its A channel).
    pub roughness_texture: Option<TextureRef>,
}

/// The interior of a `KHR_materials_volume` material: light travelling a distance `d` inside
/// keeps the fraction `attenuation_color^(d / attenuation_distance)` per channel
/// (Beer–Lambert, `σ_a = −ln(attenuation_color) / attenuation_distance`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Volume {
    /// `attenuationColor` (linear RGB in [0, 1], default white: no absorption).
    pub attenuation_color: Vec3,
    /// `attenuationDistance` (> 0, default +∞: no absorption).
    pub attenuation_distance: f32,
}

impl Volume {
    /// The absorption coefficient `σ_a = −ln(attenuation_color) / attenuation_distance` per
    /// channel (0 for a white colour or an infinite distance; +∞ for a black channel).
    pub fn sigma_a(&self) -> Vec3 {
        let c = self.attenuation_color.clamp(Vec3::ZERO, Vec3::ONE);
        let s = Vec3::new(-c.x.ln(), -c.y.ln(), -c.z.ln()) / self.attenuation_distance;
        Vec3::new(if s.x.is_nan() { 0.0 } else { s.x }, if s.y.is_nan() { 0.0 } else { s.y }, if s.z.is_nan() { 0.0 } else { s.z })
    }

    /// The fraction `exp(−σ_a d)` per channel that survives a path of length `d` inside.
    pub fn transmittance(&self, d: f32) -> Vec3 {
        let s = self.sigma_a() * d;
        Vec3::new((-s.x).exp(), (-s.y).exp(), (-s.z).exp())
    }
}

impl Material {
    /// glTF's default material (white, metallic 1, roughness 1, opaque, single-sided).
    pub fn gltf_default() -> Self {
        Self {
            name: None,
            base_color_factor: Vec4::ONE,
            base_color_texture: None,
            metallic_factor: 1.0,
            roughness_factor: 1.0,
            metallic_roughness_texture: None,
            normal_texture: None,
            occlusion_texture: None,
            emissive: Vec3::ZERO,
            emissive_texture: None,
            alpha_mode: AlphaMode::Opaque,
            double_sided: false,
            specular_factor: 1.0,
            specular_texture: None,
            specular_color_factor: Vec3::ONE,
            specular_color_texture: None,
            ior: 1.5,
            transmission_factor: 0.0,
            transmission_texture: None,
            volume: None,
            clearcoat: None,
            sheen: None,
        }
    }

    /// Whether the material can transmit light (`KHR_materials_transmission` with a factor
    /// > 0): such surfaces are hit from both sides and refract or pass rays through.
    pub fn transmits(&self) -> bool {
        self.transmission_factor > 0.0
    }
    /// Whether the material emits light.
    pub fn is_emissive(&self) -> bool {
        self.emissive.max_element() > 0.0
    }
}

/// Every triangle of the scene, world space (relative to [`Scene::origin`]). Vertex arrays are
/// indexed by `indices`; every vertex has every attribute (defaults filled at import: normals
/// computed when absent, UV (0,0), colour (1,1,1,1), tangent (0,0,0,0) meaning "generate").
///
/// # Shapes
/// `positions`, `normals`, `tangents`, `uv0`, `uv1`, `colors`: one entry per vertex;
/// `indices`, `material`: one entry per triangle.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Unit vertex normals (after the node transform's inverse transpose).
    pub normals: Vec<Vec3>,
    /// Tangents, xyz plus handedness w (glTF TANGENT); zero when the asset has none.
    pub tangents: Vec<Vec4>,
    /// TEXCOORD_0.
    pub uv0: Vec<Vec2>,
    /// TEXCOORD_1.
    pub uv1: Vec<Vec2>,
    /// COLOR_0 (linear RGBA).
    pub colors: Vec<Vec4>,
    /// Triangle vertex indices, counter-clockwise front faces (winding already flipped for
    /// nodes with a negative-determinant transform).
    pub indices: Vec<[u32; 3]>,
    /// Material index per triangle, into [`Scene::materials`].
    pub material: Vec<u32>,
}

/// A `KHR_lights_punctual` light in its physical units, world space (local frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Light {
    /// Point light: `intensity` is colour × intensity in candela (W/sr in our radiometric
    /// units); irradiance at distance r, normal incidence, is `intensity / r²`.
    Point {
        /// Position.
        position: Vec3,
        /// Colour × candela.
        intensity: Vec3,
        /// glTF `range` (None = infinite); used only as a cutoff.
        range: Option<f32>,
    },
    /// Spot light: a point light restricted to a cone with glTF's smooth falloff between
    /// `inner_cone_angle` and `outer_cone_angle`.
    Spot {
        /// Position.
        position: Vec3,
        /// Unit direction the light shines along.
        direction: Vec3,
        /// Colour × candela.
        intensity: Vec3,
        /// Inner cone angle, radians.
        inner_cone_angle: f32,
        /// Outer cone angle, radians.
        outer_cone_angle: f32,
        /// glTF `range`.
        range: Option<f32>,
    },
    /// Directional light: `illuminance` is colour × lux (irradiance on a surface facing it).
    Directional {
        /// Unit direction the light travels along (glTF: the node's −Z).
        direction: Vec3,
        /// Colour × lux.
        illuminance: Vec3,
    },
}

/// A glTF perspective camera placed in the world (offered as extra views / rig anchors).
#[derive(Clone, Debug, PartialEq)]
pub struct SceneCamera {
    /// Node or camera name.
    pub name: Option<String>,
    /// Camera-to-world, true world coordinates (not relative to the origin), rigid (scale removed).
    pub c2w: DMat4,
    /// Vertical field of view, radians.
    pub yfov: f64,
    /// Aspect ratio width / height, if the asset gives one.
    pub aspect_ratio: Option<f64>,
    /// Near plane.
    pub znear: f64,
    /// Far plane, if finite.
    pub zfar: Option<f64>,
}

/// One object of the scene: a glTF node instance that contributed triangles (one mesh under two
/// nodes is two objects). Its triangles are `first_triangle .. first_triangle + triangles` of
/// [`Scene::mesh`], in the order the import met them.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneObject {
    /// glTF node index.
    pub node: usize,
    /// Node name.
    pub name: Option<String>,
    /// glTF mesh index.
    pub mesh: usize,
    /// Mesh name.
    pub mesh_name: Option<String>,
    /// First triangle.
    pub first_triangle: u32,
    /// Number of triangles.
    pub triangles: u32,
}

/// The render scene.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Source file, for messages and scene facts.
    pub name: String,
    /// World position of the local frame's origin (the centre of the bounds at import).
    pub origin: DVec3,
    /// All triangles.
    pub mesh: Mesh,
    /// Material table (index = glTF material index; the glTF default material is last when used).
    pub materials: Vec<Material>,
    /// Decoded textures.
    pub textures: Vec<Texture>,
    /// Punctual lights.
    pub lights: Vec<Light>,
    /// glTF cameras.
    pub cameras: Vec<SceneCamera>,
    /// Bounds of all triangles, local frame.
    pub bounds: Aabb,
    /// Warnings collected at import (unsupported optional extensions, dropped primitives, ...).
    pub warnings: Vec<String>,
    /// The objects, in import order (their triangle ranges follow one another). Empty for a
    /// scene built by hand: then the whole mesh is one object.
    pub objects: Vec<SceneObject>,
}

impl Scene {
    /// The index of the object triangle `prim` belongs to: 0 for a scene without objects,
    /// `None` for a triangle no object lists.
    pub fn object_of(&self, prim: u32) -> Option<usize> {
        if self.objects.is_empty() {
            return Some(0);
        }
        let k = self.objects.partition_point(|o| o.first_triangle <= prim).checked_sub(1)?;
        let o = &self.objects[k];
        (prim - o.first_triangle < o.triangles).then_some(k)
    }

    /// The number of objects (1 for a scene without object records).
    pub fn object_count(&self) -> usize {
        self.objects.len().max(1)
    }
}
