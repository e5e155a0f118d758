//! Outputs never replace inputs: the check every command that writes runs on its output paths
//! before it reads or writes anything else.
//!
//! An output is refused, in one sentence naming the option and the file or folder, when it
//! - lies inside a dataset folder (one holding `render_config.json`, a `transforms_<split>.json`,
//!   `transforms.json` or `shard.json`): a dataset's views and records are the ground truth
//!   every evaluation trusts. An output folder may itself be a dataset folder only where the
//!   command writes datasets (`render` resumes one of the same settings);
//! - would replace a record of a run (`config.json`, `metrics.jsonl`, `eval.json`,
//!   `report.json`, `report.md` in a folder holding a run, or anything in its `checkpoints/`);
//! - would replace a file the command reads (a scene, an environment map).
//!
//! Paths are compared canonicalised, so `a/../run/config.json` and a symlinked folder are seen
//! through; an output that does not exist yet is resolved through its nearest existing ancestor.
//! A file output is checked together with its sidecars (`mesh`'s `<name>.json`).

use std::path::{Component, Path, PathBuf};

/// The records of a run folder that no other output may replace: written by `train` and
/// `eval`, read by `eval`, `mesh`, `render-nerf`, `compare` and `train --resume`.
const RUN_RECORDS: [&str; 5] = [nerf::train::CONFIG_FILE, nerf::train::METRICS_FILE, "eval.json", "report.json", "report.md"];

/// `path` absolute and canonical: its nearest existing ancestor canonicalised (symlinks and
/// `..` resolved), the rest appended with `.` and `..` applied lexically.
pub fn resolve(path: &Path) -> PathBuf {
    let abs = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir().map(|d| d.join(path)).unwrap_or_else(|_| path.to_path_buf())
    };
    for base in abs.ancestors() {
        let Ok(canonical) = base.canonicalize() else { continue };
        let mut out = canonical;
        for c in abs.strip_prefix(base).unwrap_or(Path::new("")).components() {
            match c {
                Component::ParentDir => {
                    out.pop();
                }
                Component::Normal(n) => out.push(n),
                _ => {}
            }
        }
        return out;
    }
    abs
}

/// The file in `dir` that makes it a dataset folder, if any.
fn dataset_marker(dir: &Path) -> Option<String> {
    std::iter::once(dataset::folder::RENDER_CONFIG_FILE.to_string())
        .chain(dataset::folder::top_files())
        .find(|f| dir.join(f).is_file())
}

/// Whether `dir` holds a training run: its `config.json` beside its checkpoints or metrics.
fn is_run_folder(dir: &Path) -> bool {
    dir.join(nerf::train::CONFIG_FILE).is_file()
        && (nerf::checkpoint::checkpoint_dir(dir).is_dir() || dir.join(nerf::train::METRICS_FILE).is_file())
}

/// Refuses `given` (resolved: `path`) when a proper ancestor of it is a dataset folder or a
/// run's checkpoints folder.
fn check_ancestors(option: &str, given: &Path, path: &Path) -> anyhow::Result<()> {
    for dir in path.ancestors().skip(1) {
        if let Some(marker) = dataset_marker(dir) {
            anyhow::bail!(
                "{option} {}: lies inside the dataset folder {} (it holds {marker}), whose files would be mixed with or replaced by this output; write it outside the dataset",
                given.display(),
                dir.display()
            );
        }
        if dir.file_name().is_some_and(|n| n == "checkpoints") && dir.parent().is_some_and(is_run_folder) {
            anyhow::bail!("{option} {}: lies inside the checkpoints folder {} of a run; write it outside", given.display(), dir.display());
        }
    }
    Ok(())
}

