//! `--model auto`: sizes the fast (hash-grid) model from the scene and its cameras instead of
//! fixed numbers, and states a reason for every decision (written into `config.json` as
//! `auto_reasons`).
//!
//! The rules are pure functions over constructed inputs (cameras, a box, masks, colours), so
//! each is tested on its own; [`resolve`] applies them to a loaded dataset once, before step 0,
//! and records the result in the [`TrainConfig`], so a resumed run reads the same sizes back.
//!
//! | decision | rule |
//! |---|---|
//! | bounds | scene facts' box, padded ([`SceneBounds::for_dataset`]); without facts the visual hull of the train views' alpha masks on a coarse grid ([`visual_hull`]), in two passes |
//! | finest resolution | the bounding cube's side / the smallest pixel footprint over the box ([`smallest_footprint`]: nearest distance from a train camera to the box, at least `near`, × the pixel angle); with ground-truth depth at most the resolution at which the visible surface fills the hash table at 4 cells per entry ([`surface_cells`], [`capacity_resolution`]) |
//! | coarsest resolution | instant-ngp's 16, raised until the box's smallest side spans 4 coarsest cells |
//! | levels, table size | levels from the two resolutions at growth 1.5 per level (≤ 16; instant-ngp's 1.38 costs more levels, each a share of a CPU step); table big enough for a dense finest level, at most 2^15 entries per level (one level's parameters, gradients and Adam moments in a core's 1 MiB L2 cache) and within a memory budget ([`hash_sizes`]) |
//! | view dependence | scene facts' `view_dependent`; without facts the spread of a surface point's colour across the train views that see it, with ground-truth depth ([`colour_spread`]); without depth, on the depth the model has learned after `view_test_steps` (256) steps, until then on; when it goes off the model keeps what it learned ([`view_dependence_from_model`], [`crate::models::fast::FastModel::without_view_dependence`]) |
//! | samples | occupancy cell = 8 smallest footprints (16³…64³); marching step = 2 finest cells (between one footprint and instant-ngp's 2√3), at most `max_samples_per_ray` per cube diagonal ([`sampling`]); optionally growing with distance as the footprint does, up to one occupancy cell ([`cone`], `cone_marching`, off by default) |
//! | distortion loss | mip-NeRF 360's, only when the train views show opaque surfaces ([`translucent_share`]) and see the surface from directions ≥ 45° apart ([`surface_parallax`], [`distortion_rule`]); then not on the rays of mixed pixels (partial alpha, or a depth edge within one pixel, [`crate::data::mixed_pixels`]), and not at all when more than 20 % of the covered pixels are mixed ([`mixed_rule`]) |
//! | stopping | stop when the val PSNR's least-squares trend over the last two fifths of the time budget gains < 0.1 dB per fifth even one standard error above its estimate ([`plateau_reached`]), validating every twentieth |

use crate::data::{ALPHA_EDGE, SceneBounds, TrainData};
use crate::models::ModelConfig;
use crate::models::ops::{stream, uniform};
use crate::train::TrainConfig;
use burn::config::Config;
use dataset::{Camera, Dataset, SceneFacts};
use glam::DVec3;
use serde::{Deserialize, Serialize};

