//! The acceleration structure: one type, [`Accel`], an eight-wide BVH over the scene's
//! triangles. obvhs builds a compressed wide BVH (CWBVH, PLOC, in parallel) with the settings
//! of [`AccelParams`] (named presets mirroring obvhs's `BvhBuildParams`); the tree is then
//! re-laid as eight-wide nodes with exact `f32` child boxes in structure-of-arrays form (module
//! `wide`, 224 bytes per node) and the CWBVH is dropped. Triangles are packed in BVH order with
//! their face normals, and tested with the watertight test of [`crate::geometry`].
//!
//! Queries, all answering the same bits for the same ray:
//! - one ray: [`Accel::closest_hit`] and [`Accel::occluded`] (any hit, for shadow rays) on the
//!   thread's traversal stack; [`Accel::closest_hit_in`] and [`Accel::occluded_in`] on the
//!   caller's [`TraversalStack`] (the path loop's form). Per node one eight-lane slab test with
//!   the near planes picked by the direction's signs; closest-hit children are pushed sorted by
//!   entry distance and culled when popped beyond the current hit, any-hit children unsorted;
//! - packets: [`Accel::closest_hits`] and [`Accel::occluded_many`] trace up to [`PACKET`] (64)
//!   rays together, each node loaded once for every ray that enters it. Each lane of the box
//!   test is the one-ray test's arithmetic for that ray (so the same children are entered); the
//!   lane triangle test only drops a ray where the exact test certainly rejects it (a zero edge
//!   function or a NaN is kept), and every ray kept is then tested by the exact test alone.
//!
//! The SIMD level (AVX2 eight lanes, else SSE four, else scalar) is found at run time through
//! pulp; [`Accel::at_level`] runs a closure at it.
//!
//! Conservative boxes (watertightness): the `f32` slab test can round a ray through a box
//! corner to a miss, so the tree is built over triangle boxes padded on every side by
//! `2·10⁻⁶ · max |coordinate|` of the scene (about 16 ulps), each node's child box is the union
//! of its children's padded boxes, the ray's `[t_near, t_far]` is widened by `2⁻²¹` relative,
//! and boxes are entered from `t = 0` (`BOX_T_MIN`).
//!
//! Hit rules, shared by every query:
//! - A single-sided triangle hit from behind (`d · ((p₁−p₀)×(p₂−p₀)) ≥ 0`) is ignored: glTF
//!   culls back faces, so they are invisible and do not occlude.
//! - An alpha-masked triangle (glTF `MASK`) is hit only where the caller's alpha test
//!   accepts the hit (base-colour alpha ≥ cutoff).
//! - Among hits at exactly the same `t` (e.g. on a shared edge) the lowest triangle index
//!   wins, so the answer does not depend on the BVH's layout or build.
//!
//! Why this layout, and the traversal variants tried instead: `docs/renderer.md` and
//! `docs/experiments.md`.

// Negated comparisons (`!(x > 0.0)`) are deliberate: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use crate::geometry::{Ray, TriangleHit, WatertightRay, intersect_triangle};
use glam::{Vec3, Vec3A, Vec4};
use std::time::Duration;

mod build;
mod packet;
#[cfg(test)]
mod tests;
mod wide;

pub use build::{AccelParams, MortonBits, PlocSearch};
pub use packet::PACKET;

/// The traversal stack of one-ray queries ([`Accel::closest_hit_in`], [`Accel::occluded_in`]),
/// owned by a caller that makes many queries: its entries are not read before a query writes
/// them, so it is never cleared between queries.
#[derive(Clone, Debug)]
pub struct TraversalStack([u64; wide::STACK]);

impl Default for TraversalStack {
    fn default() -> Self {
        TraversalStack([0; wide::STACK])
    }
}

/// A closest hit: triangle index (into the scene mesh), distance and barycentrics.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Triangle index into `Scene::mesh.indices`.
    pub prim: u32,
    /// Distance along the (unit-direction) ray.
    pub t: f32,
    /// Barycentrics (`b[i]` weights vertex `i` of the triangle).
    pub b: [f32; 3],
    /// Whether the front face (counter-clockwise side) was hit.
    pub front: bool,
}

