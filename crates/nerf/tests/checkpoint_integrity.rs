//! Checkpoints verify themselves: a checksum over header and data, finite parameters, header
//! scalars and array lengths checked before use, and a damaged latest checkpoint that names the
//! previous good one. Checkpoints written before the checksum existed still load.

use nerf::checkpoint::{self, CheckpointError, StateDict};
use nerf::models::ModelConfig;
use nerf::train::{TrainConfig, Trainer};
use std::path::Path;
use test_support::training::{run_to_end, synthetic_dataset, tiny_fast};

fn sample() -> StateDict {
    let mut s = StateDict::default();
    s.scalars.insert("trainer.step".into(), 12.0);
    s.arrays.insert("a".into(), vec![1.0, -2.5, f32::MIN_POSITIVE]);
    s.arrays.insert("b".into(), vec![0.25; 5]);
    s
}

/// The bytes as checkpoints were written before the checksum: magic, header length, JSON
/// header, arrays.
fn legacy_bytes(header: &str, data: &[f32]) -> Vec<u8> {
    let mut out = b"NERFCKPT".to_vec();
    out.extend_from_slice(&(header.len() as u64).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for x in data {
        out.extend_from_slice(&x.to_le_bytes());
    }
    out
}

fn corrupt_message(r: Result<StateDict, CheckpointError>) -> String {
    match r {
        Err(e @ CheckpointError::Corrupt { .. }) => e.to_string(),
        other => panic!("expected Corrupt, got {other:?}"),
    }
}

#[test]
fn new_format_is_the_old_bytes_plus_a_checksum_trailer() {
    let s = sample();
    let header = r#"{"scalars":{"trainer.step":12.0},"arrays":[["a",3],["b",5]]}"#;
    let data: Vec<f32> = s.arrays.values().flatten().copied().collect();
    let old = legacy_bytes(header, &data);
    let new = s.to_bytes();
    assert_eq!(&new[..old.len()], &old[..]);
    assert_eq!(new.len(), old.len() + 16);
}

#[test]
fn legacy_checkpoint_without_checksum_loads() {
    let s = sample();
    let header = r#"{"scalars":{"trainer.step":12.0},"arrays":[["a",3],["b",5]]}"#;
    let data: Vec<f32> = s.arrays.values().flatten().copied().collect();
    assert_eq!(StateDict::from_bytes(Path::new("old.ckpt"), &legacy_bytes(header, &data)).unwrap(), s);
}

#[test]
fn a_flipped_bit_in_header_or_data_is_refused_naming_the_file() {
    let b = sample().to_bytes();
    // A bit of a data value, of a header digit, and of the checksum itself.
    let header_digit = 16 + b[16..].iter().position(|c| *c == b'1').unwrap();
    for at in [b.len() - 20, header_digit, b.len() - 1] {
        let mut bad = b.clone();
        bad[at] ^= 0x01;
        let m = corrupt_message(StateDict::from_bytes(Path::new("run/checkpoints/step-00000012.ckpt"), &bad));
        assert!(m.contains("step-00000012.ckpt") && m.contains("checksum"), "{m}");
    }
}

#[test]
fn non_finite_parameters_are_refused_naming_the_array() {
    for v in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        let mut s = sample();
        s.arrays.insert("field.weights".into(), vec![0.0, v]);
        let m = corrupt_message(StateDict::from_bytes(Path::new("x.ckpt"), &s.to_bytes()));
        assert!(m.contains("field.weights") && m.contains("non-finite"), "{m}");
        // The same in a checkpoint written before the checksum.
        let header = r#"{"scalars":{},"arrays":[["field.weights",2]]}"#;
        let m = corrupt_message(StateDict::from_bytes(Path::new("x.ckpt"), &legacy_bytes(header, &[0.0, v])));
        assert!(m.contains("field.weights"), "{m}");
    }
}

