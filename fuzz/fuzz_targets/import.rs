//! Scene import from arbitrary bytes: GLB or JSON glTF, no base folder (only `data:` URIs and
//! the GLB chunk resolve), with small caps so a hostile file cannot exhaust memory.
//! Any `Ok` scene must also pass the renderer's consistency check and build a BVH.
#![no_main]

use libfuzzer_sys::fuzz_target;
use pathtracer::accel::AccelParams;
use pathtracer::import::{ImportOptions, load_gltf_from_slice};

fuzz_target!(|bytes: &[u8]| {
    let options = ImportOptions {
        scene: None,
        max_triangles: 4096,
        max_vertices: 8192,
        max_texture_texels: 1 << 16,
        max_buffer_bytes: 1 << 20,
        allow_outside: false,
    };
    if let Ok(scene) = load_gltf_from_slice(bytes, None, "fuzz", &options) {
        pathtracer::render::validate_scene(&scene).expect("the importer produced an inconsistent scene");
        let _ = pathtracer::render::Renderer::new(scene, &AccelParams::fastest_build());
    }
});
