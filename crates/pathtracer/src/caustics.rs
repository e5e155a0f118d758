//! Light tracing of caustic paths: the light a glossy object focuses from a punctual light
//! onto the surfaces the camera sees, estimated from the light's side.
//!
//! **Why.** A path `camera → x₁ → x₂ → punctual light` with a rough `x₁` (the surface the
//! camera sees) and a glossy `x₂` (a polished metal sphere) is found by the path tracer only
//! when the direction it samples at `x₁` happens to hit the small part of `x₂` whose mirror
//! image of the light falls towards `x₁`; such rare paths carry large weights. On the
//! committed scenes this one path class held most of the noise left in `tabletop` (its
//! images' variance fell by 85 % without it) and 40–60 % in `materials`. From the light's
//! side the same paths are easy: a ray from the light that hits the glossy object reflects
//! along its lobe onto `x₁`, which is then connected to the camera.
//!
//! **Which paths.** The path space is partitioned, so every path is estimated by exactly one
//! technique and no MIS weights are needed:
//! - a *caustic path* `camera → x₁ → … → x_n → punctual light` has `2 ≤ n ≤`
//!   [`MAX_CAUSTIC_VERTICES`] scattering vertices, `x_n` of a *caster* material and
//!   `x₁ … x_{n−1}` (`x₁` the first surface the camera ray hits) of materials that are not
//!   *sharp*;
//! - casters are materials whose specular lobe can be narrow and bright: GGX `α` below
//!   [`CASTER_ALPHA`] (roughness ≈ 0.32) and `F0 / α ≥` [`CASTER_F0_PER_ALPHA`]
//!   ([`is_caster`]); sharp materials are the metallic casters, whose whole reflection is
//!   that narrow lobe (the path tracer samples their reflections well, and a light tracer
//!   could not connect through them);
//! - the path tracer leaves out the punctual lights' next-event estimate at such an `x_n`
//!   ([`crate::integrator::PathIntegrator::caustics`], [`CausticPaths::is_caustic_vertex`]);
//!   the light tracer estimates exactly that term. Everything else (longer paths, emissive
//!   triangles, the environment) is unchanged.
//! - Paths of 3 and 4 vertices (a caustic seen after a diffuse bounce) held about a third of
//!   the variance left on `materials` after those of 2 (64×64, 64 spp, 16 seeds: 4.0e-4 →
//!   2.8e-4, for 2 % more time); on `tabletop` they made no difference.
//!
//! **The estimator.** Per view, `N = ⌈width · height · spp · LIGHT_PATHS_PER_SAMPLE⌉` light
//! paths: a punctual light in proportion to its intensity times the solid angle of the
//! casters from it (for a directional light, its illuminance times their cross-section); a
//! direction towards a caster's bounding sphere, uniform in the cone of spheres (a point
//! light; the sphere chosen in proportion to its solid angle) or a uniform point on a
//! sphere's cross-section disk (a directional light; chosen in proportion to the disk's
//! area); its first hit `z₁`, kept when it is a caster; then, for `j = 2, 3, …` up to
//! `min(max_bounces, MAX_CAUSTIC_VERTICES)`, a direction from `z_{j−1}`'s BSDF seen from the
//! light's side and its first hit `z_j`, the path ending at a sharp `z_j`. Each `z_j` in the
//! image whose camera ray hits it first is connected to the camera: the path
//! `camera → z_j → … → z₁ → light` of `j` vertices. Its value is computed as the path tracer
//! would compute it (the camera ray's hit, the shading frames and BSDFs seen from the
//! camera's side, [`crate::light::punctual_incidence`]) and its density converted to the path
//! tracer's measure: with `W = f_x f_y / cos³θ_c` the density of pixel sampling per steradian,
//! the contribution to the pixel `z_j` falls in is
//! `W · |cosᶜ| / d² · E / (P_light · A₁) · Π_{i<j} f_i · |cos_i| / (p_i · |cos'_{i+1}|) · f_j / N`,
//! where the `f` are the BSDFs times their shading cosines (`f_j` towards `z_{j−1}` seen from
//! the camera, `f_i` towards `z_{i−1}` or the light seen from `z_{i+1}`), `E` the light's
//! irradiance at `z₁`, `A₁` the area density of `z₁`, `p_i` the solid-angle density of the
//! direction sampled at `z_i`, `cos_i` and `cos'_{i+1}` the geometric cosines of the segment
//! `z_i z_{i+1}` at its two ends and `cosᶜ`, `d` those of the camera's segment at `z_j`.
//!
//! **Determinism.** Light path `k` of view `v` draws its numbers from
//! `Sampler::new(splitmix64(seed ⊕ CAUSTIC_SEED_KEY), v, 0, k)` (one stratified set per view);
//! paths are traced in fixed chunks in parallel and their contributions summed in `f64` in
//! path order, so the image is bit-identical for any thread count.
//!
//! **Known asymmetry.** The light path's segments are traced from the light's side, the path
//! tracer traces them from the camera's side. The two agree except where a
//! single-sided (back-face culled) triangle lies across a segment with its back to one end,
//! or a `Blend` triangle does (its stochastic coverage is drawn per ray): there the partition
//! is estimated with the light-side visibility.

