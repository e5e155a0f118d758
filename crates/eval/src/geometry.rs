//! Another tool's geometry scored against the scene exactly like our extracted mesh.
//!
//! - [`read_geometry`]: a PLY (`ascii`, `binary_little_endian`, `binary_big_endian`; vertex
//!   `x y z` as `float`/`double`, optional `nx ny nz`; faces as a `vertex_indices` or
//!   `vertex_index` list of any integer types) or an OBJ (`v`, `vn`, `f` in its `v`, `v/vt`,
//!   `v//vn`, `v/vt/vn` forms, negative indices relative to the vertices so far). Polygons are
//!   fan-triangulated; a file without faces is a point cloud (PLY normals, or OBJ `vn` one per
//!   `v`, are its normals). Only a regular file of at most [`MAX_GEOMETRY_BYTES`] is read, with at
//!   most [`MAX_VERTICES`] vertices and [`MAX_TRIANGLES`] triangles (checked against the file's
//!   size before anything is allocated); every malformed input is an error naming the file and
//!   the element or line. A vertex with a non-finite coordinate is dropped with the triangles
//!   using it, and counted.
//! - [`transform`]: a row-major 4x4 affine matrix `M` (last row `0 0 0 1`, non-singular) maps
//!   the file's frame to the dataset's: `p' = M·[p, 1]`; normals go through the inverse
//!   transpose of its 3x3 part and are renormalised. [`parse_matrix`] reads one from 16 numbers
//!   (or 12, the top 3x4 rows) or from a file holding them (JSON arrays or plain text).
//! - [`score_geometry`]: a mesh goes through [`crate::mesh_eval::visible_part`] and
//!   [`crate::mesh_metrics::mesh_metrics`] with [`crate::mesh_eval::metrics_options`], the path
//!   of [`crate::mesh_eval::compare_with_reference`]; a point cloud through
//!   [`crate::mesh_metrics::point_metrics`] with every point measured (points hide nothing, so
//!   there is no visibility test), normal consistency only with normals. The block records the
//!   input ([`GeometryInput`]) and, for what is absent, why.
//!
//! Coordinates are kept as `f32`, as our meshes are.
//!
//! ```
//! use eval::geometry::{Shape, parse_matrix, read_geometry, transform};
//! let dir = std::env::temp_dir().join(format!("geometry-doc-{}", std::process::id()));
//! std::fs::create_dir_all(&dir).unwrap();
//! let path = dir.join("tri.obj");
//! std::fs::write(&path, "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 4 3\n").unwrap();
//! let mut g = read_geometry(&path).unwrap();
//! assert_eq!(g.input.triangles, 2); // the quad, fan-triangulated
//! let m = parse_matrix("2 0 0 1, 0 2 0 0, 0 0 2 0, 0 0 0 1").unwrap();
//! transform(&mut g, &m).unwrap();
//! let Shape::Mesh(mesh) = &g.shape else { unreachable!() };
//! assert_eq!(mesh.positions[3], [3.0, 2.0, 0.0]);
//! std::fs::remove_dir_all(&dir).unwrap();
//! ```

mod obj;
mod ply;

use crate::EvalError;
use crate::mesh::TriMesh;
use crate::mesh_eval::{MeshBlock, SceneReference, metrics_options, visible_part};
pub use crate::mesh_eval::{GeometryInput, GeometryKind};
use crate::mesh_metrics::{mesh_metrics, point_metrics};
use glam::{DMat3, DVec3, Vec3};
use std::path::Path;

/// The largest geometry file read, bytes (2 GiB).
pub const MAX_GEOMETRY_BYTES: u64 = 2 << 30;
/// The most vertices (points) a geometry file may hold.
pub const MAX_VERTICES: usize = 50_000_000;
/// The most triangles a geometry file may hold, after fan triangulation.
pub const MAX_TRIANGLES: usize = 50_000_000;
/// The largest matrix file [`parse_matrix`] reads, bytes.
const MAX_MATRIX_BYTES: u64 = 1 << 20;

/// Another tool's geometry: a surface or points.
#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    /// Triangles.
    Mesh(TriMesh),
    /// Points, with a unit normal each or none.
    ///
    /// # Shapes
    /// `normals`, when present: one per point.
    Points {
        /// The points.
        points: Vec<[f32; 3]>,
        /// Their unit normals.
        normals: Option<Vec<[f32; 3]>>,
    },
}

