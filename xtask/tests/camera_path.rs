//! Camera paths end to end: `camera-path` writes nerfstudio's `camera_path.json` around or
//! through a dataset, `render --camera-path` path traces its frames as a dataset (exact ground
//! truth along the path), `render-nerf --camera-path` renders a run along it.

use std::path::Path;
use std::process::Command;

fn xtask(args: &[&std::ffi::OsStr]) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_xtask")).args(args).output().expect("run xtask");
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    (out.status.code().unwrap_or(-1), text)
}

macro_rules! args {
    ($($a:expr),* $(,)?) => { &[$(std::ffi::OsStr::new($a)),*] };
}

fn scene() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../crates/pathtracer/tests/data/import/valid_triangle.gltf")
}

fn read_path(p: &Path) -> dataset::CameraPathFile {
    dataset::CameraPathFile::read(p).unwrap()
}

#[test]
fn a_path_through_views_passes_through_their_poses_exactly() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    test_support::render::quick_dataset(&scene(), &data, 16, [6, 1, 1], 1);
    let path = tmp.path().join("through.json");
    let (code, out) = xtask(args!["camera-path", &data, "--through-views", "0,2,5", "--frames", "4", "--out", &path]);
    assert_eq!(code, 0, "{out}");
    let file = read_path(&path);
    let cams = file.cameras(&path).unwrap();
    let ds = dataset::Dataset::load(&data).unwrap();
    assert_eq!(cams.len(), 9);
    for (i, v) in [0, 2, 5].into_iter().enumerate() {
        // Exact in memory (the spline copies the keyframe); through JSON to within serde_json's
        // default float parsing, a unit in the last place.
        assert!(cams[4 * i].c2w.abs_diff_eq(ds.train[v].camera.c2w, 1e-15), "keyframe {i} (view {v})");
    }
    assert_eq!(file.keyframes.len(), 3);
    assert_eq!((file.render_width, file.render_height), (16, 16));
    // An orbit and a spiral around the same dataset; a bad view index is named.
    for shape in ["--orbit", "--spiral"] {
        let p = tmp.path().join("shape.json");
        let (code, out) = xtask(args!["camera-path", &data, shape, "--frames", "5", "--out", &p]);
        assert_eq!(code, 0, "{out}");
        assert_eq!(read_path(&p).cameras(&p).unwrap().len(), 5);
    }
    let bad = tmp.path().join("bad.json");
    let (code, out) = xtask(args!["camera-path", &data, "--through-views", "0,9", "--out", &bad]);
    assert_eq!(code, 1, "{out}");
    assert!(out.contains("--through-views") && out.contains("view 9"), "{out}");
    assert!(!bad.exists());
    let (code, out) = xtask(args!["camera-path", &data, "--out", &bad]);
    assert_eq!(code, 1, "{out}");
}

#[test]
fn the_path_tracer_along_a_path_renders_the_dataset_views_bit_for_bit() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    test_support::render::quick_dataset(&scene(), &data, 16, [3, 1, 1], 2);
    // A path whose frames are the train views, in order: frame k is keyed as train view k.
    let ds = dataset::Dataset::load(&data).unwrap();
    let cams: Vec<dataset::Camera> = ds.train.iter().map(|f| f.camera).collect();
    let path = tmp.path().join("views.json");
    dataset::CameraPathFile::from_cameras(&cams, &[], 30.0).write(&path).unwrap();
    let gt = tmp.path().join("gt");
    let (code, out) = xtask(args!["render", scene().as_os_str(), "--camera-path", &path, "--spp", "2", "--out", &gt]);
    assert_eq!(code, 0, "{out}");
    for k in 0..3 {
        for f in dataset::folder::view_files(dataset::SplitKind::Train, k) {
            assert_eq!(std::fs::read(gt.join(&f)).unwrap(), std::fs::read(data.join(&f)).unwrap(), "{f}");
        }
    }
    let back = dataset::Dataset::load(&gt).unwrap();
    assert_eq!((back.train.len(), back.val.len(), back.test.len()), (3, 0, 0));
    // Resumed: nothing to render again.
    let (code, out) = xtask(args!["render", scene().as_os_str(), "--camera-path", &path, "--spp", "2", "--out", &gt]);
    assert_eq!(code, 0, "{out}");
    assert!(out.contains("0 rendered, 3 kept"), "{out}");
    // The path sets the views: a rig's options with it are refused.
    let other = tmp.path().join("other");
    let (code, out) = xtask(args!["render", scene().as_os_str(), "--camera-path", &path, "--res", "8", "--out", &other]);
    assert_eq!(code, 1, "{out}");
    assert!(out.contains("--res") && out.contains("--camera-path"), "{out}");
    assert!(!other.exists());
}