/// Settings of the `auto` rules (recorded in `config.json`).
#[derive(Config, Debug)]
pub struct AutoConfig {
    /// Cells per axis of each visual-hull pass (two passes: the cameras' region, then the
    /// first hull's box).
    #[config(default = 48)]
    pub hull_grid: usize,
    /// A mask pixel is foreground when its alpha is at least this.
    #[config(default = 0.5)]
    pub mask_threshold: f32,
    /// Least coarsest resolution (instant-ngp: 16).
    #[config(default = 16)]
    pub min_base_resolution: u32,
    /// Coarsest cells across the box's smallest side.
    #[config(default = 4.0)]
    pub base_cells_per_min_side: f64,
    /// Growth factor between levels. instant-ngp's 16 levels from 16 to 2048 grow by 1.38; on a
    /// CPU every level costs about the same share of a training step (standard `thin`, auto's
    /// config, 16 → 302: 84.7 ms per step with 11 levels, 69.2 ms with 8, session 13), so
    /// auto grows by 1.5 (nerfacto's proposal grids: 1.68 and 2). With this and 8 footprint
    /// cells per occupancy cell (`bench auto`, standard, 2 min, means of 3 seeds, session 13
    /// against session 12): 1560–1840 steps instead of 1340–1560, 0.60–0.66 M parameters
    /// instead of 0.73–0.86 M; test PSNR tabletop 33.01 (32.99) dB, thin 31.58 (31.72),
    /// materials 32.09 (32.11), deep 31.55 (30.87); depth error and off-surface mass moved
    /// within the seeds' spread (tabletop 0.0114 m and 0.065 against 0.0118 m and 0.069).
    #[config(default = 1.5)]
    pub growth: f64,
    /// Most levels (the encoding's and the density network's cost per sample grow with them).
    #[config(default = 16)]
    pub max_levels: usize,
    /// Features per level.
    #[config(default = 2)]
    pub features_per_level: usize,
    /// Most log2 entries per level: while training, a level's entries are read and written with
    /// their gradient and two Adam moments, 2^15 entries × 2 features × 16 bytes = 1 MiB, one
    /// core's L2 cache on current x86 CPUs (AMD Zen 4, Intel Sapphire Rapids: 1–2 MiB).
    /// (2^17, the table alone in that cache, was the first default. The scenes disagree, in
    /// single 3-minute runs on the standard datasets: 2^15 trained faster and better on
    /// `materials` (in 40 s: 411 steps to 29.4 dB against 337 steps to 25.1 dB) and on `deep`
    /// (34.23 against 33.14 dB), worse on `tabletop` and `thin` with a one-footprint step
    /// (32.12 and 31.07 against 33.90 and 32.19 dB).) Session 7 tried 2^17 with the table
    /// sized to the visible surface at 1 cell per entry (same finest levels): on `deep`, back
    /// to back, 32.48 dB and 0.217 m depth error against 31.55 dB and 0.298 m. Over all five
    /// standard scenes (`bench auto`, 2 minutes, one run each) auto's margins over the best
    /// fixed size moved by no more than the bench's own run-to-run spread (the same fixed
    /// configuration and seed in sessions 6 and 7: up to 0.8 dB, 26 % in depth error, 10 % in
    /// off-surface mass), except deep's depth error (1.43 → 1.23 × fast-medium's); with
    /// nothing else shown, 2^15 (a quarter of the parameters) stayed.
    #[config(default = 15)]
    pub max_log2_table_size: u32,
    /// Least log2 entries per level.
    #[config(default = 10)]
    pub min_log2_table_size: u32,
    /// Memory budget of the hash tables with their Adam moments (12 bytes per parameter), MiB.
    #[config(default = 48.0)]
    pub hash_memory_mib: f64,
    /// Finest hash cells per smallest pixel footprint. One: no level finer than a train camera
    /// can see. (Two, closer to instant-ngp's 2048 over the Blender scenes' cube, was measured on
    /// the standard tabletop dataset, 5 minutes: 34.16 dB test and 86 s to 30 dB against
    /// 34.36 dB and 75 s with one; the extra levels cost more than they resolved.)
    #[config(default = 1.0)]
    pub cells_per_footprint: f64,
    /// Table capacity ([`capacity_resolution`]): no level finer than the resolution at which
    /// the surface the train views see (ground-truth depth) covers this many cells per table
    /// entry, however small the pixel footprint. `None` (and configs written before this
    /// option): the footprint alone sets the finest level. Measured with 4 (standard datasets,
    /// 2-minute runs, one each; 4 was chosen, not swept): it lowered the finest level on deep
    /// (15002 → 686), cornell (588 → 364), materials (551 → 307) and tabletop (333 → 293);
    /// test PSNR and time to 30 dB went from 31.38 dB / 85 s to 33.53 dB / 58 s on deep, 35.46 /
    /// 18.0 to 35.66 / 12.6 on cornell, 32.16 / 49.2 to 32.24 / 38.7 on materials and 33.28 /
    /// 35.5 to 33.63 / 32.2 on tabletop; cornell's depth error rose from 0.096 to 0.119 m.
    #[config(default = "Some(4.0)")]
    pub surface_cells_per_entry: Option<f64>,
    /// Footprint-sized cells (finest cells / `cells_per_footprint`) per occupancy-grid cell.
    /// instant-ngp: 16 finest cells per cell (2048 over a 128³ grid). 4 was the first default;
    /// a finer grid costs more per step on a CPU (refresh, marching and cache pressure:
    /// standard `thin`, auto's config with 8 levels, 59.2 ms per step with 32³ against 69.2 ms
    /// with 64³, session 13), so 8.
    #[config(default = 8)]
    pub hash_cells_per_grid_cell: u32,
    /// Marching step in finest hash cells (`None`, as in configs written before this option:
    /// `cells_per_footprint`, i.e. one smallest pixel footprint). A step takes a fixed number
    /// of samples (`batch_samples`), so a shorter step trains on fewer rays: with one footprint
    /// per step the standard cornell and materials datasets (3 min) reached 30 dB after 54 s
    /// and 69 s, with instant-ngp's 2√3 ≈ 3.46 cells (step √3/1024 of the unit cube against a
    /// finest cell of 1/2048) after 32 s and 60 s; but 3.46 lost thin structures (standard
    /// `thin`: 30.97 dB against 32.39 with 2, `tabletop` 32.55 against 32.98; single runs,
    /// 2^15 entries). Two cells per step, the default, was the best compromise measured.
    #[config(default = "Some(2.0)")]
    pub finest_cells_per_step: Option<f64>,
    /// Least occupancy-grid cells per axis.
    #[config(default = 16)]
    pub min_grid_resolution: usize,
    /// Most occupancy-grid cells per axis (a full refresh of 64³ cells costs several CPU steps).
    #[config(default = 64)]
    pub max_grid_resolution: usize,
    /// View dependence is on when the median colour spread (RMS over channels, display
    /// values) of surface points across views exceeds this.
    #[config(default = 0.04)]
    pub view_spread_threshold: f64,
    /// Surface points drawn for the colour-spread test.
    #[config(default = 512)]
    pub spread_points: usize,
    /// Without scene facts and ground-truth depth, the colour-spread test runs on the depth
    /// the model has learned after this many steps ([`view_dependence_from_model`]); until then
    /// the colour head sees the direction. `None`: [`DEFAULT_VIEW_TEST_STEPS`] (so a config
    /// written before this setting reads as today's default, and `bench auto` keeps its runs);
    /// `Some(0)`: not tested, kept on.
    #[config(default = "None")]
    pub view_test_steps: Option<u64>,
    /// Stop when the val PSNR gained less than this over the window.
    #[config(default = 0.1)]
    pub plateau_min_gain_db: f64,
    /// Window of the stopping rule, as a fraction of the time budget.
    #[config(default = 0.2)]
    pub plateau_window_fraction: f64,
    /// The stopping rule stops only when the val PSNR's fitted gain per window, this many
    /// standard errors above its estimate, is below `plateau_min_gain_db`
    /// ([`PlateauStop::trend_sigmas`]). `None` (configs written before session 15): the
    /// best-against-best rule those runs were trained under.
    #[config(default = "Some(1.0)")]
    pub plateau_trend_sigmas: Option<f64>,
    /// Validation interval, as a fraction of the time budget.
    #[config(default = 0.05)]
    pub val_interval_fraction: f64,
    /// Cone marching: the step grows with distance as the pixel footprint does ([`cone`]).
    /// `None` (and configs written before this option) means no: on the standard preset
    /// (3 min, 2 cores) it reached 30 dB later on cornell (63 s vs 54 s) and materials (81 s vs
    /// 72 s), final PSNR +1.3 dB on cornell and −0.2 dB on materials, single runs.
    #[config(default = "None")]
    pub cone_marching: Option<bool>,
    /// Weight of mip-NeRF 360's distortion loss ([`crate::volrend::distortion`]) when the train
    /// views show only opaque surfaces and triangulate them well ([`distortion_rule`]);
    /// mip-NeRF 360 uses 0.01. `None` (and configs written before session 9, which wrote
    /// `null`): never. Measured on the standard datasets (2 min, seed 0) with 0.01: on the
    /// orbits `tabletop` it cut the depth error from 0.0124 to 0.0116 m and the off-surface
    /// mass from 0.083 to 0.066; on the forward-facing `cornell` and `deep` it gathered the
    /// weight of walls whose depth the views leave open onto a wrong depth early in training
    /// (depth MAE 0.081 → 0.728 m and 0.24 → 0.62 m): hence [`Self::min_parallax_deg`].
    #[config(default = "Some(0.01)")]
    pub distortion_weight: Option<f32>,
    /// Least triangulation angle (degrees) of the worst-seen 5 % of the visible surface for the
    /// distortion loss ([`surface_parallax`], [`distortion_rule`]). 45°: depth is then fixed to
    /// about one pixel footprint (1 / tan 45°). The standard scenes measure 4.2° (`deep`) and
    /// 8.0° (`cornell`), forward-facing, or 126–147° (`tabletop`, `materials`, `thin`), orbits.
    /// `None`: no parallax condition.
    #[config(default = "Some(45.0)")]
    pub min_parallax_deg: Option<f64>,
    /// Surface points drawn for the parallax measurement (`None`, configs written before it:
    /// 512).
    #[config(default = "Some(512)")]
    pub parallax_points: Option<usize>,
    /// Largest share of translucent pixels ([`translucent_share`]) among the train views'
    /// covered pixels for which the scene counts as opaque.
    #[config(default = "Some(0.005)")]
    pub max_translucent_share: Option<f64>,
    /// When the distortion loss is on, rays through mixed pixels get none
    /// ([`crate::data::mixed_pixels`]: partial alpha, or a 3 × 3 depth range over this many
    /// pixel footprints; [`crate::models::fast::FastConfig::distortion_mixed_footprints`]).
    /// `None` (and configs written before this option): every ray gets the loss.
    #[config(default = "Some(16.0)")]
    pub mixed_pixel_footprints: Option<f64>,
    /// Largest share of mixed pixels among the covered train pixels for which the distortion
    /// loss stays on ([`mixed_rule`]). `None` (and configs written before this option): no
    /// limit. 0.2 lies between the standard `tabletop` (9 % mixed; with the loss, exempting
    /// mixed pixels: depth error 0.0118 m and off-surface mass 0.070, against 0.0125 and
    /// 0.083 without it) and `thin` (33 %; 31.43 dB test PSNR with it, 31.72 dB without; means
    /// of 3 seeds, 2-minute runs, session 12).
    #[config(default = "Some(0.2)")]
    pub max_mixed_share: Option<f64>,
}

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

/// Cone marching angle: the marching step at distance `t` is the pixel footprint there,
/// `t × pixel angle / cells_per_footprint` (from the camera with the smallest footprint),
/// between the constant step of [`sampling`] and one occupancy cell. Returns the angle and
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

/// Stop training when the validation PSNR has gained less than `min_gain_db` over the last
/// `window_s` seconds of training time.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PlateauStop {
    /// Window, training seconds.
    pub window_s: f64,
    /// Least gain over the window, dB.
    pub min_gain_db: f64,
    /// How the gain is measured. `Some(k)`: the least-squares trend of the val PSNR over the
    /// last [`PLATEAU_FIT_WINDOWS`] windows, plus `k` standard errors of that trend
    /// ([`plateau_trend`]). `None` (and configs written before session 15): the best val PSNR
    /// now against the best at or before `now − window_s`, which one lucky validation before
    /// the window or one dip inside it could end while the run still gained about 1 dB per
    /// window (measured: tabletop, stopped at 66 s at 31.5 dB where the same config reaches
    /// 33.0 dB at 120 s).
    #[serde(default)]
    pub trend_sigmas: Option<f64>,
}

