//! The renderer's identity in a dataset's `render_config.json` and scene facts: the crate's
//! version and a description ([`crate::RENDERER_VERSION`]) plus a hash of the renderer's output
//! on a fixed probe scene, computed on first use ([`renderer_version`]). Any change that alters
//! what the renderer writes — the integrator, a BSDF, the sampler, the lights, the ground-truth
//! ray caster, or the floating-point behaviour of the machine it runs on — changes the probe's
//! bits and so the version, and a resumed render or a merge then refuses to mix views of the
//! two renderers, without anyone remembering to bump a string.
//!
//! The probe (built in code, no file): a 3 m floor of rough dielectric, a smooth metal box, an
//! emissive triangle, a point light and a constant environment, seen by a 12×10 camera at 6
//! samples per pixel, 4 bounces, with a transparent background (so alpha is probed too); the
//! hash covers the colour and every ground-truth channel, bit for bit.
//!
//! ```
//! let v = pathtracer::version::renderer_version();
//! assert!(v.starts_with(pathtracer::RENDERER_VERSION) && v.contains("probe "));
//! ```

use crate::accel::AccelParams;
use crate::render::{RenderSettings, Renderer};
use crate::scene::{Aabb, Light, Material, Mesh, Scene};
use dataset::{Camera, Intrinsics};
use glam::{DVec3, Vec3, Vec4};
use std::sync::OnceLock;

/// The probe scene (see the module docs).
fn probe_scene() -> Scene {
    let mut positions = Vec::new();
    let mut indices = Vec::new();
    let mut material = Vec::new();
    let mut quad = |p: [Vec3; 4], m: u32| {
        let b = positions.len() as u32;
        positions.extend(p);
        indices.extend([[b, b + 1, b + 2], [b, b + 2, b + 3]]);
        material.extend([m, m]);
    };
    let h = 1.5;
    quad([Vec3::new(-h, 0.0, -h), Vec3::new(-h, 0.0, h), Vec3::new(h, 0.0, h), Vec3::new(h, 0.0, -h)], 0);
    // A box 0.6 m wide: its four sides and top.
    let (a, t) = (0.3, 0.6);
    let c = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
    quad([c(-a, t, -a), c(-a, t, a), c(a, t, a), c(a, t, -a)], 1);
    quad([c(-a, 0.0, a), c(a, 0.0, a), c(a, t, a), c(-a, t, a)], 1);
    quad([c(a, 0.0, a), c(a, 0.0, -a), c(a, t, -a), c(a, t, a)], 1);
    quad([c(a, 0.0, -a), c(-a, 0.0, -a), c(-a, t, -a), c(a, t, -a)], 1);
    quad([c(-a, 0.0, -a), c(-a, 0.0, a), c(-a, t, a), c(-a, t, -a)], 1);
    let b = positions.len() as u32;
    positions.extend([c(-1.0, 1.2, -0.8), c(-0.2, 1.6, -0.8), c(-0.6, 1.8, -0.4)]);
    indices.push([b, b + 1, b + 2]);
    material.push(2);
    let bounds = positions.iter().fold(Aabb::EMPTY, |acc, p| acc.union_point(*p));
    let floor = Material { base_color_factor: Vec4::new(0.7, 0.6, 0.5, 1.0), metallic_factor: 0.0, roughness_factor: 0.6, ..Material::gltf_default() };
    let metal = Material { base_color_factor: Vec4::new(0.9, 0.5, 0.3, 1.0), metallic_factor: 1.0, roughness_factor: 0.15, ..Material::gltf_default() };
    let lamp = Material { emissive: Vec3::new(4.0, 3.5, 3.0), double_sided: true, ..Material::gltf_default() };
    Scene {
        name: "renderer-probe".into(),
        origin: DVec3::ZERO,
        mesh: Mesh { positions, indices, material, ..Default::default() },
        materials: vec![floor, metal, lamp],
        textures: vec![],
        lights: vec![Light::Point { position: Vec3::new(1.0, 2.0, 1.5), intensity: Vec3::new(3.0, 3.0, 2.5), range: None }],
        cameras: vec![],
        bounds,
        warnings: vec![],
        objects: vec![],
    }
}

