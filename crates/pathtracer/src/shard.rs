//! Sharded rendering: a dataset's views split into `N` deterministic shards that render
//! independently (on other machines: a Ray task or a Slurm array job per shard), and the merge
//! that puts them back together into a folder **byte-identical** to an unsharded render.
//!
//! - [`Shard`] `K/N` owns the views whose position in the rig's order (train, then val, then
//!   test; the numbering of the unsharded render) is `K` modulo `N`, so every shard gets a
//!   share of every split. A shard folder holds `render_config.json` (the same record as the
//!   unsharded render), its views' files, and last `shard.json` ([`ShardManifest`]), which
//!   marks it complete. It has no transforms files: the scene facts (near / far) need every
//!   view's depth.
//! - [`merge_shards`] checks that the shards come from the same scene content and settings and
//!   together cover every view exactly once (overlapping, missing, unfinished or mismatched
//!   shards are an error naming the shard, before anything is written), copies the views
//!   (atomically, file by file), and writes `render_config.json` and the transforms files
//!   through the same code as an unsharded render, so the result is the same bytes. It needs
//!   the scene file (the path recorded in `render_config.json`, or one given) to place the
//!   cameras and state the scene facts; its content must match the recorded hash. A folder
//!   lock in `out` (`.lock`, see `dataset::lock`) is no content, and moves into the result.
//!
//! ```
//! use pathtracer::shard::Shard;
//! let s: Shard = "1/3".parse().unwrap();
//! assert_eq!((s.index, s.count), (1, 3));
//! assert!(s.owns(4) && !s.owns(3));
//! assert!("3/3".parse::<Shard>().is_err());
//! ```

use crate::PathTracerError;
use crate::dataset_folder::{
    DatasetRenderConfig, DatasetSummary, ProgressEvent, RENDER_CONFIG_FILE, RenderRecord, RunOptions, SHARD_MANIFEST_FILE, SceneSource,
    ShardManifest, ViewImages, ViewRenderer, describe_difference, shard_views, view_files,
};
use crate::dataset_render::{render_dataset_part, render_dataset_sharded};
use crate::import::ImportOptions;
use crate::dataset_folder::rig_for;
use dataset::lock::LOCK_FILE;
use dataset::{Camera, SplitKind};
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

/// A shard (defined with the folder's other types).
pub use crate::dataset_folder::Shard;

/// Renders shard `shard` of the dataset of `scene_path` into `out` (see the module docs):
/// [`crate::dataset_render::render_dataset`] for the shard's views only, then `shard.json`.
/// Resumes like a full render.
pub fn render_shard(
    scene_path: &Path,
    out: &Path,
    cfg: &DatasetRenderConfig,
    opts: &RunOptions,
    shard: Shard,
    progress: &mut dyn FnMut(ProgressEvent),
    cancel: &AtomicBool,
) -> Result<DatasetSummary, PathTracerError> {
    render_dataset_sharded(scene_path, out, cfg, opts, Some(shard), progress, cancel)
}

fn read_json<T: serde::de::DeserializeOwned>(path: &Path, what: &str) -> Result<T, PathTracerError> {
    let bytes = std::fs::read(path).map_err(|e| PathTracerError::Config(format!("{}: cannot read its {what} ({e})", path.display())))?;
    serde_json::from_slice(&bytes).map_err(|e| PathTracerError::Config(format!("{}: not a valid {what} ({e})", path.display())))
}

/// A renderer that is never asked to render: the merge finds every view already present.
struct AlreadyRendered {
    view_dependent: bool,
}

impl ViewRenderer for AlreadyRendered {
    fn render_view(&self, _camera: &Camera, view_key: u32) -> Result<ViewImages, PathTracerError> {
        Err(PathTracerError::Config(format!("view {view_key:#x} is missing after the merge")))
    }
    fn is_view_dependent(&self) -> bool {
        self.view_dependent
    }
}

// Long by design: one pass of checks in the order a user would want them reported (manifests,
// settings, scene, coverage), then one atomic write; splitting it would scatter the error texts.
/// Merges the shard folders `shards` into the dataset folder `out` (see the module docs).
/// `scene` overrides where the scene file is looked for (default: the path recorded in the
/// shards' `render_config.json`, as given or relative to a shard folder's ancestors); its
/// content must match the recorded hash. `out` must not exist or be empty. The scene is
/// imported with the default [`ImportOptions`] ([`merge_shards_with`] takes others).
pub fn merge_shards(shards: &[PathBuf], out: &Path, scene: Option<&Path>) -> Result<DatasetSummary, PathTracerError> {
    merge_shards_with(shards, out, scene, &ImportOptions::default())
}

