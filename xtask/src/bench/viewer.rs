//! `bench viewer`: the live viewer's two figures. (1) The time to answer a 256×256 colour
//! preview of a trained run (`GET /api/render`, rendering and PNG encoding, as the page asks
//! while the camera moves): the median of 20 after a warm-up, as the server reports it and as
//! the client sees it. (2) What a viewer rendering without pause costs a trainer on the same
//! machine: `xtask train` (a separate process, the run's dataset, the fast model, `--time`)
//! alone and with a client asking the viewer for preview after preview, in the order alone,
//! viewer, viewer, alone; steps per second from each run's `metrics.jsonl` (training clock).

use anyhow::Context;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// Arguments of `bench viewer`.
#[derive(clap::Args)]
pub struct ViewerBenchArgs {
    /// A trained run: its previews are timed, and its dataset trains the measured trainer.
    #[arg(long)]
    pub run: PathBuf,
    /// Training time of each of the four trainer runs (`train --time`).
    #[arg(long, default_value = "20s")]
    pub time: String,
    /// Only the preview times (no trainer runs).
    #[arg(long)]
    pub preview_only: bool,
    /// Niceness of the viewer's threads (as `view --nice`); 0 times previews on a busy machine
    /// as if it were idle.
    #[arg(long, default_value_t = 19, value_parser = clap::value_parser!(i32).range(0..=19))]
    pub nice: i32,
    /// Use the release build (the default re-runs a dev build's command line there).
    #[arg(long, hide = true)]
    pub no_release: bool,
}

/// One GET; returns the status, the server's `X-Render-Ms` and the body's length.
fn get(addr: SocketAddr, target: &str) -> anyhow::Result<(u16, Option<f64>, usize)> {
    let mut s = TcpStream::connect(addr)?;
    write!(s, "GET {target} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n")?;
    let mut raw = Vec::new();
    s.read_to_end(&mut raw)?;
    let text = String::from_utf8_lossy(&raw);
    let status = text.split(' ').nth(1).and_then(|c| c.parse().ok()).context("no HTTP status")?;
    let ms = text.lines().find_map(|l| l.strip_prefix("X-Render-Ms: ").or_else(|| l.strip_prefix("x-render-ms: "))).and_then(|v| v.trim().parse().ok());
    Ok((status, ms, raw.len()))
}

/// A 256×256 preview target on a circle around the scene's centre, at angle `a`.
fn preview(center: [f32; 3], radius: f32, a: f64) -> String {
    let c = glam::DVec3::from(center.map(f64::from));
    let eye = c + glam::DVec3::new(a.cos(), 0.5, a.sin()) * 1.6 * f64::from(radius);
    let m = dataset::matrix_to_row_major(&dataset::Camera::look_at(eye, c, glam::DVec3::Y));
    let m: Vec<String> = m.iter().map(|v| v.to_string()).collect();
    format!("/api/render?w=256&h=256&fov=45&mode=rgb&c2w={}", m.join(","))
}

