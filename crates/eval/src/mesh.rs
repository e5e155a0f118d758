//! Triangle meshes for geometry evaluation: [`TriMesh`] (positions, triangles, optional
//! per-vertex colours), its area, enclosed volume and normals, and binary PLY in and out.
//!
//! The PLY written is `binary_little_endian 1.0` with `float x, y, z`, `float nx, ny, nz`,
//! optionally `uchar red, green, blue` per vertex and `list uchar int vertex_indices` per face:
//! the layout Blender, MeshLab and trimesh read.
//!
//! ```
//! use eval::mesh::TriMesh;
//! let m = TriMesh::new(vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], vec![[0, 1, 2]]);
//! assert_eq!(m.area(), 0.5);
//! let bytes = m.to_ply();
//! assert_eq!(TriMesh::from_ply(&bytes).unwrap(), m);
//! ```

use crate::EvalError;
use glam::DVec3;
use std::path::Path;

/// A triangle mesh.
///
/// # Shapes
/// `positions`, `colors` (when present): one entry per vertex; `triangles`: one per face,
/// counter-clockwise seen from the side the normal points to.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions, world space.
    pub positions: Vec<[f32; 3]>,
    /// Vertex indices per triangle.
    pub triangles: Vec<[u32; 3]>,
    /// Display (sRGB) colour per vertex.
    pub colors: Option<Vec<[u8; 3]>>,
}

fn dv(p: [f32; 3]) -> DVec3 {
    DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}

impl TriMesh {
    /// A mesh without colours.
    pub fn new(positions: Vec<[f32; 3]>, triangles: Vec<[u32; 3]>) -> Self {
        Self { positions, triangles, colors: None }
    }

