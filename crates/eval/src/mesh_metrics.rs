//! Geometry metrics between a predicted mesh and a reference mesh, the way reconstruction
//! papers compare a mesh with a reference scan, but against exact triangles:
//!
//! - both surfaces are sampled area-uniformly with the same number of points (seeded,
//!   counter-based: sample `k` depends only on the seed and `k`);
//! - each sample's distance to the *other* mesh is exact (closest point on the closest
//!   triangle through a BVH, [`pathtracer::nearest::NearestTriangles`]);
//! - **accuracy** = mean distance of the predicted samples to the reference (how far the
//!   prediction strays: floaters, offsets); **completeness** = mean distance of the reference
//!   samples to the prediction (what the prediction misses: holes, lost thin parts);
//!   **Chamfer-L1** = their mean;
//! - **F-score** at threshold τ (fractions of the scene box's diagonal): precision = share of
//!   predicted samples within τ of the reference, recall = share of reference samples within
//!   τ of the prediction, F = 2PR / (P + R);
//! - **normal consistency** = mean over both sample sets of |n · n'|, the sample's face normal
//!   against the normal of the closest triangle on the other mesh (unsigned, so single-sided
//!   reference triangles of either winding count alike).
//!
//! A point cloud ([`point_metrics`]) stands in for the predicted mesh's samples with its
//! points; completeness then looks for the nearest point, and normal consistency needs normals.
//!
//! ```
//! use eval::mesh::TriMesh;
//! use eval::mesh_metrics::{MeshMetricsOptions, mesh_metrics};
//! // Two unit squares 0.012 apart.
//! let square = |z: f32| TriMesh::new(vec![[0.0, 0.0, z], [1.0, 0.0, z], [1.0, 1.0, z], [0.0, 1.0, z]], vec![[0, 1, 2], [0, 2, 3]]);
//! let m = mesh_metrics(&square(0.012), &square(0.0), &MeshMetricsOptions::for_diagonal(1.0)).unwrap();
//! assert!((m.chamfer_l1 - 0.012).abs() < 1e-6);
//! assert_eq!(m.f_scores[1].f_score, 0.0); // τ = 1 % of the diagonal = 0.01
//! assert_eq!(m.f_scores[2].f_score, 1.0); // τ = 0.02
//! ```

use crate::mesh::TriMesh;
use crate::{EvalError, MetricError};
use glam::{DVec3, Vec3};
use pathtracer::nearest::NearestTriangles;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The F-score thresholds, as fractions of the scene box's diagonal.
pub const F_SCORE_FRACTIONS: [f64; 3] = [0.005, 0.01, 0.02];

/// How the metrics are taken.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshMetricsOptions {
    /// Points sampled on each mesh.
    pub samples: usize,
    /// Seed of the point samples.
    pub seed: u64,
    /// The scene box's diagonal, the unit of the F-score thresholds.
    pub diagonal: f64,
    /// F-score thresholds as fractions of `diagonal`.
    pub fractions: Vec<f64>,
}

impl MeshMetricsOptions {
    /// 100 000 points per mesh, seed 0, thresholds [`F_SCORE_FRACTIONS`] of `diagonal`.
    pub fn for_diagonal(diagonal: f64) -> Self {
        Self { samples: 100_000, seed: 0, diagonal, fractions: F_SCORE_FRACTIONS.to_vec() }
    }
}

/// Precision, recall and F-score at one threshold.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FScore {
    /// The threshold as a fraction of the scene box's diagonal.
    pub fraction: f64,
    /// The threshold in scene units (metres).
    pub threshold: f64,
    /// Share of predicted samples within the threshold of the reference.
    pub precision: f64,
    /// Share of reference samples within the threshold of the prediction.
    pub recall: f64,
    /// Harmonic mean of precision and recall (0 when both are 0).
    pub f_score: f64,
}

