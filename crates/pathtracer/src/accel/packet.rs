//! The packet queries: up to [`PACKET`] rays traced together ([`Accel::closest_hits`],
//! [`Accel::occluded_many`]), each node loaded once for every ray that enters it, the rays
//! tested in groups of eight lanes. Each lane computes the one-ray query's arithmetic for its
//! ray, so the answers are the one-ray queries' bits (see the [`crate::accel`] module docs).

// Negated comparisons (`!(x > 0.0)`) are deliberate: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::{Accel, BOX_T_MIN, CULL_BACK, ChildBoxTest, FourWide, Hit, LANES, Lanes, PackedTriangle, closest_candidate, occludes, wide};
#[cfg(target_arch = "x86_64")]
use super::{EightWide, in_v3};
use crate::geometry::{Ray, TriangleHit, WatertightRay};
use glam::Vec3;

/// Depth of the traversal stack of the packet queries (node groups pending; obvhs uses 32 as
/// well).
const STACK_SIZE: usize = 32;

/// Rays per packet of the packet queries ([`Accel::closest_hits`], [`Accel::occluded_many`]):
/// one bit each of a `u64`.
pub const PACKET: usize = 64;
/// Groups per packet.
const GROUPS: usize = PACKET / LANES;

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

impl Accel {
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
}
