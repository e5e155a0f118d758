//! `eval::score` on small analytic datasets (`nerf::data::synthetic`, 24x24 views with exact
//! ground truth): known answers for colour, depth and opacity in each layout it reads, and one
//! clear refusal for each kind of bad input. Every fixture is written by the test in the
//! tool's own naming.

use dataset::SplitKind;
use eval::predictions::DepthKind;
use eval::prediction_io::npy_bytes;
use eval::truth::{GroundTruthSource, TruthView, load_truth};
use eval::{ScoreOptions, score};
use std::path::{Path, PathBuf};

const SIZE: u32 = 24;

/// The analytic dataset (2 train, 1 val, 3 test views of 24x24) in `dir/data`.
fn dataset(dir: &Path) -> PathBuf {
    let data = dir.join("data");
    nerf::data::synthetic::write(&data, SIZE, [2, 1, 3], false).unwrap();
    data
}

fn options(data: &Path, pred: &Path, out: &Path) -> ScoreOptions {
    ScoreOptions {
        dataset: data.to_path_buf(),
        predictions: pred.to_path_buf(),
        out: out.to_path_buf(),
        method: "m".into(),
        split: SplitKind::Test,
        train_seconds: Some(12.0),
        hardware: Some("a test".into()),
        downscale: None,
        depth_kind: None,
        depth_scale: None,
        allow_missing: false,
        background: [1.0; 3],
        scene: None,
        dataparser_transforms: None,
        grid_views: 1,
        geometry: None,
        geometry_frame: eval::GeometryFrame::Tool,
        geometry_samples: 1000,
        allow_outside: false,
    }
}

/// The test views' ground truth at `downscale`, composited on white.
fn truths(data: &Path, downscale: u32) -> Vec<(dataset::Frame, TruthView)> {
    let ds = dataset::Dataset::load(data).unwrap();
    let err = |m: String| eval::EvalError::Input(m);
    ds.test.iter().map(|f| (f.clone(), load_truth(f, [1.0; 3], downscale, &GroundTruthSource::File, &err).unwrap())).collect()
}

fn write_npy(path: &Path, shape: &[usize], values: &[f32]) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, npy_bytes(shape, values)).unwrap();
}

fn write_npy_gz(path: &Path, shape: &[usize], values: &[f32]) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    std::io::Write::write_all(&mut gz, &npy_bytes(shape, values)).unwrap();
    std::fs::write(path, gz.finish().unwrap()).unwrap();
}

/// Standard normal numbers from a fixed seed (SplitMix64 and Box-Muller).
fn gaussians(seed: u64, n: usize) -> Vec<f64> {
    let mut s = seed;
    let mut next = || {
        s = s.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = s;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..n).map(|_| (-2.0 * (1.0 - next()).ln()).sqrt() * (std::f64::consts::TAU * next()).cos()).collect()
}

/// PSNR from the squared errors actually written, as the formula gives it.
fn psnr_of(pred: &[f32], gt: &[f32]) -> f64 {
    let mse = pred.iter().zip(gt).map(|(&p, &g)| (f64::from(p) - f64::from(g)).powi(2)).sum::<f64>() / pred.len() as f64;
    -10.0 * mse.log10()
}

