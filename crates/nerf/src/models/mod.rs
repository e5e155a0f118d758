//! Models: a field plus its samplers and renderer, with one training step and ray rendering.
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

pub mod fast;
pub mod ops;
pub mod paper;

use crate::checkpoint::StateDict;
use crate::data::{RayBatch, SceneBounds};
use serde::{Deserialize, Serialize};

/// Which model and its settings.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum ModelConfig {
    /// The NeRF paper's model.
    Paper(paper::PaperConfig),
    /// The hash-grid model.
    Fast(fast::FastConfig),
}

impl ModelConfig {
    /// `"paper"` or `"fast"`.
    pub fn name(&self) -> &'static str {
        match self {
            ModelConfig::Paper(_) => "paper",
            ModelConfig::Fast(_) => "fast",
        }
    }
    /// Builds the model, its parameters a function of `seed`; errors on invalid settings.
    pub fn init(&self, bounds: &SceneBounds, seed: u64) -> Result<Model, String> {
        Ok(match self {
            // `FastModel::new` checks its settings and bounds itself; the paper model's
            // constructor cannot fail, so they are checked here.
            ModelConfig::Paper(c) => {
                c.check()?;
                bounds.check()?;
                Model::Paper(Box::new(paper::PaperModel::new(c.clone(), bounds.clone(), seed)))
            }
            ModelConfig::Fast(c) => Model::Fast(Box::new(fast::FastModel::new(c.clone(), bounds.clone(), seed)?)),
        })
    }

    /// Refuses settings no model can be built or trained with, naming the field (the config
    /// file may come from a user): see [`fast::FastConfig::check`] and
    /// [`paper::PaperConfig::check`].
    pub fn check(&self) -> Result<(), String> {
        match self {
            ModelConfig::Paper(c) => c.check(),
            ModelConfig::Fast(c) => c.check(),
        }
    }
}

/// Seconds spent in each part of a training step.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize)]
pub struct StepTimings {
    /// Sampling and input encodings (and, for `fast`, the hash-grid backward).
    pub encoding: f64,
    /// Network forward and backward (`paper`: in burn; `fast`: the fused sweep of
    /// [`crate::mlp::HashMlp::train_groups`], which also composites and takes the loss, so
    /// that its rendering time is counted here).
    pub mlp: f64,
    /// Volume rendering forward and backward, and the loss (`paper` only, see `mlp`).
    pub render: f64,
    /// Optimiser steps (burn Adam for the networks, sparse Adam for the hash table) and the
    /// occupancy-grid update.
    pub optimizer: f64,
    /// The phases inside the sums above, where a model measures them (`fast` does; 0 otherwise),
    /// for `bench nerf`'s roofline.
    #[serde(default)]
    pub phases: PhaseTimings,
}

/// Seconds in each phase of a `fast` training step (wall time, except `composite_cpu`).
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize)]
pub struct PhaseTimings {
    /// The trainer drawing the step's ray batch (pixels, rays, targets).
    pub batch: f64,
    /// Marching the occupancy grid and the marched samples' unit-cube points.
    pub march: f64,
    /// Hash-grid encoding forward of the samples the compaction pass reached (`StepStats::encoded`).
    pub hash_forward: f64,
    /// The density-only pass without gradients that finds where rays turn opaque (compaction).
    pub density_pass: f64,
    /// Gathering the kept samples' points, encodings and direction inputs.
    pub gather: f64,
    /// The fused sweep: density and colour networks forward and backward, compositing and loss.
    pub mlp_sweep: f64,
    /// CPU seconds (summed over threads) of the sweep spent compositing, taking the loss and
    /// the compositing backward (inside `mlp_sweep`).
    pub composite_cpu: f64,
    /// Hash-grid backward (scatter of the encoding's gradient into the table gradient). The
    /// `fast` model fuses it with the hash tables' sparse Adam level by level
    /// ([`crate::encoding::HashGrid::backward_adam`]); the fused tasks' wall time is split
    /// between this and `adam_hash` in proportion to the CPU time of each part.
    pub hash_backward: f64,
    /// burn Adam over the networks' parameters.
    pub adam_mlp: f64,
    /// Sparse Adam over the touched hash-table entries (see `hash_backward`).
    pub adam_hash: f64,
    /// Occupancy-grid update (every `grid_update_interval` steps).
    pub occupancy: f64,
}

