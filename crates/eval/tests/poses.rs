//! `eval` of runs trained on noisy or refined poses: the test views' pose protocols on a small
//! analytic dataset.

use dataset::SplitKind;
use nerf::camera_opt::CameraOptConfig;
use nerf::poses::PoseNoise;
use nerf::train::{TrainConfig, Trainer};

fn train(data: &std::path::Path, run: &std::path::Path, noise: Option<PoseNoise>, refine: bool) {
    let cfg = TrainConfig::new(data.to_path_buf(), nerf::models::ModelConfig::Fast(test_support::training::tiny_fast(8, 4)), 256, 1e-2, 1e-3, 400)
        .with_seed(3)
        .with_steps(Some(30))
        .with_val_interval_s(Some(1e9))
        .with_pose_noise(noise)
        .with_camera_opt(refine.then(|| CameraOptConfig { warmup_steps: 0, ..Default::default() }));
    test_support::training::run_to_end(&mut Trainer::new(cfg, run, false).unwrap());
}

/// With exact poses recorded (zero noise), the `aligned` protocol maps the test views by an
/// identity similarity and measures what the plain protocol measures; a refined run reports
/// both pose errors and the named protocol with per-view pose optimisation; asking a run on
/// exact poses for that optimisation is refused with the reason.
#[test]
fn test_views_are_posed_by_a_named_protocol() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    nerf::data::synthetic::write(&data, 24, [6, 1, 2], false).unwrap();
    let opts = eval::EvalRunOptions { mesh: None, ..eval::EvalRunOptions::split(SplitKind::Test) };
    let (plain, zero, refined) = (tmp.path().join("plain"), tmp.path().join("zero"), tmp.path().join("refined"));
    train(&data, &plain, None, false);
    train(&data, &zero, Some(PoseNoise { rotation_deg: 0.0, translation_rel: 0.0 }), false);
    let a = eval::evaluate_run(&plain, &opts, &mut |_, _| {}).unwrap().report;
    let b = eval::evaluate_run(&zero, &opts, &mut |_, _| {}).unwrap().report;
    assert_eq!(a.pose_protocol, None);
    assert_eq!(b.pose_protocol.as_deref(), Some("aligned"));
    assert!(b.train_poses.as_ref().is_some_and(|e| e.rotation_max_deg < 1e-6), "{:?}", b.train_poses);
    for (x, y) in a.views.iter().zip(&b.views) {
        assert!((x.metrics.psnr - y.metrics.psnr).abs() < 1e-3, "{}: {} vs {} dB", x.name, x.metrics.psnr, y.metrics.psnr);
        let (dx, dy) = (x.metrics.depth_mae.unwrap(), y.metrics.depth_mae.unwrap());
        assert!((dx - dy).abs() < 1e-4 * (1.0 + dx), "{}: depth {dx} vs {dy}", x.name);
    }
    train(&data, &refined, Some(PoseNoise { rotation_deg: 1.0, translation_rel: 0.01 }), true);
    let r = eval::evaluate_run(&refined, &eval::EvalRunOptions { test_pose_opt: Some(5), ..opts.clone() }, &mut |_, _| {}).unwrap().report;
    assert_eq!(r.pose_protocol.as_deref(), Some("aligned+test-pose-opt:5"));
    assert!(r.train_poses.is_some() && r.refined_poses.is_some());
    assert!(r.views.iter().all(|v| v.metrics.psnr.is_finite()));
    let e = eval::evaluate_run(&plain, &eval::EvalRunOptions { test_pose_opt: Some(5), ..opts }, &mut |_, _| {}).unwrap_err().to_string();
    assert!(e.contains("--test-pose-opt") && e.contains("exact poses"), "{e}");
}
