//! The renderer's tests: closed forms (Lambert under a point light, the furnace, form
//! factors, the mirror caustic), exact ground truth, bit-identity across batches, lanes,
//! thread counts and SIMD widths, and the caustic light tracer against the path tracer.

use super::*;
use crate::scene::{Aabb, Material, Mesh};
use dataset::Intrinsics;
use glam::{Vec2, Vec4};
use std::f64::consts::PI as PI64;

/// Test-scene builder: flat-shaded triangles with per-triangle materials.
struct Builder {
    mesh: Mesh,
    materials: Vec<Material>,
    lights: Vec<Light>,
}

impl Builder {
    fn new() -> Self {
        Self { mesh: Mesh::default(), materials: Vec::new(), lights: Vec::new() }
    }
    fn material(&mut self, albedo: f32, emissive: f32, double_sided: bool) -> u32 {
        // Exactly Lambertian (metallic 0, KHR_materials_specular 0), the closed forms' BRDF.
        let mut m = Material::gltf_default();
        m.metallic_factor = 0.0;
        m.specular_factor = 0.0;
        m.base_color_factor = Vec4::new(albedo, albedo, albedo, 1.0);
        m.emissive = Vec3::splat(emissive);
        m.double_sided = double_sided;
        self.materials.push(m);
        self.materials.len() as u32 - 1
    }
    fn tri(&mut self, p: [Vec3; 3], material: u32) {
        let n = (p[1] - p[0]).cross(p[2] - p[0]).normalize();
        let base = self.mesh.positions.len() as u32;
        for v in p {
            self.mesh.positions.push(v);
            self.mesh.normals.push(n);
            self.mesh.tangents.push(Vec4::ZERO);
            self.mesh.uv0.push(Vec2::ZERO);
            self.mesh.uv1.push(Vec2::ZERO);
            self.mesh.colors.push(Vec4::ONE);
        }
        self.mesh.indices.push([base, base + 1, base + 2]);
        self.mesh.material.push(material);
    }
    /// Quad p0 p1 p2 p3 (counter-clockwise seen from the front), split into `n × n` cells.
    fn quad(&mut self, p: [Vec3; 4], n: u32, material: u32) {
        let at = |u: f32, v: f32| {
            let a = p[0].lerp(p[1], u);
            let b = p[3].lerp(p[2], u);
            a.lerp(b, v)
        };
        for i in 0..n {
            for j in 0..n {
                let (u0, u1) = (i as f32 / n as f32, (i + 1) as f32 / n as f32);
                let (v0, v1) = (j as f32 / n as f32, (j + 1) as f32 / n as f32);
                self.tri([at(u0, v0), at(u1, v0), at(u1, v1)], material);
                self.tri([at(u0, v0), at(u1, v1), at(u0, v1)], material);
            }
        }
    }
    /// Axis-aligned box; faces point outward (or inward with `inward`).
    fn aabox(&mut self, lo: Vec3, hi: Vec3, inward: bool, material: u32) {
        let c = |x: bool, y: bool, z: bool| Vec3::new(if x { hi.x } else { lo.x }, if y { hi.y } else { lo.y }, if z { hi.z } else { lo.z });
        let mut faces = vec![
            [c(true, false, false), c(true, true, false), c(true, true, true), c(true, false, true)],
            [c(false, false, false), c(false, false, true), c(false, true, true), c(false, true, false)],
            [c(false, true, false), c(false, true, true), c(true, true, true), c(true, true, false)],
            [c(false, false, false), c(true, false, false), c(true, false, true), c(false, false, true)],
            [c(false, false, true), c(true, false, true), c(true, true, true), c(false, true, true)],
            [c(false, false, false), c(false, true, false), c(true, true, false), c(true, false, false)],
        ];
        if inward {
            for f in &mut faces {
                f.reverse();
            }
        }
        for f in faces {
            self.quad(f, 1, material);
        }
    }
    /// A floor (glossy dielectric, `n × n` cells), a metal and a Lambertian box, a small
    /// double-sided emitting quad above them and a point light.
    fn glossy_room(&mut self, n: u32) {
        let lambert = self.material(0.7, 0.0, false);
        let e = self.material(0.5, 3.0, true);
        let mut gltf = |metallic: f32, roughness: f32| {
            let mut m = Material::gltf_default();
            (m.metallic_factor, m.roughness_factor) = (metallic, roughness);
            m.base_color_factor = Vec4::new(0.8, 0.5, 0.3, 1.0);
            self.materials.push(m);
            self.materials.len() as u32 - 1
        };
        let (plastic, metal) = (gltf(0.0, 0.4), gltf(1.0, 0.15));
        self.quad([Vec3::new(-3.0, 0.0, 3.0), Vec3::new(3.0, 0.0, 3.0), Vec3::new(3.0, 0.0, -3.0), Vec3::new(-3.0, 0.0, -3.0)], n, plastic);
        self.aabox(Vec3::new(-0.5, 0.0, -0.5), Vec3::new(0.5, 1.0, 0.5), false, metal);
        self.aabox(Vec3::new(0.8, 0.0, -0.2), Vec3::new(1.2, 0.6, 0.2), false, lambert);
        self.quad([Vec3::new(-0.3, 2.0, -0.3), Vec3::new(0.3, 2.0, -0.3), Vec3::new(0.3, 2.0, 0.3), Vec3::new(-0.3, 2.0, 0.3)], 1, e);
        self.lights.push(Light::Point { position: Vec3::new(2.0, 3.0, 1.0), intensity: Vec3::splat(10.0), range: None });
    }
    fn build(self, origin: DVec3) -> Scene {
        let bounds = self.mesh.positions.iter().fold(Aabb::EMPTY, |b, &p| b.union_point(p));
        Scene {
            name: "test".into(),
            origin,
            mesh: self.mesh,
            materials: self.materials,
            textures: Vec::new(),
            lights: self.lights,
            cameras: Vec::new(),
            bounds,
            warnings: Vec::new(),
            objects: vec![],
        }
    }
}

fn camera(w: u32, h: u32, fov_y_deg: f64, eye: DVec3, target: DVec3) -> Camera {
    Camera::new(Intrinsics::from_fov_y(w, h, fov_y_deg.to_radians()), Camera::look_at(eye, target, DVec3::Y)).unwrap()
}

fn settings(spp: u32, max_bounces: u32, environment: f32, transparent: bool) -> RenderSettings {
    RenderSettings { spp, max_bounces, seed: 1, environment: [environment; 3], transparent_background: transparent, environment_map: None }
}

/// Mean and standard error of `n` radiance samples (red channel) along `ray`.
fn estimate(r: &Renderer, s: &RenderSettings, ray: &Ray, n: u32) -> (f64, f64) {
    let integ = r.integrator(s);
    let (mut sum, mut sum2) = (0.0f64, 0.0f64);
    for k in 0..n {
        let mut sampler = Sampler::new(s.seed, 0, k as u64, 0);
        let v = integ.radiance(ray, &mut sampler).radiance.x as f64;
        sum += v;
        sum2 += v * v;
    }
    let mean = sum / n as f64;
    (mean, ((sum2 / n as f64 - mean * mean).max(0.0) / n as f64).sqrt())
}

/// Slab intersection of a ray with an axis-aligned box: entry distance and entry axis.
fn ray_box(o: DVec3, d: DVec3, lo: DVec3, hi: DVec3) -> Option<(f64, usize)> {
    let (mut t0, mut t1, mut axis) = (f64::NEG_INFINITY, f64::INFINITY, 0);
    for a in 0..3 {
        let (n, f) = ((lo[a] - o[a]) / d[a], (hi[a] - o[a]) / d[a]);
        let (n, f) = (n.min(f), n.max(f));
        if n > t0 {
            t0 = n;
            axis = a;
        }
        t1 = t1.min(f);
    }
    (t0 <= t1 && t0 > 0.0).then_some((t0, axis))
}

#[test]
fn ground_truth_depth_distance_normal_alpha_are_exact() {
    let origin = DVec3::new(1000.0, -50.0, 2000.0);
    let (blo, bhi) = (Vec3::new(-0.5, 0.0, -0.7), Vec3::new(0.6, 1.1, 0.4));
    let mut b = Builder::new();
    let m = b.material(0.5, 0.0, false);
    b.quad([Vec3::new(-4.0, 0.0, 4.0), Vec3::new(4.0, 0.0, 4.0), Vec3::new(4.0, 0.0, -4.0), Vec3::new(-4.0, 0.0, -4.0)], 3, m);
    b.aabox(blo, bhi, false, m);
    let r = Renderer::new(b.build(origin), &AccelParams::medium_build()).unwrap();
    let cam = camera(64, 48, 60.0, origin + DVec3::new(2.5, 2.0, 3.5), origin + DVec3::new(0.0, 0.3, 0.0));
    let out = r.render_view(&cam, 0, &settings(1, 0, 0.0, true));
    let gt = &out.ground_truth;
    let (mut hits, mut checked) = (0, 0);
    for j in 0..48u32 {
        for i in 0..64u32 {
            let k = (j * 64 + i) as usize;
            let ray = cam.pixel_center_ray(i, j);
            let o = ray.origin - origin;
            let d = ray.direction;
            // Analytic: box entry, else plane y = 0 within |x|,|z| ≤ 4.
            let mut expect: Option<(f64, DVec3, DVec3)> = None;
            if let Some((t, a)) = ray_box(o, d, blo.as_dvec3(), bhi.as_dvec3()) {
                let mut n = DVec3::ZERO;
                n[a] = -d[a].signum();
                expect = Some((t, n, o + t * d));
            } else if d.y < 0.0 {
                let t = -o.y / d.y;
                let p = o + t * d;
                if p.x.abs() <= 4.0 && p.z.abs() <= 4.0 {
                    expect = Some((t, DVec3::Y, p));
                }
            }
            // Skip pixel centres within 1e-4 of a silhouette edge (box or plane border).
            let near_edge = |p: DVec3| {
                let (lo, hi) = (blo.as_dvec3(), bhi.as_dvec3());
                let on = (0..3).filter(|&a| (p[a] - lo[a]).abs() < 1e-4 || (p[a] - hi[a]).abs() < 1e-4).count();
                on >= 2 || (p.x.abs() - 4.0).abs() < 1e-4 || (p.z.abs() - 4.0).abs() < 1e-4
            };
            match expect {
                Some((t, n, p)) => {
                    if near_edge(p) {
                        continue;
                    }
                    hits += 1;
                    checked += 1;
                    assert_eq!(gt.alpha[k], 1.0, "pixel {i},{j}");
                    let depth = cam.z_depth_from_distance(i as f64 + 0.5, j as f64 + 0.5, t);
                    assert!(((gt.distance[k] as f64) - t).abs() <= 1e-6 * t, "distance {i},{j}: {} vs {t}", gt.distance[k]);
                    assert!(((gt.depth[k] as f64) - depth).abs() <= 1e-6 * depth, "depth {i},{j}");
                    let gn = DVec3::new(gt.normal[3 * k] as f64, gt.normal[3 * k + 1] as f64, gt.normal[3 * k + 2] as f64);
                    assert!((gn - n).length() < 1e-6, "normal {i},{j}: {gn} vs {n}");
                }
                None => {
                    checked += 1;
                    assert_eq!((gt.alpha[k], gt.depth[k], gt.distance[k]), (0.0, 0.0, 0.0), "pixel {i},{j} should miss");
                }
            }
        }
    }
    assert!(hits > 1500 && checked > 3000, "{hits} hits, {checked} checked");
    let (lo, hi) = out.distance_range.unwrap();
    assert!(lo > 2.0 && hi < 12.0 && lo < hi);
    // The f64 refinement is exact to ~1e-12 (beyond f32 output precision).
    let ph = r.trace_primary(&cam.pixel_center_ray(32, 40)).unwrap();
    let ray = cam.pixel_center_ray(32, 40);
    let t = -(ray.origin.y - origin.y) / ray.direction.y;
    assert!((ph.distance - t).abs() < 1e-9 * t, "{} vs {t}", ph.distance);
}

/// Lambertian plane (albedo ρ) under a point light: L = ρ/π · I cos θ / r².
fn lambert_point(albedo: f64, intensity: f64, light: DVec3, p: DVec3) -> f64 {
    let d = light - p;
    let r2 = d.length_squared();
    let cos = d.y / r2.sqrt();
    albedo / PI64 * intensity * cos / r2
}

