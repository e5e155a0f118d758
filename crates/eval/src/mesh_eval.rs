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
    let cameras: Vec<dataset::Camera> = dataset.train.iter().chain(&dataset.test).map(|f| f.camera.clone()).collect();
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