/// Largest supported |coordinate| of a vertex relative to the scene's centre, in metres.
pub const MAX_LOCAL_COORDINATE: f32 = 1e15;

const CULL_BACK: u32 = 1;
const ALPHA_TEST: u32 = 2;

/// One BVH primitive, everything the hit test reads in one 48-byte record (BVH order, so
/// the triangles of a leaf are adjacent in memory).
#[derive(Clone, Copy, Debug)]
struct PackedTriangle {
    /// Vertices.
    p: [Vec3; 3],
    /// Unnormalised face normal `(p₁−p₀)×(p₂−p₀)` (the same `f32` expression the face
    /// test would evaluate per ray), for back-face culling and the hit face.
    n: Vec3,
    /// Scene triangle index.
    prim: u32,
    /// `CULL_BACK | ALPHA_TEST`.
    flags: u32,
}

/// Nearest distance the box test accepts: 0, every box in front of the ray's origin. (obvhs's
/// own test uses 1e-4 in world units, which skipped every hit closer than 0.1 mm to a ray's
/// origin: contact shadows, and whole scenes modelled at millimetre scale. Which hits count near
/// the origin is the triangle test's business.)
const BOX_T_MIN: f32 = 0.0;

/// Lane tests in one instruction set: the packets' (below) and, through [`wide::WideTest`], the
/// one-ray traversal's eight-child box test. `max`/`min` are x86's `maxps`/`minps` (the second
/// operand when either is NaN) and no operation is fused, so every implementation gives the
/// same bits.
trait ChildBoxTest: Copy {
    /// Bit `l` set where `a[l] ≤ b[l]` (false for NaN), for the lanes of a packet's group.
    fn le(self, a: &Lanes, b: &Lanes) -> u32;
    /// Bit `l` set where `x[l] ≠ 0`.
    fn nonzero(self, x: &[u32; LANES]) -> u32;
}

/// [`ChildBoxTest`] four children at a time in glam's `Vec4` (SSE2 on x86-64, four scalars
/// elsewhere, where glam's `max`/`min` follow `maxps`/`minps` too): the baseline, and the
/// fallback where AVX2 is missing.
#[derive(Clone, Copy, Debug)]
struct FourWide;

impl ChildBoxTest for FourWide {
    #[inline(always)]
    fn le(self, a: &Lanes, b: &Lanes) -> u32 {
        let v = |x: &Lanes, k: usize| Vec4::new(x[k], x[k + 1], x[k + 2], x[k + 3]);
        v(a, 0).cmple(v(b, 0)).bitmask() | (v(a, 4).cmple(v(b, 4)).bitmask() << 4)
    }
    #[inline(always)]
    fn nonzero(self, x: &[u32; LANES]) -> u32 {
        x.iter().enumerate().fold(0, |m, (l, &v)| m | (((v != 0) as u32) << l))
    }
}

/// [`ChildBoxTest`] on all eight children at once in AVX registers (`vmaxps`/`vminps` and
/// `vcmpps` with the same operands and order as [`FourWide`]), through pulp's safe wrappers;
/// only constructed where the CPU has AVX2 (pulp's `V3` level, detected at run time).
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy, Debug)]
struct EightWide(pulp::x86::V3);

#[cfg(target_arch = "x86_64")]
impl ChildBoxTest for EightWide {
    #[inline(always)]
    fn le(self, a: &Lanes, b: &Lanes) -> u32 {
        use core::arch::x86_64::_CMP_LE_OQ;
        let avx = self.0.avx;
        let (a, b) = (pulp::cast(*a), pulp::cast(*b));
        avx._mm256_movemask_ps(avx._mm256_cmp_ps::<_CMP_LE_OQ>(a, b)) as u32
    }
    #[inline(always)]
    fn nonzero(self, x: &[u32; LANES]) -> u32 {
        let (avx, avx2) = (self.0.avx, self.0.avx2);
        let zero = avx2._mm256_cmpeq_epi32(pulp::cast(*x), avx._mm256_setzero_si256());
        !(avx._mm256_movemask_ps(avx._mm256_castsi256_ps(zero)) as u32) & 0xff
    }
}

