//! The life cycle of a dataset folder, whatever renders its views (the path tracer, a shard of
//! it, a merge of shards): which files a view has, whether a folder can take a dataset
//! ([`prepare`]: empty, missing, or holding the same dataset, whose identity file the caller
//! compares), the temporaries a killed run leaves behind, and writing one view's files
//! ([`write_view`]), each atomically. The identity itself (`render_config.json`: scene hash,
//! renderer version, settings) belongs to the renderer; this module only reads it back as the
//! caller's type and asks the caller how it differs.
//!
//! A view `r_<k>` of split `s` is complete when its six files exist ([`view_files`]): the
//! sRGB PNG, the linear EXR, the ground-truth EXR, z-depth `.npy` in metres, and for
//! nerfstudio's `transforms.json` z-depth in millimetres and the coverage mask. A resumed render
//! keeps complete views and renders the others.

use crate::error::DatasetError;
use crate::images::{
    GroundTruth, RgbaImage, check_npy_f32, linear_to_srgb, read_exr_rgba, read_ground_truth, read_png_rgba, write_exr_rgba, write_ground_truth,
    write_npy_f32, write_png_mask, write_png_rgba,
};
use crate::transforms::{SplitKind, nerfstudio_files};
use serde::de::DeserializeOwned;
use std::path::{Path, PathBuf};

/// File name of the renderer's identity record (resolved settings) inside a dataset folder.
pub const RENDER_CONFIG_FILE: &str = "render_config.json";

/// File name of a shard folder's manifest (which views of which dataset it holds).
pub const SHARD_MANIFEST_FILE: &str = "shard.json";

/// The files of view `index` of `split`, relative to the dataset folder: PNG, linear EXR,
/// ground-truth EXR, z-depth `.npy` in metres, and for nerfstudio's `transforms.json` z-depth
/// in millimetres and the coverage mask ([`nerfstudio_files`]).
pub fn view_files(split: SplitKind, index: u32) -> [String; 6] {
    let stem = format!("{}/r_{index}", split.name());
    let [depth_mm, mask] = nerfstudio_files(&stem);
    [format!("{stem}.png"), format!("{stem}.exr"), format!("{stem}_gt.exr"), format!("{stem}_depth.npy"), depth_mm, mask]
}

/// Whether all files of view `index` of `split` exist in `out`.
pub fn view_complete(out: &Path, split: SplitKind, index: u32) -> bool {
    view_files(split, index).iter().all(|f| out.join(f).is_file())
}

/// Reads back one view's files ([`view_files`], joined to the folder) as a resumed render or a
/// merge is about to keep them: each must decode, at `width` × `height`. Returns the ground
/// truth, or the first file that is damaged (our writes are atomic, so only outside damage, a
/// truncated copy or a disk error, gets here).
pub fn check_view(files: &[PathBuf; 6], width: u32, height: u32) -> Result<GroundTruth, DatasetError> {
    let size = |path: &Path, w: u32, h: u32| {
        if (w, h) == (width, height) {
            Ok(())
        } else {
            Err(DatasetError::invalid(path, format!("is {w}x{h}, the view is {width}x{height}")))
        }
    };
    for k in [0, 5] {
        let img = read_png_rgba(&files[k])?;
        size(&files[k], img.width, img.height)?;
    }
    let color = read_exr_rgba(&files[1])?;
    size(&files[1], color.width, color.height)?;
    let gt = read_ground_truth(&files[2])?;
    size(&files[2], gt.width, gt.height)?;
    check_npy_f32(&files[3], width, height)?;
    check_npy_f32(&files[4], width, height)?;
    Ok(gt)
}

/// Whether `name` is one of the files a dataset render writes inside a split folder.
pub fn is_view_file(name: &str) -> bool {
    let Some(rest) = name.strip_prefix("r_") else { return false };
    let digits = rest.chars().take_while(char::is_ascii_digit).count();
    digits > 0 && matches!(&rest[digits..], ".png" | ".exr" | "_gt.exr" | "_depth.npy" | "_depth_mm.npy" | "_mask.png" | "_ids.png" | "_material.png" | "_coverage.npy")
}

