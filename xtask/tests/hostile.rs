//! Hostile and careless input to the command line: signals from a scheduler, inputs that do not
//! exist or do not parse, outputs that name the wrong kind of thing. Each case checks that
//! nothing the user had is lost and that the refusal is one sentence naming what is wrong.

use nerf::train::TrainConfig;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
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

/// A small fast model on the analytic dataset in `dir/data`, stopped by a step count far beyond
/// what a test waits for, checkpointed only when it stops.
fn write_config(dir: &Path) -> PathBuf {
    test_support::training::write_cli_config(dir, 1_000_000, 1_000_000)
}

fn checkpoints(run: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(run.join("checkpoints")) else { return Vec::new() };
    let mut v: Vec<PathBuf> = entries.flatten().map(|e| e.path()).filter(|p| p.extension().is_some_and(|e| e == "ckpt")).collect();
    v.sort();
    v
}

/// SIGTERM (how Ray Tune and cluster drivers stop a trial) stops `train` as Ctrl-C does: the
/// current step finishes, a checkpoint is written, the process exits 130 (stopped, work saved:
/// not a finished run), and `--resume` continues.
#[test]
fn train_stopped_by_sigterm_writes_a_checkpoint_and_exits_cleanly() {
    let tmp = tempfile::tempdir().unwrap();
    let config = write_config(tmp.path());
    let run_dir = tmp.path().join("run");
    let mut c = xtask();
    c.stderr(Stdio::piped()).arg("train").arg("--config").arg(&config).arg("--out").arg(&run_dir);
    let child = c.spawn().unwrap();
    let deadline = Instant::now() + Duration::from_secs(120);
    while std::fs::read_to_string(run_dir.join("metrics.jsonl")).map_or(0, |t| t.lines().count()) < 2 {
        assert!(Instant::now() < deadline, "train wrote no metric lines in two minutes");
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(checkpoints(&run_dir).is_empty(), "a checkpoint before the signal: the test would prove nothing");
    let killed = Command::new("kill").arg("-TERM").arg(child.id().to_string()).status().unwrap();
    assert!(killed.success());
    let out = child.wait_with_output().unwrap();
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(130), "train stopped by SIGTERM exited with {}: {err}", out.status);
    assert!(err.contains("interrupted"), "{err}");
    let ckpts = checkpoints(&run_dir);
    assert_eq!(ckpts.len(), 1, "{ckpts:?}");
    nerf::checkpoint::load(&ckpts[0]).unwrap();
    let step: u64 = ckpts[0].file_stem().unwrap().to_str().unwrap().strip_prefix("step-").unwrap().parse().unwrap();
    let more = (step + 5).to_string();
    let resumed = run(&["train".as_ref(), "--out".as_ref(), run_dir.as_os_str(), "--resume".as_ref(), "--steps".as_ref(), more.as_ref()]);
    assert!(resumed.status.success(), "{}", stderr(&resumed));
}

/// A run folder with a finished-looking run and a file of the user's: config.json (a training
/// run's), metrics.jsonl and `notes.txt`.
fn run_folder(dir: &Path) -> PathBuf {
    let run_dir = dir.join("run");
    std::fs::create_dir_all(&run_dir).unwrap();
    let cfg = TrainConfig::preset("fast", dir.join("data")).unwrap().with_steps(Some(10));
    std::fs::write(run_dir.join("config.json"), serde_json::to_string_pretty(&cfg).unwrap()).unwrap();
    std::fs::write(run_dir.join("metrics.jsonl"), "{\"step\":10}\n").unwrap();
    std::fs::write(run_dir.join("notes.txt"), "mine").unwrap();
    run_dir
}

fn folder_bytes(dir: &Path) -> Vec<(String, Vec<u8>)> {
    test_support::files(dir)
}