/// Rays per group of a packet: eight `f32` lanes, one AVX register.
const LANES: usize = 8;
/// One number per ray of a group.
type Lanes = [f32; LANES];

#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn in_v3<R>(simd: pulp::x86::V3, f: impl FnOnce() -> R) -> R {
    struct Op<F>(F);
    impl<R, F: FnOnce() -> R> pulp::WithSimd for Op<F> {
        type Output = R;
        #[inline(always)]
        fn with_simd<S: pulp::Simd>(self, _simd: S) -> R {
            (self.0)()
        }
    }
    pulp::Simd::vectorize(simd, Op(f))
}

/// The scene's BVH and the triangle data its leaves reference.
pub struct Accel {
    /// obvhs's CWBVH re-laid with exact `f32` child boxes (module `wide`), which every query
    /// traverses.
    wide: wide::WideBvh,
    /// Triangles in BVH primitive order.
    tris: Vec<PackedTriangle>,
    /// AVX2 (pulp's x86-64-v3 level) when this CPU has it: the child-box test runs eight wide
    /// ([`EightWide`]); otherwise four wide ([`FourWide`]). Same answers either way.
    #[cfg(target_arch = "x86_64")]
    avx2: Option<pulp::x86::V3>,
    build_time: Duration,
}

impl std::fmt::Debug for Accel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Accel").field("primitives", &self.tris.len()).field("build_time", &self.build_time).finish()
    }
}

impl Accel {
    /// Runs `f` at pulp's x86-64-v3 level (AVX2, FMA, VEX encoding) when this CPU has it and
    /// it is enabled (see [`Accel::set_avx2`]), else as compiled for the baseline: what `f`
    /// inlines is compiled for that level. The path loop runs this way
    /// ([`crate::integrator::PathIntegrator::radiance_split`]), and so do the caustic light
    /// paths. The bits are the same at either level: no operation is contracted into an FMA.
    /// The ray queries enter the level again from inside the path loop, a call per ray: the
    /// call keeps the traversal's registers its own (inlined, it ran slower; `docs/experiments.md`).
    #[inline(always)]
    pub fn at_level<R>(&self, f: impl FnOnce() -> R) -> R {
        #[cfg(target_arch = "x86_64")]
        if let Some(simd) = self.avx2 {
            return in_v3(simd, f);
        }
        f()
    }

