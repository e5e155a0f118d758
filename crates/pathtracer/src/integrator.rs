//! The integrator: the radiance arriving along ONE ray. Tiling, parallelism and accumulation
//! live in [`crate::render`].
//!
//! [`PathIntegrator::radiance`] is a unidirectional path tracer:
//! - Next-event estimation at every vertex: every punctual light deterministically (delta
//!   lights, no MIS), one sample of the emissive triangles and, for an environment map, one of
//!   the environment, each combined with BSDF sampling by multiple importance sampling with the
//!   power heuristic `w = p_a² / (p_a² + p_b²)` (Veach 1997). A BSDF-sampled ray that hits an
//!   emitter or escapes to an environment map adds the complementary MIS-weighted term; a
//!   constant environment is reached by BSDF sampling alone (weight 1).
//! - `max_bounces` counts scattering events: 0 shows emitters and the environment only,
//!   1 is direct lighting, `n` adds paths with up to `n` surface reflections.
//! - Russian roulette from the third vertex on, with survival probability
//!   `min(1, ROULETTE_SCALE · max throughput component)` ([`ROULETTE_SCALE`]).
//! - Caustic paths (camera → 1 to 3 surfaces that are not sharp → a caster → a punctual light)
//!   are left to the light tracer of [`crate::caustics`] when [`PathIntegrator::caustics`] is
//!   set: at such a caster vertex the punctual lights' estimate is skipped.
//! - Camera rays that miss return the environment radiance, or zero with `primary_hit =
//!   false` when the background is transparent (the environment still lights the scene).
//!   An environment map is sampled with its own density ([`Environment::sample`] /
//!   [`Environment::pdf`]) and MIS-combined like the emitters.
//! - Shading: BSDFs are evaluated in [`shading_frame`] around the interpolated normal,
//!   perturbed by the material's normal map ([`normal_mapped`], with the asset's TANGENT or a
//!   per-triangle tangent from the normal map's UV set, [`triangle_tangent`]) and bent
//!   towards the viewer when it faces away. The ground-truth normal ([`Interaction::n`])
//!   is the interpolated normal without the normal map.
//! - Alpha: `Mask` cuts where alpha < cutoff; `Blend` is stochastic coverage: a ray passes
//!   through a blended triangle when `hash(ray, triangle) ≥ alpha` ([`alpha_test`]), so the
//!   decision is deterministic per ray and coverage averages to alpha over rays. Light
//!   sampled on a blended emitter is weighted by its alpha (the expected coverage).
//!
//! Batches: [`PathIntegrator::radiance_batch`] advances a pixel's camera samples together, a
//! vertex at a time, with the BSDF samples and the BSDF values towards the light samples
//! computed in loops over lanes (the same bits as one path alone); a batch's camera rays (and
//! its camera vertices' shadow rays, grouped by light) go as packets where it holds at least
//! `PACKET_MIN_RAYS`. Where every material is uniform and has no normal map, module `lanes`
//! shades whole vertices eight paths at a time.
//!
//! Shadow and bounce rays start at [`offset_ray_origin`] so they neither re-hit their own
//! surface nor leak through it; shadow rays to a point stop `1e-4` (relative) short of it.
//! Why these choices, and the estimators tried instead: `docs/renderer.md`, `docs/experiments.md`.

// Negated comparisons (`!(x > 0.0)`) are deliberate: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use crate::accel::{Accel, Hit, TraversalStack};
use crate::caustic_partition::CausticVertices;
use crate::geometry::{Frame, Ray, hit_point_error, offset_ray_origin};
use crate::light::{EmissiveTriangles, Environment, punctual_incidence};
use crate::material::{Bsdf, BsdfAt, BsdfSample, SurfaceAttributes, evaluate_many, sample_many, SurfaceMaterial, base_color, emission, facing_normals, normal_mapped, normal_mapped_by, resolve, shading_frame, triangle_tangent};
use crate::sampler::{Sampler, power_heuristic, splitmix64};
use crate::scene::{AlphaMode, Material, Scene};
use glam::{Vec2, Vec3, Vec4};

mod lanes;
pub use lanes::LaneMaterials;

/// Where each of a path vertex's numbers lies in its block of sampler dimensions: a spare
/// number for the emitter point (1, used only where the picked triangle's share of the
/// emitted power is too small to reuse the choice's number, see
/// [`EmissiveTriangles::sample`]), emitter choice and point (2), environment (2), BSDF (2),
/// Russian roulette (1).
const DIM_EMITTER_SPARE: u32 = 0;
const DIM_EMITTER_POINT: u32 = 1;
const DIM_ENVIRONMENT: u32 = 3;
const DIM_BSDF: u32 = 5;
const DIM_ROULETTE: u32 = 7;
/// Sampler dimensions every path vertex reserves (the block above).
const VERTEX_DIMENSIONS: u32 = DIM_ROULETTE + 1;

/// Fewest camera rays in a batch (a pixel's samples) traced as one packet
/// ([`PathIntegrator::intersect_many`]); smaller batches trace theirs one at a time (the same
/// bits). Packets pay from about 32 rays on (`docs/experiments.md`).
const PACKET_MIN_RAYS: usize = 32;

/// Russian roulette's survival probability over the path's largest throughput component
/// (capped at 1). pbrt and Mitsuba use 1; 2 keeps paths whose throughput is between ½ and 1
/// alive, which lowers a render's variance × time on every committed scene (the figures, and
/// Mitsuba's `min(0.95, …)` rule tried instead: `docs/experiments.md`).
pub const ROULETTE_SCALE: f32 = 2.0;

/// Fraction of a shadow ray's length left unchecked at its far end (pbrt's ShadowEpsilon).
pub const SHADOW_EPSILON: f32 = 1e-4;

/// The integrator's settings.
#[derive(Clone, Debug, PartialEq)]
pub struct IntegratorSettings {
    /// Maximum number of scattering events along a path.
    pub max_bounces: u32,
    /// The environment (lights the scene; seen by camera misses unless transparent).
    pub environment: Environment,
    /// Camera rays that miss return zero radiance (alpha 0) instead of the environment.
    pub transparent_background: bool,
}

/// The radiance along one camera ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RadianceSample {
    /// Linear RGB radiance.
    pub radiance: Vec3,
    /// Whether the camera ray hit geometry.
    pub primary_hit: bool,
}

