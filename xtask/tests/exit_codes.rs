//! The exit codes a scheduler reads (xtask/src/exit.rs): 1 for a refusal, 74 when this node's
//! storage fails under a real write (a file-size limit the kernel enforces, an unwritable
//! folder), 130 for a render stopped by SIGTERM with its finished views kept.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

fn xtask() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_xtask"));
    c.stdin(Stdio::null());
    c
}

fn scene() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell.gltf")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A small render of cornell into `out`, as arguments after `xtask`.
fn render_args(out: &Path, res: u32) -> Vec<String> {
    let out = out.to_string_lossy().into_owned();
    let res = res.to_string();
    let scene = scene().to_string_lossy().into_owned();
    ["render", &scene, "--out", &out, "--res", &res, "--train", "1", "--val", "1", "--test", "1", "--spp", "1"].map(String::from).to_vec()
}

/// Files under `dir` whose name marks an atomic write's temporary.
fn temporaries(dir: &Path) -> Vec<String> {
    test_support::files(dir).into_iter().map(|(rel, _)| rel).filter(|rel| rel.rsplit('/').next().is_some_and(|n| n.starts_with('.') && n.ends_with(".tmp"))).collect()
}

#[test]
fn a_bad_option_exits_1() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("ds");
    let mut args = render_args(&out, 8);
    args.extend(["--spp", "0"].map(String::from));
    let o = xtask().args(&args).output().unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let o = xtask().args(["render", "--no-such-option"]).output().unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(!out.exists());
}

/// A write that the kernel cuts short (`ulimit -f`: the file-size limit applies to every user,
/// root too; with SIGXFSZ ignored the write fails with EFBIG, as with a quota): exit code 74,
/// a message naming the file, no temporary left behind.
#[test]
fn a_write_the_node_cannot_complete_exits_74() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("ds");
    // 16 blocks (8 KiB in dash's 512-byte blocks, 16 KiB in bash's 1024): render_config.json
    // fits, a 64 x 64 view's depth array (16 KiB of floats and a header) does not.
    let script = r#"ulimit -f 16 && trap '' XFSZ && exec "$0" "$@""#;
    let o = Command::new("sh").arg("-c").arg(script).arg(env!("CARGO_BIN_EXE_xtask")).args(render_args(&out, 64)).stdin(Stdio::null()).output().unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(74), "{err}");
    assert!(err.contains("File too large") && err.contains(&*out.to_string_lossy()), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(temporaries(&out), Vec::<String>::new());
}

/// `--out` inside a folder this user cannot write: exit code 74. Root (or a process with
/// CAP_DAC_OVERRIDE) writes there anyway, so it runs xtask as `nobody` through `setpriv`; where
/// that is not possible the case is skipped, with the reason printed, and the classification of
/// EACCES on writing is left to xtask's unit tests.
#[test]
fn an_unwritable_output_folder_exits_74() {
    use std::os::unix::fs::PermissionsExt;
    let mode = |p: &Path, m: u32| std::fs::set_permissions(p, std::fs::Permissions::from_mode(m)).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    mode(tmp.path(), 0o755);
    let locked = tmp.path().join("locked");
    std::fs::create_dir(&locked).unwrap();
    mode(&locked, 0o555);
    let privileged = std::fs::write(locked.join("probe"), b"").is_ok();
    let _ = std::fs::remove_file(locked.join("probe"));
    let command = || {
        if !privileged {
            return xtask();
        }
        let mut c = Command::new("setpriv");
        c.args(["--reuid=65534", "--regid=65534", "--clear-groups", env!("CARGO_BIN_EXE_xtask")]).stdin(Stdio::null());
        c
    };
    if privileged {
        // As `nobody`, a render into a folder anyone may write must work, or the case proves nothing.
        let open = tmp.path().join("open");
        std::fs::create_dir(&open).unwrap();
        mode(&open, 0o777);
        match command().args(render_args(&open.join("ds"), 8)).output() {
            Ok(o) if o.status.success() => {}
            Ok(o) => {
                eprintln!("skipped: this process writes into a mode 555 folder, and as nobody xtask cannot render ({})", stderr(&o).trim());
                return;
            }
            Err(e) => {
                eprintln!("skipped: this process writes into a mode 555 folder, and setpriv cannot run ({e})");
                return;
            }
        }
    }
    let out = locked.join("ds");
    let o = command().args(render_args(&out, 8)).output().unwrap();
    let err = stderr(&o);
    mode(&locked, 0o755);
    assert_eq!(o.status.code(), Some(74), "{err}");
    assert!(err.contains("ermission denied") && err.contains(&*out.to_string_lossy()), "{err}");
    assert!(!out.exists());
}

/// SIGTERM (how Ray stops a task) during a render: the finished views are kept and the exit
/// code is 130, not the refusal's 1, so a scheduler retries (and the retry resumes).
#[test]
fn a_render_stopped_by_sigterm_exits_130() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("ds");
    let mut args = render_args(&out, 32);
    for (flag, v) in [("--train", "300"), ("--spp", "32"), ("--threads", "1")] {
        let i = args.iter().position(|a| a == flag);
        match i {
            Some(i) => args[i + 1] = v.into(),
            None => args.extend([flag.to_string(), v.to_string()]),
        }
    }
    let child = xtask().args(&args).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
    let deadline = Instant::now() + Duration::from_secs(120);
    while !out.join("train/r_0.png").exists() {
        assert!(Instant::now() < deadline, "no view rendered in two minutes");
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(Command::new("kill").arg("-TERM").arg(child.id().to_string()).status().unwrap().success());
    let o = child.wait_with_output().unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(130), "{err}");
    assert!(err.contains("stopped: interrupted after") && err.contains("re-run the same command to resume"), "{err}");
    assert!(!out.join("transforms_train.json").exists(), "the render finished before the signal: the test proved nothing");
}