/// [`merge_shards`], importing the scene with `import` (e.g. external files admitted outside
/// the scene's folder).
pub fn merge_shards_with(shards: &[PathBuf], out: &Path, scene: Option<&Path>, import: &ImportOptions) -> Result<DatasetSummary, PathTracerError> {
    let err = |m: String| PathTracerError::Config(m);
    if shards.is_empty() {
        return Err(err("merge: no shard folders given".into()));
    }
    // The folder lock of the command writing `out` is no content.
    let content = |d: &Path| std::fs::read_dir(d).map(|mut d| d.any(|e| e.map_or(true, |e| e.file_name() != LOCK_FILE))).unwrap_or(true);
    if out.exists() && content(out) {
        return Err(err(format!("--out {}: exists and is not an empty folder; merge writes a new dataset folder", out.display())));
    }
    // Every shard: finished, same record, distinct index, same count.
    let mut records: Vec<(PathBuf, RenderRecord, Vec<u8>, ShardManifest)> = Vec::new();
    for dir in shards {
        let manifest_path = dir.join(SHARD_MANIFEST_FILE);
        if !manifest_path.is_file() {
            return Err(err(format!(
                "{}: no {SHARD_MANIFEST_FILE}: not a shard folder, or its render has not finished (re-run its `render --shard` to complete it)",
                dir.display()
            )));
        }
        let manifest: ShardManifest = read_json(&manifest_path, "shard manifest")?;
        let config_path = dir.join(RENDER_CONFIG_FILE);
        let bytes = std::fs::read(&config_path).map_err(|e| err(format!("{}: cannot read ({e})", config_path.display())))?;
        let record: RenderRecord = serde_json::from_slice(&bytes).map_err(|e| err(format!("{}: not a valid {RENDER_CONFIG_FILE} ({e})", config_path.display())))?;
        if let Some((first_dir, first, _, _)) = records.first() {
            if !first.same_output(&record) {
                return Err(err(format!(
                    "shard {} ({}) was rendered with other settings than shard {} ({}): {}",
                    manifest.shard,
                    dir.display(),
                    records[0].3.shard,
                    first_dir.display(),
                    describe_difference(first, &record)
                )));
            }
            if manifest.shard.count != records[0].3.shard.count {
                return Err(err(format!(
                    "shard {} ({}) is one of {} shards, shard {} ({}) one of {}",
                    manifest.shard,
                    dir.display(),
                    manifest.shard.count,
                    records[0].3.shard,
                    first_dir.display(),
                    records[0].3.shard.count
                )));
            }
        }
        if let Some((other, ..)) = records.iter().find(|(_, _, _, m)| m.shard.index == manifest.shard.index) {
            return Err(err(format!(
                "shard {} is given twice ({} and {}): the shards overlap",
                manifest.shard,
                other.display(),
                dir.display()
            )));
        }
        let expected = shard_views(&record.config, manifest.shard);
        if manifest.views != expected {
            return Err(err(format!(
                "{}: its manifest lists other views than shard {} of this dataset owns",
                manifest_path.display(),
                manifest.shard
            )));
        }
        for v in &expected {
            let (split, k) = parse_view(v).ok_or_else(|| err(format!("{}: bad view name {v}", manifest_path.display())))?;
            for f in view_files(split, k) {
                if !dir.join(&f).is_file() {
                    return Err(err(format!("shard {} ({}) lacks {f}", manifest.shard, dir.display())));
                }
            }
            // Read back whole, as a resumed render keeps a view: a damaged file is refused
            // here rather than copied into the dataset.
            let files = view_files(split, k).map(|f| dir.join(f));
            dataset::folder::check_view(&files, record.config.width, record.config.height)
                .map_err(|e| err(format!("shard {} ({}): {e}; render the shard again", manifest.shard, dir.display())))?;
            let labels = dataset::labels::label_files(split, k).map(|f| dir.join(f));
            if labels.iter().any(|f| f.exists()) {
                dataset::labels::read_labels(&labels, record.config.width, record.config.height)
                    .map_err(|e| err(format!("shard {} ({}): {e}; render the shard again", manifest.shard, dir.display())))?;
            }
        }
        records.push((dir.clone(), record, bytes, manifest));
    }
    let count = records[0].3.shard.count;
    let missing: Vec<String> = (0..count).filter(|i| !records.iter().any(|r| r.3.shard.index == *i)).map(|i| format!("{i}/{count}")).collect();
    if !missing.is_empty() {
        return Err(err(format!("shard{} {} missing: the shards given do not cover every view", if missing.len() > 1 { "s" } else { "" }, missing.join(", "))));
    }
    let (first_dir, record, config_bytes, _) = &records[0];
    if record.renderer != crate::version::renderer_version() {
        return Err(err(format!(
            "{}: rendered by {}, but this merge is {}: merge with the binary that rendered the shards",
            first_dir.display(),
            record.renderer,
            crate::version::renderer_version()
        )));
    }
    let scene_path = find_scene(first_dir, record, scene, import)?;
    let loaded = crate::import::load_gltf(&scene_path, import)?;
    let renderer = crate::render::Renderer::new(loaded, &crate::accel::AccelParams::medium_build())?;
    // Checked: the views of the rig the recorded settings build are the ones the shards hold.
    let rig = rig_for(renderer.scene(), &record.config)?;
    if rig.kind != record.rig_resolved {
        return Err(err(format!("{}: the scene now places a {} rig, the shards a {} one", scene_path.display(), rig.kind.name(), record.rig_resolved.name())));
    }

    // Copy the views into a temporary sibling folder, finish it as a render whose views are all
    // done, then rename it to `out`: an interrupted merge leaves no half-written dataset, a
    // failed one removes its folder, and the next merge removes those of killed ones.
    let final_out = out;
    let name = final_out.file_name().map_or("dataset".into(), |n| n.to_string_lossy().into_owned());
    let tmp_name = format!("{name}.merge");
    let tmp = dataset::io::temp_path_for(&final_out.with_file_name(&tmp_name));
    let parent = tmp.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    dataset::io::remove_stale_temporaries(parent, |f| f == tmp_name)?;
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(|e| io(&tmp, e))?;
    }
    let assembled = assemble(&records, &tmp, &renderer, record, config_bytes).and_then(|summary| {
        publish(&tmp, final_out)?;
        Ok(summary)
    });
    match assembled {
        Ok(summary) => Ok(DatasetSummary { out: final_out.to_path_buf(), ..summary }),
        Err(e) => {
            let _ = std::fs::remove_dir_all(&tmp);
            Err(e)
        }
    }
}