/// A surface point with everything shading needs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Interaction {
    /// Triangle index.
    pub prim: u32,
    /// Hit point (local frame) from the barycentrics.
    pub p: Vec3,
    /// Per-component absolute error bound of `p`.
    pub p_err: Vec3,
    /// Unit geometric normal, flipped to face the incoming ray.
    pub ng: Vec3,
    /// Unit geometric normal of the front face (counter-clockwise side).
    pub ng_front: Vec3,
    /// Unit interpolated normal on the side of the incoming ray (the ground-truth normal; the
    /// integrator's shading frame is built from it, or from the normal map, per vertex).
    pub n: Vec3,
    /// Unit interpolated normal on the front side (not flipped).
    pub ns_front: Vec3,
    /// Barycentrics of the hit.
    pub b: [f32; 3],
    /// Interpolated texture coordinates and vertex colour.
    pub attr: SurfaceAttributes,
    /// Material index.
    pub material: u32,
}

/// Interpolated texture coordinates and vertex colour of triangle `prim` at barycentrics `b`
/// (attributes missing from the mesh take glTF defaults: UV 0, colour white).
#[inline]
pub fn surface_attributes(scene: &Scene, prim: u32, b: [f32; 3]) -> SurfaceAttributes {
    let m = &scene.mesh;
    let idx = m.indices[prim as usize];
    // A missing attribute skips the lookups: UVs are then exactly 0 (the bits of
    // interpolating the default) and the colour exactly white (the value of interpolating
    // the default, without the rounding of `b₀ + b₁ + b₂`), so that an untextured material
    // is the same at every point ([`crate::material::uniform_surface`]).
    let lerp2 = |v: &Vec<Vec2>| {
        if v.is_empty() {
            return Vec2::ZERO;
        }
        (0..3).fold(Vec2::ZERO, |acc, k| acc + b[k] * v.get(idx[k] as usize).copied().unwrap_or(Vec2::ZERO))
    };
    let color = if m.colors.is_empty() {
        Vec4::ONE
    } else {
        (0..3).fold(Vec4::ZERO, |acc, k| acc + b[k] * m.colors.get(idx[k] as usize).copied().unwrap_or(Vec4::ONE))
    };
    SurfaceAttributes { uv: [lerp2(&m.uv0), lerp2(&m.uv1)], color }
}

/// A uniform number in `[0, 1)` that is a pure function of a ray and a triangle (SplitMix64
/// over the bits of origin, direction and triangle index): the coin of stochastic `Blend`
/// coverage.
pub fn blend_hash(ray: &Ray, prim: u32) -> f32 {
    let mut h = splitmix64(prim as u64);
    for x in [ray.origin.x, ray.origin.y, ray.origin.z, ray.direction.x, ray.direction.y, ray.direction.z] {
        h = splitmix64(h ^ x.to_bits() as u64);
    }
    (h >> 40) as f32 * (1.0 / 16_777_216.0)
}

/// Whether the triangle `prim` is present at barycentrics `b` for `ray`: `Mask`: base-colour
/// alpha (factor × texture × vertex colour) ≥ cutoff; `Blend`: `blend_hash(ray, prim) <
/// alpha` (present with probability alpha); `Opaque`: always.
#[inline]
pub fn alpha_test(scene: &Scene, ray: &Ray, prim: u32, b: [f32; 3]) -> bool {
    let Some(mat) = scene.mesh.material.get(prim as usize).and_then(|&m| scene.materials.get(m as usize)) else { return true };
    match mat.alpha_mode {
        AlphaMode::Mask { cutoff } => {
            let attr = surface_attributes(scene, prim, b);
            base_color(mat, &scene.textures, &attr).w >= cutoff
        }
        AlphaMode::Blend => {
            let attr = surface_attributes(scene, prim, b);
            blend_hash(ray, prim) < base_color(mat, &scene.textures, &attr).w
        }
        AlphaMode::Opaque => true,
    }
}

/// The tangent (xyz, handedness w) at a hit for normal mapping: the interpolated asset
/// TANGENT when all three vertices have one, else [`triangle_tangent`] from the UV set
/// `tex_coord`; zero when neither exists.
pub fn tangent_at(scene: &Scene, prim: u32, b: [f32; 3], tex_coord: u32, n: Vec3) -> Vec4 {
    let m = &scene.mesh;
    let idx = m.indices[prim as usize];
    let t = idx.map(|i| m.tangents.get(i as usize).copied().unwrap_or(Vec4::ZERO));
    if t.iter().all(|v| v.truncate().length_squared() > 0.0) {
        let xyz = (0..3).fold(Vec3::ZERO, |acc, k| acc + b[k] * t[k].truncate());
        return xyz.extend(if t[0].w < 0.0 { -1.0 } else { 1.0 });
    }
    let uvs = if tex_coord == 1 { &m.uv1 } else { &m.uv0 };
    let uv = idx.map(|i| uvs.get(i as usize).copied().unwrap_or(Vec2::ZERO));
    let p = idx.map(|i| m.positions[i as usize]);
    triangle_tangent(p, uv, n).unwrap_or(Vec4::ZERO)
}

/// Builds the [`Interaction`] for `hit` of `ray` (hit point from barycentrics, normals
/// facing the ray).
#[inline(always)]
pub fn interaction(scene: &Scene, ray: &Ray, hit: &Hit) -> Interaction {
    let m = &scene.mesh;
    let idx = m.indices[hit.prim as usize];
    let g = hit_geometry(idx.map(|i| m.positions[i as usize]), idx.map(|i| m.normals.get(i as usize).copied().unwrap_or(Vec3::ZERO)), hit.b, ray.direction);
    Interaction {
        prim: hit.prim,
        p: g.p,
        p_err: g.p_err,
        ng: g.ng,
        ng_front: g.ng_front,
        n: g.n,
        ns_front: g.ns_front,
        b: hit.b,
        attr: surface_attributes(scene, hit.prim, hit.b),
        material: m.material.get(hit.prim as usize).copied().unwrap_or(0),
    }
}

/// The geometric part of an [`Interaction`] (its fields of the same names).
#[derive(Clone, Copy, Debug)]
pub(crate) struct HitGeometry {
    pub(crate) p: Vec3,
    pub(crate) p_err: Vec3,
    pub(crate) ng: Vec3,
    pub(crate) ng_front: Vec3,
    pub(crate) n: Vec3,
    pub(crate) ns_front: Vec3,
}

/// The hit at barycentrics `b` of the triangle with vertices `p` and vertex normals `normals`
/// (zero where the mesh has none) by a ray along `dir`: the point and its error bound, and the
/// geometric and interpolated normals, facing the ray and of the front side. Shared by
/// [`interaction`] and the path loop in lanes (one lane each).
#[inline(always)]
pub(crate) fn hit_geometry(p: [Vec3; 3], normals: [Vec3; 3], b: [f32; 3], dir: Vec3) -> HitGeometry {
    let (point, p_err) = hit_point_error(p, b);
    let ng_front = (p[1] - p[0]).cross(p[2] - p[0]).normalize_or_zero();
    let ns = (0..3).fold(Vec3::ZERO, |acc, k| acc + b[k] * normals[k]);
    let ns = if ns.length_squared() > 1e-12 { ns } else { ng_front };
    let ns_front = ns.normalize_or_zero();
    let (ng, n) = facing_normals(ng_front, ns, dir);
    HitGeometry { p: point, p_err, ng, ng_front, n, ns_front }
}

