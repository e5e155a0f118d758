//! Input encodings (in progress).
