//! `cargo xtask bench nerf`: training throughput of both models on a synthetic 64×64 dataset
//! (written to a temporary folder, so no prior step is needed): rays/s, samples/s, the time of
//! a step split into encoding, MLP (forward + backward; for `fast` with compositing and loss,
//! which run inside its fused sweep), rendering and optimiser, and the MLP's achieved GFLOP/s
//! against this machine's measured burn matmul peak; and the fast model's networks on one
//! batch through the fused kernels ([`nerf::mlp`]) against the same networks through burn
//! (forward, and forward + autodiff backward), measured in the same run. Then the time to
//! render one full-size view (default 800×800, the Blender-synthetic size) from a fast model
//! trained briefly on the same data, and with `--run RUN` from a trained run's checkpoint.

use dataset::{Camera, Intrinsics};
use nerf::models::Model;
use nerf::train::{TrainConfig, Trainer};
use std::path::PathBuf;
use std::time::Instant;

/// Options of `bench nerf`.
#[derive(clap::Args)]
pub struct NerfBenchArgs {
    /// Also time rendering the first test view of this trained run at its dataset's full
    /// resolution (what `render-nerf --downscale 1` and `eval --downscale 1` do per view).
    #[arg(long)]
    pub run: Option<PathBuf>,
    /// Side in pixels of the square view rendered from the benchmark's own fast model.
    #[arg(long, default_value_t = 800, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub view: u32,
    /// Only the render times (skips the training figures, whose paper steps take minutes).
    #[arg(long)]
    pub render_only: bool,
}

/// Training steps of the fast model whose render is timed (past the occupancy grid's
/// warm-up, so empty space is skipped as in a trained run).
const RENDER_MODEL_STEPS: u64 = 300;

/// Timed renders per view; the median is printed.
const RENDER_REPS: usize = 3;

/// Renders every pixel-centre ray of `camera` from `model` `RENDER_REPS` times: the median
/// seconds and the samples evaluated per ray.
fn time_view(model: &Model, camera: &Camera) -> (f64, f64) {
    let n = camera.intrinsics.width as usize * camera.intrinsics.height as usize;
    let mut times = Vec::new();
    let mut per_ray = 0.0;
    for _ in 0..RENDER_REPS {
        let t0 = Instant::now();
        let (o, d) = nerf::data::pixel_rays(camera);
        let out = model.render_rays(&o, &d, [0.0; 3]);
        times.push(t0.elapsed().as_secs_f64());
        per_ray = out.t.len() as f64 / n as f64;
    }
    times.sort_by(f64::total_cmp);
    (times[times.len() / 2], per_ray)
}

/// Prints training throughput figures for both models and full-size render times.
pub fn run(args: NerfBenchArgs) -> anyhow::Result<()> {
    let tmp = tempfile::Builder::new().prefix("nerf-bench-").tempdir()?;
    let dir = tmp.path().to_path_buf();
    let data = dir.join("data");
    eprintln!("writing a synthetic 64x64 dataset (20 train views) to {}", data.display());
    nerf::data::synthetic::write(&data, 64, [20, 2, 2], false)?;
    if args.render_only {
        return render_times(&data, &dir, &args);
    }
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
    render_times(&data, &dir, &args)?;
    Ok(())
}

/// The full-size render figures (see the module docs).
fn render_times(data: &std::path::Path, dir: &std::path::Path, args: &NerfBenchArgs) -> anyhow::Result<()> {
    let mut cfg = TrainConfig::preset("fast", data.to_path_buf()).map_err(anyhow::Error::msg)?;
    cfg.steps = Some(RENDER_MODEL_STEPS);
    cfg.val_max_views = 0;
    let mut t = Trainer::new(cfg, &dir.join("fast-render"), false)?;
    for _ in 0..RENDER_MODEL_STEPS {
        t.step_once();
    }
    let ds = dataset::Dataset::load(data)?;
    let first = ds.test.first().or(ds.train.first()).ok_or_else(|| anyhow::anyhow!("the synthetic dataset has no views"))?;
    let i = first.camera.intrinsics;
    let s = args.view as f64 / i.width as f64;
    let intr = Intrinsics { width: args.view, height: args.view, fl_x: i.fl_x * s, fl_y: i.fl_y * s, cx: i.cx * s, cy: i.cy * s };
    let camera = Camera::new(intr, first.camera.c2w).map_err(anyhow::Error::msg)?;
    let (sec, per_ray) = time_view(&t.model, &camera);
    let rays = (args.view as f64).powi(2);
    println!(
        " view: {v}x{v} from the fast model after {RENDER_MODEL_STEPS} steps: {sec:.2} s (median of {RENDER_REPS}), {:.2} M rays/s, {per_ray:.1} samples evaluated per ray",
        rays / sec / 1e6,
        v = args.view
    );
    if let Some(run) = &args.run {
        let m = nerf::render::RunModel::load(run)?;
        let ds = dataset::Dataset::load(m.dataset_dir())?;
        let f = ds.test.first().or(ds.val.first()).ok_or_else(|| anyhow::anyhow!("{}: the dataset has no test or val view", m.dataset_dir().display()))?;
        let (w, h) = (f.camera.intrinsics.width, f.camera.intrinsics.height);
        let (sec, per_ray) = time_view(&m.model, &f.camera);
        println!(
            " view: {w}x{h} from {} (step {}): {sec:.2} s (median of {RENDER_REPS}), {:.2} M rays/s, {per_ray:.1} samples evaluated per ray",
            run.display(),
            m.train_steps(),
            (w as f64 * h as f64) / sec / 1e6
        );
    }
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
