//! [`SceneBuilder`]: collect meshes, materials, textures, lights and cameras
//! and write them as glTF 2.0, either `.gltf` + `.bin` + `.png` files or one
//! self-contained `.glb`.
//!
//! The writer lays out one little-endian buffer: for each geometry, tightly
//! packed `POSITION`, `NORMAL`, `TEXCOORD_0` (f32), optional `COLOR_0` (f32
//! VEC3) and `TANGENT` (f32 VEC4), a skinned geometry's `JOINTS_0` (u8 VEC4)
//! and `WEIGHTS_0` (f32 VEC4), its morph targets (dense, or sparse with u32
//! indices), then indices (u16 when every index fits, else u32), each in its
//! own bufferView starting on a 4-byte boundary; skins' inverse bind matrices
//! follow. Every accessor carries exact `min`/`max`. JSON objects are written with sorted
//! keys and floats in their shortest round-trip form, so the output is
//! byte-identical for identical input.

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

use glam::{Mat3, Mat4, Quat, Vec3};
use image::RgbImage;
use serde_json::{Map, Value, json};

use crate::SceneGenError;
use crate::bin_writer::{BinWriter, canonical_json, jf, jf_slice};
use crate::deform::{self, MorphTarget, Skin};
use crate::mesh::Mesh;
use crate::texture::encode_png;

/// A node transform: scale, then rotate, then translate (glTF TRS).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transform {
    /// Translation in metres.
    pub translation: Vec3,
    /// Unit rotation quaternion.
    pub rotation: Quat,
    /// Per-axis scale.
    pub scale: Vec3,
}

impl Transform {
    /// The identity transform.
    pub const IDENTITY: Transform = Transform {
        translation: Vec3::ZERO,
        rotation: Quat::IDENTITY,
        scale: Vec3::ONE,
    };

    /// A pure translation.
    pub fn from_translation(translation: Vec3) -> Self {
        Transform {
            translation,
            ..Self::IDENTITY
        }
    }

    /// Translation and rotation.
    pub fn from_translation_rotation(translation: Vec3, rotation: Quat) -> Self {
        Transform {
            translation,
            rotation,
            ..Self::IDENTITY
        }
    }

    /// This transform with its scale replaced.
    pub fn with_scale(self, scale: Vec3) -> Self {
        Transform { scale, ..self }
    }

    /// A node at `eye` whose local −Z axis points at `target`, with local +Y
    /// as close to `up` as possible. This is how glTF cameras, spot lights and
    /// directional lights are aimed (they shine / look down their local −Z).
    /// Falls back to another up vector when `up` is parallel to the view direction.
    pub fn look_at(eye: Vec3, target: Vec3, up: Vec3) -> Self {
        let back = (eye - target).normalize_or(Vec3::Z);
        let mut right = up.cross(back);
        if right.length_squared() < 1e-12 {
            right = back.any_orthonormal_vector();
        }
        let right = right.normalize();
        let true_up = back.cross(right);
        let rotation = Quat::from_mat3(&Mat3::from_cols(right, true_up, back)).normalize();
        Transform::from_translation_rotation(eye, rotation)
    }

    /// The 4×4 matrix `T · R · S`.
    pub fn matrix(&self) -> Mat4 {
        Mat4::from_scale_rotation_translation(self.scale, self.rotation, self.translation)
    }
}

/// Index of a texture added with [`SceneBuilder::add_texture`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct TextureId(pub usize);
/// Index of a material added with [`SceneBuilder::add_material`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct MaterialId(pub usize);
/// Index of a geometry added with [`SceneBuilder::add_geometry`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct GeometryId(pub usize);
/// Index of a node (mesh instance, light or camera) in the written glTF `nodes`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct NodeId(pub usize);

/// A glTF `pbrMetallicRoughness` material. Colours are linear RGB(A).
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    /// Material name.
    pub name: String,
    /// Linear base colour (albedo) and alpha; multiplied by the texture and by vertex colours.
    pub base_color: [f32; 4],
    /// Optional sRGB base-colour texture (`TEXCOORD_0`).
    pub base_color_texture: Option<TextureId>,
    /// Metalness in [0, 1].
    pub metallic: f32,
    /// Perceptual roughness in [0, 1].
    pub roughness: f32,
    /// Optional tangent-space normal map and its scale (the mesh should carry tangents).
    pub normal_texture: Option<(TextureId, f32)>,
    /// Emissive colour in [0, 1]; emitted radiance is `emissive · emissive_strength`.
    pub emissive: [f32; 3],
    /// `KHR_materials_emissive_strength` multiplier (1 writes no extension).
    pub emissive_strength: f32,
    /// Whether back faces are rendered too (glTF `doubleSided`).
    pub double_sided: bool,
    /// Glass: `KHR_materials_transmission`, `_ior` and `_volume` (`None` writes none).
    pub glass: Option<Glass>,
    /// `KHR_materials_clearcoat`: (clearcoatFactor, clearcoatRoughnessFactor), each in [0, 1]
    /// (`None` writes none).
    pub clearcoat: Option<[f32; 2]>,
    /// The clear coat's own normal map and its scale (`clearcoatNormalTexture`; written only
    /// with a clear coat; the mesh should carry tangents).
    pub clearcoat_normal_texture: Option<(TextureId, f32)>,
    /// `KHR_materials_sheen`: (sheenColorFactor, sheenRoughnessFactor), in [0, 1] (`None`
    /// writes none).
    pub sheen: Option<([f32; 3], f32)>,
}

