//! The command line on bad input: every malformed scene, impossible option or missing folder
//! ends with exit code 1, one message naming the file and the problem, no panic, and no output
//! left behind.

use std::path::{Path, PathBuf};
use std::process::Command;

fn xtask(args: &[&str]) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_xtask")).args(args).output().expect("run xtask");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    (out.status.code().unwrap_or(-1), stderr)
}

/// Runs `xtask args` and checks that it was refused: exit code 1, no panic, a message saying
/// `what`, and nothing at `out`. Returns stderr.
fn assert_refused(args: &[&str], what: &str, out: &Path) -> String {
    let (code, stderr) = xtask(args);
    assert_eq!(code, 1, "{args:?}: exit code {code}, stderr:\n{stderr}");
    assert!(!stderr.contains("panicked"), "{args:?}: panic:\n{stderr}");
    assert!(stderr.contains(what), "{args:?}: message does not say '{what}':\n{stderr}");
    assert!(!out.exists(), "{args:?}: wrote {}", out.display());
    stderr
}

fn corpus() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../crates/pathtracer/tests/data/import")
}

#[test]
fn malformed_scenes_exit_1_naming_the_file_and_write_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let mut checked = 0;
    for entry in std::fs::read_dir(corpus()).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        if name.starts_with("valid_") {
            continue;
        }
        let out = tmp.path().join(&name);
        let (code, stderr) = xtask(&["render", path.to_str().unwrap(), "--out", out.to_str().unwrap(), "--res", "8", "--train", "1", "--val", "1", "--test", "1", "--spp", "1"]);
        assert_eq!(code, 1, "{name}: exit code {code}, stderr:\n{stderr}");
        assert!(stderr.contains(&name), "{name}: message does not name the file:\n{stderr}");
        assert!(!stderr.contains("panicked"), "{name}: panic:\n{stderr}");
        assert!(!out.exists(), "{name}: output folder left behind");
        checked += 1;
    }
    assert!(checked >= 10, "only {checked} malformed files found");
}

#[test]
fn a_valid_scene_renders_and_impossible_options_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = corpus().join("valid_triangle.gltf");
    let out = tmp.path().join("ok");
    let base = ["render", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--spp", "1"];
    for bad in [&["--res", "0"][..], &["--train", "0"], &["--spp", "0"], &["--res", "abc"]] {
        let args: Vec<&str> = base.iter().copied().filter(|a| *a != "--spp" && *a != "1").chain(bad.iter().copied()).collect();
        let (code, stderr) = xtask(&args);
        assert_eq!(code, 1, "{bad:?}: {stderr}");
        assert!(!out.exists(), "{bad:?}: wrote {}", out.display());
    }
    let (code, stderr) = xtask(&[&base[..], &["--res", "8", "--train", "2", "--val", "1", "--test", "1"]].concat());
    assert_eq!(code, 0, "{stderr}");
    assert!(out.join("transforms_train.json").is_file());
}

#[test]
fn training_on_a_missing_dataset_exits_1() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    let (code, stderr) = xtask(&["train", "/nonexistent/dataset", "--out", run.to_str().unwrap(), "--steps", "1"]);
    assert_eq!(code, 1, "{stderr}");
    assert!(stderr.contains("/nonexistent/dataset"), "{stderr}");
    assert!(!stderr.contains("panicked"));
}

fn dataset_corpus() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/corpus/transforms")
}

/// Each malformed dataset in `tests/corpus/transforms` (see its README): the file the message
/// must name (relative to the dataset folder) and what it must say is wrong.
const MALFORMED_DATASETS: [(&str, &str, &str); 20] = [
    ("invalid_json", "transforms_train.json", "EOF while parsing"),
    ("missing_camera_angle_x", "transforms_train.json", "missing field `camera_angle_x`"),
    ("missing_transform_matrix", "transforms_train.json", "missing field `transform_matrix`"),
    ("missing_file_path", "transforms_train.json", "missing field `file_path`"),
    ("empty_frames", "transforms_train.json", "no frames"),
    ("pose_3_rows", "transforms_train.json", "expected an array of length 4"),
    ("singular_pose", "transforms_train.json", "frame 1 (./train/r_1): pose is not invertible"),
    ("scaled_pose", "transforms_train.json", "frame 1 (./train/r_1): pose's rotation is not a proper rotation"),
    ("nan_pose", "transforms_train.json", "non-finite number (NaN or Infinity is not valid JSON)"),
    ("overflowing_pose", "transforms_train.json", "number out of range"),
    ("missing_image", "transforms_train.json", "train/r_7.png does not exist"),
    ("undecodable_image", "train/r_1.png", "image error"),
    ("mixed_image_sizes", "train/r_1.png", "image is 24x16 but"),
    ("w_h_disagree_with_image", "train/r_0.png", "image is 16x16 but"),
    ("fl_x_disagrees_with_camera_angle_x", "transforms_train.json", "inconsistent intrinsics"),
    ("zero_camera_angle_x", "transforms_train.json", "camera_angle_x = 0 is not a field of view"),
    ("negative_focal_length", "transforms_train.json", "focal length fl_x = -22.3 must be finite and positive"),
    ("missing_ground_truth_file", "transforms_train.json", "train/r_0_gt.exr does not exist"),
    ("val_frames_not_a_list", "transforms_val.json", "expected a sequence"),
    ("no_train_split", "transforms_train.json", "missing: a dataset needs transforms_train.json"),
];

