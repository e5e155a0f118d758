//! A run's mesh against the exact reference: the triangles of the scene the dataset was
//! rendered from ([`pathtracer::ground_truth::scene_of_dataset`]), restricted to those a train
//! or test camera sees ([`pathtracer::reference::visible_surface`], every full-resolution
//! pixel-centre ray), compared by [`crate::mesh_metrics::mesh_metrics`] with F-score
//! thresholds relative to the scene box's diagonal (the dataset's scene facts, else the
//! scene's own bounds).

use crate::mesh::TriMesh;
use crate::mesh_extract::LevelChoice;
use crate::mesh_metrics::{MeshMetrics, MeshMetricsOptions, mesh_metrics};
use crate::EvalError;
use dataset::Dataset;
use pathtracer::ground_truth::{SceneLookup, scene_of_dataset};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The reference surface of a dataset.
#[derive(Clone, Debug)]
pub struct SceneReference {
    /// The visible triangles, world space.
    pub mesh: TriMesh,
    /// Facts about it, for reports.
    pub info: ReferenceInfo,
    /// The scene box's diagonal, m.
    pub diagonal: f64,
    /// The cameras that decided visibility (train and test, full resolution).
    pub cameras: Vec<dataset::Camera>,
    /// The object ID (as in the label files) of each of `mesh`'s triangles; empty when
    /// unknown.
    pub labels: Vec<u16>,
}

/// What the reference is, as written into `eval.json` and the mesh sidecar.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReferenceInfo {
    /// The scene file.
    pub scene: String,
    /// Triangles of the scene.
    pub triangles: usize,
    /// Triangles hit by at least one camera ray.
    pub visible_triangles: usize,
    /// Visible area / total area.
    pub visible_area_fraction: f64,
    /// Area of the visible triangles, m².
    pub visible_area: f64,
    /// Cameras whose rays decided visibility (train + test).
    pub cameras: usize,
    /// Pixel-centre rays cast.
    pub rays: u64,
}

/// The reference surface of `dataset` (train and test cameras, full resolution), or why there
/// is none (`Ok(Err(why))`: not rendered by this path tracer, scene file missing or edited).
/// `scene` overrides the recorded scene file (it must have the recorded content); `import`
/// says how the scene is read (e.g. external files admitted outside its folder).
pub fn scene_reference(
    dataset: &Dataset,
    scene: Option<&Path>,
    import: &pathtracer::import::ImportOptions,
) -> Result<Result<SceneReference, String>, EvalError> {
    let (renderer, path) = match scene_of_dataset(&dataset.root, scene, import).map_err(|e| EvalError::Input(e.to_string()))? {
        SceneLookup::Found { renderer, path } => (renderer, path),
        SceneLookup::Missing(why) => return Ok(Err(why)),
    };
    let cameras: Vec<dataset::Camera> = dataset.train.iter().chain(&dataset.test).map(|f| f.camera).collect();
    let r = pathtracer::reference::visible_surface(&renderer, &cameras);
    let mesh = TriMesh::new(r.positions.iter().map(|p| p.to_array()).collect(), r.visible_mesh());
    // The visible mesh keeps the scene's triangle order: its k-th triangle is the k-th visible one.
    let labels = (0..r.triangles.len())
        .filter(|&t| r.visible[t])
        .map(|t| renderer.scene().object_of(t as u32).map_or(0, |o| (o + 1).min(dataset::labels::MAX_LABEL) as u16))
        .collect();
    let diagonal = match &dataset.facts {
        Some(f) => (0..3).map(|k| (f.aabb_max[k] - f.aabb_min[k]).powi(2)).sum::<f64>().sqrt(),
        None => renderer.scene().bounds.diagonal() as f64,
    };
    let info = ReferenceInfo {
        scene: path.display().to_string(),
        triangles: r.triangles.len(),
        visible_triangles: r.visible_triangles(),
        visible_area_fraction: r.visible_area_fraction,
        visible_area: mesh.area(),
        cameras: cameras.len(),
        rays: r.rays,
    };
    Ok(Ok(SceneReference { mesh, info, diagonal, cameras, labels }))
}

