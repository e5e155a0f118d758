//! Closest-point queries on a triangle set: the point-query counterpart of
//! [`crate::accel::Accel`] (which answers ray queries), for geometry metrics such as the
//! distance from a reconstructed mesh's samples to the scene's surface.
//!
//! [`NearestTriangles`] wraps an obvhs binary BVH (PLOC build with the settings of an
//! [`AccelParams`] preset) over the triangles' boxes. A query walks it best-first: children
//! nearer the point are visited first and a subtree is skipped once its box is at least as far
//! as the closest triangle found so far, so the answer is the exact closest point (Ericson,
//! *Real-Time Collision Detection* §5.1.5, evaluated in `f64`), not an approximation.
//!
//! ```
//! use glam::Vec3;
//! use pathtracer::nearest::NearestTriangles;
//! let positions = [Vec3::ZERO, Vec3::X, Vec3::Y];
//! let set = NearestTriangles::build(&positions, &[[0, 1, 2]]).unwrap();
//! let c = set.closest(Vec3::new(0.25, 0.25, 2.0)).unwrap();
//! assert_eq!(c.triangle, 0);
//! assert!((c.distance - 2.0).abs() < 1e-6);
//! ```

use crate::PathTracerError;
use crate::accel::AccelParams;
use glam::{DVec3, Vec3, Vec3A};
use obvhs::bvh2::Bvh2;
use obvhs::bvh2::builder::build_bvh2;
use obvhs::triangle::Triangle;
use std::time::Duration;

/// The closest point of a triangle set to a query point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Closest {
    /// Index of the triangle (into the slice given to [`NearestTriangles::build`]).
    pub triangle: u32,
    /// The closest point on it.
    pub point: Vec3,
    /// Euclidean distance from the query point.
    pub distance: f32,
}

/// A BVH over a triangle soup for exact closest-point queries.
pub struct NearestTriangles {
    bvh: Option<Bvh2>,
    /// Triangle corners, by the caller's triangle index.
    tris: Vec<[DVec3; 3]>,
}

impl std::fmt::Debug for NearestTriangles {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NearestTriangles").field("triangles", &self.tris.len()).finish()
    }
}

impl NearestTriangles {
    /// Builds the BVH over `triangles` (vertex indices into `positions`) with the
    /// [`AccelParams::medium_build`] settings. Errors on an index out of range or a non-finite
    /// vertex. An empty set is allowed: every query then answers `None`.
    pub fn build(positions: &[Vec3], triangles: &[[u32; 3]]) -> Result<Self, PathTracerError> {
        Self::build_with(positions, triangles, &AccelParams::medium_build())
    }

    /// [`Self::build`] with explicit build settings.
    pub fn build_with(positions: &[Vec3], triangles: &[[u32; 3]], params: &AccelParams) -> Result<Self, PathTracerError> {
        let config = params.to_obvhs()?;
        let mut tris = Vec::with_capacity(triangles.len());
        for (k, t) in triangles.iter().enumerate() {
            let p = t.map(|i| positions.get(i as usize).copied());
            let [Some(a), Some(b), Some(c)] = p else {
                return Err(PathTracerError::Config(format!("triangle {k} references a vertex out of range ({} vertices)", positions.len())));
            };
            if !(a.is_finite() && b.is_finite() && c.is_finite()) {
                return Err(PathTracerError::Config(format!("triangle {k} has a non-finite vertex")));
            }
            tris.push([a, b, c]);
        }
        if tris.is_empty() {
            return Ok(Self { bvh: None, tris: Vec::new() });
        }
        let prims: Vec<Triangle> = tris.iter().map(|[a, b, c]| Triangle { v0: (*a).into(), v1: (*b).into(), v2: (*c).into() }).collect();
        let mut build_time = Duration::ZERO;
        let bvh = build_bvh2(&prims, config, &mut build_time);
        Ok(Self { bvh: Some(bvh), tris: tris.iter().map(|t| t.map(|v| v.as_dvec3())).collect() })
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.tris.len()
    }

    /// Whether there are no triangles.
    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    /// The exact closest point of the set to `p`; `None` for an empty set or a non-finite `p`.
    /// Among triangles at exactly the same distance the lowest index wins.
    pub fn closest(&self, p: Vec3) -> Option<Closest> {
        let bvh = self.bvh.as_ref()?;
        if !p.is_finite() {
            return None;
        }
        let pa = Vec3A::from(p);
        let pd = p.as_dvec3();
        // Best so far: squared distance (f64), triangle, point.
        let mut best: (f64, u32, DVec3) = (f64::INFINITY, u32::MAX, DVec3::ZERO);
        let box_d2 = |node: u32| -> f32 {
            let a = bvh.nodes[node as usize].aabb();
            let d = (a.min - pa).max(pa - a.max).max(Vec3A::ZERO);
            d.length_squared()
        };
        // Boxes are f32: a box distance is compared with a small relative slack so that
        // rounding never prunes the subtree that holds the exact closest triangle.
        let prune = |d2: f32, best: f64| (d2 as f64) * (1.0 - 1e-5) > best;
        let mut stack: Vec<(u32, f32)> = Vec::with_capacity(64);
        stack.push((0, box_d2(0)));
        while let Some((node, d2)) = stack.pop() {
            if prune(d2, best.0) {
                continue;
            }
            let n = &bvh.nodes[node as usize];
            if n.is_leaf() {
                for k in n.first_index..n.first_index + n.prim_count {
                    let t = bvh.primitive_indices[k as usize];
                    let q = closest_point_on_triangle(pd, self.tris[t as usize]);
                    let e2 = (q - pd).length_squared();
                    if e2 < best.0 || (e2 == best.0 && t < best.1) {
                        best = (e2, t, q);
                    }
                }
                continue;
            }
            let (l, r) = (n.first_index, n.first_index + 1);
            let (dl, dr) = (box_d2(l), box_d2(r));
            // Push the farther child first so that the nearer one is visited next.
            let (first, second) = if dl <= dr { ((r, dr), (l, dl)) } else { ((l, dl), (r, dr)) };
            for (c, d) in [first, second] {
                if !prune(d, best.0) {
                    stack.push((c, d));
                }
            }
        }
        (best.1 != u32::MAX).then(|| Closest { triangle: best.1, point: best.2.as_vec3(), distance: best.0.sqrt() as f32 })
    }
}

