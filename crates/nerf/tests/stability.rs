//! A step with a non-finite value is skipped, counted in `metrics.jsonl`, and training goes on:
//! one training pixel is made NaN, so exactly the steps whose batch draws it produce a NaN loss.

use nerf::models::ModelConfig;
use nerf::train::{TrainConfig, Trainer};
use std::sync::atomic::AtomicBool;
use test_support::training::{synthetic_dataset, tiny_fast};

const STEPS: u64 = 60;
const RAYS: usize = 128;

fn all_finite(s: &nerf::checkpoint::StateDict) -> bool {
    s.arrays.values().flatten().all(|v| v.is_finite()) && s.scalars.values().all(|v| v.is_finite())
}

#[test]
fn a_nan_target_pixel_skips_exactly_its_steps_and_training_continues() {
    let (tmp, data) = synthetic_dataset(16, [3, 1, 0]);
    let cfg = TrainConfig::new(data, ModelConfig::Fast(tiny_fast(8, 4)), RAYS, 1e-2, 1e-3, 100)
        .with_seed(3)
        .with_steps(Some(STEPS))
        .with_log_interval_steps(10)
        .with_val_max_pixels(256);
    let run = tmp.path().join("run");
    let mut t = Trainer::new(cfg, &run, false).unwrap();

    // The pixel at the centre of view 0 (on the big sphere) becomes NaN; the steps that draw it
    // follow from the counter-based batches.
    let p = 8 * 16 + 8;
    t.data.views[0].rgba[p] = [f32::NAN; 4];
    let poisoned: Vec<u64> = (0..STEPS)
        .filter(|&s| t.data.batch(t.config.seed, s, RAYS).target.iter().flatten().any(|v| !v.is_finite()))
        .collect();
    assert!(
        !poisoned.is_empty() && poisoned.len() < STEPS as usize / 2,
        "the NaN pixel should be drawn by some steps, not most: {poisoned:?}"
    );

    let before = t.model.state();
    let mut nonfinite_at = Vec::new();
    let summary = t
        .run(&AtomicBool::new(false), &mut |p| {
            if !p.loss.is_finite() {
                nonfinite_at.push(p.step - 1);
            }
        })
        .unwrap();
    assert_eq!(summary.steps, STEPS, "training stopped early");
    assert_eq!(nonfinite_at, poisoned, "the steps with a non-finite loss are not those drawing the NaN pixel");
    assert_eq!(summary.skipped_nonfinite, poisoned.len() as u64, "skipped steps miscounted");

    // Parameters, optimiser state and occupancy grid stay finite, and they moved.
    let after = t.model.state();
    assert!(all_finite(&after), "non-finite parameters after training");
    assert!(before.arrays != after.arrays, "training did not update the model");
    let val = summary.val.expect("val views");
    assert!(val.val_psnr.is_finite(), "val PSNR {}", val.val_psnr);

    // metrics.jsonl: each training line counts the skips before its step; every loss is finite.
    let text = std::fs::read_to_string(run.join("metrics.jsonl")).unwrap();
    let mut lines = 0;
    for l in text.lines() {
        let v: serde_json::Value = serde_json::from_str(l).unwrap();
        let Some(loss) = v.get("loss") else { continue };
        let step = v["step"].as_u64().unwrap();
        let want = poisoned.iter().filter(|&&s| s < step).count() as u64;
        assert_eq!(v["skipped_nonfinite"].as_u64(), Some(want), "line at step {step}: {l}");
        assert!(loss.as_f64().is_some_and(f64::is_finite), "line at step {step}: loss not finite: {l}");
        lines += 1;
    }
    assert_eq!(lines, STEPS / 10);

    // Replayed: a skipped step leaves the parameters and optimiser state as they were (the
    // occupancy grid still follows its step schedule), and the next clean step updates them.
    let first = *poisoned.iter().find(|&&s| !poisoned.contains(&(s + 1))).unwrap();
    let mut replay = Trainer::new(t.config.clone(), &tmp.path().join("replay"), false).unwrap();
    replay.data.views[0].rgba[p] = [f32::NAN; 4];
    while replay.step < first {
        replay.step_once();
    }
    let learned = |t: &Trainer| {
        let mut s = t.model.state();
        s.arrays.retain(|k, _| !k.starts_with("occupancy."));
        s.scalars.retain(|k, _| !k.starts_with("occupancy."));
        s
    };
    let s0 = learned(&replay);
    let skipped_before = replay.skipped_nonfinite;
    let stats = replay.step_once();
    assert!(!stats.loss.is_finite() && replay.skipped_nonfinite == skipped_before + 1);
    assert!(learned(&replay) == s0, "a skipped step changed the parameters or optimiser state");
    let stats = replay.step_once();
    assert!(stats.loss.is_finite() && !stats.skipped_nonfinite);
    assert!(learned(&replay).arrays != s0.arrays, "training did not continue after the skipped step");
}

/// Depth targets planted with huge values, infinities and NaN (past the trainer's clamping)
/// leave every step of both models finite, the fast model's with the normal term too: no step is skipped, the loss is finite, and the
/// parameters stay finite and move.
#[test]
fn huge_and_nan_depth_targets_keep_every_step_finite() {
    use nerf::supervision::{DepthLoss, SupervisionConfig};
    let paper = {
        let field = nerf::field::NerfFieldConfig::new().with_width(32).with_depth(2).with_skip(1).with_color_width(16);
        ModelConfig::Paper(nerf::models::paper::PaperConfig::new().with_field(field).with_coarse_samples(16).with_fine_samples(16))
    };
    let fast = || ModelConfig::Fast(tiny_fast(8, 4));
    for (model, kind, normal) in [(fast(), DepthLoss::Expected, 0.0), (fast(), DepthLoss::Termination, 0.0), (fast(), DepthLoss::Expected, 1.0), (paper, DepthLoss::Expected, 0.0)] {
        let (tmp, data) = synthetic_dataset(16, [3, 1, 0]);
        let sup = SupervisionConfig::new().with_depth_loss(kind).with_depth_weight(1.0).with_empty_weight(1.0).with_normal_weight(normal);
        let cfg = TrainConfig::new(data, model, RAYS, 1e-2, 1e-3, 100).with_seed(3).with_steps(Some(20)).with_val_max_pixels(64).with_supervision(Some(sup));
        let mut t = Trainer::new(cfg, &tmp.path().join("run"), false).unwrap();
        let planted = [1e30f32, f32::MAX, f32::NAN, f32::INFINITY, -1e30, 0.0, 1e-3];
        let targets = t.data.depth_targets_mut().expect("supervised");
        let mut n = 0;
        for view in targets.iter_mut() {
            for (p, d) in view.iter_mut().enumerate() {
                if p % 2 == 0 {
                    *d = planted[p / 2 % planted.len()];
                    n += 1;
                }
            }
        }
        assert!(n > 100);
        let before = t.model.state();
        let mut losses = Vec::new();
        let summary = t.run(&AtomicBool::new(false), &mut |p| losses.push(p.loss)).unwrap();
        assert_eq!(summary.skipped_nonfinite, 0, "{kind:?}: steps skipped");
        assert!(losses.iter().all(|l| l.is_finite()), "{kind:?}: {losses:?}");
        let after = t.model.state();
        assert!(all_finite(&after) && before.arrays != after.arrays, "{kind:?}: parameters not finite or not updated");
    }
}
