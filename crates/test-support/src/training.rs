//! The training tests' set-up: the analytic dataset (`nerf::data::synthetic`) in a temporary
//! folder, the small `fast` configurations the CPU test budget allows, and a run to its end.

use nerf::models::fast::FastConfig;
use nerf::train::{Summary, Trainer};
use std::path::PathBuf;
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
