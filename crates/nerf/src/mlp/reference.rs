//! The fused networks' reference and measurement: the same networks through burn
//! ([`burn_reference`]), their speed against burn's ([`speed_against_burn`]) and the machine's
//! fp32 matmul peak ([`gemm_peak_gflops`]), for `cargo xtask bench nerf` and the tests.

use super::{GroupGrads, HashMlp, TILE};
use crate::field::HashField;
use burn::optim::GradientsParams;

/// This machine's fp32 matmul peak in GFLOP/s: `gemm` (the fastest fp32 GEMM in our
/// dependencies, runtime-dispatched to AVX-512 or AVX2) on an `n × n` square problem with
/// every rayon thread, best of `reps` runs.
pub fn gemm_peak_gflops(n: usize, reps: usize) -> f64 {
    super::mm::gemm_peak_gflops(n, reps.max(1))
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
