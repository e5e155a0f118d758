//! `cargo xtask bench nerf`: training throughput of both models on a synthetic 64×64 dataset
//! (written to a temporary folder, so no prior step is needed; `--dataset DS` trains on a
//! dataset folder instead), in the release profile (a dev xtask rebuilds and re-runs itself):
//! the machine's limits measured in the same run (fp32 matmul peak through `gemm`, burn's
//! matmul for comparison, stream-triad memory bandwidth, and random accesses to a table the size
//! of one hash level); rays/s, samples/s and the fast
//! model's roofline (each phase's time per step, its work — FLOPs for the networks, bytes for
//! the hash tables and optimisers, [`nerf::roofline`] — and the fraction of the limit it
//! reaches); the fast model's networks on one batch through the fused kernels ([`nerf::mlp`])
//! against the same networks through burn; then the time to render one full-size view
//! (default 800×800, the Blender-synthetic size) from a fast model trained briefly on the same
//! data, and with `--run RUN` from a trained run's checkpoint. Writes `bench-nerf.json`.
//!
//! Early steps (the default: steps 5 to 5 + `--steps` of a fresh model) march many samples per
//! ray; `--resume-run RUN` times the fast model's steps continued from a trained run's
//! checkpoint instead, the regime that most of a training run's steps are in.

use anyhow::Context;
use dataset::{Camera, Intrinsics};
use nerf::models::{Model, NerfModel};
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
    /// Only the fast model's training figures and roofline (skips the paper model's steps,
    /// which take minutes, and the render times): for comparing builds step for step.
    #[arg(long, conflicts_with = "render_only")]
    pub fast_only: bool,
    /// Train on this dataset folder instead of the benchmark's synthetic 64x64 one.
    #[arg(long, conflicts_with = "resume_run")]
    pub dataset: Option<PathBuf>,
    /// Time the fast model's steps continued from this trained `fast` (or `auto`) run's latest
    /// checkpoint, on its dataset and config, instead of from step 0: the late-training regime,
    /// where the occupancy grid has pruned empty space, rays turn opaque within a few samples
    /// and batches hold thousands of rays. The run itself is not modified (its config and
    /// checkpoint are copied); the paper model is not timed.
    #[arg(long)]
    pub resume_run: Option<PathBuf>,
    /// Timed training steps of the fast model (after 5 warm-up steps, also with --resume-run).
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(1..=100000))]
    pub steps: u64,
    /// Precision of the fast model's network products: fp32 (default) or bf16 (see `train
    /// --mlp-precision`).
    #[arg(long, value_parser = ["fp32", "bf16"])]
    pub mlp_precision: Option<String>,
    /// Folder for `bench-nerf.json`.
    #[arg(long, default_value = "out/bench")]
    pub out: PathBuf,
    /// Measure in the profile this xtask was built with instead of re-running it in release.
    #[arg(long)]
    pub no_release: bool,
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

/// One phase's line of the roofline.
#[derive(serde::Serialize)]
struct PhaseRow {
    phase: &'static str,
    ms_per_step: f64,
    /// "flops", "bytes" or "" (not modelled).
    work_unit: &'static str,
    work_per_step: f64,
    /// GFLOP/s or GB/s achieved.
    rate: f64,
    /// Fraction of the machine's limit for that unit (matmul peak or stream bandwidth).
    fraction_of_limit: f64,
    /// Hash phases: corner lookups per step (8 per sample and level), else 0.
    corners_per_step: f64,
    /// Hash phases: corner lookups per second over the measured random-access rate (reads for
    /// the forward, read-modify-writes for the backward), else NaN.
    fraction_of_random_access: f64,
}

/// The random-access limits of the hash lookups ([`nerf::roofline::random_access_rate`]),
/// measured in the same run over one level's table of the benchmarked model.
#[derive(Clone, Copy, Debug, serde::Serialize)]
struct RandomAccessLimits {
    /// Entries per table (`T`) and floats per entry (`F`).
    entries: usize,
    floats_per_entry: usize,
    /// Random entry reads per second, all threads.
    reads_per_s: f64,
    /// Random entry read-modify-writes per second, all threads.
    rmw_per_s: f64,
}

