//! The viewer's errors, each with the HTTP status it is answered with.

/// An error answering a request, or starting the server.
#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    /// A malformed or out-of-range parameter (400).
    #[error("{0}")]
    BadRequest(String),
    /// No such page, asset, view or endpoint (404).
    #[error("{0}")]
    NotFound(String),
    /// The wrong method for an endpoint (405).
    #[error("{0}")]
    Method(String),
    /// A newer request of the same page replaced this one before it started (409).
    #[error("{0}")]
    Stale(String),
    /// The run has nothing to render yet: no config or no checkpoint (503).
    #[error("{0}")]
    Unavailable(String),
    /// A file of the run or dataset could not be read (500).
    #[error("{0}")]
    Internal(String),
    /// The server could not listen on the address asked for.
    #[error("cannot listen on {addr}: {message}")]
    Bind {
        /// The address, `host:port`.
        addr: String,
        /// Why.
        message: String,
    },
}

impl ViewerError {
    /// The HTTP status code this error is answered with.
    pub fn status(&self) -> u16 {
        match self {
            Self::BadRequest(_) => 400,
            Self::NotFound(_) => 404,
            Self::Method(_) => 405,
            Self::Stale(_) => 409,
            Self::Unavailable(_) => 503,
            Self::Internal(_) | Self::Bind { .. } => 500,
        }
    }
}

/// A 400 error with `message`.
pub fn bad(message: impl Into<String>) -> ViewerError {
    ViewerError::BadRequest(message.into())
}