/// The shading frame and the BSDF seen from `wo` (unit, world) at a path vertex: the
/// interpolated normal, normal-mapped when the material has a normal texture, flipped and
/// bent by [`shading_frame`]. Shared by the path tracer and the caustic light tracer so that
/// both evaluate a vertex alike.
#[inline(always)]
pub fn vertex_bsdf(scene: &Scene, si: &Interaction, mat: &Material, surf: &SurfaceMaterial, wo: Vec3) -> (Frame, BsdfAt) {
    let ns = match &mat.normal_texture {
        Some((r, _)) => {
            let tangent = tangent_at(scene, si.prim, si.b, r.tex_coord, si.ng_front);
            normal_mapped(mat, &scene.textures, &si.attr, si.ns_front, tangent)
        }
        None => si.ns_front,
    };
    let back = si.n.dot(si.ns_front) < 0.0;
    let frame = shading_frame(ns, back, wo);
    let mut bsdf = surf.bsdf.seen_from(back);
    if let (Bsdf::Layered(l), Some(c)) = (&mut bsdf, mat.clearcoat) {
        // The coat's own normal: its normal map, else the unmapped interpolated normal where
        // the base's is mapped (else the frame's own), flipped and bent like the base's.
        let coat = match &c.normal_texture {
            Some((r, scale)) => {
                let tangent = tangent_at(scene, si.prim, si.b, r.tex_coord, si.ng_front);
                Some(normal_mapped_by(r, *scale, &scene.textures, &si.attr, si.ns_front, tangent))
            }
            None => mat.normal_texture.is_some().then_some(si.ns_front),
        };
        if let Some(nc) = coat {
            let n = frame.to_local(shading_frame(nc, back, wo).n).normalize_or_zero();
            l.coat_normal = if n == Vec3::ZERO { Vec3::Z } else { n };
        }
    }
    (frame, bsdf.at(frame.to_local(wo)))
}

/// A path of [`PathIntegrator::radiance_batch`] in flight: at the vertex `hit` of `ray`.
#[derive(Clone, Copy, Debug)]
struct PathState {
    /// Radiance gathered so far.
    l: Vec3,
    /// Throughput up to the vertex.
    beta: Vec3,
    ray: Ray,
    hit: Hit,
    /// The density of the BSDF sample that led here (for MIS at an emitter).
    prev_bsdf_pdf: f32,
    /// Scattering events before this vertex.
    depth: u32,
    /// Whether no vertex so far is sharp (see [`crate::caustics`]).
    all_rough: bool,
}

/// A shaded vertex of path `path` waiting for its BSDF sample.
#[derive(Clone, Copy, Debug)]
struct Pending {
    path: u32,
    /// The vertex's first sampler dimension.
    dim: u32,
    frame: Frame,
    bsdf: BsdfAt,
    /// Origin of every ray leaving the vertex.
    origin: Vec3,
    /// Geometric normal facing the incoming ray.
    ng: Vec3,
    /// Origin of a ray transmitted through the surface (a transmissive BSDF), else `origin`.
    origin_through: Vec3,
}

/// A light sample at a path vertex (a punctual light, a point on an emissive triangle, or a
/// direction of the environment map),
/// all but the BSDF's value there, which is computed for a whole bounce's samples at once
/// ([`evaluate_many`]).
#[derive(Clone, Copy, Debug)]
struct PendingLight {
    /// The vertex's index among the bounce's [`Pending`] vertices.
    vertex: u32,
    /// Direction to the light, in the shading frame.
    wi_l: Vec3,
    /// Punctual: the irradiance (normal to `wi`); emitter: the emitted radiance times alpha
    /// coverage; environment: its radiance.
    radiance: Vec3,
    /// Emitter or environment: the sample's solid-angle density (MIS with BSDF sampling);
    /// punctual: `None`.
    light_pdf: Option<f32>,
    /// The shadow ray and its `t_max`.
    shadow: Ray,
    t_max: f32,
    /// Which light: a punctual light's index in the scene, [`LIGHT_EMITTERS`] or
    /// [`LIGHT_ENVIRONMENT`] (the camera vertex's shadow rays are traced grouped by it).
    light: u32,
}

/// Buffers of [`PathIntegrator::occluded_by_light`].
#[derive(Default)]
struct ShadowScratch {
    /// Each group's first slot, and the next free one while filling.
    start: Vec<usize>,
    next: Vec<usize>,
    order: Vec<u32>,
    rays: Vec<Ray>,
    t_max: Vec<f32>,
    out: Vec<bool>,
    blocked: Vec<bool>,
}

/// Whether a light sample whose BSDF value is `f` has its shadow ray traced: where `f` is
/// not zero (nor NaN), the same rule for one ray at a time and for packets.
#[inline(always)]
fn traces_shadow_ray(f: Vec3) -> bool {
    !(f.max_element() <= 0.0)
}

/// [`PendingLight::light`] of an emissive-triangle sample.
const LIGHT_EMITTERS: u32 = u32::MAX - 1;
/// [`PendingLight::light`] of an environment-map sample.
const LIGHT_ENVIRONMENT: u32 = u32::MAX;

/// Rays traced, by query: closest hits (camera, bounce, ground-truth and light-tracer rays)
/// and any-hit (shadow) rays.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RayCounts {
    /// Closest-hit queries.
    pub closest: u64,
    /// Any-hit (shadow) queries.
    pub any_hit: u64,
}

impl std::ops::Add for RayCounts {
    type Output = RayCounts;
    fn add(self, o: RayCounts) -> RayCounts {
        RayCounts { closest: self.closest + o.closest, any_hit: self.any_hit + o.any_hit }
    }
}

thread_local! {
    /// The rays this thread has traced through any [`PathIntegrator`] (running totals, read
    /// before and after a task by [`PathIntegrator::tallied`]): a thread-local counter costs
    /// a ray an addition, where a shared atomic one would cost a locked instruction.
    static THREAD_RAYS: std::cell::Cell<RayCounts> = const { std::cell::Cell::new(RayCounts { closest: 0, any_hit: 0 }) };
}

/// Adds to this thread's ray counts.
#[inline(always)]
fn count_rays(closest: u64, any_hit: u64) {
    THREAD_RAYS.with(|c| {
        let v = c.get();
        c.set(RayCounts { closest: v.closest.wrapping_add(closest), any_hit: v.any_hit.wrapping_add(any_hit) });
    });
}

