//! The one place that chooses the burn device. Everything else takes a [`Device`] argument
//! and does not care where it runs.
//!
//! The default is burn's pure-Rust CPU backend `flex`; building the crate with the `ndarray`
//! feature selects burn's `ndarray` backend instead (kept for comparison, deprecated upstream).
//! Training uses the same device wrapped in autodiff; inference uses the plain device (a
//! module's `valid()` copy lives there).

use burn::tensor::Device;

/// The plain (inference) device.
pub fn inference_device() -> Device {
    #[cfg(feature = "ndarray")]
    #[allow(deprecated)]
    {
        Device::ndarray()
    }
    #[cfg(not(feature = "ndarray"))]
    {
        Device::flex()
    }
}

/// The training device: [`inference_device`] with automatic differentiation.
pub fn train_device() -> Device {
    inference_device().autodiff()
}

/// A short name of the backend in use, recorded in metrics and printed by the bench.
pub fn backend_name() -> &'static str {
    if cfg!(feature = "ndarray") { "ndarray" } else { "flex" }
}

/// Measured dense-matmul throughput of the inference device: an `n`×`n` by `n`×`n` product,
/// best of three after a warm-up, in GFLOP/s (2n³ FLOPs). The reference for the MLP's
/// achieved throughput in `cargo xtask bench nerf`.
pub fn matmul_peak_gflops(n: usize) -> f64 {
    use burn::tensor::{Tensor, TensorData};
    let dev = inference_device();
    let data = |s: u64| {
        let v: Vec<f32> = (0..n * n).map(|k| crate::kernels::uniform(s, 0, 0, k as u64) - 0.5).collect();
        Tensor::<2>::from_data(TensorData::new(v, [n, n]), &dev)
    };
    let (a, b) = (data(1), data(2));
    let _ = a.clone().matmul(b.clone()).into_data();
    let mut best = f64::INFINITY;
    for _ in 0..3 {
        let t = std::time::Instant::now();
        let _ = a.clone().matmul(b.clone()).into_data();
        best = best.min(t.elapsed().as_secs_f64());
    }
    2.0 * (n as f64).powi(3) / best / 1e9
}
