//! placeholder
pub mod error;
pub mod metrics;
