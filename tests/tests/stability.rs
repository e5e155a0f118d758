//! Training stability on hard scenes: the `fast` model (small settings) trained for 2,000 steps
//! on path-traced datasets of the thin-structure scene and of a scene with a tiny, very bright
//! emitter. Every step's loss is finite; the parameters, optimiser state and occupancy grid are
//! finite at the end; the rendered val view and the validation metrics are finite; the count
//! of skipped (non-finite) steps agrees between the trainer and `metrics.jsonl`.

use nerf::models::ModelConfig;
use nerf::train::{TrainConfig, Trainer};
use std::path::Path;
use std::sync::atomic::AtomicBool;
use test_support::render::quick_dataset;
use test_support::training::tiny_fast;

const STEPS: u64 = 2000;

/// The datasets: 24×24 views, 8 train, 1 val, 1 test, 4 spp.
fn render(scene: &Path, out: &Path) {
    quick_dataset(scene, out, 24, [8, 1, 1], 4);
}

/// The tabletop scene with a 2 mm sphere hovering above it that emits 10⁶ (linear radiance):
/// sub-pixel and far brighter than anything else, so its pixels saturate in the display
/// images and dominate the linear ones.
fn write_emitter_scene(dir: &Path) -> std::path::PathBuf {
    let mut b = scenegen::build_scene("tabletop").unwrap();
    let lamp = b.add_material(scenegen::Material::emissive("tiny_lamp", [1.0, 0.95, 0.9], 1e6)).unwrap();
    let mut at = scenegen::Transform::IDENTITY;
    (at.translation.x, at.translation.y, at.translation.z) = (0.1, 0.45, 0.05);
    b.add_mesh("tiny_lamp", scenegen::Mesh::uv_sphere(0.002, 12, 6), lamp, at).unwrap();
    let path = dir.join("emitter.gltf");
    b.write_gltf(&path).unwrap();
    path
}

fn all_finite(s: &nerf::checkpoint::StateDict) -> Option<String> {
    s.arrays
        .iter()
        .find(|(_, v)| v.iter().any(|x| !x.is_finite()))
        .map(|(k, _)| k.clone())
        .or_else(|| s.scalars.iter().find(|(_, v)| !v.is_finite()).map(|(k, _)| k.clone()))
}

/// Trains 2,000 steps and checks every number that comes out.
fn train_and_check(data: &Path, run: &Path, what: &str) {
    let fast = tiny_fast(16, 8);
    // The fast preset (random background, learning rates) with a small model and batch.
    let mut cfg = TrainConfig::preset("fast", data.to_path_buf()).unwrap();
    (cfg.model, cfg.batch_rays, cfg.lr_decay_steps) = (ModelConfig::Fast(fast), 128, STEPS);
    let cfg = cfg
        .with_batch_samples(None)
        .with_steps(Some(STEPS))
        .with_log_interval_steps(50)
        .with_checkpoint_interval_steps(STEPS)
        .with_val_interval_s(Some(1e9));
    let mut t = Trainer::new(cfg, run, false).unwrap();
    let mut nonfinite_losses = 0;
    let summary = t
        .run(&AtomicBool::new(false), &mut |p| {
            if !p.loss.is_finite() {
                nonfinite_losses += 1;
            }
        })
        .unwrap();
    eprintln!(
        "{what}: {} steps in {:.1}s, {} skipped, val PSNR {:?}",
        summary.steps,
        summary.wall_s,
        summary.skipped_nonfinite,
        summary.val.as_ref().map(|v| v.val_psnr)
    );
    assert_eq!(summary.steps, STEPS, "{what}: stopped early");
    assert_eq!(nonfinite_losses, 0, "{what}: {nonfinite_losses} steps had a non-finite loss");
    if let Some(k) = all_finite(&t.model.state()) {
        panic!("{what}: non-finite values in {k} after training");
    }
    let val = summary.val.expect("val view");
    assert!(val.val_psnr.is_finite() && val.val_psnr > 5.0, "{what}: val PSNR {}", val.val_psnr);
    assert!(val.val_depth_mae.is_some_and(f64::is_finite), "{what}: val depth MAE {:?}", val.val_depth_mae);

    // metrics.jsonl: finite numbers throughout (a NaN would be written as null), and its last
    // training line counts the same skipped steps as the trainer.
    let text = std::fs::read_to_string(run.join("metrics.jsonl")).unwrap();
    let mut last_skipped = None;
    for l in text.lines() {
        let v: serde_json::Value = serde_json::from_str(l).unwrap();
        for (k, x) in v.as_object().unwrap() {
            assert!(x.as_f64().is_some_and(f64::is_finite), "{what}: {k} = {x} in {l}");
        }
        if let Some(s) = v.get("skipped_nonfinite") {
            last_skipped = s.as_u64();
        }
    }
    assert_eq!(last_skipped, Some(summary.skipped_nonfinite), "{what}: metrics.jsonl and the trainer disagree");
    assert!(summary.skipped_nonfinite <= STEPS / 100, "{what}: {} steps skipped", summary.skipped_nonfinite);

    // A whole val view renders to finite colour, opacity in [0, 1] and finite depth.
    let ds = dataset::Dataset::load(data).unwrap();
    let cam = ds.val[0].camera;
    let n = (cam.intrinsics.width * cam.intrinsics.height) as usize;
    let (o, d): (Vec<_>, Vec<_>) = (0..n).map(|p| nerf::data::pixel_ray(&cam, p)).unzip();
    let out = t.model.render_rays(&o, &d, [1.0; 3]);
    assert!(out.rgb.iter().flatten().all(|v| v.is_finite()), "{what}: non-finite colour");
    assert!(out.opacity.iter().all(|a| (0.0..=1.0 + 1e-5).contains(a)), "{what}: opacity outside [0, 1]");
    assert!(out.distance.iter().all(|v| v.is_finite()), "{what}: non-finite depth");
}

#[test]
fn fast_trains_2000_finite_steps_on_the_thin_structure_scene() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("thin");
    render(&test_support::scene("thin"), &data);
    train_and_check(&data, &tmp.path().join("run"), "thin");
}

#[test]
fn fast_trains_2000_finite_steps_beside_a_tiny_very_bright_emitter() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = write_emitter_scene(tmp.path());
    let data = tmp.path().join("emitter");
    render(&scene, &data);
    // The emitter is in the data: some linear radiance far above any lit surface's.
    let ds = dataset::Dataset::load(&data).unwrap();
    let peak = ds
        .train
        .iter()
        .map(|f| dataset::read_exr_rgba(f.exr_path.as_ref().unwrap()).unwrap().data.iter().fold(0.0f32, |m, v| m.max(*v)))
        .fold(0.0f32, f32::max);
    assert!(peak > 100.0, "the tiny emitter is not visible in the train views (peak radiance {peak})");
    train_and_check(&data, &tmp.path().join("run"), "tiny bright emitter");
}