/// A geometry file as read: its shape and what was read (kept up to date by [`transform`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Geometry {
    /// The mesh or point cloud.
    pub shape: Shape,
    /// The file, its format and counts, the transform applied, notes.
    pub input: GeometryInput,
}

/// What a reader hands back before non-finite vertices are dropped.
struct Raw {
    format: &'static str,
    positions: Vec<[f32; 3]>,
    /// Per-vertex normals (used only for a point cloud).
    normals: Option<Vec<[f32; 3]>>,
    triangles: Vec<[u32; 3]>,
    /// Faces read (0: a point cloud).
    faces: usize,
    /// Faces of more than three corners.
    polygons: usize,
    notes: Vec<String>,
}

impl Raw {
    fn new(format: &'static str) -> Self {
        Self { format, positions: Vec::new(), normals: None, triangles: Vec::new(), faces: 0, polygons: 0, notes: Vec::new() }
    }

    /// Appends the fan triangles of a face's corners (at least three).
    fn push_face(&mut self, corners: &[u32]) -> Result<(), String> {
        if corners.len() < 3 {
            return Err(format!("it has {} corners; a face needs at least 3", corners.len()));
        }
        if self.triangles.len() + corners.len() - 2 > MAX_TRIANGLES {
            return Err(format!("more than {MAX_TRIANGLES} triangles, the most a geometry file may hold"));
        }
        self.faces += 1;
        if corners.len() > 3 {
            self.polygons += 1;
        }
        for k in 1..corners.len() - 1 {
            self.triangles.push([corners[0], corners[k], corners[k + 1]]);
        }
        Ok(())
    }
}

/// Reads `path` whole, refusing anything but a regular file (a FIFO or a device would block or
/// never end) and a file over `max_bytes`; errors name the file.
pub fn read_regular_file(path: &Path, max_bytes: u64) -> Result<Vec<u8>, EvalError> {
    use std::io::Read;
    let io = |source| EvalError::Io { path: path.to_path_buf(), source };
    let not_regular = |t: std::fs::FileType| EvalError::Input(format!("{}: not a regular file ({})", path.display(), file_kind(t)));
    let meta = std::fs::metadata(path).map_err(io)?;
    if !meta.is_file() {
        return Err(not_regular(meta.file_type()));
    }
    let too_big = |n: u64| EvalError::Input(format!("{}: {n} bytes, over the limit of {max_bytes} bytes", path.display()));
    if meta.len() > max_bytes {
        return Err(too_big(meta.len()));
    }
    let file = std::fs::File::open(path).map_err(io)?;
    let meta = file.metadata().map_err(io)?;
    if !meta.is_file() {
        return Err(not_regular(meta.file_type()));
    }
    let mut bytes = Vec::with_capacity(meta.len().min(max_bytes) as usize);
    file.take(max_bytes + 1).read_to_end(&mut bytes).map_err(io)?;
    if bytes.len() as u64 > max_bytes {
        return Err(too_big(bytes.len() as u64));
    }
    Ok(bytes)
}

fn file_kind(t: std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "a FIFO";
        }
        if t.is_char_device() || t.is_block_device() {
            return "a device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    if t.is_dir() { "a folder" } else { "not a plain file" }
}

/// Reads a PLY (recognised by its first line, `ply`) or an OBJ (by the `.obj` extension) in
/// its own frame (see the module docs for what is accepted).
pub fn read_geometry(path: &Path) -> Result<Geometry, EvalError> {
    let bytes = read_regular_file(path, MAX_GEOMETRY_BYTES)?;
    let bad = |m: String| EvalError::Input(format!("{}: {m}", path.display()));
    let is_ply = bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r\n");
    let ext = path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase());
    let raw = match ext.as_deref() {
        _ if is_ply => ply::parse(&bytes),
        Some("ply") => Err("not a PLY file: its first line is not `ply`".to_string()),
        Some("obj") => obj::parse(&bytes),
        _ => Err("not a geometry file this reads: a PLY starts with the line `ply`, an OBJ ends in .obj".to_string()),
    }
    .map_err(bad)?;
    finish(raw, &path.display().to_string()).map_err(bad)
}