/// Ground truth plus seeded Gaussian noise of sigma 0.05 scores the PSNR the formula gives for
/// the noise realisation written, to 0.01 dB: as float `.npy` (no clipping, no quantisation;
/// also within 0.3 dB of -10 log10(sigma^2), the sampling spread of 1,728 values a view) and as
/// 16-bit PNG (the realisation clipped to [0, 1] and quantised, computed from the values
/// written).
#[test]
fn ground_truth_plus_gaussian_noise_scores_the_formulas_psnr() {
    let tmp = tempfile::tempdir().unwrap();
    let data = dataset(tmp.path());
    let sigma = 0.05;
    for (k, float) in [(0u64, true), (1, false)] {
        let pred = tmp.path().join(format!("noisy{k}"));
        let mut want = Vec::new();
        for (v, (frame, t)) in truths(&data, 1).iter().enumerate() {
            let noise = gaussians(1000 * k + v as u64, t.gt_rgb.len());
            let noisy: Vec<f32> = t.gt_rgb.iter().zip(&noise).map(|(&g, n)| (f64::from(g) + sigma * n) as f32).collect();
            if float {
                write_npy(&pred.join(format!("{}.npy", frame.name)), &[t.height, t.width, 3], &noisy);
                want.push(psnr_of(&noisy, &t.gt_rgb));
                assert!((psnr_of(&noisy, &t.gt_rgb) + 10.0 * (sigma * sigma).log10()).abs() < 0.3);
            } else {
                let q: Vec<u16> = noisy.iter().map(|v| (v.clamp(0.0, 1.0) * 65535.0).round() as u16).collect();
                let written: Vec<f32> = q.iter().map(|&v| f32::from(v) / 65535.0).collect();
                std::fs::create_dir_all(&pred).unwrap();
                image::ImageBuffer::<image::Rgb<u16>, _>::from_raw(t.width as u32, t.height as u32, q).unwrap().save(pred.join(format!("{}.png", frame.name))).unwrap();
                want.push(psnr_of(&written, &t.gt_rgb));
            }
        }
        let out = score(&options(&data, &pred, &tmp.path().join(format!("out{k}"))), &mut |_, _| {}).unwrap();
        assert_eq!(out.layout.tool.name(), "images");
        for (view, w) in out.report.views.iter().zip(&want) {
            assert!((view.metrics.psnr - w).abs() < 0.01, "float {float}: {} dB scored, {w} dB from the noise written", view.metrics.psnr);
        }
        assert!(out.report.views.iter().all(|v| v.metrics.depth_mae.is_none() && v.metrics.mask_iou.is_none()));
    }
}

