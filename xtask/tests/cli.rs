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