// Negated comparisons (`!(x > 0.0)`) are deliberate: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use crate::accel::Hit;
use crate::geometry::{Frame, Ray, offset_ray_origin};
use crate::integrator::{PathIntegrator, interaction, vertex_bsdf};
use crate::light::punctual_incidence;
use crate::material::{MIN_ALPHA, max_dielectric_f0, min_roughness_texel, resolve};
use crate::render::SampleRays;
use crate::sampler::{Sampler, sample_concentric_disk, splitmix64};
use crate::scene::{Light, Material, Scene, Texture};
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::f32::consts::PI;

/// GGX `α` below which a reflecting material can be a caster (roughness ≈ 0.32), see
/// [`is_caster`].
pub const CASTER_ALPHA: f32 = 0.1;
/// Least `F0 / α` of a caster (see [`is_caster`]).
pub const CASTER_F0_PER_ALPHA: f32 = 2.0;
/// Light paths per camera sample of a view (when the scene has casters and punctual lights).
/// Measured on `tabletop` and `materials` (64×64, 64 spp, 16 seeds; variance of a render
/// over the pixels less the noisiest 0.1 %, times its time): 0.0625, 0.125 and 0.25 were
/// within 15 % of each other and 4.1–4.6x (`tabletop`), 2.0–2.1x (`materials`) better than the
/// path tracer alone; 0.5 and 1 cost more time than they removed noise.
pub const LIGHT_PATHS_PER_SAMPLE: f64 = 0.125;
/// Most caster spheres kept: more glossy objects are grouped by position into that many.
pub const MAX_CASTERS: usize = 16;
/// Sampler seed key of the light paths (`splitmix64(seed ^ CAUSTIC_SEED_KEY)`).
pub const CAUSTIC_SEED_KEY: u64 = 0x6361_7573_7469_6373;
/// Most vertices of a caustic path (the caster included): longer ones stay with the path
/// tracer.
pub const MAX_CAUSTIC_VERTICES: u32 = 4;
/// Light paths per parallel task.
const CHUNK: u64 = 4096;
/// Tasks whose splats are held at once.
const BATCH_CHUNKS: u64 = 64;