/// Drops non-finite vertices (and the triangles using them), decides mesh or point cloud, and
/// records the counts.
fn finish(raw: Raw, file: &str) -> Result<Geometry, String> {
    let Raw { format, positions, normals, triangles, faces, polygons, mut notes } = raw;
    let finite = |p: &[f32; 3]| p.iter().all(|v| v.is_finite());
    let mut new_index = vec![u32::MAX; positions.len()];
    let mut kept = Vec::with_capacity(positions.len());
    for (k, p) in positions.iter().enumerate() {
        if finite(p) {
            new_index[k] = kept.len() as u32;
            kept.push(*p);
        }
    }
    let dropped_vertices = positions.len() - kept.len();
    if kept.is_empty() {
        return Err(match positions.len() {
            0 => "it holds no vertices".to_string(),
            n => format!("none of its {n} vertices has finite coordinates"),
        });
    }
    if dropped_vertices > 0 {
        notes.push(format!("{dropped_vertices} of {} vertices have a non-finite coordinate and were dropped.", positions.len()));
    }
    let mut input = GeometryInput {
        file: file.to_string(),
        format: format.to_string(),
        kind: GeometryKind::Mesh,
        vertices: kept.len(),
        triangles: 0,
        polygons,
        dropped_vertices,
        dropped_triangles: 0,
        normals: false,
        to_dataset: None,
        measured_points: None,
        notes,
    };
    if faces > 0 {
        let tris: Vec<[u32; 3]> = triangles.iter().map(|t| t.map(|i| new_index[i as usize])).filter(|t| !t.contains(&u32::MAX)).collect();
        input.dropped_triangles = triangles.len() - tris.len();
        if input.dropped_triangles > 0 {
            input.notes.push(format!("{} of {} triangles use a dropped vertex and were dropped.", input.dropped_triangles, triangles.len()));
        }
        if tris.is_empty() {
            return Err(format!("none of its {} triangles has three finite corners", triangles.len()));
        }
        input.triangles = tris.len();
        return Ok(Geometry { shape: Shape::Mesh(TriMesh::new(kept, tris)), input });
    }
    input.kind = GeometryKind::PointCloud;
    let normals = normals.map(|n| n.iter().enumerate().filter(|(k, _)| new_index[*k] != u32::MAX).map(|(_, v)| *v).collect::<Vec<_>>());
    let normals = match normals {
        None => {
            input.notes.push("Normal consistency is absent: the points carry no normals.".into());
            None
        }
        Some(n) => match unit_normals(&n) {
            Ok(unit) => Some(unit),
            Err(bad) => {
                input.notes.push(format!("Normal consistency is absent: {bad} of {} points have a zero or non-finite normal.", n.len()));
                None
            }
        },
    };
    input.normals = normals.is_some();
    input.notes.push("Every point is measured: points hide nothing from the cameras, so there is no visibility test (a mesh keeps only what the cameras see); area and triangles are 0.".into());
    Ok(Geometry { shape: Shape::Points { points: kept, normals }, input })
}

/// The normals scaled to unit length, or how many are zero or not finite.
fn unit_normals(n: &[[f32; 3]]) -> Result<Vec<[f32; 3]>, usize> {
    let unit: Vec<Option<[f32; 3]>> = n.iter().map(|v| Vec3::from(*v).as_dvec3().try_normalize().map(|u| u.as_vec3().to_array())).collect();
    let bad = unit.iter().filter(|u| u.is_none()).count();
    if bad > 0 { Err(bad) } else { Ok(unit.into_iter().flatten().collect()) }
}

/// The linear part, translation and normal matrix of a checked affine transform.
struct Affine {
    linear: DMat3,
    translation: DVec3,
    normal: DMat3,
}