/// A point of the dataset mapped into nerfstudio's frame and back is itself; lengths scale by
/// `s`. instant-ngp's map is `cycle(p s + o)`; its saved meshes are `(cycle(p s + o) − o) / s`.
#[test]
fn tool_frames_map_back_to_the_dataset() {
    let json = r#"{"transform": [[0.0, -1.0, 0.0, 0.25], [0.0, 0.0, 1.0, -0.5], [-1.0, 0.0, 0.0, 1.0]], "scale": 0.4}"#;
    let t = eval::interop::NerfstudioTransform::parse(json, Path::new("dataparser_transforms.json")).unwrap();
    let p = glam::DVec3::new(0.3, -1.2, 2.5);
    let ns = t.to_nerfstudio().transform_point3(p);
    assert!((ns - 0.4 * glam::DVec3::new(1.2 + 0.25, 2.5 - 0.5, -0.3 + 1.0)).length() < 1e-12, "{ns}");
    assert!((t.to_dataset().transform_point3(ns) - p).length() < 1e-12);
    assert_eq!(t.length_to_dataset(0.8), 2.0);
    let e = eval::interop::NerfstudioTransform::parse(r#"{"transform": [[1, 0, 0]], "scale": 1}"#, Path::new("d.json")).unwrap_err().to_string();
    assert!(e.starts_with("d.json: ") && e.contains("3 rows of 4"), "{e}");
    let ngp = eval::interop::InstantNgpTransform::from_json(&serde_json::json!({"scale": 0.5, "offset": [0.1, 0.2, 0.3]}), Path::new("t.json")).unwrap();
    let q = ngp.to_instant_ngp().transform_point3(p);
    let s = p * 0.5 + glam::DVec3::new(0.1, 0.2, 0.3);
    assert!((q - glam::DVec3::new(s.y, s.z, s.x)).length() < 1e-12, "{q}");
    assert!((ngp.to_dataset().transform_point3(q) - p).length() < 1e-12);
    // `--save_mesh` writes (q - offset) / scale, axes still cycled.
    let saved = (q - glam::DVec3::new(0.1, 0.2, 0.3)) / 0.5;
    assert!((ngp.mesh_to_dataset().transform_point3(saved) - p).length() < 1e-12);
    let d = eval::interop::InstantNgpTransform::from_json(&serde_json::json!({}), Path::new("t.json")).unwrap();
    assert_eq!((d.scale, d.offset), (0.33, [0.5; 3]));
}

/// nerfstudio's `ns-render dataset` layout: colour in `test/rgb/` (PNG), opacity in
/// `test/raw-accumulation/` (`.npy.gz`, H x W x 1), and depth as the distance along the ray,
/// either in nerfstudio's scaled frame (`depth/`, `.npy`, with `dataparser_transforms.json`) or
/// in metres (`raw-depth/`, `.npy.gz`, as ns-render writes it): depth MAE 0 to float precision,
/// mask IoU 1, PSNR +inf.
#[test]
fn nerfstudio_renders_score_exactly_after_its_transform() {
    let tmp = tempfile::tempdir().unwrap();
    let data = dataset(tmp.path());
    let s = 0.37;
    for raw in [false, true] {
        let pred = tmp.path().join(format!("ns-{raw}"));
        let test = pred.join("test");
        std::fs::create_dir_all(test.join("rgb")).unwrap();
        for (frame, t) in truths(&data, 1) {
            let g = t.gt.as_ref().unwrap();
            let shape = [t.height, t.width, 1];
            let rgb: Vec<u8> = t.gt_rgb.iter().map(|v| (v * 255.0).round() as u8).collect();
            image::RgbImage::from_raw(t.width as u32, t.height as u32, rgb).unwrap().save(test.join("rgb").join(format!("{}.png", frame.name))).unwrap();
            write_npy_gz(&test.join("raw-accumulation").join(format!("{}.npy.gz", frame.name)), &shape, &g.alpha);
            if raw {
                write_npy_gz(&test.join("raw-depth").join(format!("{}.npy.gz", frame.name)), &shape, &g.distance);
            } else {
                let scaled: Vec<f32> = g.distance.iter().map(|d| (f64::from(*d) * s) as f32).collect();
                write_npy(&test.join("depth").join(format!("{}.npy", frame.name)), &shape, &scaled);
            }
        }
        let transform = format!(r#"{{"transform": [[1.0, 0.0, 0.0, 0.1], [0.0, 0.0, -1.0, 0.2], [0.0, 1.0, 0.0, 0.3]], "scale": {s}}}"#);
        std::fs::write(pred.join("dataparser_transforms.json"), transform).unwrap();
        let out = score(&options(&data, &pred, &tmp.path().join(format!("out-{raw}"))), &mut |_, _| {}).unwrap();
        assert_eq!(out.layout.tool.name(), "nerfstudio");
        let m = &out.report.mean;
        assert!(m.depth_mae.unwrap() < 2e-6, "depth MAE {:?} ({})", m.depth_mae, out.layout.description);
        assert_eq!(m.depth_delta_1_01, Some(1.0));
        assert_eq!(m.mask_iou, Some(1.0));
        assert!(m.psnr > 48.0, "8-bit copy of the ground truth: {} dB", m.psnr);
        let method = out.report.method.as_ref().unwrap();
        let depth = method.depth.as_ref().unwrap();
        assert_eq!((depth.kind.as_str(), depth.kind_stated), ("distance", false));
        assert!((depth.metres_per_unit - if raw { 1.0 } else { 1.0 / s }).abs() < 1e-12);
        assert_eq!(method.files_read.len(), 9);
        assert!(method.files_read[0].starts_with("test/rgb/r_0.png"), "{:?}", method.files_read);
        let json: serde_json::Value = serde_json::from_slice(&std::fs::read(tmp.path().join(format!("out-{raw}/eval.json"))).unwrap()).unwrap();
        assert_eq!(json["method"]["tool"], "nerfstudio");
        assert_eq!(json["method"]["train_seconds"], 12.0);
        assert!(json["method"]["layout"].as_str().unwrap().contains(if raw { "raw-depth" } else { "depth/ (nerfstudio's units)" }));
    }
    // Stating z for a distance map is taken at its word: the depth is then wrong, and says so.
    let mut o = options(&data, &tmp.path().join("ns-true"), &tmp.path().join("out-z"));
    o.depth_kind = Some(DepthKind::Z);
    let z = score(&o, &mut |_, _| {}).unwrap();
    assert!(z.report.mean.depth_mae.unwrap() > 1e-3);
    // Colour-mapped depth pictures are no depth: scored without depth, with a note.
    let pred = tmp.path().join("ns-false");
    std::fs::remove_dir_all(pred.join("test/depth")).unwrap();
    std::fs::create_dir_all(pred.join("test/depth")).unwrap();
    std::fs::copy(pred.join("test/rgb/r_0.png"), pred.join("test/depth/r_0.jpg")).unwrap();
    let out = score(&options(&data, &pred, &tmp.path().join("out-pictures")), &mut |_, _| {}).unwrap();
    assert!(out.report.mean.depth_mae.is_none());
    assert!(out.report.notes.iter().any(|n| n.contains("colour-mapped depth pictures")), "{:?}", out.report.notes);
}

/// instant-ngp's screenshots: RGBA PNGs named by each frame's file_path basename, with the
/// transforms file they were taken from beside them. The dataset's own PNGs as predictions
/// composite exactly as eval composites the ground truth (PSNR +inf); depth in instant-ngp's
/// units (z times its scale) scores 0.
#[test]
fn instant_ngp_screenshots_and_their_units() {
    let tmp = tempfile::tempdir().unwrap();
    let data = dataset(tmp.path());
    let pred = tmp.path().join("screenshots");
    std::fs::create_dir_all(&pred).unwrap();
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(data.join("transforms_test.json")).unwrap()).unwrap();
    let scale = json["scale"].as_f64().unwrap();
    std::fs::copy(data.join("transforms_test.json"), pred.join("transforms_test.json")).unwrap();
    for (frame, t) in truths(&data, 1) {
        std::fs::copy(&frame.image_path, pred.join(format!("{}.png", frame.name))).unwrap();
        let z: Vec<f32> = t.gt.as_ref().unwrap().depth.iter().map(|d| (f64::from(*d) * scale) as f32).collect();
        write_npy(&pred.join(format!("{}_depth.npy", frame.name)), &[t.height, t.width], &z);
    }
    let out = score(&options(&data, &pred, &tmp.path().join("out")), &mut |_, _| {}).unwrap();
    assert_eq!(out.layout.tool.name(), "instant-ngp");
    assert_eq!(out.report.mean.psnr, f64::INFINITY);
    assert!(out.report.mean.depth_mae.unwrap() < 1e-6);
    assert!(out.report.mean.mask_iou.unwrap() > 0.9, "alpha of the dataset's PNGs as opacity");
    assert!(out.report.notes.iter().any(|n| n.contains("transforms_test.json beside the predictions")), "{:?}", out.report.notes);
    assert!(out.report.method.as_ref().unwrap().depth.as_ref().unwrap().unit_source.contains("instant-ngp"));
}

/// A folder of images: linear EXR (premultiplied, as our datasets write it) converted to display
/// colour as the dataset's PNG is made from it; JPEG; and predictions at half resolution with
/// `--downscale 2`, scored at that resolution against the box-filtered ground truth.
#[test]
fn images_in_exr_jpeg_and_at_a_downscale() {
    let tmp = tempfile::tempdir().unwrap();
    let data = dataset(tmp.path());
    let (exr, jpg, half) = (tmp.path().join("exr"), tmp.path().join("jpg"), tmp.path().join("half"));
    for d in [&exr, &jpg, &half] {
        std::fs::create_dir_all(d).unwrap();
    }
    for (frame, t) in truths(&data, 1) {
        let png = dataset::read_png_rgba(&frame.image_path).unwrap();
        let mut linear = png.clone();
        for p in linear.data.chunks_exact_mut(4) {
            for c in 0..3 {
                p[c] = dataset::srgb_to_linear(p[c]) * p[3];
            }
        }
        dataset::write_exr_rgba(&exr.join(format!("{}.exr", frame.name)), &linear).unwrap();
        let rgb: Vec<u8> = t.gt_rgb.iter().map(|v| (v * 255.0).round() as u8).collect();
        image::RgbImage::from_raw(SIZE, SIZE, rgb).unwrap().save(jpg.join(format!("{}.jpg", frame.name))).unwrap();
    }
    for (frame, t) in truths(&data, 2) {
        write_npy(&half.join(format!("{}.npy", frame.name)), &[t.height, t.width, 3], &t.gt_rgb);
    }
    let e = score(&options(&data, &exr, &tmp.path().join("o1")), &mut |_, _| {}).unwrap();
    assert!(e.report.mean.psnr > 60.0, "EXR round trip: {} dB", e.report.mean.psnr);
    assert!(e.layout.description.contains("<view>.exr"), "{}", e.layout.description);
    let j = score(&options(&data, &jpg, &tmp.path().join("o2")), &mut |_, _| {}).unwrap();
    assert!(j.report.mean.psnr > 25.0 && j.report.mean.psnr.is_finite(), "{}", j.report.mean.psnr);
    let mut o = options(&data, &half, &tmp.path().join("o3"));
    o.downscale = Some(2);
    let h = score(&o, &mut |_, _| {}).unwrap();
    let r = h.report.resolution.unwrap();
    assert_eq!((r.width, r.height, r.downscale), (12, 12, 2));
    assert_eq!(h.report.mean.psnr, f64::INFINITY);
    // Without --downscale the half-size files are refused, naming the file and the factor.
    let e = score(&options(&data, &half, &tmp.path().join("o4")), &mut |_, _| {}).unwrap_err().to_string();
    assert!(e.contains("r_0.npy: is 12x12, the view is 24x24") && e.contains("give --downscale 2"), "{e}");
}

/// Bad input: each refusal is one sentence naming the file or what is missing, and nothing is
/// written (neither the output folder nor anything in the dataset folder).
#[test]
fn bad_predictions_are_refused_naming_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    let data = dataset(tmp.path());
    let before = test_files(&data);
    let good = tmp.path().join("good");
    std::fs::create_dir_all(&good).unwrap();
    for (frame, t) in truths(&data, 1) {
        write_npy(&good.join(format!("{}.npy", frame.name)), &[t.height, t.width, 3], &t.gt_rgb);
    }
    let case = |name: &str, change: &dyn Fn(&Path)| -> String {
        let pred = tmp.path().join(name);
        copy_dir(&good, &pred);
        change(&pred);
        let out = tmp.path().join(format!("out-{name}"));
        let e = score(&options(&data, &pred, &out), &mut |_, _| {}).unwrap_err().to_string();
        assert!(!out.exists(), "{name}: a refusal wrote {}", out.display());
        assert!(!e.contains('\n'), "{name}: {e}");
        e
    };
    let e = case("missing", &|p| std::fs::remove_file(p.join("r_1.npy")).unwrap());
    assert!(e.contains("1 of the 3 test views have no prediction (r_1)") && e.contains("--allow-missing"), "{e}");
    let e = case("extra", &|p| std::fs::copy(p.join("r_0.npy"), p.join("r_7.npy")).map(|_| ()).unwrap());
    assert!(e.contains("r_7.npy: names no test view"), "{e}");
    let e = case("twice", &|p| std::fs::write(p.join("r_2.png"), b"x").unwrap());
    assert!(e.contains("two colour predictions for view r_2"), "{e}");
    let e = case("mis-sized", &|p| write_npy(&p.join("r_2.npy"), &[20, 24, 3], &[0.5; 20 * 24 * 3]));
    assert!(e.contains("r_2.npy: is 24x20, the view is 24x24"), "{e}");
    let e = case("unreadable", &|p| std::fs::write(p.join("r_2.npy"), b"\x93NUMPY garbage").unwrap());
    assert!(e.contains("r_2.npy: not a .npy array"), "{e}");
    let e = case("partial-depth", &|p| write_npy(&p.join("r_0_depth.npy"), &[24, 24], &[1.0; 576]));
    assert!(e.contains("view r_1 has a colour prediction") && e.contains("but no depth"), "{e}");
    let e = case("unknown", &|p| {
        std::fs::remove_dir_all(p).unwrap();
        std::fs::create_dir_all(p).unwrap();
        std::fs::write(p.join("README.txt"), b"renders").unwrap();
    });
    assert!(e.contains("no predictions found: looked for nerfstudio's `ns-render dataset` output (test/rgb/") && e.contains("r_0, r_1, …"), "{e}");
    // A transforms file beside them for another dataset: another view count, size or pose.
    let transforms: serde_json::Value = serde_json::from_slice(&std::fs::read(data.join("transforms_test.json")).unwrap()).unwrap();
    let with = |edit: &dyn Fn(&mut serde_json::Value)| {
        let mut t = transforms.clone();
        edit(&mut t);
        move |p: &Path| std::fs::write(p.join("transforms_test.json"), serde_json::to_vec(&t).unwrap()).unwrap()
    };
    let e = case("count", &with(&|t| drop(t["frames"].as_array_mut().unwrap().pop())));
    assert!(e.contains("transforms_test.json: describes 2 test views, the dataset has 3"), "{e}");
    let e = case("size", &with(&|t| t["w"] = 32.into()));
    assert!(e.contains("its views are 32x24, the dataset's are 24x24"), "{e}");
    let e = case("pose", &with(&|t| t["frames"][1]["transform_matrix"][0][3] = 9.0.into()));
    assert!(e.contains("the pose of ./test/r_1 differs from the dataset's view r_1"), "{e}");
    // With --allow-missing a missing view is recorded and left out; the dataset is untouched.
    let pred = tmp.path().join("missing");
    let mut o = options(&data, &pred, &tmp.path().join("out-allowed"));
    o.allow_missing = true;
    let out = score(&o, &mut |_, _| {}).unwrap();
    assert_eq!(out.report.views.len(), 2);
    assert_eq!(out.report.method.as_ref().unwrap().missing_views, vec!["r_1".to_string()]);
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(tmp.path().join("out-allowed/eval.json")).unwrap()).unwrap();
    assert_eq!(json["method"]["missing_views"], serde_json::json!(["r_1"]));
    assert_eq!(test_files(&data), before, "the dataset folder changed");
}

