//! The fast model's two networks ([`crate::field::HashField`]) run as plain Rust kernels:
//! forward and an exact hand-written backward, in tiles of [`TILE`] samples that keep every
//! layer's activations in a core's cache. The matrix products are register-blocked kernels
//! picked at run time for the CPU (AVX-512 or AVX2+FMA; module `mm`): the forward product, which
//! with transposed weights also gives the backward's input gradients, and the weight (and bias)
//! gradients; without FMA, the `gemm` crate (the kernels burn's `flex` backend uses). At the
//! networks' sizes (16 to 64 wide, tiles of 512) `gemm`'s packing cost about as much as the
//! products: `cargo xtask bench nerf`'s forward + backward went 280 → 341 GFLOP/s when the
//! backward moved off it.
//!
//! Why: through burn the networks ran at ~35–45 GFLOP/s on this machine's 2 cores (`cargo
//! xtask bench nerf`) and took ~70 % of a training step. Each layer there is a separate pass
//! over a `[32768 × 64]` tensor (8 MiB, out of cache), plus autodiff bookkeeping, the
//! concatenation, the slice, the surrogate loss and their backward passes. Here a tile of
//! samples goes through all layers while it is in L2. Training uses
//! [`HashMlp::train_groups`]: per group of whole rays, forward, the caller's compositing and
//! loss, and the backward pass on the activations still in cache, so nothing is recomputed
//! and no `[N × 64]` array is built ([`HashMlp::backward`], for a gradient given after a
//! separate forward pass, recomputes each tile's forward instead). Measured: `cargo xtask
//! bench nerf` prints these kernels against burn on the same networks and batch.
//!
//! Mixed precision ([`HashMlp::with_bf16`], module [`bf16`]; opt-in, `model.mlp_precision`):
//! on CPUs with AVX512-BF16 every product's inputs are rounded to bf16 and summed in fp32
//! (`vdpbf16ps`, twice the fp32 FMA rate); weights, biases and everything kept between layers
//! stay fp32.
//!
//! burn stays the owner of the parameters (initialisation, checkpoints, its Adam):
//! [`HashMlp::from_field`] reads the weights before a step and [`HashMlpGrads::into_params`]
//! hands the gradients back to burn's optimiser as [`GradientsParams`].
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

#[path = "mlp_bf16.rs"]
#[allow(unsafe_code)]
pub mod bf16;

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

/// Matrix products on row-major slices through the `gemm` crate (single-threaded: the
/// callers parallelise over tiles). Unsafe code (as in [`super::bf16`] and the hash grid's
/// SIMD): `gemm`'s entry point takes raw pointers and strides, and each wrapper checks every
/// slice's length against the shape first.
#[allow(unsafe_code)]
mod mm {
    use gemm::{Parallelism, gemm};

    /// `c = a · b` for square `n × n` matrices through `gemm` on every rayon thread: the
    /// machine's practical fp32 matmul peak, in GFLOP/s (the best of `reps` timed runs after
    /// one warm-up).
    pub fn gemm_peak_gflops(n: usize, reps: usize) -> f64 {
        let a: Vec<f32> = (0..n * n).map(|k| ((k * 7919) % 1000) as f32 * 1e-3 - 0.5).collect();
        let b: Vec<f32> = (0..n * n).map(|k| ((k * 104729) % 1000) as f32 * 1e-3 - 0.5).collect();
        let mut c = vec![0.0f32; n * n];
        let mut best = f64::INFINITY;
        for rep in 0..=reps {
            let t = std::time::Instant::now();
            // SAFETY: a, b and c hold n × n values each, row-major with the strides given; c is exclusive.
            unsafe {
                gemm(
                    n, n, n, c.as_mut_ptr(), 1, n as isize, false, a.as_ptr(), 1, n as isize, b.as_ptr(), 1, n as isize, 0.0, 1.0,
                    false, false, false, Parallelism::Rayon(0),
                )
            }
            if rep > 0 {
                best = best.min(t.elapsed().as_secs_f64());
            }
        }
        std::hint::black_box(&c);
        2.0 * (n as f64).powi(3) / best / 1e9
    }

    /// `c[m][n] += a[m][k] · b[k][n]`.
    pub fn matmul_acc(c: &mut [f32], a: &[f32], b: &[f32], m: usize, k: usize, n: usize) {
        assert!(c.len() == m * n && a.len() == m * k && b.len() == k * n, "matmul_acc shapes");
        if m == 0 || n == 0 || k == 0 {
            return;
        }
        // SAFETY: the lengths match the shapes and strides (checked above); `c` is exclusive.
        unsafe {
            gemm(
                m, n, k, c.as_mut_ptr(), 1, n as isize, true, a.as_ptr(), 1, k as isize, b.as_ptr(), 1, n as isize, 1.0, 1.0,
                false, false, false, Parallelism::None,
            )
        }
    }

    /// A dense layer's forward pass: `y[m][n] = b + x[m][k] · w[k][n]`, through a ReLU when
    /// `relu`. Small layers (the fast model's are 16 to 64 wide) are far from `gemm`'s sweet
    /// spot, so where the CPU has FMA this runs a register-blocked kernel compiled for AVX-512
    /// or AVX2 (chosen at run time): 4 rows × 2 vectors (or 8 rows × 1) of accumulators, each
    /// output `b + Σᵢ x[i]·w[i]` fused-multiply-added in `i` order; columns left over (fewer
    /// than a vector, e.g. the colour output's 3) are dot products in vector lanes. A row's
    /// result never depends on the other rows of the call (so a pixel renders the same in any
    /// batch), and for widths that are multiples of 16 not on which kernel ran. Elsewhere:
    /// `gemm` (whose results do depend on the batch).
    #[allow(clippy::too_many_arguments)]
    pub fn dense(y: &mut [f32], x: &[f32], w: &[f32], b: &[f32], m: usize, k: usize, n: usize, relu: bool) {
        dense_strided(y, x, w, n, b, m, k, n, relu)
    }

