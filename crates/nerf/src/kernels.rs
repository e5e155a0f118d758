//! Small helpers the kernels, fields and models share, kept below all of them so that no layer
//! borrows from a higher one:
//! - counter-based random numbers keyed by `(seed, stream, a, b)` ([`uniform`], [`stream`]);
//! - burn tensors to and from flat `f32` vectors ([`tensor2`], [`to_vec`]);
//! - parameter plumbing for any burn module: seeded initialisation ([`seeded_init`]) and
//!   flattening parameters for checkpoints ([`param_vectors`], [`load_param_vectors`]);
//! - the row-to-blocks copy of the networks' and the hash grid's level-major layouts
//!   ([`scatter_blocks`]).

use crate::sampling::rng;
use burn::module::{Module, ModuleMapper, ModuleVisitor, Param};
use burn::tensor::{Device, Tensor, TensorData};

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
    /// Noise of degraded depth targets ([`crate::supervision::DepthSource`]).
    pub const DEPTH_NOISE: u64 = 9;
    /// Which pixels keep a degraded depth target.
    pub const DEPTH_MASK: u64 = 10;
}

/// The seed of a shared sampler for one random stream.
pub fn stream_seed(seed: u64, stream: u64) -> u64 {
    rng::key(&[seed, stream])
}

/// A float tensor from a row-major slice.
pub fn tensor2(data: Vec<f32>, rows: usize, cols: usize, device: &Device) -> Tensor<2> {
    Tensor::from_data(TensorData::new(data, [rows, cols]), device)
}

/// A tensor's values as a flat vector.
pub fn to_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().convert::<f32>().try_into_vec::<f32>().unwrap_or_default()
}

struct Initialiser {
    seed: u64,
    index: u64,
    fan_in: usize,
}

impl ModuleMapper for Initialiser {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let (id, tensor, mapper) = param.consume();
        let dims = tensor.dims();
        if D == 2 {
            self.fan_in = dims[0];
        }
        let bound = 1.0 / (self.fan_in.max(1) as f32).sqrt();
        let n: usize = dims.iter().product();
        let k = self.index;
        self.index += 1;
        let values: Vec<f32> =
            (0..n).map(|j| (uniform(self.seed, stream::INIT, k, j as u64) * 2.0 - 1.0) * bound).collect();
        let device = tensor.device();
        let require_grad = tensor.is_require_grad();
        let mut t = Tensor::<D>::from_data(TensorData::new(values, dims.to_vec()), &device);
        if require_grad {
            t = t.require_grad();
        }
        Param::from_mapped_value(id, t, mapper)
    }
}

/// Re-initialises every parameter from counter-based random numbers keyed by `seed` (burn's
/// default Linear scheme, U(−1/√fan_in, 1/√fan_in) for weights and biases), so a model is a
/// function of its seed alone.
pub fn seeded_init<M: Module>(module: M, seed: u64) -> M {
    module.map(&mut Initialiser { seed, index: 0, fan_in: 1 })
}

struct Collector(Vec<Vec<f32>>);
impl ModuleVisitor for Collector {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        self.0.push(to_vec(param.val()));
    }
}

/// Every parameter tensor's values, in visiting order.
pub fn param_vectors<M: Module>(module: &M) -> Vec<Vec<f32>> {
    let mut c = Collector(Vec::new());
    module.visit(&mut c);
    c.0
}

struct Loader<'a> {
    values: &'a [Vec<f32>],
    index: usize,
    error: Option<String>,
}
impl ModuleMapper for Loader<'_> {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let (id, tensor, mapper) = param.consume();
        let dims = tensor.dims();
        let n: usize = dims.iter().product();
        let k = self.index;
        self.index += 1;
        match self.values.get(k) {
            Some(v) if v.len() == n => {
                let require_grad = tensor.is_require_grad();
                let mut t = Tensor::<D>::from_data(TensorData::new(v.clone(), dims.to_vec()), &tensor.device());
                if require_grad {
                    t = t.require_grad();
                }
                Param::from_mapped_value(id, t, mapper)
            }
            other => {
                self.error.get_or_insert(format!(
                    "parameter {k}: expected {n} values, found {}",
                    other.map_or(0, Vec::len)
                ));
                Param::from_mapped_value(id, tensor, mapper)
            }
        }
    }
}

/// Replaces every parameter's values (in visiting order); errors when a count differs.
pub fn load_param_vectors<M: Module>(module: M, values: &[Vec<f32>]) -> Result<M, String> {
    let mut l = Loader { values, index: 0, error: None };
    let m = module.map(&mut l);
    if l.index != values.len() && l.error.is_none() {
        l.error = Some(format!("module has {} parameters, checkpoint {}", l.index, values.len()));
    }
    match l.error {
        Some(e) => Err(e),
        None => Ok(m),
    }
}

/// Row `s` of `rows` (`[t][pieces.len() · B]`) split into blocks of `B` columns: block `b`
/// goes to `pieces[b][s · B..(s + 1) · B]` (the networks' rows and the hash grid's level-major copy).
pub(crate) fn scatter_blocks<const B: usize>(rows: &[f32], pieces: &mut [&mut [f32]]) {
    let width = pieces.len() * B;
    for (s, row) in rows.chunks_exact(width).enumerate() {
        for (piece, src) in pieces.iter_mut().zip(row.chunks_exact(B)) {
            let dst: &mut [f32; B] = (&mut piece[s * B..(s + 1) * B]).try_into().expect("B floats");
            dst.copy_from_slice(src);
        }
    }
}
