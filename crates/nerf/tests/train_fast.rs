//! A `fast` run on a small analytic dataset reaches an honest PSNR on held-out views.

use nerf::models::ModelConfig;
use nerf::models::fast::FastConfig;
use nerf::train::{TrainConfig, Trainer};
use test_support::training::{run_to_end, small_fast, synthetic_dataset};

#[test]
fn fast_reaches_20_db_on_held_out_views() {
    let (tmp, data) = synthetic_dataset(64, [20, 4, 4]);
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
    let s = run_to_end(&mut t);
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
    let (tmp, data) = synthetic_dataset(32, [6, 1, 1]);
    let fast = small_fast(4, 4);
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

/// The distortion loss leaves mixed pixels' rays alone (`RayBatch::mixed`): four steps on
/// batches whose rays are all marked mixed end in the same parameters with the loss on
/// (λ = 0.5) as with it off; with no ray marked, the loss changes them.
#[test]
fn distortion_loss_skips_mixed_pixels() {
    use nerf::data::{Background, SceneBounds, TrainData};
    use nerf::models::{NerfModel, fast::FastModel};
    let (_tmp, data) = synthetic_dataset(32, [6, 1, 1]);
    let ds = nerf::data::load_dataset(&data, &Default::default()).unwrap();
    let train = TrainData::load(&ds.train, 1, Background::White, false).unwrap();
    let cams: Vec<_> = ds.train.iter().map(|f| f.camera).collect();
    let bounds = SceneBounds::for_dataset(ds.facts.as_ref(), &cams, 0.05, 1.5);
    let base = small_fast(2, 2);
    let run = |cfg: FastConfig, mixed: bool| {
        let mut m = FastModel::new(cfg, bounds.clone(), 7).unwrap();
        let mut losses = Vec::new();
        for s in 0..4 {
            let mut b = train.batch(7, s, 512);
            b.mixed = vec![mixed; b.origins.len()];
            let st = m.train_step(&b, s, 7);
            assert!(st.samples > 0 && !st.skipped_nonfinite);
            losses.push(st.loss);
        }
        (losses, m.state())
    };
    let (l_off, off) = run(base.clone(), false);
    let (l_skip, skipped) = run(base.clone().with_distortion_weight(Some(0.5)), true);
    let (l_on, on) = run(base.with_distortion_weight(Some(0.5)), false);
    assert_eq!(l_off, l_skip, "mixed rays add no distortion loss");
    assert!(l_on.iter().zip(&l_off).skip(1).all(|(a, b)| a > b), "unmixed rays do: {l_on:?} vs {l_off:?}");
    let mut changed = 0usize;
    for (k, v) in &off.arrays {
        assert!(v.iter().zip(&skipped.arrays[k]).all(|(x, y)| x == y), "{k}: mixed rays changed the parameters");
        changed += v.iter().zip(&on.arrays[k]).filter(|(x, y)| x != y).count();
    }
    assert!(changed > 0, "the loss on unmixed rays changed no parameter");
}

/// Impossible distortion settings are refused before anything is written, naming the option.
#[test]
fn impossible_distortion_settings_are_refused() {
    let (tmp, data) = synthetic_dataset(16, [2, 1, 1]);
    for (fast, name) in [
        (FastConfig::new().with_distortion_weight(Some(-0.01)), "distortion_weight"),
        (FastConfig::new().with_distortion_weight(Some(f32::NAN)), "distortion_weight"),
        (FastConfig::new().with_distortion_weight(Some(0.01)).with_distortion_mixed_footprints(Some(0.0)), "distortion_mixed_footprints"),
        (FastConfig::new().with_distortion_mixed_footprints(Some(f32::INFINITY)), "distortion_mixed_footprints"),
    ] {
        let cfg = TrainConfig::new(data.clone(), ModelConfig::Fast(fast), 64, 1e-2, 1e-3, 10).with_steps(Some(1));
        let run = tmp.path().join("run");
        let err = match Trainer::new(cfg, &run, false) {
            Ok(_) => panic!("{name}: accepted"),
            Err(e) => e.to_string(),
        };
        assert!(err.contains(name), "{err}");
        assert!(!run.exists(), "nothing written");
    }
}

/// Model, bounds and optimiser settings no model can be built or trained with (a config file
/// may come from a user) are refused before anything is written, naming the field: before
/// these checks some panicked inside the model's constructors, others trained to garbage.
#[test]
fn impossible_model_and_bounds_settings_are_refused() {
    use nerf::data::SceneBounds;
    use nerf::models::paper::PaperConfig;
    let (tmp, data) = synthetic_dataset(16, [2, 1, 1]);
    let fast = |f: FastConfig| TrainConfig::new(data.clone(), ModelConfig::Fast(f), 64, 1e-2, 1e-3, 10).with_steps(Some(1));
    let set = |f: &dyn Fn(&mut TrainConfig)| {
        let mut c = fast(FastConfig::new());
        f(&mut c);
        c
    };
    let bounds = |min: [f32; 3], max: [f32; 3], near: f32, far: f32| SceneBounds { aabb_min: min, aabb_max: max, near, far, source: "test".into() };
    let cases: Vec<(TrainConfig, &str)> = vec![
        (fast(FastConfig::new().with_sh_degree(99)), "model.sh_degree"),
        (fast(FastConfig::new().with_sh_degree(0)), "model.sh_degree"),
        (fast(FastConfig::new().with_levels(0)), "levels must be ≥ 1"),
        (fast(FastConfig::new().with_features_per_level(0)), "features_per_level"),
        (fast(FastConfig::new().with_density_width(0)), "model.density_width"),
        (fast(FastConfig::new().with_color_width(0)), "model.color_width"),
        (fast(FastConfig::new().with_color_depth(0)), "model.color_depth"),
        (fast(FastConfig::new().with_max_samples_per_ray(0)), "model.max_samples_per_ray"),
        (fast(FastConfig::new().with_steps_per_diagonal(0)), "model.steps_per_diagonal"),
        (fast(FastConfig::new().with_grid_update_interval(0)), "model.grid_update_interval"),
        (fast(FastConfig::new().with_grid_decay(2.0)), "model.grid_decay"),
        (fast(FastConfig::new().with_grid_threshold(-1.0)), "model.grid_threshold"),
        (fast(FastConfig::new().with_train_min_transmittance(1.0)), "model.train_min_transmittance"),
        (fast(FastConfig::new().with_cone_angle(Some(f32::NAN))), "model.cone_angle"),
        (fast(FastConfig::new().with_beta1(1.0)), "model.beta1"),
        (fast(FastConfig::new().with_beta2(-0.5)), "model.beta2"),
        (fast(FastConfig::new().with_eps(0.0)), "model.eps"),
        (fast(FastConfig::new()).with_bounds(Some(bounds([2.0; 3], [1.0; 3], 0.1, 5.0))), "aabb_min < aabb_max"),
        (fast(FastConfig::new()).with_bounds(Some(bounds([0.0; 3], [1.0, 0.0, 1.0], 0.1, 5.0))), "aabb_min < aabb_max"),
        (fast(FastConfig::new()).with_bounds(Some(bounds([0.0; 3], [1.0; 3], 6.0, 5.0))), "near < far"),
        (fast(FastConfig::new()).with_bounds(Some(bounds([0.0; 3], [1.0; 3], -1.0, 5.0))), "near < far"),
        (set(&|c: &mut TrainConfig| c.lr_init = -1.0), "lr_init"),
        (set(&|c: &mut TrainConfig| c.lr_final = f64::NAN), "lr_final"),
        (set(&|c: &mut TrainConfig| c.batch_rays = 1 << 30), "batch_rays"),
        (fast(FastConfig::new()).with_bounds_padding(-10.0), "bounds_padding"),
        (fast(FastConfig::new()).with_checkpoints_kept(0), "checkpoints_kept"),
        (
            TrainConfig::new(data.clone(), ModelConfig::Paper(PaperConfig::new().with_coarse_samples(0)), 64, 5e-4, 5e-5, 10).with_steps(Some(1)),
            "model.coarse_samples",
        ),
    ];
    for (cfg, name) in cases {
        let run = tmp.path().join("run");
        let err = match Trainer::new(cfg, &run, false) {
            Ok(_) => panic!("{name}: accepted"),
            Err(e) => e.to_string(),
        };
        assert!(err.contains(name), "{name}: {err}");
        assert!(!run.exists(), "{name}: wrote {}", run.display());
    }
}


/// `pose_noise` perturbs the training views only, as a pure function of (seed, view), records
/// both poses in `train_poses.json`, and the recorded errors measure the noise: rotation
/// errors of the order of σ after alignment, none at zero noise; a noise beyond the limits in a
/// config file is refused by the config check.
#[test]
fn pose_noise_moves_training_poses_and_records_them() {
    let (tmp, data) = synthetic_dataset(16, [12, 1, 1]);
    let noisy = |rot: f64, trans: f64, dir: &str| {
        let cfg = TrainConfig::new(data.clone(), ModelConfig::Fast(small_fast(4, 4)), 64, 1e-2, 1e-3, 100)
            .with_steps(Some(1))
            .with_pose_noise(Some(nerf::poses::PoseNoise { rotation_deg: rot, translation_rel: trans }));
        let run = tmp.path().join(dir);
        run_to_end(&mut Trainer::new(cfg, &run, false).unwrap());
        let text = std::fs::read_to_string(run.join(nerf::poses::POSES_FILE)).unwrap();
        serde_json::from_str::<nerf::poses::PoseRecord>(&text).unwrap()
    };
    let ds = dataset::Dataset::load(&data).unwrap();
    let r = noisy(2.0, 0.01, "two-degrees");
    assert_eq!(r.views.len(), ds.train.len());
    for (v, f) in r.views.iter().zip(&ds.train) {
        assert_eq!(nerf::poses::from_rows(&v.truth), f.camera.c2w, "{}: the truth is the dataset's pose", v.name);
        assert_ne!(v.trained, v.truth, "{}: the trained pose is perturbed", v.name);
    }
    assert_eq!(noisy(2.0, 0.01, "again").views, r.views, "the same seed gives the same poses");
    let e = r.errors().unwrap();
    assert!(e.rotation_median_deg > 0.3 && e.rotation_median_deg < 4.0 && e.rotation_max_deg < 10.0, "{e:?}");
    let zero = noisy(0.0, 0.0, "exact").errors().unwrap();
    assert!(zero.rotation_max_deg < 1e-6 && zero.translation_max < 1e-9, "{zero:?}");
    let bad = TrainConfig::new(data.clone(), ModelConfig::Fast(small_fast(4, 4)), 64, 1e-2, 1e-3, 100)
        .with_steps(Some(1))
        .with_pose_noise(Some(nerf::poses::PoseNoise { rotation_deg: 90.0, translation_rel: 0.0 }));
    let err = bad.check().unwrap_err();
    assert!(err.contains("pose_noise") && err.contains("45"), "{err}");
}

/// Camera refinement records what it learned and stays within its bounds: on noisy poses with
/// one view turned a further 90° (beyond repair), every step stays finite, the wrecked view's
/// correction stops at the bound, the refined poses go to `train_poses.json` and to the
/// nerfstudio-style export, and a resumed run restores the corrections exactly.
#[test]
fn camera_refinement_is_recorded_bounded_and_resumable() {
    let (tmp, data) = synthetic_dataset(16, [8, 1, 1]);
    // Turn view 0 by 90° about its own centre.
    let path = data.join("transforms_train.json");
    let mut t: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let m = &mut t["frames"][0]["transform_matrix"];
    let rows: Vec<Vec<f64>> = serde_json::from_value(m.clone()).unwrap();
    let pose = glam::DMat4::from_cols_array_2d(&std::array::from_fn(|c| std::array::from_fn(|r| rows[r][c])));
    let turned = glam::DMat4::from_translation(pose.w_axis.truncate()) * glam::DMat4::from_rotation_x(std::f64::consts::FRAC_PI_2) * glam::DMat4::from_mat3(glam::DMat3::from_mat4(pose));
    *m = serde_json::json!((0..4).map(|r| (0..4).map(|c| turned.col(c)[r]).collect::<Vec<f64>>()).collect::<Vec<_>>());
    std::fs::write(&path, serde_json::to_string(&t).unwrap()).unwrap();
    let cfg = |steps: u64| {
        TrainConfig::new(data.clone(), ModelConfig::Fast(small_fast(4, 4)), 256, 1e-2, 1e-3, 100)
            .with_steps(Some(steps))
            .with_checkpoint_interval_steps(20)
            .with_pose_noise(Some(nerf::poses::PoseNoise { rotation_deg: 2.0, translation_rel: 0.01 }))
            .with_camera_opt(Some(nerf::camera_opt::CameraOptConfig { lr: 0.05, warmup_steps: 5, ..Default::default() }))
    };
    let run = tmp.path().join("run");
    let mut trainer = Trainer::new(cfg(60), &run, false).unwrap();
    let summary = run_to_end(&mut trainer);
    assert_eq!(trainer.skipped_nonfinite, 0, "a step was not finite");
    let cam = trainer.camera.clone().expect("the run refines its cameras");
    let angle = |p: [f32; 6]| (p[0] as f64).hypot(p[1] as f64).hypot(p[2] as f64).to_degrees();
    assert!(angle(cam.params[0]) <= 15.0 + 1e-3, "the wrecked view's correction ran to {}°", angle(cam.params[0]));
    assert!(cam.params.iter().all(|p| p.iter().all(|x| x.is_finite())) && cam.params.iter().any(|p| angle(*p) > 0.0), "{:?}", cam.params);
    let record: nerf::poses::PoseRecord = serde_json::from_str(&std::fs::read_to_string(run.join(nerf::poses::POSES_FILE)).unwrap()).unwrap();
    assert!(record.is_refined() && record.refined_errors().is_some());
    for (k, v) in record.views.iter().enumerate() {
        let want = cam.corrected_pose(k, &nerf::poses::from_rows(&v.trained));
        assert!(nerf::poses::from_rows(&v.refined.unwrap()).abs_diff_eq(want, 1e-12), "{}: the recorded refined pose", v.name);
        assert_eq!(v.correction, Some(cam.params[k]));
    }
    let export: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(run.join(nerf::poses::CAMERA_OPT_EXPORT)).unwrap()).unwrap();
    let first = &export.as_array().unwrap()[0];
    assert_eq!(first["file_path"], record.views[0].name);
    assert_eq!(serde_json::from_value::<Vec<[f64; 4]>>(first["transform"].clone()).unwrap(), record.views[0].refined.unwrap()[..3].to_vec());
    // Resume from step 60 to 80 and compare with a run of 80 steps from scratch.
    let mut resumed = Trainer::new(cfg(80), &run, true).unwrap();
    assert_eq!(resumed.camera.as_ref().unwrap().params, cam.params, "the checkpoint restores the corrections");
    run_to_end(&mut resumed);
    let straight = tmp.path().join("straight");
    let mut t80 = Trainer::new(cfg(80), &straight, false).unwrap();
    run_to_end(&mut t80);
    assert_eq!(resumed.camera.unwrap().params, t80.camera.unwrap().params, "resumed and uninterrupted runs differ");
    assert!(summary.steps == 60);
}

