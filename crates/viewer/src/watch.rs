//! The run being viewed: its config, dataset and newest checkpoint's model, reloaded when the
//! trainer writes a newer checkpoint.
//!
//! [`RunWatch::poll`] compares the newest checkpoint's identity (file name, size, modification
//! time) with the loaded one's and, when it changed, loads the new model beside the old one and
//! swaps an `Arc` under a lock held only for the swap: a render that started keeps the model
//! it took. A checkpoint that fails to load is remembered (its identity and the message) and not
//! retried until it changes; the previous model stays in use. Nothing here writes anything.

use crate::error::ViewerError;
use dataset::{Dataset, LoadOptions};
use dataset::Camera;
use nerf::render::{RenderedView, RunModel};
use nerf::train::{CONFIG_FILE, TrainConfig};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, RwLock};
use std::time::SystemTime;

/// What identifies a checkpoint file on disk.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CheckpointKey {
    /// The file.
    pub path: PathBuf,
    /// Its step, from its name.
    pub step: u64,
    /// Its size, bytes.
    pub len: u64,
    /// Its modification time.
    pub modified: Option<SystemTime>,
}

impl CheckpointKey {
    /// The newest checkpoint of `run_dir`, if any can be seen.
    pub fn newest(run_dir: &Path) -> Option<Self> {
        let (step, path) = nerf::checkpoint::latest_with_step(run_dir)?;
        let meta = std::fs::metadata(&path).ok()?;
        Some(Self { path, step, len: meta.len(), modified: meta.modified().ok() })
    }
}

/// A loaded model and the checkpoint it came from. The model renders under a lock (a model is
/// `Send` but not `Sync`); one render at a time already has every viewer thread.
#[derive(Debug)]
pub struct Loaded {
    /// The run, ready to render (moved out while a render pool uses it).
    model: Mutex<Option<RunModel>>,
    /// The run's config (read without the lock).
    pub config: TrainConfig,
    /// Its checkpoint.
    pub key: CheckpointKey,
}

impl Loaded {
    /// Renders `camera` on `pool` (the calling thread's pool when `None`) once the model's lock
    /// is held and `ready` agrees. The lock is taken on the calling thread, outside the pool,
    /// and the model moved into the pool and back: a pool worker waiting inside a render never
    /// waits for the lock itself.
    pub fn render(
        &self,
        pool: Option<&rayon::ThreadPool>,
        camera: &Camera,
        ready: impl FnOnce() -> Result<(), ViewerError>,
    ) -> Result<RenderedView, ViewerError> {
        let mut slot = self.model.lock().unwrap_or_else(|p| p.into_inner());
        ready()?;
        let model = slot.take().ok_or_else(|| ViewerError::Internal("the model was lost by a failed render; the next checkpoint reloads it".into()))?;
        let bg = self.config.background.eval_color();
        let (model, view) = match pool {
            Some(p) => p.install(move || {
                let v = model.render_view(camera, bg);
                (model, v)
            }),
            None => {
                let v = model.render_view(camera, bg);
                (model, v)
            }
        };
        *slot = Some(model);
        Ok(view)
    }
}

/// The run folder being viewed.
#[derive(Debug)]
pub struct RunWatch {
    run_dir: PathBuf,
    current: RwLock<Option<Arc<Loaded>>>,
    failed: Mutex<Option<(CheckpointKey, String)>>,
    dataset: Mutex<Option<(PathBuf, Arc<Dataset>)>>,
}

impl RunWatch {
    /// Watches `run_dir`; nothing is loaded until [`Self::poll`].
    pub fn new(run_dir: PathBuf) -> Self {
        Self { run_dir, current: RwLock::new(None), failed: Mutex::new(None), dataset: Mutex::new(None) }
    }

    /// The run folder.
    pub fn run_dir(&self) -> &Path {
        &self.run_dir
    }

    /// The model in use, if one is loaded.
    pub fn current(&self) -> Option<Arc<Loaded>> {
        self.current.read().map(|g| g.clone()).unwrap_or_else(|p| p.into_inner().clone())
    }

    /// The newest checkpoint that failed to load and why, when it is still the newest.
    pub fn failure(&self) -> Option<(CheckpointKey, String)> {
        self.failed.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// Loads the newest checkpoint when it differs from the loaded one (and did not fail
    /// before); returns whether a new model is in use.
    pub fn poll(&self) -> bool {
        let Some(newest) = CheckpointKey::newest(&self.run_dir) else { return false };
        if self.current().is_some_and(|l| l.key == newest) {
            return false;
        }
        if self.failure().is_some_and(|(k, _)| k == newest) {
            return false;
        }
        match RunModel::load(&self.run_dir) {
            Ok(model) => {
                // The key of the file actually read: a newer one may have appeared meanwhile.
                let key = CheckpointKey::newest(&self.run_dir).filter(|k| k.path == model.checkpoint).unwrap_or(newest);
                let config = model.config.clone();
                let loaded = Arc::new(Loaded { model: Mutex::new(Some(model)), config, key });
                *self.current.write().unwrap_or_else(|p| p.into_inner()) = Some(loaded);
                *self.failed.lock().unwrap_or_else(|p| p.into_inner()) = None;
                true
            }
            Err(e) => {
                tracing::warn!("{}: {e} (the viewer keeps the model it has)", self.run_dir.display());
                *self.failed.lock().unwrap_or_else(|p| p.into_inner()) = Some((newest, e.to_string()));
                false
            }
        }
    }

    /// The run's config as written now (before any checkpoint exists, the trainer has written it).
    pub fn config(&self) -> Result<TrainConfig, ViewerError> {
        if let Some(l) = self.current() {
            return Ok(l.config.clone());
        }
        let path = self.run_dir.join(CONFIG_FILE);
        if !path.is_file() {
            return Err(ViewerError::Unavailable(format!("{}: no {CONFIG_FILE} yet (has training started?)", self.run_dir.display())));
        }
        TrainConfig::read(&path).map_err(|e| ViewerError::Internal(e.to_string()))
    }

    /// The run's dataset, loaded once per dataset folder (frames outside it are refused).
    pub fn dataset(&self) -> Result<Arc<Dataset>, ViewerError> {
        let dir = self.config()?.dataset;
        let mut slot = self.dataset.lock().unwrap_or_else(|p| p.into_inner());
        if let Some((d, ds)) = slot.as_ref()
            && *d == dir
        {
            return Ok(ds.clone());
        }
        let ds = Arc::new(Dataset::load_with(&dir, &LoadOptions::default()).map_err(|e| ViewerError::Internal(e.to_string()))?);
        *slot = Some((dir, ds.clone()));
        Ok(ds)
    }
}