#[test]
fn lambertian_plane_under_point_light_matches_closed_form() {
    let (albedo, intensity) = (0.6f32, 10.0f32);
    let light = Vec3::new(0.3, 2.0, -0.2);
    let mut b = Builder::new();
    let m = b.material(albedo, 0.0, false);
    b.quad([Vec3::new(-5.0, 0.0, 5.0), Vec3::new(5.0, 0.0, 5.0), Vec3::new(5.0, 0.0, -5.0), Vec3::new(-5.0, 0.0, -5.0)], 2, m);
    b.lights.push(Light::Point { position: light, intensity: Vec3::splat(intensity), range: None });
    let r = Renderer::new(b.build(DVec3::ZERO), &AccelParams::fast_build()).unwrap();
    let cam = camera(16, 12, 40.0, DVec3::new(0.0, 3.0, 3.0), DVec3::ZERO);
    // Pixel centres, deterministic (direct light from a point light has no noise).
    let s = settings(1, 1, 0.0, true);
    let integ = r.integrator(&s);
    for j in 0..12 {
        for i in 0..16 {
            let ray = cam.pixel_center_ray(i, j);
            let t = -ray.origin.y / ray.direction.y;
            let expect = lambert_point(albedo as f64, intensity as f64, light.as_dvec3(), ray.origin + t * ray.direction);
            let got = integ.radiance(&r.local_ray(&ray), &mut Sampler::new(0, 0, 0, 0)).radiance;
            assert!((got.x as f64 - expect).abs() < 1e-4 * expect, "{i},{j}: {} vs {expect}", got.x);
        }
    }
    // Whole pixels: the average of the closed form over the pixel (16×16 grid), within
    // 4.5σ of independent jitter noise (σ from the closed form's spread over the pixel);
    // the sampler's stratified pixel positions do far better than that.
    let spp = 64;
    let out = r.render_view(&cam, 0, &settings(spp, 1, 0.0, true));
    let mut chi2 = 0.0;
    for j in 0..12 {
        for i in 0..16 {
            let (mut sum, mut sum2) = (0.0, 0.0);
            for a in 0..16 {
                for c in 0..16 {
                    let ray = cam.pixel_ray(i as f64 + (a as f64 + 0.5) / 16.0, j as f64 + (c as f64 + 0.5) / 16.0);
                    let t = -ray.origin.y / ray.direction.y;
                    let v = lambert_point(albedo as f64, intensity as f64, light.as_dvec3(), ray.origin + t * ray.direction);
                    sum += v;
                    sum2 += v * v;
                }
            }
            let mean = sum / 256.0;
            let sigma = ((sum2 / 256.0 - mean * mean).max(0.0) / spp as f64).sqrt();
            let got = out.color.pixel(i, j);
            // 4.5σ per pixel (192 pixels), and the mean squared z-score near 1.
            assert!((got[0] as f64 - mean).abs() <= 4.5 * sigma + 1e-4 * mean, "{i},{j}: {} vs {mean} ± {sigma}", got[0]);
            chi2 += ((got[0] as f64 - mean) / (sigma + 1e-12)).powi(2);
            assert_eq!(got[3], 1.0);
        }
    }
    // Independent jitter would give a mean squared z-score near 1; 64 stratified positions
    // per pixel (a (0,6,2)-net) give far less (about 1e-4).
    let chi2 = chi2 / 192.0;
    assert!(chi2 < 0.05, "mean squared z-score {chi2}: pixel positions are not stratified");
    assert_eq!(out.nonfinite_samples, 0);
    assert_eq!(out.samples, 16 * 12 * spp as u64);
}

#[test]
fn closed_emissive_furnace_reaches_equilibrium_radiance() {
    // Every wall of a closed room has albedo ρ and emits Le: L = Le (1 − ρ^(n+1)) / (1 − ρ)
    // with n bounces → Le / (1 − ρ).
    let (albedo, le, bounces) = (0.5f32, 1.0f32, 40u32);
    let mut b = Builder::new();
    let m = b.material(albedo, le, false);
    b.aabox(Vec3::splat(-1.0), Vec3::splat(1.0), true, m);
    let r = Renderer::new(b.build(DVec3::ZERO), &AccelParams::fast_build()).unwrap();
    let expect = le as f64 * (1.0 - (albedo as f64).powi(bounces as i32 + 1)) / (1.0 - albedo as f64);
    let s = settings(1, bounces, 0.0, true);
    for dir in [Vec3::new(0.3, -0.2, 0.9), Vec3::new(-1.0, 0.1, 0.05), Vec3::new(0.7, 0.7, -0.1)] {
        let ray = Ray::new(Vec3::new(0.1, 0.2, -0.3), dir.normalize());
        let (mean, se) = estimate(&r, &s, &ray, 20_000);
        assert!((mean - expect).abs() < 3.0 * se, "{mean} ± {se} vs {expect}");
        assert!(se < 0.02 * expect, "noise {se} too high");
    }
    // Through the renderer: every pixel hits; alpha 1; the image mean is close.
    let cam = camera(8, 8, 70.0, DVec3::new(0.1, 0.2, 0.5), DVec3::new(0.0, -0.5, -1.0));
    let out = r.render_view(&cam, 0, &settings(32, bounces, 0.0, true));
    let mean: f64 = (0..64).map(|k| out.color.data[4 * k] as f64).sum::<f64>() / 64.0;
    assert!((mean - expect).abs() < 0.05 * expect, "{mean} vs {expect}");
    assert!(out.color.data.chunks(4).all(|p| p[3] == 1.0) && out.ground_truth.alpha.iter().all(|&a| a == 1.0));
}

#[test]
fn environment_lights_a_lambertian_plane_with_mis() {
    // A plane under a constant environment E reflects L = ρ E (the hemisphere above it is
    // all environment); camera misses are transparent or show E.
    let (albedo, env) = (0.5f32, 2.0f32);
    let mut b = Builder::new();
    let m = b.material(albedo, 0.0, false);
    b.quad([Vec3::new(-100.0, 0.0, 100.0), Vec3::new(100.0, 0.0, 100.0), Vec3::new(100.0, 0.0, -100.0), Vec3::new(-100.0, 0.0, -100.0)], 1, m);
    let r = Renderer::new(b.build(DVec3::ZERO), &AccelParams::fast_build()).unwrap();
    let s = settings(1, 3, env, true);
    let ray = Ray::new(Vec3::new(0.0, 1.0, 0.0), Vec3::new(0.2, -1.0, 0.1).normalize());
    let (mean, se) = estimate(&r, &s, &ray, 20_000);
    let expect = (albedo * env) as f64;
    assert!((mean - expect).abs() < 3.0 * se + 1e-6, "{mean} ± {se} vs {expect}");
    // Looking up: transparent miss, or the environment when opaque.
    let up = dataset::Ray { origin: DVec3::new(0.0, 1.0, 0.0), direction: DVec3::Y };
    let integ = r.integrator(&s);
    let miss = integ.radiance(&r.local_ray(&up), &mut Sampler::new(0, 0, 0, 0));
    assert_eq!((miss.radiance, miss.primary_hit), (Vec3::ZERO, false));
    let opaque = r.integrator(&settings(1, 3, env, false)).radiance(&r.local_ray(&up), &mut Sampler::new(0, 0, 0, 0));
    assert_eq!(opaque.radiance, Vec3::splat(env));
    // A view half sky, half plane: coverage alpha is the hit fraction.
    let cam = camera(8, 8, 20.0, DVec3::new(0.0, 0.5, 0.0), DVec3::new(0.0, 0.5, -10.0));
    let out = r.render_view(&cam, 0, &settings(16, 3, env, true));
    assert!(out.color.pixel(0, 0)[3] == 0.0 && out.color.pixel(0, 7)[3] == 1.0);
    let out = r.render_view(&cam, 0, &settings(4, 3, env, false));
    assert_eq!(out.color.pixel(0, 0), [env, env, env, 1.0]);
}

#[test]
fn constant_environment_map_renders_like_the_constant_environment() {
    // Lambertian plane (closed form ρE) and a glossy metal plane (compared between the two
    // environments, 4σ of the difference), with an 8 × 4 map of ones scaled by E.
    let env = 2.0f32;
    for (metallic, roughness) in [(0.0f32, 1.0f32), (1.0, 0.3)] {
        let mut b = Builder::new();
        let m = b.material(0.5, 0.0, false);
        if metallic > 0.0 {
            b.materials[m as usize].metallic_factor = metallic;
            b.materials[m as usize].roughness_factor = roughness;
            b.materials[m as usize].specular_factor = 1.0;
        }
        b.quad([Vec3::new(-100.0, 0.0, 100.0), Vec3::new(100.0, 0.0, 100.0), Vec3::new(100.0, 0.0, -100.0), Vec3::new(-100.0, 0.0, -100.0)], 1, m);
        let mut r = Renderer::new(b.build(DVec3::ZERO), &AccelParams::fast_build()).unwrap();
        let s = settings(1, 3, env, true);
        let ray = Ray::new(Vec3::new(0.0, 1.0, 0.0), Vec3::new(0.4, -1.0, 0.1).normalize());
        let (c_mean, c_se) = estimate(&r, &s, &ray, 20_000);
        r.set_environment_map(Some(Arc::new(EnvironmentMap::from_texels(8, 4, vec![Vec3::ONE; 32]).unwrap())));
        let (m_mean, m_se) = estimate(&r, &s, &ray, 20_000);
        assert!((c_mean - m_mean).abs() < 4.0 * (c_se * c_se + m_se * m_se).sqrt(), "metallic {metallic}: {c_mean} ± {c_se} vs map {m_mean} ± {m_se}");
        if metallic == 0.0 {
            assert!((m_mean - 1.0).abs() < 4.0 * m_se + 1e-6, "{m_mean} ± {m_se} vs ρE = 1");
        }
        // Misses see the map.
        let up = r.integrator(&settings(1, 3, env, false)).radiance(&Ray::new(Vec3::Y, Vec3::Y), &mut Sampler::new(0, 0, 0, 0));
        assert_eq!(up.radiance, Vec3::splat(env));
    }
}

#[test]
fn blended_surfaces_cover_alpha_of_the_rays_and_gltf_materials_render_finite() {
    use crate::scene::{AlphaMode, Filter, Texture, TextureRef, Wrap};
    let mut b = Builder::new();
    let floor = b.material(0.5, 0.0, false);
    let glass = b.material(0.5, 0.0, true);
    b.materials[glass as usize].alpha_mode = AlphaMode::Blend;
    b.materials[glass as usize].base_color_factor.w = 0.3;
    // Floor: glTF default metal with a bumpy normal map (generated tangents).
    b.materials[floor as usize] = Material::gltf_default();
    b.materials[floor as usize].roughness_factor = 0.0;
    b.materials[floor as usize].normal_texture = Some((TextureRef { texture: 0, tex_coord: 0, wrap_s: Wrap::Repeat, wrap_t: Wrap::Repeat, filter: Filter::Linear, transform: None }, 1.0));
    b.quad([Vec3::new(-5.0, 0.0, 5.0), Vec3::new(5.0, 0.0, 5.0), Vec3::new(5.0, 0.0, -5.0), Vec3::new(-5.0, 0.0, -5.0)], 4, floor);
    b.quad([Vec3::new(-5.0, 1.0, 5.0), Vec3::new(5.0, 1.0, 5.0), Vec3::new(5.0, 1.0, -5.0), Vec3::new(-5.0, 1.0, -5.0)], 1, glass);
    let mut scene = b.build(DVec3::ZERO);
    for (k, p) in scene.mesh.positions.iter().enumerate() {
        scene.mesh.uv0[k] = Vec2::new(p.x * 0.7, -p.z * 0.7);
    }
    // Strong tilts, including normals that face away from grazing viewers.
    scene.textures.push(Texture { width: 2, height: 2, texels: vec![Vec4::new(1.0, 0.5, 0.05, 1.0), Vec4::new(0.0, 0.5, 0.3, 1.0), Vec4::new(0.5, 1.0, 0.1, 1.0), Vec4::new(0.5, 0.0, 0.5, 1.0)] });
    scene.lights.push(Light::Point { position: Vec3::new(0.5, 3.0, 0.2), intensity: Vec3::splat(20.0), range: None });
    let r = Renderer::new(scene, &AccelParams::fast_build()).unwrap();
    assert!(r.is_view_dependent());
    // Coverage: about 30 % of the rays stop at the blended quad (binomial 4σ).
    let n = 20_000u64;
    let stopped = (0..n)
        .filter(|&k| {
            let u = Sampler::new(4, 0, k, 0).next_2d();
            let ray = dataset::Ray { origin: DVec3::new(u.x as f64 * 4.0 - 2.0, 3.0, u.y as f64 * 4.0 - 2.0), direction: DVec3::new(0.1, -1.0, 0.05).normalize() };
            r.trace_primary(&ray).is_some_and(|h| h.distance < 2.5)
        })
        .count() as f64
        / n as f64;
    assert!((stopped - 0.3).abs() < 4.0 * (0.3f64 * 0.7 / n as f64).sqrt(), "coverage {stopped}");
    // Deterministic per ray.
    let ray = dataset::Ray { origin: DVec3::new(0.3, 3.0, 0.1), direction: -DVec3::Y };
    assert_eq!(r.trace_primary(&ray).map(|h| h.distance), r.trace_primary(&ray).map(|h| h.distance));
    // A mirror-like normal-mapped metal seen at grazing angles renders finite and lit.
    let cam = camera(24, 16, 60.0, DVec3::new(0.0, 0.3, 4.0), DVec3::new(0.0, 0.0, -5.0));
    let out = r.render_view(&cam, 0, &settings(8, 4, 0.5, true));
    assert_eq!(out.nonfinite_samples, 0);
    assert!(out.color.data.iter().all(|x| x.is_finite()) && out.color.data.iter().any(|&x| x > 0.0));
}

