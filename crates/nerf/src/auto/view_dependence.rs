//! **View dependence.** The scene facts' `view_dependent` ([`view_dependence_from_facts`]);
//! without facts, the spread of a surface point's colour across the train views that see it,
//! measured with ground-truth depth ([`colour_spread`], [`view_dependence_from_spread`]);
//! without depth, on the depth the model has learned after [`DEFAULT_VIEW_TEST_STEPS`] steps,
//! view-dependent until then; when it goes off the model keeps what it learned
//! ([`view_dependence_from_model`],
//! [`crate::models::fast::FastModel::without_view_dependence`]).

use super::*;

/// View dependence from scene facts: on exactly when a visible material is view-dependent.
pub fn view_dependence_from_facts(facts: &SceneFacts) -> (bool, String) {
    if facts.view_dependent {
        (true, format!("view_dependent = true: scene facts of '{}' list a view-dependent (non-Lambertian) material", facts.scene))
    } else {
        (false, format!("view_dependent = false: every material of '{}' is Lambertian (scene facts); the colour head takes no direction", facts.scene))
    }
}

/// The pixel (row-major) of `camera` (world-to-camera `w2c`) the world point `x` projects to,
/// and its z-depth, when `x` is in front of the camera and inside its image.
pub(super) fn project(w2c: &glam::DMat4, camera: &Camera, x: DVec3) -> Option<(usize, f64)> {
    let c = w2c.transform_point3(x);
    let z = -c.z;
    if z <= 1e-9 {
        return None;
    }
    let k = &camera.intrinsics;
    let (qx, qy) = (k.cx + k.fl_x * c.x / z, k.cy - k.fl_y * c.y / z);
    if !(qx >= 0.0 && qy >= 0.0 && qx < k.width as f64 && qy < k.height as f64) {
        return None;
    }
    Some((qy as usize * k.width as usize + qx as usize, z))
}

/// Whether a view's depth `d` at a pixel is the point at z-depth `z` it projects there (not
/// an occluder in front, not a surface behind): they agree within 1 %.
pub(super) fn depth_agrees(d: f64, z: f64) -> bool {
    (d - z).abs() <= 0.01 * z
}

/// The pixel through which `camera` sees the world point `x` ([`project`]), when it is not
/// occluded there: the ground-truth z-depth at that pixel (`depth`, row-major) agrees with
/// `x`'s ([`depth_agrees`]).
pub(super) fn sees(w2c: &glam::DMat4, camera: &Camera, depth: &[f32], x: DVec3) -> Option<usize> {
    let (q, z) = project(w2c, camera, x)?;
    depth.get(q).is_some_and(|&d| depth_agrees(d as f64, z)).then_some(q)
}

/// One train view for [`colour_spread`].
#[derive(Clone, Copy, Debug)]
pub struct SpreadView<'a> {
    /// The camera.
    pub camera: &'a Camera,
    /// Straight-alpha display RGBA per pixel, row-major from the top.
    pub rgba: &'a [[f32; 4]],
    /// Ground-truth z-depth per pixel (0: no hit).
    pub depth: &'a [f32],
}

/// How much a surface point's colour changes between the views that see it.
#[derive(Clone, Debug, PartialEq)]
pub struct SpreadStats {
    /// Points seen by at least 3 views.
    pub points: usize,
    /// Median over points of the RMS (over channels) standard deviation of the colour.
    pub median_spread: f64,
    /// Its 90th percentile over points.
    pub p90_spread: f64,
    /// Mean views per point.
    pub views_per_point: f64,
}

/// Radius, in pixels, of the neighbourhood that must be flat in colour around a pixel the
/// colour-spread test draws ([`colour_spread`]).
pub const FLAT_RADIUS: usize = 2;
/// Most RMS colour deviation (display values) within that neighbourhood. Texture makes a
/// point's colour in other views hinge on exact registration: a depth off by a pixel's worth
/// (a model's learned depth, or a ground-truth depth at the pixel centre against a colour
/// averaged over the pixel) would read as view dependence. In flat regions it cannot.
pub const FLAT_TOLERANCE: f64 = 0.03;