/// Refuses the output folder `dir` given to `option` (see the module docs). `may_be_dataset`:
/// the command writes a dataset, so `dir` itself may be one (its own checks decide whether it
/// resumes it).
pub fn check_output_folder(option: &str, dir: &Path, may_be_dataset: bool) -> anyhow::Result<()> {
    let resolved = resolve(dir);
    if !may_be_dataset && let Some(marker) = dataset_marker(&resolved) {
        anyhow::bail!(
            "{option} {}: is a dataset folder (it holds {marker}), whose files this output would be mixed with or replace; give a folder outside the dataset",
            dir.display()
        );
    }
    check_ancestors(option, dir, &resolved)
}

/// Refuses the output files `files` of `option` (the file it names and the sidecars derived
/// from it) when one would replace a file in `reads` (the files the command reads), a run's
/// record, or lie inside a dataset folder (see the module docs).
pub fn check_output_files(option: &str, given: &Path, files: &[PathBuf], reads: &[PathBuf]) -> anyhow::Result<()> {
    let reads: Vec<PathBuf> = reads.iter().map(|r| resolve(r)).collect();
    for file in files {
        let resolved = resolve(file);
        let named = if file == given { String::new() } else { format!(" (through {})", file.display()) };
        if reads.contains(&resolved) {
            anyhow::bail!("{option} {}{named}: would replace {}, which this command reads; give another path", given.display(), resolved.display());
        }
        if let (Some(parent), Some(name)) = (resolved.parent(), resolved.file_name())
            && RUN_RECORDS.iter().any(|r| name == *r)
            && is_run_folder(parent)
        {
            anyhow::bail!(
                "{option} {}{named}: would replace the run's {} in {}; give another path",
                given.display(),
                name.to_string_lossy(),
                parent.display()
            );
        }
        check_ancestors(option, given, &resolved)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resolve_sees_through_dot_dot_and_missing_tails() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path().canonicalize().unwrap();
        std::fs::create_dir_all(root.join("a/b")).unwrap();
        assert_eq!(resolve(&root.join("a/b/../c.txt")), root.join("a/c.txt"));
        assert_eq!(resolve(&root.join("a/new/deeper/../x")), root.join("a/new/x"));
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(root.join("a/b"), root.join("link")).unwrap();
            assert_eq!(resolve(&root.join("link/f")), root.join("a/b/f"));
        }
    }

    #[test]
    fn outputs_inside_datasets_and_over_run_records_are_refused() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path();
        let data = root.join("data");
        std::fs::create_dir_all(data.join("test")).unwrap();
        std::fs::write(data.join("transforms_test.json"), "{}").unwrap();
        let run = root.join("run");
        std::fs::create_dir_all(run.join("checkpoints")).unwrap();
        std::fs::write(run.join("config.json"), "{}").unwrap();
        let e = check_output_folder("--out", &data.join("test"), false).unwrap_err().to_string();
        assert!(e.starts_with("--out ") && e.contains("inside the dataset folder") && e.contains("transforms_test.json"), "{e}");
        assert!(check_output_folder("--out", &data, false).unwrap_err().to_string().contains("is a dataset folder"));
        check_output_folder("--out", &data, true).unwrap();
        check_output_folder("--out", &data.join("new/deeper"), true).unwrap_err();
        check_output_folder("--out", &run.join("renders"), false).unwrap();
        check_output_folder("--out", &run.join("checkpoints/x"), false).unwrap_err();
        let e = check_output_files("--out", &run.join("config.ply"), &[run.join("config.ply"), run.join("config.json")], &[]).unwrap_err().to_string();
        assert!(e.contains("config.json") && e.contains("the run's"), "{e}");
        check_output_files("--out", &run.join("mesh.ply"), &[run.join("mesh.ply"), run.join("mesh.json")], &[]).unwrap();
        let scene = root.join("scene.json");
        std::fs::write(&scene, "{}").unwrap();
        let e = check_output_files("--out", &root.join("scene.ply"), &[root.join("scene.ply"), root.join("x/../scene.json")], &[scene]).unwrap_err().to_string();
        assert!(e.contains("which this command reads"), "{e}");
    }
}
