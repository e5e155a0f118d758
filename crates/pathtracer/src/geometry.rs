//! Ray–triangle geometry: the watertight ray/triangle test, floating-point error bounds for
//! hit points, robust spawning of secondary rays, the exact `f64` re-intersection used for
//! ground-truth depth, and a shading frame.
//!
//! # Watertight intersection
//! [`intersect_triangle`] is Woop, Benthin & Wald, "Watertight Ray/Triangle Intersection"
//! (JCGT 2013), in the form pbrt-v4 uses: translate the vertices to the ray origin, permute so
//! the ray's dominant axis is z, shear so the ray becomes +z, then evaluate the three 2D edge
//! functions `e_i`. A shared edge gets bit-identical edge-function values (up to sign) in both
//! of its triangles, so a ray can never slip between them; when an edge function is exactly
//! zero it is recomputed in `f64` (products of two `f32` are exact there), as the paper does.
//! The hit is accepted only if `t` is larger than a conservative bound on its rounding error
//! (pbrt-v4 §6.8.5), so a hit at the ray origin is never reported.
//!
//! # Self-intersection
//! A hit point computed from barycentrics has an absolute error bound
//! `γ₇ · (|b₀p₀| + |b₁p₁| + |b₂p₂|)` per component ([`hit_point_error`]). [`offset_ray_origin`]
//! moves a spawned ray's origin along the geometric normal by that bound projected on the
//! normal, then one ulp further away (pbrt-v4 `OffsetRayOrigin`; Wächter & Binder, Ray
//! Tracing Gems ch. 6), so secondary rays neither re-hit their own surface (acne) nor start
//! on the far side of it (leaks). The bound scales with the magnitude of the hit point.

// Negated comparisons (`!(x > 0.0)`) are deliberate: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use glam::{DVec3, Vec3, Vec3Swizzles};

/// A ray in the scene's local `f32` frame. `direction` need not be unit length for the
/// intersection routines, but the renderer always passes unit directions so that `t` is a
/// distance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Origin (local frame).
    pub origin: Vec3,
    /// Direction.
    pub direction: Vec3,
}

impl Ray {
    /// A ray from `origin` along `direction`.
    #[inline]
    pub fn new(origin: Vec3, direction: Vec3) -> Self {
        Self { origin, direction }
    }
    /// The point at parameter `t`.
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + t * self.direction
    }
}

/// `γₙ = n·ε / (1 − n·ε)` with `ε` half an ulp of one (the unit roundoff of `f32`): the
/// classic bound on the relative error of `n` chained floating-point operations.
#[inline]
pub fn gamma(n: i32) -> f32 {
    let eps = f32::EPSILON * 0.5;
    (n as f32 * eps) / (1.0 - n as f32 * eps)
}

/// The per-ray precomputation of the watertight test: the permutation that makes the
/// dominant direction axis z and the shear that maps the direction onto +z.
#[derive(Clone, Copy, Debug)]
pub struct WatertightRay {
    origin: Vec3,
    /// The dominant axis; `(kx, ky) = (kz + 1, kz + 2) mod 3`.
    kz: u8,
    sx: f32,
    sy: f32,
    sz: f32,
}

impl WatertightRay {
    /// Precomputes the permutation and shear for `ray`. Returns `None` for a zero or
    /// non-finite direction (no triangle can be hit).
    #[inline]
    pub fn new(ray: &Ray) -> Option<Self> {
        if !ray.direction.is_finite() || !ray.origin.is_finite() {
            return None;
        }
        Self::from_finite(ray)
    }

    /// [`WatertightRay::new`] for a ray whose origin and direction are known to be finite.
    #[inline(always)]
    pub(crate) fn from_finite(ray: &Ray) -> Option<Self> {
        let d = ray.direction;
        let a = d.abs();
        let kz = if a.x > a.y { if a.x > a.z { 0 } else { 2 } } else if a.y > a.z { 1 } else { 2 };
        // The direction's components in the order (kx, ky, kz) = (kz + 1, kz + 2, kz) mod 3,
        // by a swizzle ([`WatertightRay::permuted`]'s) instead of three indexings.
        let p = match kz {
            0 => d.yzx(),
            1 => d.zxy(),
            _ => d,
        };
        if p.z == 0.0 {
            return None;
        }
        Some(Self { origin: ray.origin, kz, sx: -p.x / p.z, sy: -p.y / p.z, sz: 1.0 / p.z })
    }

