//! Fields: the burn networks that map encoded positions (and directions) to raw density and
//! colour, and burn's Adam stepped parameter by parameter with a state that checkpoints can
//! hold ([`MlpAdam`]). Seeded initialisation and flattening parameters are
//! [`crate::kernels`]'.
//!
//! Each network has a `#[derive(Config)]` config with `init(&device)`. Networks output the
//! *raw* density (the activation is applied in Rust next to the compositing kernel, so both
//! models share it) and the colour after its sigmoid.

use crate::kernels::to_vec;
use burn::config::Config;
use burn::module::{Module, ModuleMapper, Param};
use burn::nn::{Linear, LinearConfig};
use burn::optim::{Adam, AdamConfig, AdamState, GradientsParams, Optimizer};
use burn::tensor::activation::{relu, sigmoid};
use burn::tensor::{Device, Tensor, TensorData};
use std::any::Any;

/// A ReLU multilayer perceptron: `depth` hidden layers of `width`, the input re-injected
/// (concatenated) before each hidden layer listed in `skips`, then an optional linear output
/// layer without activation.
#[derive(Config, Debug)]
pub struct MlpConfig {
    /// Input width.
    pub d_in: usize,
    /// Hidden width.
    pub width: usize,
    /// Number of hidden (ReLU) layers.
    pub depth: usize,
    /// Output width of a final linear layer, or `None` to end with the last hidden layer.
    #[config(default = "None")]
    pub d_out: Option<usize>,
    /// Hidden-layer indices (0-based) whose input is `[previous, network input]`.
    #[config(default = "Vec::new()")]
    pub skips: Vec<usize>,
}

/// The network of [`MlpConfig`].
#[derive(Module, Debug)]
pub struct Mlp {
    /// Hidden layers, then the output layer when there is one.
    pub layers: Vec<Linear>,
    /// Layers with the input re-injected.
    pub skips: Vec<usize>,
    /// Number of hidden layers.
    pub depth: usize,
}

impl MlpConfig {
    /// Builds the network (values are later replaced by [`crate::kernels::seeded_init`]).
    pub fn init(&self, device: &Device) -> Mlp {
        let mut layers = Vec::new();
        let mut d = self.d_in;
        for i in 0..self.depth {
            let input = if self.skips.contains(&i) { d + self.d_in } else { d };
            layers.push(LinearConfig::new(input, self.width).init(device));
            d = self.width;
        }
        if let Some(out) = self.d_out {
            layers.push(LinearConfig::new(d, out).init(device));
        }
        Mlp { layers, skips: self.skips.clone(), depth: self.depth }
    }
}

impl Mlp {
    /// # Shapes
    /// `x`: [N, d_in] → [N, d_out or width].
    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        let mut h = x.clone();
        for (i, layer) in self.layers.iter().enumerate() {
            if self.skips.contains(&i) {
                h = Tensor::cat(vec![h, x.clone()], 1);
            }
            h = layer.forward(h);
            if i < self.depth {
                h = relu(h);
            }
        }
        h
    }
}

/// The NeRF paper's field (Mildenhall et al. 2020, fig. 7): γ(x) → 8×256 ReLU with γ(x)
/// re-injected at the fifth layer → raw density (1) and a 256 feature; [feature, γ(d)] →
/// 128 ReLU → RGB (sigmoid).
#[derive(Config, Debug)]
pub struct NerfFieldConfig {
    /// Positional-encoding frequencies of the position.
    #[config(default = 10)]
    pub pos_freqs: usize,
    /// Positional-encoding frequencies of the direction.
    #[config(default = 4)]
    pub dir_freqs: usize,
    /// Trunk width.
    #[config(default = 256)]
    pub width: usize,
    /// Trunk depth.
    #[config(default = 8)]
    pub depth: usize,
    /// Trunk layer (0-based) whose input re-injects γ(x): 5 = the paper's fifth-layer skip.
    #[config(default = 5)]
    pub skip: usize,
    /// Width of the view-dependent colour layer.
    #[config(default = 128)]
    pub color_width: usize,
}

