//! The whole pipeline on a small scene: render (quick, reduced) → train `fast` for a few
//! seconds → eval. Checks that `eval.json` has every documented key with sane values and that
//! the report and pictures exist.

use dataset::SplitKind;
use std::sync::atomic::AtomicBool;
use test_support::render::quick_dataset;

#[test]
fn render_train_eval_writes_a_complete_report() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("dataset");
    let run = tmp.path().join("run");

    quick_dataset(&test_support::scene("tabletop"), &data, 48, [12, 2, 2], 8);
    let stop = AtomicBool::new(false);

    let mut tc = nerf::train::TrainConfig::preset("fast", data.clone()).unwrap();
    tc.steps = Some(40);
    tc.batch_rays = 1024;
    let mut trainer = nerf::train::Trainer::new(tc, &run, false).expect("trainer");
    let summary = trainer.run(&stop, &mut |_| {}).expect("training");
    assert_eq!(summary.steps, 40);
    assert_eq!(summary.skipped_nonfinite, 0);

    let small_mesh = eval::mesh_eval::MeshEvalOptions { resolution: 48, samples: 5_000 };
    let opts = eval::EvalRunOptions { mesh: Some(small_mesh), ..eval::EvalRunOptions::split(SplitKind::Test) };
    let out = eval::evaluate_run(&run, &opts, &mut |_, _| {}).expect("eval");
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("eval.json")).unwrap()).unwrap();
    let mean = &json["mean"];
    for key in [
        "psnr",
        "ssim",
        "depth_mae",
        "depth_rmse",
        "depth_abs_rel",
        "depth_delta_1_25",
        "depth_delta_1_01",
        "mask_iou",
        "off_surface_mass",
        "render_s_per_view",
    ] {
        assert!(mean.get(key).is_some_and(|v| v.is_number()), "mean.{key} missing in {mean}");
    }
    for key in ["train_wall_s", "train_steps", "parameters"] {
        assert!(json.get(key).is_some_and(|v| v.is_number()), "{key} missing");
    }
    assert_eq!(json["views"].as_array().map(Vec::len), Some(2));
    assert_eq!(json["train_steps"], 40);

    // Sane values: 40 steps learn something but are far from perfect; metrics in range.
    let m = &out.report.mean;
    assert!(m.psnr.is_finite() && m.psnr > 8.0 && m.psnr < 60.0, "psnr {}", m.psnr);
    assert!(m.ssim > 0.0 && m.ssim <= 1.0);
    for f in [m.depth_delta_1_25, m.depth_delta_1_01, m.mask_iou, m.off_surface_mass] {
        let f = f.expect("ground-truth metric present");
        assert!((0.0..=1.0).contains(&f), "fraction {f}");
    }
    assert!(m.depth_mae.unwrap() >= 0.0 && m.depth_rmse.unwrap() >= m.depth_mae.unwrap());
    for f in ["report.md", "report.json", "speed_vs_error.png", "grid_r_0.png", "metrics.jsonl", "config.json"] {
        assert!(run.join(f).is_file(), "{f} missing");
    }
    // The mesh against the scene's triangles, or (40 steps may leave no opaque surface) a note
    // saying why there is none.
    match &out.report.mesh {
        Some(b) => {
            let m = &b.metrics;
            assert!(m.accuracy >= 0.0 && m.completeness >= 0.0 && (m.chamfer_l1 - 0.5 * (m.accuracy + m.completeness)).abs() < 1e-12);
            assert_eq!(m.f_scores.len(), 3);
            assert!(m.f_scores.iter().all(|f| (0.0..=1.0).contains(&f.f_score)));
            assert!(b.reference.visible_area_fraction > 0.5 && b.reference.visible_area_fraction <= 1.0, "{:?}", b.reference);
            assert!(json["mesh"]["metrics"]["chamfer_l1"].is_number());
            for f in ["mesh.ply", "mesh_error.png"] {
                assert!(run.join(f).is_file(), "{f} missing");
            }
            assert!(std::fs::read_to_string(run.join("report.md")).unwrap().contains("## Geometry"));
        }
        None => assert!(out.report.notes.iter().any(|n| n.contains("no mesh metrics")), "{:?}", out.report.notes),
    }

    // The same dataset without its scene facts (a third-party dataset with depth): the
    // off-surface tolerance comes from the box around the true surface points the test views
    // see, no larger than the scene's box, and the mass stays a measurement (with a zero
    // tolerance every sample would count as off the surface).
    test_support::strip_scene_facts(&data);
    let bare = eval::evaluate_run(&run, &eval::EvalRunOptions { mesh: None, ..eval::EvalRunOptions::split(SplitKind::Test) }, &mut |_, _| {}).expect("eval without facts");
    let (tol, facts_tol) = (bare.report.surface_tol, out.report.surface_tol);
    eprintln!("surface tolerance {tol} (facts: {facts_tol}), off-surface mass {:?} (facts: {:?})", bare.report.mean.off_surface_mass, m.off_surface_mass);
    assert!(tol > 0.25 * facts_tol && tol <= facts_tol * 1.001, "{tol} vs {facts_tol}");
    let (a, b) = (bare.report.mean.off_surface_mass.unwrap(), m.off_surface_mass.unwrap());
    assert!(a >= b - 1e-9 && a < 1.0, "a smaller tolerance counts at least as much mass off the surface: {a} vs {b}");
    assert!(bare.report.notes.iter().any(|n| n.contains("ground-truth surface points")), "{:?}", bare.report.notes);
}

