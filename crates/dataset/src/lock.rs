//! One writer per folder: [`FolderLock`] is an advisory lock on `<folder>/.lock` (the OS's
//! `flock`, through `File::try_lock`), taken by every command that writes a dataset, shard or
//! run folder and held for the command's life. A second command writing into the same folder is
//! refused at once with [`DatasetError::Locked`], which names the holder's pid (written into the
//! lock file once it is held).
//!
//! - The kernel releases the lock when the holder exits or crashes; nothing is ever stale. A
//!   lock file a crash left behind holds nothing and is taken over.
//! - The holder removes the lock file when it lets go (and the folder too when taking the lock
//!   created it and nothing else was written), so a finished command leaves only its outputs. To
//!   make that removal safe, a lock counts only when the file it locked is still the one at
//!   `<folder>/.lock`; otherwise it is taken again on the new file.
//! - Readers of a folder ignore [`LOCK_FILE`]: it is no part of a dataset or a run.
//! - Where the filesystem has no locks at all (`Unsupported`), [`FolderLock::acquire`] returns a
//!   lock that [holds nothing](FolderLock::is_held), for the caller to warn about.
//!
//! ```
//! let dir = std::env::temp_dir().join(format!("folder-lock-doc-{}", std::process::id())).join("run");
//! let first = dataset::lock::FolderLock::acquire(&dir).unwrap();
//! let second = dataset::lock::FolderLock::acquire(&dir).unwrap_err().to_string();
//! assert!(second.contains(&format!("(pid {})", std::process::id())), "{second}");
//! drop(first);
//! assert!(!dir.exists(), "the folder the lock created is removed with it");
//! # std::fs::remove_dir_all(dir.parent().unwrap()).ok();
//! ```

use crate::DatasetError;
use std::fs::{File, OpenOptions, TryLockError};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

/// The lock file's name inside the folder it guards.
pub const LOCK_FILE: &str = ".lock";

/// How often a lock is taken again when its file is removed or replaced under it (by a holder
/// letting go) before giving up.
const ATTEMPTS: usize = 100;

/// The advisory lock on one folder, held until dropped (see the module docs).
#[derive(Debug)]
pub struct FolderLock {
    /// The locked file; `None` where the filesystem has no locks.
    file: Option<File>,
    /// `<dir>/.lock`.
    path: PathBuf,
    dir: PathBuf,
    /// The outermost folder that [`FolderLock::acquire`] created, removed on drop when empty.
    created: Option<PathBuf>,
}

impl FolderLock {
    /// Takes the lock of folder `dir`, creating the folder (and its parents) when missing.
    /// Refused with [`DatasetError::Locked`] when another process holds it.
    pub fn acquire(dir: &Path) -> Result<Self, DatasetError> {
        let created = dir.ancestors().take_while(|d| !d.as_os_str().is_empty() && !d.exists()).last().map(Path::to_path_buf);
        let path = dir.join(LOCK_FILE);
        let mut lock = Self { file: None, path, dir: dir.to_path_buf(), created };
        for _ in 0..ATTEMPTS {
            // Creating the folder and the lock file are writes: a refusal there is this node's storage.
            std::fs::create_dir_all(dir).map_err(|e| DatasetError::write(dir, e))?;
            let file = match open(&lock.path) {
                Ok(f) => f,
                // The folder was removed under us (an earlier holder letting go): create it again.
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
                Err(e) => return Err(DatasetError::write(&lock.path, e)),
            };
            match file.try_lock() {
                Ok(()) => {}
                Err(TryLockError::WouldBlock) => return Err(DatasetError::Locked { path: dir.to_path_buf(), pid: holder(&file) }),
                Err(TryLockError::Error(e)) if e.kind() == std::io::ErrorKind::Unsupported => return Ok(lock),
                Err(TryLockError::Error(e)) => return Err(DatasetError::io(&lock.path, e)),
            }
            if !is_at(&file, &lock.path) {
                continue;
            }
            // Best effort: a lock file only readable to us (another user's, left by a crash)
            // still locks, it just cannot name us.
            let mut w = &file;
            let _ = file.set_len(0).and_then(|()| w.seek(SeekFrom::Start(0))).and_then(|_| writeln!(w, "{}", std::process::id()));
            lock.file = Some(file);
            return Ok(lock);
        }
        Err(DatasetError::invalid(&lock.path, "the lock file keeps being removed or replaced while it is taken"))
    }

    /// Whether the lock is held: `false` only where the filesystem has no locks.
    pub fn is_held(&self) -> bool {
        self.file.is_some()
    }

