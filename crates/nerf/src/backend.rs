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
