//! The training tests' set-up: the analytic dataset (`nerf::data::synthetic`) in a temporary
//! folder, the small `fast` configurations the CPU test budget allows, and a run to its end.

use nerf::models::fast::FastConfig;
use nerf::train::{Summary, Trainer};
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

/// A temporary folder holding the analytic dataset at `<tmp>/data` (our layout, with depth and
/// scene facts): `size`×`size` views, `counts` = train, val and test views. The folder lives as
/// long as the returned [`tempfile::TempDir`].
pub fn synthetic_dataset(size: u32, counts: [usize; 3]) -> (tempfile::TempDir, PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    nerf::data::synthetic::write(&data, size, counts, false).unwrap();
    (tmp, data)
}

/// The smallest `fast` model the tests train: 4 hash-grid levels of 2^12 entries up to
/// resolution 64, a 16³ occupancy grid, 64 steps per diagonal; its occupancy grid warms up for
/// `grid_warmup_steps` and is updated every `grid_update_interval` steps.
pub fn tiny_fast(grid_warmup_steps: u64, grid_update_interval: u64) -> FastConfig {
    FastConfig::new()
        .with_levels(4)
        .with_log2_table_size(12)
        .with_finest_resolution(64)
        .with_grid_resolution(16)
        .with_steps_per_diagonal(64)
        .with_grid_warmup_steps(grid_warmup_steps)
        .with_grid_update_interval(grid_update_interval)
}

/// [`tiny_fast`] with 6 levels up to resolution 128: enough detail to test the kernels'
/// arithmetic on every level size.
pub fn small_fast(grid_warmup_steps: u64, grid_update_interval: u64) -> FastConfig {
    FastConfig::new()
        .with_levels(6)
        .with_log2_table_size(12)
        .with_finest_resolution(128)
        .with_grid_resolution(16)
        .with_steps_per_diagonal(64)
        .with_grid_warmup_steps(grid_warmup_steps)
        .with_grid_update_interval(grid_update_interval)
}

/// Runs `trainer` to the end of its budget, never interrupted, without a progress callback.
pub fn run_to_end(trainer: &mut Trainer) -> Summary {
    trainer.run(&AtomicBool::new(false), &mut |_| {}).unwrap()
}

/// Writes the analytic dataset to `dir/data` and a training config for [`tiny_fast`] on it to
/// `dir/train.json` (seed 7, 128 rays per step, a log line every 10 steps, validation only at
/// the end: validation during training is on the wall clock), stopping after `steps` and
/// checkpointing every `checkpoint_every` steps; returns the config's path, for `xtask train
/// --config`.
pub fn write_cli_config(dir: &Path, steps: u64, checkpoint_every: u64) -> PathBuf {
    let data = dir.join("data");
    nerf::data::synthetic::write(&data, 16, [4, 1, 1], false).unwrap();
    let cfg = nerf::train::TrainConfig::new(data, nerf::models::ModelConfig::Fast(tiny_fast(8, 4)), 128, 1e-2, 1e-3, 400)
        .with_seed(7)
        .with_steps(Some(steps))
        .with_log_interval_steps(10)
        .with_checkpoint_interval_steps(checkpoint_every)
        .with_val_interval_s(Some(1e9))
        .with_val_max_pixels(256);
    let path = dir.join("train.json");
    std::fs::write(&path, serde_json::to_string_pretty(&cfg).unwrap()).unwrap();
    path
}