    /// [`dense`] with the weights' rows `ldw ≥ n` floats apart: `w` `[k][ldw]`, of which the
    /// first `n` columns are used (an input gradient needed for only the first `n` inputs of
    /// a layer reads those columns of its transposed weights).
    #[allow(clippy::too_many_arguments)]
    pub fn dense_strided(y: &mut [f32], x: &[f32], w: &[f32], ldw: usize, b: &[f32], m: usize, k: usize, n: usize, relu: bool) {
        assert!(
            y.len() == m * n && x.len() == m * k && ldw >= n && w.len() == k * ldw && b.len() == n,
            "dense shapes"
        );
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU has the features the function is compiled for (checked above).
                unsafe { blocked::dense_avx512(y, x, w, ldw, b, m, k, n, relu) };
                return;
            }
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                // SAFETY: as above.
                unsafe { blocked::dense_avx2(y, x, w, ldw, b, m, k, n, relu) };
                return;
            }
        }
        for row in y.chunks_exact_mut(n.max(1)) {
            row.copy_from_slice(b);
        }
        if ldw == n {
            matmul_acc(y, x, w, m, k, n);
        } else {
            let wn: Vec<f32> = w.chunks_exact(ldw).flat_map(|r| r[..n].iter().copied()).collect();
            matmul_acc(y, x, &wn, m, k, n);
        }
        if relu {
            y.iter_mut().for_each(|v| *v = v.max(0.0));
        }
    }

    #[cfg(target_arch = "x86_64")]
    pub(super) mod blocked {
        use std::arch::x86_64::*;

        /// A kernel's register block: `RB` rows × `NV` vectors of output from row `r0`, column
        /// `c0` (its other arguments held by the implementer).
        trait Blocks {
            /// # Safety
            /// The block lies within the kernel's checked shapes; the CPU has its features.
            unsafe fn block<const RB: usize, const NV: usize>(&self, r0: usize, c0: usize);
        }

        /// The walk both kernels make over a `rows × cols` output: column blocks `NVW` vectors
        /// of `W` lanes wide where the registers allow, then 2, then 1 vector (rows in fours,
        /// in eights for one vector to keep 8 accumulators in flight, the rest one by one).
        /// Returns the first column no block covered (fewer than `W` are left).
        ///
        /// # Safety
        /// As [`Blocks::block`], for every block of the output.
        #[inline(always)]
        unsafe fn walk<B: Blocks, const W: usize, const NVW: usize>(b: &B, rows: usize, cols: usize) -> usize {
            let mut c0 = 0;
            // SAFETY (all bands): rows < `rows` and columns < `cols` (the caller's promise).
            unsafe {
                while c0 + NVW * W <= cols {
                    band::<B, 4, NVW>(b, rows, c0);
                    c0 += NVW * W;
                }
                while c0 + 2 * W <= cols {
                    band::<B, 4, 2>(b, rows, c0);
                    c0 += 2 * W;
                }
                while c0 + W <= cols {
                    band::<B, 8, 1>(b, rows, c0);
                    c0 += W;
                }
            }
            c0
        }

        /// One band of [`walk`]: the columns `NV` vectors wide from `c0`, rows in blocks of
        /// `RB`, then the rest one by one.
        ///
        /// # Safety
        /// As [`Blocks::block`], for every block of the band.
        #[inline(always)]
        unsafe fn band<B: Blocks, const RB: usize, const NV: usize>(b: &B, rows: usize, c0: usize) {
            let mut r0 = 0;
            // SAFETY: the caller's promise, block by block.
            unsafe {
                while r0 + RB <= rows {
                    b.block::<RB, NV>(r0, c0);
                    r0 += RB;
                }
                for r in r0..rows {
                    b.block::<1, NV>(r, c0);
                }
            }
        }

        /// One kernel per vector width: `$rb` rows × `$nv` vectors of `$w` lanes of columns.
        macro_rules! kernels {
            ($name:ident, $feat:literal, $w:literal, $nvw:literal, $vt:ty, $load:ident, $store:ident, $set1:ident, $fma:ident, $max:ident, $zero:ident) => {
                /// See [`super::dense_strided`]; the caller checked the shapes and the CPU's features.
                #[target_feature(enable = $feat)]
                #[allow(clippy::too_many_arguments)]
                pub unsafe fn $name(y: &mut [f32], x: &[f32], w: &[f32], ldw: usize, b: &[f32], m: usize, k: usize, n: usize, relu: bool) {
                    /// `RB` rows × `NV` vectors from row `r0`, column `c0`.
                    #[inline(always)]
                    #[allow(clippy::too_many_arguments)]
                    unsafe fn block<const RB: usize, const NV: usize>(y: *mut f32, x: *const f32, w: *const f32, ldw: usize, b: *const f32, r0: usize, c0: usize, k: usize, n: usize, relu: bool) {
                        unsafe {
                            let mut acc = [[$zero(); NV]; RB];
                            for a in acc.iter_mut() {
                                for (v, av) in a.iter_mut().enumerate() {
                                    *av = $load(b.add(c0 + v * $w));
                                }
                            }
                            for i in 0..k {
                                let mut wv = [$zero(); NV];
                                for (v, wvv) in wv.iter_mut().enumerate() {
                                    *wvv = $load(w.add(i * ldw + c0 + v * $w));
                                }
                                for (r, a) in acc.iter_mut().enumerate() {
                                    let xv = $set1(*x.add((r0 + r) * k + i));
                                    for v in 0..NV {
                                        a[v] = $fma(xv, wv[v], a[v]);
                                    }
                                }
                            }
                            for (r, a) in acc.iter().enumerate() {
                                for (v, av) in a.iter().enumerate() {
                                    let o = if relu { $max(*av, $zero()) } else { *av };
                                    $store(y.add((r0 + r) * n + c0 + v * $w), o);
                                }
                            }
                        }
                    }
                    /// The forward's blocks ([`block`] with the call's arguments).
                    struct Fwd {
                        y: *mut f32,
                        x: *const f32,
                        w: *const f32,
                        ldw: usize,
                        b: *const f32,
                        k: usize,
                        n: usize,
                        relu: bool,
                    }
                    impl Blocks for Fwd {
                        #[inline(always)]
                        unsafe fn block<const RB: usize, const NV: usize>(&self, r0: usize, c0: usize) {
                            // SAFETY: as the trait's.
                            unsafe { block::<RB, NV>(self.y, self.x, self.w, self.ldw, self.b, r0, c0, self.k, self.n, self.relu) }
                        }
                    }
                    let fwd = Fwd { y: y.as_mut_ptr(), x: x.as_ptr(), w: w.as_ptr(), ldw, b: b.as_ptr(), k, n, relu };
                    // `$nvw` vectors wide where the registers allow (AVX-512: 4 rows × 4 vectors,
                    // 16 FMAs per 4 weight loads and 4 broadcasts, FMA-bound rather than
                    // load-bound as 4 × 2 is).
                    // SAFETY: the blocks cover rows < m and columns < n, within the checked lengths.
                    let c0 = unsafe { walk::<Fwd, $w, $nvw>(&fwd, m, n) };
                    // The last columns (fewer than a vector, e.g. the colour output's 3): each a
                    // dot product of the row with the column (transposed once), `$w` lanes of
                    // partial sums added pairwise, then to the bias, then the leftover inputs.
                    if c0 < n {
                        let wt: Vec<f32> = (c0..n).flat_map(|c| (0..k).map(move |i| w[i * ldw + c])).collect();
                        for r in 0..m {
                            let xr = &x[r * k..(r + 1) * k];
                            for (ci, c) in (c0..n).enumerate() {
                                let wc = &wt[ci * k..(ci + 1) * k];
                                let mut i = 0;
                                let mut lanes = [0.0f32; $w];
                                // SAFETY: i + $w <= k, within both rows.
                                unsafe {
                                    let mut acc = $zero();
                                    while i + $w <= k {
                                        acc = $fma($load(xr.as_ptr().add(i)), $load(wc.as_ptr().add(i)), acc);
                                        i += $w;
                                    }
                                    $store(lanes.as_mut_ptr(), acc);
                                }
                                // The lanes summed pairwise: a fixed order per row, 4
                                // additions deep instead of 16.
                                let mut a = b[c] + super::pairwise_sum(&mut lanes);
                                for j in i..k {
                                    a = xr[j].mul_add(wc[j], a);
                                }
                                y[r * n + c] = if relu { a.max(0.0) } else { a };
                            }
                        }
                    }
                }
            };
        }

        kernels!(dense_avx512, "avx512f,fma", 16, 4, __m512, _mm512_loadu_ps, _mm512_storeu_ps, _mm512_set1_ps, _mm512_fmadd_ps, _mm512_max_ps, _mm512_setzero_ps);
        kernels!(dense_avx2, "avx2,fma", 8, 2, __m256, _mm256_loadu_ps, _mm256_storeu_ps, _mm256_set1_ps, _mm256_fmadd_ps, _mm256_max_ps, _mm256_setzero_ps);

        /// Samples per pass of the weight-gradient kernels: a pass's rows of `a` and `b` (at
        /// most 64 wide) stay in L1 while every block of `c` reads them.
        const TN_CHUNK: usize = 64;

        /// One weight-gradient kernel per vector width: `c[k][n] += a[m][k]ᵀ · b[m][n]` and the
        /// bias gradient `cb[n] += Σₛ b[s][n]`, blocks of `RB` rows × `NV` vectors of `c` held in
        /// registers over a pass of samples. Every element is `c + a[0][r]·b[0][j] +
        /// a[1][r]·b[1][j] + …`, fused-multiply-added in sample order (and `cb + b[0][j] +
        /// b[1][j] + …` added in sample order) whichever block, pass or kernel computes it, so
        /// both widths give the same bits.
        macro_rules! tn_kernels {
            ($name:ident, $feat:literal, $w:literal, $nvw:literal, $vt:ty, $load:ident, $store:ident, $set1:ident, $fma:ident, $add:ident, $zero:ident) => {
                /// See [`super::weight_grads_acc`]; the caller checked the shapes and the CPU's features.
                #[target_feature(enable = $feat)]
                #[allow(clippy::too_many_arguments)]
                pub unsafe fn $name(c: &mut [f32], cb: &mut [f32], a: &[f32], b: &[f32], m: usize, k: usize, n: usize) {
                    /// Rows `r0..r0 + RB`, vectors of columns from `c0`, samples `s0..s1`; with
                    /// `BIAS`, also the columns' sums of `b` into `cb` (from the loads of `b`
                    /// the block makes anyway).
                    #[inline(always)]
                    #[allow(clippy::too_many_arguments)]
                    unsafe fn block<const RB: usize, const NV: usize, const BIAS: bool>(c: *mut f32, cb: *mut f32, a: *const f32, b: *const f32, r0: usize, c0: usize, s0: usize, s1: usize, k: usize, n: usize) {
                        unsafe {
                            let mut acc = [[$zero(); NV]; RB];
                            for (r, row) in acc.iter_mut().enumerate() {
                                for (v, av) in row.iter_mut().enumerate() {
                                    *av = $load(c.add((r0 + r) * n + c0 + v * $w));
                                }
                            }
                            let mut bacc = [$zero(); NV];
                            if BIAS {
                                for (v, av) in bacc.iter_mut().enumerate() {
                                    *av = $load(cb.add(c0 + v * $w));
                                }
                            }
                            for s in s0..s1 {
                                let mut bv = [$zero(); NV];
                                for (v, bvv) in bv.iter_mut().enumerate() {
                                    *bvv = $load(b.add(s * n + c0 + v * $w));
                                }
                                if BIAS {
                                    for v in 0..NV {
                                        bacc[v] = $add(bacc[v], bv[v]);
                                    }
                                }
                                for (r, row) in acc.iter_mut().enumerate() {
                                    let av = $set1(*a.add(s * k + r0 + r));
                                    for v in 0..NV {
                                        row[v] = $fma(av, bv[v], row[v]);
                                    }
                                }
                            }
                            for (r, row) in acc.iter().enumerate() {
                                for (v, av) in row.iter().enumerate() {
                                    $store(c.add((r0 + r) * n + c0 + v * $w), *av);
                                }
                            }
                            if BIAS {
                                for (v, av) in bacc.iter().enumerate() {
                                    $store(cb.add(c0 + v * $w), *av);
                                }
                            }
                        }
                    }
                    /// [`block`], summing the bias for the first block of rows of a column block.
                    #[inline(always)]
                    #[allow(clippy::too_many_arguments)]
                    unsafe fn blk<const RB: usize, const NV: usize>(c: *mut f32, cb: *mut f32, a: *const f32, b: *const f32, r0: usize, c0: usize, s0: usize, s1: usize, k: usize, n: usize) {
                        unsafe {
                            if r0 == 0 {
                                block::<RB, NV, true>(c, cb, a, b, r0, c0, s0, s1, k, n)
                            } else {
                                block::<RB, NV, false>(c, cb, a, b, r0, c0, s0, s1, k, n)
                            }
                        }
                    }
                    /// The blocks of one pass of samples `s0..s1` ([`blk`] with the call's arguments).
                    struct Pass {
                        c: *mut f32,
                        cb: *mut f32,
                        a: *const f32,
                        b: *const f32,
                        s0: usize,
                        s1: usize,
                        k: usize,
                        n: usize,
                    }
                    impl Blocks for Pass {
                        #[inline(always)]
                        unsafe fn block<const RB: usize, const NV: usize>(&self, r0: usize, c0: usize) {
                            // SAFETY: as the trait's.
                            unsafe { blk::<RB, NV>(self.c, self.cb, self.a, self.b, r0, c0, self.s0, self.s1, self.k, self.n) }
                        }
                    }
                    let (cp, cbp, ap, bp) = (c.as_mut_ptr(), cb.as_mut_ptr(), a.as_ptr(), b.as_ptr());
                    let mut s0 = 0;
                    while s0 < m {
                        let s1 = (s0 + TN_CHUNK).min(m);
                        let pass = Pass { c: cp, cb: cbp, a: ap, b: bp, s0, s1, k, n };
                        // SAFETY (all blocks): rows < k, columns < n and samples < m, within the
                        // checked lengths.
                        unsafe {
                            let c0 = walk::<Pass, $w, $nvw>(&pass, k, n);
                            // The last columns (fewer than a vector, e.g. the colour output's 3):
                            // vectors over `$w` rows of `c` (a row of `a` is contiguous there),
                            // the remaining rows one by one; the same sums in the same order.
                            for j in c0..n {
                                for s in s0..s1 {
                                    *cbp.add(j) += *bp.add(s * n + j);
                                }
                                let mut r0 = 0;
                                while r0 + $w <= k {
                                    let mut lanes = [0.0f32; $w];
                                    for (l, v) in lanes.iter_mut().enumerate() {
                                        *v = *cp.add((r0 + l) * n + j);
                                    }
                                    let mut acc = $load(lanes.as_ptr());
                                    for s in s0..s1 {
                                        acc = $fma($load(ap.add(s * k + r0)), $set1(*bp.add(s * n + j)), acc);
                                    }
                                    $store(lanes.as_mut_ptr(), acc);
                                    for (l, v) in lanes.iter().enumerate() {
                                        *cp.add((r0 + l) * n + j) = *v;
                                    }
                                    r0 += $w;
                                }
                                for r in r0..k {
                                    let mut v = *cp.add(r * n + j);
                                    for s in s0..s1 {
                                        v = (*ap.add(s * k + r)).mul_add(*bp.add(s * n + j), v);
                                    }
                                    *cp.add(r * n + j) = v;
                                }
                            }
                        }
                        s0 = s1;
                    }
                }
            };
        }

        tn_kernels!(tn_acc_avx512, "avx512f,fma", 16, 4, __m512, _mm512_loadu_ps, _mm512_storeu_ps, _mm512_set1_ps, _mm512_fmadd_ps, _mm512_add_ps, _mm512_setzero_ps);
        tn_kernels!(tn_acc_avx2, "avx2,fma", 8, 2, __m256, _mm256_loadu_ps, _mm256_storeu_ps, _mm256_set1_ps, _mm256_fmadd_ps, _mm256_add_ps, _mm256_setzero_ps);
    }

    /// The sum of `lanes` (a power of two of them) pairwise: halves added, then quarters, …,
    /// in place; a fixed order, `log₂` additions deep.
    #[inline(always)]
    pub(super) fn pairwise_sum(lanes: &mut [f32]) -> f32 {
        debug_assert!(lanes.len().is_power_of_two());
        let mut width = lanes.len();
        while width > 1 {
            width /= 2;
            for l in 0..width {
                lanes[l] += lanes[l + width];
            }
        }
        lanes[0]
    }

    /// `Σᵢ a[i]·b[i]` in 16 lanes (lane `l` sums the products `i ≡ l (mod 16)` in order, the
    /// remainder into lane 0), then the lanes pairwise: a fixed order, vectorised (a plain
    /// sequential sum is one 64-deep chain of dependent additions per row), the same bits on
    /// every path (no fused multiply-add).
    pub fn dot(a: &[f32], b: &[f32]) -> f32 {
        assert_eq!(a.len(), b.len(), "dot lengths");
        #[inline(always)]
        fn plain(a: &[f32], b: &[f32]) -> f32 {
            let mut lanes = [0.0f32; 16];
            let (ca, cb) = (a.chunks_exact(16), b.chunks_exact(16));
            let (ra, rb) = (ca.remainder(), cb.remainder());
            for (x, y) in ca.zip(cb) {
                for l in 0..16 {
                    lanes[l] += x[l] * y[l];
                }
            }
            for (x, y) in ra.iter().zip(rb) {
                lanes[0] += x * y;
            }
            pairwise_sum(&mut lanes)
        }
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            /// `plain` compiled for AVX2: the same operations lane for lane.
            #[target_feature(enable = "avx2")]
            fn wide(a: &[f32], b: &[f32]) -> f32 {
                plain(a, b)
            }
            // SAFETY: the CPU has AVX2 (checked above).
            return unsafe { wide(a, b) };
        }
        plain(a, b)
    }

    /// `c[n] += Σₛ b[s][n]` (a bias gradient), each column summed in sample order (the
    /// fallback's; the kernels sum it inside [`weight_grads_acc`]).
    pub fn col_sums_acc(c: &mut [f32], b: &[f32]) {
        assert!(!c.is_empty() && b.len().is_multiple_of(c.len()), "col_sums_acc shapes");
        #[inline(always)]
        fn plain(c: &mut [f32], b: &[f32]) {
            for row in b.chunks_exact(c.len()) {
                c.iter_mut().zip(row).for_each(|(a, x)| *a += x);
            }
        }
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            /// `plain` compiled for AVX2: the same additions in the same order.
            #[target_feature(enable = "avx2")]
            fn wide(c: &mut [f32], b: &[f32]) {
                plain(c, b)
            }
            // SAFETY: the CPU has AVX2 (checked above).
            unsafe { wide(c, b) };
            return;
        }
        plain(c, b)
    }

    /// A gradient through a ReLU whose output was `y`: `d[i] = 0` where `y[i] ≤ 0` (the ReLU
    /// passed exactly where its output is positive).
    pub fn relu_mask(d: &mut [f32], y: &[f32]) {
        assert_eq!(d.len(), y.len(), "relu_mask shapes");
        // A select rather than a branch: the pattern is data-dependent.
        #[inline(always)]
        fn plain(d: &mut [f32], y: &[f32]) {
            d.iter_mut().zip(y).for_each(|(g, y)| *g = if *y > 0.0 { *g } else { 0.0 });
        }
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            /// 8 lanes at a time with explicit AND and full stores: from `plain`, LLVM makes
            /// masked stores of zeros (`vmaskmovps`), which AMD's cores run slowly (5 % of a
            /// training step's CPU time on a Zen 4). The AND keeps `g`'s bits or gives +0.0, as
            /// the select does.
            #[target_feature(enable = "avx2")]
            fn wide(d: &mut [f32], y: &[f32]) {
                use std::arch::x86_64::*;
                let (dc, yc) = (d.chunks_exact_mut(8), y.chunks_exact(8));
                let n8 = yc.len() * 8;
                for (g, y) in dc.zip(yc) {
                    // SAFETY: each chunk holds 8 floats.
                    unsafe {
                        let keep = _mm256_cmp_ps::<_CMP_GT_OQ>(_mm256_loadu_ps(y.as_ptr()), _mm256_setzero_ps());
                        _mm256_storeu_ps(g.as_mut_ptr(), _mm256_and_ps(_mm256_loadu_ps(g.as_ptr()), keep));
                    }
                }
                plain(&mut d[n8..], &y[n8..]);
            }
            // SAFETY: the CPU has AVX2 (checked above).
            unsafe { wide(d, y) };
            return;
        }
        plain(d, y)
    }

    /// `c[k][n] += a[m][k]ᵀ · b[m][n]` (a weight gradient: inputs transposed times output
    /// gradients) and `cb[n] += Σₛ b[s][n]` (the bias gradient). Where the CPU has FMA,
    /// register-blocked kernels for AVX-512 or AVX2 (chosen at run time, the same bits from
    /// either) that need no packing, which at the networks' sizes (`m` = 512 samples, 16 to 64
    /// wide) costs `gemm` about as much as the products, and that sum the bias from the same
    /// loads; elsewhere `gemm` and [`col_sums_acc`].
    pub fn weight_grads_acc(c: &mut [f32], cb: &mut [f32], a: &[f32], b: &[f32], m: usize, k: usize, n: usize) {
        assert!(c.len() == k * n && cb.len() == n && a.len() == m * k && b.len() == m * n, "weight_grads_acc shapes");
        if m == 0 || n == 0 {
            return;
        }
        if k == 0 {
            col_sums_acc(cb, b);
            return;
        }
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU has the features the function is compiled for (checked above).
                unsafe { blocked::tn_acc_avx512(c, cb, a, b, m, k, n) };
                return;
            }
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                // SAFETY: as above.
                unsafe { blocked::tn_acc_avx2(c, cb, a, b, m, k, n) };
                return;
            }
        }
        col_sums_acc(cb, b);
        // SAFETY: as above; aᵀ is `a` read with row stride 1 and column stride k.
        unsafe {
            gemm(
                k, n, m, c.as_mut_ptr(), 1, n as isize, true, a.as_ptr(), k as isize, 1, b.as_ptr(), 1, n as isize, 1.0, 1.0,
                false, false, false, Parallelism::None,
            )
        }
    }
}

