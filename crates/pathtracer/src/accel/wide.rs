//! The tree every query traverses: obvhs's CWBVH re-laid as eight-wide nodes with exact `f32`
//! child boxes (structure of arrays). The one-ray queries traverse it nearest child first with
//! a distance-culled stack (the layout and loop of CPU ray tracers such as Embree's BVH8,
//! written here from the published design); the packets of [`crate::accel`] read the same
//! nodes, one child box at a time for eight rays. Why this layout: `docs/renderer.md`.
//!
//! Boxes: each child's box is the union of its triangles' padded boxes (the boxes the BVH was
//! built over), computed bottom-up in `f32`, so it is at least as tight as the CWBVH's quantised
//! box of the same child. A child slot the node does not use holds the empty box (`+∞` below,
//! `−∞` above), which no ray enters.
//!
//! Box test, per child and axis: `t = (plane − o) · (1/d)` in `f32`, the near plane by the sign
//! of `1/d` (so `−0` and `+0` pick opposite planes, consistently with `1/d = ∓∞`), then
//! `t_min = max(t_near_x, max(t_near_y, max(t_near_z, 0)))`, `t_max = min(t_far_x, min(…, limit))`
//! with `max`/`min` as x86's `maxps`/`minps` (the second operand where either is NaN: a NaN slab,
//! `0 · ∞` from a ray lying in the slab's plane, constrains nothing, which is conservative), and
//! the child is entered where `t_min · (1 − 2⁻²¹) ≤ t_max · (1 + 2⁻²¹)`. Each computed `t` is
//! within three roundings (`3·2⁻²⁴` relative) of the exact slab distance for the stored plane,
//! origin and direction, and rounding keeps signs, so the widened interval contains the exact
//! one: a ray enters every child whose box it touches before `limit` in exact arithmetic. With
//! the boxes padded as the module docs describe, every triangle the watertight test would hit is
//! tested, and the queries' answers (closest hit with ties to the lowest index; any hit) are the
//! same bits as testing every triangle.

use super::{ChildBoxTest, FourWide, PackedTriangle};
use glam::{Vec3, Vec4};
use obvhs::cwbvh::CwBvh;
use std::ops::ControlFlow;

/// Eight `f32` lanes, one per child slot.
pub(super) type Lanes8 = [f32; 8];

/// A child reference: a node index, or `LEAF | (count − 1) << 29 | first triangle`.
const LEAF: u32 = 0x8000_0000;
/// Triangles per leaf are 1 to 3 (obvhs's limit), stored as `count − 1` in two bits.
const LEAF_COUNT_SHIFT: u32 = 29;
/// The first triangle of a leaf: 29 bits.
const LEAF_FIRST_MASK: u32 = (1 << LEAF_COUNT_SHIFT) - 1;
/// Relative widening of the box test's interval (see the module docs).
pub(super) const WIDEN: f32 = 1.0 / (1 << 21) as f32;
/// Entries of the one-ray queries' traversal stack ([`with_stack`]); deeper pushes spill to
/// a `Vec`.
pub(super) const STACK: usize = 64;

/// One node: eight child boxes, `b[axis][0]` the lower planes and `b[axis][1]` the upper, and
/// the eight child references (224 bytes).
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
pub(super) struct WideNode {
    pub(super) b: [[Lanes8; 2]; 3],
    child: [u32; 8],
}

/// A child reference decoded: `Ok(node index)` or `Err((first triangle, count))` for a leaf.
#[inline(always)]
fn decode(c: u32) -> Result<u32, (u32, u32)> {
    if c & LEAF != 0 { Err((c & LEAF_FIRST_MASK, ((c >> LEAF_COUNT_SHIFT) & 3) + 1)) } else { Ok(c) }
}

impl WideNode {
    /// Child slot `k`'s reference ([`decode`]d). An unused slot reads as node 0, but its box
    /// is empty, so no ray enters it.
    #[inline(always)]
    pub(super) fn child(&self, k: usize) -> Result<u32, (u32, u32)> {
        decode(self.child[k])
    }
}

/// The tree: node 0 is the root.
#[derive(Debug, Default)]
pub(super) struct WideBvh {
    pub(super) nodes: Vec<WideNode>,
}

