//! Light tracing of caustic paths: the light a glossy object focuses from a punctual light
//! onto the surfaces the camera sees, estimated from the light's side, where such paths are
//! easy to find (the path tracer finds them only by chance, with large weights; why and how
//! much noise they held: `docs/renderer.md`).
//!
//! **Which paths:** the caustic paths of [`crate::caustic_partition`], whose last vertex's
//! punctual-light term the path tracer leaves out; this tracer estimates exactly that term.
//!
//! **The estimator.** Per view, `N = ⌈width · height · spp · LIGHT_PATHS_PER_SAMPLE⌉` light
//! paths, or none when a pilot's paths rarely reach the image
//! ([`CausticPaths::paths_for_view`], [`MIN_YIELD`]): a punctual light in proportion to its
//! intensity times the casters' solid angle from it (directional: illuminance times their area
//! across the beam); a caster triangle in proportion to how strongly that light can light it
//! (`light_weight`), and a point `z₁` uniform on it, of area density `A₁ = P(triangle) / area`,
//! kept when the ray from the light hits it first. Then, for `j = 2, 3, …` up to
//! `min(max_bounces, MAX_CAUSTIC_VERTICES)`, a direction from `z_{j−1}`'s BSDF seen from the
//! light's side and its first hit `z_j`, the path ending at a sharp `z_j`. Each `z_j` whose
//! camera ray hits it first is connected to the camera, valued as the path tracer would value
//! it; with `W = f_x f_y / cos³θ_c` the density of pixel sampling per steradian, the
//! contribution to the pixel `z_j` falls in is
//! `W · |cosᶜ| / d² · E / (P_light · A₁) · Π_{i<j} f_i · |cos_i| / (p_i · |cos'_{i+1}|) · f_j / N`,
//! where the `f` are the BSDFs times their shading cosines (`f_j` towards `z_{j−1}` seen from
//! the camera, `f_i` towards `z_{i−1}` or the light seen from `z_{i+1}`), `E` the light's
//! irradiance at `z₁`, `p_i` the solid-angle density of the direction sampled at `z_i`,
//! `cos_i`, `cos'_{i+1}` the geometric cosines of `z_i z_{i+1}` at its two ends and `cosᶜ`, `d`
//! those of the camera's segment at `z_j`.
//!
//! **Determinism.** Light path `k` of view `v` draws from
//! `Sampler::new(splitmix64(seed ⊕ CAUSTIC_SEED_KEY), v, 0, k)` (the pilot's from pixel index
//! 1): dimension 0 the light, 1 the triangle, 2–3 the point, `4 + 2 (j − 2)` the direction at
//! `z_{j−1}`; chunks run in parallel and are summed in `f64` in path order (any thread count).
//!
//! **Known asymmetry.** Segments are traced from the light's side: where a back-face-culled or
//! `Blend` triangle lies across one, the partition uses the light-side visibility.

// Negated comparisons (`!(x > 0.0)`) are deliberate: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use crate::accel::{Hit, TraversalStack};
use crate::camera_rays::SampleRays;
use crate::caustic_partition::{CausticVertices, MAX_CAUSTIC_VERTICES};
use crate::geometry::{Ray, hit_point_error, offset_ray_origin};
use crate::integrator::{PathIntegrator, interaction, vertex_bsdf};
use crate::light::punctual_incidence;
use crate::sampler::{Sampler, sample_uniform_triangle, splitmix64};
use crate::scene::{Light, Scene};
use glam::{Vec2, Vec3};
use rayon::prelude::*;

/// Light paths per camera sample of a view (when the scene has casters and punctual lights):
/// the best of the rates tried on the committed scenes (`docs/experiments.md`).
pub const LIGHT_PATHS_PER_SAMPLE: f64 = 0.0625;
/// Most light paths of the pilot that decides whether a view is light-traced
/// ([`CausticPaths::paths_for_view`]): a sixteenth of the view's light paths, at least 256
/// (or all of them) and at most this many.
pub const PILOT_PATHS: u64 = 4096;
/// Least camera connections per light path (the pixels its vertices land in) for a view to be
/// light-traced: light paths that rarely reach the image cost their rays and remove little
/// noise (`docs/renderer.md`).
pub const MIN_YIELD: f64 = 0.1;
/// Most entries (caster triangles × punctual lights) of per-light caster tables; beyond it
/// every light draws its triangles from one table of their areas.
pub const MAX_TABLE_ENTRIES: usize = 1 << 22;
/// Sampler seed key of the light paths (`splitmix64(seed ^ CAUSTIC_SEED_KEY)`).
pub const CAUSTIC_SEED_KEY: u64 = 0x6361_7573_7469_6373;
/// Light paths per parallel task.
const CHUNK: u64 = 4096;
/// Tasks whose splats are held at once.
const BATCH_CHUNKS: u64 = 64;