/// The metrics of a predicted mesh against a reference (distances in scene units).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeshMetrics {
    /// Mean distance from predicted samples to the reference.
    pub accuracy: f64,
    /// Mean distance from reference samples to the prediction.
    pub completeness: f64,
    /// (accuracy + completeness) / 2.
    pub chamfer_l1: f64,
    /// Median distance from predicted samples to the reference.
    pub accuracy_median: f64,
    /// Median distance from reference samples to the prediction.
    pub completeness_median: f64,
    /// One entry per threshold.
    pub f_scores: Vec<FScore>,
    /// Mean |n · n'| over both sample sets (absent for a point cloud without normals).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub normal_consistency: Option<f64>,
    /// Points sampled on each mesh.
    pub samples: usize,
    /// Seed of the samples.
    pub seed: u64,
    /// The diagonal the thresholds are fractions of.
    pub diagonal: f64,
    /// Area of the predicted mesh, m² (0 for a point cloud).
    pub predicted_area: f64,
    /// Area of the reference mesh, m².
    pub reference_area: f64,
    /// Triangles of the predicted mesh (0 for a point cloud).
    pub predicted_triangles: usize,
    /// Triangles of the reference mesh.
    pub reference_triangles: usize,
}

/// Area-uniform points on a mesh, with the unit normal and index of the triangle each lies on.
#[derive(Clone, Debug, Default)]
pub struct SurfaceSamples {
    /// The points.
    pub points: Vec<Vec3>,
    /// Face normal at each point.
    pub normals: Vec<DVec3>,
    /// Triangle of each point.
    pub triangles: Vec<u32>,
}

/// splitmix64 of (seed, k, dim): the counter-based random number behind sample `k`.
fn uniform(seed: u64, k: u64, dim: u64) -> f64 {
    let mut z = seed ^ k.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ dim.wrapping_mul(0xd1b5_4a32_d192_ed03);
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
}

/// `n` points uniform over the area of `mesh`: sample `k` picks a triangle with probability
/// proportional to its area and a uniform point in it (`√u` barycentric warp), from random
/// numbers keyed by (`seed`, `k`). Errors when the mesh has no area.
pub fn sample_surface(mesh: &TriMesh, n: usize, seed: u64) -> Result<SurfaceSamples, MetricError> {
    let mut cumulative = Vec::with_capacity(mesh.triangles.len());
    let mut total = 0.0;
    for k in 0..mesh.triangles.len() {
        total += mesh.triangle_area(k);
        cumulative.push(total);
    }
    if !(total > 0.0 && total.is_finite()) {
        return Err(MetricError::Empty("mesh (no area to sample)"));
    }
    let picks: Vec<(Vec3, DVec3, u32)> = (0..n as u64)
        .into_par_iter()
        .map(|k| {
            let u = uniform(seed, k, 0) * total;
            let t = cumulative.partition_point(|c| *c <= u).min(cumulative.len() - 1);
            // Skip zero-area triangles the search could land on at their boundary.
            let t = (t..cumulative.len()).find(|&i| mesh.triangle_area(i) > 0.0).unwrap_or(t);
            let [a, b, c] = mesh.corners(t);
            let s = uniform(seed, k, 1).sqrt();
            let v = uniform(seed, k, 2);
            let p = a * (1.0 - s) + b * (s * (1.0 - v)) + c * (s * v);
            (p.as_vec3(), mesh.triangle_normal(t), t as u32)
        })
        .collect();
    let mut out = SurfaceSamples::default();
    for (p, nrm, t) in picks {
        out.points.push(p);
        out.normals.push(nrm);
        out.triangles.push(t);
    }
    Ok(out)
}

/// A mesh ready for exact distance queries.
#[derive(Debug)]
pub struct SurfaceIndex {
    set: NearestTriangles,
    normals: Vec<DVec3>,
}

impl SurfaceIndex {
    /// Builds the BVH of `mesh`.
    pub fn new(mesh: &TriMesh) -> Result<Self, EvalError> {
        let positions: Vec<Vec3> = mesh.positions.iter().map(|p| Vec3::from(*p)).collect();
        let set = NearestTriangles::build(&positions, &mesh.triangles).map_err(|e| EvalError::Input(format!("mesh: {e}")))?;
        Ok(Self { set, normals: (0..mesh.triangles.len()).map(|k| mesh.triangle_normal(k)).collect() })
    }

