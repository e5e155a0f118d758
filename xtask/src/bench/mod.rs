//! `cargo xtask bench`: performance figures, one benchmark per file. `render`, `scaling` and
//! `nerf` measure in the release profile (a dev build re-runs itself there); `auto`,
//! `auto-diff`, `supervision` and `poses` measure quality at equal time. `cpu` names the machine and build a figure came
//! from; `figures` holds the spread of repeated figures and the printed report beside the JSON.

mod auto;
mod auto_diff;
mod cpu;
mod figures;
mod mitsuba;
mod nerf;
mod poses;
mod render;
mod scaling;
mod supervision;
mod viewer;

use anyhow::Context;
use std::path::PathBuf;

/// Arguments of `bench`.
#[derive(clap::Args)]
pub struct BenchArgs {
    /// What to measure.
    #[command(subcommand)]
    pub what: BenchWhat,
}

/// Benchmarks, each with its own options.
#[derive(clap::Subcommand)]
pub enum BenchWhat {
    /// Path tracer (release profile): BVH build, primary and shadow rays, path samples per scene, and Mitsuba 3 side by side.
    Render(render::RenderBenchArgs),
    /// Path tracer (release profile): samples/s, BVH build time and memory against the triangle count (generated stress scenes).
    Scaling(scaling::ScalingBenchArgs),
    /// NeRF training (release profile): throughput of both models, the fast model's roofline, and the time to render a full-size view from a fast model.
    Nerf(nerf::NerfBenchArgs),
    /// `--model auto` against fixed fast sizes and paper on every scene (train, eval, compare).
    Auto(auto::AutoBenchArgs),
    /// Quality at equal time before and after a change: two `bench auto` output folders (two builds, the same runs) compared figure by figure against the seeds' noise.
    AutoDiff(auto_diff::AutoDiffArgs),
    /// Depth and empty-space supervision against colour only, at equal time on every scene (train, eval with the mesh, tables of means ± 2 SE over seeds).
    Supervision(supervision::SupervisionBenchArgs),
    /// Noisy training poses with and without camera refinement, at equal time (pose error against the exact poses, test PSNR, depth, mesh; means ± 2 SE over seeds; a plot against the noise level).
    Poses(poses::PosesBenchArgs),
    /// The live viewer (release profile): a 256x256 preview's time, and a trainer's steps/s alone and with a viewer rendering continuously.
    Viewer(viewer::ViewerBenchArgs),
}

/// Runs a benchmark.
pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    check_outputs(&args.what)?;
    match args.what {
        BenchWhat::Render(a) => {
            if a.no_release || !rerun_in_release()? {
                render::bench_render(&a)?;
            }
            Ok(())
        }
        BenchWhat::Scaling(a) => {
            if a.no_release || !rerun_in_release()? {
                scaling::bench_scaling(&a)?;
            }
            Ok(())
        }
        BenchWhat::Nerf(a) => {
            if a.no_release || !rerun_in_release()? {
                nerf::run(a)?;
            }
            Ok(())
        }
        BenchWhat::Auto(a) => auto::run(a),
        BenchWhat::AutoDiff(a) => auto_diff::run(a),
        BenchWhat::Supervision(a) => supervision::run(a),
        BenchWhat::Poses(a) => poses::run(a),
        BenchWhat::Viewer(a) => {
            if a.no_release || !rerun_in_release()? {
                viewer::run(&a)?;
            }
            Ok(())
        }
    }
}

/// Refuses an output of a benchmark inside a dataset folder or over a run's records
/// ([`crate::guard`]), before anything is measured.
fn check_outputs(what: &BenchWhat) -> anyhow::Result<()> {
    let folder = |out: &std::path::Path| crate::guard::check_output_folder("--out", out, false);
    match what {
        BenchWhat::Render(a) => folder(&figures::out_dir(&a.out)),
        BenchWhat::Scaling(a) => folder(&figures::out_dir(&a.out)),
        BenchWhat::Nerf(a) => folder(&a.out),
        BenchWhat::Auto(a) => folder(&a.out),
        BenchWhat::Supervision(a) => folder(&a.out),
        BenchWhat::Poses(a) => folder(&a.out),
        BenchWhat::Viewer(_) => Ok(()),
        BenchWhat::AutoDiff(a) => {
            let path = auto_diff::report_path(a);
            crate::guard::check_output_files("--out", &path, std::slice::from_ref(&path), &[])
        }
    }
}

/// In a dev build, builds the workspace in the release profile (`cargo build --release
/// --workspace --locked` from the repository root: the same features as every other build, so
/// nothing is rebuilt twice) and runs this same command line with the release `xtask`, returning
/// `true` once it succeeded; in a release build returns `false` at once (the caller measures).
/// Path tracing is measured in release: the dev profile keeps overflow checks and debug
/// assertions and compiles our crates incrementally.
fn rerun_in_release() -> anyhow::Result<bool> {
    if !cfg!(debug_assertions) {
        return Ok(false);
    }
    let root = crate::render::repo_root();
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    eprintln!("bench: this xtask is a dev build; building the release profile (cargo build --release --workspace; the first build takes minutes)");
    let status = std::process::Command::new(&cargo)
        .current_dir(&root)
        .args(["build", "--release", "--workspace", "--locked"])
        .status()
        .context("running cargo build --release")?;
    anyhow::ensure!(status.success(), "cargo build --release failed ({status})");
    let target = std::env::var_os("CARGO_TARGET_DIR").map(PathBuf::from).unwrap_or_else(|| root.join("target"));
    let exe = target.join("release").join(format!("xtask{}", std::env::consts::EXE_SUFFIX));
    let status = std::process::Command::new(&exe)
        .current_dir(&root)
        .args(std::env::args_os().skip(1))
        .status()
        .with_context(|| format!("running {}", exe.display()))?;
    anyhow::ensure!(status.success(), "the release run of the benchmark failed ({status})");
    Ok(true)
}
