//! A folder in the original Blender-synthetic layout (only `camera_angle_x`, RGBA PNGs, no
//! depth, no facts) loads, composites onto white or black, and gets bounds from its cameras.

use nerf::data::{Background, SceneBounds, TrainData};

#[test]
fn blender_layout_loads_with_background_compositing() {
    let tmp = tempfile::tempdir().unwrap();
    nerf::data::synthetic::write(tmp.path(), 16, [3, 1, 1], true).unwrap();
    let ds = dataset::Dataset::load(tmp.path()).unwrap();
    assert!(ds.facts.is_none());
    assert!(ds.train[0].gt_path.is_none());
    let white = TrainData::load(&ds.train, 1, Background::White, false).unwrap();
    let black = TrainData::load(&ds.train, 1, Background::Black, false).unwrap();
    // Pixel (0, 0) sees no sphere: fully transparent, so it takes the background colour.
    assert_eq!(white.views[0].rgba[0][3], 0.0);
    assert_eq!(white.views[0].color(0, Background::White.eval_color()), [1.0; 3]);
    assert_eq!(black.views[0].color(0, Background::Black.eval_color()), [0.0; 3]);
    // The batch targets use the configured background.
    let b = black.batch(1, 0, 64);
    assert!(b.background.iter().all(|c| *c == [0.0; 3]));
    // Downscaling halves the image and averages 2×2 blocks.
    let half = TrainData::load(&ds.train, 2, Background::White, false).unwrap();
    assert_eq!(half.views[0].camera.intrinsics.width, 8);
    let cams: Vec<_> = ds.train.iter().map(|f| f.camera).collect();
    let bounds = SceneBounds::for_dataset(None, &cams, 0.05, 3f32.sqrt());
    assert!((bounds.near - (4.0 - 3f32.sqrt())).abs() < 1e-3, "{bounds:?}");
    assert!((bounds.far - (4.0 + 3f32.sqrt())).abs() < 1e-3, "{bounds:?}");
    assert!(bounds.center().iter().all(|c| c.abs() < 1e-3));
}
