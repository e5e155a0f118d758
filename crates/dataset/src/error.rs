use std::path::PathBuf;

/// An output could not be written: creating, writing, renaming or removing a file or folder
/// failed with an OS error. It is a separate type, and stays in an error's `source()` chain
/// under every wrapper, so that a caller can tell this node's storage failing (disk full, a
/// quota, a read-only or unwritable folder, a disk error) from an input it cannot read.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {source}")]
pub struct WriteError {
    /// The file or folder being written.
    pub path: PathBuf,
    /// The OS error.
    #[source]
    pub source: std::io::Error,
}

/// Everything that can go wrong reading or writing a dataset. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// Writing an output failed ([`WriteError`]).
    #[error("{0}")]
    Write(#[source] WriteError),
    /// The file could not be read (or otherwise used other than by writing it).
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// The file is not valid JSON or lacks a required key.
    #[error("{path}: invalid JSON: {message}")]
    Json {
        /// The file.
        path: PathBuf,
        /// What serde said.
        message: String,
    },
    /// The file parsed but its content is inconsistent or impossible.
    #[error("{path}: {message}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// An image file could not be decoded or encoded.
    #[error("{path}: image error: {message}")]
    Image {
        /// The file.
        path: PathBuf,
        /// What the codec said.
        message: String,
    },
    /// Another process holds the folder's lock ([`crate::lock::FolderLock`]).
    #[error("{path}: another xtask process{} is writing this folder; wait for it to finish or stop it", pid.map_or(String::new(), |p| format!(" (pid {p})")))]
    Locked {
        /// The folder.
        path: PathBuf,
        /// The holder's process id, as it wrote it into the lock file.
        pid: Option<u32>,
    },
}

impl DatasetError {
    pub(crate) fn invalid(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Invalid { path: path.into(), message: message.into() }
    }
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io { path: path.into(), source }
    }
    /// A failed write (create, write, rename or remove) of the output `path`.
    pub fn write(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Write(WriteError { path: path.into(), source })
    }
    pub(crate) fn image(path: impl Into<PathBuf>, message: impl ToString) -> Self {
        Self::Image { path: path.into(), message: message.to_string() }
    }
}