/// Direct light at a point on a receiver from a parallel emissive rectangle of half-sizes
/// (a, b) at height h centred above it: L = ρ · Le · F with F the point-to-rectangle form
/// factor (sum of four corner rectangles).
fn form_factor_centered(a: f64, b: f64, h: f64) -> f64 {
    let corner = |x: f64, y: f64| {
        let (x, y) = (x / h, y / h);
        let (sx, sy) = ((1.0 + x * x).sqrt(), (1.0 + y * y).sqrt());
        (x / sx * (y / sx).atan() + y / sy * (x / sy).atan()) / (2.0 * PI64)
    };
    4.0 * corner(a, b)
}

#[test]
fn emissive_quad_direct_light_matches_form_factor() {
    let (albedo, le, h, half) = (0.8f32, 5.0f32, 1.0f32, 0.5f32);
    let mut b = Builder::new();
    let recv = b.material(albedo, 0.0, false);
    let emit = b.material(0.0, le, false);
    b.quad([Vec3::new(-5.0, 0.0, 5.0), Vec3::new(5.0, 0.0, 5.0), Vec3::new(5.0, 0.0, -5.0), Vec3::new(-5.0, 0.0, -5.0)], 1, recv);
    // Facing down (towards the receiver), split into 2×2 cells of 8 triangles.
    b.quad([Vec3::new(-half, h, -half), Vec3::new(half, h, -half), Vec3::new(half, h, half), Vec3::new(-half, h, half)], 2, emit);
    let r = Renderer::new(b.build(DVec3::ZERO), &AccelParams::fast_build()).unwrap();
    assert_eq!(r.emitters().len(), 8);
    let eye = Vec3::new(3.0, 0.5, 0.0);
    let ray = Ray::new(eye, (-eye).normalize());
    let expect = (albedo * le) as f64 * form_factor_centered(half as f64, half as f64, h as f64);
    let (mean, se) = estimate(&r, &settings(1, 1, 0.0, true), &ray, 40_000);
    assert!((mean - expect).abs() < 3.0 * se, "{mean} ± {se} vs {expect}");
    assert!(se < 0.01 * expect);
    // Seen directly, the emitter shows Le (and only from its front).
    let up = Ray::new(Vec3::new(0.1, 0.0 + 0.5, 0.1), Vec3::Y);
    let direct = r.integrator(&settings(1, 0, 0.0, true)).radiance(&up, &mut Sampler::new(0, 0, 0, 0));
    assert_eq!(direct.radiance, Vec3::splat(le));
    let down = Ray::new(Vec3::new(0.1, 2.0, 0.1), -Vec3::Y);
    let behind = r.integrator(&settings(1, 0, 0.0, true)).radiance(&down, &mut Sampler::new(0, 0, 0, 0));
    assert_eq!(behind.radiance, Vec3::ZERO, "single-sided emitter is invisible from behind");
}

#[test]
fn shadow_rays_far_from_the_origin_show_no_acne() {
    // A tessellated plane at 1e4 in local coordinates, lit at a grazing angle: every
    // pixel-centre point must be unoccluded and match the closed form.
    let off = Vec3::new(1.0e4, 1.0e4, -1.0e4);
    let (albedo, intensity) = (0.5f32, 100.0f32);
    let light = off + Vec3::new(-6.0, 0.4, 1.0);
    let mut b = Builder::new();
    let m = b.material(albedo, 0.0, false);
    b.quad([off + Vec3::new(-3.0, 0.0, 3.0), off + Vec3::new(3.0, 0.0, 3.0), off + Vec3::new(3.0, 0.0, -3.0), off + Vec3::new(-3.0, 0.0, -3.0)], 16, m);
    b.lights.push(Light::Point { position: light, intensity: Vec3::splat(intensity), range: None });
    let r = Renderer::new(b.build(DVec3::ZERO), &AccelParams::medium_build()).unwrap();
    let cam = camera(48, 48, 50.0, (off + Vec3::new(0.0, 4.0, 2.0)).as_dvec3(), off.as_dvec3());
    let integ = r.integrator(&settings(1, 1, 0.0, true));
    let mut lit = 0;
    for j in 0..48 {
        for i in 0..48 {
            let ray = cam.pixel_center_ray(i, j);
            let t = (off.y as f64 - ray.origin.y) / ray.direction.y;
            let p = ray.origin + t * ray.direction;
            if (p.x - off.x as f64).abs() > 2.99 || (p.z - off.z as f64).abs() > 2.99 {
                continue;
            }
            let expect = lambert_point(albedo as f64, intensity as f64, light.as_dvec3(), p);
            let got = integ.radiance(&r.local_ray(&ray), &mut Sampler::new(0, 0, 0, 0)).radiance.x as f64;
            // Acne would show as 0; the 1% tolerance covers the f32 hit point (ulp ≈ 1e-3 at 1e4).
            assert!((got - expect).abs() < 1e-2 * expect, "acne at {i},{j}: {got} vs {expect}");
            lit += 1;
        }
    }
    assert!(lit > 1000);
    // Bounce rays leaving the surface never re-hit it; rays leaving downwards never come back up.
    let mut escaped = 0;
    for k in 0..20_000u64 {
        let mut s = Sampler::new(9, 0, k, 0);
        let u = s.next_2d();
        let ray = Ray::new(off + Vec3::new(-2.9 + 5.8 * u.x, 5.0, -2.9 + 5.8 * u.y), -Vec3::Y);
        let hit = integ.intersect(&ray).unwrap();
        let si = crate::integrator::interaction(r.scene(), &ray, &hit);
        let w = crate::sampler::sample_cosine_hemisphere(s.next_2d());
        let w = Vec3::new(w.x, w.z, w.y);
        let o = crate::geometry::offset_ray_origin(si.p, si.p_err, si.ng, w);
        if integ.intersect(&Ray::new(o, w)).is_none() {
            escaped += 1;
        }
    }
    assert_eq!(escaped, 20_000);
}

/// A closed "cube sphere": a tessellated cube with vertices pushed onto a sphere, with
/// shared (deduplicated) vertices, double-sided.
fn cube_sphere(n: u32, centre: Vec3, radius: f32) -> (Scene, Vec<[u32; 2]>) {
    let mut b = Builder::new();
    let m = b.material(0.5, 0.0, true);
    let mut index: std::collections::HashMap<[u32; 3], u32> = std::collections::HashMap::new();
    let mut positions = Vec::new();
    let mut tris = Vec::new();
    let mut vid = |p: Vec3, positions: &mut Vec<Vec3>| {
        let key = p.to_array().map(f32::to_bits);
        *index.entry(key).or_insert_with(|| {
            positions.push(centre + radius * p.normalize());
            positions.len() as u32 - 1
        })
    };
    let g = |i: u32| -1.0 + 2.0 * i as f32 / n as f32;
    for axis in 0..3 {
        for side in [-1.0f32, 1.0] {
            for i in 0..n {
                for j in 0..n {
                    let pt = |a: u32, c: u32| {
                        let mut v = Vec3::ZERO;
                        v[axis] = side;
                        v[(axis + 1) % 3] = g(a);
                        v[(axis + 2) % 3] = g(c);
                        v
                    };
                    let q = [pt(i, j), pt(i + 1, j), pt(i + 1, j + 1), pt(i, j + 1)].map(|p| vid(p, &mut positions));
                    tris.push([q[0], q[1], q[2]]);
                    tris.push([q[0], q[2], q[3]]);
                }
            }
        }
    }
    let mut edges = std::collections::BTreeSet::new();
    for t in &tris {
        for k in 0..3 {
            let (a, c) = (t[k], t[(k + 1) % 3]);
            edges.insert([a.min(c), a.max(c)]);
        }
    }
    b.mesh.positions = positions.clone();
    let nv = positions.len();
    b.mesh.normals = positions.iter().map(|p| (*p - centre).normalize()).collect();
    b.mesh.tangents = vec![Vec4::ZERO; nv];
    b.mesh.uv0 = vec![Vec2::ZERO; nv];
    b.mesh.uv1 = vec![Vec2::ZERO; nv];
    b.mesh.colors = vec![Vec4::ONE; nv];
    b.mesh.material = vec![m; tris.len()];
    b.mesh.indices = tris;
    (b.build(DVec3::ZERO), edges.into_iter().collect())
}

#[test]
fn rays_at_shared_edges_and_vertices_never_escape_a_closed_mesh() {
    let centre = Vec3::new(10.0, -5.0, 3.0);
    let (scene, edges) = cube_sphere(12, centre, 1.0);
    let positions = scene.mesh.positions.clone();
    let r = Renderer::new(scene, &AccelParams::medium_build()).unwrap();
    let integ = r.integrator(&settings(1, 1, 0.0, true));
    let n_rays = 1_000_000u64;
    let start = std::time::Instant::now();
    let escaped: u64 = (0..n_rays)
        .into_par_iter()
        .filter(|&k| {
            let mut s = Sampler::new(11, 0, k, 0);
            let e = edges[(s.next_u32() as usize) % edges.len()];
            let (a, c) = (positions[e[0] as usize], positions[e[1] as usize]);
            // A quarter of the rays aim at vertices exactly, the rest at points on edges.
            let target = if k % 4 == 0 { a } else { a + s.next_1d() * (c - a) };
            let o = centre + 0.6 * crate::sampler::sample_uniform_sphere(s.next_2d()) * s.next_1d();
            let ray = Ray::new(o, (target - o).normalize());
            integ.intersect(&ray).is_none()
        })
        .count() as u64;
    let secs = start.elapsed().as_secs_f64();
    println!("watertight: {n_rays} rays in {secs:.2}s ({:.2} Mrays/s), {} edges", n_rays as f64 / secs / 1e6, edges.len());
    assert_eq!(escaped, 0, "{escaped} of {n_rays} rays escaped");
}

#[test]
fn edge_split_is_the_largest_power_of_two_within_the_budget() {
    assert_eq!(edge_split(0, 1000), None);
    assert_eq!(edge_split(1, 1000), Some(EDGE_MAX_SPLIT));
    assert_eq!(edge_split(10, 1000), Some(16), "25 rays allowed");
    assert_eq!(edge_split(50, 1000), Some(4), "5 rays allowed");
    assert_eq!(edge_split(100, 1000), Some(2), "2.5 rays allowed");
    assert_eq!(edge_split(200, 1000), None, "1.25 rays allowed: one per sample gains nothing");
    assert_eq!(edge_split(1000, 1000), None);
}

