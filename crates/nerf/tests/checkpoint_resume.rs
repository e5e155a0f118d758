//! Checkpoints: a saved run loads back with identical parameters and renderings, and a run
//! interrupted (as by Ctrl-C) and resumed ends bit-identical to an uninterrupted one.

use nerf::models::ModelConfig;
use nerf::render::RunModel;
use nerf::train::{TrainConfig, Trainer};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use test_support::training::{run_to_end, synthetic_dataset, tiny_fast};

fn config(data: &Path, steps: u64) -> TrainConfig {
    TrainConfig::new(data.to_path_buf(), ModelConfig::Fast(tiny_fast(8, 4)), 128, 1e-2, 1e-3, 100)
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
    let (tmp, data) = synthetic_dataset(24, [6, 2, 2]);
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

/// A run records its dataset's content hash; resuming after a train view's image, a pose, or
/// a val view changed is refused with a message naming the dataset, and an unchanged dataset
/// resumes.
#[test]
fn resume_refuses_a_dataset_whose_views_changed() {
    let (tmp, data) = synthetic_dataset(16, [4, 1, 1]);
    let run = tmp.path().join("run");
    let mut t = Trainer::new(config(&data, 20), &run, false).unwrap();
    run_to_end(&mut t);
    drop(t);
    let recorded = TrainConfig::read(&run.join(nerf::train::CONFIG_FILE)).unwrap().dataset_hash;
    assert!(recorded.as_deref().is_some_and(|h| h.len() == 16), "{recorded:?}");
    assert!(Trainer::resume(&run).is_ok(), "an unchanged dataset resumes");

    let ds = dataset::Dataset::load(&data).unwrap();
    type Edit = (std::path::PathBuf, Box<dyn Fn(&mut Vec<u8>)>);
    let edits: Vec<Edit> = vec![
        // One train image, one byte.
        (ds.train[1].image_path.clone(), Box::new(|b: &mut Vec<u8>| *b.last_mut().unwrap() ^= 1)),
        // The val view's image.
        (ds.val[0].image_path.clone(), Box::new(|b: &mut Vec<u8>| *b.last_mut().unwrap() ^= 1)),
        // A pose: the first train camera moved 1 cm along x.
        (data.join("transforms_train.json"), Box::new(|b: &mut Vec<u8>| {
            let mut v: serde_json::Value = serde_json::from_slice(b).unwrap();
            let x = &mut v["frames"][0]["transform_matrix"][0][3];
            *x = serde_json::json!(x.as_f64().unwrap() + 0.01);
            *b = serde_json::to_vec_pretty(&v).unwrap();
        })),
    ];
    for (path, edit) in edits {
        let before = std::fs::read(&path).unwrap();
        let mut after = before.clone();
        edit(&mut after);
        std::fs::write(&path, &after).unwrap();
        let e = Trainer::resume(&run).err().map(|e| e.to_string()).unwrap_or_default();
        assert!(e.contains("the dataset changed since this run started") && e.contains(&data.display().to_string()), "{}: {e}", path.display());
        std::fs::write(&path, &before).unwrap();
        assert!(Trainer::resume(&run).is_ok(), "restored {}", path.display());
    }
}
