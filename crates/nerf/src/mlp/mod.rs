//! The fast model's two networks ([`crate::field::HashField`]) as plain Rust kernels: forward
//! and an exact hand-written backward, in tiles of [`TILE`] samples that keep every layer's
//! activations in a core's cache.
//!
//! - [`HashMlp`]: the networks' weights read from burn ([`HashMlp::from_field`]), inference
//!   ([`HashMlp::forward`], [`HashMlp::raw_density`]) and training: [`HashMlp::train_groups`]
//!   runs, per group of whole rays, the forward pass, the caller's compositing and loss, and
//!   the backward pass on the activations still in cache, so nothing is recomputed and no
//!   `[N × 64]` array is built ([`HashMlp::backward`], for a gradient given after a separate
//!   forward pass, recomputes each tile's forward instead). burn stays the owner of the
//!   parameters (initialisation, checkpoints, its Adam): [`HashMlpGrads::into_params`] hands
//!   the gradients back as [`GradientsParams`].
//! - `mm`: the fp32 matrix products, register-blocked kernels picked at run time for the CPU
//!   (AVX-512 or AVX2+FMA), else the `gemm` crate.
//! - [`bf16`]: mixed precision (opt-in, `model.mlp_precision`) on CPUs with AVX512-BF16: each
//!   product's inputs rounded to bf16 and summed in fp32; everything kept between layers fp32.
//! - [`burn_reference`], [`speed_against_burn`]: the same networks through burn, the reference
//!   these kernels are tested and measured against (`cargo xtask bench nerf`).
//!
//! Why not burn: there each layer is a pass over an out-of-cache `[N × 64]` tensor plus autodiff
//! bookkeeping; the figures are in `docs/fast-model.md`.
//!
//! # Determinism
//! Samples are split into tiles of [`TILE`] (or the caller's groups) fixed by their index,
//! never by the thread count; each tile's weight gradients go to its own buffer, and the
//! buffers are summed in order. The same inputs give bit-identical outputs with any number of threads.
//!
//! # Layout
//! A layer computes `y = x·W + b` with `W` row-major `[d_in][d_out]` (burn's `Linear`
//! layout); activations are row-major `[samples][features]`.

use crate::field::{HashField, Mlp};
use crate::kernels::scatter_blocks;
use burn::module::Param;
use burn::optim::GradientsParams;
use burn::tensor::{Tensor, TensorData};
use rayon::prelude::*;

/// Samples per tile (and per parallel task and gradient buffer).
pub const TILE: usize = 512;

#[allow(unsafe_code)]
pub mod bf16;
#[allow(unsafe_code)]
mod mm;
mod reference;
#[cfg(test)]
mod tests;

pub use reference::{NetworkSpeed, burn_reference, gemm_peak_gflops, speed_against_burn};

/// One dense layer: `y = x·W + b`.
#[derive(Clone, Debug, PartialEq)]
pub struct Dense {
    pub d_in: usize,
    pub d_out: usize,
    /// `[d_in][d_out]`.
    pub w: Vec<f32>,
    /// `[d_out]`; all zeros for a layer without bias.
    pub b: Vec<f32>,
}

impl Dense {
    fn zeros_like(&self) -> Dense {
        Dense { d_in: self.d_in, d_out: self.d_out, w: vec![0.0; self.w.len()], b: vec![0.0; self.b.len()] }
    }
    fn add(&mut self, o: &Dense) {
        self.w.iter_mut().zip(&o.w).for_each(|(a, b)| *a += b);
        self.b.iter_mut().zip(&o.b).for_each(|(a, b)| *a += b);
    }
}

/// A stack of dense layers: ReLU after each but the last (which is linear).
#[derive(Clone, Debug, PartialEq)]
pub struct Stack {
    layers: Vec<Dense>,
    /// Each layer's weights transposed, `[d_out][d_in]`: the right-hand side of its input
    /// gradient, which the forward kernel then computes.
    wt: Vec<Vec<f32>>,
    /// Zeros as wide as the widest layer input: the input gradients' bias.
    zero_bias: Vec<f32>,
    /// Each layer's weights packed for the bf16 kernels ([`HashMlp::with_bf16`]); `None`: fp32.
    bf16: Option<Vec<Bf16Layer>>,
}

/// A layer's weights rounded to bf16 and packed ([`bf16::pack_weights`]): `w` for the
/// forward product, `wt` (the transposed weights) for the input gradient.
#[derive(Clone, Debug, PartialEq)]
struct Bf16Layer {
    w: Vec<u16>,
    wt: Vec<u16>,
}

