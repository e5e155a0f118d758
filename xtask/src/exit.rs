//! The process's exit codes: what a scheduler (Ray, Slurm, a shell script) reads to decide
//! whether a failed command is worth running again, here or on another node.
//!
//! | code | meaning | retry? |
//! |---|---|---|
//! | 0 | done | |
//! | 1 | refused: bad input or options (a missing or malformed file, an impossible value, a folder holding something else) | no: every node refuses it the same way |
//! | 74 | this node's storage failed (sysexits' `EX_IOERR`): disk full, quota, a read-only or unwritable output folder, a disk error | yes, elsewhere |
//! | 130 | stopped by Ctrl-C, SIGTERM or SIGHUP after saving its work | re-run to resume |
//!
//! [`code_of`] classifies an error by the OS errors in its `source()` chain. Storage faults
//! (`ENOSPC`, `EDQUOT`, `EROFS`, `EFBIG`, `ESTALE`, `EIO`) count wherever they occur;
//! permission (`EACCES`, `EPERM`) only on writing an output, marked by a
//! [`dataset::WriteError`] in the chain: an input the user cannot read is refused like a
//! missing one. A panic keeps Rust's 101 and a signal without a handler its own status; both
//! are faults of the process or node.

use std::io::ErrorKind;

/// Done.
pub const SUCCESS: u8 = 0;
/// Refused: bad input or options, the same on every node.
pub const REFUSED: u8 = 1;
/// An I/O error of this node's storage (sysexits' `EX_IOERR`).
pub const NODE_IO: u8 = 74;
/// Stopped by a signal after saving its work; a re-run resumes (128 + SIGINT, as shells report
/// a process that Ctrl-C ended).
pub const STOPPED: u8 = 130;

/// `EIO` on Linux and the BSDs: std names no [`ErrorKind`] for it.
const EIO: i32 = 5;

/// A long command stopped by Ctrl-C, SIGTERM or SIGHUP after saving what it had (finished views,
/// a checkpoint): its message says how to resume. Exit code [`STOPPED`].
#[derive(Debug)]
pub struct Stopped(pub String);

impl std::fmt::Display for Stopped {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Stopped {}

/// The exit code of a command that failed with `e`.
pub fn code_of(e: &anyhow::Error) -> u8 {
    let mut writing = false;
    for cause in e.chain() {
        if cause.is::<Stopped>() {
            return STOPPED;
        }
        if cause.is::<dataset::WriteError>() {
            writing = true;
        }
        if let Some(io) = cause.downcast_ref::<std::io::Error>() {
            return if node_io_failure(io, writing) { NODE_IO } else { REFUSED };
        }
    }
    REFUSED
}

/// Whether `e` is a fault of this node's storage rather than of the input (`writing`: it
/// happened writing an output).
fn node_io_failure(e: &std::io::Error, writing: bool) -> bool {
    match e.kind() {
        ErrorKind::StorageFull
        | ErrorKind::QuotaExceeded
        | ErrorKind::ReadOnlyFilesystem
        | ErrorKind::FileTooLarge
        | ErrorKind::StaleNetworkFileHandle => true,
        ErrorKind::PermissionDenied => writing,
        _ => cfg!(unix) && e.raw_os_error() == Some(EIO),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use anyhow::Context;
    use std::io;

    /// Linux errno values.
    const ENOENT: i32 = 2;
    const EPERM: i32 = 1;
    const EACCES: i32 = 13;
    const EFBIG: i32 = 27;
    const ENOSPC: i32 = 28;
    const EROFS: i32 = 30;
    const EDQUOT: i32 = 122;

    /// An OS error on writing `out`, wrapped the way the crates and the commands wrap it: a
    /// transparent variant of a crate's error, then context.
    fn on_write(errno: i32) -> anyhow::Error {
        let e = dataset::DatasetError::write("out/train/r_0.png", io::Error::from_raw_os_error(errno));
        let e = pathtracer::PathTracerError::from(e);
        anyhow::Error::new(e).context("rendering scene.gltf into out")
    }

    /// The same OS error on reading an input.
    fn on_read(errno: i32) -> anyhow::Error {
        let e = io::Error::from_raw_os_error(errno);
        anyhow::Error::new(e).context("scene.gltf")
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn storage_faults_are_the_nodes() {
        for errno in [ENOSPC, EDQUOT, EROFS, EFBIG, EIO] {
            assert_eq!(code_of(&on_write(errno)), NODE_IO, "errno {errno} on writing");
            assert_eq!(code_of(&on_read(errno)), NODE_IO, "errno {errno} on reading");
        }
        let train = nerf::train::TrainError::from(dataset::DatasetError::write("run/metrics.jsonl", io::Error::from_raw_os_error(ENOSPC)));
        assert_eq!(code_of(&anyhow::Error::new(train)), NODE_IO);
        let eval = eval::EvalError::from(dataset::DatasetError::write("run/report.json", io::Error::from_raw_os_error(EDQUOT)));
        assert_eq!(code_of(&anyhow::Error::new(eval)), NODE_IO);
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn permission_is_the_nodes_on_writing_and_a_refusal_on_reading() {
        for errno in [EACCES, EPERM] {
            assert_eq!(code_of(&on_write(errno)), NODE_IO, "errno {errno} on writing");
            assert_eq!(code_of(&on_read(errno)), REFUSED, "errno {errno} on reading");
        }
    }

    #[test]
    fn a_missing_input_and_a_parse_error_are_refusals() {
        let missing = io::Error::from(io::ErrorKind::NotFound);
        assert_eq!(code_of(&anyhow::Error::new(missing).context("scene file no.gltf")), REFUSED);
        let parse = serde_json::from_str::<serde_json::Value>("{").unwrap_err();
        assert_eq!(code_of(&anyhow::Error::new(parse).context("transforms_train.json")), REFUSED);
        let message: anyhow::Result<()> = Err(anyhow::anyhow!("--spp 0: at least one sample")).context("render");
        assert_eq!(code_of(&message.unwrap_err()), REFUSED);
        #[cfg(target_os = "linux")]
        assert_eq!(code_of(&on_read(ENOENT)), REFUSED);
    }

    #[test]
    fn a_stop_by_signal_is_its_own_code() {
        let e = anyhow::Error::new(Stopped("interrupted; re-run to resume".into())).context("demo");
        assert_eq!(code_of(&e), STOPPED);
    }
}