/// `train MISSING --out RUN --force` is refused on the dataset before the run in RUN is touched.
#[test]
fn train_force_with_a_missing_dataset_keeps_the_run() {
    let tmp = tempfile::tempdir().unwrap();
    let run_dir = run_folder(tmp.path());
    let before = folder_bytes(&run_dir);
    let missing = tmp.path().join("no-such-dataset");
    let o = run(&["train".as_ref(), missing.as_os_str(), "--out".as_ref(), run_dir.as_os_str(), "--force".as_ref(), "--steps".as_ref(), "5".as_ref()]);
    assert!(!o.status.success(), "train on a missing dataset succeeded");
    assert!(stderr(&o).contains("no-such-dataset"), "{}", stderr(&o));
    assert_eq!(folder_bytes(&run_dir), before, "the run folder changed although the new run was refused");
}

/// `demo --model nonsense` is refused before anything is rendered or removed.
#[test]
fn demo_with_an_unknown_model_touches_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let old = tmp.path().join("run-nonsense");
    std::fs::create_dir_all(&old).unwrap();
    std::fs::write(old.join("notes.txt"), "mine").unwrap();
    let o = run(&["demo".as_ref(), "--model".as_ref(), "nonsense".as_ref(), "--out".as_ref(), tmp.path().as_os_str()]);
    assert!(!o.status.success(), "demo with an unknown model succeeded");
    assert!(stderr(&o).contains("nonsense"), "{}", stderr(&o));
    assert_eq!(std::fs::read_to_string(old.join("notes.txt")).unwrap(), "mine");
    assert!(!tmp.path().join("dataset").exists(), "demo rendered before validating its options");
}

/// `--time` values that parse as floats but are no duration: one message naming `--time`.
#[test]
fn train_time_that_is_not_a_duration_is_refused_naming_the_option() {
    let tmp = tempfile::tempdir().unwrap();
    let config = write_config(tmp.path());
    for bad in ["1e300h", "nan", "inf", "-inf", "infinity", "1e400", "0s", "-5m", "5 parsecs", ""] {
        let run_dir = tmp.path().join("run");
        let o = run(&["train".as_ref(), "--config".as_ref(), config.as_os_str(), "--out".as_ref(), run_dir.as_os_str(), "--time".as_ref(), bad.as_ref()]);
        let err = stderr(&o);
        assert!(!o.status.success(), "--time {bad:?} accepted");
        assert!(err.contains("--time"), "--time {bad:?}: {err}");
        assert!(!err.contains("cannot parse"), "--time {bad:?}: {err}");
        assert!(!run_dir.exists(), "--time {bad:?}: the run folder was created");
    }
}

/// `--out` naming an existing regular file: a sentence naming the option and the path, and the
/// file is left as it was.
#[test]
fn out_naming_a_file_is_refused_naming_the_option_and_path() {
    let tmp = tempfile::tempdir().unwrap();
    let config = write_config(tmp.path());
    let file = tmp.path().join("a-file.txt");
    std::fs::write(&file, "mine").unwrap();
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell.gltf");
    let cases: Vec<Vec<&std::ffi::OsStr>> = vec![
        vec!["train".as_ref(), "--config".as_ref(), config.as_os_str(), "--out".as_ref(), file.as_os_str()],
        vec!["render".as_ref(), scene.as_os_str(), "--out".as_ref(), file.as_os_str(), "--res".as_ref(), "8".as_ref()],
    ];
    for args in cases {
        let o = run(&args);
        let err = stderr(&o);
        assert!(!o.status.success(), "{args:?} succeeded");
        assert!(err.contains("--out") && err.contains(&*file.to_string_lossy()), "{args:?}: {err}");
        assert!(!err.contains("os error 17"), "{args:?}: {err}");
        assert_eq!(std::fs::read_to_string(&file).unwrap(), "mine");
    }
}

/// Runs `xtask ARGS`, expects a refusal whose message holds every string of `want`.
fn assert_refused(args: &[&std::ffi::OsStr], want: &[&str]) {
    let o = run(args);
    let err = stderr(&o);
    assert!(!o.status.success(), "{args:?} succeeded: {err}");
    for w in want {
        assert!(err.contains(w), "{args:?}: the message does not say {w:?}: {err}");
    }
    assert_eq!(err.trim().lines().count(), 1, "{args:?}: not one line: {err}");
}