/// The corpus folders, checked against [`MALFORMED_DATASETS`] both ways.
fn malformed_dataset_dirs() -> Vec<(PathBuf, &'static str, &'static str)> {
    let mut on_disk: Vec<String> = std::fs::read_dir(dataset_corpus())
        .unwrap()
        .flatten()
        .filter(|e| e.path().is_dir())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| !n.starts_with("valid_"))
        .collect();
    on_disk.sort();
    let mut listed: Vec<String> = MALFORMED_DATASETS.iter().map(|c| c.0.to_string()).collect();
    listed.sort();
    assert_eq!(on_disk, listed, "corpus folders and the expectations in this test differ");
    MALFORMED_DATASETS.iter().map(|&(n, f, w)| (dataset_corpus().join(n), f, w)).collect()
}

/// The one message of a failed command, checked: exit code 1, a single line, no panic, naming
/// `file` and saying `what`. Returns it with the dataset folder's path cut out.
fn check_failure(name: &str, code: i32, stderr: &str, dir: &Path, file: &str, what: &str) -> String {
    assert_eq!(code, 1, "{name}: exit code {code}, stderr:\n{stderr}");
    assert!(!stderr.contains("panicked"), "{name}: panic:\n{stderr}");
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "{name}: not one message:\n{stderr}");
    let named = format!("{}/{file}", dir.file_name().unwrap().to_string_lossy());
    assert!(lines[0].contains(&named), "{name}: message does not name {named}:\n{stderr}");
    assert!(lines[0].contains(what), "{name}: message does not say '{what}':\n{stderr}");
    lines[0].replace(dir.to_str().unwrap(), "<dataset>")
}

/// A small `fast` model, so that a run folder is cheap to write.
fn small_config(dir: &Path, dataset: &Path) -> PathBuf {
    use nerf::models::{ModelConfig, fast::FastConfig};
    let fast = FastConfig::new().with_levels(2).with_log2_table_size(10).with_finest_resolution(32).with_grid_resolution(8);
    let cfg = nerf::train::TrainConfig::new(dataset.to_path_buf(), ModelConfig::Fast(fast), 64, 1e-2, 1e-3, 10).with_steps(Some(2));
    let path = dir.join("small.json");
    std::fs::write(&path, serde_json::to_string(&cfg).unwrap()).unwrap();
    path
}

/// Trains [`small_config`] on the corpus's valid dataset into `dir/name`; asserts it succeeds.
fn train_valid_blender(dir: &Path, name: &str) -> PathBuf {
    let run = dir.join(name);
    let config = small_config(dir, &dataset_corpus().join("valid_blender"));
    let (code, stderr) = xtask(&["train", "--config", config.to_str().unwrap(), "--out", run.to_str().unwrap()]);
    assert_eq!(code, 0, "training on valid_blender: {stderr}");
    run
}

fn listing(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            if e.path().is_dir() { stack.push(e.path()) } else { out.push(e.path()) }
        }
    }
    out.sort();
    out
}

#[test]
fn malformed_datasets_fail_training_with_one_message_and_no_run_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let mut messages = std::collections::BTreeMap::new();
    for (dir, file, what) in malformed_dataset_dirs() {
        let name = dir.file_name().unwrap().to_string_lossy().into_owned();
        let run = tmp.path().join(&name);
        let (code, stderr) = xtask(&["train", dir.to_str().unwrap(), "--out", run.to_str().unwrap(), "--steps", "1"]);
        let msg = check_failure(&name, code, &stderr, &dir, file, what);
        assert!(!run.exists(), "{name}: run folder {} left behind", run.display());
        if let Some(other) = messages.insert(msg.clone(), name.clone()) {
            panic!("{name} fails exactly as {other}: {msg}");
        }
    }
    // The dataset all of them break trains.
    let run = train_valid_blender(tmp.path(), "valid");
    assert!(run.join("checkpoints/step-00000002.ckpt").is_file());
}

