//! Triangle meshes and their builders: box, UV sphere, cylinder (also along a
//! segment, for wires), disc, quad and torus, each with outward normals and
//! texture coordinates.
//!
//! Conventions: counter-clockwise triangles seen from the side the normal
//! points to (glTF front faces). Texture coordinates follow glTF: `u` to the
//! right, `v` downwards in the image (origin at the image's top-left corner).
//!
//! Meshes that are claimed closed (`cuboid`, `uv_sphere`, `cylinder`,
//! `cylinder_between`, `torus`) are closed *by position*: vertices are split
//! along UV seams and normal creases, but split copies have bit-identical
//! positions, so welding vertices with equal positions gives a closed,
//! consistently oriented 2-manifold.

use std::f64::consts::{PI, TAU};

use glam::{Mat3, Mat4, Quat, Vec2, Vec3, Vec4};

use crate::SceneGenError;

/// An indexed triangle mesh with per-vertex attributes, ready to be written as
/// one glTF primitive.
#[derive(Clone, Debug, PartialEq)]
pub struct Mesh {
    /// Vertex positions in metres (glTF `POSITION`).
    pub positions: Vec<Vec3>,
    /// Unit vertex normals (glTF `NORMAL`), one per position.
    pub normals: Vec<Vec3>,
    /// Texture coordinates (glTF `TEXCOORD_0`), one per position.
    pub uvs: Vec<Vec2>,
    /// Optional linear RGB vertex colours (glTF `COLOR_0`, multiplied into the base colour).
    pub colors: Option<Vec<Vec3>>,
    /// Optional tangents `xyz` with handedness `w = ±1` (glTF `TANGENT`);
    /// the bitangent is `cross(normal, tangent.xyz) * w`.
    pub tangents: Option<Vec<Vec4>>,
    /// Triangle list, three indices per triangle, counter-clockwise from the front.
    pub indices: Vec<u32>,
}

/// Sine and cosine of an angle computed in f64 and rounded to f32, so that the
/// same angle always yields bit-identical coordinates.
fn sin_cos(angle: f64) -> (f32, f32) {
    let (s, c) = angle.sin_cos();
    (s as f32, c as f32)
}

impl Mesh {
    /// An empty mesh.
    pub fn empty() -> Self {
        Mesh {
            positions: Vec::new(),
            normals: Vec::new(),
            uvs: Vec::new(),
            colors: None,
            tangents: None,
            indices: Vec::new(),
        }
    }

