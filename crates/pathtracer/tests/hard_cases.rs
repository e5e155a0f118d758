//! The path tracer at the edges, each case against an untroubled reference where physics says
//! the two are equal: tiny, huge and far-from-origin scenes; grazing rays; zero-area, collinear,
//! duplicated and coincident triangles; mirror-smooth metal; a tiny, very bright emitter.

use dataset::{Camera, Intrinsics, Ray as WorldRay};
use glam::{DVec3, Quat, Vec2, Vec3};
use pathtracer::accel::AccelParams;
use pathtracer::import::{ImportOptions, load_gltf};
use pathtracer::render::{RenderSettings, Renderer, ViewOutput};
use pathtracer::scene::Scene;
use scenegen::{Light, Material, Mesh, SceneBuilder, Transform};
use std::path::PathBuf;

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("pt-hard-cases-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn load(builder: &SceneBuilder, name: &str) -> Scene {
    let dir = tmp(name);
    let path = dir.join(format!("{name}.gltf"));
    builder.write_gltf(&path).unwrap();
    let scene = load_gltf(&path, &ImportOptions::default()).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    scene
}

fn renderer(scene: Scene) -> Renderer {
    Renderer::new(scene, &AccelParams::fast_build()).unwrap()
}

/// Direct + one indirect bounce, black environment (only the scene's lights), opaque.
fn settings(spp: u32) -> RenderSettings {
    RenderSettings { spp, max_bounces: 2, seed: 7, environment: [0.0; 3], transparent_background: false, environment_map: None }
}

fn camera(eye: DVec3, target: DVec3, res: u32) -> Camera {
    Camera::new(Intrinsics::from_fov_y(res, res, 0.7), Camera::look_at(eye, target, DVec3::Y)).unwrap()
}

/// Every output array is finite and no radiance sample was NaN or infinite.
fn assert_finite(out: &ViewOutput, what: &str) {
    assert_eq!(out.nonfinite_samples, 0, "{what}: {} non-finite radiance samples", out.nonfinite_samples);
    assert!(out.color.data.iter().all(|v| v.is_finite()), "{what}: non-finite colour");
    let gt = &out.ground_truth;
    for (name, xs) in [("depth", &gt.depth), ("distance", &gt.distance), ("normal", &gt.normal), ("alpha", &gt.alpha)] {
        assert!(xs.iter().all(|v| v.is_finite()), "{what}: non-finite {name}");
    }
}

fn luminance(out: &ViewOutput) -> Vec<f64> {
    out.color.data.chunks(4).map(|p| (0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]) as f64).collect()
}

/// Compares two images that estimate the same per-pixel expectation: the mean difference is
/// within 3σ of its noise (σ from the per-pixel differences) plus `bias_rel` of the mean (a
/// stated physical difference, 0 where the scenes are equal), and the fraction of dark
/// (shadowed) pixels is the same within one pixel in a hundred (no shadow acne).
fn assert_same_image(a: &ViewOutput, b: &ViewOutput, bias_rel: f64, what: &str) {
    let (la, lb) = (luminance(a), luminance(b));
    let n = la.len() as f64;
    let d: Vec<f64> = la.iter().zip(&lb).map(|(x, y)| x - y).collect();
    let mean_d = d.iter().sum::<f64>() / n;
    let var_d = d.iter().map(|x| (x - mean_d).powi(2)).sum::<f64>() / (n - 1.0);
    let sigma = (var_d / n).sqrt();
    let mean_a = la.iter().sum::<f64>() / n;
    let tol = 3.0 * sigma + bias_rel * mean_a + 1e-6 * mean_a;
    assert!(mean_a > 0.0, "{what}: the reference image is black");
    assert!(mean_d.abs() <= tol, "{what}: mean {mean_a} vs {} differs by {mean_d}, above 3σ = {}", mean_a - mean_d, 3.0 * sigma);
    let dark = |l: &[f64]| l.iter().filter(|&&x| x < 0.2 * mean_a).count() as f64 / n;
    let (da, db) = (dark(&la), dark(&lb));
    assert!((da - db).abs() <= 0.01, "{what}: dark fraction {da} vs {db} (shadow acne?)");
}

