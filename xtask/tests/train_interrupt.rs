//! Interrupted training: `xtask train` killed with SIGKILL at seeded points (between
//! checkpoints, just after a checkpoint appears, after a few metric lines) and resumed with
//! `--resume` until it completes must end exactly where an uninterrupted run with the same
//! seed and step budget ends: the same training and validation metric lines, the same final
//! checkpoint parameters and optimiser state. At every kill point each file under a final name
//! is complete (config.json and every checkpoint load, every metrics line parses), and no
//! temporary file is left once the run completes.

use nerf::train::TrainConfig;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const STEPS: u64 = 480;
const CHECKPOINT_EVERY: u64 = 80;

fn xtask() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_xtask"));
    c.stdout(Stdio::null()).stderr(Stdio::null());
    c
}

/// A small fast model on the analytic dataset, stopped by a step count, validated only at the
/// end (validation during training is on the wall clock, so it would differ between runs).
fn write_config(dir: &Path) -> PathBuf {
    test_support::training::write_cli_config(dir, STEPS, CHECKPOINT_EVERY)
}

fn fresh(config: &Path, run: &Path) -> Command {
    let mut c = xtask();
    c.arg("train").arg("--config").arg(config).arg("--out").arg(run);
    c
}

fn resume(run: &Path) -> Command {
    let mut c = xtask();
    c.arg("train").arg("--out").arg(run).arg("--resume");
    c
}

fn files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else { continue };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() { stack.push(p) } else { out.push(p) }
        }
    }
    out.sort();
    out
}

fn is_temporary(p: &Path) -> bool {
    let name = p.file_name().unwrap().to_string_lossy();
    name.starts_with('.') && name.ends_with(".tmp")
}

/// Steps of the checkpoints in the run folder.
fn checkpoints(run: &Path) -> Vec<u64> {
    let mut v: Vec<u64> = files(&run.join("checkpoints"))
        .iter()
        .filter_map(|p| p.file_name()?.to_str()?.strip_prefix("step-")?.strip_suffix(".ckpt")?.parse().ok())
        .collect();
    v.sort();
    v
}

fn metric_lines(run: &Path) -> usize {
    std::fs::read_to_string(run.join("metrics.jsonl")).map_or(0, |t| t.lines().count())
}

/// Every file under a final name is complete: the config parses as a training config, every
/// checkpoint loads, every metrics line is a JSON object with a step; nothing else is there but
/// the folder lock a killed run leaves (it holds nothing once its process is gone). Returns the
/// number of final files.
fn check_final_files(run: &Path, when: &str) -> usize {
    let mut n = 0;
    for p in files(run) {
        if is_temporary(&p) || p == run.join(dataset::lock::LOCK_FILE) {
            continue;
        }
        let rel = p.strip_prefix(run).unwrap().display().to_string();
        let r: Result<(), String> = match rel.as_str() {
            "config.json" => TrainConfig::read(&p).map(|_| ()).map_err(|e| e.to_string()),
            "metrics.jsonl" => std::fs::read_to_string(&p).map_err(|e| e.to_string()).and_then(|t| {
                t.lines().enumerate().try_for_each(|(k, l)| {
                    let v: serde_json::Value = serde_json::from_str(l).map_err(|e| format!("line {}: {e}", k + 1))?;
                    v.get("step").and_then(|s| s.as_u64()).map(|_| ()).ok_or(format!("line {}: no step", k + 1))
                })
            }),
            r if r.starts_with("checkpoints/step-") && r.ends_with(".ckpt") => {
                nerf::checkpoint::load(&p).map(|_| ()).map_err(|e| e.to_string())
            }
            _ => Err("unexpected file".into()),
        };
        if let Err(e) = r {
            panic!("{when}: {rel} has a final name but is not complete: {e}");
        }
        n += 1;
    }
    n
}