#[test]
fn malformed_datasets_fail_evaluation_with_one_message_and_write_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let run = train_valid_blender(tmp.path(), "run");
    let recorded = std::fs::read_to_string(run.join("config.json")).unwrap();
    let before = listing(&run);
    // The run's recorded dataset replaced by each malformed one in turn.
    for (dir, file, what) in malformed_dataset_dirs() {
        let name = dir.file_name().unwrap().to_string_lossy().into_owned();
        let mut cfg: serde_json::Value = serde_json::from_str(&recorded).unwrap();
        cfg["dataset"] = serde_json::json!(dir);
        std::fs::write(run.join("config.json"), cfg.to_string()).unwrap();
        let (code, stderr) = xtask(&["eval", run.to_str().unwrap(), "--split", "train"]);
        check_failure(&name, code, &stderr, &dir, file, what);
        assert_eq!(listing(&run), before, "{name}: eval wrote into the run folder");
    }
    std::fs::write(run.join("config.json"), &recorded).unwrap();
    let (code, stderr) = xtask(&["eval", run.to_str().unwrap(), "--split", "train", "--grids", "0"]);
    assert_eq!(code, 0, "evaluating on valid_blender: {stderr}");
    assert!(listing(&run).len() > before.len(), "eval of the valid run wrote nothing");
}

#[test]
fn impossible_training_options_exit_1_and_write_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let valid = dataset_corpus().join("valid_blender");
    let run = tmp.path().join("run");
    let cases: [(&[&str], &str); 15] = [
        (&["--time", "-5s"], "time budget must be positive"),
        (&["--time=-5s"], "time budget must be positive"),
        (&["--time", "0s"], "time budget must be positive"),
        (&["--time", "5parsecs"], "bad duration unit"),
        (&["--steps", "0"], "steps must be positive"),
        (&["--steps", "1", "--batch-rays", "0"], "batch_rays must be 1..="),
        (&["--steps", "1", "--batch-samples", "0"], "batch_samples must be 1..="),
        (&["--steps", "1", "--batch-rays", "4000000000"], "batch_rays must be 1..=4194304, not 4000000000"),
        (&["--steps", "1", "--batch-samples", "99999999999"], "batch_samples must be 1..="),
        (&["--steps", "1", "--downscale", "0"], "downscale must be a positive integer"),
        (&["--steps", "1", "--downscale", "17"], "downscale 17 is larger than the 16x16 image"),
        (&["--steps", "1", "--downscale", "3"], "downscale 3 does not divide the 16x16 image"),
        (&["--steps", "1", "--model", "nope"], "unknown model 'nope'"),
        (&["--steps", "1", "--config", "/nonexistent/train.json"], "/nonexistent/train.json"),
        (&["--steps", "1", "--resume"], "config.json"),
    ];
    for (opts, what) in cases {
        let mut args = vec!["train", valid.to_str().unwrap(), "--out", run.to_str().unwrap()];
        args.extend_from_slice(opts);
        let stderr = assert_refused(&args, what, &run);
        assert!(stderr.starts_with("error: ") && stderr.trim_end().lines().count() == 1, "{opts:?}: not one message:\n{stderr}");
    }
}