impl WideBvh {
    /// Re-lays `bvh` (whose primitives are `tris`, in BVH order) with exact child boxes: each
    /// triangle's box padded by `pad` on every side, as the BVH was built.
    pub(super) fn from_cwbvh(
        bvh: &CwBvh,
        tris: &[PackedTriangle],
        pad: f32,
    ) -> Result<WideBvh, String> {
        let n = bvh.nodes.len();
        if n == 0 {
            return Ok(WideBvh::default());
        }
        if tris.len() > LEAF_FIRST_MASK as usize {
            return Err(format!(
                "{} triangles: at most {} are supported",
                tris.len(),
                LEAF_FIRST_MASK
            ));
        }
        let empty = WideNode {
            b: [[[f32::INFINITY; 8], [f32::NEG_INFINITY; 8]]; 3],
            child: [0; 8],
        };
        let mut nodes = vec![empty; n];
        // Children before parents: a post-order walk with an explicit stack.
        let mut bounds: Vec<Option<(Vec3, Vec3)>> = vec![None; n];
        let mut todo = vec![(0usize, false)];
        while let Some((i, expanded)) = todo.pop() {
            let node = &bvh.nodes[i];
            if !expanded {
                todo.push((i, true));
                for k in 0..8 {
                    if !node.is_child_empty(k) && !node.is_leaf(k) {
                        let c = node.child_node_index(k) as usize;
                        if c >= n || bounds[c].is_some() {
                            return Err(format!(
                                "node {i} slot {k}: child {c} is out of range or shared"
                            ));
                        }
                        todo.push((c, false));
                    }
                }
                continue;
            }
            let mut lo_all = Vec3::INFINITY;
            let mut hi_all = Vec3::NEG_INFINITY;
            for k in 0..8 {
                if node.is_child_empty(k) {
                    continue;
                }
                let (lo, hi, r) = if node.is_leaf(k) {
                    let (first, count) = node.child_primitives(k);
                    let range = first as usize..(first + count) as usize;
                    if !(1..=3).contains(&count) || range.end > tris.len() {
                        return Err(format!(
                            "node {i} slot {k}: leaf of {count} triangles at {first}"
                        ));
                    }
                    let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
                    for t in &tris[range] {
                        lo = lo.min(t.p[0].min(t.p[1]).min(t.p[2]) - pad);
                        hi = hi.max(t.p[0].max(t.p[1]).max(t.p[2]) + pad);
                    }
                    (lo, hi, LEAF | (count - 1) << LEAF_COUNT_SHIFT | first)
                } else {
                    let c = node.child_node_index(k);
                    let Some((lo, hi)) = bounds[c as usize] else {
                        return Err(format!("node {i} slot {k}: child {c} has no bounds"));
                    };
                    (lo, hi, c)
                };
                for ax in 0..3 {
                    nodes[i].b[ax][0][k] = lo[ax];
                    nodes[i].b[ax][1][k] = hi[ax];
                }
                nodes[i].child[k] = r;
                lo_all = lo_all.min(lo);
                hi_all = hi_all.max(hi);
            }
            bounds[i] = Some((lo_all, hi_all));
        }
        Ok(WideBvh { nodes })
    }

    /// Bytes of the nodes.
    pub(super) fn memory_bytes(&self) -> usize {
        self.nodes.len() * std::mem::size_of::<WideNode>()
    }
}

/// A ray as the box test reads it.
#[derive(Clone, Copy, Debug)]
pub(super) struct WideRay {
    pub(super) o: [f32; 3],
    pub(super) inv: [f32; 3],
    /// Which of `b[axis]` holds the near planes: 1 where `1/d` is negative.
    pub(super) near: [usize; 3],
}

impl WideRay {
    /// For a finite origin and a finite, non-zero direction.
    #[inline(always)]
    pub(super) fn new(o: Vec3, d: Vec3) -> WideRay {
        let inv = Vec3::ONE / d;
        let near = |x: f32| x.is_sign_negative() as usize;
        WideRay {
            o: o.to_array(),
            inv: inv.to_array(),
            near: [near(inv.x), near(inv.y), near(inv.z)],
        }
    }
}

/// The box test of all eight children of a node (the module docs): the mask of the children
/// entered before `limit`, and their widened entry distances.
pub(super) trait WideTest: ChildBoxTest {
    fn children(self, node: &WideNode, r: &WideRay, limit: f32) -> (u32, Lanes8);
}

impl WideTest for FourWide {
    #[inline(always)]
    fn children(self, node: &WideNode, r: &WideRay, limit: f32) -> (u32, Lanes8) {
        let mut t_out = [0.0; 8];
        let mut mask = 0;
        for h in 0..2 {
            let v = |a: &Lanes8| Vec4::from_slice(&a[h * 4..h * 4 + 4]);
            let t = |ax: usize, side: usize| {
                (v(&node.b[ax][side]) - Vec4::splat(r.o[ax])) * Vec4::splat(r.inv[ax])
            };
            let near = |ax: usize| t(ax, r.near[ax]);
            let far = |ax: usize| t(ax, 1 - r.near[ax]);
            let t_min =
                near(0).max(near(1).max(near(2).max(Vec4::ZERO))) * Vec4::splat(1.0 - WIDEN);
            let t_max =
                far(0).min(far(1).min(far(2).min(Vec4::splat(limit)))) * Vec4::splat(1.0 + WIDEN);
            mask |= t_min.cmple(t_max).bitmask() << (h * 4);
            t_min.write_to_slice(&mut t_out[h * 4..h * 4 + 4]);
        }
        (mask, t_out)
    }
}

