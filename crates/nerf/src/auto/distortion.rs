//! **Distortion loss** (mip-NeRF 360's): on only when the train views show opaque surfaces
//! ([`translucent_share`]) seen from directions at least 45° apart ([`surface_parallax`],
//! [`distortion_rule`]); then not on the rays of mixed pixels (partial alpha, or a depth edge
//! within one pixel, [`crate::data::mixed_pixels`]), and not at all when more than 20 % of the
//! covered pixels are mixed ([`mixed_rule`]). The measurements behind the thresholds are in
//! the doc of [`AutoConfig`]'s fields.

use super::*;

/// The share of translucent pixels among the covered ones (alpha > 0.02) of the train views
/// (`(width, height, alpha)` each): a pixel with partial alpha (0.02 < α < 0.98) whose eight
/// neighbours are all partial too. A pixel that a silhouette or a sub-pixel wire crosses has a
/// background or a fully covered neighbour; a translucent surface (glTF `BLEND`, smoke) makes
/// regions of partial pixels. Views without alpha (all 1) have no partial pixel.
#[allow(clippy::neg_cmp_op_on_partial_ord)] // `!(x > y)` also rejects NaN
pub fn translucent_share(views: &[(usize, usize, &[f32])]) -> f64 {
    let (mut covered, mut translucent) = (0usize, 0usize);
    let partial = |a: f32| a > ALPHA_EDGE && a < 1.0 - ALPHA_EDGE;
    for &(w, h, alpha) in views {
        if alpha.len() != w * h {
            continue;
        }
        for j in 0..h {
            for i in 0..w {
                let a = alpha[j * w + i];
                if !(a > ALPHA_EDGE) {
                    continue;
                }
                covered += 1;
                if !partial(a) {
                    continue;
                }
                let inner = (j.saturating_sub(1)..(j + 2).min(h)).all(|y| (i.saturating_sub(1)..(i + 2).min(w)).all(|x| partial(alpha[y * w + x])));
                let whole = i > 0 && j > 0 && i + 1 < w && j + 1 < h;
                if inner && whole {
                    translucent += 1;
                }
            }
        }
    }
    if covered == 0 { 0.0 } else { translucent as f64 / covered as f64 }
}

/// The distortion-loss weight for a scene with `share` translucent pixels
/// ([`translucent_share`]) whose visible surface the train views triangulate as `parallax` says
/// ([`surface_parallax`]): `weight` when the surfaces look opaque (share ≤ `max_share`) and
/// the worst-seen part of the surface is still seen from directions at least `min_parallax_deg`
/// apart. Then each ray's weight belongs at one surface whose depth the views determine, and
/// the loss pulls it there instead of leaving fog (mip-NeRF 360). Otherwise none: a
/// translucent surface in front of another needs two separate stretches of weight, which the
/// loss penalises; and where the views leave depth open (a forward-facing capture's far or
/// textureless walls) the loss gathers the weight early in training onto a wrong depth, which
/// nothing later corrects (measured: `cornell`'s back wall, `deep`'s far wall). No
/// measurement: none (the safe side).
pub fn distortion_rule(
    share: f64,
    parallax: Option<&ParallaxStats>,
    weight: Option<f32>,
    max_share: f64,
    min_parallax_deg: f64,
) -> (Option<f32>, String) {
    let pct = 100.0 * share;
    let Some(w) = weight.filter(|w| *w > 0.0) else {
        return (None, "distortion_weight = 0: turned off in the auto settings".into());
    };
    if share > max_share {
        let reason = format!("distortion_weight = 0: {pct:.2} % of covered train pixels are translucent (more than {:.2} %): a ray may need weight at two surfaces", 100.0 * max_share);
        return (None, reason);
    }
    let q = 100.0 * PARALLAX_QUANTILE;
    match parallax {
        None => (None, "distortion_weight = 0: no surface point to measure the train views' triangulation angle on; off (the safe choice)".into()),
        Some(p) if p.low_deg < min_parallax_deg => (
            None,
            format!(
                "distortion_weight = 0: the train views see {q:.0} % of the surface from directions at most {:.1}° apart (median {:.1}°, {} points: {}), under {min_parallax_deg}°: depth there is fixed only to ~{:.1} pixel footprints, and the loss would pull ambiguous surfaces onto a wrong depth",
                p.low_deg,
                p.median_deg,
                p.points,
                p.source,
                1.0 / p.low_deg.to_radians().tan().max(1e-6)
            ),
        ),
        Some(p) => (
            Some(w),
            format!(
                "distortion_weight = {w}: the train views show opaque surfaces only ({pct:.2} % of covered pixels translucent, at most {:.2} %) and see {:.0} % of the surface from directions at least {:.1}° apart (median {:.1}°, {} points: {}; at least {min_parallax_deg}°), so each ray's weight belongs in one short stretch at a depth the views fix (mip-NeRF 360's distortion loss, its weight)",
                100.0 * max_share,
                100.0 - q,
                p.low_deg,
                p.median_deg,
                p.points,
                p.source
            ),
        ),
    }
}