    /// The dominant axis `kz` and the shear `(sx, sy, sz)`, for tests that run many rays in
    /// lanes (`crate::accel`'s packets).
    #[inline(always)]
    pub(crate) fn shear(&self) -> (u32, [f32; 3]) {
        (self.kz as u32, [self.sx, self.sy, self.sz])
    }

    /// The vertices translated to the origin (`v − origin`) with their components permuted
    /// to `(kx, ky, kz)`: one fixed swizzle per dominant axis, so the hot loop has no
    /// per-component indexing.
    #[inline(always)]
    fn permuted(&self, p: [Vec3; 3]) -> [Vec3; 3] {
        let o = self.origin;
        match self.kz {
            0 => p.map(|v| (v - o).yzx()),
            1 => p.map(|v| (v - o).zxy()),
            _ => p.map(|v| v - o),
        }
    }
}

/// A ray–triangle hit: distance and barycentrics (`b[i]` weights vertex `i`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleHit {
    /// Ray parameter of the hit (a distance for unit directions).
    pub t: f32,
    /// Barycentric coordinates, summing to 1.
    pub b: [f32; 3],
}

/// Watertight ray/triangle intersection (Woop, Benthin & Wald 2013; see the module docs).
/// Returns the hit if `0 < t < t_max` (with `t` above its own rounding-error bound).
/// Both faces are reported; culling is the caller's decision.
#[inline(always)]
pub fn intersect_triangle(ray: &WatertightRay, p: [Vec3; 3], t_max: f32) -> Option<TriangleHit> {
    // Translate, permute, shear (x and y only; z is sheared after the edge test).
    let [q0, q1, q2] = ray.permuted(p);
    let tr = |v: Vec3| (v.x + ray.sx * v.z, v.y + ray.sy * v.z, v.z);
    let (p0x, p0y, p0z) = tr(q0);
    let (p1x, p1y, p1z) = tr(q1);
    let (p2x, p2y, p2z) = tr(q2);

    let mut e0 = p1x * p2y - p1y * p2x;
    let mut e1 = p2x * p0y - p2y * p0x;
    let mut e2 = p0x * p1y - p0y * p1x;
    if e0 == 0.0 || e1 == 0.0 || e2 == 0.0 {
        // Exact products of f32 in f64; one rounding for the difference, so the sign is exact.
        e0 = (p1x as f64 * p2y as f64 - p1y as f64 * p2x as f64) as f32;
        e1 = (p2x as f64 * p0y as f64 - p2y as f64 * p0x as f64) as f32;
        e2 = (p0x as f64 * p1y as f64 - p0y as f64 * p1x as f64) as f32;
    }
    if (e0 < 0.0 || e1 < 0.0 || e2 < 0.0) && (e0 > 0.0 || e1 > 0.0 || e2 > 0.0) {
        return None;
    }
    let det = e0 + e1 + e2;
    if det == 0.0 {
        return None;
    }
    let (z0, z1, z2) = (p0z * ray.sz, p1z * ray.sz, p2z * ray.sz);
    let t_scaled = e0 * z0 + e1 * z1 + e2 * z2;
    if det < 0.0 && (t_scaled >= 0.0 || t_scaled < t_max * det) {
        return None;
    }
    if det > 0.0 && (t_scaled <= 0.0 || t_scaled > t_max * det) {
        return None;
    }
    let inv_det = 1.0 / det;
    let t = t_scaled * inv_det;
    if !(t < t_max) {
        return None;
    }
    // Conservative check that t > 0 (pbrt-v4 §6.8.5).
    let max_zt = z0.abs().max(z1.abs()).max(z2.abs());
    let delta_z = gamma(3) * max_zt;
    let max_xt = p0x.abs().max(p1x.abs()).max(p2x.abs());
    let max_yt = p0y.abs().max(p1y.abs()).max(p2y.abs());
    let delta_x = gamma(5) * (max_xt + max_zt);
    let delta_y = gamma(5) * (max_yt + max_zt);
    let delta_e = 2.0 * (gamma(2) * max_xt * max_yt + delta_y * max_xt + delta_x * max_yt);
    let max_e = e0.abs().max(e1.abs()).max(e2.abs());
    let delta_t =
        3.0 * (gamma(3) * max_e * max_zt + delta_e * max_zt + delta_z * max_e) * inv_det.abs();
    if t <= delta_t {
        return None;
    }
    Some(TriangleHit { t, b: [e0 * inv_det, e1 * inv_det, e2 * inv_det] })
}