/// A trained run at `dir/run` on the analytic dataset at `dir/data` (four steps, one checkpoint).
fn trained_run(dir: &Path) -> (PathBuf, PathBuf) {
    let config = test_support::training::write_cli_config(dir, 4, 4);
    let run_dir = dir.join("run");
    let o = run(&["train".as_ref(), "--config".as_ref(), config.as_os_str(), "--out".as_ref(), run_dir.as_os_str()]);
    assert!(o.status.success(), "{}", stderr(&o));
    (run_dir, dir.join("data"))
}

/// No command writes an output over a file of a run (its config through `mesh`'s sidecar, the
/// `<name>.json` beside `--out <name>.ply`) or into a dataset folder (`render-nerf --out
/// DATASET/test` replaced the ground-truth views, which `eval` then scored at 60 dB); each is
/// refused in one sentence naming `--out`, and the run and the dataset keep every byte.
#[test]
fn outputs_over_a_run_or_inside_a_dataset_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let (run_dir, data) = trained_run(tmp.path());
    let (run_before, data_before) = (folder_bytes(&run_dir), folder_bytes(&data));
    let p = |p: PathBuf| p.into_os_string();
    let (r, d) = (run_dir.as_os_str(), data.as_os_str());
    for name in ["config", "eval", "report"] {
        let out = p(run_dir.join(format!("{name}.ply")));
        let json = format!("{name}.json");
        assert_refused(&["mesh".as_ref(), r, "--out".as_ref(), &out, "--resolution".as_ref(), "8".as_ref()], &["--out", &json, "would replace"]);
    }
    let inside = ["inside the dataset folder", "--out"];
    assert_refused(&["mesh".as_ref(), r, "--out".as_ref(), &p(data.join("transforms.ply"))], &inside);
    assert_refused(&["render-nerf".as_ref(), r, "--out".as_ref(), &p(data.join("test"))], &inside);
    assert_refused(&["render-nerf".as_ref(), r, "--out".as_ref(), d], &["is a dataset folder", "--out"]);
    assert_refused(&["train".as_ref(), d, "--out".as_ref(), &p(data.join("run")), "--steps".as_ref(), "2".as_ref()], &inside);
    assert_refused(&["compare".as_ref(), r, "--out".as_ref(), &p(data.join("cmp"))], &inside);
    assert_refused(&["demo".as_ref(), "--out".as_ref(), d], &["is a dataset folder", "--out"]);
    assert_refused(&["crosscheck".as_ref(), "cornell".as_ref(), "--out".as_ref(), &p(data.join("x"))], &inside);
    assert_refused(&["bench".as_ref(), "nerf".as_ref(), "--out".as_ref(), &p(data.join("bench"))], &inside);
    assert_refused(&["bench".as_ref(), "auto-diff".as_ref(), "--before".as_ref(), r, "--after".as_ref(), r, "--out".as_ref(), &p(run_dir.join("report.json"))], &["--out", "report.json", "would replace"]);
    assert_refused(&["merge".as_ref(), d, "--out".as_ref(), &p(data.join("merged"))], &inside);
    let render = |out: &std::ffi::OsStr| run(&["render".as_ref(), "cornell".as_ref(), "--out".as_ref(), out, "--res".as_ref(), "8".as_ref(), "--train".as_ref(), "1".as_ref(), "--val".as_ref(), "1".as_ref(), "--test".as_ref(), "1".as_ref(), "--spp".as_ref(), "1".as_ref()]);
    let o = render(&p(data.join("test/sub")));
    assert!(!o.status.success() && stderr(&o).contains("inside the dataset folder"), "{}", stderr(&o));
    // A run folder kept inside a dataset folder is not written into by eval.
    let nested = data.join("run");
    std::fs::create_dir_all(nested.join("checkpoints")).unwrap();
    for f in test_support::files(&run_dir) {
        std::fs::write(nested.join(&f.0), &f.1).unwrap();
    }
    let nested_before = folder_bytes(&nested);
    assert_refused(&["eval".as_ref(), nested.as_os_str(), "--no-mesh".as_ref()], &["the run folder", "inside the dataset folder"]);
    assert_eq!(folder_bytes(&nested), nested_before);
    std::fs::remove_dir_all(&nested).unwrap();
    assert_eq!(folder_bytes(&run_dir), run_before, "the run changed");
    assert_eq!(folder_bytes(&data), data_before, "the dataset changed");
    // Through `..` and a symlinked folder, the same files are seen.
    let sneaky = run_dir.join("checkpoints/../config.ply");
    assert_refused(&["mesh".as_ref(), r, "--out".as_ref(), sneaky.as_os_str()], &["config.json", "would replace"]);
    #[cfg(unix)]
    {
        let link = tmp.path().join("link");
        std::os::unix::fs::symlink(&data, &link).unwrap();
        assert_refused(&["render-nerf".as_ref(), r, "--out".as_ref(), &p(link.join("test"))], &inside);
    }
    // Where nothing is replaced, the same commands write: render-nerf beside the run, a
    // render's dataset resumed in place.
    let renders = tmp.path().join("renders");
    let o = run(&["render-nerf".as_ref(), r, "--out".as_ref(), renders.as_os_str()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let ds = tmp.path().join("ds");
    for _ in 0..2 {
        let o = render(ds.as_os_str());
        assert!(o.status.success(), "{}", stderr(&o));
    }
}

/// A run's `config.json` with an impossible setting (`downscale: 0`, which `eval` read as 1) is
/// refused by every reader, naming the file and the setting, and nothing is written.
#[test]
fn a_run_config_with_an_impossible_setting_is_refused_by_its_readers() {
    let tmp = tempfile::tempdir().unwrap();
    let (run_dir, _) = trained_run(tmp.path());
    let config = run_dir.join("config.json");
    let mut cfg: serde_json::Value = serde_json::from_slice(&std::fs::read(&config).unwrap()).unwrap();
    cfg["downscale"] = serde_json::json!(0);
    std::fs::write(&config, serde_json::to_string_pretty(&cfg).unwrap()).unwrap();
    let before = folder_bytes(&run_dir);
    let (renders, mesh) = (tmp.path().join("renders"), tmp.path().join("m.ply"));
    let r = run_dir.as_os_str();
    for args in [
        vec!["eval".as_ref(), r, "--split".as_ref(), "train".as_ref(), "--no-mesh".as_ref()],
        vec!["render-nerf".as_ref(), r, "--out".as_ref(), renders.as_os_str()],
        vec!["mesh".as_ref(), r, "--out".as_ref(), mesh.as_os_str(), "--resolution".as_ref(), "8".as_ref()],
    ] {
        assert_refused(&args, &[&*config.to_string_lossy(), "downscale"]);
    }
    assert_eq!(folder_bytes(&run_dir), before);
    assert!(!renders.exists() && !mesh.exists());
}

/// An evaluation leaves only its own report's outputs: the grids of views an earlier one
/// pictured and this one does not, the mesh's picture without a mesh, and temporaries of a
/// killed evaluation go; a mesh this evaluation did not make is kept and the report says so.
#[test]
fn eval_removes_what_an_earlier_evaluation_left() {
    let tmp = tempfile::tempdir().unwrap();
    let (run_dir, _) = trained_run(tmp.path());
    let eval = |grids: &str| {
        let o = run(&["eval".as_ref(), run_dir.as_os_str(), "--split".as_ref(), "train".as_ref(), "--no-mesh".as_ref(), "--grids".as_ref(), grids.as_ref()]);
        assert!(o.status.success(), "{}", stderr(&o));
    };
    eval("3");
    let grids = |d: &Path| {
        let mut g: Vec<String> = std::fs::read_dir(d).unwrap().flatten().map(|e| e.file_name().to_string_lossy().into_owned()).filter(|n| n.starts_with("grid_")).collect();
        g.sort();
        g
    };
    assert_eq!(grids(&run_dir), ["grid_r_0.png", "grid_r_1.png", "grid_r_2.png"]);
    let dead = if Path::new("/proc/self").exists() { 0 } else { 1 };
    let temp = run_dir.join(format!(".eval.json.{dead}.tmp"));
    for f in [run_dir.join("mesh.ply"), run_dir.join("mesh_error.png"), temp.clone(), run_dir.join("notes.txt")] {
        std::fs::write(f, b"earlier").unwrap();
    }
    eval("1");
    assert_eq!(grids(&run_dir), ["grid_r_0.png"]);
    assert!(!run_dir.join("mesh_error.png").exists() && !temp.exists());
    assert!(run_dir.join("mesh.ply").exists() && run_dir.join("notes.txt").exists());
    let report = std::fs::read_to_string(run_dir.join("report.md")).unwrap();
    assert!(report.contains("mesh.ply in the run folder is not this evaluation's"), "{report}");
}

/// `compare` flags a run whose report is older than its latest checkpoint (trained on after
/// its evaluation): a warning naming the run, and its row marked stale.
#[test]
fn compare_flags_a_report_older_than_the_latest_checkpoint() {
    let tmp = tempfile::tempdir().unwrap();
    let (run_dir, _) = trained_run(tmp.path());
    let r = run_dir.as_os_str();
    let o = run(&["eval".as_ref(), r, "--split".as_ref(), "train".as_ref(), "--no-mesh".as_ref(), "--grids".as_ref(), "0".as_ref()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let cmp = tmp.path().join("cmp");
    let compare = || {
        let o = run(&["compare".as_ref(), r, "--out".as_ref(), cmp.as_os_str()]);
        assert!(o.status.success(), "{}", stderr(&o));
        (stderr(&o), std::fs::read_to_string(cmp.join("compare.md")).unwrap())
    };
    let (err, md) = compare();
    assert!(!err.contains("warning") && !md.contains("stale"), "{err}\n{md}");
    let o = run(&["train".as_ref(), "--out".as_ref(), r, "--resume".as_ref(), "--steps".as_ref(), "8".as_ref()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (err, md) = compare();
    assert!(err.contains("warning") && err.contains(&*run_dir.to_string_lossy()) && err.contains("step 4") && err.contains("step 8"), "{err}");
    assert!(md.contains("run (stale)"), "{md}");
}

/// `mesh` removes the temporaries a killed `mesh` left beside its PLY and sidecar (whatever
/// becomes of this run), and no other file.
#[test]
fn mesh_removes_the_temporaries_of_a_killed_mesh() {
    let tmp = tempfile::tempdir().unwrap();
    let (run_dir, _) = trained_run(tmp.path());
    let out = tmp.path().join("m.ply");
    let dead = if Path::new("/proc/self").exists() { 0 } else { 1 };
    let stale = [tmp.path().join(format!(".m.ply.{dead}.tmp")), tmp.path().join(format!(".m.json.{dead}.tmp"))];
    let other = tmp.path().join(format!(".n.ply.{dead}.tmp"));
    for f in stale.iter().chain([&other]) {
        std::fs::write(f, b"half").unwrap();
    }
    run(&["mesh".as_ref(), run_dir.as_os_str(), "--out".as_ref(), out.as_os_str(), "--resolution".as_ref(), "8".as_ref(), "--no-metrics".as_ref()]);
    assert!(stale.iter().all(|f| !f.exists()), "the temporaries were kept");
    assert!(other.exists(), "another file's temporary was removed");
}

/// Runs `xtask ARGS` and fails the test if it has not exited within `secs` seconds (it is
/// killed then): a read of a device or a FIFO must not hang a command.
fn run_within(args: &[&std::ffi::OsStr], secs: u64) -> Output {
    let mut c = xtask();
    c.stdout(Stdio::piped()).stderr(Stdio::piped()).args(args);
    let mut child = c.spawn().unwrap();
    let deadline = Instant::now() + Duration::from_secs(secs);
    while child.try_wait().unwrap().is_none() {
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{args:?} still running after {secs} s");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

/// Bytes that stand for a file outside the folder a scene or dataset was given in; no error
/// message may quote them.
const OUTSIDE: &[u8] = b"root:x:0:0:OUTSIDE-SECRET";

/// A one-triangle glTF at `dir/scene/tri.gltf` whose buffer is the file at `uri`; the buffer's
/// bytes (followed by [`OUTSIDE`]) are written to `dir/outside.bin`, beside the scene's folder.
fn scene_with_buffer(dir: &Path, uri: &str) -> PathBuf {
    let mut bin: Vec<u8> = [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0].iter().flat_map(|v| v.to_le_bytes()).collect();
    bin.extend([0u16, 1, 2, 0].iter().flat_map(|i| i.to_le_bytes()));
    let mut outside = bin.clone();
    outside.extend_from_slice(OUTSIDE);
    std::fs::write(dir.join("outside.bin"), outside).unwrap();
    let scene = serde_json::json!({
        "asset": {"version": "2.0"},
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "buffers": [{"byteLength": bin.len(), "uri": uri}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 36, "byteLength": 6}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"}
        ]
    });
    std::fs::create_dir_all(dir.join("scene")).unwrap();
    let path = dir.join("scene/tri.gltf");
    std::fs::write(&path, serde_json::to_vec(&scene).unwrap()).unwrap();
    path
}

fn render_args<'a>(scene: &'a Path, out: &'a Path, extra: &'a [&'a str]) -> Vec<&'a std::ffi::OsStr> {
    let mut v: Vec<&std::ffi::OsStr> = vec!["render".as_ref(), scene.as_os_str(), "--out".as_ref(), out.as_os_str()];
    for a in ["--res", "8", "--train", "1", "--val", "1", "--test", "1", "--spp", "1"].iter().chain(extra) {
        v.push(a.as_ref());
    }
    v
}

/// `render` of a scene whose buffer URI leads outside its folder (`../`, `%2e%2e`, an absolute
/// path) is refused naming the scene and the URI, without quoting the outside file and without
/// writing anything; `--allow-outside` renders it.
#[test]
fn render_refuses_a_buffer_outside_the_scene_folder_unless_allowed() {
    let tmp = tempfile::tempdir().unwrap();
    let absolute = tmp.path().join("outside.bin").to_string_lossy().into_owned();
    for uri in ["../outside.bin", "%2e%2e/outside.bin", absolute.as_str()] {
        let scene = scene_with_buffer(tmp.path(), uri);
        let out = tmp.path().join("data");
        let o = run(&render_args(&scene, &out, &[]));
        let err = stderr(&o);
        assert!(!o.status.success(), "{uri}: render read a buffer outside the scene's folder");
        assert!(err.contains("tri.gltf") && err.contains(uri) && err.contains("outside the scene's folder") && err.contains("--allow-outside"), "{uri}: {err}");
        assert!(!err.contains("root:") && !err.contains("OUTSIDE-SECRET"), "{uri}: the message quotes the outside file: {err}");
        assert!(!out.exists(), "{uri}: a refused render wrote {}", out.display());
    }
    let scene = scene_with_buffer(tmp.path(), "../outside.bin");
    let out = tmp.path().join("allowed");
    let o = run(&render_args(&scene, &out, &["--allow-outside"]));
    assert!(o.status.success(), "--allow-outside: {}", stderr(&o));
    assert!(out.join("transforms_test.json").is_file());
}

/// A buffer URI naming `/dev/zero` (even with `--allow-outside`) or a FIFO in the scene's folder
/// is refused at once as not a regular file, instead of reading forever or hanging.
#[cfg(unix)]
#[test]
fn render_refuses_devices_and_fifos_promptly() {
    let tmp = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(tmp.path().join("scene")).unwrap();
    assert!(Command::new("mkfifo").arg(tmp.path().join("scene/pipe.bin")).status().unwrap().success());
    for (uri, kind) in [("/dev/zero", "device"), ("pipe.bin", "FIFO")] {
        let scene = scene_with_buffer(tmp.path(), uri);
        let out = tmp.path().join("data");
        let o = run_within(&render_args(&scene, &out, &["--allow-outside"]), 60);
        let err = stderr(&o);
        assert!(!o.status.success(), "{uri}: accepted");
        assert!(err.contains("tri.gltf") && err.contains("not a regular file") && err.contains(kind), "{uri}: {err}");
    }
}

/// A split folder of `--out` that is a symbolic link to a folder of the user's is refused, with
/// and without `--force`, and nothing in the link's target is touched.
#[cfg(unix)]
#[test]
fn render_refuses_a_split_folder_that_is_a_symlink() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell.gltf");
    let out = tmp.path().join("data");
    let theirs = tmp.path().join("theirs");
    std::fs::create_dir_all(&theirs).unwrap();
    std::fs::write(theirs.join("r_0.png"), b"precious").unwrap();
    std::fs::write(theirs.join("notes.txt"), b"mine").unwrap();
    let o = run(&render_args(&scene, &out, &[]));
    assert!(o.status.success(), "{}", stderr(&o));
    std::fs::rename(out.join("val"), tmp.path().join("old-val")).unwrap();
    std::os::unix::fs::symlink(&theirs, out.join("val")).unwrap();
    let before = folder_bytes(&theirs);
    for extra in [&[][..], &["--force"][..], &["--force", "--seed", "3"][..]] {
        let o = run(&render_args(&scene, &out, extra));
        let err = stderr(&o);
        assert!(!o.status.success(), "{extra:?}: rendered through a symlinked split folder");
        assert!(err.contains("val") && err.contains("symbolic link"), "{extra:?}: {err}");
        assert_eq!(folder_bytes(&theirs), before, "{extra:?}: the link's target changed");
    }
}

/// A dataset whose `transforms_train.json` names a frame image outside the dataset folder is
/// refused by `train` and by `eval`, naming the frame's `file_path`; `--allow-outside` admits it.
#[test]
fn train_and_eval_refuse_frame_files_outside_the_dataset_unless_allowed() {
    let tmp = tempfile::tempdir().unwrap();
    let config = test_support::training::write_cli_config(tmp.path(), 2, 1_000_000);
    let data = tmp.path().join("data");
    std::fs::create_dir_all(tmp.path().join("outside")).unwrap();
    std::fs::rename(data.join("train/r_0.png"), tmp.path().join("outside/r_0.png")).unwrap();
    let transforms = data.join("transforms_train.json");
    let mut t: serde_json::Value = serde_json::from_slice(&std::fs::read(&transforms).unwrap()).unwrap();
    t["frames"][0]["file_path"] = "../outside/r_0".into();
    std::fs::write(&transforms, serde_json::to_vec(&t).unwrap()).unwrap();
    let run_dir = tmp.path().join("run");
    let train = |extra: &[&str]| {
        let mut args: Vec<&std::ffi::OsStr> = vec!["train".as_ref(), "--config".as_ref(), config.as_os_str(), "--out".as_ref(), run_dir.as_os_str()];
        args.extend(extra.iter().map(|a| std::ffi::OsStr::new(*a)));
        run(&args)
    };
    let o = train(&[]);
    let err = stderr(&o);
    assert!(!o.status.success(), "train read a frame outside the dataset folder");
    assert!(err.contains("transforms_train.json") && err.contains("file_path '../outside/r_0'") && err.contains("--allow-outside"), "{err}");
    assert!(!run_dir.exists(), "a refused train created its run folder");
    let o = train(&["--allow-outside"]);
    assert!(o.status.success(), "train --allow-outside: {}", stderr(&o));
    let eval = |extra: &[&str]| {
        let mut args: Vec<&std::ffi::OsStr> = vec!["eval".as_ref(), run_dir.as_os_str(), "--no-mesh".as_ref(), "--grids".as_ref(), "0".as_ref()];
        args.extend(extra.iter().map(|a| std::ffi::OsStr::new(*a)));
        run(&args)
    };
    let o = eval(&[]);
    let err = stderr(&o);
    assert!(!o.status.success() && err.contains("file_path '../outside/r_0'"), "{err}");
    let o = eval(&["--allow-outside"]);
    assert!(o.status.success(), "eval --allow-outside: {}", stderr(&o));
}