#[test]
fn camera_vertex_emission_splits_off_exactly() {
    // radiance = primary_emission + radiance without it, for paths that see emitters
    // directly, through bounces and by light sampling.
    let mut b = Builder::new();
    let m = b.material(0.7, 0.0, false);
    let e = b.material(0.5, 3.0, true);
    b.quad([Vec3::new(-3.0, 0.0, 3.0), Vec3::new(3.0, 0.0, 3.0), Vec3::new(3.0, 0.0, -3.0), Vec3::new(-3.0, 0.0, -3.0)], 2, m);
    b.aabox(Vec3::new(-0.5, 0.0, -0.5), Vec3::new(0.5, 1.0, 0.5), false, e);
    b.quad([Vec3::new(-0.3, 2.0, -0.3), Vec3::new(0.3, 2.0, -0.3), Vec3::new(0.3, 2.0, 0.3), Vec3::new(-0.3, 2.0, 0.3)], 1, e);
    let r = Renderer::new(b.build(DVec3::ZERO), &AccelParams::medium_build()).unwrap();
    let integ = r.integrator(&settings(1, 4, 0.2, false));
    let cam = camera(16, 16, 70.0, DVec3::new(2.5, 1.8, 2.0), DVec3::new(0.0, 0.7, 0.0));
    let (mut emitting, mut other) = (0, 0);
    for k in 0..256u32 {
        let ray = r.local_ray(&cam.pixel_ray((k % 16) as f64 + 0.3, (k / 16) as f64 + 0.6));
        let full = integ.radiance(&ray, &mut Sampler::new(7, 0, k as u64, 0)).radiance;
        let le = integ.primary_emission(&ray);
        let rest = integ.radiance_split(&ray, &mut Sampler::new(7, 0, k as u64, 0), false).radiance;
        assert!((le + rest - full).abs().max_element() <= 1e-5 * full.max_element().max(1.0), "{le} + {rest} vs {full}");
        if le.max_element() > 0.0 { emitting += 1 } else if rest.max_element() > 0.0 { other += 1 }
    }
    assert!(emitting > 10 && other > 10, "{emitting} rays see an emitter, {other} others");
}

#[test]
fn a_batch_of_paths_is_each_path_traced_alone_bit_for_bit() {
    // Lambertian, glTF (dielectric and metal, rough and smooth) and emitting surfaces, a
    // point light and an environment: every path of a batch (batches of 1 to 70, so lanes
    // are left over) equals the path traced alone, and so does the second half of the
    // split at the camera vertex; in the lane loop and in the one-path loop (whose camera
    // vertices' shadow rays a batch traces as packets, grouped by light).
    let mut b = Builder::new();
    b.glossy_room(2);
    // Light from behind the boxes, so that the camera sees their shadows.
    b.lights.push(Light::Directional { direction: Vec3::new(0.6, -0.7, 0.5).normalize(), illuminance: Vec3::splat(0.7) });
    let r = Renderer::new(b.build(DVec3::ZERO), &AccelParams::medium_build()).unwrap();
    let lanes = r.integrator(&settings(1, 6, 0.2, false));
    assert!(lanes.lane_materials.is_some(), "the lane loop applies");
    let mut one = r.integrator(&settings(1, 6, 0.2, false));
    one.lane_materials = None;
    let cam = camera(16, 16, 70.0, DVec3::new(2.5, 1.8, 2.0), DVec3::new(0.0, 0.7, 0.0));
    let bits = |v: Vec3| v.to_array().map(f32::to_bits);
    let mut k = 0u32;
    let mut lit = 0;
    for (n, integ) in [1usize, 7, 8, 9, 64, 70].into_iter().flat_map(|n| [(n, &lanes), (n, &one)]) {
        for primary_emission in [true, false] {
            let rays: Vec<Ray> = (k..k + n as u32).map(|q| r.local_ray(&cam.pixel_ray((q % 16) as f64 + 0.3, ((q / 16) % 16) as f64 + 0.6))).collect();
            let mut samplers: Vec<Sampler> = (k..k + n as u32).map(|q| Sampler::new(7, 0, q as u64, 0)).collect();
            let mut out = vec![crate::integrator::RadianceSample { radiance: Vec3::NAN, primary_hit: false }; n];
            integ.radiance_batch(&rays, &mut samplers, primary_emission, &mut out);
            for (q, (ray, got)) in rays.iter().zip(&out).enumerate() {
                let alone = integ.radiance_split(ray, &mut Sampler::new(7, 0, (k + q as u32) as u64, 0), primary_emission);
                assert_eq!((bits(got.radiance), got.primary_hit), (bits(alone.radiance), alone.primary_hit), "batch of {n}, path {q}");
                lit += (alone.radiance.max_element() > 0.0) as u32;
            }
            k += n as u32;
        }
    }
    assert!(lit > 200, "{lit} lit paths");
}

#[test]
fn vertices_shaded_in_lanes_are_the_one_path_loop_bit_for_bit() {
    // Every case the lane loop handles: Lambertian, glossy and metal (a sharp caster)
    // surfaces; a double-sided emitter, a masked and a blended one; a point, a spot and a
    // directional light; an environment map (sampled at every vertex) over a constant;
    // interpolated normals bent off the faces, or none; the caustic vertices left to the
    // light tracer or not; the last bounce, and no bounce at all. Every path (batches of
    // 1 to 70) equals, bit for bit, the one-path loop's.
    use crate::scene::AlphaMode;
    let bits = |v: Vec3| v.to_array().map(f32::to_bits);
    let mut lit = 0;
    for normals in [true, false] {
        let mut b = Builder::new();
        b.glossy_room(3);
        let masked = b.material(0.2, 2.0, false);
        b.materials[masked as usize].alpha_mode = AlphaMode::Mask { cutoff: 0.5 };
        b.materials[masked as usize].base_color_factor.w = 0.8;
        let blended = b.material(0.2, 1.5, false);
        b.materials[blended as usize].alpha_mode = AlphaMode::Blend;
        b.materials[blended as usize].base_color_factor.w = 0.6;
        b.quad([Vec3::new(-2.0, 0.5, -1.0), Vec3::new(-2.0, 0.5, 1.0), Vec3::new(-2.0, 1.5, 1.0), Vec3::new(-2.0, 1.5, -1.0)], 2, masked);
        b.quad([Vec3::new(1.5, 1.2, -1.5), Vec3::new(2.5, 1.2, -1.5), Vec3::new(2.5, 1.2, -0.5), Vec3::new(1.5, 1.2, -0.5)], 1, blended);
        b.lights.push(Light::Spot { position: Vec3::new(-1.0, 2.5, 1.5), direction: Vec3::new(0.3, -1.0, -0.4).normalize(), intensity: Vec3::new(8.0, 6.0, 4.0), inner_cone_angle: 0.2, outer_cone_angle: 0.6, range: Some(10.0) });
        b.lights.push(Light::Directional { direction: Vec3::new(-0.4, -1.0, -0.2).normalize(), illuminance: Vec3::splat(0.7) });
        if normals {
            for (k, n) in b.mesh.normals.iter_mut().enumerate() {
                let k = k as f32;
                *n = (*n + 0.35 * Vec3::new((k * 0.7).sin(), (k * 1.3).cos(), (k * 2.1).sin())).normalize();
            }
        } else {
            b.mesh.normals.clear();
        }
        let mut r = Renderer::new(b.build(DVec3::ZERO), &AccelParams::medium_build()).unwrap();
        let texels = (0..32).map(|k| Vec3::new(0.2 + 0.1 * (k % 5) as f32, 0.3, 0.1 + 0.05 * (k % 7) as f32)).collect();
        r.set_environment_map(Some(Arc::new(EnvironmentMap::from_texels(8, 4, texels).unwrap())));
        let cam = camera(16, 16, 80.0, DVec3::new(2.5, 1.8, 2.0), DVec3::new(0.0, 0.7, 0.0));
        let mut k = 0u32;
        for (max_bounces, transparent, caustics) in [(6, false, true), (6, true, false), (1, false, true), (0, true, false)] {
            let s = settings(1, max_bounces, 0.2, transparent);
            let mut lanes = r.integrator(&s);
            assert!(lanes.lane_materials.is_some(), "the lane loop applies");
            let mut one = r.integrator(&s);
            one.lane_materials = None;
            if caustics {
                lanes.caustics = Some(r.caustics().vertices());
                one.caustics = Some(r.caustics().vertices());
            }
            for n in [1usize, 7, 8, 9, 70] {
                for primary_emission in [true, false] {
                    let rays: Vec<Ray> = (k..k + n as u32).map(|q| r.local_ray(&cam.pixel_ray((q % 16) as f64 + 0.3, ((q / 16) % 16) as f64 + 0.6))).collect();
                    let run = |integ: &PathIntegrator<'_>| {
                        let mut samplers: Vec<Sampler> = (k..k + n as u32).map(|q| Sampler::new(7, 0, q as u64, 0)).collect();
                        let mut out = vec![crate::integrator::RadianceSample { radiance: Vec3::NAN, primary_hit: false }; n];
                        integ.radiance_batch(&rays, &mut samplers, primary_emission, &mut out);
                        (out, samplers.iter().map(Sampler::dimension).collect::<Vec<_>>())
                    };
                    let ((got, got_dims), (want, want_dims)) = (run(&lanes), run(&one));
                    assert_eq!(got_dims, want_dims, "the same numbers drawn");
                    for (q, (g, w)) in got.iter().zip(&want).enumerate() {
                        assert_eq!((bits(g.radiance), g.primary_hit), (bits(w.radiance), w.primary_hit), "normals {normals}, {max_bounces} bounces, batch of {n}, path {q}");
                        lit += (w.radiance.max_element() > 0.0) as u32;
                    }
                    k += n as u32;
                }
            }
        }
    }
    assert!(lit > 500, "{lit} lit paths");
    // A normal map leaves the scene to the one-path loop.
    let mut b = Builder::new();
    let m = b.material(0.5, 0.0, false);
    b.materials[m as usize].normal_texture = Some((crate::scene::TextureRef { texture: 0, tex_coord: 0, wrap_s: crate::scene::Wrap::Repeat, wrap_t: crate::scene::Wrap::Repeat, filter: crate::scene::Filter::Linear, transform: None }, 1.0));
    b.quad([Vec3::new(-1.0, 0.0, 1.0), Vec3::new(1.0, 0.0, 1.0), Vec3::new(1.0, 0.0, -1.0), Vec3::new(-1.0, 0.0, -1.0)], 1, m);
    let scene = b.build(DVec3::ZERO);
    let uniform: Vec<_> = scene.materials.iter().map(|m| crate::material::uniform_surface(m, false)).collect();
    assert!(crate::integrator::LaneMaterials::new(&scene, &uniform).is_none());
}

#[test]
fn emitter_edge_pixels_converge_to_their_exact_coverage() {
    // An emitting rectangle facing the camera on black: at 0 bounces a pixel's value is
    // Le × the share of its area that the rectangle covers (exact: the pixel's footprint on
    // the rectangle's plane, parallel to the image, is a rectangle). Edge pixels get the
    // split estimate; it must be unbiased and far less noisy than one ray per sample.
    let le = 2.0f32;
    let (x0, x1, y0, y1) = (-0.37f32, 0.41f32, -0.29f32, 0.33f32);
    let mut b = Builder::new();
    let e = b.material(0.0, le, false);
    b.quad([Vec3::new(x0, y0, 0.0), Vec3::new(x1, y0, 0.0), Vec3::new(x1, y1, 0.0), Vec3::new(x0, y1, 0.0)], 1, e);
    let r = Renderer::new(b.build(DVec3::ZERO), &AccelParams::fast_build()).unwrap();
    let (w, h) = (64u32, 48u32);
    let cam = camera(w, h, 50.0, DVec3::new(0.0, 0.0, 2.0), DVec3::ZERO);
    let s = settings(8, 0, 0.0, true);
    let edges = r.emitter_edges(&cam, &r.integrator(&s), s.spp).expect("edge pixels");
    assert!(edges.split >= 4, "split {}", edges.split);
    // Where a ray through the image point (u, v) meets z = 0.
    let on_plane = |u: f64, v: f64| {
        let ray = cam.pixel_ray(u, v);
        let t = -ray.origin.z / ray.direction.z;
        ray.origin + t * ray.direction
    };
    let overlap = |a: f64, b: f64, lo: f32, hi: f32| (a.max(b).min(hi as f64) - a.min(b).max(lo as f64)).max(0.0) / (a - b).abs();
    let exact: Vec<f64> = (0..(w * h) as usize)
        .map(|k| {
            let (i, j) = ((k as u32 % w) as f64, (k as u32 / w) as f64);
            let (p, q) = (on_plane(i, j), on_plane(i + 1.0, j + 1.0));
            le as f64 * overlap(p.x, q.x, x0, x1) * overlap(p.y, q.y, y0, y1)
        })
        .collect();
    let partial = |k: usize| exact[k] > 1e-3 && exact[k] < le as f64 - 1e-3;
    let n_partial = (0..exact.len()).filter(|&k| partial(k)).count();
    assert!(n_partial > 60, "{n_partial} partly covered pixels");
    assert!((0..exact.len()).all(|k| !partial(k) || edges.flagged[k]), "every partly covered pixel is an edge pixel");
    let integ = r.integrator(&s);
    let views = 24u32;
    let (mut err_split, mut err_plain, mut bias) = (0.0f64, 0.0f64, vec![0.0f64; exact.len()]);
    for v in 0..views {
        let out = r.render_view(&cam, v, &s);
        for k in 0..exact.len() {
            let got = out.color.data[4 * k] as f64;
            if !partial(k) {
                assert_eq!(got, exact[k].round(), "pixel {k}: fully in or out");
                continue;
            }
            bias[k] += (got - exact[k]) / views as f64;
            err_split += (got - exact[k]).powi(2);
            // One camera ray per sample, as without the split.
            let (i, j) = ((k as u32 % w) as f64, (k as u32 / w) as f64);
            let plain = (0..s.spp)
                .map(|n| {
                    let mut sampler = Sampler::new(s.seed, v, k as u64, n);
                    let u = sampler.next_2d();
                    integ.radiance(&r.local_ray(&cam.pixel_ray(i + u.x as f64, j + u.y as f64)), &mut sampler).radiance.x as f64
                })
                .sum::<f64>()
                / s.spp as f64;
            err_plain += (plain - exact[k]).powi(2);
        }
    }
    let (mse_split, mse_plain) = (err_split / (views as usize * n_partial) as f64, err_plain / (views as usize * n_partial) as f64);
    assert!(mse_split * 4.0 < mse_plain, "split {mse_split:.3e} vs plain {mse_plain:.3e}");
    // Unbiased: the mean over views of the partly covered pixels' errors is within 4σ of 0
    // (σ from the split's own error, over views and pixels).
    let mean_bias = bias.iter().sum::<f64>() / n_partial as f64;
    let sigma = (mse_split / (views as usize * n_partial) as f64).sqrt();
    assert!(mean_bias.abs() < 4.0 * sigma, "bias {mean_bias:.3e} vs σ {sigma:.3e}");
}

