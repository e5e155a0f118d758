//! **Resolutions, levels and table size** of the hash grid ([`hash_sizes`]).
//!
//! - finest resolution: the bounding cube's side / the smallest pixel footprint over the box
//!   ([`smallest_footprint`]: nearest distance from a train camera to the box, at least `near`,
//!   times the pixel angle); with ground-truth depth at most the resolution at which the
//!   visible surface fills the hash table at 4 cells per entry ([`surface_cells`],
//!   [`capacity_resolution`]);
//! - coarsest resolution: instant-ngp's 16, raised until the box's smallest side spans 4
//!   coarsest cells;
//! - levels: from the two resolutions at growth 1.5 per level (at most 16; instant-ngp's 1.38
//!   costs more levels, each a share of a CPU step);
//! - table size: big enough for a dense finest level, at most 2^15 entries per level (one
//!   level's parameters, gradients and Adam moments fit a core's 1 MiB L2 cache, the
//!   measurement behind the cap) and within the memory budget.

use super::*;

/// The smallest pixel footprint over a box: where a train camera sees the box closest.
#[derive(Clone, Debug, PartialEq)]
pub struct Footprint {
    /// Footprint, scene units: `distance × pixel_angle`.
    pub size: f64,
    /// Distance from the camera to the box (at least the near distance).
    pub distance: f64,
    /// Pixel angle (radians) of that camera: 1 / its largest focal length in pixels.
    pub pixel_angle: f64,
    /// Index of that camera.
    pub view: usize,
}

/// The smallest pixel footprint over the box `[lo, hi]`: for each camera the distance from
/// its centre to the box (0 inside it), raised to `near` (nothing closer than the nearest
/// surface is seen, which matters for cameras inside the box), times its pixel angle
/// `1 / max(fl_x, fl_y)` (the angle of a pixel at the image centre); the smallest over
/// cameras. `None` without cameras.
///
/// Example: a 100-pixel-focal camera 2 m from the box: footprint 2 × 0.01 = 2 cm.
pub fn smallest_footprint(cameras: &[Camera], lo: [f32; 3], hi: [f32; 3], near: f64) -> Option<Footprint> {
    let (lo, hi) = (v3(lo), v3(hi));
    cameras
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let o = c.origin();
            let distance = (o.clamp(lo, hi) - o).length().max(near);
            let pixel_angle = 1.0 / c.intrinsics.fl_x.max(c.intrinsics.fl_y);
            Footprint { size: distance * pixel_angle, distance, pixel_angle, view: k }
        })
        .min_by(|a, b| a.size.total_cmp(&b.size))
}

/// The world point pixel `p` (row-major, `width` pixels per row) of `camera` sees at z-depth
/// `z`, through the pixel's centre.
pub(super) fn lift_pixel(camera: &Camera, p: usize, width: usize, z: f32) -> DVec3 {
    let (px, py) = ((p % width) as f64 + 0.5, (p / width) as f64 + 0.5);
    let ray = camera.pixel_ray(px, py);
    ray.origin + ray.direction * camera.distance_from_z_depth(px, py, z as f64)
}

/// The surface the train views see, counted as cells of a grid over the bounding cube.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceCells {
    /// Cells per axis of the counting grid.
    pub resolution: u32,
    /// Cells holding at least one lifted depth sample.
    pub cells: usize,
    /// Depth samples lifted (pixels with a hit inside the cube).
    pub samples: usize,
}

/// Counts the cells of a `resolution`³ grid over the cube `[lo, lo + side]³` that hold a
/// surface point a train view sees: every pixel with ground-truth z-depth > 0 is lifted to 3D
/// through its pixel centre. `views` are (camera, z-depth per pixel, row-major from the top).
pub fn surface_cells(views: &[(&Camera, &[f32])], lo: DVec3, side: f64, resolution: u32) -> SurfaceCells {
    let r = resolution.max(1) as i64;
    let scale = r as f64 / side.max(1e-12);
    let mut cells = std::collections::HashSet::new();
    let mut samples = 0usize;
    for (cam, depth) in views {
        let w = cam.intrinsics.width as usize;
        for (p, &z) in depth.iter().enumerate() {
            if z <= 0.0 || !z.is_finite() || w == 0 {
                continue;
            }
            let c = ((lift_pixel(cam, p, w, z) - lo) * scale).floor();
            let (i, j, k) = (c.x as i64, c.y as i64, c.z as i64);
            if !(0..r).contains(&i) || !(0..r).contains(&j) || !(0..r).contains(&k) {
                continue;
            }
            samples += 1;
            cells.insert((i * r + j) * r + k);
        }
    }
    SurfaceCells { resolution: resolution.max(1), cells: cells.len(), samples }
}