/// FNV-1a 64 over `words`' bytes.
fn fnv(h: u64, bytes: &[u8]) -> u64 {
    bytes.iter().fold(h, |h, b| (h ^ *b as u64).wrapping_mul(0x0100_0000_01b3))
}

/// The hash of the renderer's output on the probe scene (see the module docs).
pub fn probe_hash() -> Result<u64, crate::PathTracerError> {
    let renderer = Renderer::new(probe_scene(), &AccelParams::medium_build())?;
    let intr = Intrinsics::from_fov_y(12, 10, 0.9);
    let camera = Camera::new(intr, Camera::look_at(DVec3::new(1.6, 1.3, 2.4), DVec3::new(0.0, 0.4, 0.0), DVec3::Y))
        .map_err(crate::PathTracerError::Config)?;
    let settings = RenderSettings { spp: 6, max_bounces: 4, seed: 7, environment: [0.2, 0.25, 0.3], transparent_background: true, environment_map: None };
    Ok(view_hash(&renderer.render_view(&camera, 3, &settings)))
}

/// FNV-1a 64 over the bits of a rendered view: its colour and every ground-truth channel
/// (depth, distance, normal, alpha), in that order. Equal hashes mean bit-identical outputs
/// (the probe's identity, and `bench render`'s check that a change kept the images).
pub fn view_hash(v: &crate::render::ViewOutput) -> u64 {
    let g = &v.ground_truth;
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for channel in [&v.color.data, &g.depth, &g.distance, &g.normal, &g.alpha] {
        for x in channel.iter() {
            h = fnv(h, &x.to_bits().to_le_bytes());
        }
    }
    h
}

/// [`crate::RENDERER_VERSION`] with the probe's hash: `"<version> (…); probe 0123456789abcdef"`.
/// Computed once per process (a few milliseconds).
pub fn renderer_version() -> &'static str {
    static VERSION: OnceLock<String> = OnceLock::new();
    VERSION.get_or_init(|| match probe_hash() {
        Ok(h) => format!("{}; probe {h:016x}", crate::RENDERER_VERSION),
        // The probe is built in code and cannot fail to load; should it, no dataset can claim
        // to match this renderer's output.
        Err(e) => format!("{}; probe failed ({e})", crate::RENDERER_VERSION),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The probe sees every part it is meant to pin: geometry and background (alpha 0 and 1),
    /// the lamp, and radiance that is neither black nor saturated.
    #[test]
    fn the_probe_exercises_geometry_background_and_light() {
        let renderer = Renderer::new(probe_scene(), &AccelParams::medium_build()).unwrap();
        let camera = Camera::new(Intrinsics::from_fov_y(12, 10, 0.9), Camera::look_at(DVec3::new(1.6, 1.3, 2.4), DVec3::new(0.0, 0.4, 0.0), DVec3::Y)).unwrap();
        let settings = RenderSettings { spp: 6, max_bounces: 4, seed: 7, environment: [0.2, 0.25, 0.3], transparent_background: true, environment_map: None };
        let v = renderer.render_view(&camera, 3, &settings);
        let alpha = &v.ground_truth.alpha;
        assert!(alpha.contains(&0.0) && alpha.contains(&1.0), "{alpha:?}");
        assert!(v.color.data.iter().any(|x| *x > 0.05) && v.color.data.iter().all(|x| x.is_finite()));
        assert_eq!(probe_hash().unwrap(), probe_hash().unwrap());
    }

    /// Bit-identical whatever the thread count, so the version does not depend on the pool.
    #[test]
    fn the_probe_hash_does_not_depend_on_the_thread_count() {
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap().install(|| probe_hash().unwrap());
        let three = rayon::ThreadPoolBuilder::new().num_threads(3).build().unwrap().install(|| probe_hash().unwrap());
        assert_eq!(one, three);
        assert!(renderer_version().ends_with(&format!("probe {one:016x}")));
    }
}