#[test]
fn a_view_counts_the_rays_it_traces() {
    // A single-sided Lambertian floor filling the view, lit by one point light above it
    // and by nothing else (no emissive triangle, a black environment, no caster).
    let mut b = Builder::new();
    let m = b.material(0.5, 0.0, false);
    b.quad([Vec3::new(-50.0, 0.0, 50.0), Vec3::new(50.0, 0.0, 50.0), Vec3::new(50.0, 0.0, -50.0), Vec3::new(-50.0, 0.0, -50.0)], 1, m);
    b.lights.push(Light::Point { position: Vec3::new(0.0, 3.0, 0.0), intensity: Vec3::splat(10.0), range: None });
    let r = Renderer::new(b.build(DVec3::ZERO), &AccelParams::medium_build()).unwrap();
    let cam = camera(12, 8, 40.0, DVec3::new(0.0, 2.0, 0.5), DVec3::ZERO);
    let pixels = 12 * 8;
    // Emission only: one camera ray per sample and one ground-truth ray per pixel.
    let v = r.render_view(&cam, 0, &settings(8, 0, 0.0, false));
    assert_eq!(v.samples, 8 * pixels);
    assert_eq!(v.rays, RayCounts { closest: v.samples + pixels, any_hit: 0 });
    // Direct light: every camera ray hits the floor, whose vertex traces one shadow ray to
    // the light and at most one continuation ray (which escapes).
    let v = r.render_view(&cam, 0, &settings(8, 1, 0.0, false));
    assert_eq!(v.rays.any_hit, v.samples);
    assert!((v.samples + pixels..=2 * v.samples + pixels).contains(&v.rays.closest), "{:?}", v.rays);
    assert!(v.ground_truth.alpha.iter().all(|&a| a == 1.0));
}

#[test]
fn renders_are_bit_identical_across_thread_counts_and_simd_widths() {
    let mut b = Builder::new();
    let m = b.material(0.7, 0.0, false);
    let e = b.material(0.0, 4.0, true);
    // A polished metal box: a caster, so the caustic light tracer runs too.
    b.materials.push(Material { metallic_factor: 1.0, roughness_factor: 0.2, ..Material::gltf_default() });
    let metal = b.materials.len() as u32 - 1;
    b.quad([Vec3::new(-3.0, 0.0, 3.0), Vec3::new(3.0, 0.0, 3.0), Vec3::new(3.0, 0.0, -3.0), Vec3::new(-3.0, 0.0, -3.0)], 2, m);
    b.aabox(Vec3::new(-0.5, 0.0, -0.5), Vec3::new(0.5, 1.0, 0.5), false, metal);
    b.quad([Vec3::new(-0.3, 2.0, -0.3), Vec3::new(0.3, 2.0, -0.3), Vec3::new(0.3, 2.0, 0.3), Vec3::new(-0.3, 2.0, 0.3)], 1, e);
    b.lights.push(Light::Spot { position: Vec3::new(2.0, 3.0, 1.0), direction: Vec3::new(-2.0, -3.0, -1.0).normalize(), intensity: Vec3::splat(30.0), inner_cone_angle: 0.3, outer_cone_angle: 0.6, range: None });
    b.lights.push(Light::Directional { direction: Vec3::new(0.3, -1.0, 0.2).normalize(), illuminance: Vec3::new(1.0, 0.9, 0.8) });
    let r = Renderer::new(b.build(DVec3::new(5.0, 0.0, -5.0)), &AccelParams::medium_build()).unwrap();
    assert_eq!(r.caustics().caster_triangles(), r.scene().mesh.material.iter().filter(|&&k| k == metal).count());
    let cam = camera(24, 16, 55.0, DVec3::new(8.0, 2.5, -1.5), DVec3::new(5.0, 0.5, -5.0));
    let s = settings(64, 4, 0.5, true);
    // The light tracer and its pilot run in this view, at each thread count.
    let light_paths = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| r.caustics().paths_for_view(&r.integrator(&s), &SampleRays::new(&cam, r.scene().origin), (24, 16), s.seed, 3, s.spp))
    };
    let one_thread = light_paths(1);
    assert!(one_thread > 0 && one_thread == light_paths(2), "the view is light-traced");
    let render_with = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| r.render_view(&cam, 3, &s))
    };
    let (a, b2) = (render_with(1), render_with(2));
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a.color.data), bits(&b2.color.data));
    assert_eq!(a.ground_truth, b2.ground_truth);
    // So are the rays counted (the path samples', the light tracer's and its pilot's).
    assert_eq!(a.rays, b2.rays);
    assert!(a.rays.closest > a.samples && a.rays.any_hit > 0);
    assert!(a.color.data.iter().all(|x| x.is_finite()) && a.color.data.iter().any(|&x| x > 0.0));
    // A different view index or seed changes the noise.
    let c = r.render_view(&cam, 4, &s);
    assert_ne!(bits(&a.color.data), bits(&c.color.data));
    // The four-wide child-box test and the baseline x86-64 path loop (a CPU without AVX2)
    // render the same bits.
    let mut r = r;
    r.accel.set_avx2(false);
    let d = r.render_view(&cam, 3, &s);
    assert_eq!(bits(&a.color.data), bits(&d.color.data));
    assert_eq!(a.ground_truth, d.ground_truth);
}

#[test]
fn shadow_rays_go_to_every_punctual_light_and_one_emitter_point() {
    let mut b = Builder::new();
    let m = b.material(0.7, 0.0, false);
    let e = b.material(0.0, 4.0, true);
    b.quad([Vec3::new(-3.0, 0.0, 3.0), Vec3::new(3.0, 0.0, 3.0), Vec3::new(3.0, 0.0, -3.0), Vec3::new(-3.0, 0.0, -3.0)], 2, m);
    b.aabox(Vec3::new(-0.5, 0.0, -0.5), Vec3::new(0.5, 1.0, 0.5), false, m);
    b.quad([Vec3::new(-0.3, 2.0, -0.3), Vec3::new(0.3, 2.0, -0.3), Vec3::new(0.3, 2.0, 0.3), Vec3::new(-0.3, 2.0, 0.3)], 1, e);
    b.lights.push(Light::Point { position: Vec3::new(2.0, 3.0, 1.0), intensity: Vec3::splat(10.0), range: None });
    b.lights.push(Light::Directional { direction: Vec3::new(0.3, -1.0, 0.2).normalize(), illuminance: Vec3::ONE });
    let r = Renderer::new(b.build(DVec3::ZERO), &AccelParams::medium_build()).unwrap();
    let cam = camera(16, 12, 55.0, DVec3::new(3.0, 2.5, 3.5), DVec3::new(0.0, 0.5, 0.0));
    let hits = (0..12).flat_map(|j| (0..16).map(move |i| (i, j))).filter(|&(i, j)| r.trace_primary(&cam.pixel_center_ray(i, j)).is_some()).count();
    let rays = r.shadow_rays(&cam);
    // Two punctual lights and one emitter point per pixel-centre hit.
    assert!(hits > 100, "{hits} of 192 pixels hit");
    assert_eq!(rays.len(), 3 * hits);
    assert!(rays.iter().all(|(ray, t)| (ray.direction.length() - 1.0).abs() < 1e-5 && *t > 0.0));
    let stats = r.shadow_ray_throughput(&cam);
    let occluded = rays.iter().filter(|(ray, t)| r.integrator(&RenderSettings::preview(0)).occluded(ray, *t)).count() as u64;
    assert_eq!((stats.rays, stats.hits), (rays.len() as u64, occluded));
    // The box shadows some of the floor from some light.
    assert!(occluded > 0 && occluded < stats.rays);
    // Primary rays one at a time and as packets hit the same pixels.
    let (one, packets) = (r.primary_ray_throughput(&cam), r.primary_packet_throughput(&cam));
    assert_eq!((one.rays, one.hits), (192, hits as u64));
    assert_eq!((packets.rays, packets.hits), (192, hits as u64));
}

#[test]
fn back_faces_of_single_sided_triangles_and_masked_texels_are_transparent() {
    use crate::scene::{AlphaMode, Filter, Texture, TextureRef, Wrap};
    let mut b = Builder::new();
    let floor = b.material(0.5, 0.0, false);
    let one_sided = b.material(0.5, 0.0, false);
    let two_sided = b.material(0.5, 0.0, true);
    let masked = b.material(0.5, 0.0, true);
    b.materials[masked as usize].alpha_mode = AlphaMode::Mask { cutoff: 0.5 };
    // Left half of the texture has alpha 0.2 (cut out), right half alpha 0.9 (kept).
    b.materials[masked as usize].base_color_texture = Some(TextureRef { texture: 0, tex_coord: 0, wrap_s: Wrap::ClampToEdge, wrap_t: Wrap::ClampToEdge, filter: Filter::Nearest, transform: None });
    b.quad([Vec3::new(-5.0, 0.0, 5.0), Vec3::new(5.0, 0.0, 5.0), Vec3::new(5.0, 0.0, -5.0), Vec3::new(-5.0, 0.0, -5.0)], 1, floor);
    // Three horizontal quads at y = 1 whose fronts face down (seen from above: back faces).
    let down = |x0: f32| [Vec3::new(x0, 1.0, -0.5), Vec3::new(x0 + 1.0, 1.0, -0.5), Vec3::new(x0 + 1.0, 1.0, 0.5), Vec3::new(x0, 1.0, 0.5)];
    b.quad(down(-3.0), 1, one_sided);
    b.quad(down(-1.0), 1, two_sided);
    b.quad(down(1.0), 1, masked);
    let mut scene = b.build(DVec3::ZERO);
    scene.textures.push(Texture { width: 2, height: 1, texels: vec![Vec4::new(1.0, 1.0, 1.0, 0.2), Vec4::new(1.0, 1.0, 1.0, 0.9)] });
    // UV u runs with x across the masked quad (its last 6 triangles' vertices).
    let nv = scene.mesh.positions.len();
    for k in nv - 6..nv {
        let x = scene.mesh.positions[k].x;
        scene.mesh.uv0[k] = Vec2::new(x - 1.0, 0.5);
    }
    let r = Renderer::new(scene, &AccelParams::fast_build()).unwrap();
    let depth_at = |x: f64| r.trace_primary(&dataset::Ray { origin: DVec3::new(x, 3.0, 0.1), direction: -DVec3::Y }).map(|h| h.distance);
    assert_eq!(depth_at(-2.5), Some(3.0), "single-sided back face must be invisible");
    assert_eq!(depth_at(-0.5), Some(2.0), "double-sided back face is hit");
    assert_eq!(depth_at(1.25), Some(3.0), "masked texel (alpha 0.2 < 0.5) is cut out");
    assert_eq!(depth_at(1.75), Some(2.0), "kept texel (alpha 0.9 >= 0.5) is hit");
    // From below the single-sided quad is a front face and is hit; its normal faces the ray.
    let up = r.trace_primary(&dataset::Ray { origin: DVec3::new(-2.5, 0.5, 0.1), direction: DVec3::Y }).unwrap();
    assert!((up.distance - 0.5).abs() < 1e-12 && (up.normal - Vec3::new(0.0, -1.0, 0.0)).length() < 1e-6);
    // Double-sided from above: the normal is flipped to face the camera.
    let two = r.trace_primary(&dataset::Ray { origin: DVec3::new(-0.5, 3.0, 0.1), direction: -DVec3::Y }).unwrap();
    assert!((two.normal - Vec3::Y).length() < 1e-6);
    // Shadow rays follow the same rules: going down through the quads (their back faces).
    let integ = r.integrator(&settings(1, 1, 0.0, true));
    let shadow = |x: f32| integ.occluded(&Ray::new(Vec3::new(x, 2.0, 0.1), -Vec3::Y), 1.9);
    assert!(!shadow(-2.5) && shadow(-0.5) && !shadow(1.25) && shadow(1.75));
}

