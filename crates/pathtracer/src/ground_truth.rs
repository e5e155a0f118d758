//! Exact ground truth for cameras a dataset did not render: the scene a dataset folder was
//! rendered from, found through its `render_config.json` and checked against the recorded
//! content hash, loaded behind a [`Renderer`] whose [`Renderer::ground_truth`] casts the
//! pixel-centre rays of any camera (for example a dataset camera downscaled by an even factor,
//! whose pixel centres fall between the full-resolution ones the dataset stores).
//!
//! ```no_run
//! use pathtracer::ground_truth::{SceneLookup, scene_of_dataset};
//! match scene_of_dataset(std::path::Path::new("out/tabletop"), None, &Default::default()).unwrap() {
//!     SceneLookup::Found { renderer, path } => println!("{}: {} triangles", path.display(), renderer.scene().mesh.indices.len()),
//!     SceneLookup::Missing(why) => println!("no exact ray caster: {why}"),
//! }
//! ```

use crate::PathTracerError;
use crate::accel::AccelParams;
use crate::dataset_folder::{RENDER_CONFIG_FILE, RenderRecord, SceneSource};
use crate::import::{ImportOptions, load_gltf};
use crate::render::Renderer;
use std::path::{Path, PathBuf};

/// The outcome of [`scene_of_dataset`].
#[derive(Debug)]
pub enum SceneLookup {
    /// The scene the dataset was rendered from, loaded.
    Found {
        /// The scene behind a BVH.
        renderer: Box<Renderer>,
        /// The file it was loaded from.
        path: PathBuf,
    },
    /// No usable scene, and why (no `render_config.json`, the file is gone or was edited).
    Missing(String),
}

/// Finds and loads the scene the dataset in `dataset_dir` was rendered from. With `scene`
/// given, that file is used and must have the recorded content (an error otherwise: the user
/// asked for it). Without it, the recorded path is tried as given (relative to the current
/// folder), relative to the dataset folder and to each of its ancestors; the first file with
/// the recorded content hash is loaded. A dataset without `render_config.json` (e.g. Blender
/// synthetic) or whose scene is nowhere to be found gives [`SceneLookup::Missing`]. The scene
/// is hashed and imported under `import` (e.g. external files admitted outside its folder).
pub fn scene_of_dataset(dataset_dir: &Path, scene: Option<&Path>, import: &ImportOptions) -> Result<SceneLookup, PathTracerError> {
    let config = dataset_dir.join(RENDER_CONFIG_FILE);
    if !config.exists() {
        return match scene {
            Some(p) => Err(PathTracerError::Config(format!(
                "{}: no {RENDER_CONFIG_FILE}, so the scene {} cannot be checked against the one the views were rendered from",
                dataset_dir.display(),
                p.display()
            ))),
            None => Ok(SceneLookup::Missing(format!("the dataset has no {RENDER_CONFIG_FILE} (not rendered by this path tracer)"))),
        };
    }
    let bytes = dataset::io::read(&config)?;
    let record: RenderRecord = serde_json::from_slice(&bytes).map_err(|e| PathTracerError::import(&config, e.to_string()))?;
    if let Some(p) = scene {
        let source = SceneSource::from_scene_with(p, import)?;
        if !same_content(p, &source, &record.scene.hash) {
            return Err(PathTracerError::Config(format!(
                "{} is not the scene {} was rendered from (content hash {} vs the recorded {})",
                p.display(),
                dataset_dir.display(),
                source.hash,
                record.scene.hash
            )));
        }
        return load(p, import).map(|renderer| SceneLookup::Found { renderer: Box::new(renderer), path: p.to_path_buf() });
    }
    let recorded = PathBuf::from(&record.scene.path);
    let mut candidates = vec![recorded.clone()];
    if recorded.is_relative() {
        candidates.extend(dataset_dir.ancestors().map(|a| a.join(&recorded)));
        if let Ok(abs) = dataset_dir.canonicalize() {
            candidates.extend(abs.ancestors().map(|a| a.join(&recorded)));
        }
    }
    let (mut edited, mut unreadable) = (None, None);
    for c in candidates {
        if !c.is_file() {
            continue;
        }
        match SceneSource::from_scene_with(&c, import) {
            Ok(s) if same_content(&c, &s, &record.scene.hash) => return load(&c, import).map(|renderer| SceneLookup::Found { renderer: Box::new(renderer), path: c }),
            Ok(_) => edited = edited.or(Some(c)),
            // E.g. a buffer outside the scene's folder without `allow_outside`: said, not hidden.
            Err(e) => unreadable = unreadable.or(Some(e)),
        }
    }
    Ok(SceneLookup::Missing(match (edited, unreadable) {
        (Some(c), _) => format!("{} has changed since the dataset was rendered (content hash differs)", c.display()),
        (None, Some(e)) => format!("the scene it was rendered from cannot be read ({e})"),
        (None, None) => format!("the scene it was rendered from ({}) is not found", record.scene.path),
    }))
}

/// Whether the scene at `path` (content `source`) is the one a dataset recorded as `recorded`:
/// its content hash, or, for datasets rendered before buffers and images were hashed with the
/// glTF, the hash of the glTF file alone (those datasets' views are still what this scene
/// renders unless a buffer or image was edited, which they could not record).
fn same_content(path: &Path, source: &SceneSource, recorded: &str) -> bool {
    source.hash == recorded || SceneSource::from_file(path).is_ok_and(|f| f.hash == recorded)
}

fn load(path: &Path, import: &ImportOptions) -> Result<Renderer, PathTracerError> {
    let scene = load_gltf(path, import)?;
    Renderer::new(scene, &AccelParams::medium_build())
}
