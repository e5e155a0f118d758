//! Reading the files that a dataset's transforms files or a glTF scene name: confined to the
//! folder that names them, regular files only, never more than a stated number of bytes.
//!
//! A `file_path` in `transforms_train.json` or a buffer's `uri` in a `.gltf` is data from
//! whoever made the folder, not a choice of the user's, so:
//!
//! - [`is_inside`]: the named path must lie inside the folder once `..` and every symbolic link
//!   are resolved (canonical paths); a path that does not exist is judged by its nearest
//!   existing ancestor, so a missing file is reported as missing, never probed for outside.
//!   The commands that read such folders admit outside paths only with `--allow-outside`.
//! - [`open_regular`]: opens without blocking (a FIFO cannot hang the open) and refuses
//!   anything but a regular file (`/dev/zero`, a FIFO, a folder) before a byte is read.
//! - [`read_capped`]: reads through `take(limit + 1)` and refuses a file that has more than
//!   `limit` bytes, whatever its metadata says.

use std::fs::{File, FileType};
use std::io::{self, Read};
use std::path::Path;

/// Whether `path` lies inside the folder `root` after resolving `..` and symbolic links. A
/// path that does not exist is judged by its nearest existing ancestor; an empty `root` is
/// the current folder. `false` when `root` itself cannot be resolved.
pub fn is_inside(root: &Path, path: &Path) -> bool {
    let here = |p: &Path| if p.as_os_str().is_empty() { Path::new(".").canonicalize() } else { p.canonicalize() };
    let Ok(root) = here(root) else { return false };
    path.ancestors().find_map(|a| here(a).ok()).is_some_and(|p| p.starts_with(&root))
}

/// Opens `path` for reading if it is a regular file (after following symbolic links). The open
/// does not block (a FIFO with no writer would otherwise wait forever); a device, FIFO, socket
/// or folder is refused with an error that says which it is.
pub fn open_regular(path: &Path) -> io::Result<File> {
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.custom_flags(libc::O_NONBLOCK);
    }
    #[cfg(not(unix))]
    {
        let kind = std::fs::metadata(path)?.file_type();
        if !kind.is_file() {
            return Err(not_regular(kind));
        }
    }
    let file = options.open(path)?;
    let kind = file.metadata()?.file_type();
    if !kind.is_file() {
        return Err(not_regular(kind));
    }
    Ok(file)
}

fn not_regular(kind: FileType) -> io::Error {
    let what = if kind.is_dir() {
        "a folder"
    } else {
        #[cfg(unix)]
        {
            use std::os::unix::fs::FileTypeExt;
            if kind.is_fifo() {
                "a FIFO (named pipe)"
            } else if kind.is_char_device() || kind.is_block_device() {
                "a device"
            } else if kind.is_socket() {
                "a socket"
            } else {
                "not a file"
            }
        }
        #[cfg(not(unix))]
        "not a file"
    };
    io::Error::new(io::ErrorKind::InvalidInput, format!("not a regular file ({what}); only regular files are read"))
}

/// The error of a file longer than `limit` bytes.
pub fn too_large(limit: u64) -> io::Error {
    io::Error::new(io::ErrorKind::FileTooLarge, format!("larger than the limit of {limit} bytes"))
}

/// Reads the regular file `path` ([`open_regular`]) whole if it has at most `limit` bytes;
/// a longer one is refused ([`too_large`]) after reading `limit + 1` bytes at most.
pub fn read_capped(path: &Path, limit: u64) -> io::Result<Vec<u8>> {
    let file = open_regular(path)?;
    // The length is only a capacity hint: a file may grow, or be a sparse giant.
    let hint = file.metadata().map_or(0, |m| m.len()).min(limit);
    read_to_end_capped(file, limit, hint)
}