#[cfg(target_arch = "x86_64")]
impl WideTest for super::EightWide {
    #[inline(always)]
    fn children(self, node: &WideNode, r: &WideRay, limit: f32) -> (u32, Lanes8) {
        use core::arch::x86_64::{__m256, _CMP_LE_OQ};
        let avx = self.0.avx;
        let splat = |x: f32| avx._mm256_set1_ps(x);
        let t = |ax: usize, side: usize| -> __m256 {
            avx._mm256_mul_ps(
                avx._mm256_sub_ps(pulp::cast(node.b[ax][side]), splat(r.o[ax])),
                splat(r.inv[ax]),
            )
        };
        let near = |ax: usize| t(ax, r.near[ax]);
        let far = |ax: usize| t(ax, 1 - r.near[ax]);
        let (max, min) = (
            |x, y| avx._mm256_max_ps(x, y),
            |x, y| avx._mm256_min_ps(x, y),
        );
        let t_min = avx._mm256_mul_ps(
            max(near(0), max(near(1), max(near(2), avx._mm256_setzero_ps()))),
            splat(1.0 - WIDEN),
        );
        let t_max = avx._mm256_mul_ps(
            min(far(0), min(far(1), min(far(2), splat(limit)))),
            splat(1.0 + WIDEN),
        );
        let mask = avx._mm256_movemask_ps(avx._mm256_cmp_ps::<_CMP_LE_OQ>(t_min, t_max)) as u32;
        (mask, pulp::cast(t_min))
    }
}

thread_local! {
    /// The one-ray queries' traversal stack: one per thread, reused by every query and never
    /// cleared (a query reads only the entries it pushed).
    static THREAD_STACK: std::cell::RefCell<[u64; STACK]> = const { std::cell::RefCell::new([0; STACK]) };
}

/// `f` with this thread's traversal stack ([`STACK`] entries), or a fresh one where a query
/// is already using it (an alpha test that made a query of its own).
#[inline(always)]
pub(super) fn with_stack<R>(f: impl FnOnce(&mut [u64]) -> R) -> R {
    THREAD_STACK.with(|s| match s.try_borrow_mut() {
        Ok(mut s) => f(&mut s[..]),
        Err(_) => f(&mut [0u64; STACK]),
    })
}

/// Nearest-child-first traversal of `bvh` for ray `r` up to `limit`: `leaf(id)` tests BVH
/// primitive `id` and returns `Some(t)` to shrink the limit to `t`, or `None`; it returns
/// `ControlFlow::Break` to stop (any-hit queries). Children are pushed sorted by entry distance
/// (the nearest popped first) and skipped when popped beyond the current limit; without
/// `NEAREST_FIRST` (any-hit queries, whose limit never shrinks) they are pushed unsorted,
/// without their distances, and every one pushed is visited. `stack` holds the pending
/// children (its contents are not read before they are written); beyond its length they
/// spill to a `Vec`.
#[inline(always)]
pub(super) fn traverse<
    const NEAREST_FIRST: bool,
    K: WideTest,
    F: FnMut(usize) -> ControlFlow<(), Option<f32>>,
>(
    test: K,
    bvh: &WideBvh,
    r: &WideRay,
    mut limit: f32,
    mut leaf: F,
    stack: &mut [u64],
) {
    let nodes = &bvh.nodes[..];
    if nodes.is_empty() {
        return;
    }
    let n = stack.len();
    // Entries are `entry distance bits << 32 | child reference`: the distances are ≥ 0, so
    // the entries order as the distances do.
    let mut sp = 0usize;
    let mut spill: Vec<u64> = Vec::new();
    let mut cur = 0u32;
    loop {
        match decode(cur) {
            Err((first, count)) => {
                for id in first..first + count {
                    match leaf(id as usize) {
                        ControlFlow::Break(()) => return,
                        ControlFlow::Continue(Some(t)) => limit = t,
                        ControlFlow::Continue(None) => {}
                    }
                }
            }
            Ok(index) => {
                let node = &nodes[index as usize];
                let (mask, t_near) = test.children(node, r, limit);
                if mask != 0 {
                    let first = mask.trailing_zeros() as usize;
                    let rest = mask & (mask - 1);
                    if rest == 0 {
                        cur = node.child[first];
                        continue;
                    }
                    // Two or more: push them all, sorted nearest last, then take the nearest.
                    let base = sp;
                    let mut m = mask;
                    while m != 0 {
                        let k = m.trailing_zeros() as usize;
                        m &= m - 1;
                        // The any-hit query's limit never shrinks: its entries need no distance.
                        let e = if NEAREST_FIRST { (t_near[k].to_bits() as u64) << 32 } else { 0 } | node.child[k] as u64;
                        if sp < n {
                            let mut j = sp;
                            while NEAREST_FIRST && j > base && stack[j - 1] < e {
                                stack[j] = stack[j - 1];
                                j -= 1;
                            }
                            stack[j] = e;
                            sp += 1;
                        } else {
                            spill.push(e);
                        }
                    }
                }
            }
        }
        // Next: the nearest pending child still within the limit.
        loop {
            let e = if sp > 0 {
                sp -= 1;
                stack[sp]
            } else if let Some(e) = spill.pop() {
                e
            } else {
                return;
            };
            if !NEAREST_FIRST || f32::from_bits((e >> 32) as u32) <= limit {
                cur = e as u32;
                break;
            }
        }
    }
}