/// What `bench-nerf.json` holds.
#[derive(serde::Serialize)]
struct NerfBenchJson {
    profile: &'static str,
    /// The machine ([`super::cpu::CpuInfo`]).
    cpu: super::cpu::CpuInfo,
    dataset: String,
    gemm_peak_gflops: f64,
    burn_matmul_gflops: f64,
    stream_bandwidth_gbs: f64,
    random_access: Option<RandomAccessLimits>,
    /// Precision of the fast model's network products (`--mlp-precision`): "fp32" or "bf16".
    mlp_precision: String,
    steps: u64,
    rays_per_s: f64,
    samples_per_s: f64,
    /// The run whose checkpoint the fast model's steps continued (`--resume-run`), and its step.
    resumed_from: Option<(String, u64)>,
    marched_per_ray: f64,
    encoded_per_ray: f64,
    trained_per_ray: f64,
    ms_per_step: f64,
    phases: Vec<PhaseRow>,
    paper: Option<ModelLine>,
}

/// A model's overall throughput.
#[derive(serde::Serialize)]
struct ModelLine {
    rays_per_s: f64,
    samples_per_s: f64,
    ms_per_step: f64,
    mlp_gflops: f64,
}

/// Prints training throughput figures for both models (the fast model as a roofline: each
/// phase's time, work and fraction of this machine's limits, [`nerf::roofline`]) and
/// full-size render times; writes `bench-nerf.json` into `--out`.
pub fn run(args: NerfBenchArgs) -> anyhow::Result<()> {
    println!("profile: {}", super::cpu::build_profile());
    let cpu = super::cpu::CpuInfo::detect();
    println!("cpu: {}", cpu.summary());
    let tmp = tempfile::Builder::new().prefix("nerf-bench-").tempdir()?;
    let dir = tmp.path().to_path_buf();
    // With --resume-run, a copy of the run (config and latest checkpoint) to continue.
    let resumed = match &args.resume_run {
        Some(run) => Some(copy_run_for_resume(run, &dir.join("resumed"))?),
        None => None,
    };
    let data = match (&args.dataset, &resumed) {
        (_, Some((cfg, _))) => cfg.dataset.clone(),
        (Some(d), None) => d.clone(),
        (None, None) => {
            let data = dir.join("data");
            eprintln!("writing a synthetic 64x64 dataset (20 train views) to {}", data.display());
            nerf::data::synthetic::write(&data, 64, [20, 2, 2], false)?;
            data
        }
    };
    if args.render_only {
        return render_times(&data, &dir, &args);
    }
    // The machine's limits, measured in this run.
    let peak = nerf::mlp::gemm_peak_gflops(2048, 3);
    let burn_peak = nerf::backend::matmul_peak_gflops(2048);
    let bw = nerf::roofline::stream_bandwidth_gbs(1 << 25, 5);
    println!(
        "machine: gemm fp32 2048^3 peak {peak:.1} GFLOP/s ({} threads); burn matmul 2048^3 {burn_peak:.1} GFLOP/s (backend {}); stream triad bandwidth {bw:.1} GB/s",
        nerf::roofline::threads(),
        nerf::backend::backend_name()
    );
    networks_fused_vs_burn(peak);
    let mut json = NerfBenchJson {
        profile: super::cpu::build_profile(),
        cpu,
        dataset: data.display().to_string(),
        gemm_peak_gflops: peak,
        burn_matmul_gflops: burn_peak,
        stream_bandwidth_gbs: bw,
        random_access: None,
        mlp_precision: args.mlp_precision.clone().unwrap_or_else(|| "fp32".into()),
        steps: args.steps,
        rays_per_s: 0.0,
        samples_per_s: 0.0,
        resumed_from: None,
        marched_per_ray: 0.0,
        encoded_per_ray: 0.0,
        trained_per_ray: 0.0,
        ms_per_step: 0.0,
        phases: Vec::new(),
        paper: None,
    };
    if json.mlp_precision == "bf16" {
        println!("fast model's networks in bf16 (--mlp-precision bf16): their % of peak is against the fp32 gemm peak, which bf16 products can pass by up to 2x");
    }
    let models: &[(&str, u64, u64)] = if resumed.is_some() || args.fast_only { &[("fast", 5, args.steps)] } else { &[("fast", 5, args.steps), ("paper", 1, 3)] };
    for &(kind, warmup, steps) in models {
        let mut t = match &resumed {
            Some((cfg, step)) => {
                let mut cfg = cfg.clone();
                if let (nerf::models::ModelConfig::Fast(f), Some(p)) = (&mut cfg.model, &args.mlp_precision) {
                    f.mlp_precision = Some(p.clone());
                }
                cfg.steps = Some(step + warmup + steps);
                cfg.time_budget_s = None;
                cfg.val_max_views = 0;
                json.resumed_from = Some((args.resume_run.as_ref().map(|p| p.display().to_string()).unwrap_or_default(), *step));
                println!("fast: continuing {} from its checkpoint at step {step}", args.resume_run.as_ref().map(|p| p.display().to_string()).unwrap_or_default());
                let t = Trainer::new(cfg, &dir.join("resumed"), true)?;
                anyhow::ensure!(
                    t.step == *step,
                    "{}: the latest checkpoint is named for step {step} but holds step {}",
                    args.resume_run.as_ref().map(|p| p.display().to_string()).unwrap_or_default(),
                    t.step
                );
                t
            }
            None => {
                let mut cfg = TrainConfig::preset(kind, data.clone()).map_err(anyhow::Error::msg)?;
                if let (nerf::models::ModelConfig::Fast(f), Some(p)) = (&mut cfg.model, &args.mlp_precision) {
                    f.mlp_precision = Some(p.clone());
                }
                cfg.steps = Some(warmup + steps);
                cfg.val_max_views = 0;
                Trainer::new(cfg, &dir.join(kind), false)?
            }
        };
        for _ in 0..warmup {
            t.step_once();
        }
        t.timings = Default::default();
        let (wall0, mut samples, mut rays) = (t.wall_s, 0usize, 0usize);
        let mut counts = nerf::roofline::StepCounts::default();
        for _ in 0..steps {
            rays += t.config.rays_for(t.samples_per_ray);
            let st = t.step_once();
            samples += st.samples;
            counts.marched += st.marched as f64;
            counts.encoded += st.encoded as f64;
            counts.trained += st.samples as f64;
            counts.touched += st.touched as f64;
        }
        let wall = t.wall_s - wall0;
        let tm = t.timings;
        let rays = rays as f64;
        // Forward multiply-adds ×2 FLOPs, ×3 for forward + backward (two matmuls per layer back).
        let flops = samples as f64 * t.model.macs_per_sample() * 2.0 * 3.0;
        let per = |x: f64| 1e3 * x / steps as f64;
        println!(
            "{kind:>5}: {:.0} rays/step, {:.0} samples/ray | {:.0} rays/s, {:.0} samples/s | step {:.0} ms = encoding {:.0} + MLP fwd+bwd {:.0} + rendering {:.0} + optimizer {:.0} (+ {:.0} other) ms | MLP {:.1} GFLOP/s = {:.0}% of the gemm peak | {} parameters",
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
        match t.model.downcast_ref::<nerf::models::fast::FastModel>() {
            Some(m) => {
                let n = steps as f64;
                let avg = nerf::roofline::StepCounts { marched: counts.marched / n, encoded: counts.encoded / n, trained: counts.trained / n, touched: counts.touched / n };
                let work = nerf::roofline::StepWork::of(&m.config, m.parameters() - m.grid.params.len(), avg);
                // The hash lookups' own limit: random accesses to one level's table.
                let (entries, f) = (1usize << m.config.log2_table_size, m.config.features_per_level);
                let ra = RandomAccessLimits {
                    entries,
                    floats_per_entry: f,
                    reads_per_s: nerf::roofline::random_access_rate(entries, f, 1 << 24, 5, false),
                    rmw_per_s: nerf::roofline::random_access_rate(entries, f, 1 << 24, 5, true),
                };
                json.phases = roofline_rows(&tm, wall / n, steps, &work, peak, bw, &ra);
                print_roofline(&json.phases, avg, rays / n, &ra);
                json.random_access = Some(ra);
                json.rays_per_s = rays / wall;
                json.samples_per_s = samples as f64 / wall;
                json.marched_per_ray = counts.marched / rays;
                json.encoded_per_ray = counts.encoded / rays;
                json.trained_per_ray = counts.trained / rays;
                json.ms_per_step = per(wall);
            }
            None => {
                json.paper = Some(ModelLine { rays_per_s: rays / wall, samples_per_s: samples as f64 / wall, ms_per_step: per(wall), mlp_gflops: flops / tm.mlp / 1e9 });
            }
        }
    }
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let path = args.out.join("bench-nerf.json");
    dataset::io::atomic_write_json(&path, &json)?;
    println!("wrote {}", path.display());
    if !args.fast_only {
        render_times(&data, &dir, &args)?;
    }
    Ok(())
}

/// Copies the config and latest checkpoint of the trained run `run` into `dest`, for
/// [`Trainer::new`] to continue there (so the run is left as it was): the run's config, with
/// its recorded dataset, and the checkpoint's step.
fn copy_run_for_resume(run: &std::path::Path, dest: &std::path::Path) -> anyhow::Result<(TrainConfig, u64)> {
    let cfg = TrainConfig::read(&run.join("config.json"))?;
    anyhow::ensure!(
        matches!(cfg.model, nerf::models::ModelConfig::Fast(_)),
        "{}: --resume-run times the fast model, but this run trained the paper model",
        run.display()
    );
    // The step from the file name: the trainer reads the checkpoint itself, once (it is tens
    // of megabytes), and the bench checks that it resumed at this step.
    let (step, ckpt) = nerf::checkpoint::latest_with_step(run)
        .ok_or_else(|| anyhow::anyhow!("{}: no checkpoint to continue from (train it first, or pass the run folder holding checkpoints/)", run.display()))?;
    let cdir = dest.join("checkpoints");
    std::fs::create_dir_all(&cdir).with_context(|| format!("creating {}", cdir.display()))?;
    std::fs::copy(run.join("config.json"), dest.join("config.json")).with_context(|| format!("copying {}", run.join("config.json").display()))?;
    let name = ckpt.file_name().ok_or_else(|| anyhow::anyhow!("{}: not a file", ckpt.display()))?;
    std::fs::copy(&ckpt, cdir.join(name)).with_context(|| format!("copying {}", ckpt.display()))?;
    Ok((cfg, step))
}

/// The fast model's phases over `steps` steps (`tm` summed over them; `step_s` the mean
/// wall seconds of a step) against `work` (per step) and the machine's limits.
fn roofline_rows(tm: &nerf::models::StepTimings, step_s: f64, steps: u64, work: &nerf::roofline::StepWork, peak: f64, bw: f64, ra: &RandomAccessLimits) -> Vec<PhaseRow> {
    let p = &tm.phases;
    let n = steps as f64;
    let threads = nerf::roofline::threads() as f64;
    // The sweep's compositing runs inside its parallel groups: its share of the sweep's wall
    // time is taken as its CPU time over the threads.
    let composite = (p.composite_cpu / threads).min(p.mlp_sweep);
    let row = |phase, secs: f64, unit: &'static str, work: f64| {
        let s = secs / n;
        let rate = if unit.is_empty() || s <= 0.0 { 0.0 } else { work / s / 1e9 };
        let limit = match unit {
            "flops" => peak,
            "bytes" => bw,
            _ => f64::NAN,
        };
        PhaseRow {
            phase,
            ms_per_step: s * 1e3,
            work_unit: unit,
            work_per_step: work,
            rate,
            fraction_of_limit: if unit.is_empty() { f64::NAN } else { rate / limit },
            corners_per_step: 0.0,
            fraction_of_random_access: f64::NAN,
        }
    };
    // A hash phase's corners per second against the random-access rate.
    let corners = |mut r: PhaseRow, corners: f64, limit: f64| {
        r.corners_per_step = corners;
        let s = r.ms_per_step / 1e3;
        r.fraction_of_random_access = if s > 0.0 && limit > 0.0 { corners / s / limit } else { f64::NAN };
        r
    };
    let mut rows = vec![
        row("ray batch", p.batch, "", 0.0),
        row("marching", p.march, "", 0.0),
        corners(row("hash forward", p.hash_forward, "bytes", work.hash_forward_bytes), work.hash_forward_corners, ra.reads_per_s),
        row("density pass (compaction)", p.density_pass, "flops", work.density_pass_flops),
        row("gather kept samples", p.gather, "", 0.0),
        row("MLP fwd+bwd (sweep less compositing)", p.mlp_sweep - composite, "flops", work.mlp_flops),
        row("compositing + loss (in the sweep)", composite, "", 0.0),
        corners(row("hash backward", p.hash_backward, "bytes", work.hash_backward_bytes), work.hash_backward_corners, ra.rmw_per_s),
        row("Adam networks", p.adam_mlp, "bytes", work.adam_mlp_bytes),
        row("Adam hash (sparse)", p.adam_hash, "bytes", work.adam_hash_bytes),
        row("occupancy update", p.occupancy, "", 0.0),
    ];
    let known: f64 = rows.iter().map(|r| r.ms_per_step).sum::<f64>() / 1e3;
    rows.push(row("other", (step_s - known).max(0.0) * n, "", 0.0));
    rows
}