/// The `mesh` block of `eval.json` (and of the mesh sidecar): the metrics of the extracted
/// mesh, or of another tool's geometry, against the visible reference surface, and how both
/// were obtained.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeshBlock {
    /// The metrics (of the part of the mesh the cameras see).
    pub metrics: MeshMetrics,
    /// The share of the mesh's area that the train and test cameras see (the part measured;
    /// 1 for a point cloud, every point of which is measured).
    pub predicted_visible_area_fraction: f64,
    /// The reference.
    pub reference: ReferenceInfo,
    /// Grid cells along the longest side of the scene box (absent for another tool's geometry).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resolution: Option<usize>,
    /// The density level and why (absent for another tool's geometry).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub level: Option<LevelChoice>,
    /// The mesh file, relative to the run folder when inside it.
    pub mesh_file: Option<String>,
    /// The error picture, relative to the run folder.
    pub picture: Option<String>,
    /// The geometry file read, when it is another tool's rather than extracted from our field.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub input: Option<GeometryInput>,
}

/// Whether another tool's geometry is a surface or points.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum GeometryKind {
    /// Triangles (polygons fan-triangulated).
    #[serde(rename = "mesh")]
    Mesh,
    /// Points without faces, optionally with normals.
    #[serde(rename = "point cloud")]
    PointCloud,
}

/// Another tool's geometry file as read and brought to the dataset's frame
/// ([`crate::geometry`]), recorded in the `mesh` block.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GeometryInput {
    /// The file, as given.
    pub file: String,
    /// `"PLY ascii"`, `"PLY binary_little_endian"`, `"PLY binary_big_endian"` or `"OBJ"`.
    pub format: String,
    /// Mesh or point cloud.
    pub kind: GeometryKind,
    /// Vertices (points) kept.
    pub vertices: usize,
    /// Triangles kept, after fan triangulation of polygons (0 for a point cloud).
    pub triangles: usize,
    /// Polygons of more than three corners that were fan-triangulated.
    pub polygons: usize,
    /// Vertices dropped for a non-finite coordinate (with the triangles using them).
    pub dropped_vertices: usize,
    /// Triangles dropped because a corner was dropped.
    pub dropped_triangles: usize,
    /// Whether the points carry normals that the metrics use (point clouds only).
    pub normals: bool,
    /// The row-major 4x4 affine transform applied to bring the file's coordinates into the
    /// dataset's frame (absent: used as read).
    pub to_dataset: Option<[[f64; 4]; 4]>,
    /// Points of a point cloud whose distances to the reference were averaged (all of them,
    /// or a seeded draw of as many as the samples per mesh).
    pub measured_points: Option<usize>,
    /// What was dropped or is absent, and why, one sentence each.
    pub notes: Vec<String>,
}

impl GeometryInput {
    /// One phrase for reports: what was read and how it was brought to the dataset's frame.
    pub fn describe(&self) -> String {
        let body = match self.kind {
            GeometryKind::Mesh => format!("{} vertices, {} triangles", self.vertices, self.triangles),
            GeometryKind::PointCloud => format!("{} points{}", self.vertices, if self.normals { " with normals" } else { ", no normals" }),
        };
        let frame = if self.to_dataset.is_some() { "brought to the dataset's frame by the given transform" } else { "in the dataset's frame as read" };
        let kind = match self.kind {
            GeometryKind::Mesh => "mesh",
            GeometryKind::PointCloud => "point cloud",
        };
        format!("The {kind} `{}` ({}, {body}, {frame})", self.file, self.format)
    }
}

/// The options [`compare_with_reference`] measures with: `samples` points per mesh, seed 0,
/// F-score thresholds relative to the reference's diagonal.
pub fn metrics_options(reference: &SceneReference, samples: usize) -> MeshMetricsOptions {
    MeshMetricsOptions { samples, ..MeshMetricsOptions::for_diagonal(reference.diagonal) }
}

/// The metrics of the part of `mesh` the reference's cameras see ([`visible_part`]) against
/// `reference`, with `samples` points per mesh (seed 0), and that part's share of the mesh's
/// area.
pub fn compare_with_reference(mesh: &TriMesh, reference: &SceneReference, samples: usize) -> Result<(MeshMetrics, f64), EvalError> {
    let (visible, fraction) = visible_part(mesh, &reference.cameras)?;
    Ok((mesh_metrics(&visible, &reference.mesh, &metrics_options(reference, samples))?, fraction))
}