impl PhaseTimings {
    /// Adds another step's phases.
    pub fn add(&mut self, o: &PhaseTimings) {
        self.batch += o.batch;
        self.march += o.march;
        self.hash_forward += o.hash_forward;
        self.density_pass += o.density_pass;
        self.gather += o.gather;
        self.mlp_sweep += o.mlp_sweep;
        self.composite_cpu += o.composite_cpu;
        self.hash_backward += o.hash_backward;
        self.adam_mlp += o.adam_mlp;
        self.adam_hash += o.adam_hash;
        self.occupancy += o.occupancy;
    }
}

impl StepTimings {
    /// Adds another step's timings.
    pub fn add(&mut self, o: &StepTimings) {
        self.encoding += o.encoding;
        self.mlp += o.mlp;
        self.render += o.render;
        self.optimizer += o.optimizer;
        self.phases.add(&o.phases);
    }
}

/// What one training step did.
#[derive(Clone, Debug, Default)]
pub struct StepStats {
    /// The loss (MSE of the final rendering; for `paper` coarse + fine).
    pub loss: f32,
    /// Mean squared error of the final colour (display values).
    pub mse: f32,
    /// Samples evaluated by the networks.
    pub samples: usize,
    /// Samples marched (`fast`: along each ray as far as the compaction's rounds reached, from
    /// `samples` up to the full march; else equal to `samples`).
    pub marched: usize,
    /// Samples hash-encoded and put through the density-only compaction pass (`fast`; equal to
    /// `marched`, since marching and encoding go in the same rounds).
    pub encoded: usize,
    /// Hash-table entries the sparse Adam step updated (`fast` only).
    pub touched: usize,
    /// Whether the update was skipped because the loss or a gradient was not finite.
    pub skipped_nonfinite: bool,
    /// Time split.
    pub timings: StepTimings,
}

/// Per-ray rendering results.
#[derive(Clone, Debug, Default)]
pub struct RayOutputs {
    /// Colour composited onto the background.
    pub rgb: Vec<[f32; 3]>,
    /// Opacity Σw.
    pub opacity: Vec<f32>,
    /// Expected termination distance Σwt / Σw (0 where opacity is 0).
    pub distance: Vec<f32>,
    /// Samples per ray: offsets (rays + 1), distances and weights.
    pub offsets: Vec<u32>,
    /// Each sample's expected termination distance within its interval
    /// ([`crate::volrend::termination_distance`]: the midpoint where the density is low).
    pub t: Vec<f32>,
    /// Sample weights.
    pub w: Vec<f32>,
}

impl RayOutputs {
    /// The chunks' outputs one after another, allocated once (growing by appends copied the
    /// per-sample arrays of an 800x800 view into fresh pages again and again).
    pub fn concat(parts: Vec<RayOutputs>) -> RayOutputs {
        let rays: usize = parts.iter().map(|p| p.rgb.len()).sum();
        let samples: usize = parts.iter().map(|p| p.t.len()).sum();
        let mut out = RayOutputs {
            rgb: Vec::with_capacity(rays),
            opacity: Vec::with_capacity(rays),
            distance: Vec::with_capacity(rays),
            offsets: Vec::with_capacity(rays + 1),
            t: Vec::with_capacity(samples),
            w: Vec::with_capacity(samples),
        };
        out.offsets.push(0);
        for p in parts {
            out.append(p);
        }
        out
    }

    /// Appends another chunk's outputs.
    pub fn append(&mut self, o: RayOutputs) {
        let base = self.t.len() as u32;
        if self.offsets.is_empty() {
            self.offsets.push(0);
        }
        self.offsets.extend(o.offsets.iter().skip(1).map(|v| v + base));
        self.rgb.extend(o.rgb);
        self.opacity.extend(o.opacity);
        self.distance.extend(o.distance);
        self.t.extend(o.t);
        self.w.extend(o.w);
    }
}

/// A model of either kind.
#[derive(Debug)]
pub enum Model {
    /// The NeRF paper's model.
    Paper(Box<paper::PaperModel>),
    /// The hash-grid model.
    Fast(Box<fast::FastModel>),
}

impl Model {
    /// One optimisation step on `batch` at step index `step` (random numbers keyed by
    /// `(seed, step)`).
    pub fn train_step(&mut self, batch: &RayBatch, step: u64, seed: u64) -> StepStats {
        match self {
            Model::Paper(m) => m.train_step(batch, step, seed),
            Model::Fast(m) => m.train_step(batch, step, seed),
        }
    }

