//! One writer per folder: every command that writes a dataset, shard or run folder holds its
//! lock (`<folder>/.lock`) for its whole life. A second writer is refused at once with one
//! sentence naming the first one's pid, touches nothing, and the first finishes as if alone; a
//! finished command leaves no lock file.

use dataset::lock::{FolderLock, LOCK_FILE};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

fn xtask() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_xtask"));
    c.stdin(Stdio::null()).stdout(Stdio::null()).stderr(Stdio::null());
    c
}

/// Runs `xtask ARGS` to completion and returns its output.
fn run(args: &[&std::ffi::OsStr]) -> Output {
    let mut c = xtask();
    c.stdout(Stdio::piped()).stderr(Stdio::piped()).args(args);
    c.output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn scene() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell.gltf")
}

/// `render cornell --out OUT` at a size that takes a second or two on one thread (long enough
/// for a second writer to start while it runs), plus `extra`.
fn render_args(out: &Path, extra: &[&str]) -> Vec<std::ffi::OsString> {
    let mut v: Vec<std::ffi::OsString> = vec!["render".into(), scene().into(), "--out".into(), out.into()];
    v.extend(["--res", "32", "--train", "8", "--val", "1", "--test", "1", "--spp", "16", "--threads", "1"].map(Into::into));
    v.extend(extra.iter().map(Into::into));
    v
}

fn os(v: &[std::ffi::OsString]) -> Vec<&std::ffi::OsStr> {
    v.iter().map(|s| s.as_os_str()).collect()
}

/// A first writer, started in the background; killed if the test fails while it runs.
struct First(Child);

impl First {
    /// Starts `xtask ARGS`, its standard error into `log`.
    fn start(args: &[&std::ffi::OsStr], log: &Path) -> Self {
        Self(xtask().stderr(std::fs::File::create(log).unwrap()).args(args).spawn().unwrap())
    }
}

