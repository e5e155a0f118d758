use super::*;

/// `n` unit directions looking down −z through a 16-wide grid of tangents `k·spacing − start`.
fn fan(n: usize, spacing: f32, start: f32) -> Vec<[f32; 3]> {
    (0..n)
        .map(|i| {
            let (a, b) = ((i % 16) as f32 * spacing - start, (i / 16) as f32 * spacing - start);
            let l = (a * a + b * b + 1.0f32).sqrt();
            [a / l, b / l, -1.0 / l]
        })
        .collect()
}

/// `mlp_precision` takes fp32 or bf16 and nothing else; a bf16 model learns a constant
/// colour as the fp32 one does (its loss falls as far within a few per cent), or is refused
/// with a message naming AVX512-BF16 on a CPU without it.
#[test]
fn bf16_networks_train_like_fp32_or_are_refused() {
    let bad = FastConfig::new().with_mlp_precision(Some("fp16".into()));
    let e = bad.check().unwrap_err();
    assert!(e.contains("model.mlp_precision") && e.contains("fp16"), "{e}");
    let bounds = SceneBounds { aabb_min: [-1.0; 3], aabb_max: [1.0; 3], near: 0.5, far: 6.0, source: "test".into() };
    let cfg = |p: &str| {
        FastConfig::new()
            .with_levels(4)
            .with_log2_table_size(12)
            .with_finest_resolution(64)
            .with_grid_resolution(16)
            .with_steps_per_diagonal(64)
            .with_mlp_precision(Some(p.into()))
    };
    assert!(cfg("fp32").check().is_ok() && cfg("bf16").check().is_ok());
    let n = 256;
    let batch = RayBatch {
        origins: vec![[0.0, 0.0, 3.0]; n],
        dirs: fan(n, 0.02, 0.15),
        target: vec![[0.7, 0.3, 0.2]; n],
        background: vec![[0.0; 3]; n],
        ids: (0..n as u64).collect(),
        mixed: Vec::new(),
        supervision: None,
    };
    let losses = |p: &str| -> Result<Vec<f32>, String> {
        let mut m = FastModel::new(cfg(p), bounds.clone(), 3)?;
        Ok((0..40).map(|step| m.train_step(&batch, step, 0).loss).collect())
    };
    let fp32 = losses("fp32").unwrap();
    match losses("bf16") {
        Err(e) => {
            assert!(!crate::mlp::bf16::available() && e.contains("AVX512-BF16"), "{e}");
            eprintln!("skipped the training comparison: {e}");
        }
        Ok(bf16) => {
            assert!(crate::mlp::bf16::available());
            assert!(bf16.iter().all(|l| l.is_finite()));
            assert_ne!(fp32, bf16, "the bf16 run gave fp32's losses: its kernels did not run");
            let (f0, f1, b1) = (fp32[0], fp32[39], bf16[39]);
            assert!(f1 < 0.2 * f0, "fp32 learned too little: {f0} → {f1}");
            assert!((b1 - f1).abs() <= 0.05 * f0, "bf16 ended at {b1}, fp32 at {f1} (from {f0})");
        }
    }
}

