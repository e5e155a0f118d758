//! **Bounds.** The scene facts' box, padded ([`SceneBounds::for_dataset`]); without facts,
//! the visual hull of the train views' alpha masks carved on a coarse grid in two passes
//! ([`visual_hull`], [`bounds_from_hull`]).
//!
//! The rule behind the carving: a cell is kept when at least half of the views (and at least
//! two) see all of its bounding ball and none of those shows only background there. An
//! object-centric capture frames its object in every view, so a region fewer views see whole
//! lies where a narrow field of view leaves it unconstrained, which no mask can carve.

use super::*;

/// A visual hull's bounding box.
#[derive(Clone, Debug, PartialEq)]
pub struct Hull {
    /// Box minimum.
    pub min: [f64; 3],
    /// Box maximum.
    pub max: [f64; 3],
    /// Cell size of the last pass.
    pub cell: f64,
    /// Occupied cells of the last pass.
    pub occupied: usize,
    /// Whether no mask had a background pixel (then the hull is the region the cameras see).
    pub all_opaque: bool,
}

/// A mask with a summed-area table of its foreground pixels.
pub(super) struct MaskSat {
    width: usize,
    height: usize,
    /// (width + 1) × (height + 1) prefix counts.
    sat: Vec<u32>,
}

impl MaskSat {
    fn new(width: usize, height: usize, alpha: &[f32], threshold: f32) -> Self {
        let mut sat = vec![0u32; (width + 1) * (height + 1)];
        for y in 0..height {
            let mut row = 0u32;
            for x in 0..width {
                row += u32::from(alpha.get(y * width + x).is_some_and(|a| *a >= threshold));
                sat[(y + 1) * (width + 1) + x + 1] = sat[y * (width + 1) + x + 1] + row;
            }
        }
        Self { width, height, sat }
    }
    /// Foreground pixels in columns x0..=x1, rows y0..=y1 (inside the image).
    fn count(&self, x0: usize, y0: usize, x1: usize, y1: usize) -> u32 {
        let w = self.width + 1;
        self.sat[(y1 + 1) * w + x1 + 1] + self.sat[y0 * w + x0] - self.sat[y0 * w + x1 + 1] - self.sat[(y1 + 1) * w + x0]
    }
}

/// What one view says about a ball: `None` when the ball is not wholly in front of the camera
/// and inside its image; else whether a foreground pixel lies under it.
pub(super) fn carve_test(w2c: &glam::DMat4, cam: &Camera, mask: &MaskSat, centre: DVec3, radius: f64) -> Option<bool> {
    let c = w2c.transform_point3(centre);
    let z = -c.z;
    if z <= radius {
        return None;
    }
    let k = &cam.intrinsics;
    let (px, py) = (k.cx + k.fl_x * c.x / z, k.cy - k.fl_y * c.y / z);
    // The ball's image lies within a disc of radius f·r / sqrt(z² − r²) around the projected centre.
    let rp = k.fl_x.max(k.fl_y) * radius / (z * z - radius * radius).sqrt();
    let (x0, x1, y0, y1) = ((px - rp).floor(), (px + rp).floor(), (py - rp).floor(), (py + rp).floor());
    let (w, h) = (mask.width as f64, mask.height as f64);
    if x0 < 0.0 || y0 < 0.0 || x1 >= w || y1 >= h {
        return None;
    }
    Some(mask.count(x0 as usize, y0 as usize, x1 as usize, y1 as usize) > 0)
}

/// The fraction of the views that must see a hull cell whole (and never as background). An
/// object-centric capture frames its object in every view; a region that fewer views see
/// whole lies where a narrow field of view leaves it unconstrained (between a camera and the
/// object, or behind the object, outside the other views' frames), which no mask can carve.
pub(super) const HULL_MIN_VIEW_FRACTION: f64 = 0.5;

/// Views that must see a hull cell whole at least (one view gives no depth).
pub(super) const MIN_HULL_VIEWS: usize = 2;

/// One carving pass over the cells of side `cell` of the box `[lo, hi]` whose centres lie in
/// `ball` (centre, radius): a cell is kept when at least [`HULL_MIN_VIEW_FRACTION`] of the
/// views (and [`MIN_HULL_VIEWS`]) see all of its bounding ball and none of the views that do
/// shows only background there. Returns the kept cells' box and count.
pub(super) fn carve(cams: &[Camera], w2c: &[glam::DMat4], masks: &[MaskSat], lo: DVec3, hi: DVec3, cell: f64, ball: (DVec3, f64)) -> Option<(DVec3, DVec3, usize)> {
    let n = ((hi - lo) / cell).ceil().max(DVec3::ONE);
    let (nx, ny, nz) = (n.x as usize, n.y as usize, n.z as usize);
    let radius = 0.5 * cell * 3f64.sqrt();
    let min_views = MIN_HULL_VIEWS.max((HULL_MIN_VIEW_FRACTION * cams.len() as f64).ceil() as usize).min(cams.len());
    let (mut bmin, mut bmax, mut count) = (DVec3::INFINITY, DVec3::NEG_INFINITY, 0usize);
    for iz in 0..nz {
        for iy in 0..ny {
            for ix in 0..nx {
                let c = lo + (DVec3::new(ix as f64, iy as f64, iz as f64) + 0.5) * cell;
                if (c - ball.0).length() > ball.1 {
                    continue;
                }
                let mut seen = 0usize;
                let mut carved = false;
                for (k, cam) in cams.iter().enumerate() {
                    match carve_test(&w2c[k], cam, &masks[k], c, radius) {
                        None => {}
                        Some(true) => seen += 1,
                        Some(false) => {
                            carved = true;
                            break;
                        }
                    }
                }
                if seen >= min_views && !carved {
                    bmin = bmin.min(c - 0.5 * cell);
                    bmax = bmax.max(c + 0.5 * cell);
                    count += 1;
                }
            }
        }
    }
    (count > 0).then_some((bmin, bmax, count))
}

