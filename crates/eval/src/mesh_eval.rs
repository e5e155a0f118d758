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
/// `scene` overrides the recorded scene file (it must have the recorded content).
pub fn scene_reference(dataset: &Dataset, scene: Option<&Path>) -> Result<Result<SceneReference, String>, EvalError> {
    let (renderer, path) = match scene_of_dataset(&dataset.root, scene).map_err(|e| EvalError::Input(e.to_string()))? {
        SceneLookup::Found { renderer, path } => (renderer, path),
        SceneLookup::Missing(why) => return Ok(Err(why)),
    };
    let cameras: Vec<dataset::Camera> = dataset.train.iter().chain(&dataset.test).map(|f| f.camera).collect();
    let r = pathtracer::reference::visible_surface(&renderer, &cameras);
    let mesh = TriMesh::new(r.positions.iter().map(|p| p.to_array()).collect(), r.visible_mesh());
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
    Ok(Ok(SceneReference { mesh, info, diagonal }))
}

/// The `mesh` block of `eval.json` (and of the mesh sidecar): the metrics of the extracted
/// mesh against the visible reference surface, and how both were obtained.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeshBlock {
    /// The metrics.
    pub metrics: MeshMetrics,
    /// The reference.
    pub reference: ReferenceInfo,
    /// Grid cells along the longest side of the scene box.
    pub resolution: usize,
    /// The density level and why.
    pub level: LevelChoice,
    /// The mesh file, relative to the run folder when inside it.
    pub mesh_file: Option<String>,
    /// The error picture, relative to the run folder.
    pub picture: Option<String>,
}

/// The metrics of `mesh` against `reference` with `samples` points per mesh (seed 0).
pub fn compare_with_reference(mesh: &TriMesh, reference: &SceneReference, samples: usize) -> Result<MeshMetrics, EvalError> {
    let opts = MeshMetricsOptions { samples, ..MeshMetricsOptions::for_diagonal(reference.diagonal) };
    mesh_metrics(mesh, &reference.mesh, &opts)
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
    use pathtracer::accel::{Accel, AccelParams};
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
    };
    let accel = Accel::build(&scene, &AccelParams::fast_build()).map_err(|e| EvalError::Input(format!("mesh picture: {e}")))?;
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
) -> Result<MeshBlock, EvalError> {
    use crate::mesh_extract::{ExtractOptions, extract_mesh, spread_cameras};
    let extract = ExtractOptions::at_resolution(opts.resolution);
    let cameras = spread_cameras(&dataset.train, extract.level_views);
    let m = extract_mesh(model, &cameras, &extract, progress)?;
    m.mesh.write_ply(&run_dir.join("mesh.ply"))?;
    let metrics = compare_with_reference(&m.mesh, &reference, opts.samples)?;
    let index = crate::mesh_metrics::SurfaceIndex::new(&reference.mesh)?;
    let camera = picture_camera(camera);
    let rgb = error_picture(&m.mesh, &index, &camera, 0.02 * reference.diagonal)?;
    crate::io::write_png_atomic(&run_dir.join("mesh_error.png"), camera.intrinsics.width, camera.intrinsics.height, rgb)?;
    Ok(MeshBlock {
        metrics,
        reference: reference.info,
        resolution: opts.resolution,
        level: m.level,
        mesh_file: Some("mesh.ply".into()),
        picture: Some("mesh_error.png".into()),
    })
}
