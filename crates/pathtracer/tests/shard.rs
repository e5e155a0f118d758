//! Sharded rendering: three shards merged give a folder byte-identical to the unsharded
//! render; overlapping, missing, unfinished and mismatched shards are refused with the shard
//! named and nothing written.

use pathtracer::dataset_render::{DatasetRenderConfig, Preset, RunOptions, render_dataset};
use pathtracer::shard::{Shard, merge_shards, render_shard};
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

fn scene() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/tabletop.gltf")
}

fn config() -> DatasetRenderConfig {
    DatasetRenderConfig { width: 16, height: 12, train: 5, val: 2, test: 2, spp: 2, ..DatasetRenderConfig::preset(Preset::Quick) }
}

use test_support::file_map as files;

fn shard(cfg: &DatasetRenderConfig, out: &Path, s: &str) {
    let opts = RunOptions { threads: Some(1), force: false, allow_outside: false };
    render_shard(&scene(), out, cfg, &opts, s.parse().unwrap(), &mut |_| {}, &AtomicBool::new(false)).unwrap();
}

#[test]
fn three_shards_merge_into_the_unsharded_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = config();
    let whole = tmp.path().join("whole");
    render_dataset(&scene(), &whole, &cfg, &RunOptions { threads: None, force: false, allow_outside: false }, &mut |_| {}, &AtomicBool::new(false)).unwrap();
    let dirs: Vec<PathBuf> = (0..3).map(|k| tmp.path().join(format!("shard{k}"))).collect();
    for (k, d) in dirs.iter().enumerate() {
        shard(&cfg, d, &format!("{k}/3"));
        // A shard holds its own views only (9 views: 3 each), no transforms.
        let f = files(d);
        assert_eq!(f.keys().filter(|n| n.ends_with("_gt.exr")).count(), 3, "{:?}", f.keys());
        assert!(!f.contains_key("transforms_train.json") && f.contains_key("shard.json"));
    }
    let merged = tmp.path().join("merged");
    // The full-size copy a killed merge left (its pid no longer runs) is removed; the rest of
    // the folder is not touched.
    let dead = if Path::new("/proc/self").exists() { 0 } else { 1 };
    let stale = tmp.path().join(format!(".merged.merge.{dead}.tmp"));
    std::fs::create_dir_all(stale.join("train")).unwrap();
    std::fs::write(stale.join("train/r_0.png"), b"half").unwrap();
    let other = tmp.path().join(format!(".other.merge.{dead}.tmp"));
    std::fs::create_dir_all(&other).unwrap();
    // Given out of order: the order of the folders does not matter.
    let sum = merge_shards(&[dirs[2].clone(), dirs[0].clone(), dirs[1].clone()], &merged, None).unwrap();
    assert!(!stale.exists() && other.exists(), "the stale merge folder was kept, or another one removed");
    assert_eq!(sum.views_total, 9);
    let (a, b) = (files(&whole), files(&merged));
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for suffix in ["_ids.png", "_material.png", "_coverage.npy"] {
        assert_eq!(a.keys().filter(|n| n.ends_with(suffix)).count(), 9, "every view has its {suffix} file");
    }
    for (name, bytes) in &a {
        assert!(bytes == &b[name], "{name} differs between the unsharded and the merged dataset");
    }
}

#[test]
fn bad_shard_sets_are_refused_and_nothing_is_written() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = config();
    let dirs: Vec<PathBuf> = (0..2).map(|k| tmp.path().join(format!("s{k}"))).collect();
    shard(&cfg, &dirs[0], "0/2");
    shard(&cfg, &dirs[1], "1/2");
    let other = tmp.path().join("other");
    shard(&DatasetRenderConfig { spp: 3, ..cfg.clone() }, &other, "1/2");
    let three = tmp.path().join("three");
    shard(&cfg, &three, "2/3");
    let unfinished = tmp.path().join("unfinished");
    shard(&cfg, &unfinished, "1/2");
    std::fs::remove_file(unfinished.join("shard.json")).unwrap();
    let incomplete = tmp.path().join("incomplete");
    shard(&cfg, &incomplete, "1/2");
    std::fs::remove_file(incomplete.join("val/r_0.png")).unwrap();
    let damaged = tmp.path().join("damaged");
    shard(&cfg, &damaged, "1/2");
    let exr = std::fs::read(damaged.join("val/r_0.exr")).unwrap();
    std::fs::write(damaged.join("val/r_0.exr"), &exr[..40]).unwrap();

    let out = tmp.path().join("out");
    let cases: Vec<(Vec<PathBuf>, &str)> = vec![
        (vec![dirs[0].clone()], "shard 1/2 missing"),
        (vec![dirs[0].clone(), dirs[0].clone()], "shard 0/2 is given twice"),
        (vec![dirs[0].clone(), other.clone()], "shard 1/2 ("),
        (vec![dirs[0].clone(), three.clone()], "is one of 3 shards"),
        (vec![dirs[0].clone(), unfinished.clone()], "has not finished"),
        (vec![dirs[0].clone(), incomplete.clone()], "lacks val/r_0.png"),
        (vec![dirs[0].clone(), damaged.clone()], "val/r_0.exr"),
    ];
    for (set, what) in cases {
        let e = merge_shards(&set, &out, None).unwrap_err().to_string();
        assert!(e.contains(what), "{set:?}: expected '{what}' in: {e}");
        assert!(!out.exists(), "{set:?}: the output folder was created");
    }
    // The mismatched settings are named.
    let e = merge_shards(&[dirs[0].clone(), other], &out, None).unwrap_err().to_string();
    assert!(e.contains("spp was 2, now 3"), "{e}");
    // A non-empty output folder is refused.
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("keep.txt"), b"x").unwrap();
    let e = merge_shards(&dirs, &out, None).unwrap_err().to_string();
    assert!(e.contains("not an empty folder"), "{e}");
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 1);
    // A merge that fails once its copy is made (here its last step: `--out` is a dangling link,
    // which the finished folder cannot replace) removes the copy.
    #[cfg(unix)]
    {
        let link = tmp.path().join("link");
        std::os::unix::fs::symlink(tmp.path().join("nowhere"), &link).unwrap();
        merge_shards(&dirs, &link, None).unwrap_err();
        let left: Vec<String> =
            std::fs::read_dir(tmp.path()).unwrap().flatten().map(|e| e.file_name().to_string_lossy().into_owned()).filter(|n| n.ends_with(".tmp")).collect();
        assert!(left.is_empty(), "a failed merge left {left:?}");
    }
}

#[test]
fn shard_specs_parse() {
    assert_eq!("2/5".parse::<Shard>().unwrap(), Shard { index: 2, count: 5 });
    for bad in ["5/5", "1/0", "1", "a/2", "-1/2", ""] {
        let e = bad.parse::<Shard>().unwrap_err();
        assert!(e.contains("--shard") && e.contains("K/N"), "{bad}: {e}");
    }
}
