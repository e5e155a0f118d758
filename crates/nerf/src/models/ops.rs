//! Model glue over the shared kernels: the random streams the trainer and models key their
//! counter-based numbers with, and the density activation a model config chooses.
//!
//! The kernels themselves live in one place each: volume rendering in [`crate::volrend`],
//! encodings in [`crate::encoding`], samplers and the RNG in [`crate::sampling`], the occupancy
//! grid in [`crate::occupancy`].

use crate::sampling::rng;
use crate::volrend;

/// A uniform number in [0, 1) that depends only on `(seed, stream, a, b)`
/// ([`rng::key`] of the four counters).
#[inline]
pub fn uniform(seed: u64, stream: u64, a: u64, b: u64) -> f32 {
    rng::uniform_f32(rng::key(&[seed, stream, a, b]))
}

/// Random streams (the `stream` key of [`uniform`]); the seeds handed to the shared samplers
/// are `rng::key(&[seed, stream])` so that no two uses share numbers.
pub mod stream {
    /// Which training pixel a ray of the batch uses.
    pub const PIXEL: u64 = 1;
    /// Stratified jitter along rays.
    pub const STRATIFIED: u64 = 2;
    /// Importance-sampling jitter.
    pub const PDF: u64 = 3;
    /// Random background colours.
    pub const BACKGROUND: u64 = 4;
    /// Occupancy-grid update points.
    pub const OCCUPANCY: u64 = 5;
    /// Parameter initialisation.
    pub const INIT: u64 = 6;
    /// Validation pixel subset.
    pub const VAL: u64 = 7;
    /// Marching start offset.
    pub const MARCH: u64 = 8;
}

/// The seed of a shared sampler for one random stream.
pub fn stream_seed(seed: u64, stream: u64) -> u64 {
    rng::key(&[seed, stream])
}

/// Density activation, applied in Rust to the network's raw density output (the functions are
/// [`volrend`]'s).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DensityActivation {
    /// `max(x, 0)` (the NeRF paper).
    Relu,
    /// `ln(1 + e^x)` (smooth; mip-NeRF and nerfstudio): [`volrend::softplus`].
    Softplus,
    /// `exp(min(x, 15))` (instant-ngp): [`volrend::trunc_exp`].
    TruncExp,
}

impl DensityActivation {
    /// σ = f(x).
    #[inline]
    pub fn forward(self, x: f32) -> f32 {
        match self {
            Self::Relu => x.max(0.0),
            Self::Softplus => volrend::softplus(x),
            Self::TruncExp => volrend::trunc_exp(x),
        }
    }
    /// ∂L/∂x given ∂L/∂σ.
    #[inline]
    pub fn backward(self, x: f32, grad: f32) -> f32 {
        match self {
            Self::Relu => {
                if x > 0.0 { grad } else { 0.0 }
            }
            Self::Softplus => volrend::softplus_backward(x, grad),
            Self::TruncExp => volrend::trunc_exp_backward(x, grad),
        }
    }
}

/// Per-sample colours `[n][3]` from a flat row-major slice.
pub fn rgb3(flat: &[f32]) -> Vec<[f32; 3]> {
    flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

/// The direction of each sample's ray (`dirs[ray_index[s]]`).
pub fn sample_dirs(ray_index: &[u32], dirs: &[[f32; 3]]) -> Vec<[f32; 3]> {
    ray_index.iter().map(|&r| dirs[r as usize]).collect()
}