/// A transmissive material's extensions: `KHR_materials_transmission` (factor),
/// `KHR_materials_ior` and `KHR_materials_volume` (thickness > 0 bounds a volume; the
/// attenuation colour and distance give Beer–Lambert absorption inside).
#[derive(Clone, Debug, PartialEq)]
pub struct Glass {
    /// `transmissionFactor` in (0, 1].
    pub transmission: f32,
    /// `ior` (≥ 1).
    pub ior: f32,
    /// `thicknessFactor` (0: thin-walled, no volume extension written).
    pub thickness: f32,
    /// `attenuationColor` (linear RGB in [0, 1]).
    pub attenuation_color: [f32; 3],
    /// `attenuationDistance` in metres (`None`: infinite, no absorption).
    pub attenuation_distance: Option<f32>,
}

impl Material {
    /// An opaque dielectric with the given linear albedo, metallic 0 and roughness 0.8
    /// (close to Lambertian under a full BRDF).
    pub fn diffuse(name: &str, albedo: [f32; 3]) -> Self {
        Material {
            name: name.to_string(),
            base_color: [albedo[0], albedo[1], albedo[2], 1.0],
            base_color_texture: None,
            metallic: 0.0,
            roughness: 0.8,
            normal_texture: None,
            emissive: [0.0; 3],
            emissive_strength: 1.0,
            double_sided: false,
            glass: None,
            clearcoat: None,
            clearcoat_normal_texture: None,
            sheen: None,
        }
    }

    /// An emitter: black base colour, emitted radiance `colour · strength`
    /// (linear units, `KHR_materials_emissive_strength` for strength > 1).
    pub fn emissive(name: &str, colour: [f32; 3], strength: f32) -> Self {
        Material {
            emissive: colour,
            emissive_strength: strength,
            ..Material::diffuse(name, [0.0; 3])
        }
    }

    /// With metallic and roughness factors.
    pub fn with_metallic_roughness(self, metallic: f32, roughness: f32) -> Self {
        Material {
            metallic,
            roughness,
            ..self
        }
    }

    /// With a base-colour texture.
    pub fn with_texture(self, texture: TextureId) -> Self {
        Material {
            base_color_texture: Some(texture),
            ..self
        }
    }

    /// With a tangent-space normal map of the given scale.
    pub fn with_normal_map(self, texture: TextureId, scale: f32) -> Self {
        Material {
            normal_texture: Some((texture, scale)),
            ..self
        }
    }

    /// Transmissive (see [`Glass`]).
    pub fn with_glass(self, glass: Glass) -> Self {
        Material {
            glass: Some(glass),
            ..self
        }
    }

    /// With a clear coat of weight `factor` and `roughness` (`KHR_materials_clearcoat`).
    pub fn with_clearcoat(self, factor: f32, roughness: f32) -> Self {
        Material {
            clearcoat: Some([factor, roughness]),
            ..self
        }
    }

    /// With a normal map of the given scale on the clear coat alone.
    pub fn with_clearcoat_normal_map(self, texture: TextureId, scale: f32) -> Self {
        Material {
            clearcoat_normal_texture: Some((texture, scale)),
            ..self
        }
    }

    /// With a sheen of linear `color` and `roughness` (`KHR_materials_sheen`).
    pub fn with_sheen(self, color: [f32; 3], roughness: f32) -> Self {
        Material {
            sheen: Some((color, roughness)),
            ..self
        }
    }

    /// Rendered from both sides (leaves, thin sheets).
    pub fn double_sided(self) -> Self {
        Material {
            double_sided: true,
            ..self
        }
    }
}

/// A `KHR_lights_punctual` light. Directional and spot lights shine down their
/// node's local −Z (aim them with [`Transform::look_at`]).
#[derive(Clone, Debug, PartialEq)]
pub enum Light {
    /// Sun-like light; `illuminance` in lux (W/m² in the renderer's linear units)
    /// on a surface facing it.
    Directional {
        /// Linear RGB colour.
        color: [f32; 3],
        /// Illuminance in lux.
        illuminance: f32,
    },
    /// Isotropic point light; irradiance at distance `r` facing it is `intensity / r²`.
    Point {
        /// Linear RGB colour.
        color: [f32; 3],
        /// Luminous intensity in candela.
        intensity: f32,
    },
    /// Spot light with a smooth falloff between the inner and outer cone half-angles.
    Spot {
        /// Linear RGB colour.
        color: [f32; 3],
        /// Luminous intensity in candela on the axis.
        intensity: f32,
        /// Inner cone half-angle in radians, `0 <= inner < outer`.
        inner_cone_angle: f32,
        /// Outer cone half-angle in radians, `<= π/2`.
        outer_cone_angle: f32,
    },
}

/// A glTF perspective camera; the node looks down its local −Z.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PerspectiveCamera {
    /// Vertical field of view in radians.
    pub yfov: f32,
    /// Near clip distance in metres.
    pub znear: f32,
    /// Optional far clip distance (infinite when `None`).
    pub zfar: Option<f32>,
    /// Optional aspect ratio (width / height); when `None` the renderer's image decides.
    pub aspect_ratio: Option<f32>,
}

#[derive(Clone, Debug)]
enum NodeKind {
    Mesh(usize),
    Light(usize),
    Camera(usize),
    /// A transform only (a skin's joint).
    Joint,
}