/// A 4 m grey ground at y = 0 with a 0.6 m red box on it and a sphere, built in metres then
/// scaled by `s` into one mesh, placed at `offset` (exact in f32 for the offsets used), lit by
/// a directional light (irradiance does not depend on scale) and a point light whose intensity
/// is scaled by s² (irradiance at scaled distances unchanged).
///
/// The light's node translation offset + (1, 2, 1)·s goes through scenegen's f32 and is written
/// as the shortest decimal that round-trips to that f32; the importer reads the JSON number as
/// f64. The two agree only when that decimal is the intended value (1e4 + 0.001 → "10000.001"),
/// not for, say, 1e5 + 1/128 (f32 100000.0078125, written "100000.01", read 2.2 mm off), so
/// combined scale-and-offset cases use offsets whose decimals survive.
fn plane_box(s: f32, offset: Vec3) -> SceneBuilder {
    let mut b = SceneBuilder::new("plane_box");
    let grey = b.add_material(Material::diffuse("grey", [0.5, 0.5, 0.5])).unwrap();
    let red = b.add_material(Material::diffuse("red", [0.8, 0.2, 0.1])).unwrap();
    let scale = glam::Mat4::from_scale(Vec3::splat(s));
    let ground = Mesh::quad(Vec2::new(4.0, 4.0), 1.0).transformed(&scale);
    let cube = Mesh::cuboid(Vec3::splat(0.3)).transformed(&(scale * glam::Mat4::from_translation(Vec3::new(0.0, 0.3, 0.0))));
    let ball = Mesh::uv_sphere(0.25, 16, 8).transformed(&(scale * glam::Mat4::from_translation(Vec3::new(-0.8, 0.25, 0.6))));
    b.add_mesh("ground", ground, grey, Transform::from_translation(offset)).unwrap();
    b.add_mesh("cube", cube, red, Transform::from_translation(offset)).unwrap();
    b.add_mesh("ball", ball, grey, Transform::from_translation(offset)).unwrap();
    // Direction only (a directional light's position is irrelevant): aimed at the origin so
    // f32 rounding of the offset cannot tilt it.
    let sun = Transform::look_at(Vec3::ZERO, Vec3::new(-0.5, -1.0, -0.3), Vec3::Y);
    b.add_light("sun", Light::Directional { color: [1.0; 3], illuminance: 2.0 }, sun).unwrap();
    b.add_light("bulb", Light::Point { color: [1.0; 3], intensity: 3.0 * s * s }, Transform::from_translation(offset + Vec3::new(1.0, 2.0, 1.0) * s))
        .unwrap();
    b
}

fn plane_box_camera(s: f64, offset: DVec3, res: u32) -> Camera {
    camera(offset + DVec3::new(2.2, 2.4, 3.0) * s, offset + DVec3::new(0.0, 0.2, 0.0) * s, res)
}

