//! The shared per-view driver (pbrt's `ImageTileIntegrator` idea): camera rays per pixel,
//! parallelism over rows with rayon, fixed-order accumulation, ground truth at pixel centres.
//!
//! - Colour: the average over the pixel's area of `spp` jittered camera rays, each traced by
//!   [`PathIntegrator::radiance`]. Sample `s` of pixel `(i, j)` of view `v` draws every random
//!   number from `Sampler::new(seed, v, j·width + i, s)` and samples are summed in `f64` in
//!   order `s = 0, 1, …`, so the image is bit-identical for any thread count.
//! - Alpha: with a transparent background, the fraction of the pixel's samples whose camera
//!   ray hit geometry (coverage), and RGB is premultiplied (misses add zero). With an opaque
//!   background, misses add the environment radiance and alpha is 1.
//! - Ground truth: the pixel-centre ray ([`dataset::Camera::pixel_center_ray`]) is traced
//!   once; its hit distance is re-computed in `f64` against the hit triangle
//!   ([`ray_triangle_plane_distance_f64`]) and converted to z-depth with
//!   [`dataset::Camera::z_depth_from_distance`]; the normal is the world shading normal facing
//!   the camera. Misses: depth, distance, normal and alpha 0.
//! - Non-finite radiance samples are replaced by zero and counted.
//! - Cameras are in true world coordinates (`f64`); rays are moved into the scene's local
//!   frame by subtracting [`Scene::origin`] before conversion to `f32`.

use crate::PathTracerError;
use crate::accel::{Accel, AccelParams, Hit};
use crate::geometry::{Ray, ray_triangle_plane_distance_f64};
use crate::integrator::{IntegratorSettings, PathIntegrator, interaction};
use crate::light::{EmissiveTriangles, Environment};
use crate::sampler::Sampler;
use crate::scene::{Light, Scene};
use dataset::{Camera, GroundTruth, RgbaImage};
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Settings of one render. All fields are meaningful choices; use a named constructor or
/// spell them out.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RenderSettings {
    /// Samples (camera rays) per pixel for colour, ≥ 1.
    pub spp: u32,
    /// Maximum scattering events per path (0: emitters only, 1: direct light, …).
    pub max_bounces: u32,
    /// Seed of the counter-based sampler.
    pub seed: u64,
    /// Constant environment radiance (linear RGB, ≥ 0); lights the scene in every case.
    pub environment: [f32; 3],
    /// Whether camera rays that miss are transparent (alpha 0, RGB 0) instead of showing the
    /// environment.
    pub transparent_background: bool,
}

impl RenderSettings {
    /// A quick look: 16 spp, 4 bounces, transparent background, environment radiance 1.
    pub fn preview(seed: u64) -> Self {
        Self { spp: 16, max_bounces: 4, seed, environment: [1.0; 3], transparent_background: true }
    }
    /// Dataset quality: 256 spp, 8 bounces, transparent background, environment radiance 1.
    pub fn dataset(seed: u64) -> Self {
        Self { spp: 256, max_bounces: 8, seed, environment: [1.0; 3], transparent_background: true }
    }
    /// Checks the ranges: `spp ≥ 1`, `max_bounces ≤ 1024`, finite non-negative environment.
    pub fn validate(&self) -> Result<(), PathTracerError> {
        if self.spp == 0 {
            return Err(PathTracerError::Config("spp must be at least 1".into()));
        }
        if self.max_bounces > 1024 {
            return Err(PathTracerError::Config(format!("max_bounces {} is above 1024", self.max_bounces)));
        }
        if !self.environment.iter().all(|c| c.is_finite() && *c >= 0.0) {
            return Err(PathTracerError::Config(format!("environment {:?} must be finite and >= 0", self.environment)));
        }
        Ok(())
    }
    fn integrator_settings(&self) -> IntegratorSettings {
        let env = Vec3::from_array(self.environment.map(|c| if c.is_finite() && c > 0.0 { c } else { 0.0 }));
        IntegratorSettings {
            max_bounces: self.max_bounces.min(1024),
            environment: Environment { radiance: env },
            transparent_background: self.transparent_background,
        }
    }
}