/// This machine's fp32 matmul peak in GFLOP/s: `gemm` (the fastest fp32 GEMM in our
/// dependencies, runtime-dispatched to AVX-512 or AVX2) on an `n × n` square problem with
/// every rayon thread, best of `reps` runs.
pub fn gemm_peak_gflops(n: usize, reps: usize) -> f64 {
    mm::gemm_peak_gflops(n, reps.max(1))
}

/// The same networks through burn, the reference these kernels are tested and measured
/// against: the forward pass of `field` (`enc` `[n][enc_dims]`, `sh` `[n][dir_dims]`, empty
/// for `dir_dims` 0) on `field`'s device, giving raw density and flat RGB; with `grads`
/// (`d_raw`, `d_rgb`) also burn's autodiff backward through the surrogate
/// `sum(raw · d_raw) + sum(rgb · d_rgb)` (as the paper model trains), giving the gradient
/// with respect to the encoding and every parameter's. `field` must be on the training
/// (autodiff) device when `grads` is given.
#[allow(clippy::type_complexity)]
pub fn burn_reference(
    field: &HashField,
    enc: &[f32],
    sh: &[f32],
    grads: Option<(&[f32], &[[f32; 3]])>,
) -> (Vec<f32>, Vec<f32>, Option<(Vec<f32>, GradientsParams)>) {
    use crate::kernels::{tensor2, to_vec};
    let ed = field.density.layers[0].weight.val().dims()[0];
    let n = enc.len() / ed.max(1);
    let sd = sh.len() / n.max(1);
    let dev = if grads.is_some() { crate::backend::train_device() } else { crate::backend::inference_device() };
    let enc_t = tensor2(enc.to_vec(), n, ed, &dev);
    let enc_t = if grads.is_some() { enc_t.require_grad() } else { enc_t };
    let (raw_t, rgb_t) = if sd > 0 {
        field.forward(enc_t.clone(), tensor2(sh.to_vec(), n, sd, &dev))
    } else {
        let geo = field.density.forward(enc_t.clone());
        let raw = geo.clone().slice([0..n, 0..1]);
        (raw, burn::tensor::activation::sigmoid(field.color.forward(geo)))
    };
    let (raw, rgb) = (to_vec(raw_t.clone()), to_vec(rgb_t.clone()));
    let backward = grads.map(|(d_raw, d_rgb)| {
        let d_rgb_flat: Vec<f32> = d_rgb.iter().flatten().copied().collect();
        let surrogate = (raw_t * tensor2(d_raw.to_vec(), n, 1, &dev)).sum() + (rgb_t * tensor2(d_rgb_flat, n, 3, &dev)).sum();
        let grads = surrogate.backward();
        let d_enc = enc_t.grad(&grads).map(to_vec).unwrap_or_default();
        (d_enc, GradientsParams::from_grads(grads, field))
    });
    (raw, rgb, backward)
}