/// Dropping the direction input keeps the hash tables, the density network and the
/// occupancy grid exactly, and the new colour network computes the old one fed the SH
/// vector of the direction average (Y₀₀, 0, …, 0); training goes on from there.
#[test]
fn dropping_view_dependence_keeps_the_direction_averaged_colour() {
    let bounds = SceneBounds { aabb_min: [-1.0; 3], aabb_max: [1.0; 3], near: 0.5, far: 6.0, source: "test".into() };
    let cfg = FastConfig::new()
        .with_levels(4)
        .with_log2_table_size(12)
        .with_finest_resolution(64)
        .with_grid_resolution(16)
        .with_steps_per_diagonal(64)
        .with_grid_warmup_steps(2);
    let mut m = FastModel::new(cfg, bounds, 3).unwrap();
    let n = 64;
    let batch = RayBatch {
        origins: vec![[0.0, 0.0, 3.0]; n],
        dirs: (0..n)
            .map(|i| {
                let a = i as f32 * 0.01 - 0.3;
                let l = (a * a + 0.04 + 1.0f32).sqrt();
                [a / l, 0.2 / l, -1.0 / l]
            })
            .collect(),
        target: vec![[0.7, 0.3, 0.2]; n],
        background: vec![[0.0; 3]; n],
        ids: (0..n as u64).collect(),
        mixed: Vec::new(),
        supervision: None,
    };
    for step in 0..4 {
        m.lr = 1e-2;
        assert!(m.train_step(&batch, step, 0).loss.is_finite());
    }
    let mut d = m.without_view_dependence().unwrap();
    assert!(m.config.is_view_dependent() && !d.config.is_view_dependent());
    assert_eq!(d.config.dir_dims(), 0);
    assert_eq!(d.grid.params, m.grid.params);
    assert_eq!((&d.grid_adam.m, &d.grid_adam.v), (&m.grid_adam.m, &m.grid_adam.v));
    assert_eq!(d.occupancy.density, m.occupancy.density);
    assert_eq!(d.occupancy.bits, m.occupancy.bits);
    let (old, new) = (m.mlp(), d.mlp());
    let (k, ed, sd) = (50, old.enc_dims(), m.config.dir_dims());
    let enc: Vec<f32> = (0..k * ed).map(|i| ((i * 7919 % 1000) as f32 / 1000.0 - 0.5) * 0.4).collect();
    let mut sh = vec![0.0f32; k * sd];
    let y00 = sh_encode([0.0, 0.0, 1.0])[0];
    (0..k).for_each(|r| sh[r * sd] = y00);
    let (raw_o, rgb_o) = old.forward(&enc, &sh);
    let (raw_n, rgb_n) = new.forward(&enc, &[]);
    assert_eq!(raw_o, raw_n, "the density network is unchanged");
    let diff = |a: &[[f32; 3]], b: &[[f32; 3]]| a.iter().zip(b).flat_map(|(x, y)| (0..3).map(move |c| (x[c] - y[c]).abs())).fold(0.0f32, f32::max);
    assert!(diff(&rgb_o, &rgb_n) < 1e-5, "{}", diff(&rgb_o, &rgb_n));
    // Not vacuous: along an actual direction the old network's colour is another.
    let one = sh_encode([0.6, 0.0, 0.8]);
    let sh_dir: Vec<f32> = (0..k).flat_map(|_| one[..sd].to_vec()).collect();
    assert!(diff(&old.forward(&enc, &sh_dir).1, &rgb_n) > 1e-4);
    d.lr = 1e-2;
    assert!(d.train_step(&batch, 4, 0).loss.is_finite());
    assert!(m.without_view_dependence().unwrap().without_view_dependence().is_ok(), "already off: a copy");
}

