//! Input encodings in plain Rust over slices, each with an exact, deterministic backward where
//! it has parameters:
//! - [`hashgrid`]: the multiresolution hash encoding of instant-ngp (Müller et al. 2022) and the
//!   [`Adam`] optimiser for its flat parameter table;
//! - [`sh`]: real spherical harmonics of a direction up to degree 4 (tiny-cuda-nn's);
//! - [`frequency`]: the NeRF paper's positional encoding.

pub mod frequency;
pub mod hashgrid;
pub mod sh;

pub use frequency::{frequency_encode, frequency_output_dim, frequency_point_gradient};
pub use hashgrid::{Adam, AdamConfig, HashGrid, HashGridConfig};
pub use sh::{sh_encode, sh_encode_batch};

/// Errors of the encodings.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum EncodingError {
    #[error("invalid hash-grid configuration: {0}")]
    InvalidConfig(String),
}