/// A [`PathIntegrator`]'s rays, added once per task ([`PathIntegrator::tallied`]).
#[derive(Debug, Default)]
struct RayTally {
    closest: std::sync::atomic::AtomicU64,
    any_hit: std::sync::atomic::AtomicU64,
}

/// A path tracer over one scene (see the module docs).
pub struct PathIntegrator<'a> {
    /// The scene.
    pub scene: &'a Scene,
    /// Its BVH.
    pub accel: &'a Accel,
    /// Its emissive triangles.
    pub emitters: &'a EmissiveTriangles,
    /// When set, the light tracer of [`crate::caustics`] estimates the caustic paths
    /// (camera → surfaces that are not sharp → caster → punctual light) and this integrator
    /// leaves them out; `None`: every path is estimated here.
    pub caustics: Option<&'a CausticVertices>,
    /// Per material, the material resolved once where it is the same at every point
    /// ([`crate::material::uniform_surface`]), else `None` (resolved per vertex). Empty: every
    /// material is resolved per vertex (the same bits, slower).
    pub uniform_surfaces: &'a [Option<SurfaceMaterial>],
    /// Where the scene's materials allow it ([`LaneMaterials::new`]), what the path loop in
    /// lanes reads (module `lanes`); `None`: every vertex is shaded one path at a time (the
    /// same bits, slower).
    pub lane_materials: Option<&'a LaneMaterials>,
    /// Settings.
    pub settings: IntegratorSettings,
    /// The rays of the tasks run through [`PathIntegrator::tallied`].
    tally: RayTally,
}

impl std::fmt::Debug for PathIntegrator<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PathIntegrator").field("settings", &self.settings).finish()
    }
}

impl<'a> PathIntegrator<'a> {
    /// The integrator over `scene` with its acceleration structure, emitters, resolved
    /// materials and settings; no caustic light tracing ([`PathIntegrator::caustics`]).
    pub fn new(
        scene: &'a Scene,
        accel: &'a Accel,
        emitters: &'a EmissiveTriangles,
        uniform_surfaces: &'a [Option<SurfaceMaterial>],
        lane_materials: Option<&'a LaneMaterials>,
        settings: IntegratorSettings,
    ) -> Self {
        PathIntegrator { scene, accel, emitters, caustics: None, uniform_surfaces, lane_materials, settings, tally: RayTally::default() }
    }

    /// Runs `f` (one sequential task, on this thread) and adds the rays it traced to
    /// [`PathIntegrator::rays_traced`]. The count is exact and the same for any thread count
    /// as long as `f` runs no parallel work of its own (a thread waiting on a parallel join
    /// may run other tasks, whose rays would then count here too).
    pub fn tallied<R>(&self, f: impl FnOnce() -> R) -> R {
        use std::sync::atomic::Ordering::Relaxed;
        let before = THREAD_RAYS.with(|c| c.get());
        let r = f();
        let after = THREAD_RAYS.with(|c| c.get());
        self.tally.closest.fetch_add(after.closest.wrapping_sub(before.closest), Relaxed);
        self.tally.any_hit.fetch_add(after.any_hit.wrapping_sub(before.any_hit), Relaxed);
        r
    }

    /// The rays traced so far by the tasks run through [`PathIntegrator::tallied`].
    pub fn rays_traced(&self) -> RayCounts {
        use std::sync::atomic::Ordering::Relaxed;
        RayCounts { closest: self.tally.closest.load(Relaxed), any_hit: self.tally.any_hit.load(Relaxed) }
    }
}

