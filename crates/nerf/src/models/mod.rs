//! Models: a field plus its samplers and renderer, with one training step and ray rendering,
//! behind one interface ([`ModelKind`] for the settings, [`NerfModel`] for a built model).
//!
//! - [`paper`]: the NeRF paper (positional encoding, 8×256 MLP, hierarchical sampling).
//! - [`fast`]: instant-ngp's recipe (hash encoding, tiny MLPs, occupancy grid).
//!
//! Both share the training-step pattern: inputs are encoded in Rust, the networks give
//! per-sample raw density and colour, and Rust applies the density activation, volume
//! rendering ([`crate::volrend::composite_forward`]) and the loss and its gradient w.r.t. the
//! per-sample outputs. The paper model's networks run in burn, and those gradients go back
//! into burn through the surrogate `sum(output · grad.detach())`, whose backward gives exactly
//! the parameter gradients of the loss; the fast model's small networks run as fused Rust
//! kernels with a hand-written backward ([`crate::mlp`]), whose parameter gradients are handed
//! to burn's optimiser. burn's Adam steps both.
//!
//! A new model is one file (its config implementing [`ModelKind`], its model [`NerfModel`])
//! plus its registration in [`ModelConfig`]: a variant (whose lower-case name is the `kind`
//! tag in `config.json`), its arm in [`ModelConfig::kind`] and its default in `REGISTRY`.

mod base;
pub mod fast;
pub mod ops;
pub mod paper;

pub use base::{Model, ModelKind, NerfModel, PhaseTimings, RayGradients, RayGrads, RayOutputs, StepStats, StepTimings, TrainPreset};
use serde::{Deserialize, Serialize};

/// Which model and its settings (`config.json`'s `model`, tagged by `kind`).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum ModelConfig {
    /// The NeRF paper's model.
    Paper(paper::PaperConfig),
    /// The hash-grid model.
    Fast(fast::FastConfig),
}

/// Every model's default settings, in the order the CLI lists them.
const REGISTRY: &[fn() -> ModelConfig] = &[|| ModelConfig::Paper(paper::PaperConfig::new()), || ModelConfig::Fast(fast::FastConfig::new())];

impl ModelConfig {
    /// The settings as the interface every model implements.
    pub fn kind(&self) -> &dyn ModelKind {
        match self {
            ModelConfig::Paper(c) => c,
            ModelConfig::Fast(c) => c,
        }
    }

    /// The default settings of the model called `name`, if there is one.
    pub fn named(name: &str) -> Option<ModelConfig> {
        REGISTRY.iter().map(|default| default()).find(|c| c.name() == name)
    }

    /// Every model's name, in registration order.
    pub fn names() -> Vec<&'static str> {
        REGISTRY.iter().map(|default| default().name()).collect()
    }

    /// The model's name ([`ModelKind::name`]).
    pub fn name(&self) -> &'static str {
        self.kind().name()
    }

    /// Builds the model, its parameters a function of `seed` ([`ModelKind::init`]).
    pub fn init(&self, bounds: &crate::data::SceneBounds, seed: u64) -> Result<Model, String> {
        self.kind().init(bounds, seed)
    }

    /// Refuses settings no model can be built or trained with ([`ModelKind::check`]).
    pub fn check(&self) -> Result<(), String> {
        self.kind().check()
    }
}