/// Whether a material is a caster: its specular lobe can be narrow (GGX `α`, from the
/// roughness factor × the smallest G of its metallic-roughness texture, below
/// [`CASTER_ALPHA`]) and bright for its width (`F0 / α ≥` [`CASTER_F0_PER_ALPHA`], `F0` the
/// largest normal-incidence reflectance it can have: the base colour factor where it can be
/// metallic, else the dielectric layer's).
///
/// Why the second rule: the path tracer's variance for a caustic grows like `(F0 / α)²` (the
/// lobe's brightness squared over the solid angle it is found in), while the light tracer's
/// cost is the same for every caster. A dielectric's 4 % layer is a caster only below
/// `α = 0.02` (roughness 0.14): on `deep`, whose globe (α 0.04, F0 0.04) was one, tracing its
/// caustic cost 14 % of the render time and left its error unchanged.
pub fn is_caster(material: &Material, textures: &[Texture]) -> bool {
    let dielectric = max_dielectric_f0(material) * material.specular_factor.max(0.0);
    let f0 = if material.metallic_factor > 0.0 { material.base_color_factor.truncate().max_element().max(dielectric) } else { dielectric };
    if !(f0 > 0.0) {
        return false;
    }
    let r = (material.roughness_factor * min_roughness_texel(material, textures)).clamp(0.0, 1.0);
    let alpha = (r * r).max(MIN_ALPHA);
    alpha < CASTER_ALPHA && f0 >= CASTER_F0_PER_ALPHA * alpha
}

/// Whether a caster is sharp: metallic, so that its whole reflection is the narrow lobe.
pub fn is_sharp(material: &Material, textures: &[Texture]) -> bool {
    material.metallic_factor > 0.0 && is_caster(material, textures)
}

/// One punctual light as the light tracer samples it.
#[derive(Clone, Debug)]
struct Emitter {
    light: usize,
    /// Cones from a point or spot light towards the casters' spheres: axis, `cos θmax`,
    /// `1 − cos θmax`, and the running sum of their solid angles.
    cones: Vec<(Vec3, f32, f32, f32)>,
    /// Directional light: running sums of the spheres' cross-section areas `π r²`.
    disks: Vec<f32>,
}

/// The caustic light tracer of one scene (see the module docs).
#[derive(Clone, Debug, Default)]
pub struct CausticPaths {
    caster: Vec<bool>,
    sharp: Vec<bool>,
    spheres: Vec<(Vec3, f32)>,
    emitters: Vec<Emitter>,
    /// Inclusive running sums of the emitters' selection weights, normalised.
    cdf: Vec<f32>,
    /// Centre and radius of a sphere around the scene's triangles ([`Scene::bounds`]):
    /// directional light rays start outside it.
    scene_sphere: (Vec3, f32),
}