impl Stack {
    fn new(layers: Vec<Dense>) -> Self {
        let wt = layers.iter().map(|l| (0..l.d_out).flat_map(|j| (0..l.d_in).map(move |i| l.w[i * l.d_out + j])).collect()).collect();
        let zero_bias = vec![0.0; layers.iter().map(|l| l.d_in).max().unwrap_or(0)];
        Self { layers, wt, zero_bias, bf16: None }
    }

    /// The stack with its weights packed for the bf16 kernels.
    fn with_bf16(mut self) -> Self {
        let packs = self
            .layers
            .iter()
            .zip(&self.wt)
            .map(|(l, wt)| Bf16Layer { w: bf16::pack_weights(&l.w, l.d_in, l.d_out), wt: bf16::pack_weights(wt, l.d_out, l.d_in) })
            .collect();
        self.bf16 = Some(packs);
        self
    }

    /// The layers, input first.
    pub fn layers(&self) -> &[Dense] {
        &self.layers
    }
}

/// The fast field's networks as plain weights: the density stack (encoding → geometry
/// features, the first of which is the raw density) and the colour stack ([geometry, SH] →
/// RGB before its sigmoid).
#[derive(Clone, Debug, PartialEq)]
pub struct HashMlp {
    pub density: Stack,
    pub color: Stack,
    /// Width of the direction input (0: the colour stack sees the geometry features only).
    pub dir_dims: usize,
}

/// What the loss of a group of samples returns to [`HashMlp::train_groups`].
#[derive(Clone, Debug)]
pub struct GroupGrads<R> {
    /// Loss gradient with respect to each sample's raw density (before the activation).
    pub d_raw: Vec<f32>,
    /// … and to its RGB (after the sigmoid).
    pub d_rgb: Vec<[f32; 3]>,
    /// Anything else the caller wants back from the group.
    pub value: R,
}

/// Gradients of the loss with respect to every weight and bias of a [`HashMlp`].
#[derive(Clone, Debug, PartialEq)]
pub struct HashMlpGrads {
    pub density: Vec<Dense>,
    pub color: Vec<Dense>,
}

fn read_mlp(mlp: &Mlp, name: &str) -> Result<Stack, String> {
    if !mlp.skips.is_empty() {
        return Err(format!("{name}: skip connections are not supported by the fused kernels"));
    }
    if mlp.layers.len() != mlp.depth + 1 {
        return Err(format!("{name}: expected {} hidden layers and an output layer, found {} layers", mlp.depth, mlp.layers.len()));
    }
    let layers = mlp
        .layers
        .iter()
        .map(|l| {
            let [d_in, d_out] = l.weight.val().dims();
            let w = crate::kernels::to_vec(l.weight.val());
            let b = l.bias.as_ref().map_or_else(|| vec![0.0; d_out], |b| crate::kernels::to_vec(b.val()));
            Dense { d_in, d_out, w, b }
        })
        .collect::<Vec<_>>();
    for pair in layers.windows(2) {
        if pair[0].d_out != pair[1].d_in {
            return Err(format!("{name}: a layer of width {} feeds one that takes {}", pair[0].d_out, pair[1].d_in));
        }
    }
    Ok(Stack::new(layers))
}

impl HashMlp {
    /// The weights of a burn [`HashField`] (read from its tensors).
    pub fn from_field(field: &HashField) -> Result<Self, String> {
        let density = read_mlp(&field.density, "density network")?;
        let color = read_mlp(&field.color, "colour network")?;
        let geo = density.layers.last().map_or(0, |l| l.d_out);
        let c_in = color.layers.first().map_or(0, |l| l.d_in);
        if geo == 0 || c_in < geo || color.layers.last().map(|l| l.d_out) != Some(3) {
            return Err(format!("field shapes: {geo} geometry features, colour input {c_in}, colour output must be 3"));
        }
        Ok(Self { density, color, dir_dims: c_in - geo })
    }

    /// The networks with every product in mixed precision (module [`bf16`]: inputs of each
    /// product rounded to bf16, products summed in fp32; weights, biases and what the layers
    /// pass on stay fp32): the forward pass of [`Self::forward`] and [`Self::train_groups`]
    /// and the whole backward pass, and [`Self::geometry`] and [`Self::color_of`];
    /// [`Self::raw_density`] and [`Self::raw_density_serial`] (occupancy updates, the training
    /// step's density-only pass) stay fp32. Refused on a CPU without AVX512-BF16.
    pub fn with_bf16(self) -> Result<Self, String> {
        Self::bf16_supported()?;
        Ok(Self { density: self.density.with_bf16(), color: self.color.with_bf16(), dir_dims: self.dir_dims })
    }

