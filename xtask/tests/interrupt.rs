//! Interrupted work: `xtask render` killed with SIGKILL at seeded random moments, then re-run
//! until it completes, must leave exactly the dataset an uninterrupted run writes (byte for
//! byte), no temporary files, and at every kill point only complete files under final names.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn xtask() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_xtask"));
    c.stdout(Stdio::null()).stderr(Stdio::null());
    c
}

fn scene() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell.gltf")
}

fn render_cmd(out: &Path) -> Command {
    let mut c = xtask();
    c.arg("render").arg(scene()).arg("--out").arg(out);
    c.args(["--res", "32", "--train", "12", "--val", "2", "--test", "2", "--spp", "8"]);
    c
}

use test_support::files;

fn is_temporary(rel: &str) -> bool {
    let name = Path::new(rel).file_name().unwrap().to_string_lossy().into_owned();
    name.starts_with('.') && name.ends_with(".tmp")
}

/// A `.npy` file is complete: magic, a header, and as many data bytes as its shape and dtype say.
fn npy_complete(bytes: &[u8]) -> Result<(), String> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err("no npy magic".into());
    }
    let (hlen, start) = if bytes[6] == 1 { (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10) } else { (u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize, 12) };
    let header = std::str::from_utf8(bytes.get(start..start + hlen).ok_or("truncated header")?).map_err(|e| e.to_string())?;
    let item: usize = header.split("'descr': '").nth(1).and_then(|s| s.get(2..3)).and_then(|s| s.parse().ok()).ok_or("no descr")?;
    let shape = header.split("'shape': (").nth(1).and_then(|s| s.split(')').next()).ok_or("no shape")?;
    let count: usize = shape.split(',').filter(|s| !s.trim().is_empty()).map(|s| s.trim().parse::<usize>().unwrap()).product();
    let want = start + hlen + count * item;
    if bytes.len() != want { Err(format!("{} bytes, header says {want}", bytes.len())) } else { Ok(()) }
}

/// Every file under a final name is complete and readable.
fn check_final_files_readable(dir: &Path, when: &str) -> usize {
    let mut checked = 0;
    for (rel, bytes) in files(dir) {
        if is_temporary(&rel) {
            continue;
        }
        let p = dir.join(&rel);
        let r: Result<(), String> = if rel.ends_with("_gt.exr") {
            dataset::read_ground_truth(&p).map(|_| ()).map_err(|e| e.to_string())
        } else if rel.ends_with(".exr") {
            dataset::read_exr_rgba(&p).map(|_| ()).map_err(|e| e.to_string())
        } else if rel.ends_with(".png") {
            dataset::read_png_rgba(&p).map(|_| ()).map_err(|e| e.to_string())
        } else if rel.ends_with(".json") {
            serde_json::from_slice::<serde_json::Value>(&bytes).map(|_| ()).map_err(|e| e.to_string())
        } else if rel.ends_with(".npy") {
            npy_complete(&bytes)
        } else {
            Ok(())
        };
        if let Err(e) = r {
            panic!("{when}: {rel} has a final name but is unreadable: {e}");
        }
        checked += 1;
    }
    checked
}

/// SplitMix64: the kill moments are random but the same on every run of the test.
fn splitmix(state: &mut u64) -> f64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    (z ^ (z >> 31)) as f64 / u64::MAX as f64
}

#[test]
fn render_killed_at_random_moments_resumes_to_the_identical_dataset() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));

    let t0 = Instant::now();
    assert!(render_cmd(&a).status().unwrap().success(), "uninterrupted render failed");
    let full = t0.elapsed();
    let reference = files(&a);
    assert!(reference.iter().all(|(rel, _)| !is_temporary(rel)), "temporary files left by the uninterrupted run");

    // Kill points spread over what is left of the run: a random fraction of the uninterrupted
    // run's duration times the fraction of views still to render (a resumed run is shorter).
    let views = reference.iter().filter(|(rel, _)| rel.ends_with(".png")).count();
    let mut state = 0x5EED_u64;
    let mut kills = 0;
    let mut partial_states = 0;
    for round in 0..6 {
        let done = files(&b).iter().filter(|(rel, _)| rel.ends_with(".png")).count();
        let left = 1.0 - done as f64 / views as f64;
        let at = full.mul_f64((0.1 + 0.8 * splitmix(&mut state)) * left.max(0.2));
        // Waited for below: by `try_wait` when it finishes, else after the kill.
        #[allow(clippy::zombie_processes)]
        let mut child = render_cmd(&b).spawn().unwrap();
        let deadline = Instant::now() + at;
        let mut finished = None;
        while Instant::now() < deadline {
            if let Some(st) = child.try_wait().unwrap() {
                finished = Some(st);
                break;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        if finished.is_none() {
            child.kill().unwrap(); // SIGKILL on Unix
            child.wait().unwrap();
            kills += 1;
        }
        let n = check_final_files_readable(&b, &format!("round {round}, killed after {at:?}"));
        if n > 0 && n < reference.len() {
            partial_states += 1;
        }
    }
    // Then re-run until it completes.
    let mut runs = 0;
    loop {
        runs += 1;
        assert!(runs <= 3, "render did not complete after resuming");
        if render_cmd(&b).status().unwrap().success() {
            break;
        }
    }
    assert!(kills >= 3, "only {kills} of the runs were still going when killed (full run {full:?})");
    assert!(partial_states >= 1, "no kill left a partial dataset to resume (full run {full:?})");

    let resumed = files(&b);
    let temps: Vec<_> = resumed.iter().filter(|(rel, _)| is_temporary(rel)).map(|(rel, _)| rel.clone()).collect();
    assert!(temps.is_empty(), "temporary files left after completion: {temps:?}");
    let names = |v: &[(String, Vec<u8>)]| v.iter().map(|(r, _)| r.clone()).collect::<Vec<_>>();
    assert_eq!(names(&resumed), names(&reference), "file lists differ");
    for ((rel, x), (_, y)) in reference.iter().zip(&resumed) {
        assert!(x == y, "{rel} differs from the uninterrupted run's");
    }
}
