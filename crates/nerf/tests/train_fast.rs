//! A `fast` run on a small analytic dataset reaches an honest PSNR on held-out views.

use nerf::models::ModelConfig;
use nerf::models::fast::FastConfig;
use nerf::train::{TrainConfig, Trainer};
use std::sync::atomic::AtomicBool;

#[test]
fn fast_reaches_20_db_on_held_out_views() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    nerf::data::synthetic::write(&data, 64, [20, 4, 4], false).unwrap();
    let fast = FastConfig::new()
        .with_levels(8)
        .with_log2_table_size(15)
        .with_finest_resolution(256)
        .with_grid_resolution(32)
        .with_steps_per_diagonal(128)
        .with_grid_warmup_steps(64)
        .with_grid_update_interval(8);
    let cfg = TrainConfig::new(data, ModelConfig::Fast(fast), 1024, 1e-2, 2e-3, 400)
        .with_time_budget_s(Some(40.0))
        .with_val_max_pixels(16384)
        .with_checkpoint_interval_steps(1000);
    let run = tmp.path().join("run");
    let mut t = Trainer::new(cfg, &run, false).unwrap();
    let s = t.run(&AtomicBool::new(false), &mut |_| {}).unwrap();
    let val = s.val.unwrap();
    eprintln!("steps {} in {:.1}s, val psnr {:.2}, depth mae {:?}", s.steps, s.wall_s, val.val_psnr, val.val_depth_mae);
    assert!(run.join("config.json").is_file());
    let metrics = std::fs::read_to_string(run.join("metrics.jsonl")).unwrap();
    assert!(metrics.contains("train_psnr") && metrics.contains("val_psnr"));
    assert!(val.val_psnr >= 20.0, "val psnr {}", val.val_psnr);
}
