//! `cargo xtask bench nerf`: training throughput of both models on a synthetic 64×64 dataset
//! (written to a temporary folder, so no prior step is needed): rays/s, samples/s, the time of
//! a step split into encoding, MLP (forward + backward; for `fast` with compositing and loss,
//! which run inside its fused sweep), rendering and optimiser, and the MLP's achieved GFLOP/s
//! against this machine's measured burn matmul peak; and the fast model's networks on one
//! batch through the fused kernels ([`nerf::mlp`]) against the same networks through burn
//! (forward, and forward + autodiff backward), measured in the same run.

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

/// The fast preset's networks through the fused kernels and through burn
/// ([`nerf::mlp::speed_against_burn`]).
fn networks_fused_vs_burn(peak: f64) {
    let s = nerf::mlp::speed_against_burn(32, 16, 32768);
    let gf = |flops: f64, secs: f64| flops / secs / 1e9;
    println!(
        "networks (fast preset, {} samples; medians of 5; GFLOP/s count 2 FLOPs per multiply-add, 3 passes for forward + backward; peak {peak:.0}): \
         forward: fused {:.1} ms ({:.0} GFLOP/s), burn {:.1} ms ({:.0}) = {:.2}x | forward + backward: fused {:.1} ms ({:.0} GFLOP/s), burn {:.1} ms ({:.0}) = {:.2}x",
        s.samples,
        s.fused_forward_s * 1e3,
        gf(2.0 * s.macs, s.fused_forward_s),
        s.burn_forward_s * 1e3,
        gf(2.0 * s.macs, s.burn_forward_s),
        s.burn_forward_s / s.fused_forward_s,
        s.fused_train_s * 1e3,
        gf(6.0 * s.macs, s.fused_train_s),
        s.burn_train_s * 1e3,
        gf(6.0 * s.macs, s.burn_train_s),
        s.burn_train_s / s.fused_train_s,
    );
}