#[derive(Clone, Debug)]
struct Node {
    name: String,
    transform: Transform,
    kind: NodeKind,
    /// The parent node; `None` for a root of the scene.
    parent: Option<usize>,
    /// The skin placing this node's mesh.
    skin: Option<usize>,
    /// Morph weights overriding the mesh's.
    weights: Option<Vec<f32>>,
}

/// Builds one glTF scene in memory and writes it.
///
/// # Example
///
/// A single quad under a point light, written to a temporary folder:
///
/// ```
/// use scenegen::{Light, Material, Mesh, SceneBuilder, Transform};
/// use glam::{Vec2, Vec3};
///
/// let dir = std::env::temp_dir().join("scenegen_doc_example");
/// let mut scene = SceneBuilder::new("quad");
/// let grey = scene.add_material(Material::diffuse("grey", [0.5, 0.5, 0.5]))?;
/// scene.add_mesh("floor", Mesh::quad(Vec2::new(2.0, 2.0), 1.0), grey, Transform::IDENTITY)?;
/// // 2 cd at 2 m: irradiance 0.5, radiance 0.5 · 0.5 / π ≈ 0.08 below the light.
/// scene.add_light(
///     "bulb",
///     Light::Point { color: [1.0; 3], intensity: 2.0 },
///     Transform::from_translation(Vec3::new(0.0, 2.0, 0.0)),
/// )?;
/// let written = scene.write_gltf(&dir.join("quad.gltf"))?;
/// assert_eq!(written.len(), 2); // quad.gltf and quad.bin
/// # Ok::<(), scenegen::SceneGenError>(())
/// ```
#[derive(Clone, Debug)]
pub struct SceneBuilder {
    name: String,
    textures: Vec<(String, RgbImage)>,
    materials: Vec<Material>,
    geometries: Vec<(String, Mesh)>,
    meshes: Vec<(GeometryId, MaterialId)>,
    mesh_lookup: BTreeMap<(GeometryId, MaterialId), usize>,
    lights: Vec<(String, Light)>,
    cameras: Vec<(String, PerspectiveCamera)>,
    nodes: Vec<Node>,
    /// Skins by index; each geometry's per-vertex influences are in the skin.
    skins: Vec<Skin>,
    /// Geometry index → its skin (the skin's vertex influences belong to that geometry).
    geometry_skin: BTreeMap<usize, usize>,
    /// Geometry index → its morph targets and default weights.
    geometry_morph: BTreeMap<usize, (Vec<MorphTarget>, Vec<f32>)>,
}

fn check_name(name: &str, what: &str) -> Result<(), SceneGenError> {
    let ok = !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
    if ok {
        Ok(())
    } else {
        Err(SceneGenError::InvalidName {
            name: name.to_string(),
            reason: format!("{what} names must be non-empty and use only A-Z a-z 0-9 _ -"),
        })
    }
}

impl SceneBuilder {
    /// An empty scene; `name` becomes the asset's scene name.
    pub fn new(name: &str) -> Self {
        SceneBuilder {
            name: name.to_string(),
            textures: Vec::new(),
            materials: Vec::new(),
            geometries: Vec::new(),
            meshes: Vec::new(),
            mesh_lookup: BTreeMap::new(),
            lights: Vec::new(),
            cameras: Vec::new(),
            nodes: Vec::new(),
            skins: Vec::new(),
            geometry_skin: BTreeMap::new(),
            geometry_morph: BTreeMap::new(),
        }
    }

    /// Add an RGB texture image. `name` (A-Z, a-z, 0-9, `_`, `-`) becomes part
    /// of the PNG file name `<scene>_<name>.png` when written as `.gltf`.
    pub fn add_texture(&mut self, name: &str, image: RgbImage) -> Result<TextureId, SceneGenError> {
        check_name(name, "texture")?;
        if self.textures.iter().any(|(n, _)| n == name) {
            return Err(SceneGenError::InvalidName {
                name: name.to_string(),
                reason: "a texture with this name already exists".into(),
            });
        }
        if image.width() == 0 || image.height() == 0 {
            return Err(SceneGenError::InvalidName {
                name: name.to_string(),
                reason: "texture is empty".into(),
            });
        }
        self.textures.push((name.to_string(), image));
        Ok(TextureId(self.textures.len() - 1))
    }

    /// Add a material; fails if it names a texture this builder does not have
    /// or has factors outside their ranges.
    pub fn add_material(&mut self, material: Material) -> Result<MaterialId, SceneGenError> {
        let bad = |reason: &str| SceneGenError::InvalidMaterial {
            name: material.name.clone(),
            reason: reason.to_string(),
        };
        let textures = material
            .base_color_texture
            .into_iter()
            .chain(material.normal_texture.map(|t| t.0))
            .chain(material.clearcoat_normal_texture.map(|t| t.0));
        for t in textures {
            if t.0 >= self.textures.len() {
                return Err(bad("texture id out of range"));
            }
        }
        let unit = |x: f32| (0.0..=1.0).contains(&x);
        if !material.base_color.iter().all(|&c| unit(c))
            || !material.emissive.iter().all(|&c| unit(c))
            || !unit(material.metallic)
            || !unit(material.roughness)
        {
            return Err(bad(
                "colour, emissive, metallic and roughness factors must lie in [0, 1]",
            ));
        }
        if !(material.emissive_strength.is_finite() && material.emissive_strength >= 0.0) {
            return Err(bad("emissive strength must be finite and non-negative"));
        }
        let layers_ok = material.clearcoat.is_none_or(|c| c.iter().all(|&x| unit(x)))
            && material.sheen.is_none_or(|(c, r)| c.iter().all(|&x| unit(x)) && unit(r));
        if !layers_ok {
            return Err(bad("clearcoat and sheen factors must lie in [0, 1]"));
        }
        if let Some(g) = &material.glass {
            let distance_ok = g.attenuation_distance.is_none_or(|d| d.is_finite() && d > 0.0);
            if !(g.transmission > 0.0 && g.transmission <= 1.0)
                || !(g.ior.is_finite() && g.ior >= 1.0)
                || !(g.thickness.is_finite() && g.thickness >= 0.0)
                || !g.attenuation_color.iter().all(|&c| unit(c))
                || !distance_ok
            {
                return Err(bad("glass needs transmission in (0, 1], ior ≥ 1, thickness ≥ 0, attenuation colour in [0, 1] and distance > 0"));
            }
        }
        self.materials.push(material);
        Ok(MaterialId(self.materials.len() - 1))
    }

