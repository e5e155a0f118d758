//! A mesh from a trained radiance field: the field's density sampled on a regular grid over
//! the run's scene box, the level set `σ = level` extracted by [`crate::marching_cubes`], and
//! every vertex coloured by the field as seen along its normal.
//!
//! **The level is chosen from the data** ([`choose_level`]), not fixed: pixel-centre rays of a
//! few train views are rendered through the model, and along each ray that the field renders
//! as opaque (opacity ≥ [`LEVEL_MIN_OPACITY`]) the density is sampled finely; for each
//! candidate level (log-spaced, [`LEVEL_CANDIDATES`]) the first point where the density reaches
//! it is compared with the field's own expected termination distance `Σ wᵢtᵢ / Σ wᵢ` on that
//! ray. The level whose crossings lie closest (smallest median |Δ|, a ray that never crosses
//! counting as infinitely far) is taken: the surface the mesh shows is then where the field's
//! renders put it.
//!
//! Empty space: for the fast model, occupancy cells marked empty (every density sampled in them
//! was below the grid's threshold density) are not evaluated when the level is above that
//! density; they and their neighbours' cells (one cell of margin) count as density 0.
//!
//! Colour: vertex `v` with outward unit normal `n` (the direction of decreasing density) is
//! coloured by volume rendering a short ray from `v + 2h·n` towards `−n` over `4h` (`h` the grid
//! spacing) through the field with view direction `−n`: the colour a camera looking straight
//! at the surface there would see, in display sRGB.

use crate::marching_cubes::{GridSpec, marching_cubes};
use crate::mesh::TriMesh;
use crate::EvalError;
use dataset::Camera;
use nerf::render::RunModel;
use serde::{Deserialize, Serialize};

/// Largest grid resolution accepted (cells along the box's longest side).
pub const MAX_RESOLUTION: usize = 2048;

/// Rays whose rendered opacity is at least this take part in choosing the level.
pub const LEVEL_MIN_OPACITY: f32 = 0.9;

/// Candidate levels: `10^(−1 + k/10)` for `k = 0..=50`, from 0.1 to 10⁴ per metre.
pub const LEVEL_CANDIDATES: usize = 51;

/// The candidate density levels, ascending.
pub fn level_candidates() -> Vec<f32> {
    (0..LEVEL_CANDIDATES).map(|k| 10f32.powf(-1.0 + k as f32 / 10.0)).collect()
}

/// How to extract the mesh.
#[derive(Clone, Debug, PartialEq)]
pub struct ExtractOptions {
    /// Grid cells along the longest side of the scene box (1..=[`MAX_RESOLUTION`]).
    pub resolution: usize,
    /// The density level; `None`: chosen from the data ([`choose_level`]).
    pub level: Option<f32>,
    /// Train views used to choose the level (evenly spread over the split).
    pub level_views: usize,
    /// Pixel rays per view used to choose the level (a regular subset of the pixels).
    pub level_rays_per_view: usize,
    /// Skip the occupancy grid's empty cells (fast model).
    pub use_occupancy: bool,
    /// Colour the vertices (otherwise the PLY has no colours).
    pub colors: bool,
}

impl ExtractOptions {
    /// `resolution` cells along the longest side, level from the data (4 views × 1024 rays),
    /// occupancy skipping and vertex colours on.
    pub fn at_resolution(resolution: usize) -> Self {
        Self { resolution, level: None, level_views: 4, level_rays_per_view: 1024, use_occupancy: true, colors: true }
    }
}

/// One candidate level's agreement with the rendered depth.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LevelCandidate {
    /// Density level, 1/m.
    pub level: f32,
    /// Median |first crossing − expected distance| over the rays, m (`null` when fewer than
    /// half of the rays cross).
    pub median_error: Option<f64>,
    /// Share of the rays along which the density reaches the level.
    pub crossing_fraction: f64,
}