/// The plateau trend is fitted over this many windows (the window measures the gain; a longer
/// fit averages the validation noise down).
pub const PLATEAU_FIT_WINDOWS: f64 = 2.0;

/// The trend rule fits at least this many validations (more when its span holds more).
pub const PLATEAU_MIN_POINTS: usize = 5;

/// The val PSNR's trend over the last [`PLATEAU_FIT_WINDOWS`] × `window_s` of `history`
/// ((training seconds, val PSNR) points, non-finite PSNRs skipped), as (gain per window, its
/// standard error), both dB: the least-squares slope times the window, and the slope's standard
/// error (from the fit's residuals, n − 2 degrees of freedom) times the window. When the span
/// holds fewer than [`PLATEAU_MIN_POINTS`] validations (a step longer than the validation
/// interval, e.g. on a loaded machine), the last that many are fitted instead. `None` until a
/// full fitting span has passed and that many validations exist.
///
/// Example: window 10 s, points every 5 s over [0, 20] s at 20, 20.5, 21, 21.5, 22 dB: slope
/// 0.1 dB/s, gain 1.0 dB per window, standard error 0 (the points lie on the line).
pub fn plateau_trend(history: &[(f64, f64)], window_s: f64) -> Option<(f64, f64)> {
    let &(now, _) = history.last()?;
    let span = PLATEAU_FIT_WINDOWS * window_s;
    if now < span - 1e-9 {
        return None;
    }
    let finite: Vec<(f64, f64)> = history.iter().copied().filter(|p| p.1.is_finite()).collect();
    let in_span = finite.iter().filter(|p| p.0 >= now - span - 1e-9).count();
    if finite.len() < PLATEAU_MIN_POINTS {
        return None;
    }
    let pts = &finite[finite.len() - in_span.max(PLATEAU_MIN_POINTS)..];
    let n = pts.len() as f64;
    let (tm, pm) = (pts.iter().map(|p| p.0).sum::<f64>() / n, pts.iter().map(|p| p.1).sum::<f64>() / n);
    let sxx: f64 = pts.iter().map(|p| (p.0 - tm).powi(2)).sum();
    if sxx <= 0.0 {
        return None;
    }
    let slope = pts.iter().map(|p| (p.0 - tm) * (p.1 - pm)).sum::<f64>() / sxx;
    let residual = pts.iter().map(|p| (p.1 - pm - slope * (p.0 - tm)).powi(2)).sum::<f64>() / (n - 2.0);
    Some((slope * window_s, (residual / sxx).sqrt() * window_s))
}

/// Whether training has plateaued, with `history` the (training seconds, val PSNR) points so
/// far.
///
/// With `rule.trend_sigmas = Some(k)` (what `auto` writes): the val PSNR's trend
/// ([`plateau_trend`]) gains less than `min_gain_db` per window even at `k` standard errors
/// above its estimate. The validations of a hash-grid model swing by 0.2–0.6 dB from one to the
/// next (2-minute runs on the standard datasets), so a trend that is merely estimated below
/// the threshold is not enough: the rule stops when the gain is below it with confidence.
/// Example: gain 0.03 ± 0.05 dB per window, k = 1, threshold 0.1: 0.08 < 0.1 → plateaued;
/// gain 0.03 ± 0.5: 0.53 → not yet.
///
/// With `None`: the best PSNR now exceeds the best at or before `now − window_s` by less than
/// `min_gain_db`, false until a point at least `window_s` old exists. Example: points (0 s,
/// 20 dB), (10 s, 25), (20 s, 25.05), window 10 s, gain 0.1 dB: at 20 s the best before 10 s is
/// 25, the best now 25.05: gained 0.05 < 0.1 → plateaued.
pub fn plateau_reached(history: &[(f64, f64)], rule: &PlateauStop) -> bool {
    if let Some(k) = rule.trend_sigmas {
        return plateau_trend(history, rule.window_s).is_some_and(|(gain, se)| gain + k * se < rule.min_gain_db);
    }
    let Some(&(now, _)) = history.last() else { return false };
    let cutoff = now - rule.window_s;
    if cutoff < 0.0 {
        return false;
    }
    let best = |pts: &mut dyn Iterator<Item = &(f64, f64)>| pts.map(|p| p.1).filter(|v| v.is_finite()).fold(f64::NEG_INFINITY, f64::max);
    let before = best(&mut history.iter().filter(|p| p.0 <= cutoff + 1e-9));
    let all = best(&mut history.iter());
    before.is_finite() && all - before < rule.min_gain_db
}

/// A length for a reason line: mm below 1 cm, cm below 1 m, m above.
pub fn fmt_len(x: f64) -> String {
    if x < 0.01 {
        format!("{:.2} mm", x * 1e3)
    } else if x < 1.0 {
        format!("{:.1} cm", x * 1e2)
    } else {
        format!("{x:.2} m")
    }
}