#[test]
fn a_huge_array_length_is_refused_without_overflow() {
    for len in [1u64 << 62, (1u64 << 62) + 1, u64::MAX / 4 + 1, u64::MAX] {
        let header = format!(r#"{{"scalars":{{}},"arrays":[["a",{len}]]}}"#);
        let m = corrupt_message(StateDict::from_bytes(Path::new("x.ckpt"), &legacy_bytes(&header, &[1.0, 2.0])));
        assert!(m.contains("'a'"), "{m}");
    }
}

#[test]
fn counts_must_be_non_negative_integers() {
    let mut s = StateDict::default();
    for (v, ok) in [(0.0, true), (12.0, true), (9007199254740992.0, true), (1e308, false), (-1.0, false), (2.5, false), (f64::NAN, false), (f64::INFINITY, false)] {
        s.scalars.insert("trainer.step".into(), v);
        let r = s.count("trainer.step");
        assert_eq!(r.is_ok(), ok, "{v}: {r:?}");
        if let Err(m) = r {
            assert!(m.contains("trainer.step"), "{m}");
        }
    }
    assert!(s.count("missing").unwrap_err().contains("missing"));
}

fn config(data: &Path) -> TrainConfig {
    TrainConfig::new(data.to_path_buf(), ModelConfig::Fast(tiny_fast(8, 4)), 64, 1e-2, 1e-3, 100)
        .with_steps(Some(12))
        .with_log_interval_steps(4)
        .with_checkpoint_interval_steps(4)
        .with_val_max_pixels(64)
}

/// Rewrites a checkpoint with one scalar changed (as a hostile or damaged file would hold it,
/// with a valid checksum).
fn rewrite_scalar(path: &Path, name: &str, v: f64) {
    let mut s = checkpoint::load(path).unwrap();
    s.scalars.insert(name.into(), v);
    std::fs::write(path, s.to_bytes()).unwrap();
}

#[test]
fn resume_refuses_a_step_that_is_not_a_count() {
    let (tmp, data) = synthetic_dataset(12, [3, 1, 1]);
    let run = tmp.path().join("run");
    let mut t = Trainer::new(config(&data), &run, false).unwrap();
    run_to_end(&mut t);
    drop(t);
    let latest = checkpoint::latest(&run).unwrap();
    let good = std::fs::read(&latest).unwrap();
    for v in [1e308, -3.0, 7.5] {
        rewrite_scalar(&latest, "trainer.step", v);
        let e = Trainer::resume(&run).err().expect("resume accepted a bad step").to_string();
        assert!(e.contains("trainer.step"), "{e}");
        let e = nerf::render::RunModel::load(&run).err().expect("load accepted a bad step").to_string();
        assert!(e.contains("trainer.step"), "{e}");
    }
    std::fs::write(&latest, &good).unwrap();
    assert_eq!(Trainer::resume(&run).unwrap().step, 12);
}

#[test]
fn a_damaged_latest_checkpoint_names_the_previous_good_one() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path();
    let s = sample();
    let p1 = checkpoint::save(run, 4, &s, 3).unwrap();
    let p2 = checkpoint::save(run, 8, &s, 3).unwrap();
    let p3 = checkpoint::save(run, 12, &s, 3).unwrap();
    // The newest is damaged; the one before it too: the error names the newest good one.
    for p in [&p3, &p2] {
        let mut b = std::fs::read(p).unwrap();
        let n = b.len();
        b[n - 20] ^= 0x40;
        std::fs::write(p, b).unwrap();
    }
    let e = checkpoint::load_latest(run).err().expect("damaged checkpoint loaded").to_string();
    let name = |p: &Path| p.file_name().unwrap().to_string_lossy().into_owned();
    assert!(e.contains(&name(&p3)) && e.contains(&name(&p1)), "{e}");
    // On request, the newest checkpoint that loads.
    let (p, loaded, skipped) = checkpoint::load_latest_good(run).unwrap();
    assert_eq!((p, loaded), (p1.clone(), s));
    assert_eq!(skipped.len(), 2);
    // Nothing good: the plain error.
    std::fs::write(&p1, b"junk").unwrap();
    assert!(checkpoint::load_latest(run).err().unwrap().to_string().contains(&name(&p3)));
    assert!(checkpoint::load_latest_good(run).is_err());
}
