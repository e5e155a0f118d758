//! **Samples.** Occupancy cell = 8 smallest pixel footprints (16³…64³ cells); marching step =
//! 2 finest hash cells (between one footprint and instant-ngp's 2√3), at most
//! `max_samples_per_ray` per cube diagonal ([`sampling()`]); optionally growing with distance as
//! the footprint does, up to one occupancy cell ([`cone`], `cone_marching`, off by default).

use super::*;

/// Cone marching angle: the marching step at distance `t` is the pixel footprint there,
/// `t × pixel angle / cells_per_footprint` (from the camera with the smallest footprint),
/// between the constant step of [`sampling()`] and one occupancy cell. Returns the angle and
/// its reason line.
pub fn cone(footprint: &Footprint, cfg: &AutoConfig, cube_side: f64, grid: usize, steps_per_diagonal: usize) -> (f32, String) {
    let angle = footprint.pixel_angle / cfg.cells_per_footprint.max(1e-3);
    let min_step = cube_side * 3f64.sqrt() / steps_per_diagonal.max(1) as f64;
    let cell = cube_side / grid.max(1) as f64;
    (
        angle as f32,
        format!(
            "cone_angle = {angle:.3e}: the marching step follows the pixel footprint along the ray (distance × pixel angle of train view {}), {} at {} up to one occupancy cell {} at {} and beyond",
            footprint.view,
            fmt_len(min_step),
            fmt_len(min_step / angle),
            fmt_len(cell),
            fmt_len(cell / angle)
        ),
    )
}

/// Occupancy grid and marching step for a hash grid of finest resolution `finest` over a cube
/// of side `cube_side`:
/// - grid cells per axis = the power of two nearest `finest / (cells_per_footprint ·
///   hash_cells_per_grid_cell)` (i.e. that many footprint-sized finest cells per cell),
///   clamped to `[min_grid_resolution, max_grid_resolution]` (empty space is skipped at an
///   eighth of the finest detail, instant-ngp's at a sixteenth; finer grids cost more per
///   step on a CPU);
/// - steps per diagonal = ⌈√3 · finest / `finest_cells_per_step`⌉ (two finest cells per step by
///   default), at most `max_samples_per_ray` so a ray through the whole cube is never
///   cut short.
///
/// `footprint` (the smallest pixel footprint, scene units) only enters the reason lines.
pub fn sampling(finest: u32, cube_side: f64, footprint: f64, cfg: &AutoConfig, max_samples_per_ray: usize) -> (usize, usize, Vec<String>) {
    let footprints = |len: f64| len / footprint.max(1e-12);
    // The resolution of one cell per smallest footprint.
    let footprint_res = finest as f64 / cfg.cells_per_footprint.max(1e-3);
    let want = (footprint_res / cfg.hash_cells_per_grid_cell.max(1) as f64).max(1.0);
    let pow2 = 2f64.powf(want.log2().round()) as usize;
    let grid = pow2.clamp(cfg.min_grid_resolution.max(1), cfg.max_grid_resolution.max(cfg.min_grid_resolution).max(1));
    let cells_per_step = cfg.finest_cells_per_step.unwrap_or(cfg.cells_per_footprint).max(1e-3);
    let spd_raw = (3f64.sqrt() * finest as f64 / cells_per_step).ceil() as usize;
    let spd = spd_raw.min(max_samples_per_ray.max(1)).max(1);
    let reasons = vec![
        if grid == pow2 {
            format!(
                "grid_resolution = {grid}: occupancy cell {} ≈ {:.1} smallest pixel footprints (within {}..={})",
                fmt_len(cube_side / grid as f64),
                footprints(cube_side / grid as f64),
                cfg.min_grid_resolution,
                cfg.max_grid_resolution
            )
        } else {
            format!(
                "grid_resolution = {grid}: occupancy cell {} ≈ {:.1} smallest pixel footprints ({} footprint cells per cell would need {pow2}, clamped to {}..={})",
                fmt_len(cube_side / grid as f64),
                footprints(cube_side / grid as f64),
                cfg.hash_cells_per_grid_cell,
                cfg.min_grid_resolution,
                cfg.max_grid_resolution
            )
        },
        if spd < spd_raw {
            format!(
                "steps_per_diagonal = {spd}: marching step {}, coarser than {cells_per_step:.2} finest cells ({}, {spd_raw} steps per diagonal) so a cube diagonal takes at most {max_samples_per_ray} samples",
                fmt_len(cube_side * 3f64.sqrt() / spd as f64),
                fmt_len(cube_side * cells_per_step / finest as f64)
            )
        } else {
            format!(
                "steps_per_diagonal = {spd}: marching step {} = {cells_per_step:.2} finest cells = {:.2} smallest pixel footprints",
                fmt_len(cube_side * 3f64.sqrt() / spd as f64),
                footprints(cube_side * cells_per_step / finest.max(1) as f64)
            )
        },
    ];
    (grid, spd, reasons)
}