/// The network of [`NerfFieldConfig`].
#[derive(Module, Debug)]
pub struct NerfField {
    /// γ(x) → feature trunk.
    pub trunk: Mlp,
    /// Trunk → raw density.
    pub density: Linear,
    /// Trunk → feature (no activation, as the paper).
    pub feature: Linear,
    /// [feature, γ(d)] → colour hidden layer.
    pub color_hidden: Linear,
    /// Hidden → RGB (sigmoid).
    pub color_out: Linear,
}

impl NerfFieldConfig {
    /// Width of γ(x).
    pub fn pos_dims(&self) -> usize {
        crate::encoding::frequency_output_dim(self.pos_freqs)
    }
    /// Width of γ(d).
    pub fn dir_dims(&self) -> usize {
        crate::encoding::frequency_output_dim(self.dir_freqs)
    }
    /// Builds the network.
    pub fn init(&self, device: &Device) -> NerfField {
        let skips = if self.skip > 0 && self.skip < self.depth { vec![self.skip] } else { vec![] };
        NerfField {
            trunk: MlpConfig::new(self.pos_dims(), self.width, self.depth).with_skips(skips).init(device),
            density: LinearConfig::new(self.width, 1).init(device),
            feature: LinearConfig::new(self.width, self.width).init(device),
            color_hidden: LinearConfig::new(self.width + self.dir_dims(), self.color_width).init(device),
            color_out: LinearConfig::new(self.color_width, 3).init(device),
        }
    }
}

impl NerfField {
    /// # Shapes
    /// `pos`: [N, pos_dims], `dir`: [N, dir_dims] → (raw density [N, 1], rgb [N, 3]).
    pub fn forward(&self, pos: Tensor<2>, dir: Tensor<2>) -> (Tensor<2>, Tensor<2>) {
        let h = self.trunk.forward(pos);
        let raw = self.density.forward(h.clone());
        let feat = self.feature.forward(h);
        let c = relu(self.color_hidden.forward(Tensor::cat(vec![feat, dir], 1)));
        (raw, sigmoid(self.color_out.forward(c)))
    }
}

/// The fast model's two small networks (instant-ngp's): hash features → `density_width` ReLU →
/// `geo_features` (the first is the raw density); [geo features, SH(d)] → `color_width` ×
/// `color_depth` ReLU → RGB (sigmoid).
#[derive(Config, Debug, PartialEq)]
pub struct HashFieldConfig {
    /// Width of the hash encoding (levels × features per level).
    pub encoding_dims: usize,
    /// Width of the direction encoding (SH coefficients).
    pub dir_dims: usize,
    /// Hidden width of the density network.
    #[config(default = 64)]
    pub density_width: usize,
    /// Geometry features passed to the colour network (the first is the raw density).
    #[config(default = 16)]
    pub geo_features: usize,
    /// Hidden width of the colour network.
    #[config(default = 64)]
    pub color_width: usize,
    /// Hidden layers of the colour network.
    #[config(default = 2)]
    pub color_depth: usize,
}

/// The networks of [`HashFieldConfig`].
#[derive(Module, Debug)]
pub struct HashField {
    /// Encoding → geometry features.
    pub density: Mlp,
    /// [geometry, SH] → RGB.
    pub color: Mlp,
}

impl HashFieldConfig {
    /// Builds the networks.
    pub fn init(&self, device: &Device) -> HashField {
        HashField {
            density: MlpConfig::new(self.encoding_dims, self.density_width, 1).with_d_out(Some(self.geo_features)).init(device),
            color: MlpConfig::new(self.geo_features + self.dir_dims, self.color_width, self.color_depth).with_d_out(Some(3))
                .init(device),
        }
    }
}

impl HashField {
    /// # Shapes
    /// `enc`: [N, encoding_dims], `sh`: [N, dir_dims] → (raw density [N, 1], rgb [N, 3]).
    pub fn forward(&self, enc: Tensor<2>, sh: Tensor<2>) -> (Tensor<2>, Tensor<2>) {
        let geo = self.density.forward(enc);
        let [n, _] = geo.dims();
        let raw = geo.clone().slice([0..n, 0..1]);
        let rgb = sigmoid(self.color.forward(Tensor::cat(vec![geo, sh], 1)));
        (raw, rgb)
    }
}

