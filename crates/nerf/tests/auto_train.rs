//! `--model auto` end to end on the small analytic dataset: the decisions land in
//! `config.json` with their reasons, a resumed run reads the same model back, and datasets
//! without scene facts get visual-hull bounds and a data-driven view-dependence test.

use nerf::models::ModelConfig;
use nerf::train::{TrainConfig, Trainer};
use std::path::Path;
use test_support::training::{run_to_end, synthetic_dataset};

/// The spheres' true bounding box (see `nerf::data::synthetic`).
const TRUE_MIN: [f32; 3] = [-0.8, -0.6, -0.6];
const TRUE_MAX: [f32; 3] = [1.05, 0.65, 0.95];

fn auto_config(data: &Path, steps: u64) -> TrainConfig {
    let mut cfg = TrainConfig::preset("auto", data.to_path_buf()).unwrap();
    cfg.steps = Some(steps);
    cfg.val_max_pixels = 256;
    cfg.checkpoint_interval_steps = 5;
    cfg
}

fn fast(cfg: &TrainConfig) -> &nerf::models::fast::FastConfig {
    match &cfg.model {
        ModelConfig::Fast(f) => f,
        ModelConfig::Paper(_) => panic!("auto resolved to paper"),
    }
}

#[test]
fn auto_with_scene_facts_records_its_reasons_and_resumes_identically() {
    let (tmp, data) = synthetic_dataset(32, [12, 2, 2]);
    let run = tmp.path().join("run");
    let mut t = Trainer::new(auto_config(&data, 10), &run, false).unwrap();
    let written = TrainConfig::read(&run.join("config.json")).unwrap();
    let reasons = written.auto_reasons.as_ref().unwrap();
    for key in ["bounds", "finest_resolution", "base_resolution", "levels", "log2_table_size", "view_dependent", "grid_resolution", "steps_per_diagonal", "stop when"] {
        assert!(reasons.iter().any(|r| r.starts_with(key)), "no '{key}' reason in {reasons:#?}");
    }
    let f = fast(&written);
    // The analytic scene is Lambertian (its facts say so): no direction input.
    assert!(!f.is_view_dependent());
    // 32-pixel views from 4 units away over a ~2 unit cube: far coarser than the fixed 512.
    assert!(f.finest_resolution < 200 && f.levels < 16, "{f:?}");
    let b = written.bounds.clone().unwrap();
    assert!((0..3).all(|k| b.aabb_min[k] < TRUE_MIN[k] && b.aabb_max[k] > TRUE_MAX[k]), "{b:?}");
    assert!(written.plateau_stop.is_some());
    run_to_end(&mut t);
    assert!(t.model.parameters() < 1 << 22);

    // Resume with more steps: the recorded config is used as is, not sized again.
    let mut cfg = TrainConfig::read(&run.join("config.json")).unwrap();
    cfg.steps = Some(15);
    let mut r = Trainer::new(cfg, &run, true).unwrap();
    assert_eq!(r.step, 10);
    assert_eq!(serde_json::to_value(&r.config.model).unwrap(), serde_json::to_value(&written.model).unwrap());
    assert_eq!(r.config.auto_reasons, written.auto_reasons);
    let s = run_to_end(&mut r);
    assert_eq!(s.steps, 15);
}

#[test]
fn auto_without_facts_uses_the_visual_hull_and_tests_view_dependence_from_depth() {
    let tmp = tempfile::tempdir().unwrap();
    // Blender layout: no facts, no depth → hull bounds, view dependence kept on.
    let blender = tmp.path().join("blender");
    nerf::data::synthetic::write(&blender, 32, [16, 1, 1], true).unwrap();
    let t = Trainer::new(auto_config(&blender, 1), &tmp.path().join("run-b"), false).unwrap();
    let b = t.config.bounds.clone().unwrap();
    assert!(b.source.contains("visual hull"), "{b:?}");
    // The hull holds the spheres and is far tighter than the cameras' 4-unit sphere.
    for k in 0..3 {
        assert!(b.aabb_min[k] <= TRUE_MIN[k] && b.aabb_max[k] >= TRUE_MAX[k], "{b:?}");
        assert!(b.aabb_min[k] > TRUE_MIN[k] - 0.5 && b.aabb_max[k] < TRUE_MAX[k] + 0.5, "{b:?}");
    }
    // Without facts and depth, view dependence stays on until the model's depth can test it.
    assert!(fast(&t.config).is_view_dependent());
    assert_eq!(t.config.view_test_at, Some(256));
    assert!(t.config.auto_reasons.iter().flatten().any(|r| r.contains("until step 256")), "{:#?}", t.config.auto_reasons);

    // Our layout with the facts removed: ground-truth depth lets auto test colour constancy.
    let ours = tmp.path().join("ours");
    nerf::data::synthetic::write(&ours, 32, [16, 1, 1], false).unwrap();
    test_support::strip_scene_facts(&ours);
    assert!(dataset::Dataset::load(&ours).unwrap().facts.is_none());
    let t = Trainer::new(auto_config(&ours, 1), &tmp.path().join("run-o"), false).unwrap();
    assert!(!fast(&t.config).is_view_dependent(), "{:#?}", t.config.auto_reasons);
    assert!(t.config.auto_reasons.iter().flatten().any(|r| r.contains("varies by only")), "{:#?}", t.config.auto_reasons);
}