/// The same scene at scale 1e-3 and 1e4 and translated 1e5 from the origin (cameras moved
/// identically): pixel-centre distances equal the reference's × s within 1e-4 relative, the
/// same pixels are covered, and the image matches within Monte Carlo noise with no acne.
#[test]
fn scaled_and_translated_scenes_match_the_reference() {
    let res = 32;
    let reference = renderer(load(&plane_box(1.0, Vec3::ZERO), "ref"));
    let ref_out = reference.render_view(&plane_box_camera(1.0, DVec3::ZERO, res), 0, &settings(16));
    assert_finite(&ref_out, "reference");
    for (s, offset) in [(1e-3f32, 0.0f32), (1e4, 0.0), (1.0, 1e5), (1e-3, 1e4)] {
        let what = format!("scale {s:e}, offset {offset:e}");
        let off = Vec3::new(offset, 0.5 * offset, -offset);
        let r = renderer(load(&plane_box(s, off), "scaled"));
        let cam = plane_box_camera(s as f64, off.as_dvec3(), res);
        let out = r.render_view(&cam, 0, &settings(16));
        assert_finite(&out, &what);
        let (g0, g1) = (&ref_out.ground_truth, &out.ground_truth);
        assert_eq!(g0.alpha, g1.alpha, "{what}: covered pixels differ");
        let mut worst = 0.0f64;
        for k in 0..g0.distance.len() {
            if g0.alpha[k] > 0.0 {
                let expected = g0.distance[k] as f64 * s as f64;
                worst = worst.max((g1.distance[k] as f64 - expected).abs() / expected);
                let expected_z = g0.depth[k] as f64 * s as f64;
                worst = worst.max((g1.depth[k] as f64 - expected_z).abs() / expected_z);
            }
        }
        assert!(worst < 1e-4, "{what}: relative depth error {worst}");
        assert_same_image(&ref_out, &out, 0.0, &what);
    }
}

/// Exact hit distances far from the origin, checked against the analytic value (not only the
/// reference): a camera looking straight down at the ground from height h sees distance h.
#[test]
fn far_from_origin_depth_is_exact() {
    let off = Vec3::new(1e5, 0.0, -1e5);
    let r = renderer(load(&plane_box(1.0, off), "far"));
    for h in [0.5f64, 1.7, 3.0] {
        let o = off.as_dvec3() + DVec3::new(1.5, h, -1.5);
        let hit = r.trace_primary(&WorldRay { origin: o, direction: DVec3::NEG_Y }).expect("ground hit");
        assert!(((hit.distance - h) / h).abs() < 1e-6, "distance {} for height {h}", hit.distance);
    }
}

/// Rays at 89.9° from the normal of a large plane: a finite hit at the analytic distance
/// h / cos θ, from several heights and azimuths; and a grazing camera renders finite output.
#[test]
fn grazing_rays_hit_at_the_right_distance() {
    let mut b = SceneBuilder::new("graze");
    let grey = b.add_material(Material::diffuse("grey", [0.5, 0.5, 0.5])).unwrap();
    b.add_mesh("ground", Mesh::quad(Vec2::new(400.0, 400.0), 1.0), grey, Transform::IDENTITY).unwrap();
    b.add_light("sun", Light::Directional { color: [1.0; 3], illuminance: 2.0 }, Transform::look_at(Vec3::ZERO, Vec3::new(0.2, -1.0, 0.1), Vec3::Y))
        .unwrap();
    let r = renderer(load(&b, "graze"));
    let theta = 89.9f64.to_radians();
    for h in [0.01f64, 0.05, 0.2] {
        for k in 0..8 {
            let phi = k as f64 * std::f64::consts::TAU / 8.0 + 0.1;
            let d = DVec3::new(theta.sin() * phi.cos(), -theta.cos(), theta.sin() * phi.sin());
            let o = DVec3::new(1.0, h, -2.0);
            let expected = h / theta.cos();
            let hit = r.trace_primary(&WorldRay { origin: o, direction: d });
            let hit = hit.unwrap_or_else(|| panic!("h {h}, phi {phi}: grazing ray missed (expected {expected})"));
            assert!(hit.distance.is_finite() && hit.normal.is_finite(), "h {h}: non-finite hit");
            let rel = ((hit.distance - expected) / expected).abs();
            assert!(rel < 1e-4, "h {h}, phi {phi}: distance {} vs {expected} (rel {rel})", hit.distance);
        }
    }
    // A camera 5 cm above the plane looking along it: every pixel finite.
    let cam = Camera::new(Intrinsics::from_fov_y(32, 32, 0.3), Camera::look_at(DVec3::new(0.0, 0.05, 0.0), DVec3::new(0.0, 0.05 - 50.0 * 0.1f64.to_radians().tan(), -50.0), DVec3::Y))
        .unwrap();
    let out = r.render_view(&cam, 0, &settings(8));
    assert_finite(&out, "grazing camera");
}