/// How widely apart the train views see the visible surface: each surface point's
/// triangulation angle, the largest angle between two of the rays along which views see it.
/// A point seen at angle `θ` has its depth pinned down to about `1 / tan θ` pixel footprints
/// by a one-pixel disagreement between views; a small angle leaves its depth to the model's
/// prior (a forward-facing capture's far wall).
#[derive(Clone, Debug, PartialEq)]
pub struct ParallaxStats {
    /// Points measured.
    pub points: usize,
    /// The [`PARALLAX_QUANTILE`] quantile of the points' angles, degrees.
    pub low_deg: f64,
    /// The median angle, degrees.
    pub median_deg: f64,
    /// What the points were: surface points from ground-truth depth, or the cameras' common
    /// look-at point.
    pub source: &'static str,
}

/// The share of the visible surface that may be triangulated worse than
/// [`ParallaxStats::low_deg`]: the rule looks at the worst-seen 5 % of the surface, not at
/// single stray points.
pub const PARALLAX_QUANTILE: f64 = 0.05;

/// The largest angle (degrees) between two of the unit directions `dirs`.
pub(super) fn widest_angle(dirs: &[DVec3]) -> f64 {
    let mut min_cos = 1.0f64;
    for (i, a) in dirs.iter().enumerate() {
        for b in &dirs[i + 1..] {
            min_cos = min_cos.min(a.dot(*b));
        }
    }
    min_cos.clamp(-1.0, 1.0).acos().to_degrees()
}

pub(super) fn parallax_stats(mut angles: Vec<f64>, source: &'static str) -> Option<ParallaxStats> {
    if angles.is_empty() {
        return None;
    }
    angles.sort_by(f64::total_cmp);
    let at = |q: f64| angles[((q * (angles.len() - 1) as f64).round() as usize).min(angles.len() - 1)];
    Some(ParallaxStats { points: angles.len(), low_deg: at(PARALLAX_QUANTILE), median_deg: at(0.5), source })
}