    /// Whether this CPU runs [`Self::with_bf16`]'s kernels: the error it would refuse with
    /// otherwise.
    pub fn bf16_supported() -> Result<(), String> {
        if bf16::available() {
            Ok(())
        } else {
            Err("bf16 networks need a CPU with AVX512-BF16 (e.g. Intel Sapphire Rapids, AMD Zen 4 or later); this one has none: use fp32".into())
        }
    }

    /// Whether the products run in bf16 ([`Self::with_bf16`]).
    pub fn is_bf16(&self) -> bool {
        self.density.bf16.is_some()
    }

    /// Width of the encoding input.
    pub fn enc_dims(&self) -> usize {
        self.density.layers[0].d_in
    }

    fn geo_dims(&self) -> usize {
        self.density.layers.last().map_or(0, |l| l.d_out)
    }

    /// Raw density (the first geometry feature, before the activation) and RGB (after the
    /// sigmoid) of `n` samples: `enc` `[n][enc_dims]`, `sh` `[n][dir_dims]` (empty when
    /// `dir_dims` is 0).
    pub fn forward(&self, enc: &[f32], sh: &[f32]) -> (Vec<f32>, Vec<[f32; 3]>) {
        let n = self.check(enc, sh);
        let (ed, sd) = (self.enc_dims(), self.dir_dims);
        let mut raw = vec![0.0; n];
        let mut rgb = vec![[0.0; 3]; n];
        raw.par_chunks_mut(TILE).zip(rgb.par_chunks_mut(TILE)).enumerate().for_each(|(c, (raw, rgb))| {
            let (s0, t) = (c * TILE, raw.len());
            let (r, c) = with_workspace(|ws| {
                self.tile_forward(&enc[s0 * ed..(s0 + t) * ed], &sh[s0 * sd..(s0 + t) * sd], t, ws);
                self.tile_outputs(ws, t)
            });
            raw.copy_from_slice(&r);
            rgb.copy_from_slice(&c);
        });
        (raw, rgb)
    }

    /// The density stack's output for `n` samples `enc` `[n][enc_dims]`: the geometry features
    /// `[n][geo]`, the first of which is the raw density (inference; equal to what
    /// [`Self::forward`] computes on the way).
    pub fn geometry(&self, enc: &[f32]) -> Vec<f32> {
        let (n, ed, gd) = (self.samples_in(enc), self.enc_dims(), self.geo_dims());
        let mut geo = vec![0.0; n * gd];
        geo.par_chunks_mut(TILE * gd).enumerate().for_each(|(c, out)| {
            let (s0, t) = (c * TILE, out.len() / gd);
            with_workspace(|ws| {
                forward_stack(&self.density, &enc[s0 * ed..(s0 + t) * ed], t, &mut ws.density, &mut ws.xb);
                out.copy_from_slice(ws.density.last().expect("the density stack has layers"));
            });
        });
        geo
    }

    /// Width of the geometry features ([`Self::geometry`]).
    pub fn geometry_dims(&self) -> usize {
        self.geo_dims()
    }

    /// RGB (after the sigmoid) of `n` samples from their geometry features `geo` `[n][geo]`
    /// ([`Self::geometry`]) and direction inputs `sh` `[n][dir_dims]`; with [`Self::geometry`],
    /// the same numbers as [`Self::forward`] (each sample's row is computed on its own).
    pub fn color_of(&self, geo: &[f32], sh: &[f32]) -> Vec<[f32; 3]> {
        let (gd, sd) = (self.geo_dims(), self.dir_dims);
        assert!(geo.len().is_multiple_of(gd), "geometry length {} is not a multiple of {gd}", geo.len());
        let n = geo.len() / gd;
        assert_eq!(sh.len(), n * sd, "direction input for {n} samples of width {sd}");
        let mut rgb = vec![[0.0; 3]; n];
        rgb.par_chunks_mut(TILE).enumerate().for_each(|(c, rgb)| {
            let (s0, t) = (c * TILE, rgb.len());
            with_workspace(|ws| {
                colour_input(&mut ws.cin, &geo[s0 * gd..(s0 + t) * gd], &sh[s0 * sd..(s0 + t) * sd], gd, sd);
                forward_stack(&self.color, &ws.cin, t, &mut ws.color, &mut ws.xb);
                for (o, v) in rgb.iter_mut().zip(ws.color.last().expect("the colour stack has layers").chunks_exact(3)) {
                    *o = [sigmoid(v[0]), sigmoid(v[1]), sigmoid(v[2])];
                }
            });
        });
        rgb
    }