/// A Blender-layout dataset (no facts, no depth): after `view_test_steps` the trainer measures
/// the colour spread on the depth the model has learned. The Lambertian spheres lose the
/// direction input (and the run resumes with the new model); glossy ones keep it.
#[test]
fn auto_tests_view_dependence_on_the_depth_the_model_learns() {
    let tmp = tempfile::tempdir().unwrap();
    for (gloss, want) in [(0.0, false), (0.8, true)] {
        let data = tmp.path().join(format!("blender-{gloss}"));
        nerf::data::synthetic::write_glossy(&data, 48, [24, 1, 1], true, gloss).unwrap();
        let mut cfg = auto_config(&data, 140);
        cfg.auto.as_mut().unwrap().view_test_steps = Some(120);
        cfg.checkpoint_interval_steps = 50;
        let run = tmp.path().join(format!("run-{gloss}"));
        let mut t = Trainer::new(cfg, &run, false).unwrap();
        assert!(fast(&t.config).is_view_dependent() && t.config.view_test_at == Some(120));
        run_to_end(&mut t);
        let written = TrainConfig::read(&run.join("config.json")).unwrap();
        let reason = written.auto_reasons.iter().flatten().find(|r| r.starts_with("view_dependent")).unwrap().clone();
        eprintln!("gloss {gloss}: {reason}");
        assert_eq!(fast(&written).is_view_dependent(), want, "gloss {gloss}: {reason}");
        assert!(reason.contains("measured on the depth the model learned in 120 steps"), "{reason}");
        assert_eq!(written.view_test_at, None);
        assert_eq!(fast(&t.config).is_view_dependent(), want);
        // The run's checkpoints hold the model its config describes: it resumes.
        let mut cfg = written.clone();
        cfg.steps = Some(150);
        let mut r = Trainer::new(cfg, &run, true).unwrap();
        assert_eq!(r.step, 140);
        assert!(run_to_end(&mut r).val.is_some_and(|v| v.val_psnr.is_finite()));
    }
}

#[test]
fn configs_written_before_auto_still_read() {
    let cfg = TrainConfig::preset("fast", "data".into()).unwrap();
    let mut v = serde_json::to_value(&cfg).unwrap();
    let o = v.as_object_mut().unwrap();
    for k in ["auto", "auto_reasons", "plateau_stop"] {
        assert!(o.remove(k).is_some(), "{k} not written");
    }
    assert!(o["model"].as_object_mut().unwrap().remove("view_dependent").is_some());
    let old: TrainConfig = serde_json::from_value(v).unwrap();
    assert!(old.auto.is_none() && old.auto_reasons.is_none() && old.plateau_stop.is_none());
    // An auto config written before the learned-depth view test reads as today's preset
    // (what `bench auto` compares to keep a run).
    let preset = serde_json::to_value(TrainConfig::preset("auto", "data".into()).unwrap()).unwrap();
    let mut v = preset.clone();
    assert!(v["auto"].as_object_mut().unwrap().remove("view_test_steps").is_some());
    let older: TrainConfig = serde_json::from_value(v).unwrap();
    assert_eq!(serde_json::to_value(&older).unwrap(), preset);
    // Old fast configs had the direction input: their checkpoints keep their shapes.
    assert!(fast(&old).is_view_dependent());
    assert_eq!(old.model_label(), "fast");
    assert_eq!(TrainConfig::preset("auto", "data".into()).unwrap().model_label(), "auto");
    assert!(TrainConfig::preset("magic", "data".into()).unwrap_err().contains("auto"));
}

#[test]
fn the_trainer_stops_when_the_val_psnr_plateaus() {
    let (tmp, data) = synthetic_dataset(16, [6, 1, 1]);
    let mut cfg = TrainConfig::preset("fast", data).unwrap();
    cfg.steps = Some(100_000);
    cfg.val_max_pixels = 64;
    cfg.val_interval_s = Some(0.05);
    // No run gains 100 dB per 0.2 s: the rule must end it once the fitting span (0.4 s) has
    // passed and five validations exist (on a loaded machine one step can outlast the 0.05 s
    // interval: then the last five validations are fitted, about five steps).
    cfg.plateau_stop = Some(nerf::auto::PlateauStop { window_s: 0.2, min_gain_db: 100.0, trend_sigmas: Some(1.0) });
    let mut t = Trainer::new(cfg, &tmp.path().join("run"), false).unwrap();
    let s = run_to_end(&mut t);
    assert!(s.plateaued && !s.interrupted, "{s:?}");
    assert!(s.steps < 100_000 && s.wall_s >= 0.4 && s.wall_s < 5.0, "{s:?}");
}