    /// Builds the BVH of a point set (each point a degenerate triangle, so that a query finds
    /// the exact nearest point), with a unit normal per point or none (zero normals: every
    /// |n · n'| is then 0).
    ///
    /// # Shapes
    /// `normals`, when given: one per point.
    pub fn from_points(points: &[Vec3], normals: Option<&[DVec3]>) -> Result<Self, EvalError> {
        let n = u32::try_from(points.len()).map_err(|_| EvalError::Input(format!("{} points are more than a point index holds", points.len())))?;
        if normals.is_some_and(|v| v.len() != points.len()) {
            return Err(EvalError::Input(format!("{} normals for {n} points", normals.map_or(0, |v| v.len()))));
        }
        let singles: Vec<[u32; 3]> = (0..n).map(|i| [i, i, i]).collect();
        let set = NearestTriangles::build(points, &singles).map_err(|e| EvalError::Input(format!("points: {e}")))?;
        Ok(Self { set, normals: normals.map_or_else(|| vec![DVec3::ZERO; points.len()], <[DVec3]>::to_vec) })
    }

    /// Distance of each point to the mesh and |n · n'| against the closest triangle's normal
    /// (`normals[k]` belongs to `points[k]`; infinite distance and 0 on an empty mesh).
    pub fn query(&self, points: &[Vec3], normals: &[DVec3]) -> Vec<(f64, f64)> {
        points
            .par_iter()
            .zip(normals.par_iter())
            .map(|(p, n)| match self.set.closest(*p) {
                Some(c) => {
                    let dist = (c.point.as_dvec3() - p.as_dvec3()).length();
                    (dist, n.dot(self.normals[c.triangle as usize]).abs())
                }
                None => (f64::INFINITY, 0.0),
            })
            .collect()
    }

    /// Distance of each point to the mesh and the closest triangle (`u32::MAX` on an empty
    /// mesh).
    pub fn closest(&self, points: &[Vec3]) -> Vec<(f64, u32)> {
        points
            .par_iter()
            .map(|p| self.set.closest(*p).map_or((f64::INFINITY, u32::MAX), |c| ((c.point.as_dvec3() - p.as_dvec3()).length(), c.triangle)))
            .collect()
    }