    /// Which child-box test the queries use: `"avx2 8-wide"` or `"4-wide"` (SSE2 on x86-64).
    pub fn simd_level(&self) -> &'static str {
        #[cfg(target_arch = "x86_64")]
        if self.avx2.is_some() {
            return "avx2 8-wide";
        }
        "4-wide"
    }

    /// Turns the AVX2 level off (`false`: the four-wide child-box test and the path loop
    /// compiled for baseline x86-64, as on a CPU without AVX2) or back on where the CPU has
    /// it. Answers are the same either way; this exists to prove that and to measure the
    /// difference.
    pub fn set_avx2(&mut self, enabled: bool) {
        #[cfg(target_arch = "x86_64")]
        {
            self.avx2 = if enabled { pulp::x86::V3::try_new() } else { None };
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = enabled;
    }

    /// Wall time of the BVH build.
    pub fn build_time(&self) -> Duration {
        self.build_time
    }

    /// Number of BVH primitive references (one per triangle: no spatial pre-splits).
    pub fn primitive_count(&self) -> usize {
        self.tris.len()
    }

    /// Bytes the traversal reads from: the wide nodes and the packed triangles (allocation
    /// slack left out; obvhs's CWBVH is dropped after the build).
    pub fn memory_bytes(&self) -> usize {
        self.wide.memory_bytes() + self.tris.len() * std::mem::size_of::<PackedTriangle>()
    }

    /// The two forms of `ray` the traversal reads: the box test's and the watertight test's.
    /// `None` when no hit is possible: a non-finite origin or direction, a zero direction, or
    /// `t_max ≤ 0`.
    #[inline(always)]
    fn wide_query(ray: &Ray, t_max: f32) -> Option<(wide::WideRay, WatertightRay)> {
        if !Self::can_hit(ray, t_max) {
            return None;
        }
        Some((wide::WideRay::new(ray.origin, ray.direction), WatertightRay::from_finite(ray)?))
    }

    /// Whether `ray` can hit anything before `t_max`: a finite origin and direction, a
    /// non-zero direction and `t_max > 0`.
    #[inline(always)]
    fn can_hit(ray: &Ray, t_max: f32) -> bool {
        // `v · 0` is ±0 for a finite `v` and NaN otherwise: one test for all six components.
        let z = ray.origin * 0.0 + ray.direction * 0.0;
        z.x + z.y + z.z == 0.0 && ray.direction != Vec3::ZERO && t_max > 0.0
    }

    /// The closest accepted hit with `t < t_max`. `alpha_test(prim, hit)` is consulted only
    /// for alpha-masked triangles and returns whether the surface is present there.
    #[inline(always)]
    pub fn closest_hit<F: Fn(u32, &TriangleHit) -> bool>(&self, ray: &Ray, t_max: f32, alpha_test: F) -> Option<Hit> {
        #[cfg(target_arch = "x86_64")]
        if let Some(simd) = self.avx2 {
            return wide::with_stack(#[inline(always)] |stack| in_v3(simd, #[inline(always)] || self.closest_hit_with(EightWide(simd), ray, t_max, alpha_test, stack)));
        }
        wide::with_stack(#[inline(always)] |stack| self.closest_hit_with(FourWide, ray, t_max, alpha_test, stack))
    }

    /// [`Accel::closest_hit`] with the traversal stack `stack` (the caller's, reused by each
    /// of its queries): for a caller that makes many queries in a row, such as the path loop.
    #[inline(always)]
    pub fn closest_hit_in<F: Fn(u32, &TriangleHit) -> bool>(&self, stack: &mut TraversalStack, ray: &Ray, t_max: f32, alpha_test: F) -> Option<Hit> {
        #[cfg(target_arch = "x86_64")]
        if let Some(simd) = self.avx2 {
            let (o, d) = (Vec3A::from(ray.origin), Vec3A::from(ray.direction));
            return in_v3(simd, #[inline(always)] move || self.closest_hit_with(EightWide(simd), &Ray::new(o.into(), d.into()), t_max, alpha_test, &mut stack.0));
        }
        self.closest_hit_with(FourWide, ray, t_max, alpha_test, &mut stack.0)
    }

    /// [`Accel::occluded`] with the traversal stack `stack`, as [`Accel::closest_hit_in`].
    #[inline(always)]
    pub fn occluded_in<F: Fn(u32, &TriangleHit) -> bool>(&self, stack: &mut TraversalStack, ray: &Ray, t_max: f32, alpha_test: F) -> bool {
        #[cfg(target_arch = "x86_64")]
        if let Some(simd) = self.avx2 {
            let (o, d) = (Vec3A::from(ray.origin), Vec3A::from(ray.direction));
            return in_v3(simd, #[inline(always)] move || self.occluded_with(EightWide(simd), &Ray::new(o.into(), d.into()), t_max, alpha_test, &mut stack.0));
        }
        self.occluded_with(FourWide, ray, t_max, alpha_test, &mut stack.0)
    }

    /// Whether any accepted hit exists with `t < t_max` (shadow rays).
    #[inline(always)]
    pub fn occluded<F: Fn(u32, &TriangleHit) -> bool>(&self, ray: &Ray, t_max: f32, alpha_test: F) -> bool {
        #[cfg(target_arch = "x86_64")]
        if let Some(simd) = self.avx2 {
            return wide::with_stack(#[inline(always)] |stack| in_v3(simd, #[inline(always)] || self.occluded_with(EightWide(simd), ray, t_max, alpha_test, stack)));
        }
        wide::with_stack(#[inline(always)] |stack| self.occluded_with(FourWide, ray, t_max, alpha_test, stack))
    }

    /// [`Accel::closest_hit`] with the child-box test `test` and the traversal stack `stack`.
    #[inline(always)]
    fn closest_hit_with<K: wide::WideTest, F: Fn(u32, &TriangleHit) -> bool>(&self, test: K, ray: &Ray, t_max: f32, alpha_test: F, stack: &mut [u64]) -> Option<Hit> {
        let (wray, wr) = Self::wide_query(ray, t_max)?;
        let mut best: Option<Hit> = None;
        let mut best_t = t_max;
        let dir = ray.direction;
        let leaf = |id: usize| {
            closest_candidate(&self.tris[id], &wr, dir, &mut best, &mut best_t, &alpha_test);
            // obvhs shrinks its ray only when t < tmax; ties keep it.
            std::ops::ControlFlow::Continue(Some(best_t))
        };
        wide::traverse::<true, _, _>(test, &self.wide, &wray, t_max, leaf, stack);
        best
    }

    /// [`Accel::occluded`] with the child-box test `test` and the traversal stack `stack`.
    #[inline(always)]
    fn occluded_with<K: wide::WideTest, F: Fn(u32, &TriangleHit) -> bool>(&self, test: K, ray: &Ray, t_max: f32, alpha_test: F, stack: &mut [u64]) -> bool {
        let Some((wray, wr)) = Self::wide_query(ray, t_max) else { return false };
        let dir = ray.direction;
        let mut hit = false;
        let leaf = |id: usize| {
            if occludes(&self.tris[id], &wr, dir, t_max, &alpha_test) {
                hit = true;
                std::ops::ControlFlow::Break(())
            } else {
                std::ops::ControlFlow::Continue(None)
            }
        };
        wide::traverse::<false, _, _>(test, &self.wide, &wray, t_max, leaf, stack);
        hit
    }
}

/// The closest-hit query's test of one triangle: `best` (at distance `best_t`) becomes `tri`'s
/// hit where that is accepted and nearer, or as near with a lower triangle index (so ties are
/// settled the same in any order of testing).
#[inline(always)]
fn closest_candidate<F: Fn(u32, &TriangleHit) -> bool>(tri: &PackedTriangle, wr: &WatertightRay, dir: Vec3, best: &mut Option<Hit>, best_t: &mut f32, alpha_test: &F) {
    let f = tri.flags;
    // Culling first (cheaper than the intersection test, rejects the same).
    let front = tri.n.dot(dir) < 0.0;
    if f & CULL_BACK != 0 && !front {
        return;
    }
    // Accept ties (t == best_t) so the lowest index can win them.
    let limit = if best.is_some() { crate::geometry::next_float_up(*best_t) } else { *best_t };
    let Some(h) = intersect_triangle(wr, tri.p, limit) else { return };
    let prim = tri.prim;
    if f & ALPHA_TEST != 0 && !alpha_test(prim, &h) {
        return;
    }
    let better = match best {
        None => h.t < *best_t,
        Some(b) => h.t < *best_t || (h.t == *best_t && prim < b.prim),
    };
    if better {
        *best = Some(Hit { prim, t: h.t, b: h.b, front });
        *best_t = h.t;
    }
}

/// The any-hit query's test of one triangle: whether `tri` blocks the ray before `t_max`.
#[inline(always)]
fn occludes<F: Fn(u32, &TriangleHit) -> bool>(tri: &PackedTriangle, wr: &WatertightRay, dir: Vec3, t_max: f32, alpha_test: &F) -> bool {
    let f = tri.flags;
    if f & CULL_BACK != 0 && tri.n.dot(dir) >= 0.0 {
        return false;
    }
    let Some(h) = intersect_triangle(wr, tri.p, t_max) else { return false };
    f & ALPHA_TEST == 0 || alpha_test(tri.prim, &h)
}