    /// Raw density only, for `n` samples `enc` `[n][enc_dims]`: the density stack's hidden
    /// layers, then only the first output of its last layer (the other geometry features are
    /// not needed; equal to [`Self::forward`]'s up to rounding).
    pub fn raw_density(&self, enc: &[f32]) -> Vec<f32> {
        let (n, ed) = (self.samples_in(enc), self.enc_dims());
        let w0 = self.density_column();
        let mut raw = vec![0.0; n];
        raw.par_chunks_mut(TILE).enumerate().for_each(|(c, raw)| {
            let s0 = c * TILE;
            with_workspace(|ws| self.raw_density_tile(&enc[s0 * ed..(s0 + raw.len()) * ed], &w0, raw, &mut ws.density));
        });
        raw
    }

    /// [`Self::raw_density`] on the calling thread only, into `raw` (resized to the samples'
    /// count): the same values, for callers that are parallel over batches themselves.
    pub fn raw_density_serial(&self, enc: &[f32], raw: &mut Vec<f32>) {
        let ed = self.enc_dims();
        let n = self.samples_in(enc);
        let w0 = self.density_column();
        raw.clear();
        raw.resize(n, 0.0);
        with_workspace(|ws| {
            for (c, raw) in raw.chunks_mut(TILE).enumerate() {
                let s0 = c * TILE;
                self.raw_density_tile(&enc[s0 * ed..(s0 + raw.len()) * ed], &w0, raw, &mut ws.density);
            }
        });
    }

    /// Column 0 (the raw density's) of the density stack's last layer's weights, contiguous.
    fn density_column(&self) -> Vec<f32> {
        let last = &self.density.layers[self.density.layers.len() - 1];
        (0..last.d_in).map(|i| last.w[i * last.d_out]).collect()
    }

    /// The raw density of one tile of samples `x` `[t][enc_dims]` into `raw` `[t]` (`w0`:
    /// [`Self::density_column`]; `outs`: the hidden layers' scratch).
    fn raw_density_tile(&self, x: &[f32], w0: &[f32], raw: &mut [f32], outs: &mut Vec<Vec<f32>>) {
        let (hidden, last) = self.density.layers.split_at(self.density.layers.len() - 1);
        let last = &last[0];
        forward_layers(hidden, hidden.len(), x, raw.len(), outs);
        let h: &[f32] = outs.last().map_or(x, |v| v.as_slice());
        for (k, r) in raw.iter_mut().enumerate() {
            *r = last.b[0] + mm::dot(&h[k * last.d_in..(k + 1) * last.d_in], w0);
        }
    }

    /// The exact backward pass: given the loss gradient with respect to each sample's raw
    /// density `d_raw` `[n]` and RGB (after the sigmoid) `d_rgb` `[n]`, returns the gradient
    /// with respect to the encoding `[n][enc_dims]` and to every parameter (summed over the
    /// samples). The forward pass is recomputed: this is [`Self::train_groups`] over tiles of
    /// [`TILE`] samples with the given gradients.
    pub fn backward(&self, enc: &[f32], sh: &[f32], d_raw: &[f32], d_rgb: &[[f32; 3]]) -> (Vec<f32>, HashMlpGrads) {
        let n = self.check(enc, sh);
        assert!(d_raw.len() == n && d_rgb.len() == n, "gradients for {} / {} samples, not {n}", d_raw.len(), d_rgb.len());
        let tiles: Vec<std::ops::Range<usize>> = (0..n).step_by(TILE).map(|s| s..(s + TILE).min(n)).collect();
        let (d_enc, grads, _) = self.train_groups(enc, sh, &tiles, |g, _, _| GroupGrads {
            d_raw: d_raw[tiles[g].clone()].to_vec(),
            d_rgb: d_rgb[tiles[g].clone()].to_vec(),
            value: (),
        });
        (d_enc, grads)
    }