    /// Checks that every index is in range and every position finite.
    pub fn validate(&self) -> Result<(), EvalError> {
        let n = self.positions.len();
        if let Some((k, _)) = self.triangles.iter().enumerate().find(|(_, t)| t.iter().any(|&i| i as usize >= n)) {
            return Err(EvalError::Input(format!("mesh triangle {k} references a vertex out of range ({n} vertices)")));
        }
        if let Some(k) = self.positions.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
            return Err(EvalError::Input(format!("mesh vertex {k} is not finite")));
        }
        if let Some(c) = &self.colors
            && c.len() != n
        {
            return Err(EvalError::Input(format!("mesh has {} colours for {n} vertices", c.len())));
        }
        Ok(())
    }

    /// The corners of triangle `k`.
    pub fn corners(&self, k: usize) -> [DVec3; 3] {
        self.triangles[k].map(|i| dv(self.positions[i as usize]))
    }

    /// Area of triangle `k`.
    pub fn triangle_area(&self, k: usize) -> f64 {
        let [a, b, c] = self.corners(k);
        0.5 * (b - a).cross(c - a).length()
    }

    /// Unit normal of triangle `k` (zero for a degenerate one).
    pub fn triangle_normal(&self, k: usize) -> DVec3 {
        let [a, b, c] = self.corners(k);
        (b - a).cross(c - a).normalize_or_zero()
    }

    /// Total surface area.
    pub fn area(&self) -> f64 {
        (0..self.triangles.len()).map(|k| self.triangle_area(k)).sum()
    }

    /// Signed enclosed volume by the divergence theorem, `Σ a·(b×c) / 6`: the volume inside a
    /// closed mesh whose normals point outwards (negative when they point inwards).
    pub fn signed_volume(&self) -> f64 {
        (0..self.triangles.len())
            .map(|k| {
                let [a, b, c] = self.corners(k);
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }

    /// Area-weighted unit vertex normals (zero for a vertex of no triangle or only degenerate ones).
    pub fn vertex_normals(&self) -> Vec<[f32; 3]> {
        let mut n = vec![DVec3::ZERO; self.positions.len()];
        for (k, t) in self.triangles.iter().enumerate() {
            let [a, b, c] = self.corners(k);
            let f = (b - a).cross(c - a);
            for &i in t {
                n[i as usize] += f;
            }
        }
        n.into_iter().map(|v| v.normalize_or_zero().as_vec3().to_array()).collect()
    }

    /// The axis-aligned bounds `(min, max)`; `None` without vertices.
    pub fn bounds(&self) -> Option<([f32; 3], [f32; 3])> {
        let first = *self.positions.first()?;
        Some(self.positions.iter().fold((first, first), |(lo, hi), p| {
            ([0, 1, 2].map(|k| lo[k].min(p[k])), [0, 1, 2].map(|k| hi[k].max(p[k])))
        }))
    }

    /// Binary little-endian PLY with vertex normals (and colours when present).
    pub fn to_ply(&self) -> Vec<u8> {
        let normals = self.vertex_normals();
        let mut header = format!(
            "ply\nformat binary_little_endian 1.0\ncomment written by the eval crate (exact-ground-truth NeRF)\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\n",
            self.positions.len()
        );
        if self.colors.is_some() {
            header.push_str("property uchar red\nproperty uchar green\nproperty uchar blue\n");
        }
        header.push_str(&format!("element face {}\nproperty list uchar int vertex_indices\nend_header\n", self.triangles.len()));
        let per_vertex = 24 + if self.colors.is_some() { 3 } else { 0 };
        let mut out = Vec::with_capacity(header.len() + self.positions.len() * per_vertex + self.triangles.len() * 13);
        out.extend_from_slice(header.as_bytes());
        for (k, p) in self.positions.iter().enumerate() {
            for v in p.iter().chain(&normals[k]) {
                out.extend_from_slice(&v.to_le_bytes());
            }
            if let Some(c) = &self.colors {
                out.extend_from_slice(&c[k]);
            }
        }
        for t in &self.triangles {
            out.push(3);
            for &i in t {
                out.extend_from_slice(&(i as i32).to_le_bytes());
            }
        }
        out
    }

    /// Writes [`Self::to_ply`] atomically (temporary file in the same folder, then rename).
    pub fn write_ply(&self, path: &Path) -> Result<(), EvalError> {
        crate::io::write_atomic(path, &self.to_ply())
    }

    /// Reads a PLY written by [`Self::to_ply`]: binary little-endian, vertex properties among
    /// `float x y z`, `float nx ny nz` (ignored), `uchar red green blue`, faces as `list uchar
    /// int` (or `uint`) triangles. Anything else is an error.
    pub fn from_ply(bytes: &[u8]) -> Result<TriMesh, EvalError> {
        let bad = |m: &str| EvalError::Input(format!("PLY: {m}"));
        let end = b"end_header\n";
        let header_len = bytes.windows(end.len()).position(|w| w == end).ok_or_else(|| bad("no end_header"))? + end.len();
        let header = std::str::from_utf8(&bytes[..header_len]).map_err(|_| bad("header is not text"))?;
        let mut lines = header.lines();
        if lines.next() != Some("ply") || lines.next() != Some("format binary_little_endian 1.0") {
            return Err(bad("not a binary little-endian PLY"));
        }
        let (mut nv, mut nf, mut props, mut in_vertex) = (0usize, 0usize, Vec::new(), false);
        for l in lines {
            let w: Vec<&str> = l.split_whitespace().collect();
            match w.as_slice() {
                ["element", "vertex", n] => (nv, in_vertex) = (n.parse().map_err(|_| bad("vertex count"))?, true),
                ["element", "face", n] => (nf, in_vertex) = (n.parse().map_err(|_| bad("face count"))?, false),
                ["property", "float", name] if in_vertex => props.push((4, *name)),
                ["property", "uchar", name] if in_vertex => props.push((1, *name)),
                ["property", "list", "uchar", "int" | "uint", "vertex_indices"] if !in_vertex => {}
                ["comment", ..] | ["end_header"] => {}
                _ => return Err(bad(&format!("unsupported header line {l:?}"))),
            }
        }
        let stride: usize = props.iter().map(|p| p.0).sum();
        let body = &bytes[header_len..];
        if body.len() < nv * stride + nf * 13 {
            return Err(bad("file is shorter than its header says"));
        }
        let f32_at = |o: usize| f32::from_le_bytes([body[o], body[o + 1], body[o + 2], body[o + 3]]);
        let has_color = props.iter().any(|p| p.1 == "red");
        let mut m = TriMesh { positions: Vec::with_capacity(nv), triangles: Vec::with_capacity(nf), colors: has_color.then(Vec::new) };
        for v in 0..nv {
            let (mut p, mut c, mut o) = ([0.0f32; 3], [0u8; 3], v * stride);
            for (size, name) in &props {
                match *name {
                    "x" => p[0] = f32_at(o),
                    "y" => p[1] = f32_at(o),
                    "z" => p[2] = f32_at(o),
                    "red" => c[0] = body[o],
                    "green" => c[1] = body[o],
                    "blue" => c[2] = body[o],
                    _ => {}
                }
                o += size;
            }
            m.positions.push(p);
            if let Some(cs) = &mut m.colors {
                cs.push(c);
            }
        }
        let mut o = nv * stride;
        for _ in 0..nf {
            if body.get(o) != Some(&3) {
                return Err(bad("only triangle faces are supported"));
            }
            let i = |k: usize| u32::from_le_bytes([body[o + 1 + 4 * k], body[o + 2 + 4 * k], body[o + 3 + 4 * k], body[o + 4 + 4 * k]]);
            m.triangles.push([i(0), i(1), i(2)]);
            o += 13;
        }
        m.validate()?;
        Ok(m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The unit cube's 12 triangles, normals outwards.
    pub(crate) fn cube() -> TriMesh {
        let p: Vec<[f32; 3]> = (0..8).map(|c| [(c & 1) as f32, ((c >> 1) & 1) as f32, ((c >> 2) & 1) as f32]).collect();
        let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
        let t = quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
        TriMesh::new(p, t)
    }

    #[test]
    fn cube_area_volume_normals() {
        let m = cube();
        assert!((m.area() - 6.0).abs() < 1e-12);
        assert!((m.signed_volume() - 1.0).abs() < 1e-12);
        let n = m.vertex_normals();
        let s = 1.0 / 3f32.sqrt();
        assert!(n[7].iter().all(|v| (v - s).abs() < 1e-6), "{:?}", n[7]);
        assert_eq!(m.bounds(), Some(([0.0; 3], [1.0; 3])));
    }

    #[test]
    fn ply_round_trip_with_colours_and_bad_files() {
        let mut m = cube();
        m.colors = Some((0..8).map(|k| [k as u8 * 30, 255 - k as u8, 7]).collect());
        let bytes = m.to_ply();
        let text = String::from_utf8_lossy(&bytes[..300]);
        assert!(text.starts_with("ply\nformat binary_little_endian 1.0\n"), "{text}");
        assert!(text.contains("element vertex 8\n") && text.contains("element face 12\n") && text.contains("property uchar red\n"));
        assert_eq!(TriMesh::from_ply(&bytes).unwrap(), m);
        assert!(TriMesh::from_ply(&bytes[..bytes.len() - 1]).is_err());
        assert!(TriMesh::from_ply(b"ply\nformat ascii 1.0\nend_header\n").is_err());
        let mut bad = cube();
        bad.triangles.push([0, 1, 99]);
        assert!(bad.validate().is_err());
        let mut bytes = cube().to_ply();
        let n = bytes.len();
        bytes[n - 4..].copy_from_slice(&99i32.to_le_bytes());
        assert!(TriMesh::from_ply(&bytes).is_err());
    }
}
