//! A physically based path tracer that turns glTF 2.0 scenes into posed NeRF datasets with
//! exact ground truth: linear and display colour per view, plus z-depth, distance, world
//! normal and alpha at every pixel-centre ray.
//!
//! Layers: [`import`] (glTF → flat [`scene::Scene`]), [`accel`] (obvhs BVH behind one type,
//! watertight ray-triangle test in [`geometry`]), [`sampler`] (counter-based randomness),
//! [`texture`], [`material`], [`light`], [`camera_rays`] (a view's camera rays in `f32`),
//! [`integrator`] (radiance of one ray), [`caustics`] (caustic paths traced from the lights,
//! the paths it owns set by [`caustic_partition`]), [`render`] (the shared per-view driver),
//! [`rig`] (camera placement), [`dataset_folder`] (the dataset folder's types),
//! [`dataset_render`] (writing a dataset folder with resume and progress) and [`shard`]
//! (rendering it in shards and merging them). For geometry metrics,
//! [`reference`](mod@reference) gives the scene's camera-visible triangles in world space and
//! [`nearest`] exact closest-point queries on a triangle set (the BVH's point-query
//! counterpart).
//!
//! ```no_run
//! use pathtracer::import::{load_gltf, ImportOptions};
//! let scene = load_gltf(std::path::Path::new("scenes/tabletop.gltf"), &ImportOptions::default()).unwrap();
//! println!("{} triangles", scene.mesh.indices.len());
//! ```

pub mod accel;
pub mod camera_rays;
pub mod caustic_partition;
pub mod caustics;
pub mod dataset_folder;
pub mod dataset_render;
pub mod error;
pub mod export;
pub mod geometry;
pub mod ground_truth;
pub mod import;
pub mod integrator;
pub mod light;
pub mod material;
pub mod nearest;
pub mod reference;
pub mod render;
pub mod rig;
pub mod sampler;
pub mod scene;
pub mod shard;
pub mod texture;
pub mod version;

pub use error::PathTracerError;

/// Renderer name, version and description; datasets record it with the hash of the renderer's
/// output on a probe scene appended ([`version::renderer_version`]), which changes whenever the
/// output can.
pub const RENDERER_VERSION: &str = concat!("pathtracer ", env!("CARGO_PKG_VERSION"), " (padded Owen-scrambled Sobol' sampler, split emitter edges, glTF rig baseline 0.1 x depth, BVH box test from t = 0, emitter choice and point from one 2D sample, f32 camera rays per sample, caustic paths light-traced from caster triangles, Russian roulette at 2x throughput)");
