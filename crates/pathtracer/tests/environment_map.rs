//! Environment maps from files (`RenderSettings::environment_map`): a constant-valued map read
//! from an EXR or Radiance HDR file lights a Lambertian plane exactly as the constant
//! environment does (closed form: radiance = albedo × L), and missing or malformed files are
//! errors that name the file.

use dataset::{Camera, Intrinsics};
use glam::{DVec3, Vec2};
use pathtracer::accel::AccelParams;
use pathtracer::import::{ImportOptions, load_gltf};
use pathtracer::render::{RenderSettings, Renderer, load_environment_map};
use scenegen::{Material, Mesh, SceneBuilder, Transform};
use std::path::{Path, PathBuf};

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("pt-envmap-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

const ALBEDO: [f32; 3] = [0.5, 0.4, 0.25];

/// A 400 m Lambertian plane (metallic 0, specular 0: exactly Lambertian) facing +Y.
fn plane_renderer(dir: &Path) -> Renderer {
    let mut b = SceneBuilder::new("envplane");
    let grey = b.add_material(Material::diffuse("plane", ALBEDO)).unwrap();
    b.add_mesh("ground", Mesh::quad(Vec2::new(400.0, 400.0), 1.0), grey, Transform::IDENTITY).unwrap();
    let path = dir.join("envplane.gltf");
    b.write_gltf(&path).unwrap();
    let mut scene = load_gltf(&path, &ImportOptions::default()).unwrap();
    for m in &mut scene.materials {
        m.specular_factor = 0.0;
    }
    Renderer::new(scene, &AccelParams::fast_build()).unwrap()
}

/// Looking straight down at the plane from 1 m.
fn camera() -> Camera {
    Camera::new(Intrinsics::from_fov_y(24, 24, 0.6), Camera::look_at(DVec3::new(0.0, 1.0, 0.0), DVec3::ZERO, DVec3::Z)).unwrap()
}

fn settings(environment: [f32; 3], map: Option<PathBuf>) -> RenderSettings {
    RenderSettings { spp: 64, max_bounces: 1, seed: 3, environment, transparent_background: false, environment_map: map }
}

/// Per-channel image mean and its standard error (from the per-pixel spread).
fn mean_and_error(r: &Renderer, s: &RenderSettings) -> ([f64; 3], [f64; 3]) {
    let out = r.render_view(&camera(), 0, s);
    assert_eq!(out.nonfinite_samples, 0);
    let n = (out.color.width * out.color.height) as f64;
    let mut mean = [0.0; 3];
    let mut err = [0.0; 3];
    for c in 0..3 {
        let xs: Vec<f64> = out.color.data.chunks(4).map(|p| p[c] as f64).collect();
        let m = xs.iter().sum::<f64>() / n;
        let var = xs.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1.0);
        mean[c] = m;
        err[c] = (var / n).sqrt();
    }
    (mean, err)
}

fn write_exr(path: &Path, w: usize, h: usize, rgb: [f32; 3]) {
    exr::prelude::write_rgb_file(path, w, h, |_, _| (rgb[0], rgb[1], rgb[2])).unwrap();
}

fn write_hdr(path: &Path, w: u32, h: u32, rgb: [f32; 3]) {
    let img = image::Rgb32FImage::from_pixel(w, h, image::Rgb(rgb));
    image::DynamicImage::ImageRgb32F(img).save(path).unwrap();
}

#[test]
fn constant_map_files_light_a_lambertian_plane_like_the_constant_environment() {
    let dir = tmp("constant");
    let r = plane_renderer(&dir);
    // Values exactly representable in RGBE (shared exponent) and half floats.
    let l = [1.0f32, 0.5, 0.25];
    let scale = 2.0f32;
    let exr_path = dir.join("sky.exr");
    let hdr_path = dir.join("sky.HDR");
    write_exr(&exr_path, 32, 16, l);
    write_hdr(&hdr_path, 32, 16, l);
    let constant = settings(l.map(|x| x * scale), None);
    let (c_mean, c_err) = mean_and_error(&r, &constant);
    for path in [exr_path, hdr_path] {
        let s = settings([scale; 3], Some(path.clone()));
        s.validate().unwrap();
        let mut r_map = plane_renderer(&dir);
        r_map.load_environment_map(&s).unwrap();
        assert_eq!(r_map.environment_map().unwrap().size(), (32, 16));
        let (m_mean, m_err) = mean_and_error(&r_map, &s);
        for c in 0..3 {
            // Closed form: a Lambertian plane under a constant sky of radiance L reflects ρ·L.
            let expect = (ALBEDO[c] * l[c] * scale) as f64;
            assert!((m_mean[c] - expect).abs() <= 4.0 * m_err[c] + 2e-3 * expect, "{}: channel {c}: {} vs {expect} ± {}", path.display(), m_mean[c], m_err[c]);
            let sigma = (m_err[c] * m_err[c] + c_err[c] * c_err[c]).sqrt();
            assert!((m_mean[c] - c_mean[c]).abs() <= 4.0 * sigma + 2e-3 * expect, "{}: channel {c}: map {} vs constant {}", path.display(), m_mean[c], c_mean[c]);
        }
        // Camera rays that miss would show the map; a renderer without it does not.
        r_map.load_environment_map(&settings([1.0; 3], None)).unwrap();
        assert!(r_map.environment_map().is_none());
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn missing_or_malformed_map_files_are_errors_naming_the_file() {
    let dir = tmp("errors");
    let missing = dir.join("nowhere.exr");
    for e in [settings([1.0; 3], Some(missing.clone())).validate().unwrap_err().to_string(), load_environment_map(&missing).unwrap_err().to_string()] {
        assert!(e.contains("nowhere.exr") && e.contains("does not exist"), "{e}");
    }
    let garbage = dir.join("garbage.exr");
    std::fs::write(&garbage, b"this is not an OpenEXR file").unwrap();
    let e = load_environment_map(&garbage).unwrap_err().to_string();
    assert!(e.contains("garbage.exr"), "{e}");
    let garbage_hdr = dir.join("garbage.hdr");
    std::fs::write(&garbage_hdr, b"#?RADIANCE\nnot really\n").unwrap();
    let e = load_environment_map(&garbage_hdr).unwrap_err().to_string();
    assert!(e.contains("garbage.hdr"), "{e}");
    let png = dir.join("sky.png");
    std::fs::write(&png, b"png").unwrap();
    let e = settings([1.0; 3], Some(png)).validate().unwrap_err().to_string();
    assert!(e.contains("sky.png") && e.contains(".hdr"), "{e}");
    let mut r = plane_renderer(&dir);
    assert!(r.load_environment_map(&settings([1.0; 3], Some(garbage))).unwrap_err().to_string().contains("garbage.exr"));
    std::fs::remove_dir_all(&dir).ok();
}
