//! The interface every model implements: [`ModelKind`] for its settings (name, checks, the
//! training preset, building the model) and [`NerfModel`] for a built model (a training step,
//! rendering rays, queries, checkpoints), with the types they exchange and the helpers the
//! models share (loss, finiteness, checkpointing burn parameters and their Adam state).

use crate::checkpoint::StateDict;
use crate::data::{Background, RayBatch, SceneBounds};
use crate::field::MlpAdam;
use crate::occupancy::OccupancyGrid;
use serde::{Deserialize, Serialize};
use std::any::Any;

/// A built model of any kind (what [`ModelKind::init`] returns).
pub type Model = Box<dyn NerfModel>;

/// A model's settings: what the trainer and the CLI ask of every kind. Implemented by each
/// model's config and reached through [`super::ModelConfig::kind`].
pub trait ModelKind {
    /// The model's name: `--model`'s value and the `kind` tag in `config.json`.
    fn name(&self) -> &'static str;
    /// Refuses settings no model can be built or trained with, naming the field (the config
    /// file may come from a user).
    fn check(&self) -> Result<(), String>;
    /// Builds the model, its parameters a function of `seed`; errors on invalid settings.
    fn init(&self, bounds: &SceneBounds, seed: u64) -> Result<Model, String>;
    /// The training settings this model is published with, sized for a CPU.
    fn preset(&self) -> TrainPreset;
    /// Pixel footprints of the 3 × 3 depth range that marks a pixel mixed, when the loss leaves
    /// mixed pixels' rays out ([`crate::data::mixed_pixels`]); `None` when it does not.
    fn mixed_pixel_footprints(&self) -> Option<f64> {
        None
    }
}

/// A model's training preset ([`crate::train::TrainConfig::preset`]).
#[derive(Clone, Debug, PartialEq)]
pub struct TrainPreset {
    /// Rays per step (the first step's when `batch_samples` is set).
    pub batch_rays: usize,
    /// Samples per step, the rays following from the mean samples per ray.
    pub batch_samples: Option<usize>,
    /// Learning rate at step 0.
    pub lr_init: f64,
    /// Learning rate after `lr_decay_steps`.
    pub lr_final: f64,
    /// Steps of the exponential decay from `lr_init` to `lr_final`.
    pub lr_decay_steps: u64,
    /// What is behind transparent training pixels.
    pub background: Background,
}

/// A built model: one training step, rendering and queries, and its checkpoint state.
pub trait NerfModel: Any + std::fmt::Debug + Send {
    /// One optimisation step on `batch` at step index `step` (random numbers keyed by
    /// `(seed, step)`).
    fn train_step(&mut self, batch: &RayBatch, step: u64, seed: u64) -> StepStats;
    /// Sets the learning rate of the next steps (the trainer's schedule).
    fn set_lr(&mut self, lr: f64);
    /// Asks later steps for the rays' gradients ([`RayGradients`]). A model that cannot give
    /// them refuses anything but `Off`, with the reason.
    fn set_ray_gradients(&mut self, mode: RayGradients) -> Result<(), String> {
        match mode {
            RayGradients::Off => Ok(()),
            _ => Err("this model does not give the loss's gradient with respect to its rays".to_string()),
        }
    }
    /// Renders rays (inference, deterministic).
    fn render_rays(&self, origins: &[[f32; 3]], dirs: &[[f32; 3]], background: [f32; 3]) -> RayOutputs;
    /// Density σ (1/m) at world points.
    fn density(&self, points: &[[f32; 3]]) -> Vec<f32>;
    /// Density and display (sRGB) colour at world points, each seen along its unit direction.
    ///
    /// # Shapes
    /// `points`, `dirs`: n; returns n densities and n colours.
    fn query(&self, points: &[[f32; 3]], dirs: &[[f32; 3]]) -> (Vec<f32>, Vec<[f32; 3]>);
    /// The scene bounds the model covers.
    fn bounds(&self) -> &SceneBounds;
    /// The occupancy grid, if the model keeps one, and the density below which it marks a cell
    /// empty: every density sampled in an empty cell was at most that (1/m).
    fn occupancy(&self) -> Option<(&OccupancyGrid, f32)> {
        None
    }
    /// Number of trainable parameters.
    fn parameters(&self) -> usize;
    /// Parameters, optimiser state and whatever else a resumed run needs.
    fn state(&self) -> StateDict;
    /// Restores [`Self::state`].
    fn load_state(&mut self, s: &StateDict) -> Result<(), String>;
    /// Multiply-adds per network evaluation of one sample (forward), for FLOP estimates.
    fn macs_per_sample(&self) -> f64;
}

impl dyn NerfModel {
    /// The model as its concrete type, when it is a `T` (for what only one kind offers).
    pub fn downcast_ref<T: NerfModel>(&self) -> Option<&T> {
        (self as &dyn Any).downcast_ref()
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
    /// The loss's gradient with respect to the batch's rays, when asked for
    /// ([`NerfModel::set_ray_gradients`]) and the step was not skipped.
    pub ray_grads: Option<RayGrads>,
}

/// The loss's gradient with respect to each ray's origin and unit direction (batch order).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RayGrads {
    /// `∂L/∂o` per ray.
    pub d_origins: Vec<[f32; 3]>,
    /// `∂L/∂d` per ray.
    pub d_dirs: Vec<[f32; 3]>,
}

/// Whether a training step also returns [`RayGrads`] (camera refinement), and whether it
/// updates the model.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum RayGradients {
    /// Train only (every model).
    #[default]
    Off,
    /// Train and return the rays' gradients (computed before the update).
    Also,
    /// Return the rays' gradients and leave the model unchanged (a frozen model, as when the
    /// poses of held-out views are optimised).
    Only,
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

/// Saves an [`MlpAdam`] into a state dict under `prefix`.
pub(crate) fn save_adam(s: &mut StateDict, prefix: &str, adam: &MlpAdam) {
    for (k, st) in adam.export().into_iter().enumerate() {
        if let Some((time, m1, m2)) = st {
            s.scalars.insert(format!("{prefix}.{k}.time"), time as f64);
            s.arrays.insert(format!("{prefix}.{k}.m1"), m1);
            s.arrays.insert(format!("{prefix}.{k}.m2"), m2);
        }
    }
}

/// Restores what [`save_adam`] wrote, for a module of `n_params` parameter tensors.
pub(crate) fn load_adam(s: &StateDict, prefix: &str, adam: &mut MlpAdam, n_params: usize) {
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
