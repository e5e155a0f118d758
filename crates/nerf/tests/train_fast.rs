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

/// Training is bit-identical whatever the number of threads: 12 steps (through the occupancy
/// grid's warm-up and two updates, the hash grid and the fused network kernels) with 1 and 3
/// rayon threads end in the same parameters, Adam moments and occupancy grid.
#[test]
fn fast_training_is_bit_identical_across_thread_counts() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    nerf::data::synthetic::write(&data, 32, [6, 1, 1], false).unwrap();
    let fast = FastConfig::new()
        .with_levels(6)
        .with_log2_table_size(12)
        .with_finest_resolution(128)
        .with_grid_resolution(16)
        .with_steps_per_diagonal(64)
        .with_grid_warmup_steps(4)
        .with_grid_update_interval(4);
    let run = |threads: usize| {
        let cfg = TrainConfig::new(data.clone(), ModelConfig::Fast(fast.clone()), 700, 1e-2, 2e-3, 400)
            .with_steps(Some(12))
            .with_val_max_views(0)
            .with_checkpoint_interval_steps(1000);
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let mut t = Trainer::new(cfg, &tmp.path().join(format!("run{threads}")), false).unwrap();
            let samples: Vec<usize> = (0..12).map(|_| t.step_once().samples).collect();
            (samples, t.model.state())
        })
    };
    let (s1, a) = run(1);
    let (s3, b) = run(3);
    assert_eq!(s1, s3);
    assert!(s1.iter().all(|&n| n > 0), "every step trained on samples: {s1:?}");
    assert_eq!(a.arrays.keys().collect::<Vec<_>>(), b.arrays.keys().collect::<Vec<_>>());
    for (k, v) in &a.arrays {
        let w = &b.arrays[k];
        assert!(v.iter().zip(w).all(|(x, y)| x.to_bits() == y.to_bits()), "{k} differs between 1 and 3 threads");
    }
    assert_eq!(a.scalars, b.scalars);
}