/// The least-squares point closest to every camera's optical axis (their common look-at point),
/// or the mean of the points one unit in front of them when the axes are parallel.
pub fn look_at_point(cameras: &[Camera]) -> DVec3 {
    let mut a = glam::DMat3::ZERO;
    let mut b = DVec3::ZERO;
    for c in cameras {
        let d = -c.c2w.z_axis.truncate().normalize();
        let m = glam::DMat3::IDENTITY - glam::DMat3::from_cols(d * d.x, d * d.y, d * d.z);
        a += m;
        b += m * c.origin();
    }
    if a.determinant().abs() > 1e-9 {
        a.inverse() * b
    } else {
        cameras.iter().map(|c| c.origin() - c.c2w.z_axis.truncate()).sum::<DVec3>() / cameras.len().max(1) as f64
    }
}

/// The bounding box of the visual hull of the masks (`alphas[k]` belongs to `cameras[k]`,
/// row-major, the camera's size), for object-centric captures: the scene is taken to lie
/// within the ball around the cameras' common look-at point ([`look_at_point`]) that reaches
/// the nearest camera, and to be framed by most views. A first pass carves that
/// ball in `grid`³ cells; a second pass carves the first hull's box
/// grown by one coarse cell, again in about `grid` cells along its longest side. A cell
/// survives when half the views see all of it and every such view has a foreground pixel
/// (alpha ≥ `threshold`) under it, so the box holds every foreground point seen by all views,
/// inflated by at most about a cell and a pixel. Errors on mismatched inputs or when every
/// cell is carved.
pub fn visual_hull(cameras: &[Camera], alphas: &[&[f32]], grid: usize, threshold: f32) -> Result<Hull, String> {
    if cameras.is_empty() || cameras.len() != alphas.len() {
        return Err(format!("visual hull: {} cameras and {} masks", cameras.len(), alphas.len()));
    }
    let grid = grid.max(2);
    let mut masks = Vec::with_capacity(cameras.len());
    let mut all_opaque = true;
    for (c, a) in cameras.iter().zip(alphas) {
        let (w, h) = (c.intrinsics.width as usize, c.intrinsics.height as usize);
        if a.len() != w * h {
            return Err(format!("visual hull: a mask has {} pixels, its camera {w}×{h}", a.len()));
        }
        all_opaque &= a.iter().all(|v| *v >= threshold);
        masks.push(MaskSat::new(w, h, a, threshold));
    }
    let w2c: Vec<glam::DMat4> = cameras.iter().map(|c| c.c2w.inverse()).collect();
    let centre = look_at_point(cameras);
    let nearest = cameras.iter().map(|c| (c.origin() - centre).length()).fold(f64::INFINITY, f64::min).max(1e-6);
    let reach = nearest;
    let ball = (centre, reach);
    let (lo, hi) = (centre - DVec3::splat(reach), centre + DVec3::splat(reach));
    let cell1 = 2.0 * reach / grid as f64;
    let empty = || "visual hull: every cell was carved (do the masks and cameras match?)".to_string();
    let (b1, b2, _) = carve(cameras, &w2c, &masks, lo, hi, cell1, ball).ok_or_else(empty)?;
    let (lo2, hi2) = ((b1 - cell1).max(lo), (b2 + cell1).min(hi));
    let cell2 = (hi2 - lo2).max_element() / grid as f64;
    let (m1, m2, occupied) = carve(cameras, &w2c, &masks, lo2, hi2, cell2, ball).ok_or_else(empty)?;
    Ok(Hull { min: m1.to_array(), max: m2.to_array(), cell: cell2, occupied, all_opaque })
}

/// Scene bounds from a visual hull: its box padded by `padding` of its largest side; near =
/// 0.9 × the nearest camera's distance to the box (at least 1e-3 of the box's diagonal), far =
/// 1.01 × the farthest camera's distance to a corner.
pub fn bounds_from_hull(hull: &Hull, cameras: &[Camera], padding: f32) -> SceneBounds {
    let (lo, hi) = (DVec3::from(hull.min), DVec3::from(hull.max));
    let pad = (hi - lo).max_element() * padding as f64;
    let (lo, hi) = (lo - pad, hi + pad);
    let diag = (hi - lo).length();
    let near = cameras.iter().map(|c| (c.origin().clamp(lo, hi) - c.origin()).length()).fold(f64::INFINITY, f64::min);
    let far = cameras.iter().map(|c| ((c.origin() - lo).abs().max((c.origin() - hi).abs())).length()).fold(0.0, f64::max);
    SceneBounds {
        aabb_min: lo.as_vec3().to_array(),
        aabb_max: hi.as_vec3().to_array(),
        near: (0.9 * near).max(1e-3 * diag) as f32,
        far: (1.01 * far) as f32,
        source: format!(
            "visual hull of the train views' alpha masks ({} cells of {}; box padded by {padding} of its largest side)",
            hull.occupied,
            fmt_len(hull.cell)
        ),
    }
}

