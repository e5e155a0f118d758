//! End-to-end tests across crates (render → train → eval) live in `tests/tests/`; this library
//! only holds the helpers they share.

use std::path::{Path, PathBuf};

/// The repository root.
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().map(Path::to_path_buf).unwrap_or_else(|| PathBuf::from("."))
}

/// A project scene by name (`scenes/<name>.gltf`).
pub fn scene(name: &str) -> PathBuf {
    repo_root().join("scenes").join(format!("{name}.gltf"))
}