/// Inference rendering (chunks, rounds, colour only where the weight shows) against the
/// plain composite of every marched sample through the full network: equal within the
/// skipped weights; and bit-identical for any thread count and any split of the rays.
#[test]
fn rendering_matches_the_full_composite_for_any_split_and_pool() {
    let bounds = SceneBounds { aabb_min: [-1.0; 3], aabb_max: [1.0; 3], near: 0.5, far: 6.0, source: "test".into() };
    let cfg = FastConfig::new().with_levels(4).with_log2_table_size(12).with_finest_resolution(64).with_grid_resolution(16).with_steps_per_diagonal(64);
    let mut m = FastModel::new(cfg, bounds, 5).unwrap();
    // Dense enough that rays saturate: raise the density network's output bias.
    let mut s = m.state();
    let n_density = crate::kernels::param_vectors(&m.field.density).len();
    if let Some(b) = s.arrays.get_mut(&format!("field.{}", n_density - 1)) {
        b[0] = 2.0;
    }
    m.load_state(&s).unwrap();
    let n = 2 * RENDER_CHUNK + 300;
    let origins = vec![[0.0, 0.2, 3.0]; n];
    let dirs: Vec<[f32; 3]> = (0..n)
        .map(|i| {
            let (a, b) = ((i % 50) as f32 * 0.012 - 0.3, (i / 50) as f32 * 0.012 - 0.3);
            let l = (a * a + b * b + 1.0f32).sqrt();
            [a / l, b / l, -1.0 / l]
        })
        .collect();
    let bg = [0.2, 0.4, 0.6];
    let out = m.render_rays(&origins, &dirs, bg);
    // The full composite.
    let samples = m.march(&origins, &dirs, SampleMode::Deterministic);
    let unit = m.unit_points(&samples, None, &origins, &dirs);
    let enc = m.hash_encode(&unit);
    let sh = m.parts().sh_for(&samples.ray_index, &dirs);
    let (raw, rgb) = m.mlp().forward(&enc, &sh);
    let sigma: Vec<f32> = raw.iter().map(|x| ACT.forward(*x)).collect();
    let full = volrend::composite_forward_with(&volrend::CompositeInputs { offsets: &samples.offsets, sigma: &sigma, rgb: &rgb, t_start: &samples.t_start, t_end: &samples.t_end, background: &vec![bg; n] }, volrend::CompositeOptions::INFERENCE);
    let opaque = out.opacity.iter().filter(|o| **o > 0.99).count();
    assert!(opaque > n / 10, "the test needs rays that hit: {opaque} of {n} opaque");
    for r in 0..n {
        assert!((out.opacity[r] - full.opacity[r]).abs() < 1e-3, "ray {r}: opacity {} vs {}", out.opacity[r], full.opacity[r]);
        for c in 0..3 {
            assert!((out.rgb[r][c] - full.rgb[r][c]).abs() < 2e-3, "ray {r}: rgb {:?} vs {:?}", out.rgb[r], full.rgb[r]);
        }
    }
    // Any pool, any split.
    let (mlp, parts) = (m.mlp(), m.parts());
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap().install(|| parts.render_rays(&mlp, &origins, &dirs, bg));
    assert_eq!((&one.rgb, &one.opacity, &one.distance, &one.w), (&out.rgb, &out.opacity, &out.distance, &out.w));
    let k = 777;
    let mut split = m.render_rays(&origins[..k], &dirs[..k], bg);
    split.append(m.render_rays(&origins[k..], &dirs[k..], bg));
    assert_eq!((&split.rgb, &split.opacity, &split.distance), (&out.rgb, &out.opacity, &out.distance));
}