impl Affine {
    fn new(m: &[[f64; 4]; 4]) -> Result<Self, String> {
        if !m.iter().flatten().all(|v| v.is_finite()) {
            return Err("the transform to the dataset's frame holds a non-finite number".into());
        }
        let r = m[3];
        if r[0].abs() > 1e-9 || r[1].abs() > 1e-9 || r[2].abs() > 1e-9 || (r[3] - 1.0).abs() > 1e-9 {
            return Err(format!("the transform to the dataset's frame is not affine: its last row is {r:?}, not [0, 0, 0, 1]"));
        }
        let col = |c: usize| DVec3::new(m[0][c], m[1][c], m[2][c]);
        let linear = DMat3::from_cols(col(0), col(1), col(2));
        let det = linear.determinant();
        let scale = (0..3).map(|c| col(c).length()).fold(0.0, f64::max);
        if det.is_nan() || det.abs() <= 1e-12 * scale.powi(3) {
            return Err(format!("the transform to the dataset's frame is singular (its 3x3 part has determinant {det:e})"));
        }
        Ok(Self { linear, translation: col(3), normal: linear.inverse().transpose() })
    }

    fn point(&self, p: [f32; 3]) -> DVec3 {
        self.linear * Vec3::from(p).as_dvec3() + self.translation
    }
}

/// `a · b`, row-major 4x4.
fn mul(a: &[[f64; 4]; 4], b: &[[f64; 4]; 4]) -> [[f64; 4]; 4] {
    let mut out = [[0.0; 4]; 4];
    for (r, row) in out.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = (0..4).map(|k| a[r][k] * b[k][c]).sum();
        }
    }
    out
}

/// Applies the row-major affine `m` (the file's frame to the dataset's, `p' = M·[p, 1]`) to
/// every vertex, normals by the inverse transpose, renormalised; records it in
/// `g.input.to_dataset` (composed after any transform applied before). Refuses a non-finite,
/// non-affine or singular `m`, and one that takes a vertex out of `f32`'s range; `g` is left
/// as it was on error.
pub fn transform(g: &mut Geometry, m: &[[f64; 4]; 4]) -> Result<(), EvalError> {
    let t = Affine::new(m).map_err(EvalError::Input)?;
    let moved = |ps: &[[f32; 3]]| -> Result<Vec<[f32; 3]>, EvalError> {
        ps.iter()
            .enumerate()
            .map(|(k, p)| {
                let q = t.point(*p).as_vec3();
                if q.is_finite() {
                    Ok(q.to_array())
                } else {
                    Err(EvalError::Input(format!("{}: the transform takes vertex {k} out of range ({q})", g.input.file)))
                }
            })
            .collect()
    };
    match &g.shape {
        Shape::Mesh(mesh) => {
            let positions = moved(&mesh.positions)?;
            if let Shape::Mesh(mesh) = &mut g.shape {
                mesh.positions = positions;
            }
        }
        Shape::Points { points, normals } => {
            let points = moved(points)?;
            let normals = normals.as_ref().map(|ns| ns.iter().map(|n| (t.normal * Vec3::from(*n).as_dvec3()).normalize_or_zero().as_vec3().to_array()).collect());
            g.shape = Shape::Points { points, normals };
        }
    }
    g.input.to_dataset = Some(match &g.input.to_dataset {
        Some(before) => mul(m, before),
        None => *m,
    });
    Ok(())
}

/// Numbers separated by white space, commas or semicolons, brackets ignored; `None` when a
/// token is not a number or there is none.
fn numbers(text: &str) -> Option<Vec<f64>> {
    let cleaned: String = text.chars().map(|c| if "[](),;".contains(c) { ' ' } else { c }).collect();
    let v: Option<Vec<f64>> = cleaned.split_whitespace().map(|t| t.parse::<f64>().ok()).collect();
    v.filter(|v| !v.is_empty())
}

fn matrix_of(v: &[f64]) -> Result<[[f64; 4]; 4], String> {
    if v.len() != 16 && v.len() != 12 {
        return Err(format!("{} numbers; a transform is 16 (a row-major 4x4) or 12 (its top three rows)", v.len()));
    }
    if let Some(x) = v.iter().find(|x| !x.is_finite()) {
        return Err(format!("the transform holds {x}, not a finite number"));
    }
    let mut m = [[0.0, 0.0, 0.0, 1.0]; 4];
    for (k, x) in v.iter().enumerate() {
        m[k / 4][k % 4] = *x;
    }
    Affine::new(&m)?;
    Ok(m)
}