/// The level used and why.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LevelChoice {
    /// Density level, 1/m.
    pub level: f32,
    /// `"data"` (chosen by [`choose_level`]) or `"user"` (given).
    pub source: String,
    /// One sentence saying why.
    pub reason: String,
    /// The candidates tried (empty for a given level).
    pub candidates: Vec<LevelCandidate>,
    /// Rays that took part.
    pub rays: usize,
    /// Views they came from.
    pub views: usize,
}

/// The result of [`extract_mesh`].
#[derive(Clone, Debug)]
pub struct ExtractedMesh {
    /// The mesh (world space, outward normals, optional vertex colours).
    pub mesh: TriMesh,
    /// The level and why.
    pub level: LevelChoice,
    /// The sample grid.
    pub grid: GridSpec,
    /// Grid points whose density was evaluated.
    pub evaluated_points: u64,
    /// Grid points skipped as empty space.
    pub skipped_points: u64,
    /// Largest density found on the grid.
    pub max_density: f32,
}

/// Progress of a stage of [`extract_mesh`]: `(stage, done, total)`, the stage one of `"level"`,
/// `"grid"` and `"colour"`.
pub type Progress<'a> = &'a mut dyn FnMut(&str, usize, usize);

fn check_resolution(r: usize) -> Result<(), EvalError> {
    if !(1..=MAX_RESOLUTION).contains(&r) {
        return Err(EvalError::Input(format!("mesh resolution must be 1..={MAX_RESOLUTION}, not {r}")));
    }
    Ok(())
}

/// The sample grid over the model's scene box: `resolution` cells along its longest side,
/// cubic cells, the box covered (the last samples may lie up to one cell past its far faces).
pub fn grid_over_bounds(model: &RunModel, resolution: usize) -> Result<GridSpec, EvalError> {
    check_resolution(resolution)?;
    let b = model.model.bounds();
    let ext: [f64; 3] = [0, 1, 2].map(|k| (b.aabb_max[k] - b.aabb_min[k]) as f64);
    let longest = ext.iter().copied().fold(0.0, f64::max);
    if !(longest > 0.0 && longest.is_finite()) {
        return Err(EvalError::Input("the run's scene box is empty".into()));
    }
    let h = longest / resolution as f64;
    Ok(GridSpec {
        dims: ext.map(|e| ((e / h - 1e-9).ceil() as usize).max(1) + 1),
        origin: b.aabb_min.map(|v| v as f64),
        spacing: [h; 3],
    })
}