/// Marching and compaction by rounds keep exactly what one density pass over every sample
/// of the full march keeps (the same intervals, points and encodings, bit for bit), for
/// rays that miss the box, cross empty cells and stop in every round, jittered or not, on
/// any thread count, while marching fewer samples.
#[test]
fn compaction_by_rounds_equals_one_pass_over_the_full_march() {
    let bounds = SceneBounds { aabb_min: [-1.0; 3], aabb_max: [1.0; 3], near: 0.5, far: 6.0, source: "test".into() };
    let cfg = FastConfig::new().with_levels(4).with_log2_table_size(12).with_finest_resolution(64).with_grid_resolution(16).with_steps_per_diagonal(160);
    let mut m = FastModel::new(cfg, bounds, 3).unwrap();
    // Large random table values: densities from near 0 to huge, so rays stop anywhere.
    let mut x = 0x9e37_79b9_u32;
    let mut next = || {
        x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (x >> 8) as f32 / (1u32 << 24) as f32
    };
    for p in m.grid.params.iter_mut() {
        *p = next() * 8.0 - 4.0;
    }
    // A third of the occupancy cells empty (the march skips them, through the blocks).
    for (i, w) in m.occupancy.bits.iter_mut().enumerate() {
        *w &= [0x9249_2492_4924_9249u64, u64::MAX, 0xdb6d_b6db_6db6_db6d][i % 3];
    }
    m.refresh_empty_space();
    let n_rays = 300;
    // From z = 3 towards the box, some passing beside it.
    let origins: Vec<[f32; 3]> = (0..n_rays).map(|_| [next() * 2.4 - 1.2, next() * 2.4 - 1.2, 3.0]).collect();
    let dirs: Vec<[f32; 3]> = (0..n_rays)
        .map(|_| {
            let (a, b) = (next() * 0.6 - 0.3, next() * 0.6 - 0.3);
            let l = (a * a + b * b + 1.0f32).sqrt();
            [a / l, b / l, -1.0 / l]
        })
        .collect();
    let mlp = m.mlp();
    let parts = m.parts();
    let dims = m.grid.output_dim();
    // Where rays stopped (samples kept, for the rays that kept fewer than they marched).
    let mut stops = Vec::new();
    for jitter in [SampleMode::Deterministic, SampleMode::Random { seed: 9, step: 4 }] {
        let all = parts.march(&origins, &dirs, jitter);
        assert!(all.offsets.windows(2).any(|w| w[0] == w[1]) && all.len() > 20 * n_rays, "{} samples", all.len());
        let unit_all = parts.unit_points(&all, None, &origins, &dirs);
        let enc_all = parts.hash_encode(&unit_all);
        let sigma: Vec<f32> = mlp.raw_density(&enc_all).into_iter().map(|x| ACT.forward(x)).collect();
        for tau_stop in [0.05f32, 0.2, 0.5, 2.0] {
            let (want, idx) = keep_until_opaque(&all, &sigma, tau_stop);
            let want_unit: Vec<[f32; 3]> = idx.iter().map(|&i| unit_all[i]).collect();
            let want_enc: Vec<u32> = idx.iter().flat_map(|&i| enc_all[i * dims..(i + 1) * dims].iter().map(|v| v.to_bits())).collect();
            stops.extend((0..n_rays).map(|r| (want.offsets[r + 1] - want.offsets[r], all.offsets[r + 1] - all.offsets[r])).filter(|(k, n)| k < n).map(|(k, _)| k));
            for threads in [1, 3] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
                let mut tm = StepTimings::default();
                let (got, unit, enc, marched) = pool.install(|| parts.march_until_opaque(&mlp, &origins, &dirs, jitter, tau_stop, &mut tm));
                assert_eq!((&got.offsets, &got.t_start, &got.t_end, &got.ray_index), (&want.offsets, &want.t_start, &want.t_end, &want.ray_index));
                assert_eq!(unit, want_unit);
                assert_eq!(enc.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), want_enc);
                assert!(marched >= idx.len() && marched <= all.len(), "{marched} marched, {} kept of {}", idx.len(), all.len());
                // Where rays stop, fewer are marched than the full march gives.
                assert!(idx.len() == all.len() || marched < all.len(), "{marched} marched, {} kept of {}", idx.len(), all.len());
            }
        }
    }
    // Rays stop in each round: after 1-4, 5-12, 13-28 and 29-60 samples.
    assert!([1..5, 5..13, 13..29, 29..61].iter().all(|round| stops.iter().any(|k| round.contains(k))), "{stops:?}");
}

#[test]
fn ray_groups_hold_whole_rays_of_about_the_target() {
    // Rays of 3, 0, 5, 2, 9, 1 samples; target 4.
    let offsets = [0u32, 3, 3, 8, 10, 19, 20];
    let g = ray_groups(&offsets, 4);
    assert_eq!(g, vec![(0..3, 0..8), (3..5, 8..19), (5..6, 19..20)]);
    // A target of 1 makes every non-empty ray close a group; empty rays join the next.
    let g = ray_groups(&offsets, 1);
    assert_eq!(g, vec![(0..1, 0..3), (1..3, 3..8), (3..4, 8..10), (4..5, 10..19), (5..6, 19..20)]);
    assert!(ray_groups(&[0], 4).is_empty());
    // A batch of rays without samples is one empty group.
    assert_eq!(ray_groups(&[0, 0, 0], 4), vec![(0..2, 0..0)]);
}