    /// Forward, the caller's loss and the backward pass in one sweep over groups of samples,
    /// each group in cache from start to end and nothing recomputed: for group `g` (samples
    /// `groups[g]`; the groups must be contiguous, in order, and cover every sample), the
    /// networks' raw density and RGB go to `loss(g, raw, rgb)`, which returns the loss
    /// gradient with respect to them (and any value of its own, e.g. its part of the loss);
    /// then the backward pass of the group runs on the activations it left.
    ///
    /// This is how training uses the networks: a group holds whole rays, so the caller can
    /// composite them and take the loss's gradient inside the group. Returns the gradient with
    /// respect to the encoding `[n][enc_dims]`, every parameter's gradient (the groups' sums
    /// added in group order) and the callers' values in group order.
    pub fn train_groups<R: Send>(
        &self,
        enc: &[f32],
        sh: &[f32],
        groups: &[std::ops::Range<usize>],
        loss: impl Fn(usize, &[f32], &[[f32; 3]]) -> GroupGrads<R> + Sync,
    ) -> (Vec<f32>, HashMlpGrads, Vec<R>) {
        self.train_groups_blocked(enc, sh, groups, self.enc_dims(), loss)
    }

    /// [`Self::train_groups`] with the gradient with respect to the encoding returned in
    /// column blocks of `block` columns, `[enc_dims / block][n][block]`: for the hash
    /// encoding with `block = F`, the level-major layout its backward reads
    /// ([`crate::encoding::HashGrid::backward_adam`]), written while each group's gradient is
    /// in cache instead of by a pass of its own. `block = enc_dims` is the row-major
    /// `[n][enc_dims]` of [`Self::train_groups`].
    pub fn train_groups_blocked<R: Send>(
        &self,
        enc: &[f32],
        sh: &[f32],
        groups: &[std::ops::Range<usize>],
        block: usize,
        loss: impl Fn(usize, &[f32], &[[f32; 3]]) -> GroupGrads<R> + Sync,
    ) -> (Vec<f32>, HashMlpGrads, Vec<R>) {
        let n = self.check(enc, sh);
        let mut next = 0;
        for g in groups {
            assert!(g.start == next && g.end >= g.start, "groups must be contiguous and in order");
            next = g.end;
        }
        assert_eq!(next, n, "the groups must cover all {n} samples");
        let (ed, sd) = (self.enc_dims(), self.dir_dims);
        assert!(block >= 1 && ed % block == 0, "block {block} must divide the encoding's {ed} columns");
        let mut d_enc = vec![0.0; n * ed];
        // Each group's rows of every column block.
        let mut pieces: Vec<Vec<&mut [f32]>> = groups.iter().map(|_| Vec::with_capacity(ed / block)).collect();
        for plane in d_enc.chunks_mut((n * block).max(1)) {
            let mut rest = plane;
            for (g, piece) in groups.iter().zip(pieces.iter_mut()) {
                let (head, tail) = std::mem::take(&mut rest).split_at_mut(g.len() * block);
                piece.push(head);
                rest = tail;
            }
        }
        let results: Vec<(HashMlpGrads, R)> = pieces
            .into_par_iter()
            .enumerate()
            .map(|(gi, mut d_enc)| with_workspace(|ws| {
                let range = groups[gi].clone();
                let (s0, t) = (range.start, range.len());
                let x = &enc[s0 * ed..(s0 + t) * ed];
                self.tile_forward(x, &sh[s0 * sd..(s0 + t) * sd], t, ws);
                let (raw, rgb) = self.tile_outputs(ws, t);
                let GroupGrads { d_raw, d_rgb, value } = loss(gi, &raw, &rgb);
                assert!(d_raw.len() == t && d_rgb.len() == t, "group {gi}: gradients for {} / {} samples, not {t}", d_raw.len(), d_rgb.len());
                let mut g = self.zero_grads();
                self.tile_backward(x, ws, &rgb, &d_raw, &d_rgb, &mut g);
                match (&mut d_enc[..], block) {
                    ([all], _) => all.copy_from_slice(&ws.grad),
                    // The hash grid's block sizes with the width known at compile time: a copy
                    // of a run-time length is a call per block.
                    (pieces, 1) => scatter_blocks::<1>(&ws.grad, pieces),
                    (pieces, 2) => scatter_blocks::<2>(&ws.grad, pieces),
                    (pieces, 4) => scatter_blocks::<4>(&ws.grad, pieces),
                    (pieces, 8) => scatter_blocks::<8>(&ws.grad, pieces),
                    (pieces, _) => {
                        for (s, row) in ws.grad.chunks_exact(ed).enumerate() {
                            for (piece, src) in pieces.iter_mut().zip(row.chunks_exact(block)) {
                                piece[s * block..(s + 1) * block].copy_from_slice(src);
                            }
                        }
                    }
                }
                (g, value)
            }))
            .collect();
        let (partials, values): (Vec<HashMlpGrads>, Vec<R>) = results.into_iter().unzip();
        (d_enc, self.sum_grads(&partials), values)
    }