/// Reads `reader` to its end if it yields at most `limit` bytes; refused ([`too_large`])
/// after `limit + 1` bytes. `hint`: the expected length, to size the buffer once.
pub fn read_to_end_capped(reader: impl Read, limit: u64, hint: u64) -> io::Result<Vec<u8>> {
    let mut bytes = Vec::with_capacity(usize::try_from(hint.min(limit)).unwrap_or(0));
    reader.take(limit.saturating_add(1)).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > limit {
        return Err(too_large(limit));
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;
    use std::time::{Duration, Instant};

    fn tmp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("dataset-paths-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn inside_means_inside_after_dot_dot_and_symlinks() {
        let d = tmp("inside");
        let root = d.join("root");
        std::fs::create_dir_all(root.join("sub")).unwrap();
        std::fs::write(root.join("sub/a.bin"), b"a").unwrap();
        std::fs::write(d.join("secret.txt"), b"s").unwrap();
        assert!(is_inside(&root, &root.join("sub/a.bin")));
        assert!(is_inside(&root, &root.join("sub/../sub/a.bin")));
        assert!(is_inside(&root, &root.join("../root/sub/a.bin")), "out and back in is inside");
        assert!(is_inside(&root, &root.join("sub/missing.bin")), "a missing file inside is judged by its folder");
        assert!(!is_inside(&root, &root.join("../secret.txt")));
        assert!(!is_inside(&root, &root.join("../missing.txt")), "a missing file outside is outside");
        assert!(!is_inside(&root, &root.join("sub/../../secret.txt")));
        assert!(!is_inside(&root, &d.join("secret.txt")), "an absolute path outside");
        assert!(!is_inside(&root, Path::new("/etc/passwd")));
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(d.join("secret.txt"), root.join("link.bin")).unwrap();
            std::os::unix::fs::symlink(&d, root.join("up")).unwrap();
            std::os::unix::fs::symlink(root.join("sub/a.bin"), root.join("alias.bin")).unwrap();
            assert!(!is_inside(&root, &root.join("link.bin")), "a symlink to a file outside");
            assert!(!is_inside(&root, &root.join("up/secret.txt")), "through a symlinked folder");
            assert!(!is_inside(&root, &root.join("up/missing.txt")), "missing, through a symlinked folder");
            assert!(is_inside(&root, &root.join("alias.bin")), "a symlink that stays inside");
        }
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn only_regular_files_are_read_and_never_beyond_the_cap() {
        let d = tmp("regular");
        let file = d.join("f.bin");
        std::fs::write(&file, b"0123456789").unwrap();
        assert_eq!(read_capped(&file, 10).unwrap(), b"0123456789");
        let e = read_capped(&file, 9).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::FileTooLarge);
        assert!(e.to_string().contains("limit of 9 bytes"), "{e}");
        let e = read_capped(&d, 100).unwrap_err().to_string();
        assert!(e.contains("not a regular file") && e.contains("folder"), "{e}");
        assert_eq!(read_to_end_capped(io::repeat(7), 1000, u64::MAX).unwrap_err().kind(), io::ErrorKind::FileTooLarge);
        #[cfg(unix)]
        {
            let start = Instant::now();
            for dev in ["/dev/zero", "/dev/urandom"] {
                let e = read_capped(Path::new(dev), 1 << 30).unwrap_err().to_string();
                assert!(e.contains("a device"), "{dev}: {e}");
            }
            let fifo = d.join("pipe");
            assert!(std::process::Command::new("mkfifo").arg(&fifo).status().unwrap().success());
            // In a thread, so that an open that blocks fails the test instead of hanging it.
            let (tx, rx) = std::sync::mpsc::channel();
            let f = fifo.clone();
            std::thread::spawn(move || tx.send(read_capped(&f, 100).map_err(|e| e.to_string())));
            let e = rx.recv_timeout(Duration::from_secs(5)).expect("reading a FIFO hung").unwrap_err();
            assert!(e.contains("FIFO"), "{e}");
            assert!(start.elapsed() < Duration::from_secs(5), "refusing devices and FIFOs took {:?}", start.elapsed());
        }
        std::fs::remove_dir_all(&d).unwrap();
    }
}