/// Chooses the density level from the data (see the module docs), using the pixel rays of
/// `cameras` (train views) and density samples every `step` metres along them.
pub fn choose_level(model: &RunModel, cameras: &[Camera], rays_per_view: usize, step: f64, progress: Progress<'_>) -> Result<LevelChoice, EvalError> {
    let bounds = model.model.bounds();
    let (near, far) = (bounds.near as f64, bounds.far as f64);
    if !(far > near && step > 0.0) {
        return Err(EvalError::Input(format!("cannot choose a level: near {near}, far {far}, step {step}")));
    }
    let samples = (((far - near) / step).ceil() as usize).clamp(16, 4096);
    let dt = (far - near) / samples as f64;
    let background = model.eval_background();
    // (expected distance, densities along the ray) per opaque ray.
    let mut rays: Vec<(f64, Vec<f32>)> = Vec::new();
    for (v, camera) in cameras.iter().enumerate() {
        let (w, h) = (camera.intrinsics.width as usize, camera.intrinsics.height as usize);
        let stride = (((w * h) as f64 / rays_per_view.max(1) as f64).sqrt().ceil() as usize).max(1);
        let (mut origins, mut dirs) = (Vec::new(), Vec::new());
        for j in (stride / 2..h).step_by(stride) {
            for i in (stride / 2..w).step_by(stride) {
                let r = camera.pixel_center_ray(i as u32, j as u32);
                origins.push(r.origin.as_vec3().to_array());
                dirs.push(r.direction.normalize().as_vec3().to_array());
            }
        }
        let out = model.model.render_rays(&origins, &dirs, background);
        let kept: Vec<usize> = (0..origins.len()).filter(|&r| out.opacity[r] >= LEVEL_MIN_OPACITY && out.distance[r] > 0.0).collect();
        let mut points = Vec::with_capacity(kept.len() * samples);
        for &r in &kept {
            let (o, d) = (origins[r], dirs[r]);
            for k in 0..samples {
                let t = (near + (k as f64 + 0.5) * dt) as f32;
                points.push([o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]]);
            }
        }
        let sigma = model.model.density(&points);
        for (n, &r) in kept.iter().enumerate() {
            rays.push((out.distance[r] as f64, sigma[n * samples..(n + 1) * samples].to_vec()));
        }
        progress("level", v + 1, cameras.len());
    }
    if rays.is_empty() {
        return Err(EvalError::Input(format!(
            "cannot choose a density level: no pixel ray of the {} train views sampled is rendered with opacity >= {LEVEL_MIN_OPACITY} (the field shows no surface); give --level to force one",
            cameras.len()
        )));
    }
    let t_of = |k: usize| near + (k as f64 + 0.5) * dt;
    let candidates: Vec<LevelCandidate> = level_candidates()
        .into_iter()
        .map(|level| {
            let mut errors: Vec<f64> = rays
                .iter()
                .map(|(expected, sigma)| match sigma.iter().position(|s| *s >= level) {
                    Some(0) => (t_of(0) - expected).abs(),
                    Some(k) => {
                        let (a, b) = (sigma[k - 1] as f64, sigma[k] as f64);
                        let f = if b > a { ((level as f64 - a) / (b - a)).clamp(0.0, 1.0) } else { 1.0 };
                        (t_of(k - 1) + f * dt - expected).abs()
                    }
                    None => f64::INFINITY,
                })
                .collect();
            errors.sort_by(f64::total_cmp);
            let crossing = errors.iter().filter(|e| e.is_finite()).count() as f64 / errors.len() as f64;
            let median = errors[errors.len() / 2];
            LevelCandidate { level, median_error: median.is_finite().then_some(median), crossing_fraction: crossing }
        })
        .collect();
    let best = candidates
        .iter()
        .filter_map(|c| c.median_error.map(|e| (e, c)))
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, c)| c.clone())
        .ok_or_else(|| EvalError::Input(format!("no density level from 0.1 to 1e4 /m is reached along half of the {} opaque rays: the field has no surface to mesh", rays.len())))?;
    let reason = format!(
        "the candidate (of {} log-spaced from 0.1 to 1e4 /m) whose first crossing along {} opaque pixel rays of {} train views lies closest to the field's own expected depth: median |crossing - expected depth| = {:.4} m, {:.1} % of the rays reach it",
        LEVEL_CANDIDATES,
        rays.len(),
        cameras.len(),
        best.median_error.unwrap_or(f64::NAN),
        100.0 * best.crossing_fraction
    );
    Ok(LevelChoice { level: best.level, source: "data".into(), reason, candidates, rays: rays.len(), views: cameras.len() })
}

/// Up to `n` cameras spread evenly over `frames`.
pub fn spread_cameras(frames: &[dataset::Frame], n: usize) -> Vec<Camera> {
    let n = n.min(frames.len()).max(1).min(frames.len());
    (0..n).map(|k| frames[k * frames.len() / n].camera).collect()
}