/// Camera refinement is refused with its reason on fewer than 3 views, and refines the paper
/// model's cameras too.
#[test]
fn camera_refinement_refuses_too_few_views_and_runs_on_the_paper_model() {
    let (tmp, data) = synthetic_dataset(16, [2, 1, 1]);
    let se3 = Some(nerf::camera_opt::CameraOptConfig { warmup_steps: 0, ..Default::default() });
    let few = TrainConfig::new(data.clone(), ModelConfig::Fast(small_fast(4, 4)), 64, 1e-2, 1e-3, 100).with_steps(Some(1)).with_camera_opt(se3);
    let e = Trainer::new(few, &tmp.path().join("few"), false).unwrap_err().to_string();
    assert!(e.contains("at least 3 training views") && e.contains("has 2"), "{e}");
    let (tmp3, data3) = synthetic_dataset(16, [4, 1, 1]);
    let mut paper = TrainConfig::preset("paper", data3).unwrap().with_steps(Some(3)).with_camera_opt(se3);
    paper.batch_rays = 64;
    if let ModelConfig::Paper(p) = &mut paper.model {
        p.coarse_samples = 16;
        p.fine_samples = 16;
    }
    let mut t = Trainer::new(paper, &tmp3.path().join("paper"), false).unwrap();
    run_to_end(&mut t);
    let cam = t.camera.as_ref().unwrap();
    assert!(cam.params.iter().any(|p| p.iter().any(|x| *x != 0.0)), "the paper model's cameras did not move: {:?}", cam.params);
}