/// `train --out` on a folder that holds a run starts nothing there unless `--force` replaces
/// it; `--resume` continues it, extends its budget with `--steps`, and refuses flags that would
/// change its recorded settings instead of ignoring them.
#[test]
fn an_existing_run_is_refused_replaced_or_resumed_never_mixed() {
    let tmp = tempfile::tempdir().unwrap();
    let valid = dataset_corpus().join("valid_blender");
    let run = train_valid_blender(tmp.path(), "run");
    let r = run.to_str().unwrap();
    let before: Vec<(PathBuf, Vec<u8>)> = listing(&run).into_iter().map(|p| (p.clone(), std::fs::read(&p).unwrap())).collect();
    let unchanged = |why: &str| {
        let now: Vec<(PathBuf, Vec<u8>)> = listing(&run).into_iter().map(|p| (p.clone(), std::fs::read(&p).unwrap())).collect();
        assert!(now == before, "{why}: the run folder changed");
    };
    let (code, stderr) = xtask(&["train", valid.to_str().unwrap(), "--out", r, "--steps", "1", "--seed", "9"]);
    assert!(code == 1 && stderr.contains("already holds a training run") && stderr.contains("--force"), "{code}: {stderr}");
    unchanged("a fresh run into it");
    let (code, stderr) = xtask(&["train", "--resume", "--out", r, "--steps", "3", "--seed", "9", "--model", "paper"]);
    assert!(code == 1 && stderr.contains("--seed, --model would change them"), "{code}: {stderr}");
    unchanged("a resume with other settings");
    // The same settings, restated, are not a change; --steps extends the budget.
    let (code, stderr) = xtask(&["train", valid.to_str().unwrap(), "--resume", "--out", r, "--steps", "3", "--seed", "0", "--model", "fast"]);
    assert_eq!(code, 0, "{stderr}");
    assert!(run.join("checkpoints/step-00000003.ckpt").is_file(), "the resumed run did not train to step 3: {:?}", listing(&run));
    // --force starts over: the old run's checkpoints and outputs are gone, a file the run did
    // not write stays.
    std::fs::write(run.join("notes.txt"), "mine").unwrap();
    std::fs::write(run.join("report.md"), "an old report").unwrap();
    let (code, stderr) = xtask(&["train", valid.to_str().unwrap(), "--out", r, "--steps", "1", "--force"]);
    assert_eq!(code, 0, "{stderr}");
    let ckpts: Vec<PathBuf> = listing(&run).into_iter().filter(|p| p.extension().is_some_and(|e| e == "ckpt")).collect();
    assert_eq!(ckpts, vec![run.join("checkpoints/step-00000001.ckpt")], "--force kept the old run's checkpoints");
    assert!(!run.join("report.md").exists(), "--force kept the old run's report");
    assert_eq!(std::fs::read_to_string(run.join("notes.txt")).unwrap(), "mine", "--force removed a file the run did not write");
    // A folder whose config.json is not a run's is never emptied by --force.
    let foreign = tmp.path().join("foreign");
    std::fs::create_dir_all(&foreign).unwrap();
    std::fs::write(foreign.join("config.json"), r#"{"editor": "vim"}"#).unwrap();
    let (code, stderr) = xtask(&["train", valid.to_str().unwrap(), "--out", foreign.to_str().unwrap(), "--steps", "1", "--force"]);
    assert!(code == 1 && stderr.contains("is not a training run's config"), "{code}: {stderr}");
    assert_eq!(std::fs::read_to_string(foreign.join("config.json")).unwrap(), r#"{"editor": "vim"}"#);
}

#[test]
fn impossible_render_options_exit_1_and_write_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = corpus().join("valid_triangle.gltf");
    let out = tmp.path().join("out");
    let cases: [(&[&str], &str); 8] = [
        (&["--res", "0x8"], "at least 1x1"),
        (&["--res", "8x0"], "at least 1x1"),
        (&["--res", "8", "--val", "0"], "val and test need at least one view each"),
        (&["--res", "8", "--test", "0"], "val and test need at least one view each"),
        (&["--res", "8", "--fov-x", "0"], "field of view 0 rad is not in (0, pi)"),
        (&["--res", "8", "--max-bounces", "5000"], "at most 1024"),
        (&["--res", "8", "--environment=-1,0,0"], "must be finite and non-negative"),
        (&["--res", "8", "--threads", "0"], "at least one thread"),
    ];
    for (opts, what) in cases {
        let mut args = vec!["render", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--spp", "1"];
        args.extend_from_slice(opts);
        assert_refused(&args, what, &out);
    }
}

/// Values the command-line parser itself rejects (a malformed `--shard`, a number that is not
/// one, an unknown option) are bad input too: exit code 1 (not clap's 2), the option named,
/// nothing written; `--help` still exits 0.
#[test]
fn unparsable_options_exit_1_naming_the_option() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = corpus().join("valid_triangle.gltf");
    let valid = dataset_corpus().join("valid_blender");
    let out = tmp.path().join("out");
    let (o, s, v) = (out.to_str().unwrap(), scene.to_str().unwrap(), valid.to_str().unwrap());
    let cases: [(&[&str], &str); 9] = [
        (&["render", s, "--out", o, "--res", "8", "--shard", "3/3"], "--shard '3/3'"),
        (&["render", s, "--out", o, "--res", "8", "--shard", "0/0"], "--shard '0/0'"),
        (&["render", s, "--out", o, "--res", "8", "--shard", "x"], "--shard 'x'"),
        (&["render", s, "--out", o, "--res", "8", "--shard=-1/2"], "--shard"),
        (&["render", s, "--out", o, "--spp", "many"], "--spp"),
        (&["render", s, "--out", o, "--no-such-option"], "--no-such-option"),
        (&["train", v, "--out", o, "--steps", "abc"], "--steps"),
        (&["train", v, "--out", o, "--time", "nan"], "nan"),
        (&["eval", o, "--downscale=-2"], "--downscale"),
    ];
    for (args, what) in cases {
        assert_refused(args, what, &out);
    }
    let (code, stdout_or_err) = xtask(&["render", "--help"]);
    assert_eq!(code, 0, "render --help: {stdout_or_err}");
}

/// Inputs of the wrong kind say what they are, and an error's cause is printed once (errors
/// that write their source into their own message printed it twice through anyhow's chain).
#[test]
fn inputs_of_the_wrong_kind_are_named_and_causes_printed_once() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let (t, o) = (tmp.path().to_str().unwrap(), out.to_str().unwrap());
    let file = dataset_corpus().join("valid_blender/transforms_train.json");
    let cases: [(&[&str], &str); 5] = [
        (&["render", t, "--out", o], "is a folder, not a glTF file"),
        (&["train", file.to_str().unwrap(), "--out", o, "--steps", "1"], "is a file, not a dataset folder"),
        (&["crosscheck", "cornell", "--out", o, "--variant", "cuda_bogus"], "--variant cuda_bogus: the cross-check needs one of Mitsuba's RGB variants"),
        (&["crosscheck", "cornell", "--out", o, "--max-groups", "0"], "--max-groups 0: at least 2 groups"),
        (&["train", "--config", "/nonexistent/train.json", "--out", o], "/nonexistent/train.json"),
    ];
    for (args, what) in cases {
        let stderr = assert_refused(args, what, &out);
        assert!(stderr.matches("os error").count() <= 1, "{args:?}: a cause printed twice:\n{stderr}");
    }
}

