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

use crate::PathTracerError;
use crate::geometry::{Ray, TriangleHit, WatertightRay, intersect_triangle};
use crate::scene::{AlphaMode, Scene};
use glam::{Vec3, Vec3A, Vec4};
use obvhs::cwbvh::builder::build_cwbvh;
use obvhs::ploc::{PlocSearchDistance, SortPrecision};
use obvhs::{Boundable, BvhBuildParams};
use serde::{Deserialize, Serialize};
use std::time::Duration;

mod wide;

/// PLOC search radius: how many neighbours (in Morton order) each cluster considers when
/// pairing. Larger finds better pairs and builds slower.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum PlocSearch {
    /// 1 neighbour (fast path).
    Minimum,
    /// 2.
    VeryLow,
    /// 6.
    Low,
    /// 14.
    Medium,
    /// 24.
    High,
    /// 32.
    VeryHigh,
}

/// Bits of the Morton codes sorted by the PLOC builder.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum MortonBits {
    /// 64-bit codes.
    U64,
    /// 128-bit codes (better for large, uneven scenes).
    U128,
}

/// BVH build settings (obvhs `BvhBuildParams`). Use a preset such as
/// [`AccelParams::medium_build`] unless you are tuning.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AccelParams {
    /// PLOC search radius.
    pub search_distance: PlocSearch,
    /// Below this tree depth, PLOC searches only 1 neighbour.
    pub search_depth_threshold: u32,
    /// Fraction of nodes reconsidered by parallel reinsertion (0 disables; 0.01–0.2 typical).
    pub reinsertion_batch_ratio: f32,
    /// Morton code width.
    pub morton_bits: MortonBits,
    /// Triangles per CWBVH leaf, 1 to 3.
    pub max_prims_per_leaf: u32,
}

impl AccelParams {
    /// Quickest build, slowest traversal (obvhs `fastest_build`).
    pub const fn fastest_build() -> Self {
        Self { search_distance: PlocSearch::Minimum, search_depth_threshold: 0, reinsertion_batch_ratio: 0.0, morton_bits: MortonBits::U64, max_prims_per_leaf: 1 }
    }
    /// Fast build with decent traversal (obvhs `fast_build`).
    pub const fn fast_build() -> Self {
        Self { search_distance: PlocSearch::Low, search_depth_threshold: 2, reinsertion_batch_ratio: 0.02, morton_bits: MortonBits::U64, max_prims_per_leaf: 3 }
    }
    /// Balanced (obvhs `medium_build`): about Embree's build time, faster traversal. The
    /// usual choice for dataset rendering.
    pub const fn medium_build() -> Self {
        Self { search_distance: PlocSearch::Medium, search_depth_threshold: 3, reinsertion_batch_ratio: 0.05, morton_bits: MortonBits::U64, max_prims_per_leaf: 3 }
    }
    /// Slow, higher-quality build (obvhs `slow_build`, without spatial pre-splits).
    pub const fn slow_build() -> Self {
        Self { search_distance: PlocSearch::High, search_depth_threshold: 2, reinsertion_batch_ratio: 0.2, morton_bits: MortonBits::U128, max_prims_per_leaf: 3 }
    }

    /// The obvhs parameters, after checking the ranges.
    pub fn to_obvhs(&self) -> Result<BvhBuildParams, PathTracerError> {
        if !(1..=3).contains(&self.max_prims_per_leaf) {
            return Err(PathTracerError::Config(format!("accel max_prims_per_leaf must be 1..=3, got {}", self.max_prims_per_leaf)));
        }
        if !(self.reinsertion_batch_ratio.is_finite() && self.reinsertion_batch_ratio >= 0.0) {
            return Err(PathTracerError::Config(format!("accel reinsertion_batch_ratio must be finite and >= 0, got {}", self.reinsertion_batch_ratio)));
        }
        Ok(BvhBuildParams {
            pre_split: false,
            ploc_search_distance: match self.search_distance {
                PlocSearch::Minimum => PlocSearchDistance::Minimum,
                PlocSearch::VeryLow => PlocSearchDistance::VeryLow,
                PlocSearch::Low => PlocSearchDistance::Low,
                PlocSearch::Medium => PlocSearchDistance::Medium,
                PlocSearch::High => PlocSearchDistance::High,
                PlocSearch::VeryHigh => PlocSearchDistance::VeryHigh,
            },
            search_depth_threshold: self.search_depth_threshold as usize,
            reinsertion_batch_ratio: self.reinsertion_batch_ratio,
            post_collapse_reinsertion_batch_ratio_multiplier: 0.0,
            sort_precision: match self.morton_bits {
                MortonBits::U64 => SortPrecision::U64,
                MortonBits::U128 => SortPrecision::U128,
            },
            max_prims_per_leaf: self.max_prims_per_leaf,
            collapse_traversal_cost: 3.0,
        })
    }
}

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

/// A triangle's bounding box, padded (see the module docs): the primitive the BVH is built over.
struct PaddedBox(obvhs::aabb::Aabb);

impl Boundable for PaddedBox {
    fn aabb(&self) -> obvhs::aabb::Aabb {
        self.0
    }
}

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

/// Depth of the traversal stack of the packet queries (node groups pending; obvhs uses 32 as
/// well).
const STACK_SIZE: usize = 32;

/// Rays per packet of the packet queries ([`Accel::closest_hits`], [`Accel::occluded_many`]):
/// one bit each of a `u64`.
pub const PACKET: usize = 64;
/// Rays per group of a packet: eight `f32` lanes, one AVX register.
const LANES: usize = 8;
/// Groups per packet.
const GROUPS: usize = PACKET / LANES;
/// One number per ray of a group.
type Lanes = [f32; LANES];