/// Interpolated hit point `Σ bᵢ pᵢ` and its per-component absolute error bound
/// `γ₇ Σ |bᵢ pᵢ|` (pbrt-v4 §6.8.6).
#[inline]
pub fn hit_point_error(p: [Vec3; 3], b: [f32; 3]) -> (Vec3, Vec3) {
    let a = b[0] * p[0];
    let c = b[1] * p[1];
    let d = b[2] * p[2];
    let point = a + c + d;
    let err = gamma(7) * (a.abs() + c.abs() + d.abs());
    (point, err)
}

/// Next representable `f32` towards +∞.
#[inline(always)]
pub fn next_float_up(v: f32) -> f32 {
    if v.is_infinite() && v > 0.0 {
        return v;
    }
    let v = if v == -0.0 { 0.0 } else { v };
    let bits = v.to_bits();
    let bits = if v >= 0.0 { bits + 1 } else { bits - 1 };
    f32::from_bits(bits)
}

/// Next representable `f32` towards −∞.
#[inline(always)]
pub fn next_float_down(v: f32) -> f32 {
    if v.is_infinite() && v < 0.0 {
        return v;
    }
    let v = if v == 0.0 { -0.0 } else { v };
    let bits = v.to_bits();
    let bits = if v > 0.0 { bits - 1 } else { bits + 1 };
    f32::from_bits(bits)
}

/// Origin for a ray leaving the surface point `p` (with error bound `p_err`, unit geometric
/// normal `n`) in direction `w`: `p ± (|n|·p_err) n`, rounded one ulp further away
/// (pbrt-v4 `OffsetRayOrigin`). The sign is that of `w·n`, so the origin lies on the side
/// the ray leaves towards.
#[inline(always)]
pub fn offset_ray_origin(p: Vec3, p_err: Vec3, n: Vec3, w: Vec3) -> Vec3 {
    let d = n.abs().dot(p_err);
    let mut offset = d * n;
    if w.dot(n) < 0.0 {
        offset = -offset;
    }
    let po = p + offset;
    #[inline(always)]
    fn away(v: f32, off: f32) -> f32 {
        if off > 0.0 {
            next_float_up(v)
        } else if off < 0.0 {
            next_float_down(v)
        } else {
            v
        }
    }
    Vec3::new(away(po.x, offset.x), away(po.y, offset.y), away(po.z, offset.z))
}

/// Distance along the ray `o + t d` (`f64`, unit `d`) to the plane of triangle `p`
/// (`f32` vertices widened exactly to `f64`): `t = ((p₀ − o)·n) / (d·n)` with
/// `n = (p₁ − p₀) × (p₂ − p₀)`. Relative error ~1e-15 away from grazing incidence: the
/// ground-truth distance of a pixel-centre ray. `None` when the ray is parallel to the plane.
pub fn ray_triangle_plane_distance_f64(p: [Vec3; 3], o: DVec3, d: DVec3) -> Option<f64> {
    let p0 = p[0].as_dvec3();
    let n = (p[1].as_dvec3() - p0).cross(p[2].as_dvec3() - p0);
    let denom = d.dot(n);
    if denom == 0.0 || !denom.is_finite() {
        return None;
    }
    let t = (p0 - o).dot(n) / denom;
    t.is_finite().then_some(t)
}

/// An orthonormal frame around a unit normal `n` (Duff et al. 2017, "Building an
/// Orthonormal Basis, Revisited").
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    /// Tangent.
    pub s: Vec3,
    /// Bitangent.
    pub t: Vec3,
    /// Normal.
    pub n: Vec3,
}