/// A run whose `metrics.jsonl` is malformed fails evaluation before any output (the mesh's
/// files included: eval wrote them first) is written into it; with the file restored the same
/// evaluation writes the mesh, so the run is one that has a surface to mesh.
#[test]
fn eval_with_a_malformed_metrics_file_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let (ds, run) = (tmp.path().join("ds"), tmp.path().join("run"));
    let (d, r) = (ds.to_str().unwrap(), run.to_str().unwrap());
    for args in [
        &["render", "tabletop", "--out", d, "--res", "16", "--train", "3", "--val", "1", "--test", "1", "--spp", "2"][..],
        &["train", d, "--out", r, "--steps", "100"],
    ] {
        let (code, stderr) = xtask(args);
        assert_eq!(code, 0, "{args:?}: {stderr}");
    }
    let metrics = std::fs::read(run.join("metrics.jsonl")).unwrap();
    std::fs::write(run.join("metrics.jsonl"), "{\"step\": oops\n").unwrap();
    let before = listing(&run);
    let eval = ["eval", r, "--split", "test", "--mesh-resolution", "8", "--grids", "0"];
    let (code, stderr) = xtask(&eval);
    assert!(code == 1 && stderr.contains("metrics.jsonl:1"), "{code}: {stderr}");
    assert_eq!(listing(&run), before, "eval wrote into the run before failing");
    std::fs::write(run.join("metrics.jsonl"), metrics).unwrap();
    let (code, stderr) = xtask(&eval);
    assert_eq!(code, 0, "{stderr}");
    assert!(run.join("mesh.ply").is_file(), "the valid evaluation wrote no mesh: {:?}", listing(&run));
}

/// A checkpoint that does not hold the model its run's config describes is named in the
/// error (it said only "parameter 0: expected …"), on loading and on resuming.
#[test]
fn a_checkpoint_that_does_not_fit_the_config_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    let run = train_valid_blender(tmp.path(), "run");
    let mut cfg: serde_json::Value = serde_json::from_slice(&std::fs::read(run.join("config.json")).unwrap()).unwrap();
    cfg["model"]["density_width"] = serde_json::json!(32);
    std::fs::write(run.join("config.json"), cfg.to_string()).unwrap();
    let r = run.to_str().unwrap();
    for args in [&["render-nerf", r, "--split", "train"][..], &["train", "--resume", "--out", r, "--steps", "3"]] {
        let (code, stderr) = xtask(args);
        assert!(code == 1 && stderr.contains("checkpoints/step-00000002.ckpt: parameter"), "{args:?}: {code}: {stderr}");
    }
}

#[test]
fn render_nerf_and_eval_with_no_views_exit_1_and_write_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let run = train_valid_blender(tmp.path(), "run");
    let out = tmp.path().join("renders");
    // valid_blender has train views only.
    for (opts, what) in [
        (&["--orbit", "0"][..], "--orbit 0: at least one view is needed"),
        (&["--split", "test"], "has no test views"),
        (&["--split", "nope"], "unknown split 'nope'"),
    ] {
        let mut args = vec!["render-nerf", run.to_str().unwrap(), "--out", out.to_str().unwrap()];
        args.extend_from_slice(opts);
        assert_refused(&args, what, &out);
    }
    // It used to evaluate one view.
    let eval_args = ["eval", run.to_str().unwrap(), "--split", "train", "--max-views", "0"];
    assert_refused(&eval_args, "--max-views 0 evaluates nothing", &run.join("eval.json"));
    // Impossible downscale factors (the views are 16x16): one message naming the option, exit 1,
    // nothing written.
    for (d, what) in [("0", "--downscale 0"), ("3", "--downscale 3 does not divide the 16x16 image"), ("32", "--downscale 32 is larger than the 16x16 image")] {
        let eval_args = ["eval", run.to_str().unwrap(), "--split", "train", "--downscale", d];
        assert_refused(&eval_args, what, &run.join("eval.json"));
        let args = ["render-nerf", run.to_str().unwrap(), "--out", out.to_str().unwrap(), "--split", "train", "--downscale", d];
        assert_refused(&args, what, &out);
    }
    let (code, stderr) = xtask(&["render-nerf", run.to_str().unwrap(), "--out", out.to_str().unwrap(), "--split", "train"]);
    assert_eq!(code, 0, "{stderr}");
    assert!(out.join("r_0.png").is_file() && out.join("r_1_depth.npy").is_file());
    // A factor that divides the views: evaluated there and labelled so.
    let (code, stdout) = xtask(&["eval", run.to_str().unwrap(), "--split", "train", "--grids", "0", "--downscale", "2"]);
    assert_eq!(code, 0, "{stdout}");
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(run.join("eval.json")).unwrap()).unwrap();
    assert_eq!((report["resolution"]["width"].as_u64(), report["resolution"]["downscale"].as_u64()), (Some(8), Some(2)));
}

