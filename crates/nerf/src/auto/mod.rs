//! `--model auto`: sizes the fast (hash-grid) model from the scene and its cameras instead of
//! fixed numbers, and states a reason for every decision (written into `config.json` as
//! `auto_reasons`).
//!
//! The rules are pure functions over constructed inputs (cameras, a box, masks, colours), so
//! each is tested on its own; [`decide`] applies them to a loaded dataset once, before step 0,
//! and returns the decisions with their reasons; the trainer
//! ([`crate::train::Trainer::new`]) writes them into its config, so a resumed run reads the
//! same sizes back. Nothing here knows the trainer's config.
//! One module per decision, each starting with its rule:
//!
//! - [`bounds`]: the scene box (scene facts, else the visual hull of the masks);
//! - [`resolution`]: the hash grid's finest and coarsest resolutions, levels and table size;
//! - [`view_dependence`]: whether colour depends on the view direction;
//! - [`sampling`](mod@sampling): occupancy grid, marching step, cone marching;
//! - [`distortion`]: whether the distortion loss is on, and on which rays;
//! - [`plateau`]: when training stops early.

use crate::data::{ALPHA_EDGE, SceneBounds, TrainData};
use crate::models::fast::FastConfig;
use crate::kernels::{stream, uniform};
use burn::config::Config;
use dataset::{Camera, Dataset, SceneFacts};
use glam::DVec3;
use serde::{Deserialize, Serialize};

pub mod bounds;
pub mod distortion;
pub mod plateau;
pub mod resolution;
pub mod sampling;
pub mod view_dependence;

pub use bounds::*;
pub use distortion::*;
pub use plateau::*;
pub use resolution::*;
pub use sampling::*;
pub use view_dependence::*;

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
    /// CPU every level costs about the same share of a training step, so auto grows by 1.5
    /// (nerfacto's proposal grids: 1.68 and 2): more steps in the budget at the same quality
    /// (figures in `docs/auto.md`, "Resolutions, levels and table size").
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
    /// core's L2 cache on current x86 CPUs (AMD Zen 4, Intel Sapphire Rapids: 1–2 MiB). 2^17
    /// was measured against it and not kept (`docs/experiments.md`).
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
    /// instant-ngp: 16 finest cells per cell (2048 over a 128³ grid). A finer grid costs more
    /// per step on a CPU (refresh, marching and cache pressure; `docs/auto.md`), so 8.
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
    /// ([`PlateauStop::trend_sigmas`]). `None` (configs written before this option): the
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
    /// mip-NeRF 360 uses 0.01. `None` (and configs written before this option, which wrote
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
    /// of 3 seeds, 2-minute runs).
    #[config(default = "Some(0.2)")]
    pub max_mixed_share: Option<f64>,
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

fn fmt_box(lo: [f32; 3], hi: [f32; 3]) -> String {
    format!("[{:.3}, {:.3}, {:.3}]–[{:.3}, {:.3}, {:.3}]", lo[0], lo[1], lo[2], hi[0], hi[1], hi[2])
}

/// The run settings the rules read besides the [`AutoConfig`] (the trainer fills them from its
/// config).
#[derive(Clone, Debug)]
pub struct RunSettings {
    /// Bounds given by the user, if any (kept as they are).
    pub bounds: Option<SceneBounds>,
    /// Padding of a box found from facts or masks, as a fraction of its largest side.
    pub bounds_padding: f32,
    /// The scene radius assumed where nothing else gives the far plane.
    pub assumed_scene_radius: f32,
    /// Downscale factor of the train images.
    pub downscale: u32,
    /// The run's seed (sampling of the measured points).
    pub seed: u64,
    /// The time budget in seconds, if any.
    pub time_budget_s: Option<f64>,
    /// A validation interval given by the user, if any.
    pub val_interval_s: Option<f64>,
}

/// What `auto` decided, each decision with its reason line in `reasons`; the trainer applies
/// them to its config.
#[derive(Clone, Debug)]
pub struct Decisions {
    /// The fast model's configuration with the decided sizes, sampling and losses.
    pub fast: FastConfig,
    pub bounds: SceneBounds,
    /// Step at which view dependence is measured on the learned depth (no facts, no depth).
    pub view_test_at: Option<u64>,
    /// Validation interval (the user's, else a share of the budget).
    pub val_interval_s: f64,
    pub plateau_stop: PlateauStop,
    pub reasons: Vec<String>,
}

