//! `cargo xtask view RUN`: the live web viewer of a run folder (the `viewer` crate), until
//! Ctrl-C. It only reads the run and its dataset.

use clap::Args;
use std::path::PathBuf;

/// Arguments of `view`.
#[derive(Args)]
pub struct ViewArgs {
    /// The run folder (training may be going on in it, or not have started yet).
    pub run: PathBuf,
    /// Address to listen on; the default serves this machine only.
    #[arg(long, default_value = "127.0.0.1")]
    pub host: String,
    /// Port; 0 picks a free one.
    #[arg(long, default_value_t = 8080)]
    pub port: u16,
    /// Threads that render (default: every core; they run at low priority, so a trainer keeps its speed).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Niceness of the rendering threads, 0 to 19 (19 yields the most to other processes).
    #[arg(long, default_value_t = 19, value_parser = clap::value_parser!(i32).range(0..=19))]
    pub nice: i32,
}

/// Serves the viewer until a stop signal.
pub fn run(args: ViewArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.run.is_dir(), "{}: not a folder (give a run folder: the --out of `train`)", args.run.display());
    anyhow::ensure!(args.threads != Some(0), "--threads 0: at least one thread is needed");
    let mut cfg = viewer::ViewerConfig::new(args.run.clone());
    (cfg.host, cfg.port, cfg.nice) = (args.host, args.port, args.nice);
    if let Some(t) = args.threads {
        cfg.threads = t;
    }
    let v = viewer::Viewer::start(cfg).map_err(|e| match e {
        viewer::ViewerError::Bind { .. } => anyhow::anyhow!("{e} (--port 0 picks a free port)"),
        e => e.into(),
    })?;
    let state = v.app().status();
    println!("viewer of {}: {}", args.run.display(), v.url());
    eprintln!("{} (Ctrl-C stops)", state["message"].as_str().unwrap_or(""));
    // Stopping is how a viewer ends: a signal is a success here, not an interrupted job.
    v.run_until(crate::stop_flag());
    Ok(())
}