/// A failed write (or removal) of the merge's own folders.
fn io(path: &Path, e: std::io::Error) -> PathTracerError {
    PathTracerError::from(dataset::DatasetError::write(path, e))
}

/// Writes the merged dataset into the new folder `out`: the shards' views, then the record and
/// the transforms files as a render whose views are all done writes them.
fn assemble(
    records: &[(PathBuf, RenderRecord, Vec<u8>, ShardManifest)],
    out: &Path,
    renderer: &crate::render::Renderer,
    record: &RenderRecord,
    config_bytes: &[u8],
) -> Result<DatasetSummary, PathTracerError> {
    let err = |m: String| PathTracerError::Config(m);
    std::fs::create_dir_all(out).map_err(|e| io(out, e))?;
    // The record exactly as the shards wrote it (the scene's path as given to them), first, as
    // a render writes it before its views.
    dataset::io::atomic_write(&out.join(RENDER_CONFIG_FILE), config_bytes)?;
    for (dir, _, _, manifest) in records {
        for v in &manifest.views {
            let (split, k) = parse_view(v).ok_or_else(|| err(format!("bad view name {v}")))?;
            // The view's files, and its label files when the shard has them (checked whole above).
            let labels = dataset::labels::label_files(split, k);
            let with_labels = labels.iter().all(|f| dir.join(f).is_file());
            for f in view_files(split, k).into_iter().chain(labels.into_iter().filter(|_| with_labels)) {
                let bytes = std::fs::read(dir.join(&f)).map_err(|e| dataset::DatasetError::Io { path: dir.join(&f), source: e })?;
                dataset::io::atomic_write(&out.join(&f), &bytes)?;
            }
        }
    }
    let adapter = AlreadyRendered { view_dependent: renderer.is_view_dependent() };
    let opts = RunOptions { threads: Some(1), force: false, allow_outside: false };
    let summary = render_dataset_part(renderer.scene(), &record.scene, &adapter, out, &record.config, &opts, None, &mut |_| {}, &AtomicBool::new(false))?;
    dataset::io::atomic_write(&out.join(RENDER_CONFIG_FILE), config_bytes)?;
    Ok(summary)
}