/// Appends triangles to the scene's mesh (material of triangle `like`, flat normals copied from
/// vertex `like_vertex`); the mesh stays consistent for [`Renderer::new`].
fn append_triangles(scene: &mut Scene, tris: &[[Vec3; 3]], like: usize) {
    let m = &mut scene.mesh;
    let mat = m.material[like];
    let v = m.indices[like][0] as usize;
    for t in tris {
        let base = m.positions.len() as u32;
        for p in t {
            m.positions.push(*p);
            if !m.normals.is_empty() {
                let n = m.normals[v];
                m.normals.push(n);
            }
            if !m.tangents.is_empty() {
                let x = m.tangents[v];
                m.tangents.push(x);
            }
            if !m.uv0.is_empty() {
                let x = m.uv0[v];
                m.uv0.push(x);
            }
            if !m.uv1.is_empty() {
                let x = m.uv1[v];
                m.uv1.push(x);
            }
            if !m.colors.is_empty() {
                let x = m.colors[v];
                m.colors.push(x);
            }
        }
        m.indices.push([base, base + 1, base + 2]);
        m.material.push(mat);
    }
}

/// Zero-area, collinear, duplicated coplanar and coincident triangles on the ground: no NaN or
/// Inf anywhere, and the image equals the clean scene's within noise.
#[test]
fn degenerate_and_coincident_triangles_change_nothing() {
    let clean = load(&plane_box(1.0, Vec3::ZERO), "degen");
    let mut dirty = clean.clone();
    // The ground is the first mesh: find a triangle lying in its plane (local frame).
    let ground_y = clean.mesh.indices.iter().map(|t| clean.mesh.positions[t[0] as usize].y).fold(f32::INFINITY, f32::min);
    let like = clean.mesh.indices.iter().position(|t| t.iter().all(|&i| clean.mesh.positions[i as usize].y == ground_y)).unwrap();
    let y = ground_y;
    let p = |x: f32, z: f32| Vec3::new(x, y, z);
    let mut tris = vec![
        [p(0.5, 0.5); 3],                                     // zero area, a point
        [p(-1.0, 1.0), p(0.0, 1.0), p(1.0, 1.0)],             // collinear
        [p(-1.0, 1.0), p(1.0, 1.0), p(0.0, 1.0)],             // collinear, other winding
        [p(-1.5, -1.5), p(-1.5, 1.5), p(1.5, 1.5)],           // coplanar overlap (same material)
        [p(-1.0, -1.0), p(-1.0, 1.0 + 1e-7), p(1.0, 1.0)],    // nearly collinear sliver region
        [Vec3::new(0.0, 1.0, 0.0), Vec3::new(0.0, 1.0, 0.0), Vec3::new(0.0, 2.0, 0.0)], // zero area in the air
    ];
    // Exact duplicates of every ground triangle (coincident, same winding).
    for t in clean.mesh.indices.iter().filter(|t| t.iter().all(|&i| clean.mesh.positions[i as usize].y == y)) {
        tris.push(t.map(|i| clean.mesh.positions[i as usize]));
    }
    append_triangles(&mut dirty, &tris, like);
    let cam = plane_box_camera(1.0, DVec3::ZERO, 32);
    let (a, b) = (renderer(clean), renderer(dirty));
    let (oa, ob) = (a.render_view(&cam, 0, &settings(16)), b.render_view(&cam, 0, &settings(16)));
    assert_finite(&oa, "clean");
    assert_finite(&ob, "degenerate");
    for k in 0..oa.ground_truth.distance.len() {
        let (d0, d1) = (oa.ground_truth.distance[k], ob.ground_truth.distance[k]);
        assert!((d0 - d1).abs() <= 1e-5 * d0.max(1.0), "pixel {k}: distance {d0} vs {d1}");
    }
    assert_same_image(&oa, &ob, 0.0, "degenerate triangles");
}

