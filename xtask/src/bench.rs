//! `cargo xtask bench render|nerf`: performance figures, printed.

/// Arguments of `bench`.
#[derive(clap::Args)]
pub struct BenchArgs {
    /// What to measure.
    #[arg(value_enum)]
    pub what: BenchWhat,
}

/// Benchmarks.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum BenchWhat {
    /// Path tracer: BVH build, primary rays, path samples per scene.
    Render,
    /// NeRF training throughput for both models.
    Nerf,
}

/// Runs a benchmark.
pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    match args.what {
        BenchWhat::Render => anyhow::bail!("bench render is not implemented yet"),
        BenchWhat::Nerf => crate::bench_nerf::run(),
    }
}
