//! Building the tree: [`AccelParams`] (obvhs's PLOC settings, with named presets) and
//! [`Accel::build`], which packs the triangles, pads their boxes (see the [`crate::accel`]
//! module docs), builds obvhs's CWBVH over them and re-lays it as the wide tree.

use super::{ALPHA_TEST, Accel, CULL_BACK, MAX_LOCAL_COORDINATE, PackedTriangle, wide};
use crate::PathTracerError;
use crate::scene::{AlphaMode, Scene};
use glam::Vec3A;
use obvhs::cwbvh::builder::build_cwbvh;
use obvhs::ploc::{PlocSearchDistance, SortPrecision};
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

/// A triangle's bounding box, padded (see the module docs): the primitive the BVH is built over.
struct PaddedBox(obvhs::aabb::Aabb);

impl Boundable for PaddedBox {
    fn aabb(&self) -> obvhs::aabb::Aabb {
        self.0
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
                        // A transmissive surface is seen from inside its volume too.
                        if !m.double_sided && !m.transmits() {
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
}