/// Evaluation happens at the resolution a run trained at: a run trained at downscale 2 and
/// evaluated on its val views reproduces the trainer's own final val PSNR (same views, every
/// pixel, same premultiplied box filter of the targets) to within 0.05 dB; the same run
/// evaluated with downscale 1 is measured on the full-resolution images and labelled so; and
/// the exact ray caster behind even-factor ground truth gives the dataset's own ground-truth
/// files at full resolution and the odd-factor pick at downscale 3.
#[test]
fn eval_measures_at_the_training_resolution() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("dataset");
    let run = tmp.path().join("run");
    quick_dataset(&test_support::scene("tabletop"), &data, 48, [12, 3, 1], 8);
    let stop = AtomicBool::new(false);

    let mut tc = nerf::train::TrainConfig::preset("fast", data.clone()).unwrap();
    (tc.steps, tc.batch_rays, tc.downscale) = (Some(30), 1024, 2);
    (tc.val_max_views, tc.val_max_pixels) = (3, 1 << 20);
    let mut trainer = nerf::train::Trainer::new(tc, &run, false).expect("trainer");
    let summary = trainer.run(&stop, &mut |_| {}).expect("training");
    let val_psnr = summary.val.expect("val metrics").val_psnr;

    // Default: the training downscale. The trainer's val PSNR pools the squared error of every
    // pixel of the three equal-sized views; eval reports per-view PSNRs.
    let opts = eval::EvalRunOptions { mesh: None, ..eval::EvalRunOptions::split(SplitKind::Val) };
    let out = eval::evaluate_run(&run, &opts, &mut |_, _| {}).expect("eval");
    let res = out.report.resolution.expect("resolution recorded");
    assert_eq!((res.width, res.height, res.downscale, res.train_downscale), (24, 24, 2, 2));
    let mse: f64 = out.report.views.iter().map(|v| 10f64.powf(-v.metrics.psnr / 10.0)).sum::<f64>() / out.report.views.len() as f64;
    let pooled = -10.0 * mse.log10();
    eprintln!("trainer val PSNR {val_psnr:.4} dB, eval at downscale 2 {pooled:.4} dB");
    assert!((pooled - val_psnr).abs() < 0.05, "eval {pooled} dB vs the trainer's {val_psnr} dB");
    assert!(out.report.notes.iter().any(|n| n.contains("cast exactly through")), "{:?}", out.report.notes);
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(run.join("eval.json")).unwrap()).unwrap();
    assert_eq!(json["resolution"]["downscale"], 2);
    let summary_json: serde_json::Value = serde_json::from_slice(&std::fs::read(run.join("report.json")).unwrap()).unwrap();
    assert_eq!(summary_json["resolution"]["width"], 24);
    let md = std::fs::read_to_string(run.join("report.md")).unwrap();
    assert!(md.contains("Evaluated at 24x24 (downscale 2, the training resolution)"), "{md}");

    // Downscale 1: the full-resolution figure, labelled as such.
    let full = eval::evaluate_run(&run, &eval::EvalRunOptions { downscale: Some(1), ..opts.clone() }, &mut |_, _| {}).expect("eval at 1");
    let r1 = full.report.resolution.unwrap();
    assert_eq!((r1.width, r1.height, r1.downscale, r1.train_downscale), (48, 48, 1, 2));
    let md = std::fs::read_to_string(run.join("report.md")).unwrap();
    assert!(md.contains("Evaluated at 48x48 (full resolution; trained at downscale 2)"), "{md}");
    assert!(full.report.mean.psnr.is_finite() && (full.report.mean.psnr - out.report.mean.psnr).abs() > 1e-6);

    // A factor that does not divide the views is refused, naming the option.
    let err = eval::evaluate_run(&run, &eval::EvalRunOptions { downscale: Some(5), ..opts }, &mut |_, _| {}).unwrap_err().to_string();
    assert!(err.contains("--downscale 5 does not divide the 48x48 image"), "{err}");

    // The ray caster behind even factors reproduces the dataset's ground truth exactly.
    let ds = dataset::Dataset::load(&data).unwrap();
    let pathtracer::ground_truth::SceneLookup::Found { renderer, .. } = pathtracer::ground_truth::scene_of_dataset(&data, None, &Default::default()).unwrap() else {
        panic!("the scene of a dataset rendered here is found")
    };
    let frame = &ds.val[1];
    let file = dataset::read_ground_truth(frame.gt_path.as_ref().unwrap()).unwrap();
    assert_eq!(renderer.ground_truth(&frame.camera), file);
    assert_eq!(renderer.ground_truth(&frame.camera.downscaled(3)), file.at_downscale(3).unwrap());
}