/// One punctual light as the light tracer samples it.
#[derive(Clone, Debug)]
struct Emitter {
    light: usize,
    /// Which of [`CausticPaths::tables`] its caster triangles are drawn from.
    table: usize,
}

/// The caustic light tracer of one scene (see the module docs).
#[derive(Clone, Debug, Default)]
pub struct CausticPaths {
    /// Which materials are casters and which are sharp.
    vertices: CausticVertices,
    /// The caster triangles (mesh triangle indices; finite, of positive area) and their areas.
    triangles: Vec<u32>,
    areas: Vec<f32>,
    /// Inclusive running sums of the caster triangles' selection weights: one table per light
    /// ([`light_weight`]), or a single table of their areas shared by every light when
    /// per-light tables would hold more than [`MAX_TABLE_ENTRIES`] entries.
    tables: Vec<Vec<f64>>,
    emitters: Vec<Emitter>,
    /// Inclusive running sums of the emitters' selection weights, normalised.
    cdf: Vec<f32>,
    /// Centre and radius of a sphere around the scene's triangles ([`Scene::bounds`]):
    /// directional light rays start outside it.
    scene_sphere: (Vec3, f32),
}

impl CausticPaths {
    /// The caster triangles and the punctual lights that can reach them.
    pub fn build(scene: &Scene) -> Self {
        Self::build_with_limit(scene, MAX_TABLE_ENTRIES)
    }

    /// [`CausticPaths::build`] with per-light tables up to `limit` entries in all.
    pub(crate) fn build_with_limit(scene: &Scene, limit: usize) -> Self {
        let vertices = CausticVertices::new(scene);
        let m = &scene.mesh;
        let (mut triangles, mut areas) = (Vec::new(), Vec::new());
        for t in 0..m.indices.len() {
            let Some(&k) = m.material.get(t) else { continue };
            if !vertices.is_caster(k) {
                continue;
            }
            let Some(p) = triangle_positions(scene, t as u32) else { continue };
            let area = 0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length();
            if area > 0.0 && area.is_finite() {
                triangles.push(t as u32);
                areas.push(area);
            }
        }
        let b = &scene.bounds;
        let scene_sphere = if b.is_empty() { (Vec3::ZERO, 0.0) } else { (b.center(), 0.5 * b.diagonal()) };
        let shared = triangles.len().saturating_mul(scene.lights.len()) > limit;
        let running = |w: &mut dyn Iterator<Item = f64>| {
            let mut acc = 0.0f64;
            w.map(|x| {
                acc += x;
                acc
            })
            .collect::<Vec<f64>>()
        };
        let mut tables = Vec::new();
        if shared {
            tables.push(running(&mut areas.iter().map(|&a| a as f64)));
        }
        let mut emitters = Vec::new();
        let mut weights = Vec::new();
        let double_sided = |t: u32| m.material.get(t as usize).and_then(|&i| scene.materials.get(i as usize)).is_some_and(|mat| mat.double_sided);
        for (k, light) in scene.lights.iter().enumerate() {
            // In parallel, in triangle order; summed in that order.
            let w: Vec<f64> =
                triangles.par_iter().map(|&t| triangle_positions(scene, t).map_or(0.0, |p| light_weight(light, p, double_sided(t)))).collect();
            let total: f64 = w.iter().sum();
            let power = match *light {
                Light::Point { intensity, .. } | Light::Spot { intensity, .. } => intensity.max_element(),
                Light::Directional { illuminance, .. } => illuminance.max_element(),
            };
            let weight = power as f64 * total;
            if !(weight.is_finite() && weight > 0.0) {
                continue;
            }
            let table = if shared {
                0
            } else {
                tables.push(running(&mut w.into_iter()));
                tables.len() - 1
            };
            emitters.push(Emitter { light: k, table });
            weights.push(weight);
        }
        let total: f64 = weights.iter().sum();
        let mut acc = 0.0f64;
        let cdf = weights
            .iter()
            .map(|w| {
                acc += w;
                (acc / total) as f32
            })
            .collect();
        Self { vertices, triangles, areas, tables, emitters, cdf, scene_sphere }
    }