impl Frame {
    /// The frame with `n` (unit) as its z axis.
    #[inline]
    pub fn from_normal(n: Vec3) -> Self {
        let sign = 1.0f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let s = Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let t = Vec3::new(b, sign + n.y * n.y * a, -n.y);
        Self { s, t, n }
    }
    /// Local (frame) coordinates → world.
    #[inline]
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        v.x * self.s + v.y * self.t + v.z * self.n
    }
    /// World → local coordinates.
    #[inline]
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.s), v.dot(self.t), v.dot(self.n))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri() -> [Vec3; 3] {
        [Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.0, 1.0, 0.0)]
    }

    #[test]
    fn hit_distance_and_barycentrics_match_closed_form() {
        let ray = Ray::new(Vec3::new(0.25, 0.5, 2.0), Vec3::new(0.0, 0.0, -1.0));
        let h = intersect_triangle(&WatertightRay::new(&ray).unwrap(), tri(), f32::INFINITY).unwrap();
        assert!((h.t - 2.0).abs() < 1e-6);
        // Point (0.25, 0.5) = b0·p0 + b1·(1,0) + b2·(0,1) → b1 = 0.25, b2 = 0.5, b0 = 0.25.
        assert!((h.b[0] - 0.25).abs() < 1e-6 && (h.b[1] - 0.25).abs() < 1e-6 && (h.b[2] - 0.5).abs() < 1e-6);
        // Back face (from below) also reported; outside and behind are misses.
        let back = Ray::new(Vec3::new(0.25, 0.25, -1.0), Vec3::new(0.0, 0.0, 1.0));
        assert!(intersect_triangle(&WatertightRay::new(&back).unwrap(), tri(), f32::INFINITY).is_some());
        let outside = Ray::new(Vec3::new(0.75, 0.75, 1.0), Vec3::new(0.0, 0.0, -1.0));
        assert!(intersect_triangle(&WatertightRay::new(&outside).unwrap(), tri(), f32::INFINITY).is_none());
        let away = Ray::new(Vec3::new(0.25, 0.25, 1.0), Vec3::new(0.0, 0.0, 1.0));
        assert!(intersect_triangle(&WatertightRay::new(&away).unwrap(), tri(), f32::INFINITY).is_none());
        // t_max is respected.
        assert!(intersect_triangle(&WatertightRay::new(&ray).unwrap(), tri(), 1.5).is_none());
    }

    #[test]
    fn shared_edge_is_hit_by_exactly_one_or_both_never_neither() {
        // Two triangles sharing the diagonal (1,0)-(0,1); rays aimed at interior points of
        // the diagonal (its end points are corners of the union, where a ray may pass outside).
        let a = tri();
        let b = [Vec3::new(1.0, 0.0, 0.0), Vec3::new(1.0, 1.0, 0.0), Vec3::new(0.0, 1.0, 0.0)];
        for k in 1..1000 {
            let s = k as f32 / 1000.0;
            let target = Vec3::new(1.0 - s, s, 0.0);
            let origin = Vec3::new(0.3, -0.7, 1.3);
            let ray = Ray::new(origin, (target - origin).normalize());
            let wr = WatertightRay::new(&ray).unwrap();
            let hit = intersect_triangle(&wr, a, f32::INFINITY).is_some()
                || intersect_triangle(&wr, b, f32::INFINITY).is_some();
            assert!(hit, "ray to {target} slipped through the shared edge");
        }
    }

    #[test]
    fn offset_origin_lies_on_the_outgoing_side_far_from_origin() {
        let off = Vec3::new(1.0e4, 3.0e4, -2.0e4);
        let p = [tri()[0] + off, tri()[1] + off, tri()[2] + off];
        let n = Vec3::Z;
        for k in 0..100 {
            let b1 = (k as f32 * 0.37).fract() * 0.5;
            let b2 = (k as f32 * 0.61).fract() * 0.5;
            let b = [1.0 - b1 - b2, b1, b2];
            let (x, err) = hit_point_error(p, b);
            let up = offset_ray_origin(x, err, n, Vec3::Z);
            let down = offset_ray_origin(x, err, n, -Vec3::Z);
            assert!(up.z > off.z && down.z < off.z, "offset points must straddle the plane");
            // A ray leaving upwards never re-hits its own triangle.
            let r = Ray::new(up, Vec3::new(0.3, 0.1, 1.0).normalize());
            assert!(intersect_triangle(&WatertightRay::new(&r).unwrap(), p, f32::INFINITY).is_none());
        }
    }

    #[test]
    fn f64_plane_distance_is_exact() {
        let p = [Vec3::new(-1.0, -1.0, -3.0), Vec3::new(1.0, -1.0, -3.0), Vec3::new(0.0, 1.0, -3.0)];
        let d = DVec3::new(0.1, 0.2, -1.0).normalize();
        let t = ray_triangle_plane_distance_f64(p, DVec3::ZERO, d).unwrap();
        assert!((t - 3.0 / -d.z).abs() < 1e-14);
    }

    #[test]
    fn frame_is_orthonormal() {
        for n in [Vec3::Z, -Vec3::Z, Vec3::new(0.3, -0.4, 0.5).normalize(), Vec3::new(0.0, 0.0, -0.9999).normalize()] {
            let f = Frame::from_normal(n);
            assert!(f.s.dot(f.t).abs() < 1e-6 && f.s.dot(n).abs() < 1e-6 && f.t.dot(n).abs() < 1e-6);
            assert!((f.s.length() - 1.0).abs() < 1e-5 && (f.t.length() - 1.0).abs() < 1e-5);
            let v = Vec3::new(0.2, -0.7, 0.4);
            assert!((f.to_world(f.to_local(v)) - v).length() < 1e-6);
        }
    }
}