    /// The backward pass of one tile of `t` samples from its forward pass's activations `ws`
    /// (input `x`, output `rgb` after the sigmoid): adds the parameter gradients to `g` and
    /// leaves the gradient with respect to `x` in `ws.grad`.
    fn tile_backward(&self, x: &[f32], ws: &mut Workspace, rgb: &[[f32; 3]], d_raw: &[f32], d_rgb: &[[f32; 3]], g: &mut HashMlpGrads) {
        let t = rgb.len();
        let gd = self.geo_dims();
        let Workspace { density, color, cin, grad, spare, xb, xv, gv } = ws;
        // Colour: d(pre-sigmoid) = d_rgb · s (1 − s).
        grad.resize(t * 3, 0.0);
        for k in 0..t {
            for j in 0..3 {
                let s = rgb[k][j];
                grad[3 * k + j] = d_rgb[k][j] * s * (1.0 - s);
            }
        }
        // Geometry features: from the colour input (its first `gd` columns; the directions'
        // part is not needed), plus the raw density's gradient.
        backward_stack(&self.color, cin, color, grad, spare, t, &mut g.color, gd, (xb, xv, gv));
        for k in 0..t {
            grad[k * gd] += d_raw[k];
        }
        backward_stack(&self.density, x, density, grad, spare, t, &mut g.density, self.enc_dims(), (xb, xv, gv));
    }

    /// The groups' gradients summed in group order, each layer on its own task (the same
    /// additions in the same order as one loop over the groups: a serial tail of the sweep
    /// while the other core waited).
    fn sum_grads(&self, partials: &[HashMlpGrads]) -> HashMlpGrads {
        let mut total = self.zero_grads();
        let HashMlpGrads { density, color } = &mut total;
        rayon::join(
            || density.par_iter_mut().enumerate().for_each(|(i, a)| partials.iter().for_each(|p| a.add(&p.density[i]))),
            || color.par_iter_mut().enumerate().for_each(|(i, a)| partials.iter().for_each(|p| a.add(&p.color[i]))),
        );
        total
    }

    fn zero_grads(&self) -> HashMlpGrads {
        HashMlpGrads {
            density: self.density.layers.iter().map(Dense::zeros_like).collect(),
            color: self.color.layers.iter().map(Dense::zeros_like).collect(),
        }
    }

    /// The number of samples in an encoding input (checks its length).
    fn samples_in(&self, enc: &[f32]) -> usize {
        let ed = self.enc_dims();
        assert!(ed > 0 && enc.len().is_multiple_of(ed), "encoding length {} is not a multiple of {ed}", enc.len());
        enc.len() / ed
    }

    /// Checks the input lengths; returns the sample count.
    fn check(&self, enc: &[f32], sh: &[f32]) -> usize {
        let n = self.samples_in(enc);
        assert_eq!(sh.len(), n * self.dir_dims, "direction input for {n} samples of width {}", self.dir_dims);
        n
    }

    /// Forward pass of one tile of `t` samples into `ws` (the colour stack's input into
    /// `ws.cin`).
    fn tile_forward(&self, x: &[f32], sh: &[f32], t: usize, ws: &mut Workspace) {
        forward_stack(&self.density, x, t, &mut ws.density, &mut ws.xb);
        let (gd, sd) = (self.geo_dims(), self.dir_dims);
        colour_input(&mut ws.cin, &ws.density.last().unwrap()[..t * gd], sh, gd, sd);
        forward_stack(&self.color, &ws.cin, t, &mut ws.color, &mut ws.xb);
    }

    /// A tile's outputs from its forward pass: raw density (the first geometry feature) and
    /// RGB (the colour stack's output through the sigmoid).
    fn tile_outputs(&self, ws: &Workspace, t: usize) -> (Vec<f32>, Vec<[f32; 3]>) {
        let gd = self.geo_dims();
        let geo = ws.density.last().expect("the density stack has layers");
        let raw = (0..t).map(|k| geo[k * gd]).collect();
        let rgb = ws.color.last().expect("the colour stack has layers").chunks_exact(3).map(|o| [sigmoid(o[0]), sigmoid(o[1]), sigmoid(o[2])]).collect();
        (raw, rgb)
    }
}

impl HashMlpGrads {
    /// Whether every gradient is finite.
    pub fn is_finite(&self) -> bool {
        self.density.iter().chain(&self.color).all(|l| l.w.iter().chain(&l.b).all(|v| v.is_finite()))
    }