    /// Renders rays (inference, deterministic).
    pub fn render_rays(&self, origins: &[[f32; 3]], dirs: &[[f32; 3]], background: [f32; 3]) -> RayOutputs {
        let chunk = match self {
            Model::Paper(_) => 1024,
            // It chunks and parallelises itself.
            Model::Fast(m) => return m.render_rays(origins, dirs, background),
        };
        let mut out = RayOutputs::default();
        for (o, d) in origins.chunks(chunk).zip(dirs.chunks(chunk)) {
            let part = match self {
                Model::Paper(m) => m.render_rays(o, d, background),
                Model::Fast(m) => m.render_rays(o, d, background),
            };
            out.append(part);
        }
        if out.offsets.is_empty() {
            out.offsets.push(0);
        }
        out
    }

    /// Density σ (1/m) at world points (the fine network for `paper`).
    pub fn density(&self, points: &[[f32; 3]]) -> Vec<f32> {
        match self {
            Model::Paper(m) => m.query(points, &vec![[0.0, 0.0, -1.0]; points.len()]).0,
            Model::Fast(m) => m.density(points),
        }
    }

    /// Density and display (sRGB) colour at world points, each seen along its unit direction.
    ///
    /// # Shapes
    /// `points`, `dirs`: n; returns n densities and n colours.
    pub fn query(&self, points: &[[f32; 3]], dirs: &[[f32; 3]]) -> (Vec<f32>, Vec<[f32; 3]>) {
        match self {
            Model::Paper(m) => m.query(points, dirs),
            Model::Fast(m) => m.query(points, dirs),
        }
    }

    /// The scene bounds the model covers.
    pub fn bounds(&self) -> &SceneBounds {
        match self {
            Model::Paper(m) => &m.bounds,
            Model::Fast(m) => &m.bounds,
        }
    }

    /// The occupancy grid (`fast` only) and the density below which it marks a cell empty:
    /// a cell is empty when its running density (the decayed maximum of the densities sampled
    /// in it) times the marching step is at most the grid threshold, so every density sampled
    /// there was at most `threshold / step` (1/m).
    pub fn occupancy(&self) -> Option<(&crate::occupancy::OccupancyGrid, f32)> {
        match self {
            Model::Paper(_) => None,
            Model::Fast(m) => Some((&m.occupancy, m.config.grid_threshold / m.step_size())),
        }
    }

    /// Number of trainable parameters.
    pub fn parameters(&self) -> usize {
        match self {
            Model::Paper(m) => m.parameters(),
            Model::Fast(m) => m.parameters(),
        }
    }

    /// Parameters, optimiser state and (for `fast`) the occupancy grid.
    pub fn state(&self) -> StateDict {
        match self {
            Model::Paper(m) => m.state(),
            Model::Fast(m) => m.state(),
        }
    }

    /// Restores [`Self::state`].
    pub fn load_state(&mut self, s: &StateDict) -> Result<(), String> {
        match self {
            Model::Paper(m) => m.load_state(s),
            Model::Fast(m) => m.load_state(s),
        }
    }

    /// Multiply-adds per network evaluation of one sample (forward), for FLOP estimates.
    pub fn macs_per_sample(&self) -> f64 {
        match self {
            Model::Paper(m) => m.macs_per_sample(),
            Model::Fast(m) => m.macs_per_sample(),
        }
    }
}

/// Mean squared error and its gradient w.r.t. the rendered colour (mean over rays and
/// channels).
pub(crate) fn mse_and_grad(rgb: &[[f32; 3]], target: &[[f32; 3]]) -> (f32, Vec<[f32; 3]>) {
    let n = (rgb.len() * 3).max(1) as f32;
    let (sum, grad) = squared_error_and_grad(rgb, target, n);
    ((sum / n as f64) as f32, grad)
}

/// The summed squared error of some rays and the gradient of `sum / n` w.r.t. their colour
/// (`n`: the number of values the mean is over, which may include other rays: the fast model
/// takes the loss group by group).
pub(crate) fn squared_error_and_grad(rgb: &[[f32; 3]], target: &[[f32; 3]], n: f32) -> (f64, Vec<[f32; 3]>) {
    let mut sum = 0.0f64;
    let grad = rgb
        .iter()
        .zip(target)
        .map(|(c, t)| {
            let mut g = [0.0; 3];
            for k in 0..3 {
                let e = c[k] - t[k];
                sum += (e * e) as f64;
                g[k] = 2.0 * e / n;
            }
            g
        })
        .collect();
    (sum, grad)
}

