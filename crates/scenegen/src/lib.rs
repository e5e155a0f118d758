//! Procedural glTF 2.0 scene authoring for the project's ground-truth
//! datasets: a small deterministic glTF writer ([`SceneBuilder`]), mesh
//! builders with normals and UVs ([`Mesh`]), skins and morph targets
//! ([`deform`]), procedural PNG textures ([`texture`]), and the committed test
//! scenes (`cornell`, `tabletop`, `thin`, `deep`, `materials`, `bricks`,
//! `skinned`, `morphed`, `glass`) that `cargo xtask gen-scenes` regenerates with [`write_all`].
//!
//! Units are metres in glTF's right-handed, +Y-up world. Lights use
//! `KHR_lights_punctual` (point and spot intensity in candela, directional in
//! lux); area lights are emissive triangles with
//! `KHR_materials_emissive_strength`. Output is byte-identical for identical
//! input.
//!
//! ```
//! let dir = std::env::temp_dir().join("scenegen_lib_example");
//! let files = scenegen::write_scene("cornell", &dir)?;
//! assert!(files[0].ends_with("cornell.gltf"));
//! assert!(scenegen::scene_names().contains(&"tabletop"));
//! # Ok::<(), scenegen::SceneGenError>(())
//! ```

use std::path::{Path, PathBuf};

mod bin_writer;
mod bricks;
pub mod builder;
pub mod deform;
pub mod mesh;
pub mod scenes;
pub mod texture;

pub use builder::{
    GeometryId, Glass, Light, Material, MaterialId, NodeId, PerspectiveCamera, SceneBuilder, TextureId,
    Transform,
};
pub use deform::{MorphTarget, Skin};
pub use mesh::Mesh;
pub use scenes::{build_scene, scene_description, scene_names, stress};

/// Errors from building or writing scenes. Each names the file, scene or
/// object concerned and the problem.
#[derive(Debug, thiserror::Error)]
pub enum SceneGenError {
    /// Reading or writing a file failed.
    #[error("I/O error on {path}: {source}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// Encoding an image failed.
    #[error("could not encode image {what}: {source}")]
    Image {
        /// The image (file name or texture name).
        what: String,
        /// The underlying error.
        source: image::ImageError,
    },
    /// A mesh is malformed (attribute lengths, indices, non-finite values) or
    /// refers to unknown ids.
    #[error("invalid mesh {name}: {reason}")]
    InvalidMesh {
        /// The mesh name.
        name: String,
        /// What is wrong.
        reason: String,
    },
    /// A material has out-of-range factors or unknown textures.
    #[error("invalid material {name}: {reason}")]
    InvalidMaterial {
        /// The material name.
        name: String,
        /// What is wrong.
        reason: String,
    },
    /// A light has invalid parameters.
    #[error("invalid light {name}: {reason}")]
    InvalidLight {
        /// The light name.
        name: String,
        /// What is wrong.
        reason: String,
    },
    /// A camera has invalid parameters.
    #[error("invalid camera {name}: {reason}")]
    InvalidCamera {
        /// The camera name.
        name: String,
        /// What is wrong.
        reason: String,
    },
    /// A scene, texture or file name cannot be used.
    #[error("invalid name {name:?}: {reason}")]
    InvalidName {
        /// The offending name.
        name: String,
        /// What is wrong.
        reason: String,
    },
    /// [`write_scene`] was asked for a scene that does not exist.
    #[error("unknown scene {name:?}; known scenes: {known}")]
    UnknownScene {
        /// The requested name.
        name: String,
        /// The known names, comma separated.
        known: String,
    },
}

/// Write the named built-in scene into `dir` as `NAME.gltf` with `NAME.bin`
/// and its `NAME_*.png` textures. Returns the written paths, the `.gltf` first.
pub fn write_scene(name: &str, dir: &Path) -> Result<Vec<PathBuf>, SceneGenError> {
    let scene = build_scene(name)?;
    scene.write_gltf(&dir.join(format!("{name}.gltf")))
}

/// Write every built-in scene ([`scene_names`]) into `dir`, plus a
/// `README.md` describing them. Returns all written paths.
pub fn write_all(dir: &Path) -> Result<Vec<PathBuf>, SceneGenError> {
    let mut written = Vec::new();
    for name in scene_names() {
        written.extend(write_scene(name, dir)?);
    }
    let readme = dir.join("README.md");
    std::fs::write(&readme, scenes::readme()).map_err(|source| SceneGenError::Io {
        path: readme.clone(),
        source,
    })?;
    written.push(readme);
    Ok(written)
}

#[cfg(test)]
mod tests;
