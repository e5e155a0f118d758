//! `cargo xtask`: the project's command line. It parses arguments and calls the crates; it
//! holds no rendering or training logic of its own.

use clap::{Parser, Subcommand};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::OnceLock;

mod bench;
mod camera_path;
mod crosscheck;
mod evaluate;
mod exit;
mod gen_scenes;
mod guard;
mod mesh;
mod path_video;
mod render;
mod score;
mod train;
mod view;

/// mimalloc instead of the system allocator: the burn MLP allocates and frees tensors of
/// megabytes every step, and glibc's malloc hands those pages back to the kernel and faults
/// them in again (on the standard cornell dataset, 100 `fast-small` steps spent 8.8 s in the
/// MLP with glibc's defaults and 4.3 s with its trimming turned off).
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// mimalloc's `mi_option_purge_delay`: index 15 of its `mi_option_e` (v2 and v3; the
/// `libmimalloc-sys` pinned in `Cargo.toml` names no constant for it).
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

/// Memory mimalloc frees is kept for reuse and never purged (handed back to the kernel). The
/// fast model's step buffers (megabytes, freed and allocated again every step) were otherwise
/// purged between steps, and the next touch faulted a 2 MiB transparent huge page back in,
/// zeroed by the kernel: 14 page faults (about 28 MiB zeroed) per training step late in a
/// standard-tabletop run, none with this setting (`perf stat -e page-faults` of `bench nerf
/// --fast-only --resume-run` at 100 and 300 steps). Its speed gain is within this machine's
/// noise (ABBA pairs: +1 % late in training, ±4 % early). The price is that a process's
/// resident memory stays at its peak (600 training steps: 351 → 367 MB). (Resetting instead
/// of decommitting, `purge_decommits = 0`, the setting before this one, had removed the
/// decommit's cost but not these faults.) Called first in `main`, before any other thread
/// exists.
#[allow(unsafe_code)]
fn tune_allocator() {
    // SAFETY: `mi_option_set` only stores the option; it is not thread safe, and no other
    // thread exists yet.
    unsafe { libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, -1) }
}

/// Exact-ground-truth NeRF: render datasets, train radiance fields, evaluate them.
#[derive(Parser)]
#[command(name = "cargo xtask", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a glTF scene into a posed train/val/test dataset with exact depth.
    Render(render::RenderArgs),
    /// Merge shard folders (`render --shard K/N`) into one dataset, byte-identical to an unsharded render.
    Merge(render::MergeArgs),
    /// Regenerate the project's own scenes in `scenes/`.
    GenScenes(gen_scenes::GenScenesArgs),
    /// Train a radiance field on a dataset's train views.
    Train(train::TrainArgs),
    /// Render colour, opacity and depth from a trained run.
    RenderNerf(train::RenderNerfArgs),
    /// A live web viewer of a run: orbit the field, compare with the exact ground truth, watch training.
    View(view::ViewArgs),
    /// Write a camera path (nerfstudio's camera_path.json) around or through a dataset: an orbit, a spiral, or through chosen views.
    CameraPath(camera_path::CameraPathArgs),
    /// Evaluate a run against the dataset's ground truth and write its report.
    Eval(evaluate::EvalArgs),
    /// Extract a mesh (binary PLY) from a trained run's density, and measure it against the scene's triangles.
    Mesh(mesh::MeshArgs),
    /// Score another tool's renders (nerfstudio, instant-ngp, images) against the dataset's ground truth.
    Score(score::ScoreArgs),
    /// Compare several runs: one table and overlaid speed-versus-error curves.
    Compare(evaluate::CompareArgs),
    /// The main job on the built-in default scene: render, train, evaluate, report.
    Demo(evaluate::DemoArgs),
    /// Performance figures (render, nerf, auto).
    Bench(bench::BenchArgs),
    /// Render a scene with Mitsuba 3 and compare with our renderer.
    Crosscheck(crosscheck::CrosscheckArgs),
}