fn v3(a: [f32; 3]) -> DVec3 {
    DVec3::new(a[0] as f64, a[1] as f64, a[2] as f64)
}

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
fn lift_pixel(camera: &Camera, p: usize, width: usize, z: f32) -> DVec3 {
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
fn project(w2c: &glam::DMat4, camera: &Camera, x: DVec3) -> Option<(usize, f64)> {
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
fn depth_agrees(d: f64, z: f64) -> bool {
    (d - z).abs() <= 0.01 * z
}

/// The pixel through which `camera` sees the world point `x` ([`project`]), when it is not
/// occluded there: the ground-truth z-depth at that pixel (`depth`, row-major) agrees with
/// `x`'s ([`depth_agrees`]).
fn sees(w2c: &glam::DMat4, camera: &Camera, depth: &[f32], x: DVec3) -> Option<usize> {
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
fn widest_angle(dirs: &[DVec3]) -> f64 {
    let mut min_cos = 1.0f64;
    for (i, a) in dirs.iter().enumerate() {
        for b in &dirs[i + 1..] {
            min_cos = min_cos.min(a.dot(*b));
        }
    }
    min_cos.clamp(-1.0, 1.0).acos().to_degrees()
}

fn parallax_stats(mut angles: Vec<f64>, source: &'static str) -> Option<ParallaxStats> {
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
struct MaskSat {
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
fn carve_test(w2c: &glam::DMat4, cam: &Camera, mask: &MaskSat, centre: DVec3, radius: f64) -> Option<bool> {
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
const HULL_MIN_VIEW_FRACTION: f64 = 0.5;

/// Views that must see a hull cell whole at least (one view gives no depth).
const MIN_HULL_VIEWS: usize = 2;

/// One carving pass over the cells of side `cell` of the box `[lo, hi]` whose centres lie in
/// `ball` (centre, radius): a cell is kept when at least [`HULL_MIN_VIEW_FRACTION`] of the
/// views (and [`MIN_HULL_VIEWS`]) see all of its bounding ball and none of the views that do
/// shows only background there. Returns the kept cells' box and count.
fn carve(cams: &[Camera], w2c: &[glam::DMat4], masks: &[MaskSat], lo: DVec3, hi: DVec3, cell: f64, ball: (DVec3, f64)) -> Option<(DVec3, DVec3, usize)> {
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

fn fmt_box(lo: [f32; 3], hi: [f32; 3]) -> String {
    format!("[{:.3}, {:.3}, {:.3}]–[{:.3}, {:.3}, {:.3}]", lo[0], lo[1], lo[2], hi[0], hi[1], hi[2])
}

/// Resolves `auto` for `config` (whose model must be `fast`): bounds, hash sizes, view
/// dependence, sampling and the stopping rule, from the dataset `ds` and its loaded train
/// views `train`; records a reason per decision in `config.auto_reasons`. Does nothing when
/// `config.auto` is `None` or already resolved (`auto_reasons` set).
pub fn resolve(config: &mut TrainConfig, ds: &Dataset, train: &mut TrainData) -> Result<(), String> {
    let Some(auto) = config.auto.clone() else { return Ok(()) };
    if config.auto_reasons.is_some() {
        return Ok(());
    }
    let ModelConfig::Fast(mut fast) = config.model.clone() else {
        return Err("auto sizes the fast model; the config's model is not fast".into());
    };
    let cameras: Vec<Camera> = train.views.iter().map(|v| v.camera).collect();
    let mut reasons = Vec::new();

    // Bounds.
    let bounds = match (&config.bounds, &ds.facts) {
        (Some(b), _) => {
            reasons.push(format!("bounds = {}: given in the config ({})", fmt_box(b.aabb_min, b.aabb_max), b.source));
            b.clone()
        }
        (None, Some(f)) => {
            let b = SceneBounds::for_dataset(Some(f), &cameras, config.bounds_padding, config.assumed_scene_radius);
            reasons.push(format!(
                "bounds = {}: scene facts' box [{:.3}, {:.3}, {:.3}]–[{:.3}, {:.3}, {:.3}] padded by {} of its largest side; near {:.3}, far {:.3}",
                fmt_box(b.aabb_min, b.aabb_max),
                f.aabb_min[0], f.aabb_min[1], f.aabb_min[2], f.aabb_max[0], f.aabb_max[1], f.aabb_max[2],
                config.bounds_padding, b.near, b.far
            ));
            b
        }
        (None, None) => {
            let alphas = train.alphas();
            let refs: Vec<&[f32]> = alphas.iter().map(Vec::as_slice).collect();
            let hull = visual_hull(&cameras, &refs, auto.hull_grid, auto.mask_threshold)?;
            let b = bounds_from_hull(&hull, &cameras, config.bounds_padding);
            reasons.push(format!(
                "bounds = {}: no scene facts; visual hull of {} train masks ({} of {} cells{}), padded by {} of its largest side; near {:.3}, far {:.3}",
                fmt_box(b.aabb_min, b.aabb_max),
                cameras.len(),
                hull.occupied,
                fmt_len(hull.cell),
                if hull.all_opaque { "; every mask is opaque, so this is the region the cameras see" } else { "" },
                config.bounds_padding,
                b.near,
                b.far
            ));
            b
        }
    };

    // Hash sizes.
    let cube_side = 2.0 * bounds.half_extent() as f64;
    let min_side = (0..3).map(|k| (bounds.aabb_max[k] - bounds.aabb_min[k]) as f64).fold(f64::INFINITY, f64::min);
    let fp = smallest_footprint(&cameras, bounds.aabb_min, bounds.aabb_max, bounds.near as f64)
        .ok_or_else(|| "auto: the dataset has no train views".to_string())?;
    let depths = crate::data::frame_depths(&ds.train, config.downscale).map_err(|e| e.to_string())?;
    let depth_views: Option<Vec<(&Camera, &[f32])>> = depths.as_ref().map(|d| cameras.iter().zip(d).map(|(c, d)| (c, d.as_slice())).collect());
    let surface = match auto.surface_cells_per_entry {
        Some(k) if k > 0.0 => depth_views.as_ref().map(|views| {
            let lo = DVec3::from_array(bounds.cube().0.map(f64::from));
            surface_cells(views, lo, cube_side, SURFACE_COUNT_RESOLUTION)
        }),
        _ => None,
    };
    let (hs, r) = hash_sizes(cube_side, min_side, &fp, surface.as_ref(), &auto);
    reasons.extend(r);
    fast.levels = hs.levels;
    fast.features_per_level = hs.features_per_level;
    fast.log2_table_size = hs.log2_table_size;
    fast.base_resolution = hs.base_resolution;
    fast.finest_resolution = hs.finest_resolution;

    // View dependence.
    let (vd, r) = match &ds.facts {
        Some(f) => view_dependence_from_facts(f),
        None => {
            let stats = depths.as_ref().and_then(|depths| {
                let views: Vec<SpreadView<'_>> = train
                    .views
                    .iter()
                    .zip(depths)
                    .map(|(v, d)| SpreadView { camera: &v.camera, rgba: &v.rgba, depth: d })
                    .collect();
                colour_spread(&views, auto.spread_points, config.seed)
            });
            match (&stats, Some(auto.view_test_steps.unwrap_or(DEFAULT_VIEW_TEST_STEPS)).filter(|n| *n > 0)) {
                (None, Some(n)) if depths.is_none() => {
                    config.view_test_at = Some(n);
                    (
                        true,
                        format!(
                            "view_dependent = true until step {n}: no scene facts and no ground-truth depth; then the colour spread of surface points across the train views is measured on the depth the model has learned"
                        ),
                    )
                }
                _ => view_dependence_from_spread(stats.as_ref(), auto.view_spread_threshold),
            }
        }
    };
    fast.view_dependent = Some(vd);
    reasons.push(r);

    // Samples.
    let (grid, spd, r) = sampling(hs.finest_resolution, cube_side, fp.size, &auto, fast.max_samples_per_ray);
    fast.grid_resolution = grid;
    fast.steps_per_diagonal = spd;
    reasons.extend(r);
    if auto.cone_marching.unwrap_or(false) {
        let (angle, r) = cone(&fp, &auto, cube_side, grid, spd);
        fast.cone_angle = Some(angle);
        reasons.push(r);
    }

    // Distortion loss (translucency and parallax are measured only when the settings allow it).
    let (share, parallax) = match auto.distortion_weight.filter(|w| *w > 0.0) {
        None => (0.0, None),
        Some(_) => {
            let alphas = train.alphas();
            let views: Vec<(usize, usize, &[f32])> = train
                .views
                .iter()
                .zip(&alphas)
                .map(|(v, a)| (v.camera.intrinsics.width as usize, v.camera.intrinsics.height as usize, a.as_slice()))
                .collect();
            let parallax = depth_views
                .as_ref()
                .and_then(|views| surface_parallax(views, auto.parallax_points.unwrap_or(512), config.seed))
                .or_else(|| look_at_parallax(&cameras));
            (translucent_share(&views), parallax)
        }
    };
    let (dw, r) = distortion_rule(
        share,
        parallax.as_ref(),
        auto.distortion_weight,
        auto.max_translucent_share.unwrap_or(0.005),
        auto.min_parallax_deg.unwrap_or(0.0),
    );
    fast.distortion_weight = dw;
    reasons.push(r);
    if dw.is_some()
        && let Some(k) = auto.mixed_pixel_footprints.filter(|k| *k > 0.0)
    {
        let masks = train.mixed_masks(depths.as_deref(), k);
        let (keep, r) = mixed_rule(crate::data::mixed_share(&train.alphas(), &masks), k, auto.max_mixed_share, depths.is_some());
        if keep {
            fast.distortion_mixed_footprints = Some(k as f32);
            // The trainer would build the same masks from the same depths again.
            train.set_mixed(masks).map_err(|e| e.to_string())?;
        } else {
            fast.distortion_weight = None;
        }
        reasons.push(r);
    }

    // Stopping.
    let interval = config.time_budget_s.map_or(30.0, |t| t * auto.val_interval_fraction);
    let window = config.time_budget_s.map_or(4.0 * interval, |t| t * auto.plateau_window_fraction);
    if config.val_interval_s.is_none() {
        config.val_interval_s = Some(interval);
    }
    let rule = PlateauStop { window_s: window, min_gain_db: auto.plateau_min_gain_db, trend_sigmas: auto.plateau_trend_sigmas };
    let measure = match rule.trend_sigmas {
        Some(k) => format!(
            "the val PSNR's least-squares trend over the last {:.1} s, {k} standard error(s) above its estimate, gains < {} dB per",
            PLATEAU_FIT_WINDOWS * rule.window_s,
            rule.min_gain_db
        ),
        None => format!("the best val PSNR gains < {} dB over", rule.min_gain_db),
    };
    reasons.push(format!(
        "stop when {measure} {:.1} s of training (validating every {:.1} s), else at the budget",
        rule.window_s,
        config.val_interval()
    ));
    config.plateau_stop = Some(rule);

    config.model = ModelConfig::Fast(fast);
    config.bounds = Some(bounds);
    config.auto_reasons = Some(reasons);
    Ok(())
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

#[cfg(test)]
mod tests {
    use super::*;
    use dataset::Intrinsics;

    #[test]
    fn distortion_is_on_for_opaque_views_and_off_for_translucent_ones() {
        // A 60×30 view: an opaque disc with an anti-aliased rim, and a one-pixel-wide
        // half-covered wire: silhouettes only.
        let (w, h) = (60usize, 30usize);
        let mut opaque = vec![0.0f32; w * h];
        for j in 0..h {
            for i in 0..w {
                let r = ((i as f32 - 15.0).powi(2) + (j as f32 - 15.0).powi(2)).sqrt();
                opaque[j * w + i] = (10.5 - r).clamp(0.0, 1.0);
            }
            opaque[j * w + 34] = 0.5;
        }
        let share = translucent_share(&[(w, h, &opaque)]);
        assert_eq!(share, 0.0, "rims and wires are not translucent");
        let orbit = ParallaxStats { points: 100, low_deg: 120.0, median_deg: 150.0, source: "test" };
        let (on, reason) = distortion_rule(share, Some(&orbit), Some(0.01), 0.005, 45.0);
        assert_eq!(on, Some(0.01));
        assert!(reason.contains("opaque surfaces only"), "{reason}");
        // No alpha at all (every pixel 1): opaque.
        assert_eq!(translucent_share(&[(w, h, &vec![1.0; w * h])]), 0.0);
        // A 10×10 pane of alpha 0.4 on top: its 8×8 interior is translucent.
        let mut glass = opaque.clone();
        for j in 2..12 {
            for i in 44..54 {
                glass[j * w + i] = 0.4;
            }
        }
        let share = translucent_share(&[(w, h, &glass)]);
        let covered = glass.iter().filter(|a| **a > ALPHA_EDGE).count();
        assert!((share - 64.0 / covered as f64).abs() < 1e-12, "{share}");
        let (off, reason) = distortion_rule(share, Some(&orbit), Some(0.01), 0.005, 45.0);
        assert_eq!(off, None, "{reason}");
        assert!(reason.contains("translucent"), "{reason}");
        assert_eq!(distortion_rule(0.0, Some(&orbit), None, 0.005, 45.0).0, None, "switched off in the settings");
        // Opaque, but a forward-facing capture: the worst-seen surface at 8°.
        let forward = ParallaxStats { points: 100, low_deg: 8.0, median_deg: 10.0, source: "test" };
        let (off, reason) = distortion_rule(0.0, Some(&forward), Some(0.01), 0.005, 45.0);
        assert_eq!(off, None, "{reason}");
        assert!(reason.contains("8.0°") && reason.contains("7.1 pixel footprints"), "{reason}");
        // Nothing measured: off.
        assert_eq!(distortion_rule(0.0, None, Some(0.01), 0.005, 45.0).0, None);
    }

    #[test]
    fn mixed_pixels_exempt_rays_or_turn_the_loss_off() {
        let (keep, reason) = mixed_rule(0.09, 16.0, Some(0.2), true);
        assert!(keep && reason.starts_with("distortion_mixed_footprints = 16") && reason.contains("9.0 %"), "{reason}");
        let (keep, reason) = mixed_rule(0.33, 16.0, Some(0.2), true);
        assert!(!keep && reason.starts_with("distortion_weight = 0") && reason.contains("33.0 %"), "{reason}");
        // The limit is a strict "more than"; no limit keeps it on; without depth the line says
        // what the count misses.
        assert!(mixed_rule(0.2, 16.0, Some(0.2), true).0);
        assert!(mixed_rule(0.9, 16.0, None, true).0);
        assert!(mixed_rule(0.01, 16.0, Some(0.2), false).1.contains("no ground-truth depth"));
    }

    #[test]
    fn parallax_of_an_orbit_and_of_a_forward_facing_capture() {
        // The widest angle of a set of directions.
        let d = |deg: f64| DVec3::new(deg.to_radians().cos(), deg.to_radians().sin(), 0.0);
        assert!((widest_angle(&[d(0.0), d(30.0), d(100.0)]) - 100.0).abs() < 1e-9);
        assert_eq!(widest_angle(&[d(10.0)]), 0.0);
        let (c, r) = (DVec3::new(0.1, 0.0, -0.2), 0.8);
        let measure = |cams: &[Camera]| {
            let imgs = render_sphere(cams, c, r, &|_, _| [1.0; 3]);
            let views: Vec<(&Camera, &[f32])> = cams.iter().zip(&imgs).map(|(cam, (_, d))| (cam, d.as_slice())).collect();
            surface_parallax(&views, 300, 0).unwrap()
        };
        // An orbit of 12 views: every visible point is seen from widely separated directions.
        let orbit = ring(c, 3.0, 12, 32);
        let p = measure(&orbit);
        assert!(p.points == 300 && p.low_deg > 60.0 && p.median_deg > 90.0, "{p:?}");
        assert!(distortion_rule(0.0, Some(&p), Some(0.01), 0.005, 45.0).0.is_some());
        assert!(look_at_parallax(&orbit).unwrap().low_deg > 90.0);
        // Nine parallel views from a 0.6 m square 5 m in front of the sphere: no two rays to a
        // point are further apart than the square's diagonal seen from the nearest point,
        // 2 atan(0.3 √2 / (5 − 0.8)) ≈ 11.5°; and the farthest pair of views sees most points
        // at more than 6°.
        let forward: Vec<Camera> = (0..9)
            .map(|k| {
                let o = DVec3::new(0.3 * (k % 3) as f64 - 0.3, 0.3 * (k / 3) as f64 - 0.3, 0.0) + c;
                cam(o + DVec3::Z * 5.0, o, 48, 0.6911)
            })
            .collect();
        let p = measure(&forward);
        let bound = 2.0 * (0.3 * 2f64.sqrt() / 4.2).atan().to_degrees();
        assert!(p.low_deg < bound && p.median_deg < bound && p.median_deg > 6.0, "{p:?} (bound {bound})");
        assert!(distortion_rule(0.0, Some(&p), Some(0.01), 0.005, 45.0).0.is_none());
        // Without depth: parallel optical axes give 0°, whatever the least-squares point.
        assert!(look_at_parallax(&forward).is_none_or(|p| p.low_deg < 1e-6));
        // No pixel with depth: nothing measured.
        let empty = vec![0.0f32; 48 * 48];
        assert!(surface_parallax(&[(&forward[0], &empty)], 10, 0).is_none());
    }

    fn cam(eye: DVec3, target: DVec3, size: u32, fov: f64) -> Camera {
        Camera::new(Intrinsics::from_fov_x(size, size, fov), Camera::look_at(eye, target, DVec3::Y)).unwrap()
    }

    /// Cameras on a Fibonacci sphere of radius `r` around `c`, looking at it.
    fn ring(c: DVec3, r: f64, n: usize, size: u32) -> Vec<Camera> {
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        (0..n)
            .map(|k| {
                let y = 0.9 - 1.8 * (k as f64 + 0.5) / n as f64;
                let s = (1.0 - y * y).sqrt();
                let a = golden * k as f64;
                cam(c + DVec3::new(s * a.cos(), y, s * a.sin()) * r, c, size, 0.6911)
            })
            .collect()
    }

    #[test]
    fn plateau_rule_on_a_synthetic_psnr_curve() {
        // 30 · (1 − e^(−t/20)), validated every 5 s, window 10 s, fitted over 20 s (5 points).
        let curve: Vec<(f64, f64)> = (0..=30).map(|k| 5.0 * k as f64).map(|t| (t, 30.0 * (1.0 - (-t / 20.0).exp()))).collect();
        let first_stop = |rule: &PlateauStop, h: &[(f64, f64)]| (1..=h.len()).find(|&n| plateau_reached(&h[..n], rule)).map(|n| h[n - 1].0);
        let trend = PlateauStop { window_s: 10.0, min_gain_db: 0.1, trend_sigmas: Some(1.0) };
        // The least-squares slope over the 5 points τ = −10, −5, 0, 5, 10 s around the span's
        // middle m = t − 10 is y′(m) + y‴(m) Στ⁴ / (6 Στ²) = 1.5 e^(−m/20) (1 + 85/2400) (the odd
        // terms beyond are < 1e-4 of it); the y″ term leaves residuals 0.5 y″ (τ² − 50), so the
        // slope's standard error is 0.5 |y″| (8750 / 3 / 250)^½ with y″ = y′ / 20. At t = 115 s:
        // gain 0.0815 + 0.0069 < 0.1; at 110 s: 0.1046 + 0.0089 ≥ 0.1. So it stops at 115 s.
        assert_eq!(first_stop(&trend, &curve), Some(115.0));
        let (gain, se) = plateau_trend(&curve[..=23], 10.0).unwrap();
        let y1 = 1.5 * (-105.0_f64 / 20.0).exp();
        let (want_gain, want_se) = (10.0 * y1 * (1.0 + 85.0 / 2400.0), 10.0 * 0.5 * y1 / 20.0 * (8750.0_f64 / 3.0 / 250.0).sqrt());
        assert!((gain - want_gain).abs() < 1e-3 * want_gain && (se - want_se).abs() < 0.05 * want_se, "{gain} ± {se} vs {want_gain} ± {want_se}");
        // The best-against-best rule (configs before session 15) on the same curve:
        // 30 e^(−t/20) (e^½ − 1) < 0.1 ⇔ t > 20 ln(300 (e^½ − 1)) ≈ 105.4 s.
        let best = PlateauStop { trend_sigmas: None, ..trend.clone() };
        assert_eq!(first_stop(&best, &curve), Some(110.0));

        // A steady rise of 1 dB per window with one lucky validation (+1 dB at 15 s): the
        // best-against-best rule stops at 25 s, because nothing beat the lucky point; the trend
        // still sees the rise.
        let lucky: Vec<(f64, f64)> = (0..=12).map(|k| 5.0 * k as f64).map(|t| (t, 20.0 + 0.1 * t + if t == 15.0 { 1.0 } else { 0.0 })).collect();
        assert_eq!(first_stop(&best, &lucky), Some(25.0));
        assert_eq!(first_stop(&trend, &lucky), None);
        // Noise the fit cannot see through keeps a flat run going; a flat run with small noise stops.
        let flat = |amp: f64| -> Vec<(f64, f64)> { (0..=12).map(|k| (5.0 * k as f64, 25.0 + if k % 2 == 0 { amp } else { -amp })).collect() };
        assert_eq!(first_stop(&trend, &flat(0.5)), None, "gain 0 ± {:?}", plateau_trend(&flat(0.5), 10.0));
        assert_eq!(first_stop(&trend, &flat(0.02)), Some(20.0));
        // No decision before a full fitting span, nor from fewer than five points.
        assert!(!plateau_reached(&flat(0.0)[..4], &trend));
        assert!(!plateau_reached(&[(0.0, 25.0), (10.0, 25.0), (20.0, 25.0)], &trend));
        // Validations sparser than the span (slow steps): the last five are fitted.
        let sparse: Vec<(f64, f64)> = (0..5).map(|k| (15.0 * k as f64, 25.0 + 0.001 * k as f64)).collect();
        assert!(plateau_reached(&sparse, &trend));
        let (gain, _) = plateau_trend(&sparse, 10.0).unwrap();
        assert!((gain - 0.001 / 15.0 * 10.0).abs() < 1e-9, "{gain}");
        let rising: Vec<(f64, f64)> = sparse.iter().map(|&(t, _)| (t, 25.0 + 0.1 * t)).collect();
        assert!(!plateau_reached(&rising, &trend));
        assert!(!plateau_reached(&[], &trend));
        // The best-against-best rule: a dip after a peak is not a gain.
        assert!(plateau_reached(&[(0.0, 20.0), (5.0, 20.0), (10.0, 20.05)], &best));
        assert!(plateau_reached(&[(0.0, 25.0), (10.0, 24.0)], &best));
        assert!(!plateau_reached(&[(0.0, 20.0), (5.0, 20.0)], &best));
    }

    #[test]
    fn footprint_for_a_known_camera_and_distance() {
        // 100 px wide, focal 100 px: pixel angle 0.01 rad; the camera is 3 m from the box's face.
        let c = Camera::new(
            Intrinsics { width: 100, height: 100, fl_x: 100.0, fl_y: 100.0, cx: 50.0, cy: 50.0 },
            Camera::look_at(DVec3::new(0.0, 0.0, 4.0), DVec3::ZERO, DVec3::Y),
        )
        .unwrap();
        let far = cam(DVec3::new(0.0, 0.0, -9.0), DVec3::ZERO, 100, 0.6911);
        let fp = smallest_footprint(&[far, c], [-1.0; 3], [1.0; 3], 0.1).unwrap();
        assert_eq!(fp.view, 1);
        assert!((fp.distance - 3.0).abs() < 1e-9 && (fp.size - 0.03).abs() < 1e-9, "{fp:?}");
        // Inside the box the near distance is the floor.
        let inside = cam(DVec3::new(0.5, 0.0, 0.0), DVec3::new(0.5, 0.0, -1.0), 100, 0.6911);
        let fp = smallest_footprint(&[inside], [-1.0; 3], [1.0; 3], 0.25).unwrap();
        assert!((fp.distance - 0.25).abs() < 1e-9, "{fp:?}");
        // A 2 m cube at 3 cm footprint, two cells per footprint: ⌈2 · 2 / 0.03⌉ = 134.
        let fp = Footprint { size: 0.03, distance: 3.0, pixel_angle: 0.01, view: 1 };
        assert_eq!(hash_sizes(2.0, 2.0, &fp, None, &AutoConfig::new().with_cells_per_footprint(2.0)).0.finest_resolution, 134);
        // One cell per footprint (the default): finest ⌈2 / 0.03⌉ = 67.
        let (hs, reasons) = hash_sizes(2.0, 2.0, &fp, None, &AutoConfig::new().with_cells_per_footprint(1.0));
        assert_eq!(hs.finest_resolution, 67);
        assert_eq!(hs.base_resolution, 16);
        // 16 → 67 at b = 1.5: 1 + ⌈ln(4.19) / ln(1.5)⌉ = 1 + ⌈3.53⌉ = 5 levels.
        assert_eq!(hs.levels, 5);
        // A dense 68³ finest level needs 2^19 entries; the cache cap of 2^15 binds.
        assert_eq!(hs.log2_table_size, 15);
        assert!(reasons[3].contains("(1024 KiB) stay in a core's L2 cache"), "{reasons:?}");
        assert!(reasons[0].starts_with("finest_resolution = 67: 1 cell(s) per smallest pixel footprint 3.0 cm over a 2.00 m cube (train view 1 at 3.00 m)"), "{reasons:?}");
        assert_eq!(reasons.len(), 4);
    }

    #[test]
    fn table_capacity_from_a_seen_wall() {
        // A 64 × 64 camera with a 64-pixel focal length 3 m in front of a wall at z = 1/16
        // (mid-cell): it sees a 3 m × 3 m patch, which covers 24 × 24 cells of 12.5 cm in a 4 m
        // cube at r₀ = 32.
        let c = Camera::new(
            Intrinsics { width: 64, height: 64, fl_x: 64.0, fl_y: 64.0, cx: 32.0, cy: 32.0 },
            Camera::look_at(DVec3::new(0.0, 0.0, 3.0625), DVec3::new(0.0, 0.0, 0.0625), DVec3::Y),
        )
        .unwrap();
        let mut depth = vec![3.0f32; 64 * 64];
        depth[0] = 0.0; // a pixel without a hit is not lifted
        let s = surface_cells(&[(&c, &depth)], DVec3::splat(-2.0), 4.0, 32);
        assert_eq!((s.cells, s.samples, s.resolution), (576, 64 * 64 - 1, 32));
        // 32 √(4 · 2^15 / 576) = 482.7.
        let r = capacity_resolution(&s, 4.0, 15).unwrap();
        assert!((r - 32.0 * (4.0 * 32768.0f64 / 576.0).sqrt()).abs() < 1e-9 && (r - 482.7).abs() < 0.1, "{r}");
        assert_eq!(capacity_resolution(&SurfaceCells { resolution: 32, cells: 0, samples: 0 }, 4.0, 15), None);
        // A 1 mm footprint would allow 4000: the table's capacity binds.
        let cfg = AutoConfig::new().with_cells_per_footprint(1.0);
        let fine = Footprint { size: 0.001, distance: 0.5, pixel_angle: 0.002, view: 0 };
        let (hs, r) = hash_sizes(4.0, 4.0, &fine, Some(&s), &cfg);
        assert_eq!(hs.finest_resolution, 483);
        assert!(r[0].contains("visible surface (576 cells") && r[0].contains("would allow 4000"), "{r:?}");
        // Off in the settings, or a coarse footprint: the footprint decides.
        let (hs, _) = hash_sizes(4.0, 4.0, &fine, Some(&s), &cfg.clone().with_surface_cells_per_entry(None));
        assert_eq!(hs.finest_resolution, 4000);
        let coarse = Footprint { size: 0.05, distance: 5.0, pixel_angle: 0.01, view: 0 };
        let (hs, r) = hash_sizes(4.0, 4.0, &coarse, Some(&s), &cfg);
        assert_eq!(hs.finest_resolution, 80);
        assert!(r[0].contains("only at 483"), "{r:?}");
    }

    #[test]
    fn hash_sizes_follow_the_box_and_the_budget() {
        let cfg = AutoConfig::new().with_cells_per_footprint(1.0);
        // A flat box (0.1 m thick in a 2 m cube) raises the coarsest level: 4 · 2 / 0.1 = 80.
        let fp = Footprint { size: 0.002, distance: 1.0, pixel_angle: 0.002, view: 0 };
        let (hs, _) = hash_sizes(2.0, 0.1, &fp, None, &cfg);
        assert_eq!((hs.base_resolution, hs.finest_resolution), (80, 1000));
        // A tiny budget binds: 16 levels... of 2 features × 12 bytes in 1 MiB → T ≤ 2^15 / levels.
        let small = AutoConfig::new().with_cells_per_footprint(1.0).with_hash_memory_mib(1.0);
        let (hs, r) = hash_sizes(2.0, 2.0, &fp, None, &small);
        let bytes = hs.levels * (1 << hs.log2_table_size) * 2 * 12;
        assert!(bytes <= 1 << 20 && bytes * 2 > 1 << 20, "{hs:?}");
        assert!(r[3].contains("budget"), "{r:?}");
        // A coarse camera: finest level small enough to be dense.
        let coarse = Footprint { size: 0.2, distance: 10.0, pixel_angle: 0.02, view: 0 };
        let (hs, r) = hash_sizes(2.0, 2.0, &coarse, None, &cfg);
        assert_eq!((hs.finest_resolution, hs.base_resolution, hs.levels), (16, 16, 1));
        assert_eq!(hs.log2_table_size, 13); // 17³ = 4913 ≤ 2^13
        assert!(r[3].contains("densely"), "{r:?}");
    }

    #[test]
    fn cone_angle_is_the_pixel_angle() {
        // 2 mrad pixels: at 1 m the footprint is 2 mm; a 2 m cube with 1732 steps per diagonal
        // (2 mm) and a 64³ grid (3.1 cm cells, reached at 15.6 m).
        let fp = Footprint { size: 0.002, distance: 1.0, pixel_angle: 0.002, view: 3 };
        let cfg = AutoConfig::new();
        let (angle, why) = cone(&fp, &cfg, 2.0, 64, 1732);
        assert!((angle - 0.002).abs() < 1e-9, "{angle}");
        assert!(why.contains("train view 3") && why.contains("2.00 mm at 1.00 m"), "{why}");
        let (half, _) = cone(&fp, &AutoConfig::new().with_cells_per_footprint(2.0), 2.0, 64, 1732);
        assert!((half - 0.001).abs() < 1e-9);
    }

    #[test]
    fn sampling_follows_the_finest_resolution() {
        // Two finest cells per footprint: finest 200 is a footprint resolution of 100, so the
        // same grid and step as one cell per footprint at finest 100.
        // With a step of one footprint (configs written before `finest_cells_per_step`).
        let two = AutoConfig::new().with_cells_per_footprint(2.0).with_finest_cells_per_step(None);
        assert_eq!((sampling(200, 2.0, 0.02, &two, 1024).0, sampling(200, 2.0, 0.02, &two, 1024).1), (16, 174));
        let one = AutoConfig::new().with_cells_per_footprint(1.0).with_finest_cells_per_step(None);
        let (grid, spd, r) = sampling(100, 2.0, 0.02, &one, 1024);
        // 100 / 8 = 12.5 → nearest power of two 16; √3 · 100 = 173.2 → 174.
        assert_eq!((grid, spd), (16, 174));
        // Four footprint cells per grid cell (the first default): 100 / 4 = 25 → 32.
        assert_eq!(sampling(100, 2.0, 0.02, &one.clone().with_hash_cells_per_grid_cell(4), 1024).0, 32);
        assert!(r[1].contains("= 1.00 smallest pixel footprints"), "{r:?}");
        // The default step, two finest cells: ⌈√3 · 300 / 2⌉ = 260 steps per diagonal, a step
        // of 2 m · √3 / 260 = 1.33 cm ≈ 2 finest cells of 6.67 mm.
        let cfg = AutoConfig::new().with_cells_per_footprint(1.0);
        let (grid, spd, r) = sampling(300, 2.0, 2.0 / 300.0, &cfg, 1024);
        assert_eq!((grid, spd), (32, 260)); // 300 / 8 = 37.5 → 32
        assert!(r[1].contains("= 2.00 finest cells = 2.00 smallest pixel footprints"), "{r:?}");
        // A finest level coarser than the footprint (the table's capacity bound it): two finest
        // cells of 6.67 mm are four footprints of 3.33 mm.
        let (_, _, r) = sampling(300, 2.0, 1.0 / 300.0, &cfg, 1024);
        assert!(r[1].contains("= 2.00 finest cells = 4.00 smallest pixel footprints"), "{r:?}");
        // instant-ngp's ratio, 2√3 cells: 150 steps.
        let ngp = AutoConfig::new().with_cells_per_footprint(1.0).with_finest_cells_per_step(Some(2.0 * 3f64.sqrt()));
        assert!((150..=151).contains(&sampling(300, 2.0, 2.0 / 300.0, &ngp, 1024).1));
        let (grid, spd, r) = sampling(8000, 2.0, 2.0 / 8000.0, &cfg, 1024);
        assert_eq!((grid, spd), (64, 1024));
        assert!(r[1].contains("at most 1024"), "{r:?}");
        assert_eq!(sampling(20, 2.0, 0.1, &cfg, 1024).0, 16);
    }

    fn facts(view_dependent: bool) -> SceneFacts {
        SceneFacts {
            scene: "s".into(),
            aabb_min: [-1.0; 3],
            aabb_max: [1.0; 3],
            near: 1.0,
            far: 5.0,
            view_dependent,
            render: serde_json::Value::Null,
            renderer: "test".into(),
        }
    }

    #[test]
    fn view_dependence_from_scene_facts() {
        let (off, why) = view_dependence_from_facts(&facts(false));
        assert!(!off && why.contains("Lambertian"), "{why}");
        let (on, why) = view_dependence_from_facts(&facts(true));
        assert!(on && why.contains("view-dependent"), "{why}");
    }

    /// Renders a sphere (centre `c`, radius `r`) into `size`² views: alpha and z-depth at pixel
    /// centres, colour `shade(normal, view direction)`.
    fn render_sphere(cams: &[Camera], c: DVec3, r: f64, shade: &dyn Fn(DVec3, DVec3) -> [f32; 3]) -> Vec<(Vec<[f32; 4]>, Vec<f32>)> {
        cams.iter()
            .map(|cam| {
                let (w, h) = (cam.intrinsics.width, cam.intrinsics.height);
                let mut rgba = vec![[0.0; 4]; (w * h) as usize];
                let mut depth = vec![0.0; (w * h) as usize];
                for j in 0..h {
                    for i in 0..w {
                        let ray = cam.pixel_center_ray(i, j);
                        let oc = ray.origin - c;
                        let b = oc.dot(ray.direction);
                        let disc = b * b - (oc.length_squared() - r * r);
                        if disc < 0.0 {
                            continue;
                        }
                        let t = -b - disc.sqrt();
                        let n = (ray.origin + ray.direction * t - c) / r;
                        let p = (j * w + i) as usize;
                        let s = shade(n, ray.direction);
                        rgba[p] = [s[0], s[1], s[2], 1.0];
                        depth[p] = cam.z_depth_from_distance(i as f64 + 0.5, j as f64 + 0.5, t) as f32;
                    }
                }
                (rgba, depth)
            })
            .collect()
    }

    #[test]
    fn view_dependence_from_the_data() {
        let c = DVec3::new(0.1, 0.0, -0.2);
        let cams = ring(c, 3.0, 12, 64);
        let test = |shade: &dyn Fn(DVec3, DVec3) -> [f32; 3]| {
            let imgs = render_sphere(&cams, c, 0.8, shade);
            let views: Vec<SpreadView<'_>> =
                cams.iter().zip(&imgs).map(|(cam, (rgba, depth))| SpreadView { camera: cam, rgba, depth }).collect();
            let stats = colour_spread(&views, 200, 0).unwrap();
            assert!(stats.points >= 100 && stats.views_per_point >= 3.0, "{stats:?}");
            (stats.clone(), view_dependence_from_spread(Some(&stats), 0.04))
        };
        // Lambertian: colour depends on the normal only.
        let (s, (on, why)) = test(&|n, _| [(0.5 + 0.4 * n.x) as f32, (0.5 + 0.4 * n.y) as f32, 0.3]);
        // (Not 0: the other views' colour is read at the nearest pixel, whose normal differs.)
        assert!(!on && s.median_spread < 0.01, "{s:?} {why}");
        // Colour from the view direction (a mirror-like term): varies between views.
        let (s, (on, why)) = test(&|n, d| {
            let refl = d - 2.0 * d.dot(n) * n;
            [(0.5 + 0.4 * refl.x) as f32, (0.5 + 0.4 * refl.z) as f32, 0.3]
        });
        assert!(on && s.median_spread > 0.1, "{s:?} {why}");
        // Nothing to measure: stays on.
        assert!(view_dependence_from_spread(None, 0.04).0);
    }

    #[test]
    fn visual_hull_recovers_a_sphere_and_a_box() {
        let c = DVec3::new(0.3, -0.2, 0.1);
        let r = 0.5;
        let cams = ring(c, 3.0, 24, 96);
        let imgs = render_sphere(&cams, c, r, &|_, _| [1.0; 3]);
        let alphas: Vec<Vec<f32>> = imgs.iter().map(|(rgba, _)| rgba.iter().map(|p| p[3]).collect()).collect();
        let refs: Vec<&[f32]> = alphas.iter().map(Vec::as_slice).collect();
        let hull = visual_hull(&cams, &refs, 48, 0.5).unwrap();
        // Within a cell and a pixel footprint (96 px, fov 0.69: 3.7 mm per pixel per metre at 2.5 m) of the true box.
        let tol = hull.cell + 2.5 * 0.6911 / 96.0;
        for k in 0..3 {
            assert!((hull.min[k] - (c[k] - r)).abs() <= tol, "axis {k}: {hull:?}, tol {tol}");
            assert!((hull.max[k] - (c[k] + r)).abs() <= tol, "axis {k}: {hull:?}, tol {tol}");
        }
        assert!(!hull.all_opaque && hull.cell < 0.05, "{hull:?}");
        let b = bounds_from_hull(&hull, &cams, 0.0);
        // Cameras 3 m from the centre of a box of half-side ≈ 0.53: 0.9 × (3 − 0.53 · (1..√3))
        // to its nearest point, 1.01 × (3 + 0.53 · (1..√3)) to its farthest corner.
        assert!(b.near > 1.8 && b.near < 2.3 && b.far > 3.5 && b.far < 4.1, "{b:?}");

        // An axis-aligned box [−0.6, 0.2]×[0, 0.3]×[−0.2, 0.4] seen by the same kind of rig.
        let (lo, hi) = (DVec3::new(-0.6, 0.0, -0.2), DVec3::new(0.2, 0.3, 0.4));
        let cams = ring(0.5 * (lo + hi), 3.0, 24, 96);
        let alphas: Vec<Vec<f32>> = cams
            .iter()
            .map(|cam| {
                let (w, h) = (cam.intrinsics.width, cam.intrinsics.height);
                (0..h)
                    .flat_map(|j| (0..w).map(move |i| (i, j)))
                    .map(|(i, j)| {
                        let ray = cam.pixel_center_ray(i, j);
                        let inv = ray.direction.recip();
                        let (t0, t1) = ((lo - ray.origin) * inv, (hi - ray.origin) * inv);
                        let (tn, tf) = (t0.min(t1).max_element(), t0.max(t1).min_element());
                        if tn <= tf && tf > 0.0 { 1.0 } else { 0.0 }
                    })
                    .collect()
            })
            .collect();
        let refs: Vec<&[f32]> = alphas.iter().map(Vec::as_slice).collect();
        let hull = visual_hull(&cams, &refs, 48, 0.5).unwrap();
        let tol = hull.cell + 3.0 * 0.6911 / 96.0;
        for k in 0..3 {
            assert!((hull.min[k] - lo[k]).abs() <= tol && (hull.max[k] - hi[k]).abs() <= tol, "axis {k}: {hull:?}, tol {tol}");
        }
        // Mismatched inputs are an error, not a panic.
        assert!(visual_hull(&cams, &refs[..3], 48, 0.5).is_err());
        assert!(visual_hull(&cams[..1], &[&[1.0][..]], 48, 0.5).is_err());
    }

    #[test]
    fn bounds_from_a_known_box_are_the_padded_facts() {
        let f = facts(false);
        let cams = ring(DVec3::ZERO, 4.0, 8, 16);
        let b = SceneBounds::for_dataset(Some(&f), &cams, 0.05, 1.0);
        assert_eq!((b.aabb_min, b.aabb_max), ([-1.1; 3], [1.1; 3]));
        assert!((b.near - 0.9).abs() < 1e-6 && (b.far - 5.5).abs() < 1e-6, "{b:?}");
    }
}