    /// The gradients as burn's [`GradientsParams`] for `field`'s parameters (weights and
    /// biases), ready for its optimiser.
    pub fn into_params(self, field: &HashField) -> GradientsParams {
        let mut out = GradientsParams::new();
        let dev = crate::backend::inference_device();
        for (mlp, grads) in [(&field.density, self.density), (&field.color, self.color)] {
            for (layer, g) in mlp.layers.iter().zip(grads) {
                out.register::<2>(layer.weight.id, Tensor::from_data(TensorData::new(g.w, [g.d_in, g.d_out]), &dev));
                if let Some(b) = &layer.bias {
                    register_bias(&mut out, b, g.b, &dev);
                }
            }
        }
        out
    }
}

fn register_bias(out: &mut GradientsParams, b: &Param<Tensor<1>>, g: Vec<f32>, dev: &burn::tensor::Device) {
    let n = g.len();
    out.register::<1>(b.id, Tensor::from_data(TensorData::new(g, [n]), dev));
}

/// Per-tile activations: each layer's output (after its ReLU for hidden layers, before any
/// activation for the last).
#[derive(Default)]
struct Workspace {
    density: Vec<Vec<f32>>,
    color: Vec<Vec<f32>>,
    /// The colour stack's input: the geometry features, then the direction encoding.
    cin: Vec<f32>,
    /// The backward pass's gradient with respect to the current layer's output (in the end:
    /// to the tile's input), and the buffer its next layer's goes into.
    grad: Vec<f32>,
    spare: Vec<f32>,
    /// bf16 scratch ([`bf16`]): a product's row-major input, and the sample-paired input and
    /// output gradient of a weight gradient.
    xb: Vec<u16>,
    xv: Vec<u16>,
    gv: Vec<u16>,
}

thread_local! {
    /// Each thread's [`Workspace`], kept between calls: a tile's buffers (about 0.7 MiB at the
    /// fast model's sizes) were allocated afresh for every rayon task of every step, and the
    /// allocator's page faults and zeroing showed in the step's profile.
    static WORKSPACE: std::cell::Cell<Option<Box<Workspace>>> = const { std::cell::Cell::new(None) };
}

/// Runs `f` with this thread's [`Workspace`] (a fresh one when a caller up the stack on this
/// thread holds it: rayon may run another task inside `f`). Every buffer of a workspace is
/// written before it is read, so what an earlier call left in it never matters.
fn with_workspace<T>(f: impl FnOnce(&mut Workspace) -> T) -> T {
    let mut ws = WORKSPACE.take().unwrap_or_default();
    let out = f(&mut ws);
    WORKSPACE.set(Some(ws));
    out
}

