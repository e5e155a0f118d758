//! Inputs the import fuzzer (`fuzz/`) found crashing, kept as regression tests: each must
//! import and build its acceleration structure (or fail with an error), never panic.

use pathtracer::accel::AccelParams;
use pathtracer::import::{ImportOptions, load_gltf};
use pathtracer::render::Renderer;
use std::path::Path;

fn data(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/import")
        .join(name)
}

/// A mutated Cornell room whose node transform scales the room to ~1e37 m: box areas overflow
/// f32, and obvhs's wide-BVH conversion failed an internal assertion (`distribute_left < 7` in
/// `bvh2_to_cwbvh.rs`). Now a clear error that names the size.
#[test]
fn cwbvh_conversion_assertion() {
    for file in ["fuzz_crash_cwbvh.gltf", "fuzz_crash_cwbvh_2.gltf"] {
        let scene = load_gltf(&data(file), &ImportOptions::default()).expect("the file imports");
        for params in [
            AccelParams::fastest_build(),
            AccelParams::fast_build(),
            AccelParams::medium_build(),
            AccelParams::slow_build(),
        ] {
            let Err(e) = Renderer::new(scene.clone(), &params) else { panic!("a 1e37 m scene must be refused") };
            assert!(e.to_string().contains("spans"), "{e}");
        }
    }
}