/// The deterministic content of metrics.jsonl: every field except the clocks and speeds.
fn metrics(run: &Path) -> Vec<String> {
    std::fs::read_to_string(run.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| {
            let mut v: serde_json::Value = serde_json::from_str(l).unwrap();
            let o = v.as_object_mut().unwrap();
            for k in ["wall_s", "rays_per_s", "eval_s"] {
                o.remove(k);
            }
            v.to_string()
        })
        .collect()
}

/// The final checkpoint's arrays and its scalars except the training clock.
fn final_state(run: &Path) -> (u64, nerf::checkpoint::StateDict) {
    let step = *checkpoints(run).last().expect("no checkpoint");
    let (_, mut s) = nerf::checkpoint::load_latest(run).unwrap();
    for k in ["trainer.wall_s", "trainer.window.time"] {
        s.scalars.remove(k);
    }
    (step, s)
}

/// SplitMix64: the kill points are random but the same on every run of the test.
fn splitmix(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// When to kill a run.
#[derive(Debug, Clone, Copy)]
enum KillPoint {
    /// As soon as a checkpoint newer than those present at the start appears.
    NewCheckpoint,
    /// This fraction of the time between two checkpoints after a new checkpoint appears
    /// (between checkpoints: the metric lines written after it must be dropped on resume).
    AfterNewCheckpoint(f64),
    /// Once this many metric lines were added past what the folder had at the start.
    MetricLines(usize),
}

/// Runs `cmd` until `point` is reached, then SIGKILLs it; returns whether it was killed
/// (false: it completed first).
/// `between` is the time between two checkpoints.
fn run_and_kill(mut cmd: Command, run: &Path, point: KillPoint, between: Duration) -> bool {
    let start_ckpt = checkpoints(run).last().copied();
    let start_lines = metric_lines(run);
    let mut child = cmd.spawn().unwrap();
    let deadline = Instant::now() + Duration::from_secs(120);
    let mut seen_ckpt: Option<Instant> = None;
    loop {
        if let Some(st) = child.try_wait().unwrap() {
            assert!(st.success(), "train exited with {st} before the kill point {point:?}");
            return false;
        }
        assert!(Instant::now() < deadline, "train ran for two minutes without reaching {point:?}");
        let new_ckpt = checkpoints(run).last().copied() > start_ckpt;
        if new_ckpt && seen_ckpt.is_none() {
            seen_ckpt = Some(Instant::now());
        }
        let reached = match point {
            KillPoint::NewCheckpoint => new_ckpt,
            KillPoint::AfterNewCheckpoint(f) => seen_ckpt.is_some_and(|t| t.elapsed() >= between.mul_f64(f)),
            KillPoint::MetricLines(n) => metric_lines(run) >= start_lines + n,
        };
        if reached {
            child.kill().unwrap(); // SIGKILL on Unix
            child.wait().unwrap();
            return true;
        }
        std::thread::sleep(Duration::from_micros(500));
    }
}

#[test]
fn train_killed_at_seeded_points_resumes_to_the_uninterrupted_result() {
    let tmp = tempfile::tempdir().unwrap();
    let config = write_config(tmp.path());
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));

    let t0 = Instant::now();
    assert!(fresh(&config, &a).status().unwrap().success(), "uninterrupted run failed");
    let full = t0.elapsed();
    // Checkpoint to checkpoint, startup included (so a little less in fact).
    let between = full.mul_f64(CHECKPOINT_EVERY as f64 / STEPS as f64);
    eprintln!("uninterrupted run: {:.1}s", full.as_secs_f64());
    assert_eq!(check_final_files(&a, "uninterrupted"), 4, "config, metrics and the 2 kept checkpoints");
    assert!(files(&a).iter().all(|p| !is_temporary(p)), "temporary files left by the uninterrupted run");

    // Kill points: the first run when metric lines appear (before any checkpoint: resuming then
    // starts again from step 0), then seeded choices of the three kinds, then at every further
    // checkpoint.
    let mut state = 0x7EA1_u64;
    let mut points = vec![KillPoint::MetricLines(2)];
    for _ in 0..4 {
        points.push(match splitmix(&mut state) % 3 {
            0 => KillPoint::NewCheckpoint,
            1 => KillPoint::AfterNewCheckpoint((splitmix(&mut state) % 900) as f64 / 1000.0),
            _ => KillPoint::MetricLines(1 + (splitmix(&mut state) % 5) as usize),
        });
    }
    let mut kills = 0;
    let mut resumed_from = Vec::new();
    for (round, &point) in points.iter().enumerate() {
        let cmd = if round == 0 { fresh(&config, &b) } else { resume(&b) };
        resumed_from.push(checkpoints(&b).last().copied().unwrap_or(0));
        if run_and_kill(cmd, &b, point, between) {
            kills += 1;
        }
        check_final_files(&b, &format!("round {round}, killed at {point:?}"));
        if checkpoints(&b).last() == Some(&STEPS) {
            break;
        }
    }
    // Then killed as soon as each further checkpoint appears, the final one included (its
    // validation line may or may not be written yet), and resumed until it completes.
    let mut rounds = 0;
    while checkpoints(&b).last() != Some(&STEPS) {
        rounds += 1;
        assert!(rounds <= STEPS / CHECKPOINT_EVERY, "no progress from checkpoint to checkpoint");
        resumed_from.push(checkpoints(&b).last().copied().unwrap_or(0));
        if run_and_kill(resume(&b), &b, KillPoint::NewCheckpoint, between) {
            kills += 1;
        }
        check_final_files(&b, &format!("killed at a new checkpoint after {resumed_from:?}"));
    }
    let mut runs = 0;
    while checkpoints(&b).last() != Some(&STEPS) || metrics(&b).len() != metrics(&a).len() {
        runs += 1;
        assert!(runs <= 2, "resumed run did not complete");
        assert!(resume(&b).status().unwrap().success(), "resumed run failed");
    }
    eprintln!("kill points {points:?}: {kills} kills, resumed from checkpoints {resumed_from:?}, {:.1}s in all", t0.elapsed().as_secs_f64());
    assert!(kills >= 4, "only {kills} runs were killed");
    assert!(resumed_from.iter().filter(|&&s| s > 0).count() >= 2, "too few resumes from a checkpoint: {resumed_from:?}");

    check_final_files(&b, "after completion");
    let temps: Vec<_> = files(&b).into_iter().filter(|p| is_temporary(p)).collect();
    assert!(temps.is_empty(), "temporary files left after completion: {temps:?}");
    // The lock file of a run killed last (when it had finished all but exiting) is left; an
    // uninterrupted run leaves none.
    let lock = Path::new(dataset::lock::LOCK_FILE);
    let names = |d: &Path| files(d).iter().map(|p| p.strip_prefix(d).unwrap().to_path_buf()).filter(|p| p != lock).collect::<Vec<_>>();
    assert!(!a.join(lock).exists(), "the uninterrupted run left its lock file");
    assert_eq!(names(&a), names(&b), "run folders hold different files");
    assert_eq!(std::fs::read(a.join("config.json")).unwrap(), std::fs::read(b.join("config.json")).unwrap());
    let (ma, mb) = (metrics(&a), metrics(&b));
    assert!(ma.last().unwrap().contains("val_psnr"), "the run ends with a validation line");
    assert_eq!(ma.len(), mb.len(), "metric line counts differ:\n{}\nvs\n{}", ma.join("\n"), mb.join("\n"));
    for (k, (x, y)) in ma.iter().zip(&mb).enumerate() {
        assert_eq!(x, y, "metrics line {} differs", k + 1);
    }
    let (sa, sb) = (final_state(&a), final_state(&b));
    assert_eq!(sa.0, STEPS);
    assert_eq!(sa.1.scalars, sb.1.scalars, "final checkpoint scalars differ");
    assert_eq!(sa.1.arrays.keys().collect::<Vec<_>>(), sb.1.arrays.keys().collect::<Vec<_>>());
    for (k, v) in &sa.1.arrays {
        assert!(v == &sb.1.arrays[k], "final checkpoint array {k} differs");
    }
}