/// The files a dataset render writes at the top of the folder (but its identity record).
pub fn top_files() -> Vec<String> {
    let mut v: Vec<String> = SplitKind::ALL.iter().map(|s| s.file_name()).collect();
    v.push("transforms.json".into());
    v.push(SHARD_MANIFEST_FILE.into());
    v
}

/// Whether `out` holds any file a dataset render writes.
pub fn has_dataset_files(out: &Path) -> bool {
    top_files().iter().any(|f| out.join(f).exists())
        || SplitKind::ALL.iter().any(|s| {
            std::fs::read_dir(out.join(s.name()))
                .map(|d| d.flatten().any(|e| is_view_file(&e.file_name().to_string_lossy())))
                .unwrap_or(false)
        })
}

/// Whether `name` is the temporary name (`.<file>.<pid>.tmp`, see
/// [`crate::io::temp_path_for`]) of a dataset file, left behind by a killed run.
pub fn is_stale_temporary(name: &str) -> bool {
    let Some(inner) = name.strip_prefix('.').and_then(|n| n.strip_suffix(".tmp")) else { return false };
    let Some((file, pid)) = inner.rsplit_once('.') else { return false };
    !pid.is_empty()
        && pid.chars().all(|c| c.is_ascii_digit())
        && (is_view_file(file) || file == RENDER_CONFIG_FILE || top_files().iter().any(|f| f == file))
}

/// Removes temporaries of dataset files that a killed run left behind.
pub fn remove_stale_temporaries(out: &Path) -> Result<(), DatasetError> {
    for dir in std::iter::once(out.to_path_buf()).chain(SplitKind::ALL.iter().map(|s| out.join(s.name()))) {
        let Ok(entries) = std::fs::read_dir(&dir) else { continue };
        for e in entries.flatten() {
            if is_stale_temporary(&e.file_name().to_string_lossy()) {
                let p = e.path();
                std::fs::remove_file(&p).map_err(|e| DatasetError::write(&p, e))?;
            }
        }
    }
    Ok(())
}

/// Removes only the files a dataset render writes (never the folder or other files).
pub fn remove_dataset_files(out: &Path) -> Result<(), DatasetError> {
    let rm = |p: &Path| std::fs::remove_file(p).map_err(|e| DatasetError::write(p, e));
    for f in top_files().into_iter().chain([RENDER_CONFIG_FILE.to_string()]) {
        let p = out.join(f);
        if p.is_file() {
            rm(&p)?;
        }
    }
    for s in SplitKind::ALL {
        let dir = out.join(s.name());
        let Ok(entries) = std::fs::read_dir(&dir) else { continue };
        for e in entries.flatten() {
            if is_view_file(&e.file_name().to_string_lossy()) {
                rm(&e.path())?;
            }
        }
    }
    Ok(())
}

/// Checks that `out` can receive a dataset: missing, empty, or holding a dataset whose identity
/// record (`render_config.json`, read as `R`) `difference` finds the same (`None`; otherwise it
/// describes how it differs). With `force`, a different dataset's files are removed first.
/// Stale temporaries are removed. Nothing else is written. A split folder that is a symbolic
/// link is refused before anything is read or removed ([`check_split_folders`]).
pub fn prepare<R: DeserializeOwned>(out: &Path, difference: impl Fn(&R) -> Option<String>, force: bool) -> Result<(), DatasetError> {
    if out.exists() && !out.is_dir() {
        return Err(DatasetError::invalid(out, "exists and is not a folder"));
    }
    check_split_folders(out)?;
    let config_path = out.join(RENDER_CONFIG_FILE);
    let conflict = if config_path.is_file() {
        let bytes = crate::io::read(&config_path)?;
        match serde_json::from_slice::<R>(&bytes) {
            Ok(old) => difference(&old),
            Err(e) => Some(format!("its {RENDER_CONFIG_FILE} cannot be read ({e})")),
        }
    } else if has_dataset_files(out) {
        Some(format!("it holds dataset files but no {RENDER_CONFIG_FILE}"))
    } else {
        None
    };
    match conflict {
        None => remove_stale_temporaries(out),
        Some(why) if !force => Err(DatasetError::invalid(
            out,
            format!("holds a dataset rendered with different settings: {why}; choose a new --out folder, or pass --force to replace it"),
        )),
        Some(_) => {
            remove_dataset_files(out)?;
            remove_stale_temporaries(out)
        }
    }
}