/// The colour spread of surface points across views: up to `max_points` pixels with alpha 1
/// and depth whose 5 × 5 neighbourhood is opaque and flat in colour ([`FLAT_TOLERANCE`]),
/// drawn from the views round-robin (keyed by `seed`), are lifted to 3D with their
/// depth; each point is projected into every other view, which sees it when it lands inside
/// the image on an opaque pixel whose depth agrees within 1 % (not occluded); points seen by
/// ≥ 3 views give the standard deviation of their colour. `None` when no point qualifies.
pub fn colour_spread(views: &[SpreadView<'_>], max_points: usize, seed: u64) -> Option<SpreadStats> {
    let images: Vec<(&Camera, &[[f32; 4]])> = views.iter().map(|v| (v.camera, v.rgba)).collect();
    let mut lookup = |pixels: &[(usize, usize)]| -> Vec<f32> { pixels.iter().map(|&(v, p)| views[v].depth.get(p).copied().unwrap_or(0.0)).collect() };
    colour_spread_by(&images, &mut lookup, max_points, seed)
}

/// Z-depths (0: no surface) at a batch of (view, pixel) pairs, for [`colour_spread_by`].
pub type DepthAt<'a> = dyn FnMut(&[(usize, usize)]) -> Vec<f32> + 'a;

/// [`colour_spread`] with the depth coming from `depth_at`: the z-depths (0: no surface) at a
/// batch of (view, pixel) pairs. It asks twice per round of up to `max_points` drawn pixels:
/// for the drawn pixels, then for the pixels of the other views they project to, so a
/// renderer answers in batches and only for the pixels the test looks at, at full resolution.
/// Same draws and result as [`colour_spread`] on depth maps with the same values.
pub fn colour_spread_by(
    views: &[(&Camera, &[[f32; 4]])],
    depth_at: &mut DepthAt<'_>,
    max_points: usize,
    seed: u64,
) -> Option<SpreadStats> {
    let w2c: Vec<glam::DMat4> = views.iter().map(|(c, _)| c.c2w.inverse()).collect();
    let opaque = |v: usize, p: usize| views[v].1.get(p).is_some_and(|c| c[3] >= 0.999);
    // A drawn pixel's (2r + 1)² neighbourhood: inside the image, opaque, and flat in colour.
    let flat = |v: usize, p: usize| {
        let (cam, rgba) = views[v];
        let (w, h, r) = (cam.intrinsics.width as usize, cam.intrinsics.height as usize, FLAT_RADIUS);
        let (x, y) = (p % w, p / w);
        if x < r || y < r || x + r >= w || y + r >= h {
            return false;
        }
        let (mut sum, mut sq, mut n) = ([0.0f64; 3], [0.0f64; 3], 0.0);
        for yy in y - r..=y + r {
            for xx in x - r..=x + r {
                let c = rgba[yy * w + xx];
                if c[3] < 0.999 {
                    return false;
                }
                for ch in 0..3 {
                    sum[ch] += c[ch] as f64;
                    sq[ch] += (c[ch] as f64).powi(2);
                }
                n += 1.0;
            }
        }
        let var = (0..3).map(|ch| (sq[ch] / n - (sum[ch] / n).powi(2)).max(0.0)).sum::<f64>() / 3.0;
        var.sqrt() <= FLAT_TOLERANCE
    };
    let colour = |v: usize, p: usize| {
        let c = views[v].1[p];
        [c[0] as f64, c[1] as f64, c[2] as f64]
    };
    let mut spreads = Vec::new();
    let mut seen_total = 0usize;
    let tries = max_points * 4;
    let round = max_points.max(1);
    let mut k0 = 0;
    while k0 < tries && spreads.len() < max_points && !views.is_empty() {
        let k1 = (k0 + round).min(tries);
        let drawn: Vec<(usize, usize)> = (k0..k1)
            .filter_map(|k| {
                let vi = k % views.len();
                let n = views[vi].1.len();
                let p = ((uniform(seed, stream::VAL, 1 << 40 | k as u64, 0) as f64 * n as f64) as usize).min(n.max(1) - 1);
                (n > 0 && opaque(vi, p) && flat(vi, p)).then_some((vi, p))
            })
            .collect();
        k0 = k1;
        let depth = depth_at(&drawn);
        // Each lifted point with the range of its requests in the other views.
        let mut points = Vec::new();
        let (mut asks, mut want_z) = (Vec::new(), Vec::new());
        for (&(vi, p), &z) in drawn.iter().zip(&depth) {
            if !(z > 0.0 && z.is_finite()) {
                continue;
            }
            let cam = views[vi].0;
            let x = lift_pixel(cam, p, cam.intrinsics.width as usize, z);
            let start = asks.len();
            for (ui, (u, _)) in views.iter().enumerate() {
                if ui == vi {
                    continue;
                }
                if let Some((q, zq)) = project(&w2c[ui], u, x)
                    && opaque(ui, q)
                {
                    asks.push((ui, q));
                    want_z.push(zq);
                }
            }
            points.push((vi, p, start..asks.len()));
        }
        let got = if asks.is_empty() { Vec::new() } else { depth_at(&asks) };
        for (vi, p, range) in points {
            if spreads.len() >= max_points {
                break;
            }
            let mut cols = vec![colour(vi, p)];
            for r in range {
                if depth_agrees(got[r] as f64, want_z[r]) {
                    cols.push(colour(asks[r].0, asks[r].1));
                }
            }
            if cols.len() < 3 {
                continue;
            }
            let m = cols.len() as f64;
            let var: f64 = (0..3)
                .map(|ch| {
                    let mean = cols.iter().map(|c| c[ch]).sum::<f64>() / m;
                    cols.iter().map(|c| (c[ch] - mean).powi(2)).sum::<f64>() / m
                })
                .sum::<f64>()
                / 3.0;
            seen_total += cols.len();
            spreads.push(var.sqrt());
        }
    }
    if spreads.is_empty() {
        return None;
    }
    spreads.sort_by(f64::total_cmp);
    let points = spreads.len();
    Some(SpreadStats {
        points,
        median_spread: spreads[points / 2],
        p90_spread: spreads[(points * 9 / 10).min(points - 1)],
        views_per_point: seen_total as f64 / points as f64,
    })
}

/// View dependence from a colour-spread measurement: on when the median spread exceeds
/// `threshold`; on (the safe side) when nothing could be measured.
pub fn view_dependence_from_spread(stats: Option<&SpreadStats>, threshold: f64) -> (bool, String) {
    match stats {
        Some(s) if s.median_spread > threshold => (
            true,
            format!(
                "view_dependent = true: a surface point's colour varies by {:.3} (median RMS over {} points, {:.1} views each; 90th percentile {:.3}) across views, above {threshold}",
                s.median_spread, s.points, s.views_per_point, s.p90_spread
            ),
        ),
        Some(s) => (
            false,
            format!(
                "view_dependent = false: a surface point's colour varies by only {:.3} (median RMS over {} points, {:.1} views each; 90th percentile {:.3}) across views, at most {threshold}; the colour head takes no direction",
                s.median_spread, s.points, s.views_per_point, s.p90_spread
            ),
        ),
        None => (
            true,
            "view_dependent = true: no scene facts and no ground-truth depth to test colour constancy with; kept on (the safe choice)".into(),
        ),
    }
}

/// Steps after which `auto` tests view dependence on the learned depth
/// ([`AutoConfig::view_test_steps`]).
pub const DEFAULT_VIEW_TEST_STEPS: u64 = 256;

/// View dependence tested on the depth a model has learned, for datasets without scene
/// facts and ground-truth depth (the Blender synthetic ones), after `step` steps:
/// [`colour_spread_by`] over the train views, at full resolution, with the depth the model
/// renders through the centres of the pixels the test looks at (where its opacity is at least
/// 0.5; elsewhere no surface). A depth still off misplaces points and only adds spread, so
/// an early test errs on the safe side (view dependence kept).
pub fn view_dependence_from_model(
    model: &crate::models::Model,
    views: &[crate::data::ViewPixels],
    threshold: f64,
    points: usize,
    seed: u64,
    step: u64,
) -> (bool, String) {
    let images: Vec<(&Camera, &[[f32; 4]])> = views.iter().map(|v| (&v.camera, v.rgba.as_slice())).collect();
    let mut rays = 0usize;
    let mut render = |pixels: &[(usize, usize)]| -> Vec<f32> {
        rays += pixels.len();
        let (origins, dirs): (Vec<[f32; 3]>, Vec<[f32; 3]>) = pixels.iter().map(|&(v, p)| crate::data::pixel_ray(&views[v].camera, p)).unzip();
        let out = model.render_rays(&origins, &dirs, [0.0; 3]);
        pixels
            .iter()
            .enumerate()
            .map(|(i, &(v, p))| {
                let (o, t) = (out.opacity[i], out.distance[i]);
                let cam = &views[v].camera;
                let w = cam.intrinsics.width as usize;
                if o >= 0.5 && t.is_finite() && t > 0.0 {
                    cam.z_depth_from_distance((p % w) as f64 + 0.5, (p / w) as f64 + 0.5, t as f64) as f32
                } else {
                    0.0
                }
            })
            .collect()
    };
    let stats = colour_spread_by(&images, &mut render, points, seed);
    let source = format!("the depth the model learned in {step} steps ({rays} rays rendered over {} train views)", views.len());
    match stats {
        Some(st) => {
            let (vd, reason) = view_dependence_from_spread(Some(&st), threshold);
            (vd, format!("{reason}; measured on {source}"))
        }
        None => (true, format!("view_dependent = true: {source} puts no surface point in 3 views at once; kept on (the safe choice)")),
    }
}