/// The groups of a packet's ray mask `rays` that hold any of its rays: `(group, its rays as
/// an 8-bit lane mask)`.
#[inline(always)]
fn groups(rays: u64) -> impl Iterator<Item = (usize, u32)> {
    (0..GROUPS).map(move |g| (g, (rays >> (g * LANES)) as u32 & 0xff)).filter(|&(_, m)| m != 0)
}

/// The set bits of `mask`, lowest first.
#[inline(always)]
fn bits(mut mask: u32) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (mask != 0).then(|| {
            let l = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            l
        })
    })
}

/// x86's `maxps` on one lane: `a` where `a > b`, else `b` (so `b` where either is NaN).
#[inline(always)]
fn max_ps(a: f32, b: f32) -> f32 {
    if a > b { a } else { b }
}

/// x86's `minps` on one lane: `a` where `a < b`, else `b`.
#[inline(always)]
fn min_ps(a: f32, b: f32) -> f32 {
    if a < b { a } else { b }
}

/// A packet's rays in structure-of-arrays form, `[axis][group][lane]`, as the lane tests
/// read them: origin, direction (−0 as +0), inverse direction (`1 / d` of the direction as
/// given, as the one-ray box test reads it), and the watertight test's permutation and shear.
struct RayLanes {
    o: [[Lanes; GROUPS]; 3],
    d: [[Lanes; GROUPS]; 3],
    inv: [[Lanes; GROUPS]; 3],
    kz: [[u32; LANES]; GROUPS],
    s: [[Lanes; GROUPS]; 3],
}

/// The child slots of `node` that each ray of group `g` enters before its `t_max`: for slot
/// `k`, bit `l` of the result's `k`-th entry for lane `l`. Each lane computes exactly what the
/// one-ray traversal's eight-child test ([`wide::WideTest`]) computes for that ray and slot
/// (the same operations in the same order, `maxps` and `minps` semantics), so it enters the
/// same children: every child whose box the ray touches in exact arithmetic.
#[inline(always)]
fn child_slots_lanes<K: ChildBoxTest>(test: K, node: &wide::WideNode, rl: &RayLanes, g: usize, t_max: &Lanes) -> [u32; 8] {
    let mut out = [0u32; 8];
    for (k, out) in out.iter_mut().enumerate() {
        let lo = [node.b[0][0][k], node.b[1][0][k], node.b[2][0][k]];
        let hi = [node.b[0][1][k], node.b[1][1][k], node.b[2][1][k]];
        let mut near = [0.0f32; LANES];
        let mut far = [0.0f32; LANES];
        #[allow(clippy::needless_range_loop, reason = "every array is indexed by lane, which is what vectorises")]
        for l in 0..LANES {
            let slab = |ax: usize| {
                let (o, inv) = (rl.o[ax][g][l], rl.inv[ax][g][l]);
                let (n, f) = if inv.is_sign_negative() { (hi[ax], lo[ax]) } else { (lo[ax], hi[ax]) };
                ((n - o) * inv, (f - o) * inv)
            };
            let (x, y, z) = (slab(0), slab(1), slab(2));
            near[l] = max_ps(x.0, max_ps(y.0, max_ps(z.0, BOX_T_MIN))) * (1.0 - wide::WIDEN);
            far[l] = min_ps(x.1, min_ps(y.1, min_ps(z.1, t_max[l]))) * (1.0 + wide::WIDEN);
        }
        *out = test.le(&near, &far);
    }
    out
}

/// The rays of group `g` that may hit `tri` before their `limit`: a lane is left out only
/// where [`intersect_triangle`] (after back-face culling) certainly rejects that ray, by the
/// same operations in the same order up to its range test on `t`; a lane with a zero edge
/// function (which the test recomputes in `f64`) or a NaN is kept. The rays kept are then
/// tested one by one by the exact test, so the answers are the one-ray queries' bits.
#[inline(always)]
fn triangle_lanes<K: ChildBoxTest>(test: K, tri: &PackedTriangle, rl: &RayLanes, g: usize, limit: &Lanes) -> u32 {
    let cull = tri.flags & CULL_BACK != 0;
    let mut keep = [0u32; LANES];
    #[allow(clippy::needless_range_loop, reason = "every array is indexed by lane, which is what vectorises")]
    for l in 0..LANES {
        let (ox, oy, oz) = (rl.o[0][g][l], rl.o[1][g][l], rl.o[2][g][l]);
        let (kz, sx, sy, sz) = (rl.kz[g][l], rl.s[0][g][l], rl.s[1][g][l], rl.s[2][g][l]);
        // `WatertightRay::permuted`, then the shear of `intersect_triangle`.
        let tr = |v: Vec3| {
            let (x, y, z) = (v.x - ox, v.y - oy, v.z - oz);
            let (px, py, pz) = if kz == 0 { (y, z, x) } else if kz == 1 { (z, x, y) } else { (x, y, z) };
            (px + sx * pz, py + sy * pz, pz)
        };
        let (p0x, p0y, p0z) = tr(tri.p[0]);
        let (p1x, p1y, p1z) = tr(tri.p[1]);
        let (p2x, p2y, p2z) = tr(tri.p[2]);
        let e0 = p1x * p2y - p1y * p2x;
        let e1 = p2x * p0y - p2y * p0x;
        let e2 = p0x * p1y - p0y * p1x;
        let zero = (e0 == 0.0) | (e1 == 0.0) | (e2 == 0.0);
        let mixed = ((e0 < 0.0) | (e1 < 0.0) | (e2 < 0.0)) & ((e0 > 0.0) | (e1 > 0.0) | (e2 > 0.0));
        let det = e0 + e1 + e2;
        let t_scaled = e0 * (p0z * sz) + e1 * (p1z * sz) + e2 * (p2z * sz);
        let bound = limit[l] * det;
        let outside = ((det < 0.0) & ((t_scaled >= 0.0) | (t_scaled < bound))) | ((det > 0.0) & ((t_scaled <= 0.0) | (t_scaled > bound)));
        // `Vec3::dot`'s order; the direction's −0 as +0 changes no comparison with 0.
        let front = tri.n.x * rl.d[0][g][l] + tri.n.y * rl.d[1][g][l] + tri.n.z * rl.d[2][g][l] < 0.0;
        let kept = (!cull | front) & (zero | !(mixed | (det == 0.0) | outside));
        keep[l] = if kept { !0 } else { 0 };
    }
    test.nonzero(&keep)
}