/// Refuses a split folder of `out` (`train`, `val`, `test`) that is a symbolic link or not a
/// folder: a render would write its views into the link's target, and `--force` remove files
/// there. `out` itself may be a link (the user named it).
pub fn check_split_folders(out: &Path) -> Result<(), DatasetError> {
    for split in SplitKind::ALL {
        let dir = out.join(split.name());
        match std::fs::symlink_metadata(&dir) {
            Ok(m) if m.file_type().is_symlink() => {
                return Err(DatasetError::invalid(
                    &dir,
                    "is a symbolic link; a render writes its views only into real folders inside the dataset folder (remove the link, or render into another --out)",
                ));
            }
            Ok(m) if !m.is_dir() => return Err(DatasetError::invalid(&dir, "is not a folder; a render writes this split's views there")),
            _ => {}
        }
    }
    Ok(())
}

/// The linear image as written to the EXR: premultiplied, with a colour background composited
/// (`over`, then opaque).
pub fn composite(color: &RgbaImage, background: Option<[f32; 3]>) -> RgbaImage {
    let mut out = color.clone();
    if let Some(bg) = background {
        for px in out.data.chunks_exact_mut(4) {
            let a = px[3].clamp(0.0, 1.0);
            for (v, b) in px[..3].iter_mut().zip(bg) {
                *v += (1.0 - a) * b;
            }
            px[3] = 1.0;
        }
    }
    out
}

/// Display colour: straight-alpha sRGB, `rgb = srgb(premultiplied / alpha)`, 0 where alpha is 0.
pub fn display(linear: &RgbaImage) -> RgbaImage {
    let mut out = linear.clone();
    for px in out.data.chunks_exact_mut(4) {
        let a = px[3].clamp(0.0, 1.0);
        for v in &mut px[..3] {
            *v = if a > 0.0 { linear_to_srgb(*v / a) } else { 0.0 };
        }
        px[3] = a;
    }
    out
}