/// CPU seconds this process has used (user and system, every thread).
#[allow(unsafe_code)]
fn cpu_seconds() -> f64 {
    // SAFETY: `getrusage` fills the zeroed plain C struct it is given.
    let u = unsafe {
        let mut u: libc::rusage = std::mem::zeroed();
        libc::getrusage(libc::RUSAGE_SELF, &mut u);
        u
    };
    let t = |v: libc::timeval| v.tv_sec as f64 + v.tv_usec as f64 * 1e-6;
    t(u.ru_utime) + t(u.ru_stime)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Steps per second of a finished run: its last training line's step over its training clock.
fn steps_per_s(run: &Path) -> anyhow::Result<f64> {
    let recs = eval::curve::read_metrics_jsonl(&run.join("metrics.jsonl"))?;
    let last = recs.iter().rev().find(|r| r.loss.is_some()).context("no training line in metrics.jsonl")?;
    Ok(last.step as f64 / last.wall_s)
}

fn train(dataset: &Path, out: &Path, time: &str) -> anyhow::Result<f64> {
    let exe = std::env::current_exe()?;
    let status = std::process::Command::new(exe)
        .args(["train", "--model", "fast", "--seed", "0", "--time", time, "--out"])
        .arg(out)
        .arg(dataset)
        .stderr(std::process::Stdio::null())
        .status()?;
    anyhow::ensure!(status.success(), "the measured `train` failed ({status})");
    steps_per_s(out)
}

/// Runs the benchmark (in the build it was started from).
pub fn run(a: &ViewerBenchArgs) -> anyhow::Result<()> {
    let mut cfg = viewer::ViewerConfig::new(a.run.clone());
    (cfg.port, cfg.nice) = (0, a.nice);
    let threads = cfg.threads;
    let v = viewer::Viewer::start(cfg)?;
    let loaded = v.app().watch.current().with_context(|| format!("{}: no checkpoint loads", a.run.display()))?;
    let bounds = loaded.config.bounds.clone().context("the run has no bounds")?;
    let (center, radius) = (bounds.center(), bounds.half_extent() * 3f32.sqrt());
    let (mut server, mut client) = (Vec::new(), Vec::new());
    let mut cpu0 = 0.0;
    for k in 0..21 {
        if k == 1 {
            cpu0 = cpu_seconds();
        }
        let t0 = std::time::Instant::now();
        let (status, ms, _) = get(v.addr(), &preview(center, radius, k as f64 * 0.1))?;
        anyhow::ensure!(status == 200, "preview request answered {status}");
        if k > 0 {
            server.push(ms.unwrap_or(f64::NAN));
            client.push(t0.elapsed().as_secs_f64() * 1e3);
        }
    }
    let cpu_ms = (cpu_seconds() - cpu0) * 1e3 / 20.0;
    println!(
        "256x256 preview of {} (step {}), {threads} viewer threads at nice {}: median {:.1} ms rendering and encoding, {:.1} ms answered (20 requests); {cpu_ms:.0} ms of CPU each, {:.0} ms on {threads} idle cores if it all ran in parallel",
        a.run.display(),
        loaded.key.step,
        a.nice,
        median(server),
        median(client),
        cpu_ms / threads as f64
    );
    if a.preview_only {
        return Ok(());
    }
    let dataset = loaded.config.dataset.clone();
    let tmp = tempfile::tempdir()?;
    let (mut alone, mut viewed) = (Vec::new(), Vec::new());
    for (k, with_viewer) in [false, true, true, false].into_iter().enumerate() {
        let out: PathBuf = tmp.path().join(format!("run-{k}"));
        let stop = Arc::new(AtomicBool::new(false));
        let frames = Arc::new(AtomicU64::new(0));
        let hammer = with_viewer.then(|| {
            let (stop, frames, addr) = (stop.clone(), frames.clone(), v.addr());
            std::thread::spawn(move || {
                let mut a = 0.0;
                while !stop.load(Ordering::SeqCst) {
                    if get(addr, &preview(center, radius, a)).is_ok_and(|r| r.0 == 200) {
                        frames.fetch_add(1, Ordering::SeqCst);
                    }
                    a += 0.05;
                }
            })
        });
        let t0 = std::time::Instant::now();
        let sps = train(&dataset, &out, &a.time);
        stop.store(true, Ordering::SeqCst);
        if let Some(h) = hammer {
            let _ = h.join();
        }
        let sps = sps?;
        let fps = frames.load(Ordering::SeqCst) as f64 / t0.elapsed().as_secs_f64();
        println!("trainer {}: {sps:.2} steps/s{}", if with_viewer { "with the viewer rendering" } else { "alone" }, if with_viewer { format!(" (viewer: {fps:.2} previews/s)") } else { String::new() });
        if with_viewer { viewed.push(sps) } else { alone.push(sps) }
    }
    let (a0, a1) = (alone.iter().sum::<f64>() / 2.0, viewed.iter().sum::<f64>() / 2.0);
    println!("trainer steps/s: alone {a0:.2}, with a viewer rendering continuously {a1:.2}: {:+.1} %", 100.0 * (a1 / a0 - 1.0));
    Ok(())
}