/// Triangulation angles of the surface the train views see (`views`: camera and ground-truth
/// z-depth per pixel, row-major, 0 where nothing is hit): up to `max_points` pixels with depth,
/// drawn from the views in turn (keyed by `seed`), are lifted to 3D; every view in which a
/// point lands inside the image at an agreeing depth (within 1 %: not occluded) sees it, and
/// the point's angle is the widest between those views' rays to it (0 when only its own view
/// sees it). `None` when no pixel has depth.
pub fn surface_parallax(views: &[(&Camera, &[f32])], max_points: usize, seed: u64) -> Option<ParallaxStats> {
    let w2c: Vec<glam::DMat4> = views.iter().map(|(c, _)| c.c2w.inverse()).collect();
    let mut angles = Vec::new();
    for k in 0..max_points * 4 {
        if angles.len() >= max_points || views.is_empty() {
            break;
        }
        let vi = k % views.len();
        let (cam, depth) = views[vi];
        if depth.is_empty() {
            continue;
        }
        let p = ((uniform(seed, stream::VAL, 2 << 40 | k as u64, 0) as f64 * depth.len() as f64) as usize).min(depth.len() - 1);
        if !(depth[p] > 0.0 && depth[p].is_finite()) {
            continue;
        }
        let x = lift_pixel(cam, p, cam.intrinsics.width as usize, depth[p]);
        let dirs: Vec<DVec3> = views
            .iter()
            .enumerate()
            .filter(|(ui, (c, d))| *ui == vi || sees(&w2c[*ui], c, d, x).is_some())
            .map(|(_, (c, _))| (x - c.origin()).normalize_or_zero())
            .collect();
        angles.push(widest_angle(&dirs));
    }
    parallax_stats(angles, "surface points from ground-truth depth")
}

/// The stand-in for [`surface_parallax`] when the dataset has no depth: over the views that
/// have the cameras' common look-at point ([`look_at_point`]) in their image, the smaller of
/// the widest angle between their rays to it and the widest angle between their optical axes.
/// An object-centric capture orbits that point (both wide); a forward-facing one looks one way
/// (the axes' angle is small even where near-parallel axes put the least-squares point close to
/// the cameras). `None` when no view sees the point.
pub fn look_at_parallax(cameras: &[Camera]) -> Option<ParallaxStats> {
    let x = look_at_point(cameras);
    let seeing: Vec<&Camera> = cameras.iter().filter(|c| project(&c.c2w.inverse(), c, x).is_some()).collect();
    if seeing.is_empty() {
        return None;
    }
    let rays: Vec<DVec3> = seeing.iter().map(|c| (x - c.origin()).normalize_or_zero()).collect();
    let axes: Vec<DVec3> = seeing.iter().map(|c| -c.c2w.z_axis.truncate().normalize_or_zero()).collect();
    parallax_stats(vec![widest_angle(&rays).min(widest_angle(&axes))], "the cameras' common look-at point and optical axes (no depth)")
}

/// Whether the distortion loss, once [`distortion_rule`] turned it on, stays on for a scene
/// with `share` mixed pixels among its covered train pixels ([`crate::data::mixed_pixels`],
/// found at `footprints`), and the reason line. It stays on, exempting the mixed pixels'
/// rays, when `share` ≤ `max_share`; otherwise it goes off: the views are then largely
/// sub-pixel structure (wires, foliage), and the test finds only the mixed pixels whose
/// neighbours' centre rays hit both surfaces. A structure narrower than the pixel spacing lies
/// between centres and is not found, so many more pixels are mixed than counted, and the loss
/// would pull their split weight together.
pub fn mixed_rule(share: f64, footprints: f64, max_share: Option<f64>, with_depth: bool) -> (bool, String) {
    let pct = 100.0 * share;
    let what = if with_depth {
        format!("partial alpha, or surfaces in the 3 × 3 neighbourhood more than {footprints} pixel footprints apart in ground-truth depth")
    } else {
        "partial alpha; no ground-truth depth, so depth edges inside the masks are not found".to_string()
    };
    match max_share {
        Some(m) if share > m => (
            false,
            format!(
                "distortion_weight = 0 after all: {pct:.1} % of covered train pixels are mixed ({what}), more than {:.1} %: the views are largely sub-pixel structure, whose thinnest parts fall between pixel centres and escape the test, and the loss would pull the split weight of their pixels together",
                100.0 * m
            ),
        ),
        _ => (
            true,
            format!(
                "distortion_mixed_footprints = {footprints}: {pct:.1} % of covered train pixels are mixed ({what}){}, so their rays get no distortion loss: each blends surfaces at different depths, which its one centre ray reproduces only with its weight split between them",
                max_share.map_or(String::new(), |m| format!(", at most {:.1} %", 100.0 * m))
            ),
        ),
    }
}

