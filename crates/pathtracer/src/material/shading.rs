//! The shading geometry at a hit: normals facing the ray ([`facing_normals`]), tangents
//! ([`triangle_tangent`]), normal maps ([`normal_mapped`], glTF §3.9.3: tangents from the
//! asset or generated per triangle from the UVs, untransformed: a `KHR_texture_transform`
//! moves where the normal map is read, not the tangent frame) and the frame BSDFs are
//! evaluated in ([`shading_frame`]).

// Negated comparisons (`!(x > 0.0)`) are deliberate: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::SurfaceAttributes;
use crate::geometry::Frame;
use crate::scene::{Material, Texture, TextureRef};
use crate::texture::sample_ref;
use glam::{Vec2, Vec3, Vec4};

/// Smallest `cos` between `wo` and a shading normal: [`shading_frame`] bends shading normals
/// (interpolated or normal-mapped) that face away from the viewer to this value.
pub const MIN_SHADING_COS: f32 = 1e-3;

/// The normals of a hit seen from direction `-ray_dir`: the geometric normal `ng` and the
/// shading normal `ns` (returned unit length), both flipped to face the incoming ray (the
/// shading normal is also made to agree in side with the geometric one).
#[inline]
pub fn facing_normals(ng: Vec3, ns: Vec3, ray_dir: Vec3) -> (Vec3, Vec3) {
    let ng = if ng.dot(ray_dir) > 0.0 { -ng } else { ng };
    let mut ns = if ns.is_finite() && ns.length_squared() > 0.0 { ns.normalize() } else { ng };
    if ns.dot(ng) < 0.0 {
        ns = -ns;
    }
    (ng, ns)
}

/// A per-triangle tangent from positions and UVs (the `uv` set the normal texture reads),
/// for meshes without a TANGENT attribute: `T = ∂p/∂u`, `B = ∂p/∂v'` with `v' = −v` (glTF's
/// UV origin is the image's top-left, a normal map's +Y is the image's up), made orthogonal
/// to the unit normal `n`; `w = sign((n × T)·B)` is the handedness, so that the glTF rule
/// `B = (n × T) w` reproduces the UV bitangent's side. This is MikkTSpace per triangle
/// without the per-vertex averaging. `None` for degenerate UVs.
pub fn triangle_tangent(p: [Vec3; 3], uv: [Vec2; 3], n: Vec3) -> Option<Vec4> {
    let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
    let (d1, d2) = (uv[1] - uv[0], uv[2] - uv[0]);
    let (du1, dv1, du2, dv2) = (d1.x, -d1.y, d2.x, -d2.y);
    let det = du1 * dv2 - du2 * dv1;
    if !(det.abs() > 0.0) || !det.is_finite() {
        return None;
    }
    let t = (e1 * dv2 - e2 * dv1) / det;
    let b = (e2 * du1 - e1 * du2) / det;
    let t = (t - n * n.dot(t)).normalize_or_zero();
    if t == Vec3::ZERO || !t.is_finite() {
        return None;
    }
    let w = if n.cross(t).dot(b) < 0.0 { -1.0 } else { 1.0 };
    Some(t.extend(w))
}

/// The normal-mapped shading normal (glTF 2.0 §3.9.3): the texel `c` (linear, [0, 1]) gives
/// the tangent-space normal `normalize((2c − 1) · (scale, scale, 1))`, mapped to world by
/// `T`, `B = (n × T) · w`, `n`, where `n` is the unit interpolated normal (front side) and
/// `tangent = (T, w)` (the asset's TANGENT or [`triangle_tangent`], orthogonalised to `n`
/// here). Returns `n` unchanged when the material has no normal texture or the tangent is
/// degenerate.
pub fn normal_mapped(material: &Material, textures: &[Texture], attr: &SurfaceAttributes, n: Vec3, tangent: Vec4) -> Vec3 {
    let Some((r, scale)) = &material.normal_texture else { return n };
    normal_mapped_by(r, *scale, textures, attr, n, tangent)
}

/// [`normal_mapped`] with the normal texture `r` and its `scale` (e.g. a clearcoat's).
pub fn normal_mapped_by(r: &TextureRef, scale: f32, textures: &[Texture], attr: &SurfaceAttributes, n: Vec3, tangent: Vec4) -> Vec3 {
    let t = tangent.truncate();
    let t = (t - n * n.dot(t)).normalize_or_zero();
    if t == Vec3::ZERO || !t.is_finite() {
        return n;
    }
    let w = if tangent.w < 0.0 { -1.0 } else { 1.0 };
    let b = n.cross(t) * w;
    let c = sample_ref(textures, r, attr.uv).truncate() * 2.0 - Vec3::ONE;
    let c = (c * Vec3::new(scale, scale, 1.0)).normalize_or_zero();
    let m = (t * c.x + b * c.y + n * c.z).normalize_or_zero();
    if m == Vec3::ZERO || !m.is_finite() { n } else { m }
}

/// The frame BSDFs are evaluated in at a hit: `ns` (a shading normal on the front side, e.g.
/// [`normal_mapped`]) is flipped with the surface when the ray hits its back
/// (`flipped`), then, if it still faces away from the viewer (`wo·n < MIN_SHADING_COS`, which
/// normal maps and interpolated normals at silhouettes produce), bent towards `wo` to
/// `n' = normalize(n + (MIN_SHADING_COS − wo·n) wo)`, so that `wo` is always in the upper
/// hemisphere and every value stays finite.
#[inline]
pub fn shading_frame(ns: Vec3, flipped: bool, wo: Vec3) -> Frame {
    let mut n = if flipped { -ns } else { ns };
    let c = n.dot(wo);
    if !(c >= MIN_SHADING_COS) {
        n = (n + (MIN_SHADING_COS - c) * wo).normalize_or_zero();
        if n == Vec3::ZERO || !n.is_finite() {
            n = wo;
        }
    }
    Frame::from_normal(n)
}
