//! Atomic file output: every file is written under a temporary name in its final folder,
//! flushed, then renamed, so a reader (or a resumed run) never sees a half-written file with
//! its final name. Reading: regular files only, at most [`MAX_FILE_BYTES`]
//! ([`crate::paths::read_capped`]).

use crate::DatasetError;
use std::io::Write;
use std::path::{Path, PathBuf};

/// The temporary name used while `path` is being written: `.<name>.<pid>.tmp` in the same
/// folder (same filesystem, so the final rename is atomic).
pub fn temp_path_for(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}.{}.tmp", std::process::id()))
}

/// Writes `bytes` to `path` atomically, creating parent folders as needed.
pub fn atomic_write(path: &Path, bytes: &[u8]) -> Result<(), DatasetError> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| DatasetError::io(parent, e))?;
    }
    let tmp = temp_path_for(path);
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(DatasetError::io(path, e));
    }
    Ok(())
}

/// Serialises `value` as pretty JSON and writes it atomically.
pub fn atomic_write_json<T: serde::Serialize>(path: &Path, value: &T) -> Result<(), DatasetError> {
    let mut text = serde_json::to_string_pretty(value)
        .map_err(|e| DatasetError::Json { path: path.into(), message: e.to_string() })?;
    text.push('\n');
    atomic_write(path, text.as_bytes())
}

/// The most bytes one dataset file may have (8 GiB): above the largest file a render writes
/// (the ground-truth EXR of a 16384 × 16384 view, six `f32` channels, about 6.4 GB before
/// compression), far below what a sparse or endless file would make a reader allocate.
pub const MAX_FILE_BYTES: u64 = 8 << 30;

/// Reads a whole regular file of at most [`MAX_FILE_BYTES`], naming it in the error.
pub fn read(path: &Path) -> Result<Vec<u8>, DatasetError> {
    crate::paths::read_capped(path, MAX_FILE_BYTES).map_err(|e| DatasetError::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn atomic_write_leaves_no_temporary() {
        let dir = std::env::temp_dir().join(format!("dataset-io-{}", std::process::id()));
        let path = dir.join("sub").join("a.txt");
        atomic_write(&path, b"hello").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"hello");
        assert!(!temp_path_for(&path).exists());
        let names: Vec<_> = std::fs::read_dir(path.parent().unwrap()).unwrap().collect();
        assert_eq!(names.len(), 1);
        std::fs::remove_dir_all(dir).unwrap();
    }
}