    /// Add a mesh's data once, to be instanced by [`SceneBuilder::add_instance`].
    pub fn add_geometry(&mut self, name: &str, mesh: Mesh) -> Result<GeometryId, SceneGenError> {
        mesh.validate(name)?;
        self.geometries.push((name.to_string(), mesh));
        Ok(GeometryId(self.geometries.len() - 1))
    }

    /// Place a geometry with a material under a node transform. Instances of
    /// the same geometry share buffer data.
    pub fn add_instance(
        &mut self,
        name: &str,
        geometry: GeometryId,
        material: MaterialId,
        transform: Transform,
    ) -> Result<NodeId, SceneGenError> {
        if geometry.0 >= self.geometries.len() || material.0 >= self.materials.len() {
            return Err(SceneGenError::InvalidMesh {
                name: name.to_string(),
                reason: "geometry or material id out of range".into(),
            });
        }
        let next = self.meshes.len();
        let mesh = *self.mesh_lookup.entry((geometry, material)).or_insert(next);
        if mesh == next {
            self.meshes.push((geometry, material));
        }
        Ok(self.push_node(name, transform, NodeKind::Mesh(mesh)))
    }

    /// Add a geometry and place one instance of it ([`add_geometry`](Self::add_geometry)
    /// then [`add_instance`](Self::add_instance)).
    pub fn add_mesh(
        &mut self,
        name: &str,
        mesh: Mesh,
        material: MaterialId,
        transform: Transform,
    ) -> Result<NodeId, SceneGenError> {
        let g = self.add_geometry(name, mesh)?;
        self.add_instance(name, g, material, transform)
    }

    /// Add a joint: a node with only a transform, below `parent` (or a root), for a
    /// [`Skin`]'s `joints`.
    pub fn add_joint(&mut self, name: &str, transform: Transform, parent: Option<NodeId>) -> Result<NodeId, SceneGenError> {
        if parent.is_some_and(|p| p.0 >= self.nodes.len()) {
            return Err(SceneGenError::InvalidName { name: name.to_string(), reason: "parent node id out of range".into() });
        }
        let id = self.push_node(name, transform, NodeKind::Joint);
        self.nodes[id.0].parent = parent.map(|p| p.0);
        Ok(id)
    }

    /// Add a mesh posed by `skin` (glTF linear blend skinning; the node's own transform is
    /// ignored by glTF readers, so the node gets none).
    pub fn add_skinned_mesh(&mut self, name: &str, mesh: Mesh, material: MaterialId, skin: Skin) -> Result<NodeId, SceneGenError> {
        deform::check_skin(name, &mesh, &skin)?;
        if skin.joints.iter().any(|j| !matches!(self.nodes.get(j.0).map(|n| &n.kind), Some(NodeKind::Joint))) {
            return Err(SceneGenError::InvalidMesh { name: name.to_string(), reason: "skin joints must be nodes from add_joint".into() });
        }
        let g = self.add_geometry(name, mesh)?;
        self.skins.push(skin);
        self.geometry_skin.insert(g.0, self.skins.len() - 1);
        let node = self.add_instance(name, g, material, Transform::IDENTITY)?;
        self.nodes[node.0].skin = Some(self.skins.len() - 1);
        Ok(node)
    }

    /// Add a geometry with morph targets and their default weights (`mesh.weights`); place
    /// instances with [`add_instance`](Self::add_instance), overriding the weights per node
    /// with [`set_morph_weights`](Self::set_morph_weights).
    pub fn add_morphed_geometry(&mut self, name: &str, mesh: Mesh, targets: Vec<MorphTarget>, weights: Vec<f32>) -> Result<GeometryId, SceneGenError> {
        deform::check_morph(name, &mesh, &targets, &weights)?;
        let g = self.add_geometry(name, mesh)?;
        self.geometry_morph.insert(g.0, (targets, weights));
        Ok(g)
    }

    /// Sets a morphed mesh node's own weights (`node.weights`, overriding the mesh's).
    pub fn set_morph_weights(&mut self, node: NodeId, weights: Vec<f32>) -> Result<(), SceneGenError> {
        let n = self.nodes.get(node.0).ok_or_else(|| SceneGenError::InvalidName { name: format!("node {}", node.0), reason: "node id out of range".into() })?;
        let targets = match n.kind {
            NodeKind::Mesh(m) => self.geometry_morph.get(&self.meshes[m].0.0).map(|(t, _)| t.len()),
            _ => None,
        };
        if targets != Some(weights.len()) || weights.iter().any(|w| !w.is_finite()) {
            return Err(SceneGenError::InvalidMesh {
                name: n.name.clone(),
                reason: "node weights need a morphed mesh and one finite weight per target".into(),
            });
        }
        self.nodes[node.0].weights = Some(weights);
        Ok(())
    }

