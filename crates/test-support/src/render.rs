//! Small path-traced datasets of the project's scenes for the end-to-end tests: the quick
//! preset cut down to a test's budget.

use pathtracer::dataset_render::{DatasetRenderConfig, Preset, RunOptions, render_dataset};
use std::path::Path;
use std::sync::atomic::AtomicBool;

/// Renders the glTF `scene` into the dataset folder `out` with the quick preset's settings but
/// `size`×`size` views, `counts` = train, val and test views, and `spp` samples per pixel.
pub fn quick_dataset(scene: &Path, out: &Path, size: u32, counts: [u32; 3], spp: u32) {
    let mut cfg = DatasetRenderConfig::preset(Preset::Quick);
    (cfg.width, cfg.height, cfg.spp) = (size, size, spp);
    [cfg.train, cfg.val, cfg.test] = counts;
    let opts = RunOptions { threads: None, force: false, allow_outside: false };
    render_dataset(scene, out, &cfg, &opts, &mut |_| {}, &AtomicBool::new(false)).expect("render");
}
