//! Checkpoints: everything a run needs to continue bit-identically — network parameters,
//! optimiser moments, the hash table and its Adam state, the occupancy grid, the step counter
//! and the training clock.
//!
//! File layout (`<run>/checkpoints/step-<08 step>.ckpt`, written atomically): the 8 bytes
//! `NERFCKPT`, a little-endian u64 header length, a JSON header (scalars and the name and
//! length of each array, in order), then the arrays as little-endian f32. A small format of our
//! own rather than burn's records, because part of the state (hash table, occupancy grid) lives
//! outside burn and optimiser states must be keyed by parameter order, not burn's random ids.

use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Checkpoint errors.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// Reading or writing failed.
    #[error(transparent)]
    Io(#[from] dataset::DatasetError),
    /// The file is not a checkpoint or is damaged.
    #[error("{path}: {message}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// No checkpoint in the run folder.
    #[error("no checkpoint in {0}")]
    Missing(PathBuf),
}

/// Named scalars and f32 arrays.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StateDict {
    /// Scalars (step counters, times).
    pub scalars: BTreeMap<String, f64>,
    /// Arrays.
    pub arrays: BTreeMap<String, Vec<f32>>,
}

#[derive(Serialize, Deserialize)]
struct Header {
    scalars: BTreeMap<String, f64>,
    arrays: Vec<(String, usize)>,
}

const MAGIC: &[u8; 8] = b"NERFCKPT";

impl StateDict {
    /// Serialises to bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        let header = Header {
            scalars: self.scalars.clone(),
            arrays: self.arrays.iter().map(|(k, v)| (k.clone(), v.len())).collect(),
        };
        let h = serde_json::to_vec(&header).unwrap_or_default();
        let total: usize = self.arrays.values().map(Vec::len).sum();
        let mut out = Vec::with_capacity(16 + h.len() + 4 * total);
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&(h.len() as u64).to_le_bytes());
        out.extend_from_slice(&h);
        for v in self.arrays.values() {
            for x in v {
                out.extend_from_slice(&x.to_le_bytes());
            }
        }
        out
    }

    /// Parses [`Self::to_bytes`]'s output.
    pub fn from_bytes(path: &Path, bytes: &[u8]) -> Result<Self, CheckpointError> {
        let bad = |m: &str| CheckpointError::Corrupt { path: path.into(), message: m.into() };
        if bytes.len() < 16 || &bytes[..8] != MAGIC {
            return Err(bad("not a checkpoint (bad magic)"));
        }
        let hlen = u64::from_le_bytes(bytes[8..16].try_into().map_err(|_| bad("short header"))?) as usize;
        let hend = 16usize.checked_add(hlen).filter(|e| *e <= bytes.len()).ok_or_else(|| bad("truncated header"))?;
        let header: Header = serde_json::from_slice(&bytes[16..hend]).map_err(|e| bad(&format!("header: {e}")))?;
        let mut pos = hend;
        let mut arrays = BTreeMap::new();
        for (name, len) in header.arrays {
            let end = pos.checked_add(len * 4).filter(|e| *e <= bytes.len()).ok_or_else(|| bad("truncated data"))?;
            let v = bytes[pos..end].chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
            arrays.insert(name, v);
            pos = end;
        }
        if pos != bytes.len() {
            return Err(bad("trailing bytes"));
        }
        Ok(Self { scalars: header.scalars, arrays })
    }

    /// A scalar or an error naming it.
    pub fn scalar(&self, name: &str) -> Result<f64, String> {
        self.scalars.get(name).copied().ok_or_else(|| format!("checkpoint lacks '{name}'"))
    }
}

/// The checkpoint folder of a run.
pub fn checkpoint_dir(run_dir: &Path) -> PathBuf {
    run_dir.join("checkpoints")
}

/// Writes the checkpoint of `step` atomically and keeps only the newest `keep`.
pub fn save(run_dir: &Path, step: u64, state: &StateDict, keep: usize) -> Result<PathBuf, CheckpointError> {
    let dir = checkpoint_dir(run_dir);
    let path = dir.join(format!("step-{step:08}.ckpt"));
    dataset::io::atomic_write(&path, &state.to_bytes())?;
    let mut all = list(run_dir);
    all.sort();
    let n = all.len();
    for (_, old) in all.into_iter().take(n.saturating_sub(keep.max(1))) {
        let _ = std::fs::remove_file(old);
    }
    Ok(path)
}