/// `mesh` as a path-tracer scene (one double-sided default material, world = local) behind a
/// BVH, for ray casting.
fn mesh_renderer(mesh: &TriMesh) -> Result<pathtracer::render::Renderer, EvalError> {
    use glam::Vec3;
    use pathtracer::accel::AccelParams;
    use pathtracer::scene::{Aabb, Material, Mesh, Scene};
    let n = mesh.positions.len();
    let positions: Vec<Vec3> = mesh.positions.iter().map(|p| Vec3::from(*p)).collect();
    let mut material = Material::gltf_default();
    material.double_sided = true;
    let scene = Scene {
        name: "mesh".into(),
        origin: glam::DVec3::ZERO,
        mesh: Mesh {
            positions: positions.clone(),
            normals: mesh.vertex_normals().into_iter().map(Vec3::from).collect(),
            tangents: vec![glam::Vec4::ZERO; n],
            uv0: vec![glam::Vec2::ZERO; n],
            uv1: vec![glam::Vec2::ZERO; n],
            colors: vec![glam::Vec4::ONE; n],
            indices: mesh.triangles.clone(),
            material: vec![0; mesh.triangles.len()],
        },
        materials: vec![material],
        textures: Vec::new(),
        lights: Vec::new(),
        cameras: Vec::new(),
        bounds: positions.iter().fold(Aabb::EMPTY, |b, &p| b.union_point(p)),
        warnings: Vec::new(),
        objects: vec![],
    };
    pathtracer::render::Renderer::new(scene, &AccelParams::fast_build()).map_err(|e| EvalError::Input(format!("mesh: {e}")))
}

/// The part of `mesh` that `cameras` see: the triangles hit first by at least one pixel-centre
/// ray (either side counts), the same rule as the reference's. Surfaces the field hides behind
/// its own visible surface (the underside of the dense slab a floor becomes, the inside of a
/// solid) never show in a render and are left out, as the scene's hidden triangles are; floaters
/// in front of the surface are seen and stay. Returns the visible mesh and its share of the area.
pub fn visible_part(mesh: &TriMesh, cameras: &[dataset::Camera]) -> Result<(TriMesh, f64), EvalError> {
    let renderer = mesh_renderer(mesh)?;
    let r = pathtracer::reference::visible_surface(&renderer, cameras);
    let visible = TriMesh { positions: mesh.positions.clone(), triangles: r.visible_mesh(), colors: mesh.colors.clone() };
    Ok((visible, r.visible_area_fraction))
}

/// A picture of `mesh` seen by `camera`, each pixel coloured by the exact distance of the mesh
/// point it sees to the reference surface (`index`), on the viridis scale from 0 to
/// `max_error` (clamped), shaded by the angle between the view ray and the surface so that the
/// shape reads; pixels that see no mesh are dark grey. Returns 8-bit RGB, row 0 on top.
///
/// # Shapes
/// Returns `[height * width * 3]`.
pub fn error_picture(mesh: &TriMesh, index: &crate::mesh_metrics::SurfaceIndex, camera: &dataset::Camera, max_error: f64) -> Result<Vec<u8>, EvalError> {
    use glam::Vec3;
    let renderer = mesh_renderer(mesh)?;
    let accel = renderer.accel();
    let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
    let mut hits = Vec::with_capacity((w * h) as usize);
    for j in 0..h {
        for i in 0..w {
            let r = camera.pixel_center_ray(i, j);
            let d = r.direction.normalize().as_vec3();
            let ray = pathtracer::geometry::Ray::new(r.origin.as_vec3(), d);
            hits.push(accel.closest_hit(&ray, f32::INFINITY, |_, _| true).map(|hit| {
                let p = ray.at(hit.t);
                let shade = mesh.triangle_normal(hit.prim as usize).as_vec3().dot(d).abs();
                (p, shade)
            }));
        }
    }
    let points: Vec<Vec3> = hits.iter().flatten().map(|(p, _)| *p).collect();
    let dist = index.distances(&points);
    let mut k = 0;
    let mut rgb = Vec::with_capacity(hits.len() * 3);
    for hit in &hits {
        match hit {
            Some((_, shade)) => {
                let c = crate::colormap::Colormap::Viridis.map(dist[k], 0.0, max_error);
                let s = 0.35 + 0.65 * shade;
                rgb.extend(c.map(|v| (v as f32 * s).round() as u8));
                k += 1;
            }
            None => rgb.extend([40, 40, 40]),
        }
    }
    Ok(rgb)
}

/// `camera` enlarged by a whole factor to at least 400 pixels wide (the same view, finer
/// pixels), so that the error picture of a low-resolution run still shows the mesh.
pub fn picture_camera(camera: &dataset::Camera) -> dataset::Camera {
    let k = 400u32.div_ceil(camera.intrinsics.width.max(1)).max(1);
    let mut c = *camera;
    let i = &mut c.intrinsics;
    i.width *= k;
    i.height *= k;
    i.fl_x *= k as f64;
    i.fl_y *= k as f64;
    i.cx *= k as f64;
    i.cy *= k as f64;
    c
}