impl PathIntegrator<'_> {
    /// Closest hit honouring alpha masks and back-face culling.
    #[inline(always)]
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        count_rays(1, 0);
        self.accel.closest_hit(ray, f32::INFINITY, |prim, h| alpha_test(self.scene, ray, prim, h.b))
    }

    /// [`PathIntegrator::intersect`] for each of `rays`, into `out` (the same bits), by packets
    /// of rays ([`Accel::closest_hits`]).
    #[inline(always)]
    pub fn intersect_many(&self, rays: &[Ray], out: &mut [Option<Hit>]) {
        count_rays(rays.len() as u64, 0);
        self.accel.closest_hits(rays, f32::INFINITY, |r, prim, h| alpha_test(self.scene, &rays[r], prim, h.b), out)
    }

    /// [`PathIntegrator::intersect`] with the traversal stack `stack` ([`Accel::closest_hit_in`]).
    #[inline(always)]
    pub(crate) fn intersect_in(&self, stack: &mut TraversalStack, ray: &Ray) -> Option<Hit> {
        let hit = self.accel.closest_hit_in(stack, ray, f32::INFINITY, |prim, h| alpha_test(self.scene, ray, prim, h.b));
        count_rays(1, 0);
        hit
    }

    /// [`PathIntegrator::occluded`] with the traversal stack `stack` ([`Accel::occluded_in`]).
    #[inline(always)]
    fn occluded_in(&self, stack: &mut TraversalStack, ray: &Ray, t_max: f32) -> bool {
        let blocked = self.accel.occluded_in(stack, ray, t_max, |prim, h| alpha_test(self.scene, ray, prim, h.b));
        count_rays(0, 1);
        blocked
    }

    /// Whether anything blocks `ray` before `t_max`.
    #[inline(always)]
    pub fn occluded(&self, ray: &Ray, t_max: f32) -> bool {
        count_rays(0, 1);
        self.accel.occluded(ray, t_max, |prim, h| alpha_test(self.scene, ray, prim, h.b))
    }

    /// Whether each light sample's shadow ray is blocked (`scratch.blocked[e]` for
    /// `lights[e]`; false where its BSDF value `values[e]` is zero, whose ray is not traced):
    /// the rays grouped by light (a counting sort, each light's samples in vertex order) and
    /// traced as packets ([`Accel::occluded_many`]), the same answers as one
    /// [`PathIntegrator::occluded`] each. For the camera vertex's samples of a pixel, whose
    /// rays to one light nearly coincide.
    #[inline(always)]
    fn occluded_by_light(&self, lights: &[PendingLight], values: &[(Vec3, f32)], scratch: &mut ShadowScratch) {
        let ShadowScratch { start, next, order, rays, t_max, out, blocked } = scratch;
        let n = self.scene.lights.len();
        // Punctual light `i` is group `i`, the emitters `n`, the environment `n + 1`.
        let group = |e: &PendingLight| match e.light {
            LIGHT_EMITTERS => n,
            LIGHT_ENVIRONMENT => n + 1,
            i => i as usize,
        };
        start.clear();
        start.resize(n + 3, 0);
        for (e, v) in lights.iter().zip(values) {
            if traces_shadow_ray(v.0) {
                start[group(e) + 1] += 1;
            }
        }
        for g in 1..start.len() {
            start[g] += start[g - 1];
        }
        let traced = start[n + 2];
        order.clear();
        order.resize(traced, 0);
        rays.clear();
        rays.resize(traced, Ray::new(Vec3::ZERO, Vec3::Z));
        t_max.clear();
        t_max.resize(traced, 0.0);
        next.clear();
        next.extend_from_slice(start);
        for (i, (e, v)) in lights.iter().zip(values).enumerate() {
            if traces_shadow_ray(v.0) {
                let slot = &mut next[group(e)];
                (order[*slot], rays[*slot], t_max[*slot]) = (i as u32, e.shadow, e.t_max);
                *slot += 1;
            }
        }
        out.clear();
        out.resize(traced, false);
        for g in 0..n + 2 {
            let r = start[g]..start[g + 1];
            if !r.is_empty() {
                self.occluded_many(&rays[r.clone()], &t_max[r.clone()], &mut out[r]);
            }
        }
        blocked.clear();
        blocked.resize(lights.len(), false);
        for (&e, &o) in order.iter().zip(out.iter()) {
            blocked[e as usize] = o;
        }
    }

    /// [`PathIntegrator::occluded`] for each of `rays` (with limits `t_max`), into `out`, by
    /// packets ([`Accel::occluded_many`]).
    #[inline(always)]
    pub fn occluded_many(&self, rays: &[Ray], t_max: &[f32], out: &mut [bool]) {
        count_rays(0, rays.len() as u64);
        self.accel.occluded_many(rays, t_max, |r, prim, h| alpha_test(self.scene, &rays[r], prim, h.b), out)
    }

    /// Whether every vertex samples the environment (an environment map that is not black;
    /// a constant environment is left to BSDF sampling, see the module docs).
    #[inline(always)]
    fn samples_environment(&self) -> bool {
        let env = &self.settings.environment;
        !env.is_black() && env.map.is_some()
    }

    /// The material `mat` of `si` resolved at its point: from [`PathIntegrator::uniform_surfaces`]
    /// where it is the same everywhere, else by [`resolve`] (the same bits either way).
    #[inline(always)]
    pub fn surface(&self, mat: &Material, si: &Interaction) -> SurfaceMaterial {
        match self.uniform_surfaces.get(si.material as usize) {
            Some(Some(surf)) => *surf,
            _ => resolve(mat, &self.scene.textures, &si.attr),
        }
    }

    /// The radiance arriving at `ray.origin` from direction `−ray.direction` (unit).
    pub fn radiance(&self, ray: &Ray, sampler: &mut Sampler) -> RadianceSample {
        self.radiance_split(ray, sampler, true)
    }

    /// The emission of the surface a camera ray sees first (zero for a miss or a surface that
    /// does not emit): exactly the term [`PathIntegrator::radiance`] adds at the camera
    /// vertex, so that `radiance = primary_emission + radiance_split(…, false)` for every ray
    /// and sampler.
    pub fn primary_emission(&self, ray: &Ray) -> Vec3 {
        let scene = self.scene;
        let Some(hit) = self.intersect(ray) else { return Vec3::ZERO };
        let Some(mat) = scene.mesh.material.get(hit.prim as usize).and_then(|&m| scene.materials.get(m as usize)) else { return Vec3::ZERO };
        if !mat.is_emissive() {
            return Vec3::ZERO;
        }
        emission(mat, &scene.textures, &surface_attributes(scene, hit.prim, hit.b))
    }

    /// [`PathIntegrator::radiance`], with the emission of the surface the camera ray hits first
    /// left out when `primary_emission` is false (the caller then estimates that term
    /// separately, [`PathIntegrator::primary_emission`]); the random numbers drawn are the
    /// same either way.
    ///
    /// The path loop runs inside pulp's `vectorize` at the x86-64-v3 level (AVX2, FMA, VEX
    /// encoding) where the CPU has it ([`Accel::at_level`]), with the functions a vertex calls
    /// (`interaction`, `vertex_bsdf`, the BSDF's `sample` and `evaluate_pdf`, the emitter
    /// sample, the ray queries) inlined into it so that they are compiled at that level too;
    /// elsewhere it runs compiled for baseline x86-64. The bits are the same either way (no