    /// The lock file, `<folder>/.lock`.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for FolderLock {
    /// Removes the lock file while still holding it (unless it was moved or replaced), then the
    /// folders that taking the lock created when they hold nothing else; the lock is released
    /// when the file closes, after this.
    fn drop(&mut self) {
        if let Some(file) = &self.file
            && is_at(file, &self.path)
        {
            let _ = std::fs::remove_file(&self.path);
        }
        if let Some(top) = &self.created {
            for d in self.dir.ancestors() {
                if std::fs::remove_dir(d).is_err() || d == top {
                    break;
                }
            }
        }
    }
}

/// Opens (creating) a lock file for writing its holder's pid, or only for reading when that is
/// all the file's permissions allow.
fn open(path: &Path) -> std::io::Result<File> {
    match OpenOptions::new().read(true).write(true).create(true).truncate(false).open(path) {
        Err(e) if e.kind() == std::io::ErrorKind::PermissionDenied => File::open(path),
        r => r,
    }
}

/// The pid the holder wrote into its lock file. The holder writes it just after taking the
/// lock, so an empty file is read again a few times.
fn holder(file: &File) -> Option<u32> {
    for _ in 0..10 {
        let mut text = String::new();
        let mut r = file;
        if r.seek(SeekFrom::Start(0)).is_ok()
            && r.read_to_string(&mut text).is_ok()
            && let Ok(pid) = text.trim().parse()
        {
            return Some(pid);
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    None
}

/// Whether `file` is still the file at `path` (not removed or replaced since it was opened).
#[cfg(unix)]
fn is_at(file: &File, path: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (file.metadata(), std::fs::metadata(path)) {
        (Ok(a), Ok(b)) => (a.dev(), a.ino()) == (b.dev(), b.ino()),
        _ => false,
    }
}

/// Whether `file` is still the file at `path`: without inode numbers, whether one is there.
#[cfg(not(unix))]
fn is_at(_file: &File, path: &Path) -> bool {
    path.is_file()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An empty folder of its own for each test.
    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("folder-lock-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn a_second_lock_is_refused_naming_the_holder_until_the_first_is_dropped() {
        let tmp = scratch("second");
        let dir = tmp.join("a").join("run");
        let first = FolderLock::acquire(&dir).unwrap();
        assert!(first.is_held());
        let path = dir.join(LOCK_FILE);
        assert_eq!(first.path(), path);
        assert_eq!(std::fs::read_to_string(&path).unwrap().trim(), std::process::id().to_string());
        // The OS lock itself: another open file description of the same file cannot take it.
        let other = File::open(&path).unwrap();
        assert!(matches!(other.try_lock(), Err(TryLockError::WouldBlock)));
        drop(other);
        let e = FolderLock::acquire(&dir).unwrap_err();
        assert!(matches!(e, DatasetError::Locked { pid: Some(p), .. } if p == std::process::id()), "{e:?}");
        let msg = e.to_string();
        assert!(msg.starts_with(&dir.display().to_string()), "{msg}");
        assert!(msg.contains(&format!("another xtask process (pid {}) is writing this folder", std::process::id())), "{msg}");
        std::fs::write(dir.join("notes.txt"), b"mine").unwrap();
        drop(first);
        assert!(!path.exists(), "the lock file is removed when let go");
        assert_eq!(std::fs::read(dir.join("notes.txt")).unwrap(), b"mine", "a folder with content stays");
        let again = FolderLock::acquire(&dir).unwrap();
        assert!(again.is_held() && path.is_file());
        drop(again);
        // Nothing but the lock was written: the folders it created go with it, the others stay.
        std::fs::remove_file(dir.join("notes.txt")).unwrap();
        let existing = FolderLock::acquire(&dir).unwrap();
        drop(existing);
        assert!(dir.is_dir(), "a folder that existed before is kept");
        let deep = tmp.join("b").join("c").join("d");
        drop(FolderLock::acquire(&deep).unwrap());
        assert!(!tmp.join("b").exists(), "every folder the lock created is removed with it");
        std::fs::remove_dir_all(&tmp).unwrap();
    }

    #[test]
    fn a_lock_file_left_by_a_crash_or_replaced_under_a_holder_is_taken_over() {
        let dir = scratch("crash");
        // Left by a killed process: its pid inside, no lock on it.
        std::fs::write(dir.join(LOCK_FILE), "999999999\n").unwrap();
        let lock = FolderLock::acquire(&dir).unwrap();
        assert_eq!(std::fs::read_to_string(dir.join(LOCK_FILE)).unwrap().trim(), std::process::id().to_string());
        // A holder whose file was replaced (removed by hand, a new one made) no longer counts:
        // the new file is free, and dropping the old holder leaves the new file alone.
        std::fs::remove_file(dir.join(LOCK_FILE)).unwrap();
        let second = FolderLock::acquire(&dir).unwrap();
        drop(lock);
        assert!(dir.join(LOCK_FILE).is_file(), "the old holder removed its successor's lock file");
        assert!(FolderLock::acquire(&dir).is_err());
        drop(second);
        assert!(!dir.join(LOCK_FILE).exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