// Long by design: one short section per decision, in the order the decisions depend on each
// other (bounds → resolutions → view dependence → samples → distortion → stopping); each calls
// the rule of its module and records the reason.
/// Decides bounds, hash sizes, view dependence, sampling, the distortion loss and the stopping
/// rule for the fast model `fast` from the dataset `ds` and its loaded train views `train`
/// (which get the mixed-pixel masks when the distortion rule uses them).
pub fn decide(auto: &AutoConfig, mut fast: FastConfig, run: &RunSettings, ds: &Dataset, train: &mut TrainData) -> Result<Decisions, String> {
    let mut view_test_at = None;
    let cameras: Vec<Camera> = train.views.iter().map(|v| v.camera).collect();
    let mut reasons = Vec::new();

    // Bounds.
    let bounds = match (&run.bounds, &ds.facts) {
        (Some(b), _) => {
            reasons.push(format!("bounds = {}: given in the config ({})", fmt_box(b.aabb_min, b.aabb_max), b.source));
            b.clone()
        }
        (None, Some(f)) => {
            let b = SceneBounds::for_dataset(Some(f), &cameras, run.bounds_padding, run.assumed_scene_radius);
            reasons.push(format!(
                "bounds = {}: scene facts' box [{:.3}, {:.3}, {:.3}]–[{:.3}, {:.3}, {:.3}] padded by {} of its largest side; near {:.3}, far {:.3}",
                fmt_box(b.aabb_min, b.aabb_max),
                f.aabb_min[0], f.aabb_min[1], f.aabb_min[2], f.aabb_max[0], f.aabb_max[1], f.aabb_max[2],
                run.bounds_padding, b.near, b.far
            ));
            b
        }
        (None, None) => {
            let alphas = train.alphas();
            let refs: Vec<&[f32]> = alphas.iter().map(Vec::as_slice).collect();
            let hull = visual_hull(&cameras, &refs, auto.hull_grid, auto.mask_threshold)?;
            let b = bounds_from_hull(&hull, &cameras, run.bounds_padding);
            reasons.push(format!(
                "bounds = {}: no scene facts; visual hull of {} train masks ({} of {} cells{}), padded by {} of its largest side; near {:.3}, far {:.3}",
                fmt_box(b.aabb_min, b.aabb_max),
                cameras.len(),
                hull.occupied,
                fmt_len(hull.cell),
                if hull.all_opaque { "; every mask is opaque, so this is the region the cameras see" } else { "" },
                run.bounds_padding,
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
    let depths = crate::data::frame_depths(&ds.train, run.downscale).map_err(|e| e.to_string())?;
    let depth_views: Option<Vec<(&Camera, &[f32])>> = depths.as_ref().map(|d| cameras.iter().zip(d).map(|(c, d)| (c, d.as_slice())).collect());
    let surface = match auto.surface_cells_per_entry {
        Some(k) if k > 0.0 => depth_views.as_ref().map(|views| {
            let lo = DVec3::from_array(bounds.cube().0.map(f64::from));
            surface_cells(views, lo, cube_side, SURFACE_COUNT_RESOLUTION)
        }),
        _ => None,
    };
    let (hs, r) = hash_sizes(cube_side, min_side, &fp, surface.as_ref(), auto);
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
                colour_spread(&views, auto.spread_points, run.seed)
            });
            match (&stats, Some(auto.view_test_steps.unwrap_or(DEFAULT_VIEW_TEST_STEPS)).filter(|n| *n > 0)) {
                (None, Some(n)) if depths.is_none() => {
                    view_test_at = Some(n);
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
    let (grid, spd, r) = sampling(hs.finest_resolution, cube_side, fp.size, auto, fast.max_samples_per_ray);
    fast.grid_resolution = grid;
    fast.steps_per_diagonal = spd;
    reasons.extend(r);
    if auto.cone_marching.unwrap_or(false) {
        let (angle, r) = cone(&fp, auto, cube_side, grid, spd);
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
                .and_then(|views| surface_parallax(views, auto.parallax_points.unwrap_or(512), run.seed))
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
    let interval = run.time_budget_s.map_or(30.0, |t| t * auto.val_interval_fraction);
    let window = run.time_budget_s.map_or(4.0 * interval, |t| t * auto.plateau_window_fraction);
    let val_interval_s = run.val_interval_s.unwrap_or(interval);
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
        // as `TrainConfig::val_interval` reads it
        val_interval_s.max(1e-3)
    ));
    Ok(Decisions { fast, bounds, view_test_at, val_interval_s, plateau_stop: rule, reasons })
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
        // The best-against-best rule (configs written before the trend rule) on the same curve:
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
            objects: vec![],
            materials: vec![],
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