/// What a packet traversal ([`traverse_packet`]) asks of its query.
trait PacketQuery {
    /// Group `g`'s current far limits (the box tests enter only boxes nearer than them).
    fn t_max(&self, g: usize) -> &Lanes;
    /// Tests BVH primitive `id` against the rays `rays` (bit `r` for ray `r`); returns those
    /// of them that are finished (an any-hit query's blocked rays), which leave the packet.
    fn leaf<K: ChildBoxTest>(&mut self, test: K, rl: &RayLanes, id: usize, rays: u64) -> u64;
}

/// Traverses the BVH with a packet of rays (those of `active`, in lanes `rl`): each node is
/// loaded once for all the rays that enter it, the rays test its children's boxes group by
/// group of eight lanes ([`child_slots_lanes`], each lane the box test of the one-ray
/// traversal with the ray's own current limit) and the triangles of the leaves they enter.
/// A ray therefore tests every triangle whose box it enters before its current limit, as
/// [`traverse`] does, so the closest hit (ties to the lowest index) and the any-hit answer
/// are the same bits in this order as in that one. Nodes are visited front to back for the
/// packet's first ray.
#[inline(always)]
fn traverse_packet<K: ChildBoxTest, Q: PacketQuery>(test: K, bvh: &wide::WideBvh, rl: &RayLanes, mut active: u64, q: &mut Q) {
    if bvh.nodes.is_empty() || active == 0 {
        return;
    }
    // Slot `oct ^ j` is the `j`-th nearest for a ray in octant `oct` (sign bits x, y, z): the
    // wide nodes keep the CWBVH's slots, which its builder ordered so.
    let first = active.trailing_zeros() as usize;
    let dir = |ax: usize| rl.d[ax][first / LANES][first % LANES];
    let oct = (((dir(0) < 0.0) as usize) << 2) | (((dir(1) < 0.0) as usize) << 1) | ((dir(2) < 0.0) as usize);
    // Each node popped pushes at most 8 children: 8 per level of [`STACK_SIZE`] levels.
    let mut stack = [(0u32, 0u64); 8 * STACK_SIZE];
    stack[0] = (0, active);
    let mut sp = 1usize;
    while sp > 0 {
        sp -= 1;
        let (n, m) = stack[sp];
        let rays = m & active;
        if rays == 0 {
            continue;
        }
        let node = &bvh.nodes[n as usize];
        let mut slots = [0u64; 8];
        for (g, in_group) in groups(rays) {
            let hits = child_slots_lanes(test, node, rl, g, q.t_max(g));
            for (s, h) in slots.iter_mut().zip(hits) {
                *s |= ((h & in_group) as u64) << (g * LANES);
            }
        }
        // The leaves' triangles first, then the inner children, nearest on top of the stack.
        for j in 0..8 {
            let k = oct ^ j;
            if slots[k] == 0 {
                continue;
            }
            let Err((first, count)) = node.child(k) else { continue };
            for id in first..first + count {
                let rays = slots[k] & active;
                if rays == 0 {
                    break;
                }
                active &= !q.leaf(test, rl, id as usize, rays);
            }
            if active == 0 {
                return;
            }
        }
        for j in (0..8).rev() {
            let k = oct ^ j;
            if slots[k] != 0
                && let Ok(child) = node.child(k)
            {
                stack[sp] = (child, slots[k]);
                sp += 1;
            }
        }
    }
}

/// The closest-hit query of a packet ([`Accel::closest_hits`]).
struct ClosestPacket<'a, F> {
    tris: &'a [PackedTriangle],
    wr: [WatertightRay; PACKET],
    dir: [Vec3; PACKET],
    best: [Option<Hit>; PACKET],
    /// Each ray's distance to its best hit so far (the box tests' limit), by group.
    best_t: [Lanes; GROUPS],
    /// The triangle test's limit: `best_t`, one ulp further once there is a hit (ties).
    limit: [Lanes; GROUPS],
    alpha_test: F,
}

impl<F: Fn(usize, u32, &TriangleHit) -> bool> PacketQuery for ClosestPacket<'_, F> {
    #[inline(always)]
    fn t_max(&self, g: usize) -> &Lanes {
        &self.best_t[g]
    }
    #[inline(always)]
    fn leaf<K: ChildBoxTest>(&mut self, test: K, rl: &RayLanes, id: usize, rays: u64) -> u64 {
        let tri = &self.tris[id];
        for (g, in_group) in groups(rays) {
            for l in bits(triangle_lanes(test, tri, rl, g, &self.limit[g]) & in_group) {
                let r = g * LANES + l;
                let alpha_test = |prim: u32, h: &TriangleHit| (self.alpha_test)(r, prim, h);
                let (best, best_t) = (&mut self.best[r], &mut self.best_t[g][l]);
                closest_candidate(tri, &self.wr[r], self.dir[r], best, best_t, &alpha_test);
                if best.is_some() {
                    self.limit[g][l] = crate::geometry::next_float_up(*best_t);
                }
            }
        }
        0
    }
}

/// The any-hit query of a packet ([`Accel::occluded_many`]).
struct OccludedPacket<'a, F> {
    tris: &'a [PackedTriangle],
    wr: [WatertightRay; PACKET],
    dir: [Vec3; PACKET],
    t_max: [Lanes; GROUPS],
    /// The rays found blocked so far.
    blocked: u64,
    alpha_test: F,
}