/// Seconds of one batch through the fast model's networks (64-wide, 16 geometry features,
/// two colour layers; medians of 5 runs after a warm-up) — `cargo xtask bench nerf`'s
/// comparison of these kernels with burn, measured in one run.
#[derive(Clone, Copy, Debug)]
pub struct NetworkSpeed {
    pub samples: usize,
    /// Forward multiply-adds of the batch.
    pub macs: f64,
    /// [`HashMlp::forward`].
    pub fused_forward_s: f64,
    /// [`HashMlp::train_groups`] over groups of [`TILE`] samples with a fixed loss gradient.
    pub fused_train_s: f64,
    /// burn's forward on the inference device.
    pub burn_forward_s: f64,
    /// burn's forward and autodiff backward (the surrogate loss the paper model uses), with
    /// the gradients with respect to the input and the parameters.
    pub burn_train_s: f64,
}

/// Measures [`NetworkSpeed`] for `enc_dims` encoding features, `dir_dims` direction features
/// and `n` samples of fixed pseudo-random inputs.
pub fn speed_against_burn(enc_dims: usize, dir_dims: usize, n: usize) -> NetworkSpeed {
    use crate::field::HashFieldConfig;
    use crate::kernels::seeded_init;
    use burn::module::Module;
    let (ed, sd) = (enc_dims, dir_dims);
    let field = seeded_init(HashFieldConfig::new(ed, sd).init(&crate::backend::train_device()), 1);
    let mlp = HashMlp::from_field(&field).expect("the default field's shape");
    let value = |k: usize, s: u64| crate::kernels::uniform(s, 0, k as u64, 0) * 2.0 - 1.0;
    let enc: Vec<f32> = (0..n * ed).map(|k| value(k, 1)).collect();
    let sh: Vec<f32> = (0..n * sd).map(|k| value(k, 2)).collect();
    let d_raw: Vec<f32> = (0..n).map(|k| 1e-3 * value(k, 3)).collect();
    let d_rgb: Vec<[f32; 3]> = (0..n).map(|k| std::array::from_fn(|j| 1e-3 * value(3 * k + j, 4))).collect();
    let time = |f: &mut dyn FnMut()| {
        f();
        let mut t: Vec<f64> = (0..5)
            .map(|_| {
                let t0 = std::time::Instant::now();
                f();
                t0.elapsed().as_secs_f64()
            })
            .collect();
        t.sort_by(f64::total_cmp);
        t[2]
    };
    let fused_forward_s = time(&mut || {
        std::hint::black_box(mlp.forward(&enc, &sh));
    });
    let groups: Vec<std::ops::Range<usize>> = (0..n).step_by(TILE).map(|s| s..(s + TILE).min(n)).collect();
    let fused_train_s = time(&mut || {
        std::hint::black_box(mlp.train_groups(&enc, &sh, &groups, |g, _, _| GroupGrads {
            d_raw: d_raw[groups[g].clone()].to_vec(),
            d_rgb: d_rgb[groups[g].clone()].to_vec(),
            value: (),
        }));
    });
    let inference = field.valid();
    let burn_forward_s = time(&mut || {
        std::hint::black_box(burn_reference(&inference, &enc, &sh, None));
    });
    let burn_train_s = time(&mut || {
        std::hint::black_box(burn_reference(&field, &enc, &sh, Some((&d_raw, &d_rgb))));
    });
    let macs = (ed * 64 + 64 * 16 + (16 + sd) * 64 + 64 * 64 + 64 * 3) as f64 * n as f64;
    NetworkSpeed { samples: n, macs, fused_forward_s, fused_train_s, burn_forward_s, burn_train_s }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::field::HashFieldConfig;
    use crate::kernels::{seeded_init, to_vec, uniform};

    fn inputs(n: usize, d: usize, stream: u64) -> Vec<f32> {
        (0..n * d).map(|k| uniform(7, stream, k as u64, 0) * 2.0 - 1.0).collect()
    }

    /// Network inputs and loss gradients of `n` samples, uniform in [−1, 1).
    struct Batch {
        enc: Vec<f32>,
        sh: Vec<f32>,
        d_raw: Vec<f32>,
        d_rgb: Vec<[f32; 3]>,
    }

    fn batch(n: usize, ed: usize, sd: usize) -> Batch {
        Batch {
            enc: inputs(n, ed, 1),
            sh: inputs(n, sd, 2),
            d_raw: inputs(n, 1, 3),
            d_rgb: inputs(n, 3, 4).chunks(3).map(|c| [c[0], c[1], c[2]]).collect(),
        }
    }

    /// [`super::burn_reference`] with gradients: (raw, rgb, d_enc, parameter gradients).
    fn burn_grads(field: &HashField, enc: &[f32], sh: &[f32], d_raw: &[f32], d_rgb: &[[f32; 3]]) -> (Vec<f32>, Vec<f32>, Vec<f32>, GradientsParams) {
        let (raw, rgb, grads) = super::burn_reference(field, enc, sh, Some((d_raw, d_rgb)));
        let (d_enc, params) = grads.unwrap();
        (raw, rgb, d_enc, params)
    }

    fn assert_close(what: &str, ours: &[f32], reference: &[f32], tol: f32) {
        assert_eq!(ours.len(), reference.len(), "{what}: lengths");
        let scale = reference.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1e-6);
        for (i, (a, b)) in ours.iter().zip(reference).enumerate() {
            assert!((a - b).abs() <= tol * scale, "{what}[{i}]: {a} against burn's {b} (scale {scale})");
        }
    }

    /// Forward outputs, input gradients and every parameter gradient agree with burn's
    /// autodiff, with and without the direction input, for a sample count that is not a
    /// multiple of the tile.
    #[test]
    fn matches_burn_forward_and_autodiff() {
        for (sd, n) in [(16usize, 2 * TILE + 77), (0, 300)] {
            let ed = 24;
            let cfg = HashFieldConfig { color_depth: 2, ..HashFieldConfig::new(ed, sd) };
            let field = seeded_init(cfg.init(&crate::backend::train_device()), 3);
            let Batch { enc, sh, d_raw, d_rgb } = batch(n, ed, sd);
            let (raw_b, rgb_b, d_enc_b, mut grads_b) = burn_grads(&field, &enc, &sh, &d_raw, &d_rgb);

            let mlp = HashMlp::from_field(&field).unwrap();
            assert_eq!((mlp.enc_dims(), mlp.dir_dims), (ed, sd));
            let (raw, rgb) = mlp.forward(&enc, &sh);
            assert_close("raw", &raw, &raw_b, 1e-5);
            assert_close("rgb", &rgb.iter().flatten().copied().collect::<Vec<_>>(), &rgb_b, 1e-5);
            assert_close("raw density only", &mlp.raw_density(&enc), &raw_b, 1e-5);

            let (d_enc, grads) = mlp.backward(&enc, &sh, &d_raw, &d_rgb);
            assert_close("d_enc", &d_enc, &d_enc_b, 1e-4);
            let mut ours = grads.into_params(&field);
            let mut checked = 0;
            for mlp_b in [&field.density, &field.color] {
                for layer in &mlp_b.layers {
                    let w = |g: &mut GradientsParams| to_vec(g.remove::<2>(layer.weight.id).unwrap());
                    assert_close("weight gradient", &w(&mut ours), &w(&mut grads_b), 1e-4);
                    let b_id = layer.bias.as_ref().unwrap().id;
                    let b = |g: &mut GradientsParams| to_vec(g.remove::<1>(b_id).unwrap());
                    assert_close("bias gradient", &b(&mut ours), &b(&mut grads_b), 1e-4);
                    checked += 2;
                }
            }
            assert_eq!(checked, 2 * (2 + 3), "every layer's weight and bias compared");
        }
    }

    /// ‖ours − reference‖ / ‖reference‖.
    fn relative_l2(ours: &[f32], reference: &[f32]) -> f64 {
        assert_eq!(ours.len(), reference.len());
        let d: f64 = ours.iter().zip(reference).map(|(a, b)| ((a - b) as f64).powi(2)).sum();
        let r: f64 = reference.iter().map(|b| (*b as f64).powi(2)).sum();
        (d / r.max(1e-300)).sqrt()
    }

    /// The bf16 networks ([`HashMlp::with_bf16`]) against burn's fp32 autodiff, and not the
    /// fp32 path's bits (the products did run in bf16); the same bits with one thread as with
    /// all. The kernels themselves are checked exactly against f64 in [`bf16`]'s tests; this
    /// checks the wiring:
    /// - forward outputs within 2 % of their largest value (each product's inputs carry a
    ///   relative error up to 2⁻⁹: measured 0.3 %);
    /// - gradients within 10 % in relative L2 norm. Not closer, because a hidden unit whose
    ///   pre-activation is within that 0.3 % of zero can fall on the other side of its ReLU,
    ///   and its whole gradient then flows or not: about 0.2 % of units flip, which makes
    ///   √0.002 ≈ 4–6 % (measured) of the gradients' norm. Any mistake in the layouts or the
    ///   wiring gives errors of order 100 %.
    #[test]
    fn bf16_networks_match_burn_within_bf16_rounding() {
        if !bf16::available() {
            assert!(HashMlp::from_field(&seeded_init(HashFieldConfig::new(8, 0).init(&crate::backend::train_device()), 1)).unwrap().with_bf16().is_err());
            eprintln!("skipped: this CPU has no AVX512-BF16 (checked that bf16 is refused)");
            return;
        }
        let (ed, sd, n) = (32, 16, TILE + 131);
        let cfg = HashFieldConfig { color_depth: 2, ..HashFieldConfig::new(ed, sd) };
        let field = seeded_init(cfg.init(&crate::backend::train_device()), 5);
        let Batch { enc, sh, d_raw, d_rgb } = batch(n, ed, sd);
        let (raw_b, rgb_b, d_enc_b, mut grads_b) = burn_grads(&field, &enc, &sh, &d_raw, &d_rgb);
        let fp32 = HashMlp::from_field(&field).unwrap();
        let mlp = fp32.clone().with_bf16().unwrap();
        assert!(mlp.is_bf16() && !fp32.is_bf16());
        let (raw, rgb) = mlp.forward(&enc, &sh);
        let rgb: Vec<f32> = rgb.iter().flatten().copied().collect();
        assert_close("bf16 raw", &raw, &raw_b, 2e-2);
        assert_close("bf16 rgb", &rgb, &rgb_b, 2e-2);
        let (raw32, _) = fp32.forward(&enc, &sh);
        assert!(raw.iter().zip(&raw32).any(|(a, b)| a != b), "bf16 gave fp32's bits: the bf16 kernels did not run");
        let (d_enc, grads) = mlp.backward(&enc, &sh, &d_raw, &d_rgb);
        let close = |what: &str, ours: &[f32], reference: &[f32]| {
            let e = relative_l2(ours, reference);
            assert!(e <= 0.1, "{what}: relative L2 error {e} against burn");
        };
        close("bf16 d_enc", &d_enc, &d_enc_b);
        let mut ours = grads.clone().into_params(&field);
        let mut checked = 0;
        for mlp_b in [&field.density, &field.color] {
            for layer in &mlp_b.layers {
                let w = |g: &mut GradientsParams| to_vec(g.remove::<2>(layer.weight.id).unwrap());
                close("bf16 weight gradient", &w(&mut ours), &w(&mut grads_b));
                let b_id = layer.bias.as_ref().unwrap().id;
                let b = |g: &mut GradientsParams| to_vec(g.remove::<1>(b_id).unwrap());
                close("bf16 bias gradient", &b(&mut ours), &b(&mut grads_b));
                checked += 2;
            }
        }
        assert_eq!(checked, 2 * (2 + 3));
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let (d_enc1, grads1) = one.install(|| mlp.backward(&enc, &sh, &d_raw, &d_rgb));
        assert!(d_enc1 == d_enc && grads1 == grads, "bf16 gradients depend on the thread count");
    }

    /// One Adam step with our gradients moves burn's parameters as one with burn's own.
    #[test]
    fn gradients_step_burns_optimiser() {
        use crate::field::{AdamSettings, MlpAdam};
        use crate::kernels::param_vectors;
        let (ed, sd, n) = (16, 9, 200);
        let field = seeded_init(HashFieldConfig::new(ed, sd).init(&crate::backend::train_device()), 5);
        let Batch { enc, sh, d_raw, d_rgb } = batch(n, ed, sd);
        let (_, _, _, mut grads_b) = burn_grads(&field, &enc, &sh, &d_raw, &d_rgb);
        let settings = AdamSettings::new(0.9, 0.99, 1e-15);
        let stepped_b = MlpAdam::new(&settings).step(1e-2, field.clone(), &mut grads_b);
        let mlp = HashMlp::from_field(&field).unwrap();
        let mut ours = mlp.backward(&enc, &sh, &d_raw, &d_rgb).1.into_params(&field);
        let stepped = MlpAdam::new(&settings).step(1e-2, field.clone(), &mut ours);
        let (a, b) = (param_vectors(&stepped), param_vectors(&stepped_b));
        let before = param_vectors(&field);
        for ((a, b), p) in a.iter().zip(&b).zip(&before) {
            assert_close("stepped parameter", a, b, 1e-5);
            assert!(a.iter().zip(p).any(|(x, y)| x != y), "the step moved the parameters");
        }
    }

    /// The grouped sweep gives what a forward pass, then the backward pass with the same
    /// per-sample gradients, gives (groups of uneven sizes, one empty).
    #[test]
    fn train_groups_equals_forward_then_backward() {
        let (ed, sd, n) = (20, 9, 1500);
        let field = seeded_init(HashFieldConfig::new(ed, sd).init(&crate::backend::inference_device()), 4);
        let mlp = HashMlp::from_field(&field).unwrap();
        let Batch { enc, sh, d_raw, d_rgb } = batch(n, ed, sd);
        let (raw, rgb) = mlp.forward(&enc, &sh);
        let (d_enc, grads) = mlp.backward(&enc, &sh, &d_raw, &d_rgb);
        let groups = [0..100, 100..700, 700..700, 700..703, 703..n];
        let (d_enc_g, grads_g, values) = mlp.train_groups(&enc, &sh, &groups, |g, raw_g, rgb_g| {
            let r = groups[g].clone();
            assert_close("grouped raw", raw_g, &raw[r.clone()], 1e-6);
            let flat = |v: &[[f32; 3]]| v.iter().flatten().copied().collect::<Vec<_>>();
            assert_close("grouped rgb", &flat(rgb_g), &flat(&rgb[r.clone()]), 1e-6);
            GroupGrads { d_raw: d_raw[r.clone()].to_vec(), d_rgb: d_rgb[r.clone()].to_vec(), value: r.len() }
        });
        assert_eq!(values, vec![100, 600, 0, 3, n - 703]);
        assert_close("d_enc", &d_enc_g, &d_enc, 1e-5);
        for (a, b) in grads_g.density.iter().chain(&grads_g.color).zip(grads.density.iter().chain(&grads.color)) {
            assert_close("weight gradient", &a.w, &b.w, 1e-5);
            assert_close("bias gradient", &a.b, &b.b, 1e-5);
        }
        assert!(grads_g.is_finite());
        // In column blocks: the same numbers, block-major, bit for bit.
        let ed = mlp.enc_dims();
        assert!(ed.is_multiple_of(4) && ed > 4, "the test covers blocks of the hash grid's sizes and others");
        for block in (1..=ed).filter(|b| ed.is_multiple_of(*b)) {
            let (d_blk, _, _) = mlp.train_groups_blocked(&enc, &sh, &groups, block, |g, _, _| {
                let r = groups[g].clone();
                GroupGrads { d_raw: d_raw[r.clone()].to_vec(), d_rgb: d_rgb[r.clone()].to_vec(), value: () }
            });
            for (s, row) in d_enc_g.chunks_exact(ed).enumerate() {
                for (c, v) in row.iter().enumerate() {
                    let (b, j) = (c / block, c % block);
                    assert_eq!(d_blk[(b * n + s) * block + j].to_bits(), v.to_bits(), "block {block}, sample {s}, column {c}");
                }
            }
        }
    }

    /// Bit-identical results with 1 and 3 threads.
    #[test]
    fn deterministic_across_thread_counts() {
        let (ed, sd, n) = (32, 16, 5 * TILE + 3);
        let field = seeded_init(HashFieldConfig::new(ed, sd).init(&crate::backend::inference_device()), 9);
        let mlp = HashMlp::from_field(&field).unwrap();
        let Batch { enc, sh, d_raw, d_rgb } = batch(n, ed, sd);
        let run = |threads| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| (mlp.forward(&enc, &sh), mlp.backward(&enc, &sh, &d_raw, &d_rgb)))
        };
        assert!(run(1) == run(3));
    }

    /// The ReLU's backward mask keeps a gradient exactly where the output is > 0 (NaN and ±0
    /// outputs are not) and otherwise gives +0.0, bit for bit, at every length (vector tails).
    #[test]
    fn relu_mask_keeps_the_gradient_where_the_output_passed() {
        let ys = [1.0f32, -1.0, 0.0, -0.0, f32::NAN, f32::INFINITY, f32::NEG_INFINITY, f32::MIN_POSITIVE / 4.0, -f32::MIN_POSITIVE / 4.0];
        let gs = [2.5f32, -3.0, f32::NAN, -0.0, f32::INFINITY, 1e-40, -7.0];
        for n in [0usize, 1, 7, 8, 9, 31, 64, 67] {
            let y: Vec<f32> = (0..n).map(|i| ys[i % ys.len()]).collect();
            let g: Vec<f32> = (0..n).map(|i| gs[(i * 5 + 1) % gs.len()]).collect();
            let mut d = g.clone();
            mm::relu_mask(&mut d, &y);
            for i in 0..n {
                let want = if y[i] > 0.0 { g[i] } else { 0.0 };
                assert_eq!(d[i].to_bits(), want.to_bits(), "n {n}, element {i}: y {} g {}", y[i], g[i]);
            }
        }
    }

    #[test]
    fn empty_input_gives_empty_outputs() {
        let field = seeded_init(HashFieldConfig::new(8, 4).init(&crate::backend::inference_device()), 1);
        let mlp = HashMlp::from_field(&field).unwrap();
        let (raw, rgb) = mlp.forward(&[], &[]);
        assert!(raw.is_empty() && rgb.is_empty());
        let (d_enc, g) = mlp.backward(&[], &[], &[], &[]);
        assert!(d_enc.is_empty());
        assert!(g.density.iter().chain(&g.color).all(|l| l.w.iter().chain(&l.b).all(|v| *v == 0.0)));
    }

    /// The dense kernel against an f64 reference for shapes that exercise every path (row
    /// tails, 1- and 2-vector column blocks, columns narrower than a vector), with and without
    /// the ReLU; each row's bits do not depend on the other rows of the call; and where the CPU
    /// has both, the AVX2 and AVX-512 kernels agree bit for bit.
    #[test]
    fn dense_kernel_matches_f64_and_is_row_independent() {
        for (m, k, n) in [(1usize, 1usize, 1usize), (7, 32, 64), (13, 64, 16), (9, 16, 3), (21, 19, 40), (5, 64, 70), (33, 35, 24), (8, 64, 8)] {
            let x: Vec<f32> = (0..m * k).map(|i| ((i * 7919) % 1013) as f32 / 1013.0 - 0.5).collect();
            let w: Vec<f32> = (0..k * n).map(|i| ((i * 104729) % 997) as f32 / 997.0 - 0.5).collect();
            let b: Vec<f32> = (0..n).map(|i| (i as f32 * 0.37).sin()).collect();
            for relu in [false, true] {
                let mut y = vec![f32::NAN; m * n];
                super::mm::dense(&mut y, &x, &w, &b, m, k, n, relu);
                for r in 0..m {
                    for c in 0..n {
                        let mut e = b[c] as f64;
                        for i in 0..k {
                            e += x[r * k + i] as f64 * w[i * n + c] as f64;
                        }
                        let e = if relu { e.max(0.0) } else { e };
                        assert!((y[r * n + c] as f64 - e).abs() <= 1e-5 * (1.0 + e.abs()), "{m}x{k}x{n} ({r},{c}): {} vs {e}", y[r * n + c]);
                    }
                }
                // The last row alone gives the same bits.
                let mut last = vec![0.0; n];
                super::mm::dense(&mut last, &x[(m - 1) * k..], &w, &b, 1, k, n, relu);
                assert_eq!(last, y[(m - 1) * n..], "{m}x{k}x{n}: row {} alone", m - 1);
                #[cfg(target_arch = "x86_64")]
                if n.is_multiple_of(16) && std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                    let mut y2 = vec![0.0; m * n];
                    // SAFETY: the CPU has AVX2 and FMA (checked).
                    #[allow(unsafe_code)]
                    unsafe {
                        super::mm::blocked::dense_avx2(&mut y2, &x, &w, n, &b, m, k, n, relu)
                    };
                    assert_eq!(y2, y, "{m}x{k}x{n}: AVX2 against AVX-512");
                }
            }
        }
    }

    /// The weight-gradient kernel against an f64 reference for shapes that exercise every
    /// path (passes of samples, row tails, 1-, 2- and 4-vector column blocks, columns narrower
    /// than a vector), accumulating onto a nonzero `c`; where the CPU has both, the AVX2 and
    /// AVX-512 kernels give the same bits (each element is the same fused sum in sample order).
    /// And the strided forward kernel on the first `n` of `ldw` columns equals the dense one on
    /// those columns alone, bit for bit.
    #[test]
    fn weight_gradient_kernel_matches_f64_and_strided_dense_its_slice() {
        for (m, k, n) in [(1usize, 1usize, 1usize), (512, 64, 64), (512, 32, 64), (100, 64, 16), (77, 64, 3), (70, 19, 40), (5, 64, 70), (130, 35, 24), (65, 16, 8)] {
            let a: Vec<f32> = (0..m * k).map(|i| ((i * 7919) % 1013) as f32 / 1013.0 - 0.5).collect();
            let b: Vec<f32> = (0..m * n).map(|i| ((i * 104729) % 997) as f32 / 997.0 - 0.5).collect();
            let c0: Vec<f32> = (0..k * n).map(|i| (i as f32 * 0.37).sin()).collect();
            let cb0: Vec<f32> = (0..n).map(|i| (i as f32 * 0.71).cos()).collect();
            let (mut c, mut cb) = (c0.clone(), cb0.clone());
            super::mm::weight_grads_acc(&mut c, &mut cb, &a, &b, m, k, n);
            // The bias: each column summed in sample order, as the plain column sums do.
            let mut cb_plain = cb0.clone();
            for row in b.chunks_exact(n) {
                cb_plain.iter_mut().zip(row).for_each(|(x, y)| *x += y);
            }
            assert_eq!(cb, cb_plain, "{m}x{k}x{n}: bias gradient");
            for r in 0..k {
                for j in 0..n {
                    let (mut e, mut scale) = (c0[r * n + j] as f64, c0[r * n + j].abs() as f64);
                    for s in 0..m {
                        let p = a[s * k + r] as f64 * b[s * n + j] as f64;
                        e += p;
                        scale += p.abs();
                    }
                    let got = c[r * n + j] as f64;
                    assert!((got - e).abs() <= 1e-6 * (1.0 + scale), "{m}x{k}x{n} ({r},{j}): {got} vs {e}");
                }
            }
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                let (mut c2, mut cb2) = (c0.clone(), cb0.clone());
                // SAFETY: the CPU has AVX2 and FMA (checked).
                #[allow(unsafe_code)]
                unsafe {
                    super::mm::blocked::tn_acc_avx2(&mut c2, &mut cb2, &a, &b, m, k, n)
                };
                assert_eq!((c2, cb2), (c, cb), "{m}x{k}x{n}: AVX2 against AVX-512");
            }
            // The strided forward kernel: `b` `[m][n]` times the first `k.min(n)` columns of `c0`
            // read as `[k][n]` with row stride `n`.
            let cols = k.min(n).max(1);
            let (w, wn): (Vec<f32>, Vec<f32>) = (c0.clone(), c0.chunks_exact(n).flat_map(|r| r[..cols].iter().copied()).collect());
            let bias: Vec<f32> = (0..cols).map(|i| i as f32 * 0.1).collect();
            let x: Vec<f32> = (0..m * k).map(|i| a[i] * 0.5).collect();
            let (mut y1, mut y2) = (vec![0.0; m * cols], vec![0.0; m * cols]);
            super::mm::dense_strided(&mut y1, &x, &w, n, &bias, m, k, cols, true);
            super::mm::dense(&mut y2, &x, &wn, &bias, m, k, cols, true);
            assert_eq!(y1, y2, "{m}x{k}x{n}: strided against sliced");
        }
    }
}