fn list(run_dir: &Path) -> Vec<(u64, PathBuf)> {
    let Ok(rd) = std::fs::read_dir(checkpoint_dir(run_dir)) else { return Vec::new() };
    rd.filter_map(|e| e.ok())
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let step = name.strip_prefix("step-")?.strip_suffix(".ckpt")?.parse().ok()?;
            Some((step, e.path()))
        })
        .collect()
}

/// The file a temporary name (`.<file>.<pid>.tmp`, see [`dataset::io::temp_path_for`]) stands
/// for, if `name` is one.
fn temporary_of(name: &str) -> Option<&str> {
    let (file, pid) = name.strip_prefix('.')?.strip_suffix(".tmp")?.rsplit_once('.')?;
    (!pid.is_empty() && pid.chars().all(|c| c.is_ascii_digit())).then_some(file)
}

/// Removes the temporaries that a killed run left behind: of checkpoints, and of the files
/// named in `run_files` at the top of the run folder.
pub fn remove_stale_temporaries(run_dir: &Path, run_files: &[&str]) -> Result<(), CheckpointError> {
    let is_ckpt = |f: &str| f.strip_prefix("step-").and_then(|r| r.strip_suffix(".ckpt")).is_some();
    for (dir, ours) in [(run_dir.to_path_buf(), false), (checkpoint_dir(run_dir), true)] {
        let Ok(entries) = std::fs::read_dir(&dir) else { continue };
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if temporary_of(&name).is_some_and(|f| if ours { is_ckpt(f) } else { run_files.contains(&f) }) {
                let p = e.path();
                std::fs::remove_file(&p).map_err(|e| dataset::DatasetError::Io { path: p.clone(), source: e })?;
            }
        }
    }
    Ok(())
}

/// Removes every checkpoint of a run (when the model they hold no longer matches its config).
pub fn remove_all(run_dir: &Path) -> Result<(), CheckpointError> {
    for (_, p) in list(run_dir) {
        std::fs::remove_file(&p).map_err(|e| dataset::DatasetError::Io { path: p.clone(), source: e })?;
    }
    Ok(())
}

/// The newest checkpoint of a run, if any.
pub fn latest(run_dir: &Path) -> Option<PathBuf> {
    latest_with_step(run_dir).map(|(_, p)| p)
}

/// The newest checkpoint of a run with the step its file name gives (`step-<08 step>.ckpt`,
/// as [`save`] names it), if any, without reading the file.
pub fn latest_with_step(run_dir: &Path) -> Option<(u64, PathBuf)> {
    list(run_dir).into_iter().max_by_key(|(s, _)| *s)
}

/// Loads a checkpoint file.
pub fn load(path: &Path) -> Result<StateDict, CheckpointError> {
    let bytes = dataset::io::read(path)?;
    StateDict::from_bytes(path, &bytes)
}

/// Loads the newest checkpoint of a run, with its path (for messages that name it).
pub fn load_latest(run_dir: &Path) -> Result<(PathBuf, StateDict), CheckpointError> {
    let p = latest(run_dir).ok_or_else(|| CheckpointError::Missing(run_dir.into()))?;
    let s = load(&p)?;
    Ok((p, s))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_round_trip() {
        let mut s = StateDict::default();
        s.scalars.insert("step".into(), 12.0);
        s.arrays.insert("a".into(), vec![1.0, -2.5, f32::MIN_POSITIVE]);
        s.arrays.insert("b".into(), vec![]);
        let b = s.to_bytes();
        assert_eq!(StateDict::from_bytes(Path::new("x"), &b).unwrap(), s);
        assert!(StateDict::from_bytes(Path::new("x"), &b[..b.len() - 1]).is_err());
    }

    #[test]
    fn stale_temporaries_are_removed_and_nothing_else() {
        let dir = tempfile::tempdir().unwrap();
        let run = dir.path();
        let ckpts = checkpoint_dir(run);
        std::fs::create_dir_all(&ckpts).unwrap();
        let keep = [run.join("notes.txt"), run.join(".notes.txt.12.tmp"), ckpts.join("step-00000010.ckpt"), ckpts.join(".step-00000010.ckpt.tmp")];
        let gone = [run.join(".config.json.4242.tmp"), run.join(".metrics.jsonl.7.tmp"), ckpts.join(".step-00000020.ckpt.99.tmp")];
        for p in keep.iter().chain(&gone) {
            std::fs::write(p, b"x").unwrap();
        }
        remove_stale_temporaries(run, &["config.json", "metrics.jsonl"]).unwrap();
        assert!(keep.iter().all(|p| p.exists()) && gone.iter().all(|p| !p.exists()));
    }
}