/// The colour stack's input into `cin`: each sample's geometry features (`geo` `[t][gd]`)
/// followed by its direction input (`sh` `[t][sd]`, empty when `sd` is 0).
fn colour_input(cin: &mut Vec<f32>, geo: &[f32], sh: &[f32], gd: usize, sd: usize) {
    cin.clear();
    if sd == 0 {
        cin.extend_from_slice(geo);
        return;
    }
    cin.reserve(geo.len() + sh.len());
    for (g, d) in geo.chunks_exact(gd).zip(sh.chunks_exact(sd)) {
        cin.extend_from_slice(g);
        cin.extend_from_slice(d);
    }
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// Runs a stack over `t` samples `x` `[t][d_in]`; `outs[i]` = layer `i`'s output.
fn forward_stack(stack: &Stack, x: &[f32], t: usize, outs: &mut Vec<Vec<f32>>, xb: &mut Vec<u16>) {
    match &stack.bf16 {
        None => forward_layers(&stack.layers, stack.layers.len() - 1, x, t, outs),
        Some(packs) => forward_layers_bf16(stack, packs, x, t, outs, xb),
    }
}

/// [`forward_layers`] of a whole stack in bf16 ([`bf16::dense`]; `xb` is scratch).
fn forward_layers_bf16(stack: &Stack, packs: &[Bf16Layer], x: &[f32], t: usize, outs: &mut Vec<Vec<f32>>, xb: &mut Vec<u16>) {
    let layers = &stack.layers;
    outs.truncate(layers.len());
    outs.resize_with(layers.len(), Vec::new);
    for (i, (l, p)) in layers.iter().zip(packs).enumerate() {
        let (done, rest) = outs.split_at_mut(i);
        let input: &[f32] = if i == 0 { x } else { &done[i - 1] };
        bf16::rows(input, t, l.d_in, xb);
        let y = &mut rest[0];
        y.resize(t * l.d_out, 0.0);
        let (kp, np) = (bf16::round_up(l.d_in, 2), bf16::round_up(l.d_out, 16));
        bf16::dense(y, xb, kp, &p.w, np, &l.b, t, l.d_out, i + 1 < layers.len());
    }
}

/// Runs `layers` over `t` samples `x`, the first `relu` of them followed by a ReLU; `outs`
/// ends with one output per layer, reusing the buffers it already holds (a caller that keeps
/// `outs` across tiles allocates nothing after the first).
fn forward_layers(layers: &[Dense], relu: usize, x: &[f32], t: usize, outs: &mut Vec<Vec<f32>>) {
    outs.truncate(layers.len());
    outs.resize_with(layers.len(), Vec::new);
    for (i, l) in layers.iter().enumerate() {
        let (done, rest) = outs.split_at_mut(i);
        let input: &[f32] = if i == 0 { x } else { &done[i - 1] };
        let y = &mut rest[0];
        // (every element is written below: no need to clear what a previous tile left)
        y.resize(t * l.d_out, 0.0);
        mm::dense(y, input, &l.w, &l.b, t, l.d_in, l.d_out, i < relu);
    }
}

/// Backward through a stack for one tile: `grad` holds the gradient with respect to the last
/// layer's output; accumulates parameter gradients into `grads` and leaves in `grad` the
/// gradient with respect to the first `need` columns of the stack's input `x` (`[t][need]`).
/// `spare` is scratch; neither buffer is cleared (every element is written).
#[allow(clippy::too_many_arguments)]
fn backward_stack(stack: &Stack, x: &[f32], outs: &[Vec<f32>], grad: &mut Vec<f32>, spare: &mut Vec<f32>, t: usize, grads: &mut [Dense], need: usize, bf: Bf16Scratch) {
    if let Some(packs) = &stack.bf16 {
        return backward_stack_bf16(stack, packs, x, outs, grad, spare, t, grads, need, bf);
    }
    for i in (0..stack.layers.len()).rev() {
        let l = &stack.layers[i];
        let input: &[f32] = if i == 0 { x } else { &outs[i - 1] };
        let g = &mut grads[i];
        mm::weight_grads_acc(&mut g.w, &mut g.b, input, grad, t, l.d_in, l.d_out);
        // d_in = d · Wᵀ: the forward kernel on the transposed weights, with a zero bias.
        let cols = if i == 0 { need.min(l.d_in) } else { l.d_in };
        spare.resize(t * cols, 0.0);
        mm::dense_strided(spare, grad, &stack.wt[i], l.d_in, &stack.zero_bias[..cols], t, l.d_out, cols, false);
        if i > 0 {
            // Through the previous layer's ReLU: its output is > 0 exactly where it passed.
            mm::relu_mask(spare, input);
        }
        std::mem::swap(grad, spare);
    }
}

/// The bf16 scratch buffers of a [`Workspace`] (`xb`, `xv`, `gv`).
type Bf16Scratch<'a> = (&'a mut Vec<u16>, &'a mut Vec<u16>, &'a mut Vec<u16>);

/// [`backward_stack`] in bf16: each weight gradient from the layer's input and output
/// gradient paired by samples ([`bf16::weight_grads_acc`]; the bias gradient, a plain sum, in
/// fp32), each input gradient through the transposed weights ([`bf16::dense`]).
#[allow(clippy::too_many_arguments)]
fn backward_stack_bf16(stack: &Stack, packs: &[Bf16Layer], x: &[f32], outs: &[Vec<f32>], grad: &mut Vec<f32>, spare: &mut Vec<f32>, t: usize, grads: &mut [Dense], need: usize, (xb, xv, gv): Bf16Scratch) {
    for i in (0..stack.layers.len()).rev() {
        let l = &stack.layers[i];
        let input: &[f32] = if i == 0 { x } else { &outs[i - 1] };
        let g = &mut grads[i];
        bf16::paired(input, t, l.d_in, xv);
        bf16::paired(grad, t, l.d_out, gv);
        bf16::weight_grads_acc(&mut g.w, xv, gv, t, l.d_in, l.d_out);
        mm::col_sums_acc(&mut g.b, grad);
        let cols = if i == 0 { need.min(l.d_in) } else { l.d_in };
        bf16::rows(grad, t, l.d_out, xb);
        spare.resize(t * cols, 0.0);
        let (kp, np) = (bf16::round_up(l.d_out, 2), bf16::round_up(l.d_in, 16));
        bf16::dense(spare, xb, kp, &packs[i].wt, np, &stack.zero_bias, t, cols, false);
        if i > 0 {
            mm::relu_mask(spare, input);
        }
        std::mem::swap(grad, spare);
    }
}