#[test]
fn a_run_along_a_path_gives_frames_a_side_by_side_video_and_the_error_along_it() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    test_support::render::quick_dataset(&scene(), &data, 16, [4, 1, 1], 1);
    let cfg = nerf::train::TrainConfig::new(data.clone(), nerf::models::ModelConfig::Fast(test_support::training::tiny_fast(8, 4)), 128, 1e-2, 1e-3, 400)
        .with_seed(7)
        .with_steps(Some(20))
        .with_val_interval_s(Some(1e9))
        .with_val_max_pixels(256);
    let config = tmp.path().join("train.json");
    std::fs::write(&config, serde_json::to_string_pretty(&cfg).unwrap()).unwrap();
    let run = tmp.path().join("run");
    let (code, out) = xtask(args!["train", "--config", &config, "--out", &run]);
    assert_eq!(code, 0, "{out}");
    let path = tmp.path().join("orbit.json");
    let (code, out) = xtask(args!["camera-path", &data, "--orbit", "--frames", "3", "--width", "12", "--out", &path]);
    assert_eq!(code, 0, "{out}");
    let gt = tmp.path().join("gt");
    let (code, out) = xtask(args!["render", scene().as_os_str(), "--camera-path", &path, "--spp", "1", "--out", &gt]);
    assert_eq!(code, 0, "{out}");
    let renders = tmp.path().join("renders");
    let video = tmp.path().join("orbit.mp4");
    let (code, out) = xtask(args!["render-nerf", &run, "--camera-path", &path, "--out", &renders, "--video", &video, "--layout", "side-by-side", "--gt", &gt]);
    assert_eq!(code, 0, "{out}");
    for k in 0..3 {
        let img = dataset::read_png_rgba(&renders.join(format!("frame_{k:05}.png"))).unwrap();
        assert_eq!((img.width, img.height), (12, 12));
        for suffix in ["depth", "opacity"] {
            assert!(renders.join(format!("frame_{k:05}_{suffix}.npy")).is_file(), "{suffix} {k}");
        }
    }
    // Four 12-pixel panels under a label strip, decoded back with the same codec.
    let probe = eval::video_probe::probe(&video).unwrap();
    assert_eq!((probe.samples, probe.decoded), (3, 3));
    assert_eq!(probe.decoded_size, (48, 12 + eval::path_video::LABEL_H));
    // The error along the path joins eval.json and the report.
    let (code, out) = xtask(args!["eval", &run, "--no-mesh", "--grids", "0", "--camera-path", &gt]);
    assert_eq!(code, 0, "{out}");
    let e: serde_json::Value = serde_json::from_slice(&std::fs::read(run.join("eval.json")).unwrap()).unwrap();
    assert_eq!(e["camera_path"]["frames"], 3, "{e}");
    assert!(e["camera_path"]["mean_psnr"].as_f64().unwrap().is_finite());
    assert_eq!(std::fs::read_to_string(run.join("path_error.csv")).unwrap().lines().count(), 4);
    assert!(run.join("path_error.png").is_file());
    assert!(std::fs::read_to_string(run.join("report.md")).unwrap().contains("Along the camera path"));
    // Side by side without the ground truth, or with another path's, is refused before writing.
    let v2 = tmp.path().join("v2.mp4");
    let (code, out) = xtask(args!["render-nerf", &run, "--camera-path", &path, "--out", &tmp.path().join("r2"), "--video", &v2, "--layout", "side-by-side"]);
    assert_eq!(code, 1, "{out}");
    assert!(out.contains("--gt"), "{out}");
    assert!(!v2.exists());
    // A path file with a bad frame is refused, naming the key and the frame.
    let mut file = read_path(&path);
    file.camera_path[1].fov = 180.0;
    file.write(&path).unwrap();
    let (code, out) = xtask(args!["render-nerf", &run, "--camera-path", &path, "--out", &tmp.path().join("r3")]);
    assert_eq!(code, 1, "{out}");
    assert!(out.contains("camera_path[1].fov"), "{out}");
}
