use std::path::PathBuf;

/// Everything that can go wrong reading or writing a dataset. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// The file could not be read or written.
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
    pub(crate) fn image(path: impl Into<PathBuf>, message: impl ToString) -> Self {
        Self::Image { path: path.into(), message: message.to_string() }
    }
}
