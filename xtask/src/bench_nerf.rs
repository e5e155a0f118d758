//! `cargo xtask bench nerf`: training throughput of both models on a synthetic 64×64 dataset
//! (written to a temporary folder, so no prior step is needed): rays/s, samples/s, the time of
//! a step split into encoding, MLP (forward + backward; for `fast` with compositing and loss, which run inside its fused sweep), rendering and optimiser, and the MLP's
//! achieved GFLOP/s against this machine's measured burn matmul peak; and the fast model's
//! networks on one batch through the fused kernels ([`nerf::mlp`]) against the same networks
//! through burn (forward, and forward + autodiff backward), measured in the same run.

use nerf::train::{TrainConfig, Trainer};

/// Prints training throughput figures for both models.
pub fn run() -> anyhow::Result<()> {
    let dir = std::env::temp_dir().join(format!("nerf-bench-{}", std::process::id()));
    let data = dir.join("data");
    eprintln!("writing a synthetic 64x64 dataset (20 train views) to {}", data.display());
    nerf::data::synthetic::write(&data, 64, [20, 2, 2], false)?;
    let peak = nerf::backend::matmul_peak_gflops(2048);
    println!("backend {}; burn matmul 2048^3 peak: {peak:.1} GFLOP/s", nerf::backend::backend_name());
    networks_fused_vs_burn(peak);
    for (kind, warmup, steps) in [("fast", 3u64, 20u64), ("paper", 1, 3)] {
        let mut cfg = TrainConfig::preset(kind, data.clone()).map_err(anyhow::Error::msg)?;
        cfg.steps = Some(warmup + steps);
        cfg.val_max_views = 0;
        let run = dir.join(kind);
        let mut t = Trainer::new(cfg, &run, false)?;
        for _ in 0..warmup {
            t.step_once();
        }
        t.timings = Default::default();
        let (wall0, mut samples, mut rays) = (t.wall_s, 0usize, 0usize);
        for _ in 0..steps {
            rays += t.config.rays_for(t.samples_per_ray);
            samples += t.step_once().samples;
        }
        let wall = t.wall_s - wall0;
        let tm = t.timings;
        let rays = rays as f64;
        // Forward multiply-adds ×2 FLOPs, ×3 for forward + backward (two matmuls per layer back).
        let flops = samples as f64 * t.model.macs_per_sample() * 2.0 * 3.0;
        let per = |x: f64| 1e3 * x / steps as f64;
        println!(
            "{kind:>5}: {:.0} rays/step, {:.0} samples/ray | {:.0} rays/s, {:.0} samples/s | step {:.0} ms = encoding {:.0} + MLP fwd+bwd {:.0} + rendering {:.0} + optimizer {:.0} (+ {:.0} other) ms | MLP {:.1} GFLOP/s = {:.0}% of peak | {} parameters",
            rays / steps as f64,
            samples as f64 / rays,
            rays / wall,
            samples as f64 / wall,
            per(wall),
            per(tm.encoding),
            per(tm.mlp),
            per(tm.render),
            per(tm.optimizer),
            per(wall - tm.encoding - tm.mlp - tm.render - tm.optimizer),
            flops / tm.mlp / 1e9,
            100.0 * flops / tm.mlp / 1e9 / peak,
            t.model.parameters(),
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}

/// The fast preset's networks (32 hash features, 16 SH coefficients, 64-wide) on 32768
/// samples: medians of 5 timed runs after a warm-up, fused kernels against burn.
fn networks_fused_vs_burn(peak: f64) {
    use nerf::field::{HashFieldConfig, seeded_init, tensor2, to_vec};
    let (ed, sd, n) = (32usize, 16usize, 32768usize);
    let field = seeded_init(HashFieldConfig::new(ed, sd).init(&nerf::backend::train_device()), 1);
    let mlp = nerf::mlp::HashMlp::from_field(&field).expect("the preset's field shape");
    let value = |k: usize, s: u64| nerf::models::ops::uniform(s, 0, k as u64, 0) * 2.0 - 1.0;
    let enc: Vec<f32> = (0..n * ed).map(|k| value(k, 1)).collect();
    let sh: Vec<f32> = (0..n * sd).map(|k| value(k, 2)).collect();
    let d_raw: Vec<f32> = (0..n).map(|k| 1e-3 * value(k, 3)).collect();
    let d_rgb: Vec<[f32; 3]> = (0..n).map(|k| [1e-3 * value(3 * k, 4), 1e-3 * value(3 * k + 1, 4), 1e-3 * value(3 * k + 2, 4)]).collect();
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
    let fused_fwd = time(&mut || {
        std::hint::black_box(mlp.forward(&enc, &sh));
    });
    // As training runs them: one sweep over groups of samples, forward → loss gradient (here
    // fixed values) → backward, each group in cache.
    let groups: Vec<std::ops::Range<usize>> = (0..n).step_by(nerf::mlp::TILE).map(|s| s..(s + nerf::mlp::TILE).min(n)).collect();
    let fused_step = time(&mut || {
        std::hint::black_box(mlp.train_groups(&enc, &sh, &groups, |g, _, _| nerf::mlp::GroupGrads {
            d_raw: d_raw[groups[g].clone()].to_vec(),
            d_rgb: d_rgb[groups[g].clone()].to_vec(),
            value: (),
        }));
    });
    let burn_pass = |backward: bool| {
        let dev = if backward { nerf::backend::train_device() } else { nerf::backend::inference_device() };
        let field = if backward { field.clone() } else { burn::module::Module::valid(&field) };
        let enc_t = tensor2(enc.clone(), n, ed, &dev);
        let enc_t = if backward { enc_t.require_grad() } else { enc_t };
        let (raw, rgb) = field.forward(enc_t.clone(), tensor2(sh.clone(), n, sd, &dev));
        let (r, c) = (to_vec(raw.clone()), to_vec(rgb.clone()));
        if backward {
            let d_rgb_flat: Vec<f32> = d_rgb.iter().flatten().copied().collect();
            let surrogate = (raw * tensor2(d_raw.clone(), n, 1, &dev)).sum() + (rgb * tensor2(d_rgb_flat, n, 3, &dev)).sum();
            let grads = surrogate.backward();
            let d_enc = enc_t.grad(&grads).map(to_vec);
            std::hint::black_box((d_enc, grads));
        }
        std::hint::black_box((r, c));
    };
    let burn_fwd = time(&mut || burn_pass(false));
    let burn_step = time(&mut || burn_pass(true));
    let macs = (ed * 64 + 64 * 16 + (16 + sd) * 64 + 64 * 64 + 64 * 3) as f64 * n as f64;
    let gf = |flops: f64, s: f64| flops / s / 1e9;
    println!(
        "networks (fast preset, {n} samples; GFLOP/s count 2 FLOPs per multiply-add, 3 passes for forward + backward; peak {peak:.0}): \
         forward: fused {:.1} ms ({:.0} GFLOP/s), burn {:.1} ms ({:.0}) = {:.2}x | forward + backward: fused {:.1} ms ({:.0} GFLOP/s), burn {:.1} ms ({:.0}) = {:.2}x",
        fused_fwd * 1e3,
        gf(2.0 * macs, fused_fwd),
        burn_fwd * 1e3,
        gf(2.0 * macs, burn_fwd),
        burn_fwd / fused_fwd,
        fused_step * 1e3,
        gf(6.0 * macs, fused_step),
        burn_step * 1e3,
        gf(6.0 * macs, burn_step),
        burn_step / fused_step,
    );
}
