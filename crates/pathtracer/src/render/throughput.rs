//! Ray-throughput measurements for the benchmarks (`cargo bench -p pathtracer --bench render`,
//! `cargo xtask bench render`): primary rays one at a time or as packets, the shadow rays of the
//! first vertex, and any ray file (`tests/mitsuba/rays.py`'s records) through the path loop's
//! queries. They time the same queries as rendering, never alter a render, and live apart from
//! the per-view driver they measure.

use super::{RenderSettings, Renderer};
use crate::PathTracerError;
use crate::geometry::Ray;
use crate::integrator::interaction;
use crate::sampler::Sampler;
use crate::scene::Light;
use dataset::Camera;
use glam::Vec3;
use rayon::prelude::*;

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

/// A ray query [`Renderer::ray_query_throughput`] times.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RayQuery {
    /// The closest hit of each ray alone (no limit), as the path loop's later bounces trace.
    Closest,
    /// The same, as packets of up to 64 consecutive rays, as the path loop traces a pixel's
    /// camera rays.
    ClosestPackets,
    /// Whether anything blocks each ray before its own limit (shadow rays).
    AnyHit,
}

/// Rays in the little-endian `f32` records of a ray file: origin xyz, direction xyz, `t_max`
/// (28 bytes each), in the scene's local frame (`tests/mitsuba/rays.py` writes such files
/// with Mitsuba's rays for an exported scene).
pub fn read_ray_file(path: &std::path::Path) -> Result<Vec<(Ray, f32)>, PathTracerError> {
    let bytes = std::fs::read(path).map_err(|e| PathTracerError::import(path, format!("reading the ray file: {e}")))?;
    if bytes.len() % 28 != 0 {
        return Err(PathTracerError::import(path, format!("{} bytes is not a whole number of 28-byte ray records", bytes.len())));
    }
    Ok(bytes
        .chunks_exact(28)
        .map(|r| {
            let f = |k: usize| f32::from_le_bytes([r[4 * k], r[4 * k + 1], r[4 * k + 2], r[4 * k + 3]]);
            (Ray::new(Vec3::new(f(0), f(1), f(2)), Vec3::new(f(3), f(4), f(5))), f(6))
        })
        .collect())
}

impl Renderer {
    /// Traces every pixel-centre ray of `camera` (closest hit only, in parallel) and times
    /// it: a primary-ray throughput figure for benchmarks.
    pub fn primary_ray_throughput(&self, camera: &Camera) -> PrimaryRayStats {
        self.primary_throughput(camera, false)
    }

    /// [`Renderer::primary_ray_throughput`] with each row's pixel-centre rays traced as packets
    /// of up to [`crate::accel::PACKET`] neighbours ([`crate::integrator::PathIntegrator::intersect_many`], the
    /// same hits): the throughput of coherent camera rays, as the renderer traces a pixel's
    /// samples.
    pub fn primary_packet_throughput(&self, camera: &Camera) -> PrimaryRayStats {
        self.primary_throughput(camera, true)
    }

    fn primary_throughput(&self, camera: &Camera, packets: bool) -> PrimaryRayStats {
        let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
        let integ = self.integrator(&RenderSettings::preview(0));
        let start = std::time::Instant::now();
        let hits: u64 = (0..h)
            .into_par_iter()
            .map(|j| {
                let ray = |i: u32| self.local_ray(&camera.pixel_center_ray(i, j));
                if packets {
                    let rays: Vec<Ray> = (0..w).map(ray).collect();
                    let mut hits = vec![None; rays.len()];
                    integ.intersect_many(&rays, &mut hits);
                    hits.iter().filter(|h| h.is_some()).count() as u64
                } else {
                    (0..w).filter(|&i| integ.intersect(&ray(i)).is_some()).count() as u64
                }
            })
            .sum();
        let seconds = start.elapsed().as_secs_f64();
        let rays = w as u64 * h as u64;
        PrimaryRayStats { rays, hits, seconds, rays_per_second: if seconds > 0.0 { rays as f64 / seconds } else { 0.0 } }
    }