/// The result of rendering one view.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewOutput {
    /// Linear RGBA. Transparent background: RGB premultiplied by alpha, alpha = coverage
    /// (fraction of the pixel's samples that hit geometry). Opaque background: alpha 1.
    pub color: RgbaImage,
    /// Ground truth at the pixel-centre rays: z-depth, distance, world shading normal facing
    /// the camera, alpha 0/1.
    pub ground_truth: GroundTruth,
    /// Camera samples traced (width · height · spp).
    pub samples: u64,
    /// Radiance samples that were NaN or infinite (replaced by zero).
    pub nonfinite_samples: u64,
    /// Minimum and maximum pixel-centre hit distance (`f64`), `None` when nothing was hit.
    pub distance_range: Option<(f64, f64)>,
}

/// A pixel-centre (ground-truth) hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PrimaryHit {
    /// The BVH hit (triangle, `f32` distance, barycentrics).
    pub hit: Hit,
    /// Distance along the ray re-computed in `f64` against the hit triangle's plane.
    pub distance: f64,
    /// Unit world shading normal facing the ray's origin.
    pub normal: Vec3,
}

/// Primary-ray throughput figures from [`Renderer::primary_ray_throughput`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PrimaryRayStats {
    /// Rays traced.
    pub rays: u64,
    /// Rays that hit geometry.
    pub hits: u64,
    /// Wall time, seconds.
    pub seconds: f64,
    /// `rays / seconds`.
    pub rays_per_second: f64,
}

/// A scene ready to render: the scene, its BVH and its light tables.
pub struct Renderer {
    scene: Scene,
    accel: Accel,
    emitters: EmissiveTriangles,
}

impl std::fmt::Debug for Renderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Renderer")
            .field("scene", &self.scene.name)
            .field("triangles", &self.scene.mesh.indices.len())
            .field("emissive_triangles", &self.emitters.len())
            .field("accel", &self.accel)
            .finish()
    }
}

/// Checks the scene's internal consistency (the importer's output, or a hand-made scene).
pub fn validate_scene(scene: &Scene) -> Result<(), PathTracerError> {
    let m = &scene.mesh;
    let bad = |msg: String| Err(PathTracerError::Config(format!("scene {}: {msg}", scene.name)));
    if !scene.origin.is_finite() {
        return bad("non-finite origin".into());
    }
    if m.material.len() != m.indices.len() {
        return bad(format!("{} triangles but {} material indices", m.indices.len(), m.material.len()));
    }
    let nv = m.positions.len();
    for (name, len) in [("normals", m.normals.len()), ("tangents", m.tangents.len()), ("uv0", m.uv0.len()), ("uv1", m.uv1.len()), ("colors", m.colors.len())] {
        if len != nv && len != 0 {
            return bad(format!("{name} has {len} entries for {nv} vertices"));
        }
    }
    if let Some(k) = m.indices.iter().position(|t| t.iter().any(|&i| i as usize >= nv)) {
        return bad(format!("triangle {k} references a vertex out of range"));
    }
    if let Some(k) = m.material.iter().position(|&i| i as usize >= scene.materials.len()) {
        return bad(format!("triangle {k} references material {} of {}", m.material[k], scene.materials.len()));
    }
    if m.positions.iter().any(|p| !p.is_finite()) {
        return bad("non-finite vertex position".into());
    }
    for (k, mat) in scene.materials.iter().enumerate() {
        let refs = [mat.base_color_texture, mat.emissive_texture, mat.metallic_roughness_texture, mat.normal_texture.map(|t| t.0), mat.occlusion_texture.map(|t| t.0)];
        for r in refs.into_iter().flatten() {
            let ok = scene.textures.get(r.texture as usize).is_some_and(|t| t.texels.len() == t.width as usize * t.height as usize);
            if !ok {
                return bad(format!("material {k} references missing or malformed texture {}", r.texture));
            }
        }
        if !(mat.emissive.is_finite() && mat.emissive.min_element() >= 0.0 && mat.base_color_factor.is_finite()) {
            return bad(format!("material {k} has a non-finite or negative factor"));
        }
    }
    for (k, l) in scene.lights.iter().enumerate() {
        let ok = match *l {
            Light::Point { position, intensity, .. } => position.is_finite() && intensity.is_finite(),
            Light::Spot { position, direction, intensity, inner_cone_angle, outer_cone_angle, .. } => {
                position.is_finite() && direction.is_finite() && intensity.is_finite() && inner_cone_angle.is_finite() && outer_cone_angle.is_finite()
            }
            Light::Directional { direction, illuminance } => direction.is_finite() && direction != Vec3::ZERO && illuminance.is_finite(),
        };
        if !ok {
            return bad(format!("light {k} has non-finite parameters"));
        }
    }
    Ok(())
}