/// The finest resolution whose level still holds the visible surface in its hash table: a
/// surface covering `N₀` cells at resolution `r₀` covers about `N₀ (r / r₀)²` at `r`, so with
/// at most `cells_per_entry` surface cells per entry of a `2^log2_table_size` table,
/// `r = r₀ √(cells_per_entry · T / N₀)`. (Finer levels average unrelated surface points in
/// every entry; on 2 CPU cores and minutes of training they cost samples without resolving
/// more.) `None` when no surface was counted.
///
/// Example: a 2 m × 2 m wall in a 4 m cube covers 16² = 256 cells at r₀ = 32 (cells of
/// 12.5 cm); a 2^15 table at 4 cells per entry holds it up to 32 √(4 · 32768 / 256) = 724.
pub fn capacity_resolution(surface: &SurfaceCells, cells_per_entry: f64, log2_table_size: u32) -> Option<f64> {
    (surface.cells > 0).then(|| {
        surface.resolution as f64 * (cells_per_entry.max(1e-9) * (1u64 << log2_table_size.min(40)) as f64 / surface.cells as f64).sqrt()
    })
}

/// Resolution of the grid [`surface_cells`] counts on: coarse enough that the train views'
/// pixels sample every cell a surface crosses, fine enough that surfaces (not the box) set the
/// count.
pub const SURFACE_COUNT_RESOLUTION: u32 = 64;

/// The hash grid's sizes.
#[derive(Clone, Debug, PartialEq)]
pub struct HashSizes {
    /// Coarsest resolution over the bounding cube.
    pub base_resolution: u32,
    /// Finest resolution over the bounding cube.
    pub finest_resolution: u32,
    /// Levels.
    pub levels: usize,
    /// log2 of the entries per level.
    pub log2_table_size: u32,
    /// Features per level.
    pub features_per_level: usize,
}