#[test]
fn mesh_on_bad_input_exits_1_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let run = train_valid_blender(tmp.path(), "run");
    let out = tmp.path().join("mesh.ply");
    let r = run.to_str().unwrap();
    let o = out.to_str().unwrap();
    for (res, what) in [("0", "--resolution must be 1..=2048, not 0"), ("2049", "--resolution must be 1..=2048, not 2049")] {
        assert_refused(&["mesh", r, "--out", o, "--resolution", res], what, &out);
    }
    assert_refused(&["mesh", r, "--out", o, "--level=-1"], "--level must be a positive density", &out);
    // Two training steps leave no surface: none at an absurd level, and none (or no level to
    // choose) from the data.
    assert_refused(&["mesh", r, "--out", o, "--resolution", "16", "--level", "1e30"], "no surface at density level", &out);
    let stderr = assert_refused(&["mesh", r, "--out", o, "--resolution", "16"], "", &out);
    assert!(stderr.contains("no surface") || stderr.contains("cannot choose a density level"), "{stderr}");
    // A run folder without a checkpoint.
    let bare = tmp.path().join("bare");
    std::fs::create_dir_all(&bare).unwrap();
    std::fs::copy(run.join("config.json"), bare.join("config.json")).unwrap();
    assert_refused(&["mesh", bare.to_str().unwrap(), "--out", o], "checkpoint", &out);
    assert!(!tmp.path().join("mesh.json").exists());
}

/// `score` on another tool's predictions (here the dataset's own images, so PSNR is +inf):
/// eval.json carries the method block and `compare` reads the folder; an output inside the
/// dataset or the predictions, and a missing view, are refused with exit code 1 and nothing
/// written; the dataset folder is never changed.
#[test]
fn score_measures_predictions_and_never_writes_over_its_inputs() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    nerf::data::synthetic::write(&data, 16, [2, 1, 2], false).unwrap();
    let before = test_support::file_map(&data);
    let pred = tmp.path().join("pred");
    std::fs::create_dir_all(&pred).unwrap();
    for k in 0..2 {
        std::fs::copy(data.join(format!("test/r_{k}.png")), pred.join(format!("r_{k}.png"))).unwrap();
    }
    let (d, p) = (data.to_str().unwrap(), pred.to_str().unwrap());
    let out = tmp.path().join("scored");
    let (code, stderr) = xtask(&["score", d, p, "--method", "copy", "--train-seconds", "5", "--out", out.to_str().unwrap()]);
    assert_eq!(code, 0, "{stderr}");
    let eval: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("eval.json")).unwrap()).unwrap();
    assert_eq!((eval["method"]["name"].as_str(), eval["method"]["tool"].as_str()), (Some("copy"), Some("images")));
    assert_eq!(eval["mean"]["psnr"], "inf");
    let cmp = tmp.path().join("cmp");
    let (code, stderr) = xtask(&["compare", out.to_str().unwrap(), "--out", cmp.to_str().unwrap()]);
    assert_eq!(code, 0, "{stderr}");
    assert!(std::fs::read_to_string(cmp.join("compare.md")).unwrap().contains("| copy (images) |"));
    let inside = data.join("test/report");
    assert_refused(&["score", d, p, "--method", "x", "--out", inside.to_str().unwrap()], "inside the dataset folder", &inside);
    let mixed = pred.join("report");
    assert_refused(&["score", d, p, "--method", "x", "--out", mixed.to_str().unwrap()], "lies in the predictions folder", &mixed);
    std::fs::remove_file(pred.join("r_1.png")).unwrap();
    let other = tmp.path().join("other");
    let stderr = assert_refused(&["score", d, p, "--method", "x", "--out", other.to_str().unwrap()], "1 of the 2 test views have no prediction (r_1)", &other);
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    assert_eq!(test_support::file_map(&data), before, "score changed the dataset folder");
}