/// The mesh part of an evaluation.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshEvalOptions {
    /// Grid cells along the longest side of the scene box.
    pub resolution: usize,
    /// Points sampled on each mesh.
    pub samples: usize,
}

impl MeshEvalOptions {
    /// 256 cells, 100 000 points per mesh.
    pub fn standard() -> Self {
        Self { resolution: 256, samples: 100_000 }
    }
}

/// Extracts the run's mesh (level from the data, vertex colours), writes it to
/// `run_dir/mesh.ply` and its error picture seen from `camera` to `run_dir/mesh_error.png`
/// (error scale 0 to 2 % of the diagonal), and measures it against `reference`.
pub fn evaluate_run_mesh(
    run_dir: &Path,
    model: &nerf::render::RunModel,
    dataset: &Dataset,
    reference: SceneReference,
    camera: &dataset::Camera,
    opts: &MeshEvalOptions,
    progress: crate::mesh_extract::Progress<'_>,
) -> Result<(MeshBlock, Vec<crate::mesh_metrics::LabelDistance>), EvalError> {
    use crate::mesh_extract::{ExtractOptions, extract_mesh, spread_cameras};
    let extract = ExtractOptions::at_resolution(opts.resolution);
    let cameras = spread_cameras(&dataset.train, extract.level_views);
    let m = extract_mesh(model, &cameras, &extract, progress)?;
    m.mesh.write_ply(&run_dir.join("mesh.ply"))?;
    let (visible, predicted_visible_area_fraction) = visible_part(&m.mesh, &reference.cameras)?;
    let options = metrics_options(&reference, opts.samples);
    let metrics = mesh_metrics(&visible, &reference.mesh, &options)?;
    let per_object = if reference.labels.len() == reference.mesh.triangles.len() {
        crate::mesh_metrics::label_distances(&visible, &reference.mesh, &reference.labels, &options)?
    } else {
        Vec::new()
    };
    let index = crate::mesh_metrics::SurfaceIndex::new(&reference.mesh)?;
    let camera = picture_camera(camera);
    let rgb = error_picture(&m.mesh, &index, &camera, 0.02 * reference.diagonal)?;
    crate::io::write_png_atomic(&run_dir.join("mesh_error.png"), camera.intrinsics.width, camera.intrinsics.height, rgb)?;
    let block = MeshBlock {
        metrics,
        predicted_visible_area_fraction,
        reference: reference.info,
        resolution: Some(opts.resolution),
        level: Some(m.level),
        mesh_file: Some("mesh.ply".into()),
        picture: Some("mesh_error.png".into()),
        input: None,
    };
    Ok((block, per_object))
}

#[cfg(test)]
mod tests {
    use super::*;
    use dataset::{Camera, Intrinsics};
    use glam::DVec3;

    #[test]
    fn visible_part_keeps_what_a_camera_sees() {
        // The unit cube seen straight on from +z: only the front face's two triangles.
        let p: Vec<[f32; 3]> = (0..8).map(|c| [(c & 1) as f32, ((c >> 1) & 1) as f32, ((c >> 2) & 1) as f32]).collect();
        let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
        let t = quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
        let cube = TriMesh::new(p, t);
        let eye = DVec3::new(0.5, 0.5, 6.0);
        let camera = Camera::new(Intrinsics::from_fov_y(64, 64, 30f64.to_radians()), Camera::look_at(eye, DVec3::new(0.5, 0.5, 0.5), DVec3::Y)).unwrap();
        let (visible, fraction) = visible_part(&cube, &[camera]).unwrap();
        assert_eq!(visible.triangles, vec![[4, 5, 7], [4, 7, 6]]);
        assert!((fraction - 1.0 / 6.0).abs() < 1e-12);
        // The error picture: the front face at distance 0 from itself, the rest background.
        let index = crate::mesh_metrics::SurfaceIndex::new(&cube).unwrap();
        let rgb = error_picture(&cube, &index, &camera, 0.1).unwrap();
        assert_eq!(rgb.len(), 64 * 64 * 3);
        assert_eq!(&rgb[..3], &[40, 40, 40]);
        let centre = (32 * 64 + 32) * 3;
        let zero = crate::colormap::Colormap::Viridis.at(0.0);
        assert_eq!(&rgb[centre..centre + 3], &zero);
    }
}