    /// Number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    fn push_vertex(&mut self, p: Vec3, n: Vec3, uv: Vec2) -> u32 {
        let i = self.positions.len() as u32;
        self.positions.push(p);
        self.normals.push(n);
        self.uvs.push(uv);
        i
    }

    /// An axis-aligned box centred at the origin with the given half extents.
    /// 24 vertices (4 per face, flat normals), 12 triangles; each face maps the
    /// whole texture once. Closed; volume `8·hx·hy·hz`.
    pub fn cuboid(half_extents: Vec3) -> Self {
        let mut m = Mesh::empty();
        // (normal, u axis, v axis); v axis points "down" in the image.
        let faces = [
            (Vec3::X, Vec3::NEG_Z, Vec3::NEG_Y),
            (Vec3::NEG_X, Vec3::Z, Vec3::NEG_Y),
            (Vec3::Y, Vec3::X, Vec3::Z),
            (Vec3::NEG_Y, Vec3::X, Vec3::NEG_Z),
            (Vec3::Z, Vec3::X, Vec3::NEG_Y),
            (Vec3::NEG_Z, Vec3::NEG_X, Vec3::NEG_Y),
        ];
        for (n, u, v) in faces {
            let base = m.positions.len() as u32;
            for (su, sv) in [(-1.0f32, -1.0f32), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                // Corners are exactly ±h on each axis, so shared corners weld exactly.
                let p = (n + u * su + v * sv) * half_extents;
                m.push_vertex(p, n, Vec2::new((su + 1.0) * 0.5, (sv + 1.0) * 0.5));
            }
            // Every frame has u × v = -n (u right, v down seen from outside),
            // so this order is counter-clockwise seen from outside.
            m.indices
                .extend([base, base + 2, base + 1, base, base + 3, base + 2]);
        }
        m
    }

    /// A UV sphere of the given radius centred at the origin, `segments`
    /// around the +Y axis (at least 3) and `rings` from pole to pole (at least
    /// 2). `u` runs once around (seam at +X), `v` from the north pole (0) to the
    /// south pole (1). The pole rows are triangles, so no triangle is
    /// degenerate. Closed; volume tends to `4/3·π·r³`.
    pub fn uv_sphere(radius: f32, segments: u32, rings: u32) -> Self {
        let segments = segments.max(3);
        let rings = rings.max(2);
        let mut m = Mesh::empty();
        let point = |ring: u32, seg: u32| -> Vec3 {
            if ring == 0 {
                return Vec3::Y;
            }
            if ring == rings {
                return Vec3::NEG_Y;
            }
            let (st, ct) = sin_cos(PI * ring as f64 / rings as f64);
            let (sp, cp) = sin_cos(TAU * (seg % segments) as f64 / segments as f64);
            Vec3::new(st * cp, ct, -st * sp)
        };
        // Rows 0..=rings, columns 0..=segments (the last column duplicates the seam).
        for ring in 0..=rings {
            for seg in 0..=segments {
                let n = point(ring, seg);
                let u = if ring == 0 || ring == rings {
                    (seg as f32 + 0.5) / segments as f32
                } else {
                    seg as f32 / segments as f32
                };
                m.push_vertex(n * radius, n, Vec2::new(u, ring as f32 / rings as f32));
            }
        }
        let idx = |ring: u32, seg: u32| ring * (segments + 1) + seg;
        for ring in 0..rings {
            for seg in 0..segments {
                let a = idx(ring, seg);
                let b = idx(ring + 1, seg);
                let c = idx(ring + 1, seg + 1);
                let d = idx(ring, seg + 1);
                // Longitude increases towards -Z from +X, i.e. counter-clockwise seen from +Y.
                if ring != 0 {
                    m.indices.extend([a, b, d]);
                }
                if ring != rings - 1 {
                    m.indices.extend([d, b, c]);
                }
            }
        }
        m
    }

    /// A capped cylinder of the given radius along +Y from `y = 0` to
    /// `y = height`, `segments` around (at least 3). The side maps `u` around
    /// and `v` downwards; the caps map a disc of diameter 1 in UV space.
    /// Closed; volume `segments/2 · r² · sin(2π/segments) · height` exactly
    /// (the inscribed prism).
    pub fn cylinder(radius: f32, height: f32, segments: u32) -> Self {
        let segments = segments.max(3);
        let mut m = Mesh::empty();
        let ring = |seg: u32| -> Vec3 {
            let (s, c) = sin_cos(TAU * (seg % segments) as f64 / segments as f64);
            Vec3::new(c, 0.0, -s)
        };
        // The side and the caps compute rim points with this one expression, so
        // they are bit-identical.
        let rim = |seg: u32, y: f32| ring(seg) * radius + Vec3::Y * y;
        // Side.
        for seg in 0..=segments {
            let n = ring(seg);
            let u = seg as f32 / segments as f32;
            m.push_vertex(rim(seg, height), n, Vec2::new(u, 0.0));
            m.push_vertex(rim(seg, 0.0), n, Vec2::new(u, 1.0));
        }
        for seg in 0..segments {
            let top0 = 2 * seg;
            let bot0 = top0 + 1;
            let top1 = top0 + 2;
            let bot1 = top0 + 3;
            m.indices.extend([top0, bot0, bot1, top0, bot1, top1]);
        }
        // Caps.
        for (y, n) in [(height, Vec3::Y), (0.0, Vec3::NEG_Y)] {
            let centre = m.push_vertex(Vec3::Y * y, n, Vec2::splat(0.5));
            let first = m.positions.len() as u32;
            for seg in 0..segments {
                let d = ring(seg);
                let uv = Vec2::new(0.5 + 0.5 * d.x, 0.5 + 0.5 * d.z * n.y);
                m.push_vertex(rim(seg, y), n, uv);
            }
            for seg in 0..segments {
                let a = first + seg;
                let b = first + (seg + 1) % segments;
                if n.y > 0.0 {
                    m.indices.extend([centre, a, b]);
                } else {
                    m.indices.extend([centre, b, a]);
                }
            }
        }
        m
    }

    /// A capped cylinder (a wire, a rod, a pillar) from point `a` to point `b`.
    /// Closed. Returns an empty mesh when `a == b`.
    pub fn cylinder_between(a: Vec3, b: Vec3, radius: f32, segments: u32) -> Self {
        let axis = b - a;
        let length = axis.length();
        if length <= 0.0 || !length.is_finite() {
            return Mesh::empty();
        }
        let rotation = Quat::from_rotation_arc(Vec3::Y, axis / length);
        Mesh::cylinder(radius, length, segments)
            .transformed(&Mat4::from_rotation_translation(rotation, a))
    }

    /// A flat disc of the given radius in the XZ plane, facing +Y, centred at
    /// the origin, `segments` around (at least 3). UVs map the planar
    /// coordinates: `(u, v) = (x, z) / (2·radius) + 0.5`, scaled by `uv_scale`
    /// about the centre (use > 1 to repeat a texture). Open (one boundary loop).
    pub fn disc(radius: f32, segments: u32, uv_scale: f32) -> Self {
        let segments = segments.max(3);
        let mut m = Mesh::empty();
        let uv = |p: Vec3| Vec2::new(p.x, p.z) / (2.0 * radius) * uv_scale + Vec2::splat(0.5);
        let centre = m.push_vertex(Vec3::ZERO, Vec3::Y, uv(Vec3::ZERO));
        for seg in 0..segments {
            let (s, c) = sin_cos(TAU * seg as f64 / segments as f64);
            let p = Vec3::new(c, 0.0, -s) * radius;
            m.push_vertex(p, Vec3::Y, uv(p));
        }
        for seg in 0..segments {
            m.indices
                .extend([centre, 1 + seg, 1 + (seg + 1) % segments]);
        }
        m
    }

    /// A rectangle of `size.x` (along X) by `size.y` (along Z) in the XZ
    /// plane, facing +Y, centred at the origin. `u` runs along +X and `v`
    /// along +Z, over `[0, uv_scale]`. Two triangles; open.
    pub fn quad(size: Vec2, uv_scale: f32) -> Self {
        let mut m = Mesh::empty();
        let h = size * 0.5;
        for (sx, sz) in [(-1.0f32, -1.0f32), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
            m.push_vertex(
                Vec3::new(sx * h.x, 0.0, sz * h.y),
                Vec3::Y,
                Vec2::new((sx + 1.0) * 0.5, (sz + 1.0) * 0.5) * uv_scale,
            );
        }
        // Seen from +Y, (-x,-z) → (-x,+z) → (+x,+z) is counter-clockwise.
        m.indices.extend([0, 3, 2, 0, 2, 1]);
        m
    }

    /// A planar quadrilateral through four corners given counter-clockwise as
    /// seen from the front; the flat normal is `normalize((c1 − c0) × (c2 − c0))`.
    /// UVs: `c0 → (0, 1)`, `c1 → (1, 1)`, `c2 → (1, 0)`, `c3 → (0, 0)` (the
    /// texture upright when `c0 → c1` is "right"). The corners are stored
    /// exactly, so quads sharing corners share bit-identical edges.
    pub fn quad_from_corners(corners: [Vec3; 4]) -> Self {
        let mut m = Mesh::empty();
        let n = (corners[1] - corners[0])
            .cross(corners[2] - corners[0])
            .normalize_or_zero();
        let uvs = [
            Vec2::new(0.0, 1.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(1.0, 0.0),
            Vec2::new(0.0, 0.0),
        ];
        for (c, uv) in corners.into_iter().zip(uvs) {
            m.push_vertex(c, n, uv);
        }
        m.indices.extend([0, 1, 2, 0, 2, 3]);
        m
    }

    /// Replace the UVs by a planar projection onto XZ: `uv = (x, z) / period`,
    /// so a texture repeats every `period` metres (with REPEAT wrapping).
    pub fn with_planar_uvs(mut self, period: f32) -> Self {
        self.uvs = self
            .positions
            .iter()
            .map(|p| Vec2::new(p.x, p.z) / period)
            .collect();
        self
    }

    /// A torus around the +Y axis, centred at the origin, with the given
    /// major (centre-line) and minor (tube) radii. `u` runs around the major
    /// circle, `v` around the tube. Closed; volume tends to `2π²·R·r²`.
    pub fn torus(major: f32, minor: f32, major_segments: u32, minor_segments: u32) -> Self {
        let ns = major_segments.max(3);
        let nt = minor_segments.max(3);
        let mut m = Mesh::empty();
        for i in 0..=ns {
            let (sp, cp) = sin_cos(TAU * (i % ns) as f64 / ns as f64);
            let radial = Vec3::new(cp, 0.0, -sp);
            for j in 0..=nt {
                let (st, ct) = sin_cos(TAU * (j % nt) as f64 / nt as f64);
                let n = radial * ct + Vec3::Y * st;
                let p = radial * major + n * minor;
                m.push_vertex(p, n, Vec2::new(i as f32 / ns as f32, j as f32 / nt as f32));
            }
        }
        let idx = |i: u32, j: u32| i * (nt + 1) + j;
        for i in 0..ns {
            for j in 0..nt {
                let a = idx(i, j);
                let b = idx(i + 1, j);
                let c = idx(i + 1, j + 1);
                let d = idx(i, j + 1);
                m.indices.extend([a, b, c, a, c, d]);
            }
        }
        m
    }

    /// This mesh with every vertex transformed by `m` (positions by `m`,
    /// normals by its inverse transpose, tangents by its linear part). A
    /// transform with negative determinant flips the triangle winding so faces
    /// stay front-facing outwards.
    pub fn transformed(&self, m: &Mat4) -> Mesh {
        let linear = Mat3::from_mat4(*m);
        let normal_matrix = linear.inverse().transpose();
        let flip = linear.determinant() < 0.0;
        let mut out = self.clone();
        for p in &mut out.positions {
            *p = m.transform_point3(*p);
        }
        for n in &mut out.normals {
            *n = (normal_matrix * *n).normalize_or_zero();
        }
        if let Some(ts) = &mut out.tangents {
            for t in ts {
                let xyz = (linear * t.truncate()).normalize_or_zero();
                let w = if flip { -t.w } else { t.w };
                *t = xyz.extend(w);
            }
        }
        if flip {
            for tri in out.indices.chunks_exact_mut(3) {
                tri.swap(1, 2);
            }
        }
        out
    }

    /// Append `other` to this mesh. Optional attributes (colours, tangents)
    /// are kept only if both meshes have them, except that colours missing
    /// on one side are filled with white.
    pub fn append(&mut self, other: &Mesh) {
        let base = self.positions.len() as u32;
        let self_n = self.positions.len();
        match (&mut self.colors, &other.colors) {
            (Some(a), Some(b)) => a.extend_from_slice(b),
            (Some(a), None) => a.extend(std::iter::repeat_n(Vec3::ONE, other.positions.len())),
            (None, Some(b)) => {
                let mut a = vec![Vec3::ONE; self_n];
                a.extend_from_slice(b);
                self.colors = Some(a);
            }
            (None, None) => {}
        }
        match (&mut self.tangents, &other.tangents) {
            (Some(a), Some(b)) => a.extend_from_slice(b),
            _ if self_n == 0 => self.tangents = other.tangents.clone(),
            _ => self.tangents = None,
        }
        self.positions.extend_from_slice(&other.positions);
        self.normals.extend_from_slice(&other.normals);
        self.uvs.extend_from_slice(&other.uvs);
        self.indices.extend(other.indices.iter().map(|i| i + base));
    }

    /// Concatenate meshes into one (see [`Mesh::append`]).
    pub fn merge<'a>(meshes: impl IntoIterator<Item = &'a Mesh>) -> Mesh {
        let mut out = Mesh::empty();
        for m in meshes {
            out.append(m);
        }
        out
    }

    /// Set per-vertex colours from a function of position and normal.
    pub fn with_colors(mut self, f: impl Fn(Vec3, Vec3) -> Vec3) -> Mesh {
        self.colors = Some(
            self.positions
                .iter()
                .zip(&self.normals)
                .map(|(&p, &n)| f(p, n))
                .collect(),
        );
        self
    }

    /// Compute per-vertex tangents from the texture coordinates (the
    /// per-triangle `dP/du` accumulated at each vertex, made orthogonal to the
    /// normal). Handedness `w` is chosen so that `cross(normal, tangent) * w`
    /// points towards decreasing `v`, i.e. "up" in the image, which is the
    /// glTF / OpenGL normal-map convention (+Y up).
    pub fn with_tangents(mut self) -> Mesh {
        let n = self.positions.len();
        let mut tu = vec![Vec3::ZERO; n];
        let mut tv = vec![Vec3::ZERO; n];
        for tri in self.indices.chunks_exact(3) {
            let [a, b, c] = [tri[0] as usize, tri[1] as usize, tri[2] as usize];
            let e1 = self.positions[b] - self.positions[a];
            let e2 = self.positions[c] - self.positions[a];
            let d1 = self.uvs[b] - self.uvs[a];
            let d2 = self.uvs[c] - self.uvs[a];
            let det = d1.x * d2.y - d2.x * d1.y;
            if det.abs() < 1e-12 {
                continue;
            }
            let r = 1.0 / det;
            let dpdu = (e1 * d2.y - e2 * d1.y) * r;
            let dpdv = (e2 * d1.x - e1 * d2.x) * r;
            for v in [a, b, c] {
                tu[v] += dpdu;
                tv[v] += dpdv;
            }
        }
        let tangents = (0..n)
            .map(|i| {
                let nrm = self.normals[i];
                let mut t = (tu[i] - nrm * nrm.dot(tu[i])).normalize_or_zero();
                if t == Vec3::ZERO {
                    t = nrm.any_orthonormal_vector();
                }
                let w = if nrm.cross(t).dot(-tv[i]) < 0.0 {
                    -1.0
                } else {
                    1.0
                };
                t.extend(w)
            })
            .collect();
        self.tangents = Some(tangents);
        self
    }

    /// Signed enclosed volume by the divergence theorem,
    /// `V = Σ p0 · (p1 × p2) / 6` over the triangles, computed in f64. Positive
    /// for a closed mesh with outward (counter-clockwise) winding.
    pub fn signed_volume(&self) -> f64 {
        self.indices
            .chunks_exact(3)
            .map(|t| {
                let p = |i: u32| self.positions[i as usize].as_dvec3();
                p(t[0]).dot(p(t[1]).cross(p(t[2]))) / 6.0
            })
            .sum()
    }

    /// Axis-aligned bounds `(min, max)` of the positions, or `None` if empty.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let first = *self.positions.first()?;
        Some(
            self.positions
                .iter()
                .fold((first, first), |(lo, hi), &p| (lo.min(p), hi.max(p))),
        )
    }

    /// Check the mesh is well formed: attribute arrays of equal length,
    /// indices in range and a whole number of triangles, finite values.
    pub fn validate(&self, name: &str) -> Result<(), SceneGenError> {
        let bad = |reason: String| SceneGenError::InvalidMesh {
            name: name.to_string(),
            reason,
        };
        let n = self.positions.len();
        if n == 0 || self.indices.is_empty() {
            return Err(bad("mesh has no vertices or no triangles".into()));
        }
        if self.normals.len() != n || self.uvs.len() != n {
            return Err(bad(format!(
                "{} positions but {} normals and {} uvs",
                n,
                self.normals.len(),
                self.uvs.len()
            )));
        }
        if self.colors.as_ref().is_some_and(|c| c.len() != n) {
            return Err(bad("colour count differs from vertex count".into()));
        }
        if self.tangents.as_ref().is_some_and(|t| t.len() != n) {
            return Err(bad("tangent count differs from vertex count".into()));
        }
        if !self.indices.len().is_multiple_of(3) {
            return Err(bad(format!(
                "{} indices is not a multiple of 3",
                self.indices.len()
            )));
        }
        if let Some(&i) = self.indices.iter().find(|&&i| i as usize >= n) {
            return Err(bad(format!("index {i} out of range for {n} vertices")));
        }
        let finite = self.positions.iter().all(|p| p.is_finite())
            && self.normals.iter().all(|p| p.is_finite())
            && self.uvs.iter().all(|p| p.is_finite());
        if !finite {
            return Err(bad("non-finite vertex attribute".into()));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    /// Weld vertices with bit-identical positions; return triangles over welded ids.
    fn welded_triangles(m: &Mesh) -> Vec<[u32; 3]> {
        let mut ids: HashMap<[u32; 3], u32> = HashMap::new();
        let remap: Vec<u32> = m
            .positions
            .iter()
            .map(|p| {
                // + 0.0 maps -0.0 to +0.0.
                let key = [
                    (p.x + 0.0).to_bits(),
                    (p.y + 0.0).to_bits(),
                    (p.z + 0.0).to_bits(),
                ];
                let next = ids.len() as u32;
                *ids.entry(key).or_insert(next)
            })
            .collect();
        m.indices
            .chunks_exact(3)
            .map(|t| {
                [
                    remap[t[0] as usize],
                    remap[t[1] as usize],
                    remap[t[2] as usize],
                ]
            })
            .collect()
    }

    /// Closed, consistently oriented: every directed edge appears once and its
    /// reverse appears once (so every undirected edge has exactly two faces).
    fn assert_closed(m: &Mesh, what: &str) {
        m.validate(what).unwrap();
        let tris = welded_triangles(m);
        let mut directed: HashMap<(u32, u32), u32> = HashMap::new();
        for t in &tris {
            assert!(
                t[0] != t[1] && t[1] != t[2] && t[0] != t[2],
                "{what}: degenerate triangle {t:?}"
            );
            for k in 0..3 {
                *directed.entry((t[k], t[(k + 1) % 3])).or_default() += 1;
            }
        }
        for (&(a, b), &count) in &directed {
            assert_eq!(
                count, 1,
                "{what}: directed edge {a}->{b} used {count} times"
            );
            assert_eq!(
                directed.get(&(b, a)),
                Some(&1),
                "{what}: edge {a}-{b} has no opposite face"
            );
        }
    }

    /// Every triangle's geometric normal agrees with its vertex normals, and normals are unit.
    fn assert_normals_agree(m: &Mesh, what: &str) {
        for t in m.indices.chunks_exact(3) {
            let p: Vec<Vec3> = t.iter().map(|&i| m.positions[i as usize]).collect();
            let g = (p[1] - p[0]).cross(p[2] - p[0]);
            assert!(g.length() > 0.0, "{what}: zero-area triangle");
            for &i in t {
                let n = m.normals[i as usize];
                assert!((n.length() - 1.0).abs() < 1e-5, "{what}: normal not unit");
                assert!(
                    g.dot(n) > 0.0,
                    "{what}: winding disagrees with normal at vertex {i}"
                );
            }
        }
    }

    #[test]
    fn cuboid_is_closed_with_exact_volume() {
        let m = Mesh::cuboid(Vec3::new(0.5, 1.0, 1.5));
        assert_closed(&m, "cuboid");
        assert_normals_agree(&m, "cuboid");
        assert!((m.signed_volume() - 6.0).abs() < 1e-9);
        assert_eq!(
            m.bounds(),
            Some((Vec3::new(-0.5, -1.0, -1.5), Vec3::new(0.5, 1.0, 1.5)))
        );
    }

    #[test]
    fn sphere_is_closed_and_volume_converges() {
        let r = 0.7f64;
        let exact = 4.0 / 3.0 * PI * r.powi(3);
        let mut last_err = f64::INFINITY;
        for (seg, rings) in [(8, 4), (16, 8), (32, 16), (64, 32)] {
            let m = Mesh::uv_sphere(r as f32, seg, rings);
            assert_closed(&m, "sphere");
            assert_normals_agree(&m, "sphere");
            let err = (m.signed_volume() - exact).abs() / exact;
            // Inscribed polyhedron: volume below the sphere's, error shrinking ~4x per doubling.
            assert!(m.signed_volume() < exact);
            assert!(
                err < last_err / 3.0,
                "error {err} did not shrink from {last_err}"
            );
            last_err = err;
        }
        assert!(last_err < 0.005, "64x32 sphere volume error {last_err}");
    }

    #[test]
    fn cylinder_is_closed_with_exact_prism_volume() {
        for seg in [3u32, 7, 32] {
            let (r, h) = (0.3f64, 2.0f64);
            let m = Mesh::cylinder(r as f32, h as f32, seg);
            assert_closed(&m, "cylinder");
            assert_normals_agree(&m, "cylinder");
            let n = seg as f64;
            let prism = n / 2.0 * r * r * (TAU / n).sin() * h;
            assert!(
                (m.signed_volume() - prism).abs() < 1e-6 * prism,
                "seg {seg}"
            );
        }
    }

    #[test]
    fn cylinder_between_spans_the_segment() {
        let a = Vec3::new(0.1, -0.2, 0.3);
        let b = Vec3::new(-0.5, 0.7, 1.1);
        let r = 0.01f32;
        let m = Mesh::cylinder_between(a, b, r, 12);
        assert_closed(&m, "wire");
        let len = (b - a).length() as f64;
        let prism = 6.0 * (r as f64).powi(2) * (TAU / 12.0).sin() * len;
        assert!((m.signed_volume() - prism).abs() < 1e-4 * prism);
        // Every vertex lies within radius of the segment and between its end planes.
        let axis = (b - a).normalize();
        for &p in &m.positions {
            let t = (p - a).dot(axis);
            let d = (p - a - axis * t).length();
            assert!(t > -1e-5 && t < (b - a).length() + 1e-5);
            assert!(d < r * 1.0001);
        }
        assert!(Mesh::cylinder_between(a, a, r, 12).positions.is_empty());
    }

    #[test]
    fn torus_is_closed_and_volume_converges() {
        let (big, small) = (1.0f64, 0.25f64);
        let exact = 2.0 * PI * PI * big * small * small;
        let coarse = Mesh::torus(big as f32, small as f32, 16, 8);
        let fine = Mesh::torus(big as f32, small as f32, 96, 48);
        for m in [&coarse, &fine] {
            assert_closed(m, "torus");
            assert_normals_agree(m, "torus");
        }
        let e_coarse = (coarse.signed_volume() - exact).abs() / exact;
        let e_fine = (fine.signed_volume() - exact).abs() / exact;
        // Leading-order error of the inscribed polygons in both directions:
        // area ratio sin(x)/x ≈ 1 - x²/6 with x = 2π/n.
        let predicted = |ns: f64, nt: f64| ((TAU / ns).powi(2) + (TAU / nt).powi(2)) / 6.0;
        assert!(
            e_fine < 1.2 * predicted(96.0, 48.0),
            "fine torus error {e_fine}"
        );
        assert!(
            e_fine > 0.8 * predicted(96.0, 48.0),
            "fine torus error {e_fine}"
        );
        // 6x finer in both directions: ~36x smaller error.
        assert!(e_coarse > 20.0 * e_fine);
    }

    #[test]
    fn open_meshes_face_up_and_have_one_boundary_loop() {
        for (m, area) in [
            (Mesh::quad(Vec2::new(2.0, 3.0), 1.0), 6.0f64),
            (Mesh::disc(1.0, 64, 1.0), 32.0 * (TAU / 64.0).sin()),
        ] {
            m.validate("open").unwrap();
            assert_normals_agree(&m, "open");
            let mut sum = Vec3::ZERO.as_dvec3();
            for t in m.indices.chunks_exact(3) {
                let p: Vec<_> = t
                    .iter()
                    .map(|&i| m.positions[i as usize].as_dvec3())
                    .collect();
                sum += (p[1] - p[0]).cross(p[2] - p[0]) * 0.5;
            }
            // Vector area points +Y with magnitude equal to the polygon's area.
            assert!((sum.y - area).abs() < 1e-5 * area && sum.x.abs() < 1e-9 && sum.z.abs() < 1e-9);
        }
    }

    #[test]
    fn mirrored_transform_keeps_outward_winding() {
        let m =
            Mesh::uv_sphere(1.0, 12, 6).transformed(&Mat4::from_scale(Vec3::new(-1.0, 2.0, 1.0)));
        assert_closed(&m, "mirrored");
        assert_normals_agree(&m, "mirrored");
        assert!(m.signed_volume() > 0.0);
    }

    #[test]
    fn tangents_follow_u_and_are_orthonormal() {
        let m = Mesh::quad(Vec2::ONE, 1.0).with_tangents();
        for t in m.tangents.as_ref().unwrap() {
            // u runs along +X; v along +Z, so "up" (-v) is -Z = cross(+Y, +X): w = +1.
            assert!((t.truncate() - Vec3::X).length() < 1e-6 && t.w == 1.0);
        }
        let s = Mesh::uv_sphere(1.0, 16, 8).with_tangents();
        for ((t, n), p) in s
            .tangents
            .as_ref()
            .unwrap()
            .iter()
            .zip(&s.normals)
            .zip(&s.positions)
        {
            assert!((t.truncate().length() - 1.0).abs() < 1e-5);
            assert!(t.truncate().dot(*n).abs() < 1e-5);
            // Away from the poles u increases with longitude φ, p = (cos φ, ·, -sin φ)·sin θ,
            // so the tangent is ∂p/∂φ ∝ (z, 0, -x).
            if p.y.abs() < 0.9 {
                let east = Vec3::new(p.z, 0.0, -p.x).normalize();
                assert!(t.truncate().dot(east) > 0.9, "tangent {t} at {p}");
            }
        }
    }

    #[test]
    fn validate_rejects_bad_indices() {
        let mut m = Mesh::quad(Vec2::ONE, 1.0);
        m.indices[0] = 99;
        assert!(matches!(
            m.validate("q"),
            Err(SceneGenError::InvalidMesh { .. })
        ));
    }
}