/// Extracts the mesh of the run (see the module docs). `level_cameras` are the train views the
/// level is chosen from (unused when `opts.level` is given). Errors on a resolution out of
/// range, a non-positive or non-finite level, or a field with no surface at the level.
pub fn extract_mesh(model: &RunModel, level_cameras: &[Camera], opts: &ExtractOptions, progress: Progress<'_>) -> Result<ExtractedMesh, EvalError> {
    let grid = grid_over_bounds(model, opts.resolution)?;
    let h = grid.spacing[0];
    let level = match opts.level {
        Some(l) if l > 0.0 && l.is_finite() => LevelChoice {
            level: l,
            source: "user".into(),
            reason: "given on the command line".into(),
            candidates: Vec::new(),
            rays: 0,
            views: 0,
        },
        Some(l) => return Err(EvalError::Input(format!("the density level must be positive and finite, not {l}"))),
        None => choose_level(model, level_cameras, opts.level_rays_per_view, 0.5 * h, progress)?,
    };
    let iso = level.level;
    // Empty space from the occupancy grid, dilated by one cell.
    let occupancy = match (opts.use_occupancy, model.model.occupancy()) {
        (true, Some((occ, below))) if iso > below && occ.config.resolution <= 256 => {
            let r = occ.config.resolution as i64;
            let mut dilated = vec![false; (r * r * r) as usize];
            for z in 0..r {
                for y in 0..r {
                    for x in 0..r {
                        if occ.is_occupied([x, y, z].map(|v| v as u32)) {
                            for (dx, dy, dz) in (-1..=1).flat_map(|a| (-1..=1).flat_map(move |b| (-1..=1).map(move |c| (a, b, c)))) {
                                let (u, v, w) = (x + dx, y + dy, z + dz);
                                if (0..r).contains(&u) && (0..r).contains(&v) && (0..r).contains(&w) {
                                    dilated[(u + r * (v + r * w)) as usize] = true;
                                }
                            }
                        }
                    }
                }
            }
            Some((occ, dilated))
        }
        _ => None,
    };
    let [nx, ny, nz] = grid.dims;
    let (mut evaluated, mut skipped, mut max_density) = (0u64, 0u64, 0.0f32);
    let mesh = marching_cubes(
        &grid,
        iso,
        |z| {
            let mut values = vec![0.0f32; nx * ny];
            let mut points = Vec::with_capacity(nx * ny);
            let mut slots = Vec::with_capacity(nx * ny);
            for y in 0..ny {
                for x in 0..nx {
                    let p = grid.point(x, y, z).map(|v| v as f32);
                    let live = match &occupancy {
                        // Outside the occupancy box there is no field: density 0.
                        Some((occ, dilated)) => occ.cell_of(p).is_some_and(|c| dilated[occ.cell_index(c)]),
                        None => true,
                    };
                    if live {
                        points.push(p);
                        slots.push(y * nx + x);
                    }
                }
            }
            let sigma = if points.is_empty() { Vec::new() } else { model.model.density(&points) };
            for (s, v) in slots.iter().zip(sigma) {
                let v = if v.is_finite() { v } else { 0.0 };
                max_density = max_density.max(v);
                values[*s] = v;
            }
            evaluated += points.len() as u64;
            skipped += (nx * ny - points.len()) as u64;
            values
        },
        &mut |d, t| progress("grid", d, t),
    );
    if mesh.triangles.is_empty() {
        return Err(EvalError::Input(format!(
            "the field has no surface at density level {iso} /m on the {nx}x{ny}x{nz} grid (largest density sampled: {max_density} /m)"
        )));
    }
    let mut mesh = mesh;
    if opts.colors {
        mesh.colors = Some(vertex_colors(model, &mesh, h, progress));
    }
    Ok(ExtractedMesh { mesh, level, grid, evaluated_points: evaluated, skipped_points: skipped, max_density })
}

/// Samples per vertex of the short colour ray.
const COLOR_SAMPLES: usize = 8;