    /// Which vertices the path tracer leaves to this light tracer (see [`CausticVertices`]).
    pub fn vertices(&self) -> &CausticVertices {
        &self.vertices
    }

    /// The punctual lights the light paths start from (indices into the scene's lights), in
    /// the order [`CausticPaths::sample_caster_point`] numbers them.
    #[cfg(test)]
    pub(crate) fn emitter_lights(&self) -> Vec<usize> {
        self.emitters.iter().map(|e| e.light).collect()
    }

    /// How many caster triangles the light paths start on.
    pub fn caster_triangles(&self) -> usize {
        self.triangles.len()
    }

    /// How many light paths a view of `pixels` pixels at `spp` samples traces with
    /// `max_bounces`: 0 when the scene has no caster a punctual light reaches or paths stop
    /// before their second vertex's light (`max_bounces < 2`).
    pub fn light_paths(&self, pixels: u64, spp: u32, max_bounces: u32) -> u64 {
        if self.emitters.is_empty() || max_bounces < 2 {
            return 0;
        }
        ((pixels as f64 * spp as f64 * LIGHT_PATHS_PER_SAMPLE).ceil() as u64).min(u32::MAX as u64)
    }

    /// Traces `n` light paths of view `view` and returns each pixel's caustic radiance
    /// (row-major RGB, `f64`; zero when `n` is 0), with the count of non-finite path values
    /// (dropped). `integ` must be the view's integrator, `rays` its camera rays and `size` its
    /// width and height.
    pub fn render(&self, integ: &PathIntegrator<'_>, rays: &SampleRays, size: (u32, u32), seed: u64, view: u32, n: u64) -> (Vec<[f64; 3]>, u64) {
        let eye = Eye { integ, rays, size };
        let mut image = vec![[0.0f64; 3]; size.0 as usize * size.1 as usize];
        if n == 0 {
            return (image, 0);
        }
        let max_vertices = integ.settings.max_bounces.min(MAX_CAUSTIC_VERTICES);
        let key = Sampler::new(splitmix64(seed ^ CAUSTIC_SEED_KEY), view, 0, 0);
        let mut nonfinite = 0u64;
        let inv = 1.0 / n as f64;
        // Chunks in parallel, a bounded batch at a time (the splats of a 800×800, 128 spp
        // view would otherwise be held at once), summed in path order.
        let chunks = n.div_ceil(CHUNK);
        for batch in (0..chunks).step_by(BATCH_CHUNKS as usize) {
            let splats: Vec<Vec<(u32, Vec3)>> = (batch..(batch + BATCH_CHUNKS).min(chunks))
                .into_par_iter()
                .map(|c| {
                    integ.tallied(|| {
                        let mut out = Vec::new();
                        self.trace_range(&eye, max_vertices, &key, c * CHUNK..((c + 1) * CHUNK).min(n), &mut out);
                        out
                    })
                })
                .collect();
            for &(pixel, v) in splats.iter().flatten() {
                if v.is_finite() {
                    let px = &mut image[pixel as usize];
                    for (acc, x) in px.iter_mut().zip(v.to_array()) {
                        *acc += x as f64 * inv;
                    }
                } else {
                    nonfinite += 1;
                }
            }
        }
        (image, nonfinite)
    }