/// One parameter's Adam state as flat vectors: (time, first moment, second moment).
pub type MomentState = (usize, Vec<f32>, Vec<f32>);

/// burn's Adam applied parameter by parameter, its per-parameter state kept in visiting order
/// (not by burn's random parameter ids) so that it can be written to and read from a
/// checkpoint as flat vectors.
pub struct MlpAdam {
    optim: Adam,
    states: Vec<Option<Box<dyn Any + Send>>>,
    /// States read from a checkpoint, turned into tensors on the next step: (time, m1, m2).
    pending: Vec<Option<MomentState>>,
}

impl std::fmt::Debug for MlpAdam {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "MlpAdam({} states)", self.states.len())
    }
}

/// Adam hyper-parameters.
#[derive(Config, Debug)]
pub struct AdamSettings {
    /// β₁.
    pub beta1: f32,
    /// β₂.
    pub beta2: f32,
    /// ε.
    pub eps: f32,
}

impl MlpAdam {
    /// A fresh optimiser.
    pub fn new(s: &AdamSettings) -> Self {
        let optim = AdamConfig::new().with_beta_1(s.beta1).with_beta_2(s.beta2).with_epsilon(s.eps).build();
        Self { optim, states: Vec::new(), pending: Vec::new() }
    }

    /// One step of every parameter that has a gradient in `grads`.
    pub fn step<M: Module>(&mut self, lr: f64, module: M, grads: &mut GradientsParams) -> M {
        let mut m = AdamMapper { owner: self, grads, lr, index: 0 };
        module.map(&mut m)
    }

    /// The state as flat vectors per parameter (time, first moment, second moment); `None` for
    /// a parameter that has not been stepped.
    pub fn export(&self) -> Vec<Option<MomentState>> {
        let n = self.states.len().max(self.pending.len());
        (0..n)
            .map(|k| {
                if let Some(Some(s)) = self.states.get(k) {
                    if let Some(s) = s.downcast_ref::<AdamState<2>>() {
                        let m = &s.momentum;
                        return Some((m.time, to_vec(m.moment_1.clone()), to_vec(m.moment_2.clone())));
                    }
                    if let Some(s) = s.downcast_ref::<AdamState<1>>() {
                        let m = &s.momentum;
                        return Some((m.time, to_vec(m.moment_1.clone()), to_vec(m.moment_2.clone())));
                    }
                }
                self.pending.get(k).cloned().flatten()
            })
            .collect()
    }

    /// Restores a state written by [`Self::export`].
    pub fn import(&mut self, states: Vec<Option<MomentState>>) {
        self.states = states.iter().map(|_| None).collect();
        self.pending = states;
    }
}

struct AdamMapper<'a> {
    owner: &'a mut MlpAdam,
    grads: &'a mut GradientsParams,
    lr: f64,
    index: usize,
}

impl ModuleMapper for AdamMapper<'_> {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let k = self.index;
        self.index += 1;
        let (id, tensor, mapper) = param.consume();
        let Some(grad) = self.grads.remove::<D>(id) else {
            return Param::from_mapped_value(id, tensor, mapper);
        };
        if self.owner.states.len() <= k {
            self.owner.states.resize_with(k + 1, || None);
        }
        let dims = tensor.dims();
        let inner = tensor.inner();
        let device = inner.device();
        let mut state: Option<AdamState<D>> =
            self.owner.states[k].take().and_then(|b| b.downcast::<AdamState<D>>().ok().map(|b| *b));
        if state.is_none()
            && let Some(Some((time, m1, m2))) = self.owner.pending.get_mut(k).map(Option::take)
        {
            let t = |v: Vec<f32>| Tensor::<D>::from_data(TensorData::new(v, dims.to_vec()), &device);
            state = Some(AdamState::new(burn::optim::AdaptiveMomentumState::new(time, t(m1), t(m2))));
        }
        let (updated, new_state) = self.owner.optim.step(self.lr, inner, grad, state);
        self.owner.states[k] = new_state.map(|s| Box::new(s) as Box<dyn Any + Send>);
        Param::from_mapped_value(id, Tensor::from_inner(updated).require_grad(), mapper)
    }
}