#[test]
fn invalid_scenes_and_settings_are_errors() {
    let mut b = Builder::new();
    let m = b.material(0.5, 0.0, false);
    b.tri([Vec3::ZERO, Vec3::X, Vec3::Y], m);
    let mut scene = b.build(DVec3::ZERO);
    scene.mesh.material[0] = 7;
    assert!(matches!(Renderer::new(scene.clone(), &AccelParams::fast_build()), Err(PathTracerError::Config(_))));
    scene.mesh.material[0] = 0;
    scene.mesh.indices[0] = [0, 1, 9];
    assert!(Renderer::new(scene.clone(), &AccelParams::fast_build()).is_err());
    scene.mesh.indices[0] = [0, 1, 2];
    let mut p = AccelParams::fast_build();
    p.max_prims_per_leaf = 0;
    assert!(Renderer::new(scene.clone(), &p).is_err());
    assert!(settings(0, 1, 0.0, true).validate().is_err());
    assert!(settings(1, 1, f32::NAN, true).validate().is_err());
    assert!(RenderSettings::dataset(0).validate().is_ok());
    // An empty scene renders: all misses.
    let empty = Builder::new().build(DVec3::ZERO);
    let r = Renderer::new(empty, &AccelParams::fast_build()).unwrap();
    let out = r.render_view(&camera(4, 4, 40.0, DVec3::Z, DVec3::ZERO), 0, &settings(2, 2, 1.0, true));
    assert!(out.color.data.iter().all(|&x| x == 0.0) && out.distance_range.is_none());
    assert!(!r.is_view_dependent());
}

/// A unit square light in the z = 0 plane, `cells × cells` quads of two triangles each, and
/// its emitter table.
fn unit_square_light(cells: u32) -> (Scene, EmissiveTriangles) {
    let mut b = Builder::new();
    let lamp = b.material(0.0, 1.0, false);
    b.quad([Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0), Vec3::new(1.0, 1.0, 0.0), Vec3::new(0.0, 1.0, 0.0)], cells, lamp);
    let scene = b.build(DVec3::ZERO);
    let emitters = EmissiveTriangles::build(&scene);
    (scene, emitters)
}

/// The point an emitter sample stands for (the barycentric interpolation light sampling uses).
fn emitter_point(scene: &Scene, es: &crate::light::EmitterSample) -> Vec3 {
    let p = scene.mesh.indices[es.prim as usize].map(|k| scene.mesh.positions[k as usize]);
    crate::geometry::hit_point_error(p, es.b).0
}

/// Light sampling keeps a stratified 2D set stratified over the whole light, across the
/// triangles it is made of: integrating a smooth function over a square light of 2 and of
/// 32 equal triangles with 256 points of a pixel's set errs far less than independent
/// points would (their error is about sd/√n); a separate number for the triangle choice,
/// as before, made the points on each triangle an arbitrary subset of the set, with errors
/// of that size.
#[test]
fn emitter_points_stay_stratified_across_the_triangles_of_a_light() {
    let f = |p: Vec2| (3.0 * p.x as f64).sin() + (p.y as f64 * 2.0).powi(2) + (p.x * p.y) as f64;
    // The exact mean of `f` over the square and its standard deviation, from a fine grid.
    let g = 512;
    let vals: Vec<f64> = (0..g * g).map(|k| f(Vec2::new(((k % g) as f32 + 0.5) / g as f32, ((k / g) as f32 + 0.5) / g as f32))).collect();
    let mean = vals.iter().sum::<f64>() / vals.len() as f64;
    let sd = (vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / vals.len() as f64).sqrt();
    let n = 256;
    for cells in [1, 4] {
        let (scene, emitters) = unit_square_light(cells);
        let mut worst = 0.0f64;
        for pixel in 0..16 {
            let base = Sampler::new(7, 0, pixel, 0);
            let estimate = (0..n)
                .map(|s| {
                    let sampler = base.with_sample(s);
                    let es = emitters.sample(sampler.get_2d(1), || sampler.get_1d(0)).unwrap();
                    f(emitter_point(&scene, &es).truncate())
                })
                .sum::<f64>()
                / n as f64;
            worst = worst.max((estimate - mean).abs() / (sd / (n as f64).sqrt()));
        }
        // Independent points: |err| / (sd/√n) is |N(0, 1)|, above 0.5 for 62 % of pixels.
        assert!(worst < 0.25, "{cells}x{cells} quads: worst error {worst:.3} x sd/sqrt(n)");
    }
}

/// Where a triangle's share of the light is under `MIN_REUSED_INTERVAL` the spare number
/// places the point (the rescaled choice number would keep too few bits), and the point
/// is still uniform on the light: the mean of x and y over 4096 points is ½ within their
/// Monte Carlo error.
#[test]
fn emitter_points_on_tiny_triangles_use_the_spare_number() {
    let (scene, emitters) = unit_square_light(64);
    assert_eq!(emitters.len(), 8192);
    let (mut used, mut mean) = (0u32, DVec3::ZERO);
    let n = 4096;
    for s in 0..n {
        let sampler = Sampler::new(3, 0, 0, s);
        let es = emitters.sample(sampler.get_2d(1), || {
            used += 1;
            sampler.get_1d(0)
        });
        mean += emitter_point(&scene, &es.unwrap()).as_dvec3() / n as f64;
    }
    assert_eq!(used, n, "every point on a 1/8192 share should take the spare number");
    // Uniform on [0, 1]: sd 1/√12 per coordinate; 4 standard errors.
    let tol = 4.0 / 12f64.sqrt() / (n as f64).sqrt();
    assert!((mean.x - 0.5).abs() < tol && (mean.y - 0.5).abs() < tol, "mean point {mean:?}");
}

/// The `f32` camera rays of path samples are `Camera::pixel_ray` to `f32` rounding: the
/// same origin bits as `Renderer::local_ray`, directions within 4e-7 radians, for a
/// camera far from the world origin (a scene centred at 10 km), an off-centre principal
/// point and unequal focal lengths, at pixel corners, centres and random points.
#[test]
fn sample_rays_are_the_cameras_pixel_rays_in_f32() {
    let mut b = Builder::new();
    let m = b.material(0.5, 0.0, false);
    b.tri([Vec3::ZERO, Vec3::X, Vec3::Y], m);
    let scene_origin = DVec3::new(1.0e4, -3.0e3, 2.5e3);
    let r = Renderer::new(b.build(scene_origin), &AccelParams::fast_build()).unwrap();
    let mut cam = camera(37, 23, 55.0, scene_origin + DVec3::new(3.0, 2.0, 4.5), scene_origin + DVec3::new(0.1, 0.2, -0.3));
    cam.intrinsics.cx = 16.25;
    cam.intrinsics.cy = 12.5;
    cam.intrinsics.fl_y *= 1.1;
    let rays = SampleRays::new(&cam, r.scene().origin);
    let mut rng = Sampler::new(4, 0, 0, 0);
    for k in 0..2000 {
        let (px, py) = match k % 3 {
            0 => ((k % 38) as f32, (k / 38 % 24) as f32),
            1 => ((k % 37) as f32 + 0.5, (k / 37 % 23) as f32 + 0.5),
            _ => (rng.next_1d() * 37.0, rng.next_1d() * 23.0),
        };
        let got = rays.ray(px, py);
        let want = r.local_ray(&cam.pixel_ray(px as f64, py as f64));
        assert_eq!(got.origin, want.origin, "point ({px}, {py})");
        let angle = got.direction.as_dvec3().angle_between(want.direction.as_dvec3());
        assert!(angle < 4e-7 && (got.direction.length() - 1.0).abs() < 1e-6, "point ({px}, {py}): {angle:e} rad");
    }
}

/// A diffuse floor lit by a punctual light directly and through a mirror (GGX at the
/// smallest α, white metal: reflectance 1): with two bounces the floor's irradiance is the
/// light's plus its mirror image's where the reflection point lies on the mirror, in
/// closed form for a point, a spot (inside its inner cone) and a directional light. The
/// mirrored term is a caustic path, estimated by the light tracer; the path tracer alone
/// finds the mirror's lobe too rarely to compare.
#[test]
fn light_traced_mirror_caustic_matches_the_mirror_image_of_the_light() {
    let (x_m, top, pos) = (1.0f32, 0.4f32, Vec3::new(0.3, 0.8, 0.0));
    let to_sun = Vec3::new(-1.0, 1.2, 0.1).normalize();
    let lights = [
        Light::Point { position: pos, intensity: Vec3::splat(1.0), range: None },
        Light::Spot { position: pos, direction: -Vec3::Y, intensity: Vec3::splat(1.0), inner_cone_angle: 1.4, outer_cone_angle: 1.5, range: None },
        Light::Directional { direction: -to_sun, illuminance: Vec3::splat(1.0) },
    ];
    for light in lights {
        let mut b = Builder::new();
        let floor = b.material(0.5, 0.0, false);
        let mut mirror = Material::gltf_default();
        mirror.metallic_factor = 1.0;
        mirror.roughness_factor = 0.0;
        b.materials.push(mirror);
        let mirror = b.materials.len() as u32 - 1;
        b.quad([Vec3::new(-2.0, 0.0, 1.5), Vec3::new(x_m, 0.0, 1.5), Vec3::new(x_m, 0.0, -1.5), Vec3::new(-2.0, 0.0, -1.5)], 4, floor);
        b.quad([Vec3::new(x_m, 0.0, -1.0), Vec3::new(x_m, 0.0, 1.0), Vec3::new(x_m, top, 1.0), Vec3::new(x_m, top, -1.0)], 2, mirror);
        b.lights.push(light);
        let mut r = Renderer::new(b.build(DVec3::ZERO), &AccelParams::medium_build()).unwrap();
        let mirror_triangles = r.scene().mesh.material.iter().filter(|&&k| k == mirror).count();
        assert!(mirror_triangles > 0 && r.caustics().caster_triangles() == mirror_triangles, "the mirror is the one caster");
        let cam = camera(32, 32, 50.0, DVec3::new(0.1, 2.2, 0.01), DVec3::new(0.1, 0.0, 0.0));
        let s = settings(256, 2, 0.0, false);
        // Irradiance at floor point q from a light at `at` (a position, or a unit
        // direction towards a directional light): E = cos / r² or cos.
        let irradiance = |q: Vec3, at: Vec3| -> (f64, Vec3) {
            match light {
                Light::Directional { .. } => (at.y as f64, at),
                _ => {
                    let d = at - q;
                    ((d.y / d.length()) as f64 / d.length_squared() as f64, d)
                }
            }
        };
        let (real, image) = match light {
            Light::Directional { .. } => (to_sun, to_sun * Vec3::new(-1.0, 1.0, 1.0)),
            _ => (pos, pos.with_x(2.0 * x_m - pos.x)),
        };
        // The closed-form radiance at a floor point, whether the mirror term is on there,
        // and that term.
        let closed = |q: Vec3| -> (f64, bool, f64) {
            let direct = irradiance(q, real).0;
            let (e, m) = irradiance(q, image);
            let p = q + m * ((x_m - q.x) / m.x);
            let on = m.x > 0.0 && p.y > 0.0 && p.y < top && p.z.abs() < 1.0;
            let mirrored = if on { e } else { 0.0 };
            (0.5 / PI64 * (direct + mirrored), on, 0.5 / PI64 * mirrored)
        };
        let floor_point = |px: f64, py: f64| {
            let ray = cam.pixel_ray(px, py);
            let t = -ray.origin.y / ray.direction.y;
            (ray.origin + ray.direction * t).as_vec3()
        };
        // Floor pixels wholly inside the mirrored patch or wholly outside it (corners and
        // centre agree), away from the mirror's foot.
        let side = |i: u32, j: u32| {
            let on = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (0.5, 0.5)].map(|(a, b)| closed(floor_point(i as f64 + a, j as f64 + b)).1);
            let q = floor_point(i as f64 + 0.5, j as f64 + 0.5);
            (on.iter().all(|&c| c == on[0]) && q.x < x_m - 0.05).then_some(on[0])
        };
        let mut sums = [[0.0f64; 3]; 2]; // [inside, outside][rendered, closed form, its mirrored term]
        let mut counts = [0usize; 2];
        let renders: Vec<ViewOutput> = (0..2).map(|k| r.render_view(&cam, k, &s)).collect();
        r.set_caustic_light_tracing(false);
        let off = r.render_view(&cam, 0, &s);
        let mut off_mirrored = 0.0;
        for j in 0..32u32 {
            for i in 0..32u32 {
                let Some(inside) = side(i, j) else { continue };
                let slot = if inside { 0 } else { 1 };
                let (c, _, m) = closed(floor_point(i as f64 + 0.5, j as f64 + 0.5));
                let k = 4 * (j * 32 + i) as usize;
                counts[slot] += 1;
                sums[slot][1] += c;
                sums[slot][2] += m;
                for out in &renders {
                    sums[slot][0] += out.color.data[k] as f64 / renders.len() as f64;
                }
                if inside {
                    off_mirrored += off.color.data[k] as f64 - (c - m);
                }
            }
        }
        assert!(counts[0] > 50 && counts[1] > 100, "{light:?}: pixels inside / outside the mirrored patch: {counts:?}");
        let outside = sums[1][0] / sums[1][1];
        // The mirrored light alone: what the rendered patch holds beyond the direct term.
        let mirrored = (sums[0][0] - (sums[0][1] - sums[0][2])) / sums[0][2];
        eprintln!("{light:?}: mirrored light {mirrored:.4}, direct only {outside:.4}; path tracer alone: mirrored {:.4} ({counts:?} pixels)", off_mirrored / sums[0][2]);
        assert!((outside - 1.0).abs() < 0.01, "{light:?}: direct light only: rendered / closed form = {outside}");
        assert!((mirrored - 1.0).abs() < 0.02, "{light:?}: mirrored light: rendered / closed form = {mirrored}");
    }
}