    /// How many light paths view `view` at `spp` samples traces: its count
    /// ([`CausticPaths::light_paths`], `n`) when a pilot's light paths reach its image at least
    /// [`MIN_YIELD`] times per path, else 0 (the path tracer then estimates every path). The
    /// pilot is `n / 16` paths (at least 256 or `n`, at most [`PILOT_PATHS`]) of their own
    /// random numbers (sampler pixel index 1), so the decision does not depend on the paths that are summed and the estimate stays
    /// unbiased; its paths are traced in fixed chunks, so the decision is the same for any
    /// thread count. `integ`, `rays` and `size` are the view's, as for
    /// [`CausticPaths::render`].
    pub fn paths_for_view(&self, integ: &PathIntegrator<'_>, rays: &SampleRays, size: (u32, u32), seed: u64, view: u32, spp: u32) -> u64 {
        let n = self.light_paths(size.0 as u64 * size.1 as u64, spp, integ.settings.max_bounces);
        if n == 0 {
            return 0;
        }
        let eye = Eye { integ, rays, size };
        let max_vertices = integ.settings.max_bounces.min(MAX_CAUSTIC_VERTICES);
        let key = Sampler::new(splitmix64(seed ^ CAUSTIC_SEED_KEY), view, 1, 0);
        let pilot = (n / 16).clamp(n.min(256), PILOT_PATHS);
        const PILOT_CHUNK: u64 = 256;
        let splats: u64 = (0..pilot.div_ceil(PILOT_CHUNK))
            .into_par_iter()
            .map(|c| {
                integ.tallied(|| {
                    let mut out = Vec::new();
                    self.trace_range(&eye, max_vertices, &key, c * PILOT_CHUNK..((c + 1) * PILOT_CHUNK).min(pilot), &mut out);
                    out.len() as u64
                })
            })
            .sum();
        if splats as f64 >= MIN_YIELD * pilot as f64 { n } else { 0 }
    }

    /// The light paths `paths` (sample indices of the sampler `key`), [`CausticPaths::trace`]d
    /// in order at the path loop's SIMD level ([`crate::accel::Accel::at_level`]), their
    /// queries on one stack of their own.
    fn trace_range(&self, eye: &Eye<'_>, max_vertices: u32, key: &Sampler, paths: std::ops::Range<u64>, out: &mut Vec<(u32, Vec3)>) {
        let mut stack = TraversalStack::default();
        eye.integ.accel.at_level(
            #[inline(always)]
            || {
                for k in paths {
                    self.trace(eye, &mut stack, max_vertices, &key.with_sample(k as u32), out);
                }
            },
        );
    }

    /// One light path: the pixels its vertices after the caster land in, with their values
    /// (times `N`), pushed to `out`.
    #[inline(always)]
    fn trace(&self, eye: &Eye<'_>, stack: &mut TraversalStack, max_vertices: u32, sampler: &Sampler, out: &mut Vec<(u32, Vec3)>) {
        let integ = eye.integ;
        let scene = integ.scene;
        // The light, in proportion to its weight.
        let u_light = sampler.get_1d(0);
        let e = self.cdf.iter().position(|&c| u_light < c).unwrap_or(self.cdf.len() - 1);
        let p_light = self.cdf[e] - if e == 0 { 0.0 } else { self.cdf[e - 1] };
        let emitter = &self.emitters[e];
        let light = &scene.lights[emitter.light];
        // A point on a caster triangle (the triangle by the light's table, the point uniform on
        // it), its density per unit area, and the ray from the light through it.
        let Some((prim, z, p_area)) = self.sample_caster_point(scene, e, sampler.get_1d(1), sampler.get_2d(2)) else { return };
        let (ray_l, expected) = match *light {
            Light::Point { position, .. } | Light::Spot { position, .. } => {
                let d = z - position;
                let dist = d.length();
                (Ray::new(position, d / dist), dist)
            }
            Light::Directional { direction, .. } => {
                let d = direction.normalize_or_zero();
                let back = 2.0 * ((self.scene_sphere.0 - z).length() + self.scene_sphere.1) + 1.0;
                (Ray::new(z - d * back, d), back)
            }
        };
        if !(ray_l.direction.is_finite() && expected > 0.0 && expected.is_finite()) {
            return;
        }
        // The light reaches the point when the ray's first hit is it (its triangle, or another
        // caster at the same distance, as at a shared edge).
        let Some(hit) = integ.intersect_in(stack, &ray_l) else { return };
        if hit.prim != prim && !((hit.t - expected).abs() <= 1e-4 * expected) {
            return;
        }
        let si = interaction(scene, &ray_l, &hit);
        if !self.vertices.is_caster(si.material) {
            return;
        }
        let Some(inc) = punctual_incidence(light, si.p) else { return };
        let denom = p_light * p_area;
        if !(denom > 0.0) {
            return;
        }
        // `beta`: the path tracer's value of the light's end of the path (E · Π f · cos ratios)
        // over its light-tracing density, so far. Vertex z₁ is the caster; z_j (j ≥ 2) the
        // surfaces the light reaches after it, each connected to the camera.
        let mut beta = inc.irradiance / denom;
        let (mut cur, mut cur_si, mut arrival, mut toward_prev) = (hit, si, ray_l.direction, inc.wi);
        for j in 2..=max_vertices {
            // A direction from z_{j−1} by its BSDF seen from the light's side, and its hit z_j.
            let Some(mat) = scene.materials.get(cur_si.material as usize) else { return };
            // (The material at z_{j−1} depends on its point only, not on the side it is seen from.)
            let surf = integ.surface(mat, &cur_si);
            let (frame_l, bsdf_l) = vertex_bsdf(scene, &cur_si, mat, &surf, -arrival);
            let Some(bs) = bsdf_l.sample(sampler.get_2d(4 + 2 * (j - 2))) else { return };
            let wb = frame_l.to_world(bs.wi).normalize();
            if !(wb.dot(cur_si.ng) > 0.0) {
                return;
            }
            let ray_b = Ray::new(offset_ray_origin(cur_si.p, cur_si.p_err, cur_si.ng, cur_si.ng), wb);
            let Some(next) = integ.intersect_in(stack, &ray_b) else { return };
            let next_si = interaction(scene, &ray_b, &next);
            if self.vertices.is_sharp(next_si.material) {
                return;
            }
            // The path tracer's f at z_{j−1}, seen from z_j, towards z_{j−2} or the light.
            let seen = Ray::new(next_si.p, -wb);
            let cur_pt = interaction(scene, &seen, &Hit { prim: cur.prim, t: next.t, b: cur.b, front: seen.direction.dot(cur_si.ng_front) < 0.0 });
            let (frame, bsdf) = vertex_bsdf(scene, &cur_pt, mat, &surf, wb);
            if !(toward_prev.dot(cur_pt.ng) > 0.0) {
                return;
            }
            let (f, _) = bsdf.evaluate_pdf(frame.to_local(toward_prev));
            let g = cur_pt.ng.dot(wb).abs() / (bs.pdf * next_si.ng.dot(wb).abs());
            if !(f.max_element() > 0.0 && g > 0.0 && g.is_finite()) {
                return;
            }
            beta *= f * g;
            let p_next = ray_b.origin + wb * next.t;
            if let Some(splat) = self.connect(eye, stack, next.prim, p_next, cur_pt.p, beta) {
                out.push(splat);
            }
            (cur, cur_si, arrival, toward_prev) = (next, next_si, wb, -wb);
        }
    }

