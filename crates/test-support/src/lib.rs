//! Helpers shared by the workspace's tests; a dev-dependency of the crates that use them, never
//! a dependency of shipped code. Folder helpers are always here; the training tests' builders
//! (`training`, feature `nerf`) and small renders of the project's scenes (`render`, feature
//! `pathtracer`) come with the feature named after the crate they need.
//!
//! ```
//! let tmp = tempfile::tempdir().unwrap();
//! std::fs::write(tmp.path().join("a.txt"), b"a").unwrap();
//! assert_eq!(test_support::files(tmp.path()), vec![("a.txt".to_string(), b"a".to_vec())]);
//! ```

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[cfg(feature = "pathtracer")]
pub mod render;
#[cfg(feature = "nerf")]
pub mod training;

/// Every file under `dir` (recursively), as (path relative to `dir`, bytes), sorted by path; a
/// folder that does not exist, or one that vanishes while read, contributes nothing.
pub fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    file_map(dir).into_iter().collect()
}

/// [`files`] as a map from relative path to bytes.
pub fn file_map(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else { continue };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if let Ok(bytes) = std::fs::read(&p) {
                out.insert(p.strip_prefix(dir).unwrap_or(&p).display().to_string(), bytes);
            }
        }
    }
    out
}

/// The repository root (two levels above this crate).
pub fn repo_root() -> PathBuf {
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    here.parent().and_then(Path::parent).map(Path::to_path_buf).unwrap_or_else(|| PathBuf::from("."))
}

/// A project scene by name (`scenes/<name>.gltf`).
pub fn scene(name: &str) -> PathBuf {
    repo_root().join("scenes").join(format!("{name}.gltf"))
}

/// Removes `scene_facts` from a dataset folder's three `transforms_<split>.json`: the dataset as
/// a third party would ship it (with depth, without the facts only our renderer knows).
pub fn strip_scene_facts(dataset: &Path) {
    for split in ["train", "val", "test"] {
        let p = dataset.join(format!("transforms_{split}.json"));
        let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(&p).unwrap()).unwrap();
        v.as_object_mut().unwrap().remove("scene_facts");
        std::fs::write(&p, serde_json::to_vec(&v).unwrap()).unwrap();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lists_nested_files_sorted_with_their_bytes() {
        let tmp = std::env::temp_dir().join(format!("test-support-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&tmp);
        std::fs::create_dir_all(tmp.join("b/c")).unwrap();
        std::fs::write(tmp.join("b/c/z.txt"), b"z").unwrap();
        std::fs::write(tmp.join("a.txt"), b"a").unwrap();
        let f = files(&tmp);
        let sep = std::path::MAIN_SEPARATOR;
        assert_eq!(f, vec![("a.txt".to_string(), b"a".to_vec()), (format!("b{sep}c{sep}z.txt"), b"z".to_vec())]);
        assert!(files(&tmp.join("missing")).is_empty());
        std::fs::remove_dir_all(&tmp).unwrap();
    }

    #[test]
    fn the_repository_root_holds_the_scenes() {
        assert!(repo_root().join("Cargo.toml").is_file());
        assert!(scene("tabletop").is_file(), "{}", scene("tabletop").display());
    }

    #[test]
    fn stripping_the_facts_keeps_every_other_key() {
        let tmp = tempfile::tempdir().unwrap();
        for split in ["train", "val", "test"] {
            let v = serde_json::json!({ "camera_angle_x": 0.5, "frames": [], "scene_facts": { "near": 1.0 } });
            std::fs::write(tmp.path().join(format!("transforms_{split}.json")), serde_json::to_vec(&v).unwrap()).unwrap();
        }
        strip_scene_facts(tmp.path());
        for split in ["train", "val", "test"] {
            let v: serde_json::Value = serde_json::from_slice(&std::fs::read(tmp.path().join(format!("transforms_{split}.json"))).unwrap()).unwrap();
            assert_eq!(v, serde_json::json!({ "camera_angle_x": 0.5, "frames": [] }));
        }
    }
}