/// Writes `mesh` as an OBJ with every vertex mapped by the column-vector affine `m`.
fn write_moved_obj(path: &Path, mesh: &eval::mesh::TriMesh, m: glam::DMat4) {
    let mut s = String::new();
    for p in &mesh.positions {
        let q = m.transform_point3(glam::Vec3::from(*p).as_dvec3());
        s.push_str(&format!("v {:?} {:?} {:?}\n", q.x, q.y, q.z));
    }
    for t in &mesh.triangles {
        s.push_str(&format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1));
    }
    std::fs::write(path, s).unwrap();
}

/// Row-major numbers of `m`, as `--to-dataset` reads them.
fn row_major(m: glam::DMat4) -> String {
    m.transpose().to_cols_array().iter().map(|x| format!("{x:?}")).collect::<Vec<_>>().join(" ")
}

fn chamfer(out: &Path) -> f64 {
    let eval: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("eval.json")).unwrap()).unwrap();
    eval["mesh"]["metrics"]["chamfer_l1"].as_f64().unwrap_or_else(|| panic!("no chamfer in {eval}"))
}

/// `score --geometry`: the scene's own visible surface, moved by a known similarity, scores
/// Chamfer 0 once `--to-dataset` undoes it, and so does the same surface written in nerfstudio's
/// frame beside a `dataparser_transforms.json` with the default `--geometry-frame tool`; left in
/// that frame it is far from the scene (or refused as unseen), and a singular `--to-dataset` is
/// refused naming the option.
#[test]
fn score_geometry_moved_by_a_known_similarity_scores_chamfer_zero() {
    use glam::{DMat4, DQuat, DVec3};
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    test_support::render::quick_dataset(&test_support::scene("tabletop"), &data, 16, [3, 1, 2], 1);
    let ds = dataset::Dataset::load(&data).unwrap();
    let reference = eval::mesh_eval::scene_reference(&ds, None, &Default::default()).unwrap().unwrap();
    let d = data.to_str().unwrap();
    let samples = ["--geometry-samples", "20000"];

    // A plain folder of images, and the surface moved by S = T·R·(0.37).
    let pred = tmp.path().join("pred");
    std::fs::create_dir_all(&pred).unwrap();
    for k in 0..2 {
        std::fs::copy(data.join(format!("test/r_{k}.png")), pred.join(format!("r_{k}.png"))).unwrap();
    }
    let rotation = DQuat::from_axis_angle(DVec3::new(1.0, 2.0, 3.0).normalize(), 0.52);
    let s = DMat4::from_scale_rotation_translation(DVec3::splat(0.37), rotation, DVec3::new(0.4, -1.2, 2.5));
    let moved = tmp.path().join("moved.obj");
    write_moved_obj(&moved, &reference.mesh, s);
    let out = tmp.path().join("scored");
    let inverse = row_major(s.inverse());
    let mut args = vec!["score", d, pred.to_str().unwrap(), "--method", "m", "--out", out.to_str().unwrap(), "--geometry", moved.to_str().unwrap()];
    args.extend(["--to-dataset", &inverse]);
    args.extend(samples);
    let (code, stderr) = xtask(&args);
    assert_eq!(code, 0, "{stderr}");
    let c = chamfer(&out);
    assert!(c < 1e-5, "Chamfer {c} m after undoing the similarity");
    assert!(std::fs::read_to_string(out.join("report.md")).unwrap().contains("## Geometry"));

    // nerfstudio's layout: x_ns = scale · (R x + t), written to dataparser_transforms.json.
    let ns = tmp.path().join("ns");
    std::fs::create_dir_all(ns.join("test/rgb")).unwrap();
    for k in 0..2 {
        std::fs::copy(data.join(format!("test/r_{k}.png")), ns.join(format!("test/rgb/r_{k}.png"))).unwrap();
    }
    let (r, t, scale) = (glam::DMat3::from_quat(rotation), DVec3::new(-0.3, 0.2, 0.9), 0.41);
    let rows: Vec<[f64; 4]> = (0..3).map(|i| [r.row(i).x, r.row(i).y, r.row(i).z, t[i]]).collect();
    std::fs::write(ns.join("dataparser_transforms.json"), serde_json::json!({"transform": rows, "scale": scale}).to_string()).unwrap();
    let to_ns = DMat4::from_scale(DVec3::splat(scale)) * DMat4::from_translation(t) * DMat4::from_mat3(r);
    let in_ns = tmp.path().join("tsdf_mesh.obj");
    write_moved_obj(&in_ns, &reference.mesh, to_ns);
    let out_ns = tmp.path().join("scored-ns");
    let mut args = vec!["score", d, ns.to_str().unwrap(), "--method", "ns", "--out", out_ns.to_str().unwrap(), "--geometry", in_ns.to_str().unwrap()];
    args.extend(samples);
    let (code, stderr) = xtask(&args);
    assert_eq!(code, 0, "{stderr}");
    let c = chamfer(&out_ns);
    assert!(c < 1e-5, "Chamfer {c} m after undoing nerfstudio's transform");

    // Left in nerfstudio's frame, the surface is far from the scene or unseen.
    let out_raw = tmp.path().join("scored-raw");
    let mut args = vec!["score", d, ns.to_str().unwrap(), "--method", "raw", "--out", out_raw.to_str().unwrap(), "--geometry", in_ns.to_str().unwrap()];
    args.extend(["--geometry-frame", "dataset"]);
    args.extend(samples);
    let (code, stderr) = xtask(&args);
    if code == 0 {
        let c = chamfer(&out_raw);
        assert!(c > 0.05, "Chamfer {c} m with the transform left out");
    } else {
        assert!(stderr.contains("none of the mesh's") && stderr.contains("frame"), "{stderr}");
    }

    let bad = tmp.path().join("scored-bad");
    let mut args = vec!["score", d, pred.to_str().unwrap(), "--method", "m", "--out", bad.to_str().unwrap(), "--geometry", moved.to_str().unwrap()];
    args.extend(["--to-dataset", "0 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1"]);
    assert_refused(&args, "--to-dataset", &bad);
}