    /// A caster triangle drawn from `emitter`'s table with `u` (in proportion to its weight), a
    /// point uniform on it from `v`, and the point's density per unit area, `P(triangle) /
    /// area`; `None` when the table is empty.
    pub(crate) fn sample_caster_point(&self, scene: &Scene, emitter: usize, u: f32, v: Vec2) -> Option<(u32, Vec3, f32)> {
        let table = self.tables.get(self.emitters.get(emitter)?.table)?;
        let total = *table.last()?;
        let x = u as f64 * total;
        // The first running sum above x: never a triangle of zero weight.
        let i = table.partition_point(|&c| c <= x).min(table.len() - 1);
        let weight = table[i] - if i == 0 { 0.0 } else { table[i - 1] };
        let prim = self.triangles[i];
        let p = triangle_positions(scene, prim)?;
        let (z, _) = hit_point_error(p, sample_uniform_triangle(v));
        let p_area = (weight / total) as f32 / self.areas[i];
        (p_area > 0.0 && p_area.is_finite()).then_some((prim, z, p_area))
    }

    /// The camera's end of a caustic path: the light-path vertex `p` (on triangle `prim`) seen by
    /// the camera ray through its image point, the path tracer's f there towards `toward` (the
    /// next vertex on the light's side), and the pixel it falls in with
    /// `beta · f · W · |cos| / d²`; `None` when the camera does not see `p` first, `p` is off the
    /// image or on a sharp material.
    #[inline(always)]
    fn connect(&self, eye: &Eye<'_>, stack: &mut TraversalStack, prim: u32, p: Vec3, toward: Vec3, beta: Vec3) -> Option<(u32, Vec3)> {
        let (integ, rays, (width, height)) = (eye.integ, eye.rays, eye.size);
        let scene = integ.scene;
        let (px, py, cos_c, dist_c) = rays.project(p)?;
        if !(px >= 0.0 && py >= 0.0 && px < width as f32 && py < height as f32) {
            return None;
        }
        let ray_c = rays.ray(px, py);
        let hit1 = integ.intersect_in(stack, &ray_c)?;
        if hit1.prim != prim && !((hit1.t - dist_c).abs() <= 1e-4 * dist_c) {
            return None;
        }
        let si1 = interaction(scene, &ray_c, &hit1);
        if self.vertices.is_sharp(si1.material) {
            return None;
        }
        let mat1 = scene.materials.get(si1.material as usize)?;
        let surf1 = integ.surface(mat1, &si1);
        let (frame1, bsdf1) = vertex_bsdf(scene, &si1, mat1, &surf1, -ray_c.direction);
        let origin1 = offset_ray_origin(si1.p, si1.p_err, si1.ng, si1.ng);
        let wi1 = (toward - origin1).normalize_or_zero();
        if !(wi1.dot(si1.ng) > 0.0) {
            return None;
        }
        let (f1, _) = bsdf1.evaluate_pdf(frame1.to_local(wi1));
        if !(f1.max_element() > 0.0) {
            return None;
        }
        let cos1_c = si1.ng.dot(-ray_c.direction).abs();
        let value = beta * f1 * (rays.pixel_density(cos_c) * cos1_c / (dist_c * dist_c));
        Some((py as u32 * width + px as u32, value))
    }
}