/// The display colour of each vertex seen along its normal (see the module docs).
fn vertex_colors(model: &RunModel, mesh: &TriMesh, h: f64, progress: Progress<'_>) -> Vec<[u8; 3]> {
    let normals = mesh.vertex_normals();
    let (start, length) = (2.0 * h as f32, 4.0 * h as f32);
    let dt = length / COLOR_SAMPLES as f32;
    let mut colors = Vec::with_capacity(mesh.positions.len());
    let chunk = 16384;
    let total = mesh.positions.len().div_ceil(chunk);
    for (c, (ps, ns)) in mesh.positions.chunks(chunk).zip(normals.chunks(chunk)).enumerate() {
        let mut points = Vec::with_capacity(ps.len() * COLOR_SAMPLES);
        let mut dirs = Vec::with_capacity(ps.len() * COLOR_SAMPLES);
        for (p, n) in ps.iter().zip(ns) {
            let n = if n.iter().all(|v| *v == 0.0) { [0.0, 0.0, 1.0] } else { *n };
            let d = n.map(|v| -v);
            for k in 0..COLOR_SAMPLES {
                let t = (k as f32 + 0.5) * dt - start;
                points.push([0, 1, 2].map(|a| p[a] + t * d[a]));
                dirs.push(d);
            }
        }
        let (sigma, rgb) = model.model.query(&points, &dirs);
        for v in 0..ps.len() {
            let (mut trans, mut acc, mut wsum) = (1.0f32, [0.0f32; 3], 0.0f32);
            for k in 0..COLOR_SAMPLES {
                let s = v * COLOR_SAMPLES + k;
                let alpha = 1.0 - (-sigma[s].max(0.0) * dt).exp();
                let w = trans * alpha;
                for a in 0..3 {
                    acc[a] += w * rgb[s][a];
                }
                wsum += w;
                trans *= 1.0 - alpha;
            }
            let c = if wsum > 1e-4 { acc.map(|x| x / wsum) } else { rgb[v * COLOR_SAMPLES + COLOR_SAMPLES / 2] };
            colors.push(c.map(|x| (x.clamp(0.0, 1.0) * 255.0).round() as u8));
        }
        progress("colour", c + 1, total);
    }
    colors
}

/// The sidecar record written next to an extracted mesh (`mesh.json` beside `mesh.ply`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeshRecord {
    /// The run folder.
    pub run: String,
    /// The checkpoint the field was loaded from.
    pub checkpoint: String,
    /// Its training step.
    pub train_steps: u64,
    /// Grid cells along the longest side of the scene box.
    pub resolution: usize,
    /// Grid samples per axis.
    pub grid_dims: [usize; 3],
    /// World position of the first grid sample.
    pub grid_origin: [f64; 3],
    /// Grid spacing, m.
    pub grid_spacing: f64,
    /// The density level and why it was chosen.
    pub level: LevelChoice,
    /// Vertices of the mesh.
    pub vertices: usize,
    /// Triangles of the mesh.
    pub triangles: usize,
    /// Surface area, m².
    pub area: f64,
    /// Grid points whose density was evaluated.
    pub evaluated_points: u64,
    /// Grid points skipped as empty space (occupancy grid).
    pub skipped_points: u64,
    /// Largest density on the grid, 1/m.
    pub max_density: f32,
    /// How the vertex colours were obtained (`null`: no colours).
    pub colors: Option<String>,
    /// Wall time of the extraction, s.
    pub seconds: f64,
}

impl MeshRecord {
    /// The record of `m`, extracted from `model` in `seconds`.
    pub fn new(run: &std::path::Path, model: &RunModel, m: &ExtractedMesh, resolution: usize, seconds: f64) -> Self {
        Self {
            run: run.display().to_string(),
            checkpoint: model.checkpoint.display().to_string(),
            train_steps: model.train_steps(),
            resolution,
            grid_dims: m.grid.dims,
            grid_origin: m.grid.origin,
            grid_spacing: m.grid.spacing[0],
            level: m.level.clone(),
            vertices: m.mesh.positions.len(),
            triangles: m.mesh.triangles.len(),
            area: m.mesh.area(),
            evaluated_points: m.evaluated_points,
            skipped_points: m.skipped_points,
            max_density: m.max_density,
            colors: m.mesh.colors.as_ref().map(|_| {
                "display sRGB volume-rendered along a short ray into the surface along -normal (view direction = -vertex normal)".to_string()
            }),
            seconds,
        }
    }
}