    /// A node's world transform (its parents' transforms first).
    fn node_world(&self, mut index: usize) -> Mat4 {
        let mut m = self.nodes[index].transform.matrix();
        while let Some(p) = self.nodes[index].parent {
            m = self.nodes[p].transform.matrix() * m;
            index = p;
        }
        m
    }

    /// A mesh node's vertices in world space at the default pose (morphed, then skinned or
    /// placed by the node's world transform), as a glTF reader should place them; `None` for
    /// a node without a mesh.
    pub fn world_positions(&self, node: NodeId) -> Option<Vec<Vec3>> {
        match self.nodes.get(node.0)?.kind {
            NodeKind::Mesh(m) => Some(self.posed_positions(node.0, m)),
            _ => None,
        }
    }

    fn posed_positions(&self, index: usize, mesh: usize) -> Vec<Vec3> {
        let g = self.meshes[mesh].0.0;
        let geometry = &self.geometries[g].1;
        let positions = match self.geometry_morph.get(&g) {
            Some((targets, weights)) => deform::morphed_positions(geometry, targets, self.nodes[index].weights.as_deref().unwrap_or(weights)),
            None => geometry.positions.clone(),
        };
        match self.nodes[index].skin {
            Some(s) => {
                let skin = &self.skins[s];
                let joint_world: Vec<Mat4> = skin.joints.iter().map(|j| self.node_world(j.0)).collect();
                deform::skinned_positions(&positions, skin, &joint_world)
            }
            None => {
                let world = self.node_world(index);
                positions.iter().map(|&p| world.transform_point3(p)).collect()
            }
        }
    }

    /// Add a punctual light at a node.
    pub fn add_light(
        &mut self,
        name: &str,
        light: Light,
        transform: Transform,
    ) -> Result<NodeId, SceneGenError> {
        let bad = |reason: &str| SceneGenError::InvalidLight {
            name: name.to_string(),
            reason: reason.to_string(),
        };
        let (color, power) = match &light {
            Light::Directional { color, illuminance } => (color, illuminance),
            Light::Point { color, intensity } => (color, intensity),
            Light::Spot {
                color,
                intensity,
                inner_cone_angle,
                outer_cone_angle,
            } => {
                let ok = *inner_cone_angle >= 0.0
                    && inner_cone_angle < outer_cone_angle
                    && *outer_cone_angle <= std::f32::consts::FRAC_PI_2;
                if !ok {
                    return Err(bad("spot cones need 0 <= inner < outer <= pi/2"));
                }
                (color, intensity)
            }
        };
        let valid =
            power.is_finite() && *power >= 0.0 && color.iter().all(|c| (0.0..=1.0).contains(c));
        if !valid {
            return Err(bad(
                "intensity must be finite and >= 0 and colour in [0, 1]",
            ));
        }
        self.lights.push((name.to_string(), light));
        Ok(self.push_node(name, transform, NodeKind::Light(self.lights.len() - 1)))
    }

    /// Add a perspective camera at a node (looking down its local −Z).
    pub fn add_camera(
        &mut self,
        name: &str,
        camera: PerspectiveCamera,
        transform: Transform,
    ) -> Result<NodeId, SceneGenError> {
        let ok = camera.yfov > 0.0
            && camera.yfov < std::f32::consts::PI
            && camera.znear > 0.0
            && camera.zfar.is_none_or(|f| f > camera.znear)
            && camera.aspect_ratio.is_none_or(|a| a > 0.0);
        if !ok {
            return Err(SceneGenError::InvalidCamera {
                name: name.to_string(),
                reason: "need 0 < yfov < pi, 0 < znear < zfar, aspect > 0".into(),
            });
        }
        self.cameras.push((name.to_string(), camera));
        Ok(self.push_node(name, transform, NodeKind::Camera(self.cameras.len() - 1)))
    }

    fn push_node(&mut self, name: &str, transform: Transform, kind: NodeKind) -> NodeId {
        self.nodes.push(Node {
            name: name.to_string(),
            transform,
            kind,
            parent: None,
            skin: None,
            weights: None,
        });
        NodeId(self.nodes.len() - 1)
    }