/// The camera's side of one view, shared by its light paths: the view's integrator, its camera
/// rays and its width and height.
struct Eye<'a> {
    integ: &'a PathIntegrator<'a>,
    rays: &'a SampleRays,
    size: (u32, u32),
}

/// The corners of triangle `t` (scene-local frame), `None` when an index is out of range or
/// a corner is not finite.
fn triangle_positions(scene: &Scene, t: u32) -> Option<[Vec3; 3]> {
    let m = &scene.mesh;
    let idx = m.indices.get(t as usize)?;
    let p = [m.positions.get(idx[0] as usize)?, m.positions.get(idx[1] as usize)?, m.positions.get(idx[2] as usize)?].map(|v| *v);
    p.iter().all(|v| v.is_finite()).then_some(p)
}

/// How strongly `light` can light a caster triangle with corners `p`, the weight it is drawn
/// with: zero exactly where the light cannot reach its front (a single-sided triangle seen from
/// behind, or one wholly outside a spot light's cone or a light's range); else, for a point or
/// spot light, the triangle's solid angle from it (Van Oosterom and Strackee 1983, in `f64`),
/// and for a directional light its area projected across the beam.
pub(crate) fn light_weight(light: &Light, p: [Vec3; 3], double_sided: bool) -> f64 {
    let [a, b, c] = p.map(|v| v.as_dvec3());
    let n = (b - a).cross(c - a);
    match *light {
        Light::Point { position, range, .. } | Light::Spot { position, range, .. } => {
            let q = position.as_dvec3();
            let side = n.dot(q - a);
            if !(side > 0.0 || (double_sided && side < 0.0)) {
                return 0.0;
            }
            // The triangle's bounding sphere about its centroid, for the range and cone tests.
            let centre = (a + b + c) / 3.0;
            let radius = [a, b, c].iter().map(|v| (*v - centre).length()).fold(0.0, f64::max);
            let to = centre - q;
            let dist = to.length();
            if range.is_some_and(|r| dist - radius > r as f64) {
                return 0.0;
            }
            if let Light::Spot { direction, outer_cone_angle, .. } = *light
                && dist > radius
            {
                let off_axis = (to.dot(direction.as_dvec3()) / dist).clamp(-1.0, 1.0).acos();
                let half = (radius / dist).asin();
                if off_axis - half > outer_cone_angle as f64 {
                    return 0.0;
                }
            }
            let (ra, rb, rc) = (a - q, b - q, c - q);
            let (la, lb, lc) = (ra.length(), rb.length(), rc.length());
            let num = ra.dot(rb.cross(rc)).abs();
            let den = la * lb * lc + ra.dot(rb) * lc + ra.dot(rc) * lb + rb.dot(rc) * la;
            let omega = 2.0 * num.atan2(den);
            if omega.is_finite() { omega.max(0.0) } else { 0.0 }
        }
        Light::Directional { direction, .. } => {
            // Light travelling along `direction` meets the front face where it opposes `n`.
            let facing = -n.dot(direction.as_dvec3());
            let projected = 0.5 * if double_sided { facing.abs() } else { facing.max(0.0) } / direction.as_dvec3().length().max(f64::MIN_POSITIVE);
            if projected.is_finite() { projected } else { 0.0 }
        }
    }
}