    /// The shadow rays the integrator would trace at the first vertex of every pixel-centre
    /// ray of `camera` that hits: one towards each punctual light (as far as the light) and one
    /// towards a point on the emissive triangles (drawn with the pixel's first sampler
    /// numbers); in a scene with neither, one cosine-distributed direction to infinity (an
    /// environment sample). Each ray starts at the offset origin and comes with its `t_max`.
    /// The set for [`Renderer::shadow_ray_throughput`].
    pub fn shadow_rays(&self, camera: &Camera) -> Vec<(Ray, f32)> {
        use crate::geometry::offset_ray_origin;
        use crate::integrator::SHADOW_EPSILON;
        let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
        let integ = self.integrator(&RenderSettings::preview(0));
        let rows: Vec<Vec<(Ray, f32)>> = (0..h)
            .into_par_iter()
            .map(|j| {
                let mut out = Vec::new();
                for i in 0..w {
                    let ray = self.local_ray(&camera.pixel_center_ray(i, j));
                    let Some(hit) = integ.intersect(&ray) else { continue };
                    let si = interaction(&self.scene, &ray, &hit);
                    let origin = offset_ray_origin(si.p, si.p_err, si.ng, si.ng);
                    let mut sampler = Sampler::new(0, 0, j as u64 * w as u64 + i as u64, 0);
                    for light in &self.scene.lights {
                        let Some(inc) = crate::light::punctual_incidence(light, si.p) else { continue };
                        let t_max = match *light {
                            Light::Point { position, .. } | Light::Spot { position, .. } => (position - origin).length() * (1.0 - SHADOW_EPSILON),
                            Light::Directional { .. } => f32::INFINITY,
                        };
                        out.push((Ray::new(origin, inc.wi), t_max));
                    }
                    let (u_spare, u_pt) = (sampler.next_1d(), sampler.next_2d());
                    if let Some(es) = self.emitters.sample(u_pt, || u_spare) {
                        let m = &self.scene.mesh;
                        let p = m.indices[es.prim as usize].map(|k| m.positions[k as usize]);
                        let (q, _) = crate::geometry::hit_point_error(p, es.b);
                        let seg = q - origin;
                        let len = seg.length();
                        if len > 0.0 {
                            out.push((Ray::new(origin, seg / len), len * (1.0 - SHADOW_EPSILON)));
                        }
                    } else if self.scene.lights.is_empty() {
                        let d = crate::sampler::sample_cosine_hemisphere(sampler.next_2d());
                        out.push((Ray::new(origin, crate::geometry::Frame::from_normal(si.n).to_world(d).normalize()), f32::INFINITY));
                    }
                }
                out
            })
            .collect();
        rows.into_iter().flatten().collect()
    }

    /// Throughput of `query` on `rays` (origins and directions in the scene's local frame,
    /// with their limits; [`read_ray_file`]), on all threads, chunks of 256 rays: the same
    /// queries, alpha tests included, as the path loop's. `hits` counts the rays that hit
    /// (closest-hit queries) or are blocked (any hit).
    pub fn ray_query_throughput(&self, rays: &[(Ray, f32)], query: RayQuery) -> PrimaryRayStats {
        let integ = self.integrator(&RenderSettings::preview(0));
        let start = std::time::Instant::now();
        let hits: u64 = rays
            .par_chunks(256)
            .map(|c| match query {
                RayQuery::Closest => c.iter().filter(|(r, _)| integ.intersect(r).is_some()).count() as u64,
                RayQuery::ClosestPackets => {
                    let rs: Vec<Ray> = c.iter().map(|(r, _)| *r).collect();
                    let mut out = vec![None; rs.len()];
                    integ.intersect_many(&rs, &mut out);
                    out.iter().filter(|h| h.is_some()).count() as u64
                }
                RayQuery::AnyHit => c.iter().filter(|(r, t)| integ.occluded(r, *t)).count() as u64,
            })
            .sum();
        let seconds = start.elapsed().as_secs_f64();
        let n = rays.len() as u64;
        PrimaryRayStats { rays: n, hits, seconds, rays_per_second: if seconds > 0.0 { n as f64 / seconds } else { 0.0 } }
    }

    /// Traces [`Renderer::shadow_rays`] of `camera` (any-hit queries only, in parallel; the
    /// rays are made before the clock starts) and times them: a shadow-ray throughput figure
    /// for benchmarks. `hits` counts the occluded rays.
    pub fn shadow_ray_throughput(&self, camera: &Camera) -> PrimaryRayStats {
        self.ray_query_throughput(&self.shadow_rays(camera), RayQuery::AnyHit)
    }
}