impl CausticPaths {
    /// The casters, their bounding spheres and the punctual lights that can reach them.
    pub fn build(scene: &Scene) -> Self {
        let caster: Vec<bool> = scene.materials.iter().map(|m| is_caster(m, &scene.textures)).collect();
        let sharp: Vec<bool> = scene.materials.iter().map(|m| is_sharp(m, &scene.textures)).collect();
        let spheres = group(caster_spheres(scene, &caster));
        let b = &scene.bounds;
        let scene_sphere = if b.is_empty() { (Vec3::ZERO, 0.0) } else { (b.center(), 0.5 * b.diagonal()) };
        let mut emitters = Vec::new();
        let mut weights = Vec::new();
        if !spheres.is_empty() {
            for (k, light) in scene.lights.iter().enumerate() {
                let (e, w) = match *light {
                    Light::Point { position, intensity, .. } | Light::Spot { position, intensity, .. } => {
                        let cones = cones_from(position, &spheres);
                        let total = cones.last().map_or(0.0, |c| c.3);
                        (Emitter { light: k, cones, disks: Vec::new() }, intensity.max_element() * total)
                    }
                    Light::Directional { illuminance, .. } => {
                        let mut acc = 0.0f32;
                        let disks = spheres
                            .iter()
                            .map(|&(_, r)| {
                                acc += PI * r * r;
                                acc
                            })
                            .collect();
                        (Emitter { light: k, cones: Vec::new(), disks }, illuminance.max_element() * acc)
                    }
                };
                if w.is_finite() && w > 0.0 {
                    emitters.push(e);
                    weights.push(w as f64);
                }
            }
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
        Self { caster, sharp, spheres, emitters, cdf, scene_sphere }
    }

    /// Whether material `m` is sharp (a light path stops there; a caustic path has none
    /// before its caster).
    #[inline]
    pub fn is_sharp(&self, m: u32) -> bool {
        self.sharp.get(m as usize).copied().unwrap_or(true)
    }

    /// Whether the path tracer leaves out the punctual lights' estimate at its vertex
    /// `vertex` (1-based: the camera ray's hit is vertex 1) of material `m`, when every vertex
    /// before it is not sharp: a caustic path of `vertex` vertices, which the light tracer
    /// estimates.
    #[inline]
    pub fn is_caustic_vertex(&self, vertex: u32, m: u32) -> bool {
        (2..=MAX_CAUSTIC_VERTICES).contains(&vertex) && self.is_caster(m)
    }

    /// The casters' bounding spheres (centre, radius; scene-local frame).
    pub fn spheres(&self) -> &[(Vec3, f32)] {
        &self.spheres
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
        let key = Sampler::new(splitmix64(seed ^ CAUSTIC_SEED_KEY), view, 0, 0);
        let max_vertices = integ.settings.max_bounces.min(MAX_CAUSTIC_VERTICES);
        let mut nonfinite = 0u64;
        let inv = 1.0 / n as f64;
        // Chunks in parallel, a bounded batch at a time (the splats of a 800×800, 128 spp
        // view would otherwise be held at once), summed in path order.
        let chunks = n.div_ceil(CHUNK);
        for batch in (0..chunks).step_by(BATCH_CHUNKS as usize) {
            let splats: Vec<Vec<(u32, Vec3)>> = (batch..(batch + BATCH_CHUNKS).min(chunks))
                .into_par_iter()
                .map(|c| {
                    let mut out = Vec::new();
                    for k in c * CHUNK..((c + 1) * CHUNK).min(n) {
                        self.trace(&eye, max_vertices, &key.with_sample(k as u32), &mut out);
                    }
                    out
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

    /// One light path: the pixels its vertices after the caster land in, with their values
    /// (times `N`), pushed to `out`.
    fn trace(&self, eye: &Eye<'_>, max_vertices: u32, sampler: &Sampler, out: &mut Vec<(u32, Vec3)>) {
        let integ = eye.integ;
        let scene = integ.scene;
        // The light, in proportion to its weight.
        let u_light = sampler.get_1d(0);
        let e = self.cdf.iter().position(|&c| u_light < c).unwrap_or(self.cdf.len() - 1);
        let p_light = self.cdf[e] - if e == 0 { 0.0 } else { self.cdf[e - 1] };
        let emitter = &self.emitters[e];
        let light = &scene.lights[emitter.light];
        // A ray towards the casters, and the density of its first hit per unit area, less the
        // cosine there: per steradian at the light / distance² (point, spot), or per unit
        // area across the beam (directional).
        let u = sampler.get_2d(1);
        let (ray_l, density, infinite) = match *light {
            Light::Point { position, .. } | Light::Spot { position, .. } => {
                let d = sample_cones(&emitter.cones, u);
                let Some(&(.., total)) = emitter.cones.last() else { return };
                let count = emitter.cones.iter().filter(|c| d.dot(c.0) >= c.1).count();
                (Ray::new(position, d), count as f32 / total, false)
            }
            Light::Directional { direction, .. } => {
                let d = direction.normalize_or_zero();
                let Some(&total) = emitter.disks.last() else { return };
                let (k, v) = pick(&emitter.disks, u.x);
                let (centre, r) = self.spheres[k];
                let frame = Frame::from_normal(d);
                let q = sample_concentric_disk(Vec2::new(v, u.y)) * r;
                let on_disk = centre + frame.s * q.x + frame.t * q.y;
                let back = (self.scene_sphere.0 - on_disk).length() + self.scene_sphere.1 + r;
                let origin = on_disk - d * (2.0 * back + 1.0);
                let count = self
                    .spheres
                    .iter()
                    .filter(|(c, r)| {
                        let v = *c - on_disk;
                        (v - d * v.dot(d)).length_squared() <= r * r
                    })
                    .count();
                (Ray::new(origin, d), count as f32 / total, true)
            }
        };
        let Some(hit) = integ.intersect(&ray_l) else { return };
        let si = interaction(scene, &ray_l, &hit);
        if !self.is_caster(si.material) {
            return;
        }
        let cos_l = si.ng.dot(ray_l.direction).abs();
        let area = if infinite { density * cos_l } else { density * cos_l / (hit.t * hit.t) };
        let Some(inc) = punctual_incidence(light, si.p) else { return };
        let denom = p_light * area;
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
            let surf = resolve(mat, &scene.textures, &cur_si.attr);
            let (frame_l, bsdf_l) = vertex_bsdf(scene, &cur_si, mat, &surf, -arrival);
            let Some(bs) = bsdf_l.sample(sampler.get_2d(3 + 2 * (j - 2))) else { return };
            let wb = frame_l.to_world(bs.wi).normalize();
            if !(wb.dot(cur_si.ng) > 0.0) {
                return;
            }
            let ray_b = Ray::new(offset_ray_origin(cur_si.p, cur_si.p_err, cur_si.ng, cur_si.ng), wb);
            let Some(next) = integ.intersect(&ray_b) else { return };
            let next_si = interaction(scene, &ray_b, &next);
            if self.is_sharp(next_si.material) {
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
            if let Some(splat) = self.connect(eye, next.prim, p_next, cur_pt.p, beta) {
                out.push(splat);
            }
            (cur, cur_si, arrival, toward_prev) = (next, next_si, wb, -wb);
        }
    }

    /// Whether material `m` is a caster.
    #[inline]
    fn is_caster(&self, m: u32) -> bool {
        self.caster.get(m as usize).copied().unwrap_or(false)
    }

    /// The camera's end of a caustic path: the light-path vertex `p` (on triangle `prim`) seen by
    /// the camera ray through its image point, the path tracer's f there towards `toward` (the
    /// next vertex on the light's side), and the pixel it falls in with
    /// `beta · f · W · |cos| / d²`; `None` when the camera does not see `p` first, `p` is off the
    /// image or on a sharp material.
    fn connect(&self, eye: &Eye<'_>, prim: u32, p: Vec3, toward: Vec3, beta: Vec3) -> Option<(u32, Vec3)> {
        let (integ, rays, (width, height)) = (eye.integ, eye.rays, eye.size);
        let scene = integ.scene;
        let (px, py, cos_c, dist_c) = rays.project(p)?;
        if !(px >= 0.0 && py >= 0.0 && px < width as f32 && py < height as f32) {
            return None;
        }
        let ray_c = rays.ray(px, py);
        let hit1 = integ.intersect(&ray_c)?;
        if hit1.prim != prim && !((hit1.t - dist_c).abs() <= 1e-4 * dist_c) {
            return None;
        }
        let si1 = interaction(scene, &ray_c, &hit1);
        if self.is_sharp(si1.material) {
            return None;
        }
        let mat1 = scene.materials.get(si1.material as usize)?;
        let surf1 = resolve(mat1, &scene.textures, &si1.attr);
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

/// The running sums `cdf` and a uniform `u`: the chosen index and `u` rescaled within it.
fn pick(cdf: &[f32], u: f32) -> (usize, f32) {
    let total = cdf[cdf.len() - 1];
    let x = u * total;
    let k = cdf.iter().position(|&c| x < c).unwrap_or(cdf.len() - 1);
    let lo = if k == 0 { 0.0 } else { cdf[k - 1] };
    let width = cdf[k] - lo;
    (k, if width > 0.0 { ((x - lo) / width).clamp(0.0, 1.0 - f32::EPSILON) } else { 0.5 })
}

/// The cones from `p` towards `spheres`: axis, `cos θmax`, `1 − cos θmax` and the running
/// sum of their solid angles; a sphere holding `p` is the whole sphere of directions.
fn cones_from(p: Vec3, spheres: &[(Vec3, f32)]) -> Vec<(Vec3, f32, f32, f32)> {
    let mut total = 0.0f32;
    spheres
        .iter()
        .filter_map(|&(c, r)| {
            let d = c - p;
            let dist2 = d.length_squared();
            let (axis, cos_max, omc) = if dist2 <= r * r || !(dist2 > 0.0) {
                (Vec3::Z, -1.0, 2.0)
            } else {
                let sin2 = r * r / dist2;
                let cos_max = (1.0 - sin2).sqrt();
                (d / dist2.sqrt(), cos_max, sin2 / (1.0 + cos_max))
            };
            let omega = 2.0 * PI * omc;
            if !(omega > 0.0) || !axis.is_finite() {
                return None;
            }
            total += omega;
            Some((axis, cos_max, omc, total))
        })
        .collect()
}

/// A direction uniform in one of `cones`, the cone chosen in proportion to its solid angle.
fn sample_cones(cones: &[(Vec3, f32, f32, f32)], u: Vec2) -> Vec3 {
    let sums: Vec<f32> = cones.iter().map(|c| c.3).collect();
    let (k, v) = pick(&sums, u.x);
    let (axis, _, omc, _) = cones[k];
    // cos θ = 1 − v (1 − cos θmax); sin² θ = a (2 − a) with a = v (1 − cos θmax).
    let a = v * omc;
    let cos_t = 1.0 - a;
    let sin_t = (a * (2.0 - a)).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Frame::from_normal(axis).to_world(Vec3::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t)).normalize()
}

fn find(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        let g = parent[parent[i as usize] as usize];
        parent[i as usize] = g;
        i = g;
    }
    i
}

fn union(parent: &mut [u32], a: u32, b: u32) {
    let (ra, rb) = (find(parent, a), find(parent, b));
    if ra != rb {
        // The smaller root wins, so the result does not depend on the order of the unions.
        let (lo, hi) = if ra < rb { (ra, rb) } else { (rb, ra) };
        parent[hi as usize] = lo;
    }
}

/// Bounding spheres of the casters' objects: their triangles joined along edges and where
/// vertices share a position (meshes split at seams or flat-shaded), in order of each
/// object's first vertex.
fn caster_spheres(scene: &Scene, caster: &[bool]) -> Vec<(Vec3, f32)> {
    let m = &scene.mesh;
    let nv = m.positions.len();
    let is_caster = |t: usize| m.material.get(t).and_then(|&k| caster.get(k as usize)).copied().unwrap_or(false);
    let mut parent: Vec<u32> = (0..nv as u32).collect();
    let mut used = vec![false; nv];
    for (t, tri) in m.indices.iter().enumerate() {
        if !is_caster(t) || tri.iter().any(|&i| i as usize >= nv || !m.positions[i as usize].is_finite()) {
            continue;
        }
        for &i in tri {
            used[i as usize] = true;
        }
        union(&mut parent, tri[0], tri[1]);
        union(&mut parent, tri[0], tri[2]);
    }
    let mut by_position: Vec<u32> = (0..nv as u32).filter(|&i| used[i as usize]).collect();
    let key = |i: u32| m.positions[i as usize].to_array().map(f32::to_bits);
    by_position.sort_unstable_by_key(|&i| (key(i), i));
    for w in by_position.windows(2) {
        if key(w[0]) == key(w[1]) {
            union(&mut parent, w[0], w[1]);
        }
    }
    let mut slot = vec![u32::MAX; nv];
    let mut boxes: Vec<(Vec3, Vec3)> = Vec::new();
    for i in (0..nv).filter(|&i| used[i]) {
        let r = find(&mut parent, i as u32) as usize;
        let p = m.positions[i];
        if slot[r] == u32::MAX {
            slot[r] = boxes.len() as u32;
            boxes.push((p, p));
        } else {
            let b = &mut boxes[slot[r] as usize];
            b.0 = b.0.min(p);
            b.1 = b.1.max(p);
        }
    }
    let mut spheres: Vec<(Vec3, f32)> = boxes.iter().map(|&(lo, hi)| (0.5 * (lo + hi), 0.0)).collect();
    for i in (0..nv).filter(|&i| used[i]) {
        let r = find(&mut parent, i as u32) as usize;
        let s = &mut spheres[slot[r] as usize];
        // Padded by a few ulps of the coordinates so that rounding never leaves a vertex out.
        let pad = 4.0 * f32::EPSILON * m.positions[i].abs().max_element().max(s.0.abs().max_element());
        s.1 = s.1.max((m.positions[i] - s.0).length() + pad);
    }
    spheres
}

/// At most [`MAX_CASTERS`] spheres: more are sorted along a Morton curve of their centres and
/// cut into that many runs of consecutive spheres, each run bounded by one sphere.
fn group(spheres: Vec<(Vec3, f32)>) -> Vec<(Vec3, f32)> {
    let spheres: Vec<(Vec3, f32)> = spheres.into_iter().filter(|(c, r)| c.is_finite() && r.is_finite()).collect();
    if spheres.len() <= MAX_CASTERS {
        return spheres;
    }
    let (lo, hi) = spheres.iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), (c, _)| (lo.min(*c), hi.max(*c)));
    let ext = (hi - lo).max(Vec3::splat(f32::MIN_POSITIVE));
    let morton = |c: Vec3| {
        let q = ((c - lo) / ext * 1023.0).clamp(Vec3::ZERO, Vec3::splat(1023.0)).as_uvec3();
        let spread = |mut x: u32| {
            x &= 0x3ff;
            x = (x | (x << 16)) & 0x030000ff;
            x = (x | (x << 8)) & 0x0300f00f;
            x = (x | (x << 4)) & 0x030c30c3;
            (x | (x << 2)) & 0x09249249
        };
        spread(q.x) | (spread(q.y) << 1) | (spread(q.z) << 2)
    };
    let mut order: Vec<(u32, usize)> = spheres.iter().enumerate().map(|(i, (c, _))| (morton(*c), i)).collect();
    order.sort_unstable();
    let n = order.len();
    (0..MAX_CASTERS)
        .map(|g| {
            let run = &order[g * n / MAX_CASTERS..(g + 1) * n / MAX_CASTERS];
            let (blo, bhi) = run.iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(a, b), &(_, i)| {
                let (c, r) = spheres[i];
                (a.min(c - Vec3::splat(r)), b.max(c + Vec3::splat(r)))
            });
            let centre = 0.5 * (blo + bhi);
            let radius = run.iter().map(|&(_, i)| (spheres[i].0 - centre).length() + spheres[i].1).fold(0.0f32, f32::max);
            (centre, radius * (1.0 + 4.0 * f32::EPSILON))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn uniform(state: &mut u64) -> f32 {
        *state = splitmix64(*state);
        (*state >> 40) as f32 / (1u64 << 24) as f32
    }

    /// The density of [`sample_cones`] is `count / Σ Ω`: it integrates to one over the sphere,
    /// every sample lies in a cone, and `E[1 / pdf]` over the samples is the solid angle of the
    /// cones' union (measured independently by uniform sphere sampling).
    #[test]
    fn cone_sampling_density_integrates_to_one_and_matches_its_samples() {
        let spheres = [(Vec3::new(0.0, 0.0, 3.0), 1.0), (Vec3::new(0.5, 0.2, 2.5), 0.6), (Vec3::new(-2.0, 0.0, 1.0), 0.3)];
        let cones = cones_from(Vec3::ZERO, &spheres);
        let total = cones.last().unwrap().3;
        let pdf = |d: Vec3| cones.iter().filter(|c| d.dot(c.0) >= c.1).count() as f64 / total as f64;
        let (mut s, n) = (7u64, 400_000);
        let (mut integral, mut union) = (0.0f64, 0.0f64);
        for _ in 0..n {
            let z = 1.0 - 2.0 * uniform(&mut s);
            let phi = 2.0 * PI * uniform(&mut s);
            let r = (1.0 - z * z).max(0.0).sqrt();
            let p = pdf(Vec3::new(r * phi.cos(), r * phi.sin(), z));
            integral += p;
            union += (p > 0.0) as u32 as f64;
        }
        let sphere = 4.0 * std::f64::consts::PI / n as f64;
        let (integral, union) = (integral * sphere, union * sphere);
        assert!((integral - 1.0).abs() < 0.02, "∫ pdf = {integral}");
        let m = 200_000;
        let mut est = 0.0f64;
        for _ in 0..m {
            let d = sample_cones(&cones, Vec2::new(uniform(&mut s), uniform(&mut s)));
            assert!((d.length() - 1.0).abs() < 1e-5);
            let p = pdf(d);
            assert!(p > 0.0, "a sample outside every cone: {d}");
            est += 1.0 / p;
        }
        let est = est / m as f64;
        assert!((est - union).abs() < 0.02 * union, "E[1/pdf] = {est}, the union's solid angle {union}");
        // A light inside a sphere: the whole sphere of directions, uniformly.
        let inside = cones_from(Vec3::new(0.0, 0.0, 2.8), &spheres[..1]);
        assert!((inside[0].3 - 4.0 * PI).abs() < 1e-4 && inside[0].1 == -1.0);
    }

    #[test]
    fn casters_are_narrow_bright_lobes_and_sharp_ones_are_metal() {
        let m = |metallic: f32, roughness: f32| Material { metallic_factor: metallic, roughness_factor: roughness, ..Material::gltf_default() };
        // Metals: narrow enough (α < 0.1) is bright enough.
        assert!(is_caster(&m(1.0, 0.05), &[]) && is_sharp(&m(1.0, 0.05), &[]));
        assert!(is_caster(&m(1.0, 0.3), &[]));
        assert!(!is_caster(&m(1.0, 0.35), &[]));
        // A dark metal's lobe is dim: F0 0.05 needs α ≤ 0.025.
        let dark = Material { base_color_factor: glam::Vec4::new(0.05, 0.05, 0.05, 1.0), ..m(1.0, 0.2) };
        assert!(!is_caster(&dark, &[]));
        // Dielectrics (F0 0.04): only below α = 0.02 (roughness 0.14), and never sharp.
        assert!(is_caster(&m(0.0, 0.05), &[]) && !is_sharp(&m(0.0, 0.05), &[]));
        assert!(!is_caster(&m(0.0, 0.2), &[]));
        // No specular layer, no caster.
        assert!(!is_caster(&Material { specular_factor: 0.0, ..m(0.0, 0.0) }, &[]));
    }

    #[test]
    fn many_casters_are_grouped_into_spheres_that_bound_them() {
        let mut s = 3u64;
        let spheres: Vec<(Vec3, f32)> =
            (0..100).map(|_| (Vec3::new(uniform(&mut s), uniform(&mut s), uniform(&mut s)) * 10.0, 0.1 + uniform(&mut s) * 0.2)).collect();
        let groups = group(spheres.clone());
        assert_eq!(groups.len(), MAX_CASTERS);
        for (c, r) in &spheres {
            assert!(groups.iter().any(|(gc, gr)| (*c - *gc).length() + r <= *gr), "sphere {c} {r} is in no group");
        }
    }
}