    /// Distance of each point to the mesh.
    pub fn distances(&self, points: &[Vec3]) -> Vec<f64> {
        points.par_iter().map(|p| self.set.closest(*p).map_or(f64::INFINITY, |c| (c.point.as_dvec3() - p.as_dvec3()).length())).collect()
    }
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

/// Accuracy, completeness, Chamfer-L1, F-scores and normal consistency of `predicted` against
/// `reference` (see the module docs). Errors when either mesh is invalid or has no area, or the
/// options ask for no samples or a non-positive diagonal.
pub fn mesh_metrics(predicted: &TriMesh, reference: &TriMesh, opts: &MeshMetricsOptions) -> Result<MeshMetrics, EvalError> {
    check_options(opts)?;
    predicted.validate()?;
    reference.validate()?;
    let ps = sample_surface(predicted, opts.samples, opts.seed).map_err(metric("predicted mesh"))?;
    let rs = sample_surface(reference, opts.samples, opts.seed ^ REFERENCE_SEED).map_err(metric("reference mesh"))?;
    let to_ref = SurfaceIndex::new(reference)?.query(&ps.points, &ps.normals);
    let to_pred = SurfaceIndex::new(predicted)?.query(&rs.points, &rs.normals);
    let sides = Sides { to_ref, to_pred, normals: true, predicted_area: predicted.area(), predicted_triangles: predicted.triangles.len() };
    Ok(sides.metrics(reference, opts))
}

/// The metrics of a point cloud against `reference`, the way [`mesh_metrics`] takes them with
/// the points in place of the predicted mesh's samples: accuracy over the points (all of them,
/// or `opts.samples` of them drawn without replacement, seeded, when there are more),
/// completeness from the reference's samples to the nearest point, F-scores alike; normal
/// consistency only when `normals` are given (the point's normal against the closest
/// reference triangle's, the reference sample's against the nearest point's). Area and
/// triangles of the prediction are 0. Errors on no points or a non-finite one.
///
/// # Shapes
/// `normals`, when given: one unit vector per point.
pub fn point_metrics(points: &[Vec3], normals: Option<&[DVec3]>, reference: &TriMesh, opts: &MeshMetricsOptions) -> Result<MeshMetrics, EvalError> {
    check_options(opts)?;
    reference.validate()?;
    if points.is_empty() {
        return Err(EvalError::Input("the point cloud has no points".into()));
    }
    if let Some(k) = points.iter().position(|p| !p.is_finite()) {
        return Err(EvalError::Input(format!("point {k} is not finite")));
    }
    let index = SurfaceIndex::from_points(points, normals)?;
    let picked = pick(points.len(), opts.samples, opts.seed);
    let ps: Vec<Vec3> = picked.iter().map(|&k| points[k]).collect();
    let pn: Vec<DVec3> = match normals {
        Some(n) => picked.iter().map(|&k| n[k]).collect(),
        None => vec![DVec3::ZERO; ps.len()],
    };
    let rs = sample_surface(reference, opts.samples, opts.seed ^ REFERENCE_SEED).map_err(metric("reference mesh"))?;
    let to_ref = SurfaceIndex::new(reference)?.query(&ps, &pn);
    let to_pred = index.query(&rs.points, &rs.normals);
    let sides = Sides { to_ref, to_pred, normals: normals.is_some(), predicted_area: 0.0, predicted_triangles: 0 };
    Ok(sides.metrics(reference, opts))
}

/// Accuracy and completeness restricted to one label of the reference's triangles (an object).
#[derive(Clone, Debug, PartialEq)]
pub struct LabelDistance {
    /// The label.
    pub label: u16,
    /// Mean distance to the reference of the predicted samples whose closest reference
    /// triangle carries the label (`None` when none does).
    pub accuracy: Option<f64>,
    /// Mean distance to the prediction of the reference samples on the label's triangles.
    pub completeness: Option<f64>,
}

/// [`mesh_metrics`]' accuracy and completeness split by `labels` (one per reference triangle):
/// a predicted sample counts for the label of its closest reference triangle, a reference
/// sample for the label of the triangle it lies on. The same samples as [`mesh_metrics`]
/// (the same seeds), ascending by label.
pub fn label_distances(predicted: &TriMesh, reference: &TriMesh, labels: &[u16], opts: &MeshMetricsOptions) -> Result<Vec<LabelDistance>, EvalError> {
    check_options(opts)?;
    predicted.validate()?;
    reference.validate()?;
    if labels.len() != reference.triangles.len() {
        return Err(EvalError::Input(format!("{} labels for {} reference triangles", labels.len(), reference.triangles.len())));
    }
    let ps = sample_surface(predicted, opts.samples, opts.seed).map_err(metric("predicted mesh"))?;
    let rs = sample_surface(reference, opts.samples, opts.seed ^ REFERENCE_SEED).map_err(metric("reference mesh"))?;
    let to_ref = SurfaceIndex::new(reference)?.closest(&ps.points);
    let to_pred = SurfaceIndex::new(predicted)?.distances(&rs.points);
    let mut sums: std::collections::BTreeMap<u16, [f64; 4]> = std::collections::BTreeMap::new();
    for (d, t) in to_ref {
        if let Some(&l) = labels.get(t as usize) {
            let s = sums.entry(l).or_default();
            s[0] += d;
            s[1] += 1.0;
        }
    }
    for (d, t) in to_pred.into_iter().zip(&rs.triangles) {
        let s = sums.entry(labels[*t as usize]).or_default();
        s[2] += d;
        s[3] += 1.0;
    }
    Ok(sums
        .into_iter()
        .map(|(label, s)| LabelDistance { label, accuracy: (s[1] > 0.0).then(|| s[0] / s[1]), completeness: (s[3] > 0.0).then(|| s[2] / s[3]) })
        .collect())
}

/// The reference's samples are drawn with the seed xor this, apart from the prediction's.
const REFERENCE_SEED: u64 = 0x05ee_d0f2_ef00;

fn metric(what: &'static str) -> impl Fn(MetricError) -> EvalError {
    move |e| EvalError::Metric { view: what.into(), source: e }
}

fn check_options(opts: &MeshMetricsOptions) -> Result<(), EvalError> {
    if opts.samples == 0 {
        return Err(EvalError::Input("mesh metrics need at least one sample per mesh".into()));
    }
    if !(opts.diagonal > 0.0 && opts.diagonal.is_finite()) {
        return Err(EvalError::Input(format!("mesh metrics need a positive scene diagonal, got {}", opts.diagonal)));
    }
    Ok(())
}

/// `0..n` when `n <= m`, else `m` distinct indices of `0..n` drawn uniformly (Floyd's
/// algorithm on the counter-based random numbers of `seed`), ascending.
fn pick(n: usize, m: usize, seed: u64) -> Vec<usize> {
    if n <= m {
        return (0..n).collect();
    }
    let mut chosen = std::collections::HashSet::with_capacity(m);
    for j in n - m..n {
        let t = ((uniform(seed, j as u64, 3) * (j + 1) as f64) as usize).min(j);
        if !chosen.insert(t) {
            chosen.insert(j);
        }
    }
    let mut out: Vec<usize> = chosen.into_iter().collect();
    out.sort_unstable();
    out
}

/// Distances (and |n · n'|) of the prediction's samples to the reference and of the
/// reference's samples to the prediction.
struct Sides {
    to_ref: Vec<(f64, f64)>,
    to_pred: Vec<(f64, f64)>,
    normals: bool,
    predicted_area: f64,
    predicted_triangles: usize,
}

impl Sides {
    fn metrics(self, reference: &TriMesh, opts: &MeshMetricsOptions) -> MeshMetrics {
        let Sides { to_ref, to_pred, normals, predicted_area, predicted_triangles } = self;
        let mean = |v: &[(f64, f64)], f: fn(&(f64, f64)) -> f64| v.iter().map(f).sum::<f64>() / v.len() as f64;
        let accuracy = mean(&to_ref, |x| x.0);
        let completeness = mean(&to_pred, |x| x.0);
        let within = |v: &[(f64, f64)], tau: f64| v.iter().filter(|x| x.0 < tau).count() as f64 / v.len() as f64;
        let f_scores = opts
            .fractions
            .iter()
            .map(|&fraction| {
                let threshold = fraction * opts.diagonal;
                let (precision, recall) = (within(&to_ref, threshold), within(&to_pred, threshold));
                let f_score = if precision + recall > 0.0 { 2.0 * precision * recall / (precision + recall) } else { 0.0 };
                FScore { fraction, threshold, precision, recall, f_score }
            })
            .collect();
        MeshMetrics {
            accuracy,
            completeness,
            chamfer_l1: 0.5 * (accuracy + completeness),
            accuracy_median: median(&to_ref.iter().map(|x| x.0).collect::<Vec<_>>()),
            completeness_median: median(&to_pred.iter().map(|x| x.0).collect::<Vec<_>>()),
            f_scores,
            normal_consistency: normals.then(|| 0.5 * (mean(&to_ref, |x| x.1) + mean(&to_pred, |x| x.1))),
            samples: opts.samples,
            seed: opts.seed,
            diagonal: opts.diagonal,
            predicted_area,
            reference_area: reference.area(),
            predicted_triangles,
            reference_triangles: reference.triangles.len(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// A UV sphere of radius `r` with `n` rings and `2n` segments.
    fn uv_sphere(r: f64, n: usize) -> TriMesh {
        let mut p = vec![[0.0, r as f32, 0.0]];
        for i in 1..n {
            let th = PI * i as f64 / n as f64;
            for j in 0..2 * n {
                let ph = PI * j as f64 / n as f64;
                p.push([(r * th.sin() * ph.cos()) as f32, (r * th.cos()) as f32, (r * th.sin() * ph.sin()) as f32]);
            }
        }
        p.push([0.0, -r as f32, 0.0]);
        let m = 2 * n as u32;
        let ring = |i: u32, j: u32| 1 + (i - 1) * m + j % m;
        let mut t = Vec::new();
        for j in 0..m {
            t.push([0, ring(1, j + 1), ring(1, j)]);
            for i in 1..n as u32 - 1 {
                t.push([ring(i, j), ring(i, j + 1), ring(i + 1, j + 1)]);
                t.push([ring(i, j), ring(i + 1, j + 1), ring(i + 1, j)]);
            }
            let last = p.len() as u32 - 1;
            t.push([last, ring(n as u32 - 1, j), ring(n as u32 - 1, j + 1)]);
        }
        TriMesh::new(p, t)
    }

    fn square(z: f32, size: f32) -> TriMesh {
        TriMesh::new(vec![[0.0, 0.0, z], [size, 0.0, z], [size, size, z], [0.0, size, z]], vec![[0, 1, 2], [0, 2, 3]])
    }

    fn opts(samples: usize, diagonal: f64) -> MeshMetricsOptions {
        MeshMetricsOptions { samples, ..MeshMetricsOptions::for_diagonal(diagonal) }
    }

    #[test]
    fn samples_are_area_uniform_and_seeded() {
        // Two squares of areas 1 and 3 side by side: a quarter of the samples on the first.
        let m = TriMesh::new(
            vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0], [4.0, 0.0, 0.0], [4.0, 1.0, 0.0]],
            vec![[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]],
        );
        let s = sample_surface(&m, 40_000, 7).unwrap();
        let first = s.points.iter().filter(|p| p.x < 1.0).count() as f64 / 40_000.0;
        assert!((first - 0.25).abs() < 0.01, "{first}");
        let mean_y = s.points.iter().map(|p| p.y as f64).sum::<f64>() / 40_000.0;
        assert!((mean_y - 0.5).abs() < 0.01, "{mean_y}");
        assert_eq!(s.points, sample_surface(&m, 40_000, 7).unwrap().points);
        assert_ne!(s.points, sample_surface(&m, 40_000, 8).unwrap().points);
        assert!(sample_surface(&TriMesh::default(), 10, 0).is_err());
    }

    #[test]
    fn identical_meshes_give_zero_and_f_one() {
        let s = uv_sphere(1.0, 16);
        let m = mesh_metrics(&s, &s, &opts(20_000, 2.0 * 3f64.sqrt())).unwrap();
        assert!(m.accuracy < 1e-6 && m.completeness < 1e-6 && m.chamfer_l1 < 1e-6, "{m:?}");
        for f in &m.f_scores {
            assert_eq!((f.precision, f.recall, f.f_score), (1.0, 1.0, 1.0));
        }
        assert!((m.normal_consistency.unwrap() - 1.0).abs() < 1e-9);
    }

    #[test]
    fn offset_plane_gives_the_closed_form() {
        // A unit square 0.015 above another: every sample is exactly 0.015 from the other one.
        let d = 0.015;
        let m = mesh_metrics(&square(d as f32, 1.0), &square(0.0, 1.0), &opts(5_000, 1.0)).unwrap();
        assert!((m.accuracy - d).abs() < 1e-7 && (m.completeness - d).abs() < 1e-7 && (m.chamfer_l1 - d).abs() < 1e-7, "{m:?}");
        let f: Vec<f64> = m.f_scores.iter().map(|f| f.f_score).collect();
        assert_eq!(f, [0.0, 0.0, 1.0]); // thresholds 0.005, 0.01, 0.02
        assert!((m.normal_consistency.unwrap() - 1.0).abs() < 1e-9);
        // A half-size square over the unit one: accuracy stays d, but only a quarter of the
        // reference is near the prediction, and the rest is √(d² + x²) away, x the distance
        // to the half square's footprint. Recall at τ = 0.02 is the share of the unit
        // square within √(τ² − d²) of [0, ½]²: (½ + √(τ² − d²))².
        let m = mesh_metrics(&square(d as f32, 0.5), &square(0.0, 1.0), &opts(100_000, 1.0)).unwrap();
        assert!((m.accuracy - d).abs() < 1e-7);
        let reach = (0.02f64 * 0.02 - d * d).sqrt();
        let recall = (0.5 + reach).powi(2);
        assert!((m.f_scores[2].recall - recall).abs() < 0.005, "{} vs {recall}", m.f_scores[2].recall);
        assert_eq!(m.f_scores[2].precision, 1.0);
        // Completeness: ¼·d + the mean of √(d² + dist²) over the rest, ≈ its value for the
        // L-shaped region (numerically, 1-D integrals): checked loosely against quadrature.
        let n = 2000;
        let mut sum = 0.0;
        for i in 0..n {
            for j in 0..n {
                let (x, y) = ((i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64);
                let (dx, dy) = ((x - 0.5).max(0.0), (y - 0.5).max(0.0));
                sum += (d * d + dx * dx + dy * dy).sqrt();
            }
        }
        let completeness = sum / (n * n) as f64;
        assert!((m.completeness - completeness).abs() < 0.01 * completeness, "{} vs {completeness}", m.completeness);
    }

    #[test]
    fn sphere_meshes_converge_with_resolution() {
        let reference = uv_sphere(1.0, 96);
        let o = opts(20_000, 2.0 * 3f64.sqrt());
        let coarse = mesh_metrics(&uv_sphere(1.0, 8), &reference, &o).unwrap();
        let fine = mesh_metrics(&uv_sphere(1.0, 32), &reference, &o).unwrap();
        // The chord error of a UV sphere falls as 1/n²: 16× fewer rings, about 16× closer
        // (not exactly: the reference is a polyhedron too).
        assert!(fine.chamfer_l1 < coarse.chamfer_l1 / 8.0, "{} vs {}", fine.chamfer_l1, coarse.chamfer_l1);
        assert!(fine.chamfer_l1 < 2e-3, "{}", fine.chamfer_l1);
        assert!(fine.normal_consistency > coarse.normal_consistency && fine.normal_consistency > Some(0.999));
        assert!(fine.f_scores[0].f_score >= coarse.f_scores[0].f_score);
    }

    #[test]
    fn point_clouds_give_the_closed_form() {
        // A 101 x 101 grid of points 0.015 above the unit square: every point is exactly d from
        // it; a reference sample is √(d² + r²) from the nearest point, r ≤ half a diagonal
        // of a 0.01 cell.
        let d = 0.015f32;
        let pts: Vec<Vec3> = (0..101 * 101).map(|k| Vec3::new((k % 101) as f32 / 100.0, (k / 101) as f32 / 100.0, d)).collect();
        let m = point_metrics(&pts, None, &square(0.0, 1.0), &opts(5_000, 1.0)).unwrap();
        assert!((m.accuracy - d as f64).abs() < 1e-7 && m.accuracy_median == m.accuracy, "{m:?}");
        let reach = (d as f64).hypot(0.005 * 2f64.sqrt());
        assert!(m.completeness >= d as f64 - 1e-7 && m.completeness <= reach + 1e-7, "{m:?}");
        let f: Vec<f64> = m.f_scores.iter().map(|f| f.f_score).collect();
        assert_eq!(f, [0.0, 0.0, 1.0]);
        assert_eq!((m.normal_consistency, m.predicted_area, m.predicted_triangles, m.reference_triangles), (None, 0.0, 0, 2));
        // Normals of either sign count alike; a tilted one by its cosine.
        let up = vec![DVec3::NEG_Z; pts.len()];
        let m = point_metrics(&pts, Some(&up), &square(0.0, 1.0), &opts(5_000, 1.0)).unwrap();
        assert!((m.normal_consistency.unwrap() - 1.0).abs() < 1e-12);
        let tilted = vec![DVec3::new(0.6, 0.0, 0.8); pts.len()];
        let m = point_metrics(&pts, Some(&tilted), &square(0.0, 1.0), &opts(5_000, 1.0)).unwrap();
        assert!((m.normal_consistency.unwrap() - 0.8).abs() < 1e-9, "{m:?}");
        // More points than samples: a seeded draw of as many, the same each time.
        assert_eq!(pick(3, 5, 0), [0, 1, 2]);
        let p = pick(1000, 50, 7);
        assert!(p.len() == 50 && p.windows(2).all(|w| w[0] < w[1]) && p[49] < 1000);
        assert_eq!(p, pick(1000, 50, 7));
        assert_ne!(p, pick(1000, 50, 8));
        assert!(point_metrics(&[], None, &square(0.0, 1.0), &opts(10, 1.0)).is_err());
        assert!(point_metrics(&[Vec3::NAN], None, &square(0.0, 1.0), &opts(10, 1.0)).is_err());
        assert!(point_metrics(&pts, Some(&up[..3]), &square(0.0, 1.0), &opts(10, 1.0)).is_err());
    }

    #[test]
    fn bad_options_and_meshes_are_errors() {
        let s = square(0.0, 1.0);
        assert!(mesh_metrics(&s, &s, &opts(0, 1.0)).is_err());
        assert!(mesh_metrics(&s, &s, &opts(10, 0.0)).is_err());
        assert!(mesh_metrics(&TriMesh::default(), &s, &opts(10, 1.0)).is_err());
        let mut bad = s.clone();
        bad.triangles.push([0, 1, 9]);
        assert!(mesh_metrics(&bad, &s, &opts(10, 1.0)).is_err());
    }
}
