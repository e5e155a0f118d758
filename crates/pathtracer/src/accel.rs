//! The acceleration structure: one type, [`Accel`], wrapping an obvhs compressed wide BVH
//! (CWBVH, built in parallel with PLOC) over the scene's triangles. obvhs does the node
//! traversal; triangles are tested with the watertight test of [`crate::geometry`].
//!
//! Build settings are one struct, [`AccelParams`], with named presets mirroring obvhs's
//! `BvhBuildParams` presets.
//!
//! Conservative boxes: obvhs's `f32` ray/box test can round a ray that passes exactly
//! through a triangle's extreme vertex (a box corner) to a miss, which would break
//! watertightness. The BVH is therefore built over triangle boxes padded by
//! `2·10⁻⁶ × (largest absolute coordinate of the scene)` (about 16 ulps) on every side, so
//! rounding in the box test can no longer reject a box that the ray touches. (obvhs's
//! spatial pre-splits need the exact triangles, so they are not offered.)
//!
//! Hit rules, shared by closest-hit and any-hit queries:
//! - A single-sided triangle hit from behind (`d · ((p₁−p₀)×(p₂−p₀)) ≥ 0`) is ignored: glTF
//!   culls back faces, so they are invisible and do not occlude.
//! - An alpha-masked triangle (glTF `MASK`) is hit only where the caller's alpha test
//!   accepts the hit (base-colour alpha ≥ cutoff).
//! - Among hits at exactly the same `t` (e.g. on a shared edge) the lowest triangle index
//!   wins, so the answer does not depend on the BVH's layout or build.

// Negated comparisons (`!(x > 0.0)`) are deliberate: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use crate::PathTracerError;
use crate::geometry::{Ray, TriangleHit, WatertightRay, intersect_triangle};
use crate::scene::{AlphaMode, Scene};
use glam::{Vec3, Vec3A};
use obvhs::cwbvh::CwBvh;
use obvhs::cwbvh::builder::build_cwbvh;
use obvhs::ploc::{PlocSearchDistance, SortPrecision};
use obvhs::ray::RayHit;
use obvhs::{Boundable, BvhBuildParams};
use serde::{Deserialize, Serialize};
use std::time::Duration;

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

/// The scene's BVH and the triangle data its leaves reference.
pub struct Accel {
    bvh: Option<CwBvh>,
    /// Triangles in BVH primitive order.
    tris: Vec<PackedTriangle>,
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
            return Ok(Accel { bvh: None, tris: Vec::new(), build_time: Duration::ZERO });
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
        let build_time = start.elapsed();
        let bvh_tris = bvh
            .primitive_indices
            .iter()
            .map(|&i| {
                let p = tris[i as usize];
                PackedTriangle { p, n: (p[1] - p[0]).cross(p[2] - p[0]), prim: i, flags: tri_flags[i as usize] }
            })
            .collect();
        Ok(Accel { bvh: Some(bvh), tris: bvh_tris, build_time })
    }

    /// Wall time of the BVH build.
    pub fn build_time(&self) -> Duration {
        self.build_time
    }

    /// Number of BVH primitive references (≥ the triangle count with pre-splits).
    pub fn primitive_count(&self) -> usize {
        self.tris.len()
    }

    #[inline]
    fn obvhs_ray(ray: &Ray, t_max: f32) -> Option<obvhs::ray::Ray> {
        if !ray.origin.is_finite() || !ray.direction.is_finite() || ray.direction == Vec3::ZERO || !(t_max > 0.0) {
            return None;
        }
        // `+ 0.0` turns −0 into +0: obvhs derives slab order from `d < 0` but the inverse
        // from the sign bit, which disagree for −0.
        let d = ray.direction + Vec3::ZERO;
        Some(obvhs::ray::Ray::new(Vec3A::from(ray.origin), Vec3A::from(d), 0.0, t_max))
    }

    /// The closest accepted hit with `t < t_max`. `alpha_test(prim, hit)` is consulted only
    /// for alpha-masked triangles and returns whether the surface is present there.
    pub fn closest_hit<F: Fn(u32, &TriangleHit) -> bool>(&self, ray: &Ray, t_max: f32, alpha_test: F) -> Option<Hit> {
        let bvh = self.bvh.as_ref()?;
        let oray = Self::obvhs_ray(ray, t_max)?;
        let wr = WatertightRay::new(ray)?;
        let mut best: Option<Hit> = None;
        let mut best_t = t_max;
        let mut rh = RayHit::none();
        let dir = ray.direction;
        bvh.ray_traverse(oray, &mut rh, |_r, id| {
            let tri = &self.tris[id];
            // Accept ties (t == best_t) so the lowest index can win them.
            let f = tri.flags;
            // Culling first (cheaper than the intersection test, rejects the same).
            let front = tri.n.dot(dir) < 0.0;
            if f & CULL_BACK != 0 && !front {
                return f32::INFINITY;
            }
            let limit = if best.is_some() { crate::geometry::next_float_up(best_t) } else { best_t };
            let Some(h) = intersect_triangle(&wr, tri.p, limit) else { return f32::INFINITY };
            let prim = tri.prim;
            if f & ALPHA_TEST != 0 && !alpha_test(prim, &h) {
                return f32::INFINITY;
            }
            let better = match best {
                None => h.t < best_t,
                Some(b) => h.t < best_t || (h.t == best_t && prim < b.prim),
            };
            if better {
                best = Some(Hit { prim, t: h.t, b: h.b, front });
                best_t = h.t;
            }
            h.t
        });
        best
    }

    /// Whether any accepted hit exists with `t < t_max` (shadow rays).
    pub fn occluded<F: Fn(u32, &TriangleHit) -> bool>(&self, ray: &Ray, t_max: f32, alpha_test: F) -> bool {
        let Some(bvh) = self.bvh.as_ref() else { return false };
        let Some(oray) = Self::obvhs_ray(ray, t_max) else { return false };
        let Some(wr) = WatertightRay::new(ray) else { return false };
        let dir = ray.direction;
        !bvh.ray_traverse_miss(oray, |_r, id| {
            let tri = &self.tris[id];
            let f = tri.flags;
            if f & CULL_BACK != 0 && tri.n.dot(dir) >= 0.0 {
                return f32::INFINITY;
            }
            let Some(h) = intersect_triangle(&wr, tri.p, t_max) else { return f32::INFINITY };
            if f & ALPHA_TEST != 0 && !alpha_test(tri.prim, &h) {
                return f32::INFINITY;
            }
            h.t
        })
    }
}
