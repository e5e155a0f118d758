//! Checkpoints: a saved run loads back with identical parameters and renderings, and a run
//! interrupted (as by Ctrl-C) and resumed ends bit-identical to an uninterrupted one.

use nerf::models::ModelConfig;
use nerf::models::fast::FastConfig;
use nerf::render::RunModel;
use nerf::train::{TrainConfig, Trainer};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

fn config(data: &Path, steps: u64) -> TrainConfig {
    let fast = FastConfig::new()
        .with_levels(4)
        .with_log2_table_size(12)
        .with_finest_resolution(64)
        .with_grid_resolution(16)
        .with_steps_per_diagonal(64)
        .with_grid_warmup_steps(8)
        .with_grid_update_interval(4);
    TrainConfig::new(data.to_path_buf(), ModelConfig::Fast(fast), 128, 1e-2, 1e-3, 100)
        .with_steps(Some(steps))
        .with_log_interval_steps(5)
        .with_checkpoint_interval_steps(15)
        .with_val_max_pixels(256)
}

fn train_lines(run: &Path) -> Vec<String> {
    std::fs::read_to_string(run.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .filter_map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).unwrap();
            v.get("loss").map(|loss| format!("{} {} {}", v["step"], loss, v["train_psnr"]))
        })
        .collect()
}

#[test]
fn checkpoint_round_trip_and_exact_resume() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    nerf::data::synthetic::write(&data, 24, [6, 2, 2], false).unwrap();
    let never = AtomicBool::new(false);

    // Uninterrupted: 40 steps.
    let full = tmp.path().join("full");
    let mut a = Trainer::new(config(&data, 40), &full, false).unwrap();
    a.run(&never, &mut |_| {}).unwrap();

    // Interrupted at step 22 through the stop flag (Ctrl-C), then resumed to 40.
    let part = tmp.path().join("part");
    let stop = AtomicBool::new(false);
    let mut b = Trainer::new(config(&data, 40), &part, false).unwrap();
    let s = b.run(&stop, &mut |p| if p.step == 22 { stop.store(true, Ordering::SeqCst) }).unwrap();
    assert!(s.interrupted);
    assert_eq!(s.steps, 22);
    drop(b);
    let mut c = Trainer::resume(&part).unwrap();
    assert_eq!(c.step, 22);
    c.run(&never, &mut |_| {}).unwrap();
    assert_eq!(c.step, 40);
    assert_eq!(a.model.state().arrays, c.model.state().arrays, "resumed parameters differ");
    assert_eq!(train_lines(&full), train_lines(&part), "resumed metrics differ");

    // Round trip: the run folder loads back with the same parameters and renders the same.
    let loaded = RunModel::load(&full).unwrap();
    assert_eq!(loaded.train_steps(), 40);
    assert_eq!(loaded.model.state().arrays, a.model.state().arrays);
    let ds = dataset::Dataset::load(&data).unwrap();
    let cam = ds.test[0].camera;
    let v1 = loaded.render_view(&cam, [1.0; 3]);
    let (o, d): (Vec<_>, Vec<_>) = (0..24 * 24).map(|p| nerf::data::pixel_ray(&cam, p)).unzip();
    let v2 = a.model.render_rays(&o, &d, [1.0; 3]);
    let rgb2: Vec<f32> = v2.rgb.iter().flatten().copied().collect();
    assert_eq!(v1.rgb, rgb2);
    assert_eq!(v1.opacity, v2.opacity);
    assert_eq!(v1.samples.offsets.len(), 24 * 24 + 1);
}