/// operation is contracted into an FMA); the level is faster (`docs/renderer.md`). It is
/// [`PathIntegrator::radiance_batch`] with a batch of one (whose vectorised BSDF sample,
/// [`crate::material::sample_many`], then runs one lane).
    pub fn radiance_split(&self, ray: &Ray, sampler: &mut Sampler, primary_emission: bool) -> RadianceSample {
        // `inline(always)` on the closure: without it the closure, called from both of
        // `at_level`'s branches, stays out of line and compiled for the baseline (the path loop
        // then runs with SSE only, slower).
        self.accel.at_level(#[inline(always)] || self.radiance_split_impl(ray, sampler, primary_emission))
    }

    /// [`PathIntegrator::radiance_split`] for many camera rays at once (`rays[k]` with
    /// `samplers[k]`, into `out[k]`): the same bits as one call per ray. The paths advance
    /// together, a vertex at a time: every live path's vertex is shaded, then every BSDF
    /// sample is drawn, then every path is continued and its next ray traced.
    ///
    /// # Panics
    /// If the three slices differ in length.
    pub fn radiance_batch(&self, rays: &[Ray], samplers: &mut [Sampler], primary_emission: bool, out: &mut [RadianceSample]) {
        assert!(rays.len() == samplers.len() && rays.len() == out.len(), "radiance_batch: {} rays, {} samplers, {} results", rays.len(), samplers.len(), out.len());
        self.accel.at_level(#[inline(always)] || self.radiance_batch_impl(rays, samplers, primary_emission, out))
    }

    #[inline(always)]
    fn radiance_split_impl(&self, ray: &Ray, sampler: &mut Sampler, primary_emission: bool) -> RadianceSample {
        let mut out = [RadianceSample { radiance: Vec3::ZERO, primary_hit: false }];
        self.radiance_batch_impl(std::slice::from_ref(ray), std::slice::from_mut(sampler), primary_emission, &mut out);
        out[0]
    }

    #[inline(always)]
    fn radiance_batch_impl(&self, rays: &[Ray], samplers: &mut [Sampler], primary_emission: bool, out: &mut [RadianceSample]) {
        if let Some(mats) = self.lane_materials {
            return self.radiance_lanes(mats, rays, samplers, primary_emission, out);
        }
        let mut stack = TraversalStack::default();
        let (mut paths, mut active) = self.camera_vertices(&mut stack, rays, out);
        let mut pending: Vec<Pending> = Vec::with_capacity(active.len());
        let mut sampled: Vec<Option<BsdfSample>> = Vec::with_capacity(active.len());
        let mut numbers: Vec<Vec2> = Vec::with_capacity(active.len());
        let mut light_wi: Vec<Vec3> = Vec::with_capacity(active.len());
        let mut values: Vec<(Vec3, f32)> = Vec::with_capacity(active.len());
        let mut lights: Vec<PendingLight> = Vec::with_capacity(active.len());
        let mut shadow = ShadowScratch::default();
        let mut camera_vertex = true;
        while !active.is_empty() {
            pending.clear();
            lights.clear();
            for &k in &active {
                let k = k as usize;
                match self.shade_vertex(&mut paths[k], &mut samplers[k], primary_emission, pending.len() as u32, &mut lights) {
                    Some(v) => pending.push(Pending { path: k as u32, ..v }),
                    None => out[k].radiance = paths[k].l,
                }
            }
            // The light samples' BSDF values, then their shadow rays and estimates: a punctual
            // light's `f · E`, an emitter's or the environment's `f · Le · w_light / pdf_light`.
            if !lights.is_empty() {
                light_wi.clear();
                light_wi.extend(lights.iter().map(|e| e.wi_l));
                values.clear();
                values.resize(lights.len(), (Vec3::ZERO, 0.0));
                evaluate_many(|e| &pending[lights[e].vertex as usize].bsdf, &light_wi, &mut values);
                if camera_vertex && lights.len() >= PACKET_MIN_RAYS {
                    self.occluded_by_light(&lights, &values, &mut shadow);
                    for ((e, &value), &b) in lights.iter().zip(&values).zip(&shadow.blocked) {
                        Self::add_light_estimate_traced(&mut paths[pending[e.vertex as usize].path as usize], e, value, b);
                    }
                } else {
                    for (e, &value) in lights.iter().zip(&values) {
                        self.add_light_estimate(&mut stack, &mut paths[pending[e.vertex as usize].path as usize], e, value);
                    }
                }
            }
            camera_vertex = false;
            numbers.clear();
            numbers.extend(pending.iter().map(|v| samplers[v.path as usize].get_2d(v.dim + DIM_BSDF)));
            sampled.clear();
            sampled.resize(pending.len(), None);
            sample_many(|k| &pending[k].bsdf, &numbers, &mut sampled);
            active.clear();
            for (v, bs) in pending.iter().zip(&sampled) {
                let k = v.path as usize;
                if self.continue_path(&mut stack, &mut paths[k], &samplers[k], v, bs) {
                    active.push(k as u32);
                } else {
                    out[k].radiance = paths[k].l;
                }
            }
        }
    }

    /// The batch's camera rays traced (as packets where the batch is large enough): every
    /// path at its first vertex, the paths that hit something (their indices), and `out`
    /// set for every ray (the environment for a miss).
    #[inline(always)]
    fn camera_vertices(&self, stack: &mut TraversalStack, rays: &[Ray], out: &mut [RadianceSample]) -> (Vec<PathState>, Vec<u32>) {
        let env = &self.settings.environment;
        let mut paths: Vec<PathState> = Vec::with_capacity(rays.len());
        let mut active: Vec<u32> = Vec::with_capacity(rays.len());
        // The camera rays (a pixel's, close to each other) as packets where the batch is large
        // enough to pay, else one at a time (the same bits either way).
        let mut hits = vec![None; rays.len()];
        if rays.len() >= PACKET_MIN_RAYS {
            self.intersect_many(rays, &mut hits);
        } else {
            for (h, r) in hits.iter_mut().zip(rays) {
                *h = self.intersect_in(stack, r);
            }
        }
        for (k, (ray, &hit)) in rays.iter().zip(&hits).enumerate() {
            paths.push(PathState {
                l: Vec3::ZERO,
                beta: Vec3::ONE,
                ray: *ray,
                hit: hit.unwrap_or(Hit { prim: 0, t: 0.0, b: [0.0; 3], front: true }),
                prev_bsdf_pdf: 0.0,
                depth: 0,
                all_rough: true,
            });
            out[k] = match hit {
                Some(_) => {
                    active.push(k as u32);
                    RadianceSample { radiance: Vec3::ZERO, primary_hit: true }
                }
                None => {
                    let radiance = if self.settings.transparent_background { Vec3::ZERO } else { env.eval(ray.direction) };
                    RadianceSample { radiance, primary_hit: false }
                }
            };
        }
        (paths, active)
    }

    /// A path's vertex at `path.hit`: the emission it shows added to `path.l`, its
    /// punctual-light, emitter and environment samples pushed on `lights` (as the bounce's
    /// vertex `vertex`); `None` when the path ends here (having pushed nothing),
    /// else what its BSDF sample needs.
    #[inline(always)]
    fn shade_vertex(&self, path: &mut PathState, sampler: &mut Sampler, primary_emission: bool, vertex: u32, lights: &mut Vec<PendingLight>) -> Option<Pending> {
        let scene = self.scene;
        let (ray, hit, depth) = (path.ray, path.hit, path.depth);
        // Past the last scattering event only the emission this vertex shows counts: where
        // its material emits nothing, the interaction is not even built (the same bits).
        if depth >= self.settings.max_bounces {
            let material = scene.mesh.material.get(hit.prim as usize).copied().unwrap_or(0);
            if !scene.materials.get(material as usize).is_some_and(Material::is_emissive) {
                return None;
            }
        }
        let si = interaction(scene, &ray, &hit);
        let mat = scene.materials.get(si.material as usize)?;
        let surf = self.surface(mat, &si);
        self.add_emission_seen(path, surf.emission, si.ng_front, primary_emission);
        if depth >= self.settings.max_bounces {
            return None;
        }
        // The vertex's fixed block of dimensions (`DIM_*`), reserved at once; each number is
        // computed only where it is used (the same numbers as drawing all eight in order).
        let dim = sampler.skip(VERTEX_DIMENSIONS);

        let (frame, bsdf) = vertex_bsdf(scene, &si, mat, &surf, -ray.direction);
        // Every ray leaving this vertex is checked to leave on the `ng` side first, and
        // `offset_ray_origin` depends on the direction only through that side: one origin
        // serves them all (bit-identical to offsetting per ray).
        let origin = offset_ray_origin(si.p, si.p_err, si.ng, si.ng);
        // A rough transmissive surface also takes light samples on its far side, whose shadow
        // rays leave from there (a smooth one's delta lobes have no value towards any).
        let through = match bsdf.transmissive() {
            Some(t) if !t.glass.is_smooth() => Some(offset_ray_origin(si.p, si.p_err, si.ng, -si.ng)),
            _ => None,
        };

        // Punctual lights: deterministic, all of them, unless this is a caustic vertex
        // whose punctual light the light tracer estimates instead ([`crate::caustics`]).
        if !self.caustic_vertex(path, si.material) {
            self.punctual_samples(si.p, si.ng, origin, through, &frame, |e| lights.push(PendingLight { vertex, ..e }));
        }

        // Emissive triangles: one sample, MIS with BSDF sampling.
        if !self.emitters.is_empty()
            && let Some(es) = self.emitters.sample(sampler.get_2d(dim + DIM_EMITTER_POINT), || sampler.get_1d(dim + DIM_EMITTER_SPARE))
            && let Some(e) = self.emitter_pending(&si, &frame, origin, through, es)
        {
            lights.push(PendingLight { vertex, ..e });
        }

        // Environment map: one sample, MIS with BSDF sampling. A constant environment is
        // left to BSDF sampling alone (see the module docs).
        if self.samples_environment()
            && let Some(e) = self.environment_sample(sampler.get_2d(dim + DIM_ENVIRONMENT), si.ng, origin, through, &frame)
        {
            lights.push(PendingLight { vertex, ..e });
        }
        let origin_through = if bsdf.transmissive().is_some() { offset_ray_origin(si.p, si.p_err, si.ng, -si.ng) } else { origin };
        Some(Pending { path: 0, dim, frame, bsdf, origin, ng: si.ng, origin_through })
    }

    /// Adds a light sample's estimate to `path` where its BSDF value `f` (with density
    /// `bsdf_pdf`) is not zero and its shadow ray is not blocked: a punctual light's `f · E`,
    /// an emitter's or the environment's `f · Le · w_light / pdf_light`.
    #[inline(always)]
    fn add_light_estimate(&self, stack: &mut TraversalStack, path: &mut PathState, e: &PendingLight, (f, bsdf_pdf): (Vec3, f32)) {
        if traces_shadow_ray(f) && !self.occluded_in(stack, &e.shadow, e.t_max) {
            Self::add_unblocked(path, e, f, bsdf_pdf);
        }
    }

    /// [`PathIntegrator::add_light_estimate`] with the shadow ray's answer known: `blocked`.
    #[inline(always)]
    fn add_light_estimate_traced(path: &mut PathState, e: &PendingLight, (f, bsdf_pdf): (Vec3, f32), blocked: bool) {
        if traces_shadow_ray(f) && !blocked {
            Self::add_unblocked(path, e, f, bsdf_pdf);
        }
    }

    /// The estimate of an unblocked light sample with BSDF value `f` (density `bsdf_pdf`).
    #[inline(always)]
    fn add_unblocked(path: &mut PathState, e: &PendingLight, f: Vec3, bsdf_pdf: f32) {
        path.l += match e.light_pdf {
            None => path.beta * f * e.radiance,
            Some(light_pdf) => path.beta * (f * e.radiance * (power_heuristic(light_pdf, bsdf_pdf) / light_pdf)),
        };
    }

    /// Adds the emission `emission` that a path's vertex shows (its surface's, geometric
    /// front normal `ng_front`) to `path.l`: whole at the camera vertex (when
    /// `primary_emission`), else MIS-weighted against the emitter sample that could have
    /// found it.
    #[inline(always)]
    fn add_emission_seen(&self, path: &mut PathState, emission: Vec3, ng_front: Vec3, primary_emission: bool) {
        if emission.max_element() > 0.0 {
            if path.depth == 0 {
                if primary_emission {
                    path.l += path.beta * emission;
                }
            } else {
                let cos_l = ng_front.dot(-path.ray.direction);
                let light_pdf = self.emitters.pdf_solid_angle(path.hit.prim, path.hit.t, cos_l);
                path.l += path.beta * emission * power_heuristic(path.prev_bsdf_pdf, light_pdf);
            }
        }
    }

    /// Whether a path's vertex on `material` is a caustic vertex whose punctual lights the
    /// light tracer estimates ([`crate::caustics`]); updates the path's `all_rough`.
    #[inline(always)]
    fn caustic_vertex(&self, path: &mut PathState, material: u32) -> bool {
        let caustic = path.all_rough && self.caustics.is_some_and(|c| c.is_caustic_vertex(path.depth + 1, material));
        path.all_rough &= self.caustics.is_some_and(|c| !c.is_sharp(material));
        caustic
    }

    /// Every punctual light's sample at the point `p` (geometric normal `ng` facing the
    /// incoming ray, rays leaving from `origin`, shading frame `frame`) that lights its side
    /// (or the far side, with rays leaving from `through`, where that is given), up to the
    /// BSDF's value, passed to `push` in the scene's order (its `vertex` is the caller's to set).
    #[inline(always)]
    fn punctual_samples(&self, p: Vec3, ng: Vec3, origin: Vec3, through: Option<Vec3>, frame: &Frame, mut push: impl FnMut(PendingLight)) {
        for (index, light) in self.scene.lights.iter().enumerate() {
            let Some(inc) = punctual_incidence(light, p) else { continue };
            let origin = match (inc.wi.dot(ng) <= 0.0, through) {
                (false, _) => origin,
                (true, Some(o)) => o,
                (true, None) => continue,
            };
            let t_max = if inc.distance.is_finite() {
                match *light {
                    crate::scene::Light::Point { position, .. } | crate::scene::Light::Spot { position, .. } => (position - origin).length() * (1.0 - SHADOW_EPSILON),
                    crate::scene::Light::Directional { .. } => f32::INFINITY,
                }
            } else {
                f32::INFINITY
            };
            push(PendingLight { vertex: 0, wi_l: frame.to_local(inc.wi), radiance: inc.irradiance, light_pdf: None, shadow: Ray::new(origin, inc.wi), t_max, light: index as u32 });
        }
    }

    /// The environment map's sample with the numbers `u` at a point (geometric normal `ng`
    /// facing the incoming ray, rays leaving from `origin`, shading frame `frame`), up to the
    /// BSDF's value; `None` where it lies below the surface (unless rays can leave from
    /// `through` there) or has no radiance (its `vertex` is the caller's to set).
    #[inline(always)]
    fn environment_sample(&self, u: Vec2, ng: Vec3, origin: Vec3, through: Option<Vec3>, frame: &Frame) -> Option<PendingLight> {
        let env = &self.settings.environment;
        let (wi, pdf) = env.sample(u)?;
        let side = wi.dot(ng);
        let origin = if side > 0.0 {
            origin
        } else if side < 0.0 {
            through?
        } else {
            return None;
        };
        let le = env.eval(wi);
        (le.max_element() > 0.0).then(|| PendingLight { vertex: 0, wi_l: frame.to_local(wi), radiance: le, light_pdf: Some(pdf), shadow: Ray::new(origin, wi), t_max: f32::INFINITY, light: LIGHT_ENVIRONMENT })
    }

    /// Continues a path from its vertex `v` along the BSDF sample `bs` (Russian roulette, the
    /// next ray traced); false when the path ends (its escape to the environment added).
    #[inline(always)]
    fn continue_path(&self, stack: &mut TraversalStack, path: &mut PathState, sampler: &Sampler, v: &Pending, bs: &Option<BsdfSample>) -> bool {
        let Some(bs) = bs else { return false };
        let wi = v.frame.to_world(bs.wi).normalize();
        if v.bsdf.transmissive().is_some() && wi.dot(v.ng) < 0.0 {
            // Through the surface: MIS against the light samples taken on this side (a smooth
            // interface's delta sample has `pdf = ∞`: the emitter it finds counts whole).
            let goes_on = self.continue_along(stack, path, v.origin_through, -v.ng, wi, bs.weight, bs.pdf, || sampler.get_1d(v.dim + DIM_ROULETTE));
            if goes_on {
                self.absorb(path);
            }
            return goes_on;
        }
        let goes_on = self.continue_along(stack, path, v.origin, v.ng, wi, bs.weight, bs.pdf, || sampler.get_1d(v.dim + DIM_ROULETTE));
        if goes_on && v.bsdf.transmissive().is_some() {
            self.absorb(path);
        }
        goes_on
    }

    /// Beer–Lambert absorption along the ray that led to `path.hit` where that ray ran inside
    /// a volume: it left a transmissive surface and hits the back face of a material with
    /// `KHR_materials_volume` (`beta ×= exp(−σ_a t)`, [`crate::scene::Volume`]). Media are not
    /// nested: an opaque object inside a volume ends the absorbing segment unattenuated.
    #[inline(always)]
    fn absorb(&self, path: &mut PathState) {
        if path.hit.front {
            return;
        }
        let scene = self.scene;
        let volume = scene.mesh.material.get(path.hit.prim as usize).and_then(|&m| scene.materials.get(m as usize)).and_then(|m| m.volume);
        if let Some(v) = volume {
            path.beta *= v.transmittance(path.hit.t);
        }
    }

    /// Continues a path from its vertex (rays leave from `origin`, geometric normal `ng`
    /// facing the incoming ray) along the BSDF sample's world direction `wi`, with its weight
    /// and density: Russian roulette (with the number `roulette()`), the next ray traced;
    /// false when the path ends (its escape to the environment added).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn continue_along(&self, stack: &mut TraversalStack, path: &mut PathState, origin: Vec3, ng: Vec3, wi: Vec3, weight: Vec3, pdf: f32, roulette: impl FnOnce() -> f32) -> bool {
        let env = &self.settings.environment;
        if wi.dot(ng) <= 0.0 {
            return false;
        }
        path.beta *= weight;
        path.prev_bsdf_pdf = pdf;
        if path.depth >= 2 {
            let survive = (ROULETTE_SCALE * path.beta.max_element()).min(1.0);
            if !(survive > 0.0) || roulette() >= survive {
                return false;
            }
            path.beta /= survive;
        }
        path.ray = Ray::new(origin, wi);
        match self.intersect_in(stack, &path.ray) {
            Some(h) => {
                path.hit = h;
                path.depth += 1;
                true
            }
            None => {
                if self.samples_environment() {
                    path.l += path.beta * env.eval(wi) * power_heuristic(path.prev_bsdf_pdf, env.pdf(wi));
                } else if !env.is_black() {
                    path.l += path.beta * env.eval(wi);
                }
                false
            }
        }
    }

    /// One light-sampling sample of the emissive triangles at `si`, up to the BSDF's value
    /// ([`PendingLight`]; the bounce's values are computed together, in lanes, and the
    /// estimate is `f · Le · w_light / pdf_light`); `None` where the estimate is zero whatever
    /// that value (its `vertex` is the caller's to set). `origin` is the shadow ray's start, `offset_ray_origin(si.p, si.p_err, si.ng, si.ng)`;
    /// `through`, where given, its start for a point below the surface.
    #[inline(always)]
    fn emitter_pending(&self, si: &Interaction, frame: &Frame, origin: Vec3, through: Option<Vec3>, es: crate::light::EmitterSample) -> Option<PendingLight> {
        let scene = self.scene;
        let m = &scene.mesh;
        let idx = m.indices[es.prim as usize];
        let p = idx.map(|i| m.positions[i as usize]);
        let (q, q_err) = hit_point_error(p, es.b);
        let n_l = (p[1] - p[0]).cross(p[2] - p[0]).normalize_or_zero();
        let d = q - si.p;
        let dist = d.length();
        if !(dist > 0.0) {
            return None;
        }
        let wi = d / dist;
        let origin = if wi.dot(si.ng) <= 0.0 { through? } else { origin };
        let lmat = m.material.get(es.prim as usize).and_then(|&k| scene.materials.get(k as usize))?;
        let cos_l = n_l.dot(-wi);
        if !lmat.double_sided && cos_l <= 0.0 {
            return None;
        }
        // The light's attributes matter only to its textures and alpha; an opaque, untextured
        // emitter (the common case) skips interpolating them.
        let lattr = if lmat.emissive_texture.is_some() || !matches!(lmat.alpha_mode, AlphaMode::Opaque) {
            surface_attributes(scene, es.prim, es.b)
        } else {
            SurfaceAttributes { uv: [Vec2::ZERO; 2], color: Vec4::ONE }
        };
        let coverage = match lmat.alpha_mode {
            AlphaMode::Opaque => 1.0,
            AlphaMode::Mask { cutoff } => {
                if base_color(lmat, &scene.textures, &lattr).w >= cutoff { 1.0 } else { 0.0 }
            }
            AlphaMode::Blend => base_color(lmat, &scene.textures, &lattr).w.clamp(0.0, 1.0),
        };
        let le = emission(lmat, &scene.textures, &lattr) * coverage;
        if le.max_element() <= 0.0 {
            return None;
        }
        let light_pdf = self.emitters.pdf_solid_angle(es.prim, dist, cos_l);
        if !(light_pdf > 0.0) || !light_pdf.is_finite() {
            return None;
        }
        let target = offset_ray_origin(q, q_err, n_l, -wi);
        let seg = target - origin;
        let len = seg.length();
        if !(len > 0.0) {
            return None;
        }
        Some(PendingLight { vertex: 0, wi_l: frame.to_local(wi), radiance: le, light_pdf: Some(light_pdf), shadow: Ray::new(origin, seg / len), t_max: len * (1.0 - SHADOW_EPSILON), light: LIGHT_EMITTERS })
    }
}
