//! The path tracer's error type. Every variant names the file or option at fault.

use std::path::PathBuf;

/// Errors from importing, rendering and writing datasets.
#[derive(Debug, thiserror::Error)]
pub enum PathTracerError {
    /// A scene file is malformed, unsupported or references something missing.
    #[error("{path}: {message}")]
    Import {
        /// The scene file (or the referenced file that failed).
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// An impossible option or configuration (zero resolution, zero views, ...).
    #[error("invalid option: {0}")]
    Config(String),
    /// Reading or writing a dataset file failed.
    #[error(transparent)]
    Dataset(#[from] dataset::DatasetError),
    /// Rendering was interrupted (e.g. Ctrl-C); finished views are kept.
    #[error("interrupted")]
    Interrupted,
}

impl PathTracerError {
    /// An import error for `path`.
    pub fn import(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Import { path: path.into(), message: message.into() }
    }
}