/// The process-wide stop flag, set by Ctrl-C (SIGINT), SIGTERM (how schedulers such as Slurm
/// and Ray Tune stop a job) and SIGHUP (a closed terminal). The handlers are installed on
/// first use, once, so `demo` can render and then train under them. Long commands check the
/// flag between units of work (views, steps), save what they have, and stop so that a re-run
/// resumes. A second signal ends the process at once. A signal the process was started with
/// ignored stays ignored: `nohup` (SIGHUP) and a script's `cmd &` (SIGINT) keep their meaning,
/// and the other two signals are still handled.
pub fn stop_flag() -> &'static AtomicBool {
    static INSTALLED: OnceLock<()> = OnceLock::new();
    INSTALLED.get_or_init(install_stop_handlers);
    &STOP
}

static STOP: AtomicBool = AtomicBool::new(false);

const STOP_MESSAGE: &[u8] = b"\ninterrupt: finishing the current unit of work, then stopping (re-run to resume; a second signal stops at once)\n";

/// The signal handler: only async-signal-safe calls (an atomic swap, `write`, `signal`,
/// `raise`). The first signal sets [`STOP`]; a second restores the default action and raises
/// the signal again, ending the process as if no handler were installed.
extern "C" fn on_stop_signal(sig: libc::c_int) {
    if STOP.swap(true, Ordering::SeqCst) {
        #[allow(unsafe_code)]
        // SAFETY: `signal` and `raise` are async-signal-safe.
        unsafe {
            libc::signal(sig, libc::SIG_DFL);
            libc::raise(sig);
        }
        return;
    }
    #[allow(unsafe_code)]
    // SAFETY: `write` is async-signal-safe; the buffer is a static byte string.
    unsafe {
        libc::write(libc::STDERR_FILENO, STOP_MESSAGE.as_ptr().cast(), STOP_MESSAGE.len());
    }
}

/// Installs [`on_stop_signal`] for SIGINT, SIGTERM and SIGHUP, each unless it is ignored.
#[allow(unsafe_code)]
fn install_stop_handlers() {
    for sig in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
        // SAFETY: `sigaction` with a null new action only reads the current one into `old`, a
        // zeroed plain C struct; with a new action it installs a handler that only makes
        // async-signal-safe calls.
        unsafe {
            let mut old: libc::sigaction = std::mem::zeroed();
            if libc::sigaction(sig, std::ptr::null(), &mut old) != 0 {
                tracing::warn!("cannot read the disposition of signal {sig}; it will stop without saving");
                continue;
            }
            if old.sa_sigaction == libc::SIG_IGN {
                tracing::debug!("signal {sig} is ignored by the parent process; left ignored");
                continue;
            }
            let mut new: libc::sigaction = std::mem::zeroed();
            new.sa_sigaction = on_stop_signal as *const () as libc::sighandler_t;
            new.sa_flags = libc::SA_RESTART;
            libc::sigemptyset(&mut new.sa_mask);
            if libc::sigaction(sig, &new, std::ptr::null_mut()) != 0 {
                tracing::warn!("cannot install the handler of signal {sig}; it will stop without saving");
            }
        }
    }
}

