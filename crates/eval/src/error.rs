//! Typed errors of the evaluation crate.

use std::path::PathBuf;

/// A metric could not be computed from the arrays it was given.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MetricError {
    /// Two arrays that must describe the same pixels (or rays) have different lengths.
    #[error("{what}: expected {expected} values, got {got}")]
    Length {
        /// Which array is wrong.
        what: &'static str,
        /// Length implied by the other inputs.
        expected: usize,
        /// Length received.
        got: usize,
    },
    /// The image is smaller than the metric's window (SSIM needs at least 11x11).
    #[error("image of {width}x{height} is smaller than the {window}x{window} window")]
    TooSmall {
        /// Image width in pixels.
        width: usize,
        /// Image height in pixels.
        height: usize,
        /// Window side in pixels.
        window: usize,
    },
    /// No pixel or ray passed the mask (e.g. no foreground pixel), so the mean is undefined.
    #[error("{0}: no pixel or ray passes the mask, the metric is undefined")]
    EmptyMask(&'static str),
    /// Ragged-array offsets are not a non-decreasing sequence starting at 0 and ending at the sample count.
    #[error("ray offsets are invalid: {0}")]
    Offsets(String),
    /// An image has zero pixels or zero channels.
    #[error("{0}: image is empty")]
    Empty(&'static str),
}

/// Anything that can go wrong while evaluating a run, reading its metrics or writing its report.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// A metric failed on one view.
    #[error("view {view:?}: {source}")]
    Metric {
        /// Name of the view.
        view: String,
        /// What went wrong.
        #[source]
        source: MetricError,
    },
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating-system error.
        #[source]
        source: std::io::Error,
    },
    /// A line of a `metrics.jsonl` file is not a valid record.
    #[error("{path}:{line}: {message}")]
    Jsonl {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// The parser's message.
        message: String,
    },
    /// Serialising or parsing a JSON file failed.
    #[error("{path}: {source}")]
    Json {
        /// The file.
        path: PathBuf,
        /// The serde_json error.
        #[source]
        source: serde_json::Error,
    },
    /// Drawing a picture failed.
    #[error("{path}: drawing failed: {message}")]
    Plot {
        /// The picture being drawn.
        path: PathBuf,
        /// The plotting backend's message.
        message: String,
    },
    /// Encoding a PNG failed.
    #[error("{path}: PNG encoding failed: {source}")]
    Png {
        /// The picture being written.
        path: PathBuf,
        /// The encoder's error.
        #[source]
        source: image::ImageError,
    },
    /// Reading the dataset (cameras, ground truth) failed.
    #[error(transparent)]
    Dataset(#[from] dataset::DatasetError),
    /// Loading or rendering the trained run failed.
    #[error("{run}: {message}")]
    Run {
        /// The run folder.
        run: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// The inputs to a report are inconsistent (e.g. no views, or no runs to compare).
    #[error("{0}")]
    Input(String),
}