/// Writes one view's six files ([`view_files`], joined to the folder) from its linear
/// premultiplied colour and exact ground truth, each atomically; `background` is composited
/// behind the colour when given. The PNG is written last, so a view whose PNG exists was
/// written whole.
pub fn write_view(files: &[PathBuf; 6], color: &RgbaImage, gt: &GroundTruth, background: Option<[f32; 3]>) -> Result<(), DatasetError> {
    let linear = composite(color, background);
    write_ground_truth(&files[2], gt)?;
    write_npy_f32(&files[3], gt.width, gt.height, &gt.depth)?;
    let depth_mm: Vec<f32> = gt.depth.iter().map(|d| (*d as f64 * 1000.0) as f32).collect();
    write_npy_f32(&files[4], gt.width, gt.height, &depth_mm)?;
    let hit: Vec<bool> = gt.alpha.iter().map(|a| *a > 0.0).collect();
    write_png_mask(&files[5], gt.width, gt.height, &hit)?;
    write_exr_rgba(&files[1], &linear)?;
    write_png_rgba(&files[0], &display(&linear))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn view_and_temporary_names() {
        assert!(is_view_file("r_12.png") && is_view_file("r_0_gt.exr") && is_view_file("r_3_depth_mm.npy") && is_view_file("r_3_mask.png"));
        assert!(!is_view_file("r_.png") && !is_view_file("r_1.jpg") && !is_view_file("notes.png"));
        assert!(is_stale_temporary(".r_4.exr.1234.tmp") && is_stale_temporary(".render_config.json.9.tmp"));
        assert!(is_stale_temporary(".transforms_train.json.77.tmp") && is_stale_temporary(".shard.json.5.tmp"));
        assert!(!is_stale_temporary(".r_4.exr.tmp") && !is_stale_temporary(".mine.txt.12.tmp") && !is_stale_temporary("r_4.exr.12.tmp"));
        assert_eq!(view_files(SplitKind::Val, 7)[0], "val/r_7.png");
    }

    #[test]
    fn prepare_refuses_another_dataset_unless_forced_and_keeps_other_files() {
        let dir = std::env::temp_dir().join(format!("dataset-folder-test-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("train")).unwrap();
        let same = |r: &serde_json::Value| (r["seed"] != 1).then(|| format!("seed was {}", r["seed"]));
        // empty: fine
        prepare::<serde_json::Value>(&dir, same, false).unwrap();
        std::fs::write(dir.join(RENDER_CONFIG_FILE), r#"{"seed": 2}"#).unwrap();
        std::fs::write(dir.join("train/r_0.png"), b"x").unwrap();
        std::fs::write(dir.join("train/.r_1.exr.42.tmp"), b"x").unwrap();
        std::fs::write(dir.join("notes.txt"), b"mine").unwrap();
        let e = prepare::<serde_json::Value>(&dir, same, false).unwrap_err().to_string();
        assert!(e.contains("different settings: seed was 2") && e.contains("--force"), "{e}");
        assert!(dir.join("train/r_0.png").is_file(), "a refusal removes nothing");
        prepare::<serde_json::Value>(&dir, same, true).unwrap();
        assert!(!dir.join("train/r_0.png").exists() && !dir.join(RENDER_CONFIG_FILE).exists() && !dir.join("train/.r_1.exr.42.tmp").exists());
        assert_eq!(std::fs::read(dir.join("notes.txt")).unwrap(), b"mine");
        // dataset files without an identity record: refused
        std::fs::write(dir.join("transforms_train.json"), b"{}").unwrap();
        let e = prepare::<serde_json::Value>(&dir, same, false).unwrap_err().to_string();
        assert!(e.contains("no render_config.json"), "{e}");
        // a file where the folder should be
        let file = dir.join("notes.txt");
        assert!(prepare::<serde_json::Value>(&file, same, false).unwrap_err().to_string().contains("not a folder"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A split folder that is a symbolic link (here to a folder of the user's, holding a file
    /// named like a view) is refused, with or without `force`, and nothing behind it is
    /// removed; so is a split that is a file.
    #[cfg(unix)]
    #[test]
    fn prepare_refuses_a_split_folder_that_is_a_link() {
        let base = std::env::temp_dir().join(format!("dataset-folder-link-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&base);
        let (out, theirs) = (base.join("out"), base.join("theirs"));
        std::fs::create_dir_all(&out).unwrap();
        std::fs::create_dir_all(&theirs).unwrap();
        std::fs::write(theirs.join("r_0.png"), b"precious").unwrap();
        std::fs::write(out.join(RENDER_CONFIG_FILE), r#"{"seed": 2}"#).unwrap();
        std::os::unix::fs::symlink(&theirs, out.join("val")).unwrap();
        let same = |r: &serde_json::Value| (r["seed"] != 1).then(|| format!("seed was {}", r["seed"]));
        for force in [false, true] {
            let e = prepare::<serde_json::Value>(&out, same, force).unwrap_err().to_string();
            assert!(e.contains("val") && e.contains("symbolic link"), "{e}");
            assert_eq!(std::fs::read(theirs.join("r_0.png")).unwrap(), b"precious");
        }
        std::fs::remove_file(out.join("val")).unwrap();
        std::fs::write(out.join("test"), b"x").unwrap();
        let e = prepare::<serde_json::Value>(&out, same, true).unwrap_err().to_string();
        assert!(e.contains("test") && e.contains("not a folder"), "{e}");
        std::fs::remove_dir_all(&base).unwrap();
    }
}