/// The rays' gradients ([`RayGradients`]) agree with finite differences of the step's loss
/// (origins with the view-dependent model, directions with the view-independent one, whose
/// colour does not read the direction), and a step that only returns them leaves the model
/// unchanged.
#[test]
fn ray_gradients_match_finite_differences_of_the_loss() {
    // The rays start inside the box and end before leaving it, and the occupancy grid keeps
    // every cell (it is never updated), so every sample's `t` is the same for the
    // shifted rays: marching places samples from `max(near, box entry)` to
    // `min(far, box exit)`, skipping empty cells, which the gradient (at fixed `t`) does not
    // follow.
    let bounds = SceneBounds { aabb_min: [-1.0; 3], aabb_max: [1.0; 3], near: 0.2, far: 1.6, source: "test".into() };
    let cfg = FastConfig::new().with_levels(4).with_log2_table_size(12).with_finest_resolution(32).with_grid_resolution(16).with_steps_per_diagonal(128);
    // ... and no compaction, which drops samples behind the point where a ray turns opaque.
    let cfg = FastConfig { grid_update_interval: 1 << 40, train_min_transmittance: 0.0, ..cfg };
    let n = 256;
    let dirs: Vec<[f32; 3]> = fan(n, 0.03, 0.22);
    // A target with structure, so that the trained field has gradients in space.
    let target: Vec<[f32; 3]> = (0..n).map(|i| if (i % 16) / 4 % 2 == (i / 64) % 2 { [0.9, 0.2, 0.1] } else { [0.1, 0.3, 0.8] }).collect();
    let batch = RayBatch { origins: vec![[0.0, 0.0, 0.9]; n], dirs, target, background: vec![[0.0; 3]; n], ids: (0..n as u64).collect(), mixed: Vec::new(), supervision: None };
    let mut m = FastModel::new(cfg, bounds, 5).unwrap();
    for step in 0..80 {
        m.train_step(&batch, step, 1);
    }
    let check = |m: &mut FastModel, origins: bool| {
        m.set_ray_gradients(RayGradients::Only).unwrap();
        let (params, field) = (m.grid.params.clone(), format!("{:?}", m.field.clone().into_record()));
        let at = |b: &RayBatch, m: &mut FastModel| m.train_step(b, 1000, 1);
        let base = at(&batch, m);
        let g = base.ray_grads.clone().expect("ray gradients were asked for");
        assert_eq!(m.grid.params, params, "a gradient-only step changed the tables");
        assert_eq!(format!("{:?}", m.field.clone().into_record()), field, "a gradient-only step changed the networks");
        let delta: Vec<[f32; 3]> = (0..n).map(|r| [0, 1, 2].map(|a| (((r * 7 + a * 3) % 11) as f32 - 5.0) / 5.0)).collect();
        let grads = if origins { &g.d_origins } else { &g.d_dirs };
        let predicted: f64 = grads.iter().zip(&delta).map(|(g, d)| (0..3).map(|a| g[a] as f64 * d[a] as f64).sum::<f64>()).sum();
        let h = 1e-4f32;
        let shifted = |sign: f32| {
            let mut b = batch.clone();
            let v = if origins { &mut b.origins } else { &mut b.dirs };
            v.iter_mut().zip(&delta).for_each(|(x, d)| (0..3).for_each(|a| x[a] += sign * h * d[a]));
            b
        };
        let (lp, lm) = (at(&shifted(1.0), m).loss as f64, at(&shifted(-1.0), m).loss as f64);
        let fd = (lp - lm) / (2.0 * h as f64);
        eprintln!("{}: predicted {predicted}, differences {fd}", if origins { "origins" } else { "directions" });
        // The loss is an f32 sum over ~10⁴ samples whose derivative changes at every hash
        // cell face: the difference converges to the gradient as h falls (0.4 % at 1e-4, 20 %
        // off at 4e-4, where f32 rounding is still far below the signal).
        assert!(predicted.abs() > 1e-4, "the gradient is too small to test: {predicted}");
        assert!((fd - predicted).abs() < 0.03 * predicted.abs(), "{} rays' directional derivative: {predicted} predicted, {fd} by differences", if origins { "origins" } else { "directions" });
        m.set_ray_gradients(RayGradients::Off).unwrap();
    };
    check(&mut m, true);
    let mut flat = m.without_view_dependence().unwrap();
    for step in 80..120 {
        flat.train_step(&batch, step, 1);
    }
    check(&mut flat, false);
}