/// Renames the finished folder `tmp` to `out`, which must still be missing or empty: a folder
/// another merge (or any writer) filled meanwhile is left as it is, in one sentence.
fn publish(tmp: &Path, out: &Path) -> Result<(), PathTracerError> {
    let filled = |e: &std::io::Error| {
        matches!(e.kind(), std::io::ErrorKind::DirectoryNotEmpty | std::io::ErrorKind::AlreadyExists)
            || std::fs::read_dir(out).is_ok_and(|mut d| d.any(|e| e.map_or(true, |e| e.file_name() != LOCK_FILE)))
    };
    let taken = || {
        PathTracerError::Config(format!(
            "--out {}: another merge or program wrote into it while this merge ran, so this merge's result was discarded and the folder left as it is; merge into a new folder",
            out.display()
        ))
    };
    // The lock file of the process writing `out` moves with the folder: its holder keeps the
    // lock (on the file, wherever it is named) and finds it at `out/.lock` again after the rename.
    let lock = out.join(LOCK_FILE);
    if lock.is_file() {
        std::fs::rename(&lock, tmp.join(LOCK_FILE)).map_err(|e| io(&lock, e))?;
    }
    if out.exists() {
        std::fs::remove_dir(out).map_err(|e| if filled(&e) { taken() } else { io(out, e) })?;
    }
    std::fs::rename(tmp, out).map_err(|e| if filled(&e) { taken() } else { io(out, e) })
}

/// `train/r_12` → (train, 12).
fn parse_view(v: &str) -> Option<(SplitKind, u32)> {
    let (split, rest) = v.split_once('/')?;
    let split = SplitKind::ALL.into_iter().find(|s| s.name() == split)?;
    Some((split, rest.strip_prefix("r_")?.parse().ok()?))
}

/// The scene file of a record: `given` (whose content must match), else the recorded path as
/// given or relative to `dir`'s ancestors, the first with the recorded content.
fn find_scene(dir: &Path, record: &RenderRecord, given: Option<&Path>, import: &ImportOptions) -> Result<PathBuf, PathTracerError> {
    if let Some(p) = given {
        let s = SceneSource::from_scene_with(p, import)?;
        if s.hash != record.scene.hash {
            return Err(PathTracerError::Config(format!(
                "--scene {}: not the scene the shards were rendered from (content hash {} vs the recorded {})",
                p.display(),
                s.hash,
                record.scene.hash
            )));
        }
        return Ok(p.to_path_buf());
    }
    let recorded = PathBuf::from(&record.scene.path);
    let mut candidates = vec![recorded.clone()];
    if recorded.is_relative() {
        let abs = dir.canonicalize().unwrap_or_else(|_| dir.to_path_buf());
        candidates.extend(abs.ancestors().map(|a| a.join(&recorded)));
    }
    for c in &candidates {
        if c.is_file() && SceneSource::from_scene_with(c, import).is_ok_and(|s| s.hash == record.scene.hash) {
            return Ok(c.clone());
        }
    }
    Err(PathTracerError::Config(format!(
        "the scene the shards were rendered from ({}, content hash {}) is not found or has changed; give it with --scene",
        record.scene.path, record.scene.hash
    )))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two merges into one folder: the second to finish finds the folder filled and says so in
    /// one sentence (it said "Directory not empty"), leaving the first's dataset as it is.
    #[test]
    fn publishing_into_a_folder_filled_meanwhile_is_one_sentence() {
        let dir = tempfile::tempdir().unwrap();
        let (tmp, out) = (dir.path().join(".out.merge.1.tmp"), dir.path().join("out"));
        std::fs::create_dir_all(&tmp).unwrap();
        std::fs::write(tmp.join("transforms_train.json"), b"mine").unwrap();
        std::fs::create_dir_all(&out).unwrap();
        std::fs::write(out.join("transforms_train.json"), b"theirs").unwrap();
        let e = publish(&tmp, &out).unwrap_err().to_string();
        assert!(e.contains("--out") && e.contains("another merge") && !e.contains("os error"), "{e}");
        assert_eq!(std::fs::read(out.join("transforms_train.json")).unwrap(), b"theirs");
        // Still empty: published.
        std::fs::remove_file(out.join("transforms_train.json")).unwrap();
        publish(&tmp, &out).unwrap();
        assert_eq!(std::fs::read(out.join("transforms_train.json")).unwrap(), b"mine");
        assert!(!tmp.exists());
    }
}