/// Roughness-0 metal (a perfect mirror lobe) under a point light, a sun and an area light:
/// every output finite.
#[test]
fn roughness_zero_metal_is_finite() {
    let mut b = plane_box(1.0, Vec3::ZERO);
    let mirror = b.add_material(Material::diffuse("mirror", [0.9, 0.9, 0.9]).with_metallic_roughness(1.0, 0.0)).unwrap();
    let lamp = b.add_material(Material::emissive("lamp", [1.0; 3], 20.0).double_sided()).unwrap();
    b.add_mesh("ball", Mesh::uv_sphere(0.3, 24, 12), mirror, Transform::from_translation(Vec3::new(0.7, 0.3, -0.5))).unwrap();
    b.add_mesh("slab", Mesh::cuboid(Vec3::new(0.4, 0.02, 0.4)), mirror, Transform::from_translation(Vec3::new(-0.6, 0.02, -0.8))).unwrap();
    b.add_mesh("lamp", Mesh::quad(Vec2::new(0.3, 0.3), 1.0), lamp, Transform::from_translation_rotation(Vec3::new(0.0, 1.8, 0.0), Quat::from_rotation_x(std::f32::consts::PI)))
        .unwrap();
    let r = renderer(load(&b, "mirror"));
    let s = RenderSettings { max_bounces: 6, ..settings(8) };
    let out = r.render_view(&plane_box_camera(1.0, DVec3::ZERO, 32), 0, &s);
    assert_finite(&out, "roughness 0 metal");
    let top = r.render_view(&camera(DVec3::new(0.7, 2.0, -0.5), DVec3::new(0.7, 0.0, -0.5), 32), 1, &s);
    assert_finite(&top, "roughness 0 metal, from above");
}

/// A receiving plane under a downward emissive square of side `side` at height 1 m, radiance
/// chosen so the power is the same for every side; camera below the emitter looking down.
fn emitter_scene(side: f32) -> Renderer {
    let mut b = SceneBuilder::new("emitter");
    let grey = b.add_material(Material::diffuse("grey", [0.5, 0.5, 0.5])).unwrap();
    let strength = 400.0 * (0.05 / side).powi(2);
    let lamp = b.add_material(Material::emissive("lamp", [1.0; 3], strength)).unwrap();
    b.add_mesh("ground", Mesh::quad(Vec2::new(6.0, 6.0), 1.0), grey, Transform::IDENTITY).unwrap();
    let down = Quat::from_rotation_x(std::f32::consts::PI);
    b.add_mesh("lamp", Mesh::quad(Vec2::splat(side), 1.0), lamp, Transform::from_translation_rotation(Vec3::new(0.0, 1.0, 0.0), down)).unwrap();
    renderer(load(&b, "emitter"))
}

/// A 0.5 mm emitter 10⁴× brighter than a 5 cm one (same power): no NaN/Inf, and the mean
/// radiance on the receiver equals the larger emitter's within noise (the light estimate is
/// unbiased however small the emitter). The 5 cm square's finite size changes on-axis
/// irradiance by O((a/h)²) ≈ 2.5e-3 relative, so 0.5 % of the mean is allowed on top of 3σ.
#[test]
fn tiny_bright_emitter_is_unbiased() {
    let cam = Camera::new(Intrinsics::from_fov_y(32, 32, 1.2), Camera::look_at(DVec3::new(0.0, 0.9, 0.0), DVec3::ZERO, DVec3::Z)).unwrap();
    let s = RenderSettings { max_bounces: 1, ..settings(16) };
    let big = emitter_scene(0.05).render_view(&cam, 0, &s);
    let tiny = emitter_scene(0.0005).render_view(&cam, 0, &s);
    assert_finite(&big, "5 cm emitter");
    assert_finite(&tiny, "0.5 mm emitter");
    assert_same_image(&big, &tiny, 5e-3, "tiny bright emitter");
}