/// Our own run's test views, rendered through `RunModel` and written as a plain folder of float
/// files (`r_<k>.npy` colour, `_depth.npy` z-depth, `_opacity.npy`), score bit for bit what
/// `eval` measures on the run: the same ground truth, compositing and metric code.
#[test]
fn our_runs_renders_as_files_score_exactly_what_eval_measures() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    nerf::data::synthetic::write(&data, SIZE, [6, 1, 3], false).unwrap();
    let cfg = nerf::train::TrainConfig::new(data.clone(), nerf::models::ModelConfig::Fast(test_support::training::tiny_fast(8, 4)), 256, 1e-2, 1e-3, 400)
        .with_seed(7)
        .with_steps(Some(30))
        .with_val_interval_s(Some(1e9));
    let run = tmp.path().join("run");
    test_support::training::run_to_end(&mut nerf::train::Trainer::new(cfg, &run, false).unwrap());
    let evaluated = eval::evaluate_run(&run, &eval::EvalRunOptions { mesh: None, ..eval::EvalRunOptions::split(SplitKind::Test) }, &mut |_, _| {}).unwrap();
    let model = nerf::render::RunModel::load(&run).unwrap();
    let downscale = model.config.downscale.max(1);
    let pred = tmp.path().join("renders");
    for frame in &dataset::Dataset::load(&data).unwrap().test {
        let v = model.render_view(&frame.camera.downscaled(downscale), model.eval_background());
        let (h, w) = (v.height as usize, v.width as usize);
        write_npy(&pred.join(format!("{}.npy", frame.name)), &[h, w, 3], &v.rgb);
        write_npy(&pred.join(format!("{}_depth.npy", frame.name)), &[h, w], &v.depth);
        write_npy(&pred.join(format!("{}_opacity.npy", frame.name)), &[h, w], &v.opacity);
    }
    let mut o = options(&data, &pred, &tmp.path().join("scored"));
    (o.background, o.downscale) = (model.eval_background(), Some(downscale));
    let scored = score(&o, &mut |_, _| {}).unwrap();
    assert_eq!(scored.report.views.len(), evaluated.report.views.len());
    for (s, e) in scored.report.views.iter().zip(&evaluated.report.views) {
        let (a, b) = (&s.metrics, &e.metrics);
        assert_eq!(s.name, e.name);
        assert!(b.psnr.is_finite() && b.depth_mae.is_some() && b.mask_iou.is_some());
        assert_eq!((a.psnr, a.ssim, a.mask_iou), (b.psnr, b.ssim, b.mask_iou), "view {}", s.name);
        assert_eq!((a.depth_mae, a.depth_rmse, a.depth_abs_rel), (b.depth_mae, b.depth_rmse, b.depth_abs_rel), "view {}", s.name);
        assert_eq!((a.depth_delta_1_25, a.depth_delta_1_01), (b.depth_delta_1_25, b.depth_delta_1_01), "view {}", s.name);
        assert!(a.off_surface_mass.is_none() && b.off_surface_mass.is_some(), "files carry no density samples");
    }
    assert_eq!(scored.report.resolution.map(|r| (r.width, r.height, r.downscale)), evaluated.report.resolution.map(|r| (r.width, r.height, r.downscale)));
    // compare reads the score folder beside the run folder.
    let rows = vec![eval::summarise_run(&run).unwrap(), eval::summarise_run(&tmp.path().join("scored")).unwrap()];
    let table = eval::compare_runs(&rows, tmp.path()).unwrap();
    assert!(table.contains("| m (images) |"), "{table}");
}