/// Prints the roofline table.
fn print_roofline(rows: &[PhaseRow], c: nerf::roofline::StepCounts, rays: f64, ra: &RandomAccessLimits) {
    println!(
        " fast roofline per step ({rays:.0} rays, {:.0} samples marched, {:.0} encoded by the compaction pass, {:.0} trained, {:.0} hash entries updated; work model in nerf::roofline):",
        c.marched, c.encoded, c.trained, c.touched
    );
    println!("  {:<38} {:>9} {:>14} {:>12} {:>9}", "phase", "ms/step", "work/step", "rate", "of limit");
    for r in rows {
        let (work, rate, frac) = match r.work_unit {
            "flops" => (format!("{:.2} GFLOP", r.work_per_step / 1e9), format!("{:.1} GFLOP/s", r.rate), format!("{:.1} %", 100.0 * r.fraction_of_limit)),
            "bytes" => (format!("{:.1} MB", r.work_per_step / 1e6), format!("{:.1} GB/s", r.rate), format!("{:.1} %", 100.0 * r.fraction_of_limit)),
            _ => ("-".into(), "-".into(), "-".into()),
        };
        println!("  {:<38} {:>9.2} {:>14} {:>12} {:>9}", r.phase, r.ms_per_step, work, rate, frac);
    }
    println!(
        "  hash lookups against random access (8 corners per sample and level; limit measured in this run: independent random accesses to entries of {} floats in one {:.1} MB table per thread, {:.0} M reads/s, {:.0} M read-modify-writes/s):",
        ra.floats_per_entry,
        (ra.entries * ra.floats_per_entry * 4) as f64 / 1e6,
        ra.reads_per_s / 1e6,
        ra.rmw_per_s / 1e6
    );
    for r in rows.iter().filter(|r| r.corners_per_step > 0.0) {
        println!(
            "  {:<38} {:>9.2} {:>9.2} M corners {:>7.0} M/s {:>7.1} %",
            r.phase,
            r.ms_per_step,
            r.corners_per_step / 1e6,
            r.corners_per_step / (r.ms_per_step / 1e3) / 1e6,
            100.0 * r.fraction_of_random_access
        );
    }
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