/// Refuses an output-folder option naming something that is not a folder (a regular file, a
/// symlink loop): one sentence naming the option and the path. A missing path is fine (created).
pub fn check_out_folder(option: &str, path: &std::path::Path) -> anyhow::Result<()> {
    match std::fs::metadata(path) {
        Ok(m) if m.is_dir() => Ok(()),
        Ok(_) => anyhow::bail!("{option} {}: a file is there, not a folder; give a folder (it is created if missing)", path.display()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => anyhow::bail!("{option} {}: cannot be used as a folder ({e})", path.display()),
    }
}

/// Takes the lock of the folder `dir` that a command writes (`<dir>/.lock`, see
/// [`dataset::lock`]), creating the folder if missing, for as long as the returned lock lives:
/// a second command writing into the same folder is refused, naming this one's pid.
pub fn lock_folder(dir: &std::path::Path) -> anyhow::Result<dataset::lock::FolderLock> {
    let lock = dataset::lock::FolderLock::acquire(dir)?;
    if !lock.is_held() {
        tracing::warn!("{}: this filesystem has no file locks; nothing stops a second command writing into this folder", dir.display());
    }
    Ok(lock)
}

fn main() -> std::process::ExitCode {
    tune_allocator();
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    tracing_subscriber::fmt().with_env_filter(filter).with_target(false).with_writer(std::io::stderr).init();
    // A malformed command line is bad input like any other: one message naming the option,
    // exit code 1 (clap's own is 2); help and version still print and exit 0. The codes are
    // listed in `exit`.
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            use clap::error::ErrorKind;
            if matches!(e.kind(), ErrorKind::DisplayHelp | ErrorKind::DisplayVersion) {
                e.exit();
            }
            let _ = e.print();
            return std::process::ExitCode::from(exit::REFUSED);
        }
    };
    let result = match cli.command {
        Command::Render(a) => render::run(a).map(|_| ()),
        Command::Merge(a) => render::run_merge(a),
        Command::GenScenes(a) => gen_scenes::run(a),
        Command::Train(a) => train::run(a),
        Command::RenderNerf(a) => train::run_render(a),
        Command::View(a) => view::run(a),
        Command::CameraPath(a) => camera_path::run(a),
        Command::Eval(a) => evaluate::run(a),
        Command::Mesh(a) => mesh::run(a),
        Command::Score(a) => score::run(a),
        Command::Compare(a) => evaluate::run_compare(a),
        Command::Demo(a) => evaluate::run_demo(a),
        Command::Bench(a) => bench::run(a),
        Command::Crosscheck(a) => crosscheck::run(a),
    };
    match result {
        Ok(()) => std::process::ExitCode::from(exit::SUCCESS),
        Err(e) => {
            let code = exit::code_of(&e);
            match code {
                exit::STOPPED => eprintln!("stopped: {}", error_message(&e)),
                _ => eprintln!("error: {}", error_message(&e)),
            }
            std::process::ExitCode::from(code)
        }
    }
}

/// The error and its causes in one line, `outer: inner: …` (anyhow's `{:#}`), less the causes
/// a message already ends with: most of our errors write their source into their own message
/// (`{path}: {source}`), which `{:#}` would print twice.
fn error_message(e: &anyhow::Error) -> String {
    let mut msg = e.to_string();
    for cause in e.chain().skip(1) {
        let c = cause.to_string();
        if !msg.ends_with(&c) {
            msg = format!("{msg}: {c}");
        }
    }
    msg
}

#[cfg(test)]
#[allow(unsafe_code)]
mod allocator_tests {
    /// [`super::MI_OPTION_PURGE_DELAY`] is an enum index read off mimalloc's v2 and v3
    /// headers: a newer major version must be checked again before it is trusted. In a process
    /// that did not change it (tests do not run `main`), the option at that index holds
    /// `purge_delay`'s default (10 in v2, 1000 in v3; its neighbours' are 0 or 1, and 0), or
    /// the number given in `MIMALLOC_PURGE_DELAY`. Only reads: the tests run on several threads, and setting an
    /// option is not thread safe.
    #[test]
    fn the_purge_option_index_is_the_linked_mimallocs() {
        // SAFETY: `mi_version` only returns a constant.
        let version = unsafe { libmimalloc_sys::mi_version() };
        assert!((200..400).contains(&(version / 100)), "mimalloc {version}: check MI_OPTION_PURGE_DELAY against its mimalloc.h");
        let want = match std::env::var("MIMALLOC_PURGE_DELAY") {
            Ok(v) => match v.trim().parse::<std::ffi::c_long>() {
                Ok(n) => n,
                Err(_) => return, // a word mimalloc reads its own way
            },
            Err(_) if version >= 300 => 1000,
            Err(_) => 10,
        };
        // SAFETY: `mi_option_get` only reads the option.
        assert_eq!(unsafe { libmimalloc_sys::mi_option_get(super::MI_OPTION_PURGE_DELAY) }, want);
    }
}