/// Predictions with NaN and infinite values: counted in eval.json and left out of the means.
#[test]
fn non_finite_predictions_are_counted_in_the_method_block() {
    let tmp = tempfile::tempdir().unwrap();
    let data = dataset(tmp.path());
    let pred = tmp.path().join("nan");
    for (frame, t) in truths(&data, 1) {
        let mut rgb = t.gt_rgb.clone();
        rgb[0] = f32::NAN;
        rgb[7] = f32::INFINITY;
        write_npy(&pred.join(format!("{}.npy", frame.name)), &[t.height, t.width, 3], &rgb);
    }
    let out = score(&options(&data, &pred, &tmp.path().join("out")), &mut |_, _| {}).unwrap();
    assert_eq!(out.report.mean.psnr, f64::INFINITY, "the finite pixels are exact");
    assert_eq!(out.report.method.as_ref().unwrap().nonfinite.colour, 6);
    assert!(out.report.notes.iter().any(|n| n.starts_with("pixels with a non-finite colour are left out of PSNR and SSIM (3 of 3 views)")), "{:?}", out.report.notes);
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap().flatten() {
        std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
    }
}

fn test_files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            if e.path().is_dir() {
                stack.push(e.path());
            } else {
                out.push((e.path().display().to_string(), std::fs::read(e.path()).unwrap()));
            }
        }
    }
    out.sort();
    out
}