/// Σwt / Σw from [`crate::volrend`]'s unnormalised distance (0 where the opacity is ≤ 1e-6).
pub(crate) fn expected_distance(distance: f32, opacity: f32) -> f32 {
    if opacity > 1e-6 { crate::volrend::normalized_distance(distance, opacity, 1e-6) } else { 0.0 }
}

/// Whether every value is finite: blocks of values folded without a branch per value (so the
/// compiler vectorises the test; `Iterator::all` stops at each value and does not), stopping
/// after the first block with a non-finite one.
pub(crate) fn all_finite(v: &[f32]) -> bool {
    v.chunks(1024).all(|block| block.iter().fold(true, |ok, x| ok & x.is_finite()))
}

/// Saves an [`crate::field::MlpAdam`] into a state dict under `prefix`.
pub(crate) fn save_adam(s: &mut StateDict, prefix: &str, adam: &crate::field::MlpAdam) {
    for (k, st) in adam.export().into_iter().enumerate() {
        if let Some((time, m1, m2)) = st {
            s.scalars.insert(format!("{prefix}.{k}.time"), time as f64);
            s.arrays.insert(format!("{prefix}.{k}.m1"), m1);
            s.arrays.insert(format!("{prefix}.{k}.m2"), m2);
        }
    }
}

/// Restores what [`save_adam`] wrote, for a module of `n_params` parameter tensors.
pub(crate) fn load_adam(s: &StateDict, prefix: &str, adam: &mut crate::field::MlpAdam, n_params: usize) {
    let states = (0..n_params)
        .map(|k| {
            let time = s.scalars.get(&format!("{prefix}.{k}.time"))?;
            let m1 = s.arrays.get(&format!("{prefix}.{k}.m1"))?.clone();
            let m2 = s.arrays.get(&format!("{prefix}.{k}.m2"))?.clone();
            Some((*time as usize, m1, m2))
        })
        .collect();
    adam.import(states);
}

/// Saves a module's parameters under `prefix`.
pub(crate) fn save_params<M: burn::module::Module>(s: &mut StateDict, prefix: &str, m: &M) {
    for (k, v) in crate::kernels::param_vectors(m).into_iter().enumerate() {
        s.arrays.insert(format!("{prefix}.{k}"), v);
    }
}

/// Restores what [`save_params`] wrote.
pub(crate) fn load_params<M: burn::module::Module>(s: &StateDict, prefix: &str, m: M) -> Result<M, String> {
    let n = crate::kernels::param_vectors(&m).len();
    let values = (0..n)
        .map(|k| s.arrays.get(&format!("{prefix}.{k}")).cloned().ok_or_else(|| format!("checkpoint lacks {prefix}.{k}")))
        .collect::<Result<Vec<_>, _>>()?;
    crate::kernels::load_param_vectors(m, &values)
}

/// Refuses Adam settings that make no optimiser: β₁ and β₂ in [0, 1), ε finite and > 0 (the
/// fields `{prefix}.beta1`, `.beta2`, `.eps`).
pub fn check_adam(prefix: &str, beta1: f32, beta2: f32, eps: f32) -> Result<(), String> {
    for (field, b) in [("beta1", beta1), ("beta2", beta2)] {
        if !(0.0..1.0).contains(&b) {
            return Err(format!("{prefix}.{field} must be in [0, 1), not {b}"));
        }
    }
    if !(eps.is_finite() && eps > 0.0) {
        return Err(format!("{prefix}.eps must be a finite number > 0, not {eps}"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::all_finite;

    /// One NaN or infinity anywhere (first value, a block's last and next first, the last
    /// value, a short tail) makes the answer false; all finite values, extremes included, and
    /// no values make it true.
    #[test]
    fn all_finite_finds_any_non_finite_value() {
        let finite = [0.0, -0.0, f32::MAX, f32::MIN, f32::MIN_POSITIVE, 1e-45, -1.0];
        for n in [0usize, 1, 7, 1023, 1024, 1025, 4096 + 3] {
            let v: Vec<f32> = (0..n).map(|i| finite[i % finite.len()]).collect();
            assert!(all_finite(&v), "{n} finite values");
            for at in [0, 1022, 1023, 1024, n.saturating_sub(1)].into_iter().filter(|&i| i < n) {
                for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
                    let mut w = v.clone();
                    w[at] = bad;
                    assert!(!all_finite(&w), "{bad} at {at} of {n}");
                }
            }
        }
    }
}