impl<F: Fn(usize, u32, &TriangleHit) -> bool> PacketQuery for OccludedPacket<'_, F> {
    #[inline(always)]
    fn t_max(&self, g: usize) -> &Lanes {
        &self.t_max[g]
    }
    #[inline(always)]
    fn leaf<K: ChildBoxTest>(&mut self, test: K, rl: &RayLanes, id: usize, rays: u64) -> u64 {
        let tri = &self.tris[id];
        let mut blocked = 0u64;
        for (g, in_group) in groups(rays) {
            for l in bits(triangle_lanes(test, tri, rl, g, &self.t_max[g]) & in_group) {
                let r = g * LANES + l;
                let alpha_test = |prim: u32, h: &TriangleHit| (self.alpha_test)(r, prim, h);
                if occludes(tri, &self.wr[r], self.dir[r], self.t_max[g][l], &alpha_test) {
                    blocked |= 1u64 << r;
                }
            }
        }
        self.blocked |= blocked;
        blocked
    }
}

/// Runs `f` inside pulp's `vectorize` at the x86-64-v3 level `simd`: what `f` inlines (the
/// whole traversal for a query, the whole path loop for [`Accel::at_level`]) is compiled with
/// AVX2 and FMA enabled.
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
    /// Builds the BVH over every triangle of `scene` (in parallel, on the current rayon
    /// pool). The scene must have been validated (indices and materials in range, finite
    /// positions); an out-of-range index is reported as an error, not a panic.
    pub fn build(scene: &Scene, params: &AccelParams) -> Result<Accel, PathTracerError> {
        let obvhs_params = params.to_obvhs()?;
        let mesh = &scene.mesh;
        let nv = mesh.positions.len();
        let mut tris = Vec::with_capacity(mesh.indices.len());
        for (k, idx) in mesh.indices.iter().enumerate() {
            if idx.iter().any(|&i| i as usize >= nv) {
                return Err(PathTracerError::Config(format!("triangle {k} references a vertex out of range")));
            }
            let p = idx.map(|i| mesh.positions[i as usize]);
            if !p.iter().all(|v| v.is_finite()) {
                return Err(PathTracerError::Config(format!("triangle {k} has a non-finite vertex")));
            }
            tris.push(p);
        }
        let tri_flags: Vec<u32> = (0..mesh.indices.len())
            .map(|k| {
                let m = mesh.material.get(k).and_then(|&m| scene.materials.get(m as usize));
                match m {
                    Some(m) => {
                        let mut f = 0;
                        if !m.double_sided {
                            f |= CULL_BACK;
                        }
                        if matches!(m.alpha_mode, AlphaMode::Mask { .. } | AlphaMode::Blend) {
                            f |= ALPHA_TEST;
                        }
                        f
                    }
                    None => CULL_BACK,
                }
            })
            .collect();
        if tris.is_empty() {
            return Ok(Accel {
                wide: wide::WideBvh::default(),
                tris: Vec::new(),
                #[cfg(target_arch = "x86_64")]
                avx2: pulp::x86::V3::try_new(),
                build_time: Duration::ZERO,
            });
        }
        let max_abs = tris.iter().flatten().fold(0.0f32, |m, v| m.max(v.abs().max_element()));
        // Box areas (the SAH cost) must stay finite in f32: beyond ~1e19 they overflow to
        // infinity and the BVH builder's decisions become meaningless (found by the import
        // fuzzer). Coordinates are relative to the scene's centre, so this bounds the scene's
        // size, not its position.
        if max_abs > MAX_LOCAL_COORDINATE {
            return Err(PathTracerError::Config(format!(
                "scene '{}' spans {max_abs:e} m from its centre; at most {MAX_LOCAL_COORDINATE:e} m is supported in f32 geometry",
                scene.name
            )));
        }
        let pad = Vec3A::splat(2e-6 * max_abs.max(f32::MIN_POSITIVE));
        let boxes: Vec<PaddedBox> = tris
            .iter()
            .map(|p| {
                let lo = p[0].min(p[1]).min(p[2]);
                let hi = p[0].max(p[1]).max(p[2]);
                PaddedBox(obvhs::aabb::Aabb::new(Vec3A::from(lo) - pad, Vec3A::from(hi) + pad))
            })
            .collect();
        let start = std::time::Instant::now();
        let mut core = Duration::ZERO;
        let bvh = build_cwbvh(&boxes, obvhs_params, &mut core);
        let bvh_tris: Vec<PackedTriangle> = bvh
            .primitive_indices
            .iter()
            .map(|&i| {
                let p = tris[i as usize];
                PackedTriangle { p, n: (p[1] - p[0]).cross(p[2] - p[0]), prim: i, flags: tri_flags[i as usize] }
            })
            .collect();
        let wide = wide::WideBvh::from_cwbvh(&bvh, &bvh_tris, pad.x).map_err(|e| PathTracerError::Config(format!("scene '{}': BVH: {e}", scene.name)))?;
        // The build time includes the wide tree's boxes.
        let build_time = start.elapsed();
        Ok(Accel {
            wide,
            tris: bvh_tris,
            #[cfg(target_arch = "x86_64")]
            avx2: pulp::x86::V3::try_new(),
            build_time,
        })
    }

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

    /// [`Accel::closest_hit`] for many rays: `out[r]` is `closest_hit(&rays[r], t_max, …)`, the
    /// same bits, found by packets of up to [`PACKET`] rays that load each node once for all
    /// the rays entering it (the gain is in coherent rays: a pixel's camera rays).
    /// `alpha_test(r, prim, hit)` is ray `r`'s alpha test.
    ///
    /// # Panics
    /// If `rays` and `out` differ in length.
    #[inline(always)]
    pub fn closest_hits<F: Fn(usize, u32, &TriangleHit) -> bool>(&self, rays: &[Ray], t_max: f32, alpha_test: F, out: &mut [Option<Hit>]) {
        assert_eq!(rays.len(), out.len(), "closest_hits: {} rays, {} results", rays.len(), out.len());
        #[cfg(target_arch = "x86_64")]
        if let Some(simd) = self.avx2 {
            return in_v3(simd, #[inline(always)] || self.closest_hits_with(EightWide(simd), rays, t_max, &alpha_test, out));
        }
        self.closest_hits_with(FourWide, rays, t_max, &alpha_test, out)
    }

    /// [`Accel::occluded`] for many rays: `out[r]` is `occluded(&rays[r], t_max[r], …)`, by
    /// packets as in [`Accel::closest_hits`].
    ///
    /// # Panics
    /// If the slices differ in length.
    #[inline(always)]
    pub fn occluded_many<F: Fn(usize, u32, &TriangleHit) -> bool>(&self, rays: &[Ray], t_max: &[f32], alpha_test: F, out: &mut [bool]) {
        assert!(rays.len() == out.len() && rays.len() == t_max.len(), "occluded_many: {} rays, {} limits, {} results", rays.len(), t_max.len(), out.len());
        #[cfg(target_arch = "x86_64")]
        if let Some(simd) = self.avx2 {
            return in_v3(simd, #[inline(always)] || self.occluded_many_with(EightWide(simd), rays, t_max, &alpha_test, out));
        }
        self.occluded_many_with(FourWide, rays, t_max, &alpha_test, out)
    }

    /// A packet's rays (`rays`, at most [`PACKET`], with limits `t_max(r)`) in lanes and in
    /// the watertight test's form, their directions, and the mask of those that can hit
    /// anything ([`Accel::wide_query`]); the other lanes hold a placeholder ray.
    #[inline(always)]
    fn packet_rays(rays: &[Ray], t_max: impl Fn(usize) -> f32) -> (RayLanes, [WatertightRay; PACKET], [Vec3; PACKET], u64) {
        let placeholder = WatertightRay::from_finite(&Ray::new(Vec3::ZERO, Vec3::Z)).expect("+z is a valid direction");
        let mut rl = RayLanes { o: [[[0.0; LANES]; GROUPS]; 3], d: [[[0.0; LANES]; GROUPS]; 3], inv: [[[0.0; LANES]; GROUPS]; 3], kz: [[2; LANES]; GROUPS], s: [[[0.0; LANES]; GROUPS]; 3] };
        let mut wrs = [placeholder; PACKET];
        let mut dirs = [Vec3::Z; PACKET];
        let mut valid = 0u64;
        for (r, ray) in rays.iter().enumerate().take(PACKET) {
            if let Some((o, w)) = Self::wide_query(ray, t_max(r)) {
                let (g, l) = (r / LANES, r % LANES);
                let (kz, s) = w.shear();
                // `+ 0.0` turns −0 into +0 (the octant of the packet's first ray).
                let d = ray.direction + Vec3::ZERO;
                for (ax, &s) in s.iter().enumerate() {
                    rl.o[ax][g][l] = o.o[ax];
                    rl.d[ax][g][l] = d[ax];
                    rl.inv[ax][g][l] = o.inv[ax];
                    rl.s[ax][g][l] = s;
                }
                rl.kz[g][l] = kz;
                wrs[r] = w;
                dirs[r] = ray.direction;
                valid |= 1u64 << r;
            }
        }
        (rl, wrs, dirs, valid)
    }

    /// [`Accel::closest_hits`] with the child-box test `test`.
    #[inline(always)]
    fn closest_hits_with<K: ChildBoxTest, F: Fn(usize, u32, &TriangleHit) -> bool>(&self, test: K, rays: &[Ray], t_max: f32, alpha_test: &F, out: &mut [Option<Hit>]) {
        if self.wide.nodes.is_empty() {
            out.fill(None);
            return;
        }
        for (c, (rays, out)) in rays.chunks(PACKET).zip(out.chunks_mut(PACKET)).enumerate() {
            let (rl, wr, dir, valid) = Self::packet_rays(rays, |_| t_max);
            let base = c * PACKET;
            let mut q = ClosestPacket {
                tris: &self.tris,
                wr,
                dir,
                best: [None; PACKET],
                best_t: [[t_max; LANES]; GROUPS],
                limit: [[t_max; LANES]; GROUPS],
                alpha_test: |r: usize, prim: u32, h: &TriangleHit| alpha_test(base + r, prim, h),
            };
            traverse_packet(test, &self.wide, &rl, valid, &mut q);
            out.copy_from_slice(&q.best[..out.len()]);
        }
    }

    /// [`Accel::occluded_many`] with the child-box test `test`.
    #[inline(always)]
    fn occluded_many_with<K: ChildBoxTest, F: Fn(usize, u32, &TriangleHit) -> bool>(&self, test: K, rays: &[Ray], t_max: &[f32], alpha_test: &F, out: &mut [bool]) {
        if self.wide.nodes.is_empty() {
            out.fill(false);
            return;
        }
        for (c, ((rays, t_max), out)) in rays.chunks(PACKET).zip(t_max.chunks(PACKET)).zip(out.chunks_mut(PACKET)).enumerate() {
            let (rl, wr, dir, valid) = Self::packet_rays(rays, |r| t_max[r]);
            let base = c * PACKET;
            let mut limits = [[0.0; LANES]; GROUPS];
            for (r, &t) in t_max.iter().enumerate() {
                limits[r / LANES][r % LANES] = t;
            }
            let mut q = OccludedPacket { tris: &self.tris, wr, dir, t_max: limits, blocked: 0, alpha_test: |r: usize, prim: u32, h: &TriangleHit| alpha_test(base + r, prim, h) };
            traverse_packet(test, &self.wide, &rl, valid, &mut q);
            for (r, o) in out.iter_mut().enumerate() {
                *o = q.blocked & (1u64 << r) != 0;
            }
        }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampler::{Sampler, sample_uniform_sphere};
    use crate::scene::{Aabb, Material, Mesh};
    use glam::DVec3;

    /// A soup of `n` random triangles in the unit cube (half single-sided, half
    /// double-sided), plus a grid of quads sharing edges and vertices (watertightness).
    fn soup(n: usize) -> Scene {
        let mut rng = Sampler::new(3, 0, 0, 0);
        let mut positions = Vec::new();
        let mut indices = Vec::new();
        let mut material = Vec::new();
        for k in 0..n {
            let c = Vec3::new(rng.next_1d(), rng.next_1d(), rng.next_1d()) * 2.0 - 1.0;
            let size = 0.05 + 0.3 * rng.next_1d();
            let base = positions.len() as u32;
            for _ in 0..3 {
                positions.push(c + size * sample_uniform_sphere(rng.next_2d()));
            }
            indices.push([base, base + 1, base + 2]);
            material.push((k % 2) as u32);
        }
        let g = 6u32;
        let base = positions.len() as u32;
        for j in 0..=g {
            for i in 0..=g {
                positions.push(Vec3::new(i as f32 / g as f32 * 2.0 - 1.0, -0.9, j as f32 / g as f32 * 2.0 - 1.0));
            }
        }
        for j in 0..g {
            for i in 0..g {
                let v = base + j * (g + 1) + i;
                indices.push([v, v + g + 1, v + 1]);
                indices.push([v + 1, v + g + 1, v + g + 2]);
                material.extend([1, 1]);
            }
        }
        let bounds = positions.iter().fold(Aabb::EMPTY, |a, p| a.union_point(*p));
        let single = Material::gltf_default();
        let double = Material { double_sided: true, ..Material::gltf_default() };
        Scene {
            name: "soup".into(),
            origin: DVec3::ZERO,
            mesh: Mesh { positions, indices, material, ..Default::default() },
            materials: vec![single, double],
            textures: vec![],
            lights: vec![],
            cameras: vec![],
            bounds,
            warnings: vec![],
        }
    }

    /// The closest hit and the any-hit answer by testing every triangle, with the same rules
    /// (culling, ties to the lowest index).
    fn brute_force(scene: &Scene, ray: &Ray, t_max: f32) -> (Option<(u32, f32)>, bool) {
        let wr = WatertightRay::new(ray).unwrap();
        let mut best: Option<(u32, f32)> = None;
        let mut any = false;
        for (k, idx) in scene.mesh.indices.iter().enumerate() {
            let p = idx.map(|i| scene.mesh.positions[i as usize]);
            let front = (p[1] - p[0]).cross(p[2] - p[0]).dot(ray.direction) < 0.0;
            if !scene.materials[scene.mesh.material[k] as usize].double_sided && !front {
                continue;
            }
            let Some(h) = intersect_triangle(&wr, p, t_max) else { continue };
            any = true;
            if best.is_none_or(|(bk, bt)| h.t < bt || (h.t == bt && (k as u32) < bk)) {
                best = Some((k as u32, h.t));
            }
        }
        (best, any)
    }

    /// The traversal with one stack entry (every further pending child spilled to the heap)
    /// answers exactly as with the full stack, and as the brute force, in trees from a few
    /// to thousands of triangles; so do the queries with a caller's stack, reused by every
    /// query of both kinds without being cleared.
    #[test]
    fn a_traversal_that_spills_its_stack_answers_the_same() {
        for (n, params) in [(40, AccelParams::medium_build()), (3000, AccelParams::fastest_build()), (3000, AccelParams::slow_build())] {
            let scene = soup(n);
            let accel = Accel::build(&scene, &params).unwrap();
            let mut rng = Sampler::new(17, 0, 3, 0);
            let mut stack = TraversalStack::default();
            let mut hits = 0;
            for k in 0..1500 {
                let o = Vec3::new(rng.next_1d(), rng.next_1d(), rng.next_1d()) * 3.0 - 1.5;
                let ray = Ray::new(o, sample_uniform_sphere(rng.next_2d()));
                let t_max = if k % 4 == 0 { 0.3 + rng.next_1d() } else { f32::INFINITY };
                let key = |h: Option<Hit>| h.map(|h| (h.prim, h.t.to_bits(), h.b.map(f32::to_bits), h.front));
                let full = key(accel.closest_hit(&ray, t_max, |_, _| true));
                let spilled = key(accel.closest_hit_with(FourWide, &ray, t_max, |_, _| true, &mut [0; 1]));
                assert_eq!(spilled, full, "{n} triangles, ray {k}");
                assert_eq!(key(accel.closest_hit_in(&mut stack, &ray, t_max, |_, _| true)), full, "{n} triangles, ray {k}");
                let occluded = accel.occluded(&ray, t_max, |_, _| true);
                assert_eq!(accel.occluded_with(FourWide, &ray, t_max, |_, _| true, &mut [0; 1]), occluded, "{n} triangles, ray {k}");
                assert_eq!(accel.occluded_in(&mut stack, &ray, t_max, |_, _| true), occluded, "{n} triangles, ray {k}");
                let (want, any) = brute_force(&scene, &ray, t_max);
                assert_eq!(full.map(|f| (f.0, f32::from_bits(f.1))), want, "{n} triangles, ray {k}");
                assert_eq!(occluded, any);
                hits += want.is_some() as u32;
            }
            assert!(hits > 100, "{n} triangles: too few hits ({hits})");
        }
    }

    #[test]
    fn a_query_made_inside_another_answers_as_alone() {
        // The one-ray queries share their thread's traversal stack; an alpha test that makes
        // a query of its own (while the outer query's stack is in use) gets a fresh one, and
        // both answer as when made alone. Every triangle alpha-masked, so that the alpha test
        // runs (it keeps every surface).
        let mut scene = soup(500);
        for m in &mut scene.materials {
            m.alpha_mode = crate::scene::AlphaMode::Mask { cutoff: 0.5 };
        }
        let accel = Accel::build(&scene, &AccelParams::medium_build()).unwrap();
        let mut rng = Sampler::new(29, 0, 7, 0);
        let mut inner_queries = 0;
        for k in 0..2000 {
            let o = Vec3::new(rng.next_1d(), rng.next_1d(), rng.next_1d()) * 3.0 - 1.5;
            let ray = Ray::new(o, sample_uniform_sphere(rng.next_2d()));
            let other = Ray::new(-o, sample_uniform_sphere(rng.next_2d()));
            let key = |h: Option<Hit>| h.map(|h| (h.prim, h.t.to_bits()));
            let (alone, other_alone) = (key(accel.closest_hit(&ray, f32::INFINITY, |_, _| true)), key(accel.closest_hit(&other, f32::INFINITY, |_, _| true)));
            let other_blocked = accel.occluded(&other, f32::INFINITY, |_, _| true);
            let nested = std::cell::Cell::new(0);
            let got = key(accel.closest_hit(&ray, f32::INFINITY, |_, _| {
                assert_eq!(key(accel.closest_hit(&other, f32::INFINITY, |_, _| true)), other_alone, "ray {k}");
                assert_eq!(accel.occluded(&other, f32::INFINITY, |_, _| true), other_blocked, "ray {k}");
                nested.set(nested.get() + 1);
                true
            }));
            let blocked = accel.occluded(&ray, f32::INFINITY, |_, _| {
                assert_eq!(key(accel.closest_hit(&other, f32::INFINITY, |_, _| true)), other_alone, "ray {k}");
                true
            });
            assert_eq!(got, alone, "ray {k}");
            assert_eq!(blocked, alone.is_some(), "ray {k}");
            inner_queries += nested.get();
        }
        assert!(inner_queries > 100, "{inner_queries} nested queries");
    }

    #[test]
    fn traversal_finds_exactly_what_testing_every_triangle_finds() {
        let scene = soup(300);
        for params in [AccelParams::fastest_build(), AccelParams::medium_build()] {
            let accel = Accel::build(&scene, &params).unwrap();
            let mut rng = Sampler::new(11, 0, 1, 0);
            let mut hits = 0;
            for k in 0..4000 {
                let o = Vec3::new(rng.next_1d(), rng.next_1d(), rng.next_1d()) * 3.0 - 1.5;
                // Some axis-aligned directions (zero components) as well as general ones.
                let d = if k % 10 == 0 { [Vec3::X, -Vec3::Y, Vec3::Z, -Vec3::X][k / 10 % 4] } else { sample_uniform_sphere(rng.next_2d()) };
                let ray = Ray::new(o, d);
                let t_max = if k % 3 == 0 { 0.5 + rng.next_1d() } else { f32::INFINITY };
                let (want, any) = brute_force(&scene, &ray, t_max);
                let got = accel.closest_hit(&ray, t_max, |_, _| true).map(|h| (h.prim, h.t));
                assert_eq!(got, want, "ray {k}: {ray:?} t_max {t_max}");
                assert_eq!(accel.occluded(&ray, t_max, |_, _| true), any, "ray {k}: {ray:?} t_max {t_max}");
                hits += want.is_some() as u32;
            }
            assert!(hits > 500, "too few hits ({hits}) to mean anything");
        }
    }

    /// The eight-wide (AVX2, where the CPU has it) and the four-wide child-box tests give the
    /// same hits bit for bit, and exactly the watertight test's on every triangle (the brute
    /// force), hits near the ray's origin included: rays aimed at
    /// the shared vertices and edges of the quad grid and at random points, in scenes scaled
    /// from 1e-4 to 1e5.
    #[test]
    fn eight_and_four_wide_box_tests_answer_as_the_brute_force_at_any_scale() {
        for scale in [1e-4f32, 1.0, 1e5] {
            let mut scene = soup(200);
            for p in &mut scene.mesh.positions {
                *p *= scale;
            }
            let accel = Accel::build(&scene, &AccelParams::medium_build()).unwrap();
            let mut four = Accel::build(&scene, &AccelParams::medium_build()).unwrap();
            four.set_avx2(false);
            assert_eq!(four.simd_level(), "4-wide");
            let mut rng = Sampler::new(5, 0, 2, 0);
            let mut hits = 0;
            for k in 0..3000 {
                let o = (Vec3::new(rng.next_1d(), rng.next_1d(), rng.next_1d()) * 3.0 - 1.5) * scale;
                let g = 6.0;
                let (i, j) = ((rng.next_1d() * 7.0).floor(), (rng.next_1d() * 7.0).floor());
                let vertex = |i: f32, j: f32| Vec3::new(i / g * 2.0 - 1.0, -0.9, j / g * 2.0 - 1.0) * scale;
                let target = match k % 3 {
                    0 => vertex(i, j),
                    1 => vertex(i, j).lerp(vertex(i + 1.0, j + 1.0), 0.5),
                    _ => (Vec3::new(rng.next_1d(), rng.next_1d(), rng.next_1d()) * 2.0 - 1.0) * scale,
                };
                let ray = Ray::new(o, (target - o).normalize());
                if !ray.direction.is_finite() {
                    continue;
                }
                let full = |a: &Accel| a.closest_hit(&ray, f32::INFINITY, |_, _| true).map(|h| (h.prim, h.t.to_bits(), h.b.map(f32::to_bits), h.front));
                assert_eq!(full(&accel), full(&four), "scale {scale} ray {k}: 8-wide and 4-wide differ");
                let occluded = accel.occluded(&ray, f32::INFINITY, |_, _| true);
                assert_eq!(four.occluded(&ray, f32::INFINITY, |_, _| true), occluded, "scale {scale} ray {k}");
                hits += full(&accel).is_some() as u32;
                {
                    let (want, any) = brute_force(&scene, &ray, f32::INFINITY);
                    let got = accel.closest_hit(&ray, f32::INFINITY, |_, _| true).map(|h| (h.prim, h.t));
                    assert_eq!(got, want, "scale {scale} ray {k}: {ray:?}");
                    assert_eq!(occluded, any, "scale {scale} ray {k}");
                }
            }
            assert!(hits > 1000, "scale {scale}: too few hits ({hits})");
        }
    }

    /// The packet queries answer every ray exactly as the one-ray queries do (triangle, `t`,
    /// barycentrics and face, bit for bit; the any-hit answer): coherent bundles (one origin,
    /// a narrow cone, as a pixel's camera rays), incoherent rays, rays that cannot hit
    /// (non-finite, zero direction, `t_max ≤ 0`), finite limits, alpha-tested triangles with
    /// an answer that depends on the ray, batches across packet boundaries, in a shallow and
    /// a deep tree, with both child-box tests.
    #[test]
    fn packet_queries_answer_each_ray_as_the_one_ray_queries() {
        for (n, params) in [(300, AccelParams::medium_build()), (5000, AccelParams::fastest_build())] {
            let mut scene = soup(n);
            // Material 1 (double-sided, and the grid) alpha-tested.
            scene.materials[1].alpha_mode = AlphaMode::Mask { cutoff: 0.5 };
            for avx2 in [true, false] {
                let mut accel = Accel::build(&scene, &params).unwrap();
                accel.set_avx2(avx2);
                let mut rng = Sampler::new(17, 0, n as u64, avx2 as u32);
                for (batch, len) in [0usize, 1, 7, 64, 65, 200].into_iter().enumerate() {
                    let coherent = batch % 2 == 0;
                    let o0 = Vec3::new(rng.next_1d(), rng.next_1d(), rng.next_1d()) * 3.0 - 1.5;
                    // Aimed into the soup, so that a bundle hits as well as misses.
                    let d0 = ((Vec3::new(rng.next_1d(), rng.next_1d(), rng.next_1d()) - 0.5) - o0).normalize();
                    let mut rays = Vec::new();
                    let mut limits = Vec::new();
                    for k in 0..len {
                        let ray = match k % 23 {
                            5 => Ray::new(Vec3::new(f32::NAN, 0.0, 0.0), Vec3::X),
                            11 => Ray::new(o0, Vec3::ZERO),
                            17 => Ray::new(o0, Vec3::new(0.0, f32::INFINITY, 0.0)),
                            // At the grid's shared vertices and edges (zero edge functions).
                            19 | 20 => {
                                let (i, j) = ((rng.next_1d() * 7.0).floor(), (rng.next_1d() * 7.0).floor());
                                let vertex = |i: f32, j: f32| Vec3::new(i / 6.0 * 2.0 - 1.0, -0.9, j / 6.0 * 2.0 - 1.0);
                                let target = if k % 23 == 19 { vertex(i, j) } else { vertex(i, j).lerp(vertex(i + 1.0, j), 0.5) };
                                // Straight down onto it (the edge functions exactly zero), or from the bundle's origin.
                                if k % 2 == 0 { Ray::new(target + 1.9 * Vec3::Y, -Vec3::Y) } else { Ray::new(o0, (target - o0).normalize()) }
                            }
                            _ if coherent => Ray::new(o0 + 1e-3 * Vec3::new(rng.next_1d(), rng.next_1d(), rng.next_1d()), (d0 + 0.05 * sample_uniform_sphere(rng.next_2d())).normalize()),
                            _ => Ray::new(Vec3::new(rng.next_1d(), rng.next_1d(), rng.next_1d()) * 3.0 - 1.5, sample_uniform_sphere(rng.next_2d())),
                        };
                        rays.push(ray);
                        limits.push(match k % 5 {
                            0 => 0.5 + rng.next_1d(),
                            1 if k % 7 == 0 => 0.0,
                            _ => f32::INFINITY,
                        });
                    }
                    // The alpha test depends on the ray and the hit.
                    let alpha = |r: usize, prim: u32, h: &TriangleHit| !(r as u32 * 7 + prim * 13 + (h.b[0] * 8.0) as u32).is_multiple_of(3);
                    let key = |h: Option<Hit>| h.map(|h| (h.prim, h.t.to_bits(), h.b.map(f32::to_bits), h.front));
                    for t_max in [f32::INFINITY, 1.0] {
                        let mut got = vec![None; len];
                        accel.closest_hits(&rays, t_max, alpha, &mut got);
                        for (r, ray) in rays.iter().enumerate() {
                            let want = accel.closest_hit(ray, t_max, |prim, h| alpha(r, prim, h));
                            assert_eq!(key(got[r]), key(want), "n {n} avx2 {avx2} batch {batch} ray {r}: {ray:?} t_max {t_max}");
                        }
                    }
                    let mut blocked = vec![false; len];
                    accel.occluded_many(&rays, &limits, alpha, &mut blocked);
                    for (r, ray) in rays.iter().enumerate() {
                        let want = accel.occluded(ray, limits[r], |prim, h| alpha(r, prim, h));
                        assert_eq!(blocked[r], want, "n {n} avx2 {avx2} batch {batch} ray {r}: {ray:?} t_max {}", limits[r]);
                    }
                    if len >= 64 {
                        let hits = rays.iter().filter(|r| accel.closest_hit(r, f32::INFINITY, |_, _| true).is_some()).count();
                        assert!(hits > len / 10 && hits < len, "n {n} batch {batch}: {hits} of {len} rays hit; the test needs hits and misses");
                    }
                }
            }
        }
    }
}