/// A real render of a committed scene with several objects, scored with predictions equal to
/// the ground truth except on one object's pixels (its ID in the label files), where seeded
/// noise is added: that object alone loses, to the PSNR the formula gives for the noise
/// written, and every other object stays exact (the cap); interior and edge pixels add up.
#[test]
fn noise_on_one_object_is_charged_to_that_object_alone() {
    use pathtracer::dataset_render::{DatasetRenderConfig, Preset, RunOptions, render_dataset};
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/tabletop.gltf");
    let cfg = DatasetRenderConfig { width: 32, height: 24, train: 2, val: 1, test: 2, spp: 4, ..DatasetRenderConfig::preset(Preset::Quick) };
    let opts = RunOptions { threads: Some(2), force: false, allow_outside: false };
    render_dataset(&scene, &data, &cfg, &opts, &mut |_| {}, &std::sync::atomic::AtomicBool::new(false)).unwrap();
    let views = truths(&data, 1);
    let labels: Vec<dataset::labels::ViewLabels> = views
        .iter()
        .map(|(f, t)| {
            let files = dataset::labels::label_files(SplitKind::Test, f.name.trim_start_matches("r_").parse().unwrap()).map(|x| data.join(x));
            dataset::labels::read_labels(&files, t.width as u32, t.height as u32).unwrap()
        })
        .collect();
    // The object covering the most pixels of the first view gets the noise.
    let mut counts = std::collections::BTreeMap::<u16, usize>::new();
    for &id in labels[0].object.iter().filter(|&&id| id > 0) {
        *counts.entry(id).or_default() += 1;
    }
    let (&target, _) = counts.iter().max_by_key(|&(_, &n)| n).unwrap();
    assert!(counts.len() >= 2, "tabletop shows several objects: {counts:?}");
    let pred = tmp.path().join("pred");
    let (mut sse, mut n) = (0.0f64, 0usize);
    for (v, ((frame, t), l)) in views.iter().zip(&labels).enumerate() {
        let noise = gaussians(7 + v as u64, t.gt_rgb.len());
        let rgb: Vec<f32> = t
            .gt_rgb
            .iter()
            .enumerate()
            .map(|(k, &g)| if l.object[k / 3] == target { (f64::from(g) + 0.05 * noise[k]) as f32 } else { g })
            .collect();
        for (k, (&p, &g)) in rgb.iter().zip(&t.gt_rgb).enumerate() {
            if l.object[k / 3] == target {
                sse += (f64::from(p) - f64::from(g)).powi(2);
                n += 1;
            }
        }
        write_npy(&pred.join(format!("{}.npy", frame.name)), &[t.height, t.width, 3], &rgb);
    }
    let out = score(&options(&data, &pred, &tmp.path().join("out")), &mut |_, _| {}).unwrap();
    let block = out.report.objects.as_ref().expect("the dataset has label files");
    assert_eq!(block.views, 2);
    let worst = &block.objects[0];
    assert_eq!(worst.id, target as u32, "{:?}", block.objects);
    let want = -10.0 * (sse / n as f64).log10();
    assert!((worst.psnr - want).abs() < 0.01, "{} dB against the formula's {want}", worst.psnr);
    assert_eq!(worst.pixels as usize * 3, n);
    for r in &block.objects[1..] {
        assert_eq!(r.psnr, eval::objects::PSNR_CAP_DB, "object {} ({}) was left exact", r.id, r.name);
        assert!(r.edge_pixels <= r.pixels);
    }
    let total: u64 = block.objects.iter().map(|r| r.pixels).sum();
    assert_eq!(total as usize, views.iter().map(|(_, t)| t.width * t.height).sum::<usize>());
    let md = std::fs::read_to_string(tmp.path().join("out/report.md")).unwrap();
    assert!(md.contains("## Error per object and per material") && tmp.path().join("out").join(eval::objects::OBJECTS_PICTURE).is_file(), "{md}");
}
