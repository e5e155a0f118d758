//! Atomic file output: every file is written under a temporary name in its final folder,
//! flushed, then renamed, so a reader (or a resumed run) never sees a half-written file with
//! its final name.

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
        std::fs::create_dir_all(parent).map_err(|e| DatasetError::write(parent, e))?;
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
        return Err(DatasetError::write(path, e));
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

/// Reads a whole file, naming it in the error.
pub fn read(path: &Path) -> Result<Vec<u8>, DatasetError> {
    std::fs::read(path).map_err(|e| DatasetError::io(path, e))
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

    /// A failed write is told apart from a failed read: a [`crate::WriteError`] that stays in
    /// the `source()` chain, so a caller can classify the OS error under it.
    #[test]
    fn a_failed_write_is_a_write_error_in_the_chain() {
        let dir = std::env::temp_dir().join(format!("dataset-io-fail-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("a-file");
        std::fs::write(&file, b"x").unwrap();
        let e = atomic_write(&file.join("under-a-file.json"), b"{}").unwrap_err();
        assert!(matches!(e, DatasetError::Write(_)), "{e:?}");
        let source = std::error::Error::source(&e).unwrap();
        assert!(source.downcast_ref::<crate::WriteError>().is_some(), "{source:?}");
        assert!(std::error::Error::source(source).unwrap().downcast_ref::<std::io::Error>().is_some());
        assert!(matches!(read(&dir.join("missing")), Err(DatasetError::Io { .. })));
        std::fs::remove_dir_all(dir).unwrap();
    }
}