/// The row-major 4x4 affine transform given as 16 numbers (or 12: the top three rows, the
/// last taken as `0 0 0 1`) separated by white space or commas (brackets allowed, so a JSON
/// array reads too), or as the path of a file holding them that way (`[[…], …]` JSON or
/// text). Refuses a non-finite, non-affine or singular one; the message does not name the
/// option, which the caller adds.
pub fn parse_matrix(text: &str) -> Result<[[f64; 4]; 4], String> {
    if let Some(v) = numbers(text) {
        return matrix_of(&v);
    }
    let path = Path::new(text.trim());
    let bytes = match read_regular_file(path, MAX_MATRIX_BYTES) {
        Ok(b) => b,
        Err(e) => return Err(format!("neither 16 numbers nor a file holding them: {e}")),
    };
    let content = String::from_utf8(bytes).map_err(|_| format!("{}: not text (not UTF-8)", path.display()))?;
    let v = numbers(&content).ok_or_else(|| format!("{}: not a list of numbers (expected 16, as `[[1, 0, 0, 0], …]` or plain text)", path.display()))?;
    matrix_of(&v).map_err(|e| format!("{}: {e}", path.display()))
}

/// The axis-aligned bounds of points, `None` without any.
fn bounds(points: &[[f32; 3]]) -> Option<(Vec3, Vec3)> {
    let first = Vec3::from(*points.first()?);
    Some(points.iter().fold((first, first), |(lo, hi), p| (lo.min(Vec3::from(*p)), hi.max(Vec3::from(*p)))))
}

/// A sentence when the geometry's box does not meet the reference's: the usual sign of a
/// geometry left in its tool's frame.
fn frame_hint(points: &[[f32; 3]], reference: &SceneReference) -> Option<String> {
    let (lo, hi) = bounds(points)?;
    let (rlo, rhi) = bounds(&reference.mesh.positions)?;
    let apart = lo.cmpgt(rhi).any() || hi.cmplt(rlo).any();
    apart.then(|| {
        format!("Its bounds {lo} to {hi} do not meet the scene's {rlo} to {rhi}: is it in the dataset's frame (a transform to the dataset's frame may be missing)?")
    })
}

/// Scores `g` (already in the dataset's frame) against `reference` with `samples` points per
/// mesh, as `mesh` and `eval` score our extracted mesh (see the module docs). The block has no
/// level, resolution or picture; its `input` records the file and the notes. Errors when no
/// triangle of a mesh is seen by the reference's cameras (the reason, with the bounds when
/// they do not meet the scene's), or as the metrics do.
pub fn score_geometry(g: &Geometry, reference: &SceneReference, samples: usize) -> Result<MeshBlock, EvalError> {
    let mut input = g.input.clone();
    let opts = metrics_options(reference, samples);
    let (metrics, fraction) = match &g.shape {
        Shape::Mesh(mesh) => {
            let (visible, fraction) = visible_part(mesh, &reference.cameras)?;
            if visible.area() <= 0.0 {
                let hint = frame_hint(&mesh.positions, reference).map_or(String::new(), |h| format!(" {h}"));
                return Err(EvalError::Input(format!(
                    "{}: none of the mesh's {} triangles is seen by the dataset's {} cameras.{hint}",
                    input.file,
                    mesh.triangles.len(),
                    reference.cameras.len()
                )));
            }
            input.notes.extend(frame_hint(&mesh.positions, reference));
            (mesh_metrics(&visible, &reference.mesh, &opts)?, fraction)
        }
        Shape::Points { points, normals } => {
            input.notes.extend(frame_hint(points, reference));
            let p: Vec<Vec3> = points.iter().map(|p| Vec3::from(*p)).collect();
            let n: Option<Vec<DVec3>> = normals.as_ref().map(|n| n.iter().map(|v| Vec3::from(*v).as_dvec3()).collect());
            input.measured_points = Some(points.len().min(samples));
            (point_metrics(&p, n.as_deref(), &reference.mesh, &opts)?, 1.0)
        }
    };
    Ok(MeshBlock {
        metrics,
        predicted_visible_area_fraction: fraction,
        reference: reference.info.clone(),
        resolution: None,
        level: None,
        mesh_file: Some(input.file.clone()),
        picture: None,
        input: Some(input),
    })
}

#[cfg(test)]
mod tests;