/// The supervision options are checked when parsed: a sparse or holes fraction outside
/// (0, 1], a negative sigma or weight, an unknown loss or source, and depth settings without
/// `--depth-loss`, and the normal term on the paper model are refused in one sentence naming
/// the option, before anything is written; a dataset without ground-truth depth (a Blender one) given `--depth-loss` or
/// `--empty-loss` or `--normal-loss` is refused naming the dataset.
#[test]
fn supervision_options_are_refused_naming_the_option_or_the_dataset() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let valid = dataset_corpus().join("valid_blender");
    let ds = valid.to_str().unwrap();
    let o = out.to_str().unwrap();
    for (args, what) in [
        (vec!["--depth-loss", "expected", "--depth-source", "sparse:0"], "--depth-source"),
        (vec!["--depth-loss", "expected", "--depth-source", "sparse:1.5"], "the fraction must be in (0, 1]"),
        (vec!["--depth-loss", "expected", "--depth-source", "holes:-0.3"], "--depth-source"),
        (vec!["--depth-loss", "expected", "--depth-source", "noisy:-0.01"], "the relative standard deviation must be a finite number ≥ 0"),
        (vec!["--depth-loss", "expected", "--depth-source", "lidar"], "unknown depth source"),
        (vec!["--depth-loss", "median"], "--depth-loss"),
        (vec!["--depth-loss", "expected", "--depth-weight", "-1"], "--depth-weight"),
        (vec!["--empty-loss", "nan"], "--empty-loss"),
        (vec!["--normal-loss", "-0.1"], "--normal-loss"),
        (vec!["--model", "paper", "--normal-loss", "0.1"], "built for the hash-grid models (fast, auto), not the paper model"),
        (vec!["--depth-loss", "expected", "--depth-half-life", "0"], "--depth-half-life"),
        (vec!["--depth-source", "noisy:0.01"], "--depth-source sets the depth term, which is off"),
        (vec!["--pose-noise", "50,0"], "--pose-noise"),
        (vec!["--pose-noise", "1,2"], "100 % of the scene size"),
        (vec!["--pose-noise", "-1,0"], "--pose-noise"),
        (vec!["--pose-noise", "nan,0.01"], "the rotation 'nan' is not a finite number ≥ 0"),
        (vec!["--pose-noise", "1"], "ROT_DEG,TRANS_REL"),
        (vec!["--camera-opt", "so3"], "--camera-opt"),
    ] {
        let mut a = vec!["train", ds, "--out", o, "--steps", "2"];
        a.extend(args);
        let err = assert_refused(&a, what, &out);
        assert_eq!(err.lines().filter(|l| l.starts_with("error")).count(), 1, "{a:?}: {err}");
    }
    for opt in [["--depth-loss", "expected"], ["--empty-loss", "0.1"], ["--normal-loss", "0.1"]] {
        let mut a = vec!["train", ds, "--out", o, "--steps", "2"];
        a.extend(opt);
        let err = assert_refused(&a, &format!("the dataset has no ground-truth depth and alpha files (gt_file_path, r_<k>_gt.exr) for its train views, which {} needs", opt[0]), &out);
        assert!(err.contains("valid_blender"), "{err}");
    }
}