/// A scene of caster triangles for the sampling tests: a single-sided metal box (faces
/// outward) and a double-sided tilted metal quad, under a point, a spot and a directional
/// light.
fn caster_builder() -> Builder {
    let mut b = Builder::new();
    b.materials.push(Material { metallic_factor: 1.0, roughness_factor: 0.1, ..Material::gltf_default() });
    b.materials.push(Material { metallic_factor: 1.0, roughness_factor: 0.1, double_sided: true, ..Material::gltf_default() });
    b.aabox(Vec3::new(-0.5, 0.0, -0.5), Vec3::new(0.5, 1.0, 0.5), false, 0);
    b.quad([Vec3::new(1.0, 0.0, -1.0), Vec3::new(2.0, 0.5, -1.0), Vec3::new(2.0, 0.5, 0.0), Vec3::new(1.0, 0.0, 0.0)], 3, 1);
    b.lights.push(Light::Point { position: Vec3::new(2.0, 3.0, 1.0), intensity: Vec3::splat(5.0), range: None });
    b.lights.push(Light::Spot { position: Vec3::new(-2.0, 2.0, 0.0), direction: Vec3::new(1.0, -0.8, 0.0).normalize(), intensity: Vec3::splat(5.0), inner_cone_angle: 0.1, outer_cone_angle: 0.3, range: None });
    b.lights.push(Light::Directional { direction: Vec3::new(0.3, -1.0, 0.2).normalize(), illuminance: Vec3::ONE });
    b
}

/// The light tracer's first vertex is drawn with the density it claims: for every light,
/// `E[g(z) / p_A(z)]` over the drawn points is `∫ g dA` over the caster triangles the light
/// can reach (`g = 1`: their area; `g = x`: their first moment, which also checks that
/// points are uniform on each triangle), every point lies on the triangle it names, and no
/// triangle the light cannot reach is drawn. Which triangles a point or directional light
/// reaches is worked out here from their faces, not from the sampler's weights; with the
/// per-light tables given up (a limit of 0), every light draws by area from all of them.
#[test]
fn caster_points_are_drawn_with_the_density_they_claim() {
    let scene = caster_builder().build(DVec3::ZERO);
    let tri = |t: u32| scene.mesh.indices[t as usize].map(|i| scene.mesh.positions[i as usize]);
    let double = |t: u32| scene.materials[scene.mesh.material[t as usize] as usize].double_sided;
    let count = scene.mesh.indices.len() as u32;
    for (limit, shared) in [(usize::MAX, false), (0, true)] {
        let c = crate::caustics::CausticPaths::build_with_limit(&scene, limit);
        assert_eq!(c.caster_triangles(), count as usize);
        let lights = c.emitter_lights();
        assert_eq!(lights.len(), 3, "every light reaches a caster");
        for (e, &l) in lights.iter().enumerate() {
            let light = &scene.lights[l];
            // The triangles this light's table can draw.
            let reached = |t: u32| {
                if shared {
                    return true;
                }
                let p = tri(t);
                let n = (p[1] - p[0]).cross(p[2] - p[0]);
                let side = match *light {
                    Light::Point { position, .. } | Light::Spot { position, .. } => n.dot(position - p[0]),
                    Light::Directional { direction, .. } => -n.dot(direction),
                };
                match *light {
                    // The spot's cone is the sampler's own conservative test: checked for
                    // consistency only (`E[1/p]` against the triangles it draws).
                    Light::Spot { .. } => crate::caustics::light_weight(light, p, double(t)) > 0.0,
                    _ => side > 0.0 || (double(t) && side < 0.0),
                }
            };
            let area = |t: u32| {
                let p = tri(t);
                0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length() as f64
            };
            let exact_area: f64 = (0..count).filter(|&t| reached(t)).map(area).sum();
            let exact_x: f64 = (0..count).filter(|&t| reached(t)).map(|t| area(t) * tri(t).iter().map(|v| v.x as f64).sum::<f64>() / 3.0).sum();
            assert!(exact_area > 0.0);
            let (mut s_area, mut s_x, n) = (0.0f64, 0.0f64, 200_000u32);
            let mut state = 11u64 + e as u64;
            let mut uniform = || {
                state = crate::sampler::splitmix64(state);
                (state >> 40) as f32 / (1u64 << 24) as f32
            };
            for _ in 0..n {
                let (t, z, p_area) = c.sample_caster_point(&scene, e, uniform(), Vec2::new(uniform(), uniform())).expect("a caster point");
                assert!(reached(t), "light {l} drew triangle {t}, which it cannot reach");
                let p = tri(t);
                // On the triangle: in its plane and inside its edges.
                let nrm = (p[1] - p[0]).cross(p[2] - p[0]);
                for k in 0..3 {
                    let edge = (p[(k + 1) % 3] - p[k]).cross(z - p[k]).dot(nrm);
                    assert!(edge >= -1e-5 * nrm.length_squared(), "point {z} outside triangle {t}");
                }
                assert!(nrm.normalize().dot(z - p[0]).abs() < 1e-5);
                s_area += 1.0 / p_area as f64;
                s_x += z.x as f64 / p_area as f64;
            }
            let (s_area, s_x) = (s_area / n as f64, s_x / n as f64);
            assert!((s_area - exact_area).abs() < 0.01 * exact_area, "light {l}, shared {shared}: E[1/p] = {s_area}, area {exact_area}");
            assert!((s_x - exact_x).abs() < 0.01 * exact_area, "light {l}, shared {shared}: E[x/p] = {s_x}, ∫x dA = {exact_x}");
        }
    }
}

/// A view that the light paths rarely reach (its pilot's paths land in it less than
/// `MIN_YIELD` times per path) is left to the path tracer: here a camera looking up into
/// the empty sky renders exactly as with the light tracer switched off, while one looking
/// at the floor around the casters traces all its light paths.
#[test]
fn views_the_light_paths_miss_are_left_to_the_path_tracer() {
    let mut b = caster_builder();
    let floor = b.material(0.6, 0.0, false);
    b.quad([Vec3::new(-4.0, 0.0, 4.0), Vec3::new(4.0, 0.0, 4.0), Vec3::new(4.0, 0.0, -4.0), Vec3::new(-4.0, 0.0, -4.0)], 2, floor);
    let mut r = Renderer::new(b.build(DVec3::ZERO), &AccelParams::medium_build()).unwrap();
    let s = settings(8, 4, 0.1, false);
    let paths_for = |r: &Renderer, cam: &Camera| {
        let (w, h) = (cam.intrinsics.width, cam.intrinsics.height);
        let n = r.caustics().light_paths(w as u64 * h as u64, s.spp, s.max_bounces);
        (n, r.caustics().paths_for_view(&r.integrator(&s), &SampleRays::new(cam, r.scene().origin), (w, h), s.seed, 0, s.spp))
    };
    let floor_cam = camera(24, 24, 60.0, DVec3::new(3.0, 3.0, 3.0), DVec3::new(0.5, 0.0, -0.5));
    let (n, traced) = paths_for(&r, &floor_cam);
    assert!(n > 0 && traced == n, "the floor view traces its {n} light paths ({traced})");
    let sky_cam = camera(24, 24, 40.0, DVec3::new(0.0, 3.0, 0.0), DVec3::new(0.1, 10.0, 0.0));
    let (n, traced) = paths_for(&r, &sky_cam);
    assert!(n > 0 && traced == 0, "the sky view traces none of its {n} light paths ({traced})");
    let with = r.render_view(&sky_cam, 0, &s);
    r.set_caustic_light_tracing(false);
    let without = r.render_view(&sky_cam, 0, &s);
    assert_eq!(crate::version::view_hash(&with), crate::version::view_hash(&without));
}

/// The weights caster triangles are drawn with are exact solid angles and projected
/// areas: a closed box of inward faces around a point light subtends 4π; seen from outside,
/// a single-sided box's faces towards a light subtend as much as the faces away from it
/// (every ray through the box crosses one of each), so double-sided faces weigh twice as
/// much; for a directional light the same holds for the projected areas.
#[test]
fn caster_weights_are_exact_solid_angles_and_projected_areas() {
    use crate::caustics::light_weight;
    let box_tris = |inward: bool| {
        let mut b = Builder::new();
        b.aabox(Vec3::new(-0.5, -0.3, -0.7), Vec3::new(0.6, 0.4, 0.2), inward, 0);
        b.mesh.indices.iter().map(|i| i.map(|k| b.mesh.positions[k as usize])).collect::<Vec<_>>()
    };
    let inside = Light::Point { position: Vec3::new(0.1, 0.05, -0.2), intensity: Vec3::ONE, range: None };
    let total: f64 = box_tris(true).iter().map(|&p| light_weight(&inside, p, false)).sum();
    assert!((total - 4.0 * PI64).abs() < 1e-5, "Σ Ω = {total}");
    for light in [
        Light::Point { position: Vec3::new(2.0, 1.5, 1.0), intensity: Vec3::ONE, range: None },
        Light::Directional { direction: Vec3::new(-0.4, -1.0, 0.3).normalize(), illuminance: Vec3::ONE },
    ] {
        let tris = box_tris(false);
        let front: f64 = tris.iter().map(|&p| light_weight(&light, p, false)).sum();
        let both: f64 = tris.iter().map(|&p| light_weight(&light, p, true)).sum();
        assert!(front > 0.0 && (both - 2.0 * front).abs() < 1e-5 * both, "{light:?}: front {front}, double-sided {both}");
    }
    // A light beyond its range reaches nothing.
    let far = Light::Point { position: Vec3::new(20.0, 0.0, 0.0), intensity: Vec3::ONE, range: Some(5.0) };
    assert!(box_tris(false).iter().all(|&p| light_weight(&far, p, true) == 0.0));
}

