//! A training run's history and checkpoints under careless use: `--force` removes only what a
//! run wrote, `--resume` refuses a damaged history instead of shortening it and can fall back
//! past a damaged checkpoint, and a run started under `nohup` still stops cleanly on SIGTERM.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

fn xtask() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_xtask"));
    c.stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped());
    c
}

fn run(args: &[&std::ffi::OsStr]) -> Output {
    xtask().args(args).output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn checkpoints(run: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(run.join("checkpoints")) else { return Vec::new() };
    let mut v: Vec<PathBuf> = entries.flatten().map(|e| e.path()).filter(|p| p.extension().is_some_and(|e| e == "ckpt")).collect();
    v.sort();
    v
}

/// Trains the small CLI config to `steps` (a checkpoint every `every`) into `dir/run`.
fn trained_run(dir: &Path, steps: u64, every: u64) -> PathBuf {
    let config = test_support::training::write_cli_config(dir, steps, every);
    let run_dir = dir.join("run");
    let o = run(&["train".as_ref(), "--config".as_ref(), config.as_os_str(), "--out".as_ref(), run_dir.as_os_str()]);
    assert!(o.status.success(), "{}", stderr(&o));
    run_dir
}

fn resume(run_dir: &Path, steps: u64, extra: &[&str]) -> Output {
    let steps = steps.to_string();
    let mut args: Vec<&std::ffi::OsStr> = vec!["train".as_ref(), "--out".as_ref(), run_dir.as_os_str(), "--resume".as_ref(), "--steps".as_ref(), steps.as_ref()];
    args.extend(extra.iter().map(|s| std::ffi::OsStr::new(*s)));
    run(&args)
}

/// `--force` replaces a run file by file: the old checkpoints, metrics and render-nerf views go,
/// the user's own files (beside the run, among its checkpoints, among its renders) stay.
#[test]
fn train_force_removes_only_what_a_run_wrote() {
    let tmp = tempfile::tempdir().unwrap();
    let run_dir = trained_run(tmp.path(), 30, 10);
    let old = checkpoints(&run_dir);
    assert!(!old.is_empty());
    let renders = run_dir.join("renders").join("test");
    std::fs::create_dir_all(&renders).unwrap();
    std::fs::write(renders.join("r_0.png"), b"old view").unwrap();
    let mine = [run_dir.join("notes.txt"), run_dir.join("checkpoints").join("notes.txt"), renders.join("notes.txt")];
    for p in &mine {
        std::fs::write(p, b"mine").unwrap();
    }
    let config = tmp.path().join("train.json");
    let o = run(&["train".as_ref(), "--config".as_ref(), config.as_os_str(), "--out".as_ref(), run_dir.as_os_str(), "--force".as_ref(), "--steps".as_ref(), "5".as_ref()]);
    assert!(o.status.success(), "{}", stderr(&o));
    for p in &mine {
        assert_eq!(std::fs::read(p).unwrap(), b"mine", "{} was removed or changed by --force", p.display());
    }
    assert!(!renders.join("r_0.png").exists(), "the old run's render was kept");
    let now = checkpoints(&run_dir);
    assert!(now.iter().all(|p| !old.contains(p)), "an old checkpoint survived: {now:?} (old {old:?})");
    let lines = std::fs::read_to_string(run_dir.join("metrics.jsonl")).unwrap();
    assert!(lines.lines().all(|l| serde_json::from_str::<serde_json::Value>(l).unwrap()["step"].as_u64().unwrap() <= 5), "{lines}");
}

/// A damaged line inside `metrics.jsonl` makes `--resume` refuse, naming the file and the line,
/// and leaves the history byte for byte as it was (it used to keep only the lines that parsed).
#[test]
fn resume_refuses_a_damaged_history_and_keeps_it() {
    let tmp = tempfile::tempdir().unwrap();
    let run_dir = trained_run(tmp.path(), 40, 20);
    let path = run_dir.join("metrics.jsonl");
    let mut bytes = std::fs::read(&path).unwrap();
    let second = bytes.iter().position(|&b| b == b'\n').unwrap() + 1;
    bytes.insert(second + 1, 0xff); // line 2 is no longer UTF-8
    std::fs::write(&path, &bytes).unwrap();
    let o = resume(&run_dir, 60, &[]);
    let err = stderr(&o);
    assert!(!o.status.success(), "resume accepted a damaged history: {err}");
    assert!(err.contains("metrics.jsonl") && err.contains("line 2"), "{err}");
    assert_eq!(std::fs::read(&path).unwrap(), bytes, "the history was rewritten although the resume was refused");
}

/// A torn last line (a process killed mid-write) is the one damage a resume repairs: the run
/// continues and the history it ends with parses line by line.
#[test]
fn resume_drops_a_torn_last_line() {
    let tmp = tempfile::tempdir().unwrap();
    let run_dir = trained_run(tmp.path(), 40, 20);
    let path = run_dir.join("metrics.jsonl");
    let mut f = std::fs::OpenOptions::new().append(true).open(&path).unwrap();
    std::io::Write::write_all(&mut f, b"{\"step\":41,\"wall_").unwrap();
    drop(f);
    let o = resume(&run_dir, 60, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = std::fs::read_to_string(&path).unwrap();
    let steps: Vec<u64> = text.lines().map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap()["step"].as_u64().unwrap()).collect();
    assert!(steps.windows(2).all(|w| w[0] <= w[1]) && steps.last() == Some(&60), "{steps:?}");
}

/// A damaged latest checkpoint: `--resume` refuses and names the previous good one and
/// `--fallback`; `--resume --fallback` continues from the good one, keeps the damaged file
/// renamed `.damaged`, and ends at the step budget.
#[test]
fn resume_fallback_continues_from_the_newest_good_checkpoint() {
    let tmp = tempfile::tempdir().unwrap();
    let run_dir = trained_run(tmp.path(), 40, 20);
    let ckpts = checkpoints(&run_dir);
    assert!(ckpts.len() >= 2, "{ckpts:?}");
    let (good, latest) = (&ckpts[ckpts.len() - 2], &ckpts[ckpts.len() - 1]);
    let mut bytes = std::fs::read(latest).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x55;
    std::fs::write(latest, &bytes).unwrap();

    let o = resume(&run_dir, 60, &[]);
    let err = stderr(&o);
    assert!(!o.status.success(), "resumed from a damaged checkpoint: {err}");
    assert!(err.contains(&good.file_name().unwrap().to_string_lossy().into_owned()) && err.contains("--fallback"), "{err}");
    assert_eq!(std::fs::read(latest).unwrap(), bytes, "the refused resume touched the damaged checkpoint");

    let o = resume(&run_dir, 60, &["--fallback"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let mut aside = latest.clone().into_os_string();
    aside.push(".damaged");
    assert_eq!(std::fs::read(&aside).unwrap(), bytes, "the damaged checkpoint was not kept aside");
    let (_, s) = nerf::checkpoint::load_latest(&run_dir).unwrap();
    assert_eq!(s.count("trainer.step").unwrap(), 60);
}

/// Under `nohup` (SIGHUP ignored by the parent) a SIGHUP is still ignored, and SIGTERM still
/// stops the run with a checkpoint (the stop handlers used to be all or nothing, so a run
/// started with `nohup` died on SIGTERM without saving).
#[test]
fn train_under_nohup_ignores_sighup_and_stops_cleanly_on_sigterm() {
    let tmp = tempfile::tempdir().unwrap();
    let config = test_support::training::write_cli_config(tmp.path(), 1_000_000, 1_000_000);
    let run_dir = tmp.path().join("run");
    let mut c = Command::new("nohup");
    c.current_dir(tmp.path()).stdin(Stdio::null()).stdout(Stdio::null()).stderr(Stdio::piped());
    c.arg(env!("CARGO_BIN_EXE_xtask")).arg("train").arg("--config").arg(&config).arg("--out").arg(&run_dir);
    let child = c.spawn().unwrap();
    let deadline = Instant::now() + Duration::from_secs(120);
    while std::fs::read_to_string(run_dir.join("metrics.jsonl")).map_or(0, |t| t.lines().count()) < 2 {
        assert!(Instant::now() < deadline, "train wrote no metric lines in two minutes");
        std::thread::sleep(Duration::from_millis(5));
    }
    let signal = |name: &str| assert!(Command::new("kill").arg(format!("-{name}")).arg(child.id().to_string()).status().unwrap().success());
    signal("HUP");
    std::thread::sleep(Duration::from_millis(300));
    assert!(checkpoints(&run_dir).is_empty(), "SIGHUP under nohup stopped the run");
    signal("TERM");
    let out = child.wait_with_output().unwrap();
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(130), "train under nohup stopped by SIGTERM: {err}");
    assert!(err.contains("interrupted"), "{err}");
    assert_eq!(checkpoints(&run_dir).len(), 1);
}
