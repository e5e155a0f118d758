//! Model glue over the shared kernels: the density activation a model config chooses and
//! per-sample views of per-ray inputs.
//!
//! The kernels themselves live in one place each: volume rendering in [`crate::volrend`],
//! encodings in [`crate::encoding`], samplers and the RNG in [`crate::sampling`], the occupancy
//! grid in [`crate::occupancy`], the random streams and parameter plumbing in [`crate::kernels`].

use crate::volrend;

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