/// The partition holds with longer paths (4 bounces: caustic paths of 2 to 4 vertices go
/// to the light tracer, everything else stays): a glossy metal box between a diffuse
/// floor and wall, under a point and a directional light, renders the same mean over the
/// pixels its caustics reach with and without the light tracer, within the renders'
/// noise (16 seeds each). The path tracer's estimate of a caustic is heavy-tailed, so
/// this catches a caustic counted twice or left out (counting those of 3 and 4 vertices
/// twice: 5 standard errors), not a small error in its value: the mirror's closed form
/// above does that.
#[test]
fn the_light_tracer_and_the_path_tracer_agree_on_a_glossy_scene() {
    let mut b = Builder::new();
    let floor = b.material(0.6, 0.0, false);
    b.materials.push(Material { metallic_factor: 1.0, roughness_factor: 0.15, base_color_factor: Vec4::new(0.95, 0.8, 0.5, 1.0), ..Material::gltf_default() });
    let metal = b.materials.len() as u32 - 1;
    b.quad([Vec3::new(-3.0, 0.0, 3.0), Vec3::new(3.0, 0.0, 3.0), Vec3::new(3.0, 0.0, -3.0), Vec3::new(-3.0, 0.0, -3.0)], 2, floor);
    b.aabox(Vec3::new(-0.4, 0.0, -0.4), Vec3::new(0.4, 0.7, 0.4), false, metal);
    // A white wall behind: caustics it receives reach the floor (paths of 3 vertices).
    let wall = b.material(0.9, 0.0, false);
    b.quad([Vec3::new(-3.0, 2.0, 1.2), Vec3::new(3.0, 2.0, 1.2), Vec3::new(3.0, 0.0, 1.2), Vec3::new(-3.0, 0.0, 1.2)], 2, wall);
    b.lights.push(Light::Point { position: Vec3::new(1.2, 1.5, 0.8), intensity: Vec3::splat(3.0), range: None });
    b.lights.push(Light::Directional { direction: Vec3::new(-0.5, -1.0, 0.3).normalize(), illuminance: Vec3::splat(1.0) });
    let mut r = Renderer::new(b.build(DVec3::ZERO), &AccelParams::medium_build()).unwrap();
    assert_eq!(r.caustics().caster_triangles(), r.scene().mesh.material.iter().filter(|&&k| k == metal).count());
    let cam = camera(24, 24, 60.0, DVec3::new(-2.0, 2.0, -2.5), DVec3::new(0.0, 0.2, 0.0));
    let s = settings(512, 4, 0.1, false);
    // The pixels the caustic reaches (an independent light-traced image, another seed).
    let (caustic, _) = r.caustics().render(&r.integrator(&s), &SampleRays::new(&cam, r.scene().origin), (24, 24), 99, 0, 1 << 16);
    let mask: Vec<bool> = caustic.iter().map(|c| c.iter().sum::<f64>() > 0.0).collect();
    let lit = mask.iter().filter(|&&m| m).count();
    assert!(lit > 50, "{lit} pixels see the caustic");
    // Every seed's view is light-traced (its pilot keeps the light tracer), so the two
    // sides below differ in how they estimate the caustic.
    for k in 0..16 {
        assert!(r.caustics().paths_for_view(&r.integrator(&s), &SampleRays::new(&cam, r.scene().origin), (24, 24), s.seed, k, s.spp) > 0);
    }
    let stats = |r: &Renderer| {
        let mean = |v: &ViewOutput| v.color.data.chunks(4).zip(&mask).filter(|(_, m)| **m).map(|(p, _)| (p[0] + p[1] + p[2]) as f64).sum::<f64>() / (3 * lit) as f64;
        let means: Vec<f64> = (0..16).map(|k| mean(&r.render_view(&cam, k, &s))).collect();
        let m = means.iter().sum::<f64>() / 16.0;
        let var = means.iter().map(|x| (x - m).powi(2)).sum::<f64>() / 15.0;
        (m, var / 16.0)
    };
    let (on, se2_on) = stats(&r);
    r.set_caustic_light_tracing(false);
    let (off, se2_off) = stats(&r);
    let se = (se2_on + se2_off).sqrt();
    eprintln!("caustic pixels ({lit}): mean with the light tracer {on:.5} (SE {:.1e}), without {off:.5} (SE {:.1e})", se2_on.sqrt(), se2_off.sqrt());
    assert!((on - off).abs() < 4.0 * se + 1e-4 * on, "with {on}, without {off}, SE {se}");
}

/// A glass slab (`KHR_materials_transmission` + `_volume`, ior 1.5, smooth) of thickness
/// `d` between the camera and a black emitter of radiance 1.
fn glass_slab(d: f32, attenuation: Option<(f32, f32)>) -> Renderer {
    let mut b = Builder::new();
    let mut g = Material::gltf_default();
    (g.metallic_factor, g.roughness_factor, g.transmission_factor) = (0.0, 0.0, 1.0);
    g.volume = Some(crate::scene::Volume {
        attenuation_color: Vec3::splat(attenuation.map_or(1.0, |a| a.0)),
        attenuation_distance: attenuation.map_or(f32::INFINITY, |a| a.1),
    });
    b.materials.push(g);
    b.aabox(Vec3::new(-1.0, -1.0, -0.5 * d), Vec3::new(1.0, 1.0, 0.5 * d), false, 0);
    let e = b.material(0.0, 1.0, true);
    b.quad([Vec3::new(-3.0, -3.0, -1.0), Vec3::new(3.0, -3.0, -1.0), Vec3::new(3.0, 3.0, -1.0), Vec3::new(-3.0, 3.0, -1.0)], 1, e);
    Renderer::new(b.build(DVec3::ZERO), &AccelParams::fast_build()).unwrap()
}

#[test]
fn a_glass_slab_transmits_its_closed_form_fraction_and_ground_truth_stays_on_its_first_surface() {
    // Normal incidence through two interfaces (F = 0.04 each) and Beer–Lambert absorption
    // A = c^(d / distance) per crossing, summed over the internal reflections:
    // T = (1 − F)² A / (1 − F² A²).
    let f = 0.04f64;
    for (d, att) in [(0.5f32, None), (0.5, Some((0.5f32, 0.5f32))), (0.3, Some((0.2, 1.0)))] {
        let r = glass_slab(d, att);
        let a = att.map_or(1.0, |(c, dist)| (c as f64).powf(d as f64 / dist as f64));
        let expect = (1.0 - f).powi(2) * a / (1.0 - f * f * a * a);
        let ray = Ray::new(Vec3::new(0.1, 0.05, 3.0), -Vec3::Z);
        let (mean, se) = estimate(&r, &settings(1, 64, 0.0, true), &ray, 20_000);
        assert!((mean - expect).abs() < 4.0 * se + 1e-4, "d {d} {att:?}: {mean} ± {se} vs {expect}");
    }
    // Depth, distance, normal and alpha are those of the slab's front face, not of the
    // emitter seen through it.
    let r = glass_slab(0.5, Some((0.5, 0.5)));
    let cam = camera(8, 8, 20.0, DVec3::new(0.0, 0.0, 3.0), DVec3::ZERO);
    let gt = r.render_view(&cam, 0, &settings(1, 8, 0.0, true)).ground_truth;
    for k in 0..64 {
        assert_eq!(gt.alpha[k], 1.0);
        assert!((gt.depth[k] - 2.75).abs() < 1e-5, "pixel {k}: depth {}", gt.depth[k]);
        assert!((Vec3::from_slice(&gt.normal[3 * k..3 * k + 3]) - Vec3::Z).length() < 1e-5);
    }
}

#[test]
fn a_rough_glass_sheet_transmits_a_light_behind_it_by_next_event_estimation() {
    // A thin rough glass sheet (roughness 0.5, no volume) facing the camera, lit only by a
    // directional light from behind: the radiance through it is the BSDF's transmitted value
    // towards the light times the illuminance, which only a light sample taken on the sheet's
    // far side can find (a delta light is never hit by BSDF sampling).
    let mut b = Builder::new();
    let mut g = Material::gltf_default();
    (g.metallic_factor, g.roughness_factor, g.transmission_factor) = (0.0, 0.5, 1.0);
    b.materials.push(g.clone());
    b.quad([Vec3::new(-1.0, -1.0, 0.0), Vec3::new(1.0, -1.0, 0.0), Vec3::new(1.0, 1.0, 0.0), Vec3::new(-1.0, 1.0, 0.0)], 1, 0);
    let travel = Vec3::new(0.3, 0.2, 1.0).normalize();
    let e = 2.0f32;
    b.lights.push(Light::Directional { direction: travel, illuminance: Vec3::splat(e) });
    let r = Renderer::new(b.build(DVec3::ZERO), &AccelParams::fast_build()).unwrap();
    let ray = Ray::new(Vec3::new(0.1, 0.05, 2.0), -Vec3::Z);
    let (mean, se) = estimate(&r, &settings(1, 1, 0.0, true), &ray, 4000);
    let surf = crate::material::resolve(&g, &[], &crate::material::SurfaceAttributes { uv: [Vec2::ZERO; 2], color: Vec4::ONE });
    let wi = -travel;
    let local = Vec3::new((1.0 - wi.z * wi.z).sqrt(), 0.0, wi.z);
    let expect = (surf.bsdf.evaluate(Vec3::Z, local).x * e) as f64;
    assert!(expect > 0.01, "{expect}");
    assert!((mean - expect).abs() < 4.0 * se + 1e-4 * expect, "{mean} ± {se} vs {expect}");
}

/// The clear coat's normal at a path vertex: the frame's own without normal maps; the
/// interpolated normal, unmapped, where only the base is normal-mapped (the extension: no
/// clearcoatNormalTexture, no normal mapping on the coat); its own map where it has one.
#[test]
fn the_clear_coat_takes_its_own_normal_at_a_vertex() {
    use crate::material::{Bsdf, resolve};
    use crate::scene::{Clearcoat, Filter, Texture, TextureRef, Wrap};
    let mut b = Builder::new();
    b.tri([Vec3::new(-1.0, 0.0, 1.0), Vec3::new(1.0, 0.0, 1.0), Vec3::new(0.0, 0.0, -1.0)], 0);
    b.mesh.tangents = vec![Vec4::new(1.0, 0.0, 0.0, 1.0); 3];
    b.mesh.uv0 = vec![Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0), Vec2::new(0.5, 1.0)];
    b.materials.push(Material { metallic_factor: 0.0, ..Material::gltf_default() });
    let mut scene = b.build(DVec3::ZERO);
    // A normal map tilting the normal towards the tangent (+X): c = (0.6, 0, 0.8).
    scene.textures.push(Texture { width: 1, height: 1, texels: vec![Vec4::new(0.8, 0.5, 0.9, 1.0)] });
    let map = TextureRef { texture: 0, tex_coord: 0, wrap_s: Wrap::Repeat, wrap_t: Wrap::Repeat, filter: Filter::Nearest, transform: None };
    let tilted = Vec3::new(0.6, 0.8, 0.0);
    let ray = Ray::new(Vec3::new(0.1, 1.0, 0.2), Vec3::new(0.0, -1.0, 0.05).normalize());
    let hit = crate::accel::Hit { prim: 0, t: 1.0, b: [0.3, 0.3, 0.4], front: true };
    let si = crate::integrator::interaction(&scene, &ray, &hit);
    let coat = |m: &Material| {
        let surf = resolve(m, &scene.textures, &si.attr);
        let (frame, at) = crate::integrator::vertex_bsdf(&scene, &si, m, &surf, -ray.direction);
        let Bsdf::Layered(l) = at.bsdf() else { panic!("a clear coat gives a layered BSDF") };
        (frame.n, frame.to_world(l.coat_normal))
    };
    let mut m = Material { metallic_factor: 0.0, ..Material::gltf_default() };
    m.clearcoat = Some(Clearcoat { factor: 1.0, texture: None, roughness_factor: 0.2, roughness_texture: None, normal_texture: None });
    let (n, nc) = coat(&m);
    assert!((n - Vec3::Y).length() < 1e-6 && (nc - Vec3::Y).length() < 1e-6, "no maps: {n} {nc}");
    m.normal_texture = Some((map, 1.0));
    let (n, nc) = coat(&m);
    assert!((n - tilted).length() < 1e-2, "the base is mapped: {n}");
    assert!((nc - Vec3::Y).length() < 1e-5, "the coat is not: {nc}");
    m.clearcoat.as_mut().unwrap().normal_texture = Some((map, 1.0));
    let (n, nc) = coat(&m);
    assert!((nc - tilted).length() < 1e-2 && (nc - n).length() < 1e-5, "the coat's own map: {n} {nc}");
}