/// Hash-grid sizes for a bounding cube of side `cube_side` around a box whose smallest side is
/// `min_side`, seen with smallest pixel footprint `footprint`:
/// - finest = ⌈`cells_per_footprint` · cube_side / footprint⌉ (by default one finest cell per
///   smallest pixel footprint: no level finer than what a train camera can see), clamped to
///   `[base, 2^20]`;
/// - base = max(`min_base_resolution`, ⌈`base_cells_per_min_side` · cube_side / min_side⌉),
///   at most finest;
/// - levels = 1 + ⌈ln(finest / base) / ln(`growth`)⌉, at most `max_levels`;
/// - log2 T = the least of: ⌈log2 (finest + 1)³⌉ (a dense finest level needs no more),
///   `max_log2_table_size`, and the largest T with levels · T · F · 12 bytes ≤ the budget;
///   at least `min_log2_table_size`.
///
/// Returns the sizes and a reason line per decision.
///
/// With `surface` (the visible surface counted by [`surface_cells`]) and
/// `cfg.surface_cells_per_entry` set, the finest resolution is also at most
/// [`capacity_resolution`] for a `max_log2_table_size` table.
pub fn hash_sizes(cube_side: f64, min_side: f64, footprint: &Footprint, surface: Option<&SurfaceCells>, cfg: &AutoConfig) -> (HashSizes, Vec<String>) {
    let min_side = min_side.max(1e-9 * cube_side.max(1e-9));
    let want_base = (cfg.base_cells_per_min_side * cube_side / min_side).ceil().min(1e6) as u32;
    let base0 = cfg.min_base_resolution.max(want_base).max(1);
    let cells = cfg.cells_per_footprint.max(1e-3);
    let footprint_res = (cells * cube_side / footprint.size.max(1e-12)).ceil().min((1u64 << 20) as f64) as u32;
    let capacity = match (surface, cfg.surface_cells_per_entry) {
        (Some(s), Some(k)) if k > 0.0 => capacity_resolution(s, k, cfg.max_log2_table_size).map(|r| (s, k, r)),
        _ => None,
    };
    let finest_raw = match capacity {
        Some((_, _, r)) if r.ceil() < footprint_res as f64 => r.ceil().max(1.0) as u32,
        _ => footprint_res,
    };
    let finest = finest_raw.clamp(base0.min(1 << 20), 1 << 20);
    let base = base0.min(finest);
    let mut reasons = Vec::new();
    let raised = if finest != finest_raw { format!(", raised from {finest_raw} to the coarsest resolution") } else { String::new() };
    reasons.push(match capacity {
        Some((s, k, r)) if finest_raw < footprint_res => format!(
            "finest_resolution = {finest}: the visible surface ({} cells of a {}³ grid, from {} depth samples) fills a 2^{} table at {k} cells per entry at {r:.0}; the smallest pixel footprint {} over a {} cube (train view {} at {}) would allow {footprint_res}{raised}",
            s.cells,
            s.resolution,
            s.samples,
            cfg.max_log2_table_size,
            fmt_len(footprint.size),
            fmt_len(cube_side),
            footprint.view,
            fmt_len(footprint.distance),
        ),
        _ => format!(
            "finest_resolution = {finest}: {cells} cell(s) per smallest pixel footprint {} over a {} cube (train view {} at {}){}{raised}",
            fmt_len(footprint.size),
            fmt_len(cube_side),
            footprint.view,
            fmt_len(footprint.distance),
            match capacity {
                Some((_, k, r)) => format!("; the visible surface fills a 2^{} table at {k} cells per entry only at {r:.0}", cfg.max_log2_table_size),
                None => String::new(),
            }
        ),
    });
    reasons.push(if want_base > cfg.min_base_resolution {
        format!(
            "base_resolution = {base}: coarsest cell {}, so the box's smallest side {} spans {} coarsest cells",
            fmt_len(cube_side / base as f64),
            fmt_len(min_side),
            cfg.base_cells_per_min_side
        )
    } else {
        format!(
            "base_resolution = {base}: coarsest cell {} (instant-ngp's {} over the cube; the box's smallest side {} already spans ≥ {} cells)",
            fmt_len(cube_side / base as f64),
            cfg.min_base_resolution,
            fmt_len(min_side),
            cfg.base_cells_per_min_side
        )
    });
    let ratio = finest as f64 / base as f64;
    let levels_raw = if ratio <= 1.0 + 1e-9 { 1 } else { 1 + (ratio.ln() / cfg.growth.max(1.0001).ln()).ceil() as usize };
    let levels = levels_raw.clamp(1, cfg.max_levels.max(1));
    let b = if levels > 1 { ratio.powf(1.0 / (levels - 1) as f64) } else { 1.0 };
    reasons.push(format!(
        "levels = {levels}: {base} → {finest} at growth {b:.3} per level (target {}{})",
        cfg.growth,
        if levels < levels_raw { format!(", capped at {} levels", cfg.max_levels) } else { String::new() }
    ));
    let f = cfg.features_per_level.max(1);
    let dense = ((finest as f64 + 1.0).powi(3)).log2().ceil() as u32;
    let budget_bytes = cfg.hash_memory_mib * 1024.0 * 1024.0;
    let budget = (budget_bytes / (12.0 * levels as f64 * f as f64)).max(1.0).log2().floor() as u32;
    let log2 = dense.min(cfg.max_log2_table_size).min(budget).max(cfg.min_log2_table_size);
    let why = if log2 == dense {
        format!("2^{dense} holds the finest level ({}³ vertices) densely", finest + 1)
    } else if log2 == budget && budget < cfg.max_log2_table_size {
        format!(
            "{levels} levels × {f} features × 12 bytes within the {} MiB budget (a dense finest level needs 2^{dense})",
            cfg.hash_memory_mib
        )
    } else if log2 == cfg.max_log2_table_size {
        format!(
            "one level's entries with their gradients and Adam moments ({} KiB) stay in a core's L2 cache (a dense finest level needs 2^{dense})",
            (1u64 << log2) * f as u64 * 16 / 1024
        )
    } else {
        format!("the least table size (a dense finest level needs 2^{dense})")
    };
    reasons.push(format!("log2_table_size = {log2}: {why}; {} hash parameters", levels * (1usize << log2) * f));
    (HashSizes { base_resolution: base, finest_resolution: finest, levels, log2_table_size: log2, features_per_level: f }, reasons)
}