impl Renderer {
    /// Validates the scene, builds its BVH (in parallel) and light tables.
    pub fn new(scene: Scene, accel: &AccelParams) -> Result<Renderer, PathTracerError> {
        validate_scene(&scene)?;
        let accel = Accel::build(&scene, accel)?;
        let emitters = EmissiveTriangles::build(&scene);
        Ok(Renderer { scene, accel, emitters })
    }

    /// The scene.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The acceleration structure.
    pub fn accel(&self) -> &Accel {
        &self.accel
    }

    /// The emissive-triangle table.
    pub fn emitters(&self) -> &EmissiveTriangles {
        &self.emitters
    }

    /// Whether any material is shaded view-dependently. Always false for now: every
    /// material is shaded Lambertian (see [`crate::material`]); becomes true per material
    /// once the metallic-roughness BRDF lands.
    pub fn is_view_dependent(&self) -> bool {
        self.scene.materials.iter().any(crate::material::is_view_dependent)
    }

    /// The path integrator for `settings`.
    pub fn integrator(&self, settings: &RenderSettings) -> PathIntegrator<'_> {
        PathIntegrator { scene: &self.scene, accel: &self.accel, emitters: &self.emitters, settings: settings.integrator_settings() }
    }

    /// A world-space (`f64`) ray moved into the scene's local `f32` frame.
    pub fn local_ray(&self, ray: &dataset::Ray) -> Ray {
        let o = ray.origin - self.scene.origin;
        Ray::new(o.as_vec3(), ray.direction.as_vec3().normalize_or_zero())
    }

    /// Traces a world-space ray (e.g. a pixel-centre ray) and returns its exact ground truth:
    /// the hit, its `f64` distance and the shading normal facing the ray.
    pub fn trace_primary(&self, ray: &dataset::Ray) -> Option<PrimaryHit> {
        let local = self.local_ray(ray);
        let integ = PathIntegrator { scene: &self.scene, accel: &self.accel, emitters: &self.emitters, settings: RenderSettings::preview(0).integrator_settings() };
        let hit = integ.intersect(&local)?;
        let m = &self.scene.mesh;
        let p = m.indices[hit.prim as usize].map(|i| m.positions[i as usize]);
        let o64: DVec3 = ray.origin - self.scene.origin;
        let d64 = ray.direction.normalize();
        let distance = ray_triangle_plane_distance_f64(p, o64, d64)
            .filter(|t| *t > 0.0 && (*t - hit.t as f64).abs() <= 1e-3 * (hit.t as f64).max(1.0))
            .unwrap_or(hit.t as f64);
        let si = interaction(&self.scene, &local, &hit);
        Some(PrimaryHit { hit, distance, normal: si.frame.n })
    }

    /// Renders one view (see the module docs). `settings` should have passed
    /// [`RenderSettings::validate`]; out-of-range values are clamped (spp 0 renders no
    /// samples: black, alpha 0; a negative or non-finite environment is treated as 0).
    pub fn render_view(&self, camera: &Camera, view_index: u32, settings: &RenderSettings) -> ViewOutput {
        let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
        let integ = self.integrator(settings);
        let spp = settings.spp;
        struct PixelOut {
            rgba: [f32; 4],
            gt: Option<(f32, f32, Vec3, f64)>,
            nonfinite: u64,
        }
        let rows: Vec<Vec<PixelOut>> = (0..h)
            .into_par_iter()
            .map(|j| {
                (0..w)
                    .map(|i| {
                        let pixel = j as u64 * w as u64 + i as u64;
                        let mut sum = [0.0f64; 3];
                        let mut hits = 0u32;
                        let mut nonfinite = 0u64;
                        for s in 0..spp {
                            let mut sampler = Sampler::new(settings.seed, view_index, pixel, s);
                            let u = sampler.next_2d();
                            let wray = camera.pixel_ray(i as f64 + u.x as f64, j as f64 + u.y as f64);
                            let r = integ.radiance(&self.local_ray(&wray), &mut sampler);
                            let mut rad = r.radiance;
                            if !rad.is_finite() {
                                nonfinite += 1;
                                rad = Vec3::ZERO;
                            }
                            if r.primary_hit {
                                hits += 1;
                            }
                            sum[0] += rad.x as f64;
                            sum[1] += rad.y as f64;
                            sum[2] += rad.z as f64;
                        }
                        let inv = if spp > 0 { 1.0 / spp as f64 } else { 0.0 };
                        let alpha = if settings.transparent_background { hits as f64 * inv } else if spp > 0 { 1.0 } else { 0.0 };
                        let rgba = [(sum[0] * inv) as f32, (sum[1] * inv) as f32, (sum[2] * inv) as f32, alpha as f32];
                        let gt = self.trace_primary(&camera.pixel_center_ray(i, j)).map(|ph| {
                            let depth = camera.z_depth_from_distance(i as f64 + 0.5, j as f64 + 0.5, ph.distance);
                            (depth as f32, ph.distance as f32, ph.normal, ph.distance)
                        });
                        PixelOut { rgba, gt, nonfinite }
                    })
                    .collect()
            })
            .collect();
        let n = w as usize * h as usize;
        let mut color = RgbaImage::new(w, h);
        let mut gt = GroundTruth { width: w, height: h, depth: vec![0.0; n], distance: vec![0.0; n], normal: vec![0.0; 3 * n], alpha: vec![0.0; n] };
        let mut nonfinite = 0u64;
        let mut range: Option<(f64, f64)> = None;
        for (j, row) in rows.iter().enumerate() {
            for (i, px) in row.iter().enumerate() {
                let k = j * w as usize + i;
                color.data[4 * k..4 * k + 4].copy_from_slice(&px.rgba);
                nonfinite += px.nonfinite;
                if let Some((depth, dist, normal, d64)) = px.gt {
                    gt.depth[k] = depth;
                    gt.distance[k] = dist;
                    gt.normal[3 * k..3 * k + 3].copy_from_slice(&normal.to_array());
                    gt.alpha[k] = 1.0;
                    range = Some(match range {
                        None => (d64, d64),
                        Some((lo, hi)) => (lo.min(d64), hi.max(d64)),
                    });
                }
            }
        }
        ViewOutput { color, ground_truth: gt, samples: n as u64 * spp as u64, nonfinite_samples: nonfinite, distance_range: range }
    }

    /// Traces every pixel-centre ray of `camera` (closest hit only, in parallel) and times
    /// it: a primary-ray throughput figure for benchmarks.
    pub fn primary_ray_throughput(&self, camera: &Camera) -> PrimaryRayStats {
        let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
        let integ = self.integrator(&RenderSettings::preview(0));
        let start = std::time::Instant::now();
        let hits: u64 = (0..h)
            .into_par_iter()
            .map(|j| (0..w).filter(|&i| integ.intersect(&self.local_ray(&camera.pixel_center_ray(i, j))).is_some()).count() as u64)
            .sum();
        let seconds = start.elapsed().as_secs_f64();
        let rays = w as u64 * h as u64;
        PrimaryRayStats { rays, hits, seconds, rays_per_second: if seconds > 0.0 { rays as f64 / seconds } else { 0.0 } }
    }
}