/// The point of triangle `t` closest to `p` (Ericson's Voronoi-region method). A degenerate
/// triangle (zero area) is handled as the union of its edges.
pub fn closest_point_on_triangle(p: DVec3, t: [DVec3; 3]) -> DVec3 {
    let [a, b, c] = t;
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = va + vb + vc;
    if denom > 0.0 && denom.is_finite() {
        let (v, w) = (vb / denom, vc / denom);
        return a + ab * v + ac * w;
    }
    // Degenerate (collinear or coincident corners): the closest of the three edges.
    [(a, b), (b, c), (c, a)]
        .into_iter()
        .map(|(s, e)| closest_point_on_segment(p, s, e))
        .min_by(|x, y| (*x - p).length_squared().total_cmp(&(*y - p).length_squared()))
        .unwrap_or(a)
}

fn closest_point_on_segment(p: DVec3, a: DVec3, b: DVec3) -> DVec3 {
    let ab = b - a;
    let l2 = ab.length_squared();
    if l2.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return a;
    }
    a + ab * ((p - a).dot(ab) / l2).clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute force over every triangle.
    fn brute(positions: &[Vec3], tris: &[[u32; 3]], p: Vec3) -> f64 {
        tris.iter()
            .map(|t| {
                let q = closest_point_on_triangle(p.as_dvec3(), t.map(|i| positions[i as usize].as_dvec3()));
                (q - p.as_dvec3()).length()
            })
            .fold(f64::INFINITY, f64::min)
    }

    fn hash(k: u64) -> f32 {
        let mut z = k.wrapping_add(0x9e37_79b9_7f4a_7c15);
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    }

    #[test]
    fn closest_point_regions_of_one_triangle() {
        let t = [DVec3::ZERO, DVec3::X, DVec3::Y];
        // Interior: straight down.
        assert!((closest_point_on_triangle(DVec3::new(0.2, 0.3, 5.0), t) - DVec3::new(0.2, 0.3, 0.0)).length() < 1e-15);
        // Vertex regions.
        assert_eq!(closest_point_on_triangle(DVec3::new(-1.0, -1.0, 0.0), t), DVec3::ZERO);
        assert_eq!(closest_point_on_triangle(DVec3::new(3.0, -0.5, 1.0), t), DVec3::X);
        // Edge regions.
        assert_eq!(closest_point_on_triangle(DVec3::new(0.5, -2.0, 0.0), t), DVec3::new(0.5, 0.0, 0.0));
        let q = closest_point_on_triangle(DVec3::new(1.0, 1.0, 0.0), t);
        assert!((q - DVec3::new(0.5, 0.5, 0.0)).length() < 1e-12);
        // Degenerate: a segment from (0,0,0) to (2,0,0) given as a triangle.
        let seg = [DVec3::ZERO, DVec3::new(1.0, 0.0, 0.0), DVec3::new(2.0, 0.0, 0.0)];
        assert_eq!(closest_point_on_triangle(DVec3::new(1.5, 1.0, 0.0), seg), DVec3::new(1.5, 0.0, 0.0));
    }

    #[test]
    fn bvh_query_equals_brute_force() {
        // A random soup of 400 small triangles in the unit cube, 300 random queries in a
        // larger box.
        let mut positions = Vec::new();
        let mut tris = Vec::new();
        for k in 0..400u64 {
            let c = Vec3::new(hash(6 * k), hash(6 * k + 1), hash(6 * k + 2));
            let base = positions.len() as u32;
            for j in 0..3u64 {
                let d = Vec3::new(hash(1000 + 9 * k + 3 * j), hash(5000 + 9 * k + 3 * j), hash(9000 + 9 * k + 3 * j)) - 0.5;
                positions.push(c + 0.1 * d);
            }
            tris.push([base, base + 1, base + 2]);
        }
        let set = NearestTriangles::build(&positions, &tris).unwrap();
        for q in 0..300u64 {
            let p = Vec3::new(hash(20000 + 3 * q), hash(20001 + 3 * q), hash(20002 + 3 * q)) * 2.0 - 0.5;
            let c = set.closest(p).unwrap();
            let b = brute(&positions, &tris, p);
            assert!((c.distance as f64 - b).abs() <= 1e-6 * b.max(1.0), "query {q}: bvh {} vs brute {b}", c.distance);
            assert!(((c.point - p).length() - c.distance).abs() < 1e-5);
        }
    }

    #[test]
    fn empty_set_and_bad_input() {
        let set = NearestTriangles::build(&[], &[]).unwrap();
        assert!(set.is_empty());
        assert!(set.closest(Vec3::ZERO).is_none());
        assert!(NearestTriangles::build(&[Vec3::ZERO], &[[0, 1, 2]]).is_err());
        assert!(NearestTriangles::build(&[Vec3::ZERO, Vec3::X, Vec3::NAN], &[[0, 1, 2]]).is_err());
        let one = NearestTriangles::build(&[Vec3::ZERO, Vec3::X, Vec3::Y], &[[0, 1, 2]]).unwrap();
        assert!(one.closest(Vec3::NAN).is_none());
    }
}
