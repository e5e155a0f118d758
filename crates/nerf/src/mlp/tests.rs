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

/// [`burn_reference`] with gradients: (raw, rgb, d_enc, parameter gradients).
fn burn_grads(field: &HashField, enc: &[f32], sh: &[f32], d_raw: &[f32], d_rgb: &[[f32; 3]]) -> (Vec<f32>, Vec<f32>, Vec<f32>, GradientsParams) {
    let (raw, rgb, grads) = burn_reference(field, enc, sh, Some((d_raw, d_rgb)));
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