/// The normal term's part of a step's loss is the supervision module's formula evaluated, in
/// f64, with the model's own densities at the six points one finest cell either side of each
/// ray's target surface point; rays without a target add nothing.
#[test]
fn normal_term_loss_is_the_formula_at_the_models_densities() {
    use crate::supervision::{DepthLoss, G_MIN, RaySupervision};
    let bounds = SceneBounds { aabb_min: [-1.0; 3], aabb_max: [1.0; 3], near: 0.5, far: 6.0, source: "test".into() };
    let cfg = FastConfig::new().with_levels(4).with_log2_table_size(12).with_finest_resolution(64).with_grid_resolution(16).with_steps_per_diagonal(64);
    let n = 256;
    let dirs: Vec<[f32; 3]> = fan(n, 0.04, 0.3);
    let mut batch = RayBatch {
        origins: vec![[0.0, 0.0, 3.0]; n],
        target: (0..n).map(|i| if i % 3 == 0 { [0.9, 0.2, 0.1] } else { [0.1, 0.5, 0.8] }).collect(),
        dirs,
        background: vec![[0.0; 3]; n],
        ids: (0..n as u64).collect(),
        mixed: Vec::new(),
        supervision: None,
    };
    let mut m = FastModel::new(cfg, bounds.clone(), 3).unwrap();
    for step in 0..60 {
        m.train_step(&batch, step, 0);
    }
    m.set_ray_gradients(RayGradients::Only).unwrap();
    let plain = m.train_step(&batch, 60, 0);
    // Targets on the plane z = 0.2 with a tilted normal; every fifth ray has none, one leaves the cube.
    let tilt = [0.3f32, -0.2, 0.93];
    let len = tilt.iter().map(|x| x * x).sum::<f32>().sqrt();
    let normal = tilt.map(|x| x / len);
    let depth: Vec<f32> = (0..n).map(|i| if i % 5 == 0 { f32::NAN } else if i == 7 { 10.0 } else { 2.8 / -batch.dirs[i][2] }).collect();
    let weight = 0.8f32;
    batch.supervision = Some(RaySupervision { depth_loss: DepthLoss::Off, depth_weight: 0.0, empty_weight: 0.0, depth: depth.clone(), empty: vec![false; n], normal_weight: weight, normal: vec![normal; n] });
    let with = m.train_step(&batch, 60, 0);
    let hw = 2.0 * bounds.half_extent() / 64.0;
    let (mut want, mut counted) = (0.0f64, 0);
    for i in 0..n {
        let d = depth[i];
        let x: [f32; 3] = std::array::from_fn(|a| batch.origins[i][a] + d * batch.dirs[i][a]);
        if !d.is_finite() || x.iter().any(|v| v.abs() > 1.0 - hw) {
            continue;
        }
        let pts: Vec<[f32; 3]> = (0..6)
            .map(|k| {
                let mut p = x;
                p[k / 2] += if k % 2 == 0 { hw } else { -hw };
                p
            })
            .collect();
        let s: Vec<f64> = m.density(&pts).iter().map(|&v| v as f64).collect();
        let g = [s[0] - s[1], s[2] - s[3], s[4] - s[5]];
        let gl = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        if gl < G_MIN {
            continue;
        }
        counted += 1;
        let cos = -(0..3).map(|a| g[a] / gl * normal[a] as f64).sum::<f64>();
        want += weight as f64 / n as f64 * (1.0 - cos);
    }
    assert!(counted > 100, "only {counted} rays had a density gradient");
    let got = with.loss as f64 - plain.loss as f64;
    assert!(want > 1e-3 && (got - want).abs() < 2e-3 * want + 1e-6, "normal term {got}, formula {want}");
}
