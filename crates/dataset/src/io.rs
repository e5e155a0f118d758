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

/// The file a temporary name stands for and the writer's pid, when `name` is one
/// (`.<file>.<pid>.tmp`, [`temp_path_for`]).
pub fn temporary_of(name: &str) -> Option<(&str, u32)> {
    let (file, pid) = name.strip_prefix('.')?.strip_suffix(".tmp")?.rsplit_once('.')?;
    if file.is_empty() || pid.is_empty() || !pid.chars().all(|c| c.is_ascii_digit()) {
        return None;
    }
    Some((file, pid.parse().ok()?))
}

/// Whether process `pid` runs on this machine: the writer of a temporary that may still be
/// at work. Read from `/proc`; where there is none, only this process counts.
pub fn process_running(pid: u32) -> bool {
    if pid == std::process::id() {
        return true;
    }
    let proc = Path::new("/proc");
    proc.join("self").exists() && proc.join(pid.to_string()).exists()
}

/// Removes the temporaries in `dir` (files, or folders a whole output was assembled in) of the
/// files `owns` accepts, left by a writer that no longer runs (killed, or stopped by a power
/// cut); returns what was removed. A missing `dir` holds none.
pub fn remove_stale_temporaries(dir: &Path, owns: impl Fn(&str) -> bool) -> Result<Vec<PathBuf>, DatasetError> {
    let mut removed = Vec::new();
    let Ok(entries) = std::fs::read_dir(dir) else { return Ok(removed) };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some((file, pid)) = temporary_of(&name) else { continue };
        if !owns(file) || process_running(pid) {
            continue;
        }
        let p = e.path();
        let gone = match std::fs::symlink_metadata(&p) {
            Ok(m) if m.is_dir() => std::fs::remove_dir_all(&p),
            _ => std::fs::remove_file(&p),
        };
        match gone {
            Ok(()) => removed.push(p),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(DatasetError::io(&p, e)),
        }
    }
    Ok(removed)
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

    #[test]
    fn stale_temporaries_of_the_named_files_are_removed_and_nothing_else() {
        let dir = std::env::temp_dir().join(format!("dataset-io-stale-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let d = dir.as_path();
        // No process has pid 0 in /proc; this process's own temporaries are at work.
        let dead = if Path::new("/proc/self").exists() { 0 } else { 1 };
        let mine = std::process::id();
        let gone = [format!(".eval.json.{dead}.tmp"), format!(".out.merge.{dead}.tmp")];
        let kept = [format!(".eval.json.{mine}.tmp"), format!(".notes.txt.{dead}.tmp"), ".eval.json.tmp".into(), "eval.json".into()];
        std::fs::create_dir_all(d.join(&gone[1]).join("train")).unwrap();
        std::fs::write(d.join(&gone[1]).join("train/r_0.png"), b"x").unwrap();
        for f in [&gone[0]].into_iter().chain(&kept) {
            std::fs::write(d.join(f), b"x").unwrap();
        }
        let removed = remove_stale_temporaries(d, |f| f == "eval.json" || f == "out.merge").unwrap();
        assert_eq!(removed.len(), 2, "{removed:?}");
        assert!(gone.iter().all(|f| !d.join(f).exists()) && kept.iter().all(|f| d.join(f).exists()));
        assert_eq!(temporary_of(".a.b.12.tmp"), Some(("a.b", 12)));
        assert_eq!(temporary_of(".a.tmp"), None);
        assert!(remove_stale_temporaries(&d.join("missing"), |_| true).unwrap().is_empty());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