impl Drop for First {
    fn drop(&mut self) {
        if self.0.try_wait().unwrap().is_none() {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

/// Waits until the process `child` holds the lock of `dir`: its pid is in the lock file.
fn wait_for_lock(child: &mut Child, dir: &Path) {
    let deadline = Instant::now() + Duration::from_secs(60);
    let pid = child.id().to_string();
    while std::fs::read_to_string(dir.join(LOCK_FILE)).map_or(true, |t| t.trim() != pid) {
        assert!(child.try_wait().unwrap().is_none(), "the first writer ended before it was seen holding {}", dir.display());
        assert!(Instant::now() < deadline, "{} was never locked by pid {pid}", dir.display());
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// `o` is a refusal naming the holder `pid` of the folder's lock.
fn assert_refused_by(o: &Output, pid: u32, what: &str) {
    let err = stderr(o);
    assert!(!o.status.success(), "{what}: a second writer succeeded: {err}");
    assert!(err.contains(&format!("another xtask process (pid {pid}) is writing this folder")), "{what}: {err}");
    assert_eq!(err.trim().lines().count(), 1, "{what}: one sentence, not {err}");
}

/// Two `train`s into one run folder: the second (with `--force`, which would replace the run) is
/// refused naming the first, which goes on and stops cleanly with a whole run.
#[test]
fn a_second_train_into_a_running_run_is_refused_and_the_first_run_stays_whole() {
    let tmp = tempfile::tempdir().unwrap();
    let config = test_support::training::write_cli_config(tmp.path(), 1_000_000, 1_000_000);
    let run_dir = tmp.path().join("run");
    let log = tmp.path().join("first.log");
    let mut first = First::start(&["train".as_ref(), "--config".as_ref(), config.as_os_str(), "--out".as_ref(), run_dir.as_os_str()], &log);
    wait_for_lock(&mut first.0, &run_dir);
    let second = run(&["train".as_ref(), "--config".as_ref(), config.as_os_str(), "--out".as_ref(), run_dir.as_os_str(), "--force".as_ref(), "--steps".as_ref(), "5".as_ref()]);
    assert_refused_by(&second, first.0.id(), "train --force into a running run");
    let deadline = Instant::now() + Duration::from_secs(120);
    while std::fs::read_to_string(run_dir.join("metrics.jsonl")).map_or(0, |t| t.lines().count()) < 2 {
        assert!(Instant::now() < deadline, "train wrote no metric lines in two minutes");
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(Command::new("kill").arg("-TERM").arg(first.0.id().to_string()).status().unwrap().success());
    // 130: stopped by the signal with its checkpoint written.
    assert_eq!(first.0.wait().unwrap().code(), Some(130), "the first train: {}", std::fs::read_to_string(&log).unwrap());
    let steps: Vec<u64> = std::fs::read_to_string(run_dir.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap()["step"].as_u64())
        .collect();
    assert!(steps.len() >= 2 && steps.windows(2).all(|w| w[0] < w[1]), "one run's metrics, in order: {steps:?}");
    let (step, ckpt) = nerf::checkpoint::latest_with_step(&run_dir).expect("no checkpoint");
    nerf::checkpoint::load(&ckpt).unwrap();
    assert!(step >= *steps.last().unwrap(), "the checkpoint (step {step}) is the run's last");
    assert!(!run_dir.join(LOCK_FILE).exists(), "the finished train left its lock file");
}

/// `render --force` racing a render into the same folder is refused, and the first render's
/// dataset is byte for byte the one it writes alone.
#[test]
fn a_second_render_into_a_rendering_folder_is_refused_and_the_dataset_is_the_first_ones() {
    let tmp = tempfile::tempdir().unwrap();
    let (alone, raced) = (tmp.path().join("alone"), tmp.path().join("raced"));
    let o = run(&os(&render_args(&alone, &[])));
    assert!(o.status.success(), "{}", stderr(&o));
    let log = tmp.path().join("first.log");
    let mut first = First::start(&os(&render_args(&raced, &[])), &log);
    wait_for_lock(&mut first.0, &raced);
    let second = run(&os(&render_args(&raced, &["--force", "--seed", "3"])));
    assert_refused_by(&second, first.0.id(), "render --force into a folder being rendered");
    assert!(first.0.try_wait().unwrap().is_none(), "the first render had finished: make it longer, or the test proves nothing");
    assert!(first.0.wait().unwrap().success(), "the first render: {}", std::fs::read_to_string(&log).unwrap());
    assert!(test_support::files(&raced) == test_support::files(&alone), "the raced dataset differs from the one rendered alone");
    assert!(!raced.join(LOCK_FILE).exists(), "the finished render left its lock file");
}

/// Every writing command refuses a folder whose lock another process holds (here: this test),
/// before it changes anything there: render (a dataset or a shard), merge, train, eval, mesh
/// and render-nerf.
#[test]
fn every_writer_refuses_a_locked_folder_and_changes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let me = std::process::id();
    let config = test_support::training::write_cli_config(tmp.path(), 10, 10);
    let run_dir = tmp.path().join("run");
    let o = run(&["train".as_ref(), "--config".as_ref(), config.as_os_str(), "--out".as_ref(), run_dir.as_os_str()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (dataset_dir, shard, merged) = (tmp.path().join("dataset"), tmp.path().join("shard"), tmp.path().join("merged"));
    let renders = run_dir.join("renders").join("test");
    let mesh = run_dir.join("mesh.ply");
    let cases: Vec<(&str, &Path, Vec<std::ffi::OsString>)> = vec![
        ("render", &dataset_dir, render_args(&dataset_dir, &[])),
        ("render --shard", &shard, render_args(&shard, &["--shard", "0/2"])),
        ("merge", &merged, vec!["merge".into(), shard.clone().into(), "--out".into(), merged.clone().into()]),
        ("train --force", &run_dir, vec!["train".into(), "--config".into(), config.clone().into(), "--out".into(), run_dir.clone().into(), "--force".into()]),
        ("train --resume", &run_dir, vec!["train".into(), "--out".into(), run_dir.clone().into(), "--resume".into(), "--steps".into(), "20".into()]),
        ("eval", &run_dir, vec!["eval".into(), run_dir.clone().into(), "--no-mesh".into()]),
        ("mesh", &run_dir, vec!["mesh".into(), run_dir.clone().into(), "--out".into(), mesh.clone().into(), "--resolution".into(), "8".into()]),
        ("render-nerf", &renders, vec!["render-nerf".into(), run_dir.clone().into()]),
    ];
    for (what, dir, args) in cases {
        let lock = FolderLock::acquire(dir).unwrap();
        let before = test_support::files(tmp.path());
        let o = run(&os(&args));
        assert_refused_by(&o, me, what);
        assert!(stderr(&o).contains(&dir.display().to_string()), "{what}: the folder is named: {}", stderr(&o));
        assert!(test_support::files(tmp.path()) == before, "{what}: changed files although refused");
        drop(lock);
    }
    assert!(!renders.exists() && !dataset_dir.exists(), "the folders the test's locks created are gone with them");
}

/// A sharded render merged through the command line is byte for byte the unsharded render, and
/// neither the shards, the merge (into a new folder or an empty one) nor the render leave a lock
/// file.
#[test]
fn shards_merged_into_a_new_or_empty_folder_are_the_unsharded_render_without_lock_files() {
    let tmp = tempfile::tempdir().unwrap();
    let small = ["--res", "8", "--train", "3", "--val", "1", "--test", "1", "--spp", "2"];
    let render = |out: &Path, extra: &[&str]| {
        let mut args: Vec<std::ffi::OsString> = vec!["render".into(), scene().into(), "--out".into(), out.into()];
        args.extend(small.iter().chain(extra).map(Into::into));
        let o = run(&os(&args));
        assert!(o.status.success(), "{}", stderr(&o));
    };
    let whole = tmp.path().join("whole");
    render(&whole, &[]);
    let shards: Vec<PathBuf> = (0..2).map(|k| tmp.path().join(format!("shard{k}"))).collect();
    for (k, s) in shards.iter().enumerate() {
        render(s, &["--shard", &format!("{k}/2")]);
        assert!(!s.join(LOCK_FILE).exists(), "shard {k} left its lock file");
    }
    let empty = tmp.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    for out in [tmp.path().join("new"), empty] {
        let o = run(&["merge".as_ref(), shards[0].as_os_str(), shards[1].as_os_str(), "--out".as_ref(), out.as_os_str()]);
        assert!(o.status.success(), "merge into {}: {}", out.display(), stderr(&o));
        assert!(test_support::files(&out) == test_support::files(&whole), "the merge into {} differs from the unsharded render", out.display());
    }
    let names: Vec<String> = std::fs::read_dir(tmp.path()).unwrap().flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect();
    assert!(names.iter().all(|n| !n.starts_with('.')), "the merges left temporaries: {names:?}");
}
