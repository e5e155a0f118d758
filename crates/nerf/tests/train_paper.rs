//! A `paper` run (the published architecture, narrowed for the CPU test budget: 4×64 trunk
//! with the skip at layer 2, 32 + 32 samples, 256 rays) clears a lower PSNR bar on held-out
//! views within its training-time budget.

use nerf::field::NerfFieldConfig;
use nerf::models::ModelConfig;
use nerf::models::paper::PaperConfig;
use nerf::train::{TrainConfig, Trainer};
use test_support::training::{run_to_end, synthetic_dataset};

#[test]
fn paper_reaches_15_db_on_held_out_views() {
    let (tmp, data) = synthetic_dataset(32, [20, 4, 4]);
    let field = NerfFieldConfig::new().with_width(64).with_depth(4).with_skip(2).with_color_width(32);
    let paper = PaperConfig::new().with_field(field).with_coarse_samples(32).with_fine_samples(32);
    let cfg = TrainConfig::new(data, ModelConfig::Paper(paper), 256, 2e-3, 2e-4, 2000)
        .with_time_budget_s(Some(45.0))
        .with_val_max_pixels(4096)
        .with_checkpoint_interval_steps(100_000);
    let run = tmp.path().join("run");
    let mut t = Trainer::new(cfg, &run, false).unwrap();
    let s = run_to_end(&mut t);
    let val = s.val.unwrap();
    eprintln!("paper: steps {} in {:.1}s, val psnr {:.2}, depth mae {:?}", s.steps, s.wall_s, val.val_psnr, val.val_depth_mae);
    assert!(val.val_psnr >= 15.0, "val psnr {}", val.val_psnr);
}