    /// World-space axis-aligned bounds `(min, max)` of all mesh instances, or
    /// `None` when the scene has no meshes.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let mut out: Option<(Vec3, Vec3)> = None;
        for (index, node) in self.nodes.iter().enumerate() {
            if let NodeKind::Mesh(m) = node.kind {
                for p in self.posed_positions(index, m) {
                    out = Some(out.map_or((p, p), |(a, b)| (a.min(p), b.max(p))));
                }
            }
        }
        out
    }

    /// Write `<path>` (a `.gltf` file) with its buffer `<stem>.bin` and
    /// textures `<stem>_<texture>.png` beside it. Returns the written paths,
    /// the `.gltf` first.
    pub fn write_gltf(&self, path: &Path) -> Result<Vec<PathBuf>, SceneGenError> {
        let stem = file_stem(path)?;
        let dir = path.parent().unwrap_or(Path::new(""));
        let mut written = vec![path.to_path_buf()];
        let bin_name = format!("{stem}.bin");
        let (mut doc, bin) = self.document(&[])?;
        doc["buffers"] = json!([{ "uri": bin_name, "byteLength": bin.len() }]);
        let mut images = Vec::new();
        for (name, img) in &self.textures {
            let file = format!("{stem}_{name}.png");
            let bytes = encode_png(img, &file)?;
            images.push(json!({ "name": name, "uri": file }));
            written.push(dir.join(&file));
            write_file(&dir.join(&file), &bytes)?;
        }
        if !images.is_empty() {
            doc["images"] = Value::Array(images);
        }
        create_dir(dir)?;
        write_file(&dir.join(&bin_name), &bin)?;
        written.insert(1, dir.join(&bin_name));
        write_file(path, canonical_json(&doc).as_bytes())?;
        Ok(written)
    }

    /// Write to `path`: a `.glb` extension writes one self-contained binary
    /// file ([`write_glb`](Self::write_glb)), anything else `.gltf` + `.bin` +
    /// `.png` ([`write_gltf`](Self::write_gltf)). Returns the written paths.
    pub fn write(&self, path: &Path) -> Result<Vec<PathBuf>, SceneGenError> {
        if path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("glb"))
        {
            Ok(vec![self.write_glb(path)?])
        } else {
            self.write_gltf(path)
        }
    }

    /// Write one self-contained binary glTF (`.glb`) with the PNG textures
    /// embedded in its buffer. Returns the written path.
    pub fn write_glb(&self, path: &Path) -> Result<PathBuf, SceneGenError> {
        let mut pngs = Vec::new();
        for (name, img) in &self.textures {
            pngs.push((name.clone(), encode_png(img, name)?));
        }
        let (mut doc, bin) = self.document(&pngs)?;
        doc["buffers"] = json!([{ "byteLength": bin.len() }]);
        let mut json_bytes = canonical_json(&doc).into_bytes();
        while !json_bytes.len().is_multiple_of(4) {
            json_bytes.push(b' ');
        }
        let total = 12 + 8 + json_bytes.len() + 8 + bin.len();
        let mut out = Vec::with_capacity(total);
        out.extend_from_slice(b"glTF");
        out.extend_from_slice(&2u32.to_le_bytes());
        out.extend_from_slice(&(total as u32).to_le_bytes());
        out.extend_from_slice(&(json_bytes.len() as u32).to_le_bytes());
        out.extend_from_slice(b"JSON");
        out.extend_from_slice(&json_bytes);
        out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&bin);
        if let Some(dir) = path.parent() {
            create_dir(dir)?;
        }
        write_file(path, &out)?;
        Ok(path.to_path_buf())
    }

    // Long by design: it writes the glTF document section by section (accessors, meshes,
    // materials, textures, nodes, lights) into one buffer whose offsets the sections share.
    /// Build the glTF JSON (without `buffers`) and the binary buffer. Images in
    /// `embedded` are appended to the buffer and referenced through bufferViews.
    fn document(&self, embedded: &[(String, Vec<u8>)]) -> Result<(Value, Vec<u8>), SceneGenError> {
        let mut bin = BinWriter::default();
        // Accessor indices per geometry.
        let mut prims = Vec::new();
        for (g, (name, mesh)) in self.geometries.iter().enumerate() {
            let mut attrs = Map::new();
            attrs.insert(
                "POSITION".into(),
                bin.floats(&flat3(&mesh.positions), 3).into(),
            );
            attrs.insert("NORMAL".into(), bin.floats(&flat3(&mesh.normals), 3).into());
            let uvs: Vec<f32> = mesh.uvs.iter().flat_map(|v| [v.x, v.y]).collect();
            attrs.insert("TEXCOORD_0".into(), bin.floats(&uvs, 2).into());
            if let Some(c) = &mesh.colors {
                attrs.insert("COLOR_0".into(), bin.floats(&flat3(c), 3).into());
            }
            if let Some(t) = &mesh.tangents {
                let flat: Vec<f32> = t.iter().flat_map(|v| v.to_array()).collect();
                attrs.insert("TANGENT".into(), bin.floats(&flat, 4).into());
            }
            if let Some(&s) = self.geometry_skin.get(&g) {
                let skin = &self.skins[s];
                attrs.insert("JOINTS_0".into(), bin.joints(&skin.vertex_joints).into());
                let weights: Vec<f32> = skin.vertex_weights.iter().flatten().copied().collect();
                attrs.insert("WEIGHTS_0".into(), bin.floats(&weights, 4).into());
            }
            let mut targets = Vec::new();
            for target in self.geometry_morph.get(&g).map(|(t, _)| t.as_slice()).unwrap_or_default() {
                let mut t = Map::new();
                let position = match target.sparse_indices() {
                    Some(moved) => {
                        let values: Vec<[f32; 3]> = moved.iter().map(|&i| target.positions[i as usize].to_array()).collect();
                        bin.sparse_vec3(target.positions.len(), &moved, &values)
                    }
                    None => bin.floats(&flat3(&target.positions), 3),
                };
                t.insert("POSITION".into(), position.into());
                if let Some(n) = &target.normals {
                    t.insert("NORMAL".into(), bin.floats(&flat3(n), 3).into());
                }
                targets.push(Value::Object(t));
            }
            let indices = bin.indices(&mesh.indices, mesh.positions.len());
            prims.push((name, attrs, indices, targets));
        }
        let mut image_json = Vec::new();
        for (name, bytes) in embedded {
            let view = bin.view(bytes, None);
            image_json.push(json!({ "name": name, "bufferView": view, "mimeType": "image/png" }));
        }

        let mut doc = Map::new();
        doc.insert(
            "asset".into(),
            json!({ "version": "2.0", "generator": concat!("scenegen ", env!("CARGO_PKG_VERSION")) }),
        );
        doc.insert("scene".into(), json!(0));
        doc.insert(
            "scenes".into(),
            json!([{ "name": self.name, "nodes": (0..self.nodes.len()).filter(|&i| self.nodes[i].parent.is_none()).collect::<Vec<_>>() }]),
        );
        let mut used_ext = Vec::new();

        let nodes: Vec<Value> = self
            .nodes
            .iter()
            .enumerate()
            .map(|(i, node)| {
                let children: Vec<usize> = (0..self.nodes.len()).filter(|&c| self.nodes[c].parent == Some(i)).collect();
                node_json(node, &children)
            })
            .collect();
        doc.insert("nodes".into(), Value::Array(nodes));
        if !self.skins.is_empty() {
            let skins: Vec<Value> = self
                .skins
                .iter()
                .map(|skin| {
                    let ibms: Vec<[f32; 16]> = skin.inverse_bind_matrices.iter().map(|m| m.to_cols_array()).collect();
                    json!({
                        "joints": skin.joints.iter().map(|j| j.0).collect::<Vec<_>>(),
                        "inverseBindMatrices": bin.matrices(&ibms),
                    })
                })
                .collect();
            doc.insert("skins".into(), Value::Array(skins));
        }

        let meshes: Vec<Value> = self
            .meshes
            .iter()
            .map(|&(g, m)| {
                let (name, attrs, indices, targets) = &prims[g.0];
                let mut prim = json!({ "attributes": attrs, "indices": indices, "material": m.0, "mode": 4 });
                let mut mesh = json!({ "name": name });
                if let Some((_, weights)) = self.geometry_morph.get(&g.0) {
                    prim["targets"] = Value::Array(targets.clone());
                    mesh["weights"] = jf_slice(weights);
                }
                mesh["primitives"] = json!([prim]);
                mesh
            })
            .collect();
        if !meshes.is_empty() {
            doc.insert("meshes".into(), Value::Array(meshes));
        }

        let mut materials = Vec::new();
        for m in &self.materials {
            let mut pbr = Map::new();
            pbr.insert("baseColorFactor".into(), jf_slice(&m.base_color));
            pbr.insert("metallicFactor".into(), jf(m.metallic));
            pbr.insert("roughnessFactor".into(), jf(m.roughness));
            if let Some(t) = m.base_color_texture {
                pbr.insert("baseColorTexture".into(), json!({ "index": t.0 }));
            }
            let mut mat = Map::new();
            mat.insert("name".into(), json!(m.name));
            mat.insert("pbrMetallicRoughness".into(), Value::Object(pbr));
            if let Some((t, scale)) = m.normal_texture {
                mat.insert(
                    "normalTexture".into(),
                    json!({ "index": t.0, "scale": jf(scale) }),
                );
            }
            let mut extensions = Map::new();
            if m.emissive != [0.0; 3] {
                mat.insert("emissiveFactor".into(), jf_slice(&m.emissive));
                if m.emissive_strength != 1.0 {
                    extensions.insert(
                        "KHR_materials_emissive_strength".into(),
                        json!({ "emissiveStrength": jf(m.emissive_strength) }),
                    );
                    used_ext.push("KHR_materials_emissive_strength");
                }
            }
            if let Some(g) = &m.glass {
                extensions.insert(
                    "KHR_materials_transmission".into(),
                    json!({ "transmissionFactor": jf(g.transmission) }),
                );
                extensions.insert("KHR_materials_ior".into(), json!({ "ior": jf(g.ior) }));
                used_ext.extend(["KHR_materials_transmission", "KHR_materials_ior"]);
                if g.thickness > 0.0 {
                    let mut v = Map::new();
                    v.insert("thicknessFactor".into(), jf(g.thickness));
                    v.insert("attenuationColor".into(), jf_slice(&g.attenuation_color));
                    if let Some(d) = g.attenuation_distance {
                        v.insert("attenuationDistance".into(), jf(d));
                    }
                    extensions.insert("KHR_materials_volume".into(), Value::Object(v));
                    used_ext.push("KHR_materials_volume");
                }
            }
            if let Some([factor, roughness]) = m.clearcoat {
                let mut c = json!({ "clearcoatFactor": jf(factor), "clearcoatRoughnessFactor": jf(roughness) });
                if let Some((t, scale)) = m.clearcoat_normal_texture {
                    c["clearcoatNormalTexture"] = json!({ "index": t.0, "scale": jf(scale) });
                }
                extensions.insert("KHR_materials_clearcoat".into(), c);
                used_ext.push("KHR_materials_clearcoat");
            }
            if let Some((color, roughness)) = &m.sheen {
                extensions.insert(
                    "KHR_materials_sheen".into(),
                    json!({ "sheenColorFactor": jf_slice(color), "sheenRoughnessFactor": jf(*roughness) }),
                );
                used_ext.push("KHR_materials_sheen");
            }
            if !extensions.is_empty() {
                mat.insert("extensions".into(), Value::Object(extensions));
            }
            if m.double_sided {
                mat.insert("doubleSided".into(), json!(true));
            }
            materials.push(Value::Object(mat));
        }
        if !materials.is_empty() {
            doc.insert("materials".into(), Value::Array(materials));
        }

        if !self.textures.is_empty() {
            // 9729 LINEAR, 9987 LINEAR_MIPMAP_LINEAR, 10497 REPEAT.
            doc.insert(
                "samplers".into(),
                json!([{ "magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497 }]),
            );
            let textures: Vec<Value> = (0..self.textures.len())
                .map(|i| json!({ "sampler": 0, "source": i }))
                .collect();
            doc.insert("textures".into(), Value::Array(textures));
        }
        if !image_json.is_empty() {
            doc.insert("images".into(), Value::Array(image_json));
        }

        if !self.cameras.is_empty() {
            let cams: Vec<Value> = self
                .cameras
                .iter()
                .map(|(name, c)| camera_json(name, c))
                .collect();
            doc.insert("cameras".into(), Value::Array(cams));
        }
        if !self.lights.is_empty() {
            let lights: Vec<Value> = self
                .lights
                .iter()
                .map(|(name, l)| light_json(name, l))
                .collect();
            doc.insert(
                "extensions".into(),
                json!({ "KHR_lights_punctual": { "lights": lights } }),
            );
            used_ext.push("KHR_lights_punctual");
        }
        used_ext.sort_unstable();
        used_ext.dedup();
        if !used_ext.is_empty() {
            doc.insert("extensionsUsed".into(), json!(used_ext));
        }

        doc.insert("accessors".into(), Value::Array(bin.accessors));
        doc.insert("bufferViews".into(), Value::Array(bin.views));
        Ok((Value::Object(doc), bin.data))
    }
}

fn node_json(node: &Node, children: &[usize]) -> Value {
    let mut n = Map::new();
    n.insert("name".into(), json!(node.name));
    if !children.is_empty() {
        n.insert("children".into(), json!(children));
    }
    if let Some(s) = node.skin {
        n.insert("skin".into(), json!(s));
    }
    if let Some(w) = &node.weights {
        n.insert("weights".into(), jf_slice(w));
    }
    let t = &node.transform;
    if t.translation != Vec3::ZERO {
        n.insert("translation".into(), jf_slice(&t.translation.to_array()));
    }
    if t.rotation != Quat::IDENTITY {
        n.insert(
            "rotation".into(),
            jf_slice(&t.rotation.normalize().to_array()),
        );
    }
    if t.scale != Vec3::ONE {
        n.insert("scale".into(), jf_slice(&t.scale.to_array()));
    }
    match node.kind {
        NodeKind::Mesh(m) => {
            n.insert("mesh".into(), json!(m));
        }
        NodeKind::Camera(c) => {
            n.insert("camera".into(), json!(c));
        }
        NodeKind::Light(l) => {
            n.insert(
                "extensions".into(),
                json!({ "KHR_lights_punctual": { "light": l } }),
            );
        }
        NodeKind::Joint => {}
    }
    Value::Object(n)
}

fn camera_json(name: &str, c: &PerspectiveCamera) -> Value {
    let mut p = Map::new();
    p.insert("yfov".into(), jf(c.yfov));
    p.insert("znear".into(), jf(c.znear));
    if let Some(f) = c.zfar {
        p.insert("zfar".into(), jf(f));
    }
    if let Some(a) = c.aspect_ratio {
        p.insert("aspectRatio".into(), jf(a));
    }
    json!({ "name": name, "type": "perspective", "perspective": p })
}

fn light_json(name: &str, l: &Light) -> Value {
    match l {
        Light::Directional { color, illuminance } => {
            json!({ "name": name, "type": "directional", "color": jf_slice(color), "intensity": jf(*illuminance) })
        }
        Light::Point { color, intensity } => {
            json!({ "name": name, "type": "point", "color": jf_slice(color), "intensity": jf(*intensity) })
        }
        Light::Spot {
            color,
            intensity,
            inner_cone_angle,
            outer_cone_angle,
        } => json!({
            "name": name,
            "type": "spot",
            "color": jf_slice(color),
            "intensity": jf(*intensity),
            "spot": { "innerConeAngle": jf(*inner_cone_angle), "outerConeAngle": jf(*outer_cone_angle) },
        }),
    }
}

fn flat3(v: &[Vec3]) -> Vec<f32> {
    v.iter().flat_map(|p| p.to_array()).collect()
}

fn file_stem(path: &Path) -> Result<String, SceneGenError> {
    let stem =
        path.file_stem()
            .and_then(|s| s.to_str())
            .ok_or_else(|| SceneGenError::InvalidName {
                name: path.display().to_string(),
                reason: "output path has no UTF-8 file name".into(),
            })?;
    check_name(stem, "scene file")?;
    Ok(stem.to_string())
}

fn create_dir(dir: &Path) -> Result<(), SceneGenError> {
    if dir.as_os_str().is_empty() {
        return Ok(());
    }
    fs::create_dir_all(dir).map_err(|source| SceneGenError::Io {
        path: dir.to_path_buf(),
        source,
    })
}

fn write_file(path: &Path, bytes: &[u8]) -> Result<(), SceneGenError> {
    if let Some(dir) = path.parent() {
        create_dir(dir)?;
    }
    fs::write(path, bytes).map_err(|source| SceneGenError::Io {
        path: path.to_path_buf(),
        source,
    })
}
