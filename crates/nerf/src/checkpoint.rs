//! Checkpoints: everything a run needs to continue bit-identically — network parameters,
//! optimiser moments, the hash table and its Adam state, the occupancy grid, the step counter
//! and the training clock.
//!
//! File layout (`<run>/checkpoints/step-<08 step>.ckpt`, written atomically): the 8 bytes
//! `NERFCKPT`, a little-endian u64 header length, a JSON header (scalars and the name and
//! length of each array, in order), the arrays as little-endian f32, then a 16-byte trailer:
//! the 8 bytes `NERFSUM1` and the little-endian u64 FNV-1a-64 hash of every byte before the
//! trailer (offset basis 0xcbf29ce484222325, prime 0x100000001b3). A small format of our
//! own rather than burn's records, because part of the state (hash table, occupancy grid) lives
//! outside burn and optimiser states must be keyed by parameter order, not burn's random ids.
//!
//! Loading verifies, before anything is used: the checksum, before the header is parsed (a
//! file not ending in the trailer is one written before it existed and loads without it), each array's length
//! (`len * 4` with checked arithmetic against the bytes present, so no huge allocation), and
//! that every value is finite (a NaN or infinity is refused naming its array). Counts in the
//! header (steps) are read through [`StateDict::count`]: non-negative integers up to 2^53.
//! A damaged newest checkpoint is reported naming the newest one that loads;
//! [`load_latest_good`] falls back to it on request.

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
const SUM_TAG: &[u8; 8] = b"NERFSUM1";

/// 64-bit FNV-1a of `bytes`.
fn fnv1a64(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, b| (h ^ u64::from(*b)).wrapping_mul(0x0000_0100_0000_01b3))
}

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
        let sum = fnv1a64(&out);
        out.extend_from_slice(SUM_TAG);
        out.extend_from_slice(&sum.to_le_bytes());
        out
    }

    /// Parses [`Self::to_bytes`]'s output.
    pub fn from_bytes(path: &Path, bytes: &[u8]) -> Result<Self, CheckpointError> {
        let bad = |m: &str| CheckpointError::Corrupt { path: path.into(), message: m.into() };
        if bytes.len() < 16 || &bytes[..8] != MAGIC {
            return Err(bad("not a checkpoint (bad magic)"));
        }
        // A file ending in the trailer is checked before anything in it is parsed.
        let n = bytes.len();
        let data_end = if n >= 32 && &bytes[n - 16..n - 8] == SUM_TAG {
            let stored = u64::from_le_bytes(bytes[n - 8..].try_into().map_err(|_| bad("short checksum"))?);
            let actual = fnv1a64(&bytes[..n - 16]);
            if stored != actual {
                return Err(bad(&format!("checksum mismatch (stored {stored:016x}, computed {actual:016x}): the file is damaged")));
            }
            n - 16
        } else {
            n // written before the checksum trailer existed
        };
        let bytes = &bytes[..data_end];
        let hlen = u64::from_le_bytes(bytes[8..16].try_into().map_err(|_| bad("short header"))?) as usize;
        let hend = 16usize.checked_add(hlen).filter(|e| *e <= bytes.len()).ok_or_else(|| bad("truncated header"))?;
        let header: Header = serde_json::from_slice(&bytes[16..hend]).map_err(|e| bad(&format!("header: {e}")))?;
        let mut pos = hend;
        let mut spans = Vec::with_capacity(header.arrays.len());
        for (name, len) in &header.arrays {
            let end = len
                .checked_mul(4)
                .and_then(|n| pos.checked_add(n))
                .filter(|e| *e <= bytes.len())
                .ok_or_else(|| bad(&format!("array '{name}' of {len} values runs past the end of the file ({} bytes)", bytes.len())))?;
            spans.push((name, pos..end));
            pos = end;
        }
        if pos != bytes.len() {
            return Err(bad("trailing bytes after the arrays"));
        }
        if let Some((name, v)) = header.scalars.iter().find(|(_, v)| !v.is_finite()) {
            return Err(bad(&format!("scalar '{name}' is {v}")));
        }
        let mut arrays = BTreeMap::new();
        for (name, span) in spans {
            let v: Vec<f32> = bytes[span].chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
            if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                return Err(bad(&format!("array '{name}' holds a non-finite value ({} at index {i})", v[i])));
            }
            arrays.insert(name.clone(), v);
        }
        Ok(Self { scalars: header.scalars, arrays })
    }

    /// A scalar or an error naming it.
    pub fn scalar(&self, name: &str) -> Result<f64, String> {
        self.scalars.get(name).copied().ok_or_else(|| format!("checkpoint lacks '{name}'"))
    }

    /// A scalar that counts (steps, samples): a non-negative integer up to 2^53 (beyond, f64
    /// no longer holds every integer), or an error naming it.
    pub fn count(&self, name: &str) -> Result<u64, String> {
        let v = self.scalar(name)?;
        if v.is_finite() && v >= 0.0 && v.fract() == 0.0 && v <= 9_007_199_254_740_992.0 {
            Ok(v as u64)
        } else {
            Err(format!("checkpoint scalar '{name}' is {v}, not a count (a non-negative integer up to 2^53)"))
        }
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
                std::fs::remove_file(&p).map_err(|e| dataset::DatasetError::write(&p, e))?;
            }
        }
    }
    Ok(())
}

/// Removes every checkpoint of a run (when the model they hold no longer matches its config).
pub fn remove_all(run_dir: &Path) -> Result<(), CheckpointError> {
    for (_, p) in list(run_dir) {
        std::fs::remove_file(&p).map_err(|e| dataset::DatasetError::write(&p, e))?;
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

/// Loads the newest checkpoint of a run, with its path (for messages that name it). When it is
/// damaged, the error names the newest older checkpoint that loads, so the user can fall back.
pub fn load_latest(run_dir: &Path) -> Result<(PathBuf, StateDict), CheckpointError> {
    let p = latest(run_dir).ok_or_else(|| CheckpointError::Missing(run_dir.into()))?;
    match load(&p) {
        Ok(s) => Ok((p, s)),
        Err(CheckpointError::Corrupt { path, message }) => {
            let hint = match load_latest_good(run_dir) {
                Ok((good, _, _)) => format!(
                    "; the previous checkpoint {} loads: `train --resume --fallback` continues from it (or move the damaged file out of {})",
                    good.display(),
                    checkpoint_dir(run_dir).display()
                ),
                Err(_) => "; no older checkpoint of this run loads".into(),
            };
            Err(CheckpointError::Corrupt { path, message: message + &hint })
        }
        Err(e) => Err(e),
    }
}

/// The newest checkpoint of a run that loads, with the newer ones that did not and why (the
/// fallback when the latest is damaged); the newest one's error when none loads.
#[allow(clippy::type_complexity)]
pub fn load_latest_good(run_dir: &Path) -> Result<(PathBuf, StateDict, Vec<(PathBuf, CheckpointError)>), CheckpointError> {
    let mut all = list(run_dir);
    all.sort_by(|a, b| b.0.cmp(&a.0));
    let mut skipped = Vec::new();
    for (_, p) in all {
        match load(&p) {
            Ok(s) => return Ok((p, s, skipped)),
            Err(e) => skipped.push((p, e)),
        }
    }
    Err(skipped.into_iter().next().map_or_else(|| CheckpointError::Missing(run_dir.into()), |(_, e)| e))
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
