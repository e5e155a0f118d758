//! The fast model's settings ([`FastConfig`]): the hash grid, the networks, the occupancy grid
//! and marching, the losses and the optimisers, with their checks.

use crate::encoding::hashgrid::HashGridConfig;
use crate::encoding::sh::sh_output_dim;
use crate::field::HashFieldConfig;
use crate::models::base::check_adam;
use burn::config::Config;

/// Settings of the fast model.
#[derive(Config, Debug)]
pub struct FastConfig {
    /// Hash levels L.
    #[config(default = 16)]
    pub levels: usize,
    /// Features per level F.
    #[config(default = 2)]
    pub features_per_level: usize,
    /// log2 of the entries per level T.
    #[config(default = 17)]
    pub log2_table_size: u32,
    /// Coarsest grid resolution over the bounding cube.
    #[config(default = 16)]
    pub base_resolution: u32,
    /// Finest grid resolution over the bounding cube (instant-ngp: 2048 × the scene's extent in
    /// units of its unit cube; 512 suits the 64–400 pixel images used on the CPU: finer levels
    /// only memorise the few training views).
    #[config(default = 512)]
    pub finest_resolution: u32,
    /// Spherical-harmonics degree of the direction encoding (4 → 16 coefficients).
    #[config(default = 4)]
    pub sh_degree: usize,
    /// Whether the colour network sees the view direction (SH of it); without, colour is a
    /// function of position only (Lambertian scenes; `--model auto` decides). `None` (and
    /// configs written before this option) means yes: burn's config files need every
    /// non-`Option` field, so an `Option` keeps older `config.json` files readable.
    #[config(default = "None")]
    pub view_dependent: Option<bool>,
    /// Hidden width of the density network.
    #[config(default = 64)]
    pub density_width: usize,
    /// Geometry features passed on to the colour network.
    #[config(default = 16)]
    pub geo_features: usize,
    /// Hidden width of the colour network.
    #[config(default = 64)]
    pub color_width: usize,
    /// Hidden layers of the colour network.
    #[config(default = 2)]
    pub color_depth: usize,
    /// Occupancy-grid cells per axis.
    #[config(default = 64)]
    pub grid_resolution: usize,
    /// Marching steps along the bounding cube's diagonal (the step size is diagonal / this;
    /// instant-ngp: 1024 for 800-pixel images; 512 suits the ≤ 400-pixel images of CPU runs).
    #[config(default = 512)]
    pub steps_per_diagonal: usize,
    /// Most samples per ray.
    #[config(default = 1024)]
    pub max_samples_per_ray: usize,
    /// Cone marching: the step at distance `t` from the camera is `t · cone_angle` (the pixel
    /// footprint there), at least the constant step above and at most one occupancy cell.
    /// `None` or 0 (and configs written before this option): the constant step everywhere.
    #[config(default = "None")]
    pub cone_angle: Option<f32>,
    /// Steps between occupancy-grid updates (instant-ngp: 16); the first update is at this step
    /// (before it every cell is occupied).
    #[config(default = 16)]
    pub grid_update_interval: u64,
    /// Updates before this step refresh every cell, later ones a random quarter of the cells
    /// plus a quarter of the occupied ones (nerfacc: 256 steps; 64 here: a full refresh of
    /// 64³ cells costs several CPU steps, and CPU runs are short).
    #[config(default = 64)]
    pub grid_warmup_steps: u64,
    /// A cell is occupied when σ·step_size exceeds this, or the mean of σ·step_size when that
    /// is lower (nerfacc's `occ_thre`).
    #[config(default = 0.01)]
    pub grid_threshold: f32,
    /// Decay of a cell's running density per update (instant-ngp: 0.95).
    #[config(default = 0.95)]
    pub grid_decay: f32,
    /// Training rays stop once their transmittance, from a density-only pass over the marched
    /// samples, drops below this (instant-ngp: 1e-4); 0 trains on every marched sample.
    #[config(default = 1e-4)]
    pub train_min_transmittance: f32,
    /// Weight λ of mip-NeRF 360's distortion loss ([`volrend::distortion`], distances
    /// normalised by `far − near` as there), added to the colour MSE: it pulls each ray's weight
    /// into one short stretch, against fog and floaters. `None` or 0 (instant-ngp's recipe, and
    /// configs written before this option): off. mip-NeRF 360 uses 0.01; `--model auto` can turn
    /// it on for scenes whose surfaces are all opaque (off by default there, see
    /// [`crate::auto::AutoConfig::distortion_weight`]).
    #[config(default = "None")]
    pub distortion_weight: Option<f32>,
    /// Rays through mixed pixels get no distortion loss ([`crate::data::mixed_pixels`]: partial
    /// alpha, or surfaces hit in the pixel's 3 × 3 neighbourhood more than this many pixel
    /// footprints apart in depth). Such a pixel's colour blends surfaces at different depths
    /// (a wire and what lies behind it), which the one ray through its centre reproduces only
    /// with its weight split between them; the loss would pull that weight together and the
    /// blend apart. `None` (and configs written before this option): every ray gets the loss.
    #[config(default = "None")]
    pub distortion_mixed_footprints: Option<f32>,
    /// Precision of the networks' products in training: `None` or `"fp32"` (and configs
    /// written before this option): fp32 throughout; `"bf16"`: each product's inputs rounded
    /// to bf16 and summed in fp32, weights and everything else fp32 ([`HashMlp::with_bf16`];
    /// about twice the networks' rate, on CPUs with AVX512-BF16 only). Rendering and
    /// evaluation stay fp32.
    #[config(default = "None")]
    pub mlp_precision: Option<String>,
    /// Adam β₁ (instant-ngp 0.9).
    #[config(default = 0.9)]
    pub beta1: f32,
    /// Adam β₂ (instant-ngp 0.99).
    #[config(default = 0.99)]
    pub beta2: f32,
    /// Adam ε (instant-ngp 1e-15).
    #[config(default = 1e-15)]
    pub eps: f32,
}

impl FastConfig {
    /// Refuses values no model can be built or trained with (each message names the field):
    /// the hash grid's ranges ([`HashGridConfig::validate`]), SH degree 1..=4, network widths
    /// 1..=4096 and colour depth 1..=16, the occupancy grid 1..=1024 cells per axis, positive
    /// marching steps and sample caps, a positive update interval, a threshold ≥ 0, a decay in
    /// [0, 1], a stopping transmittance in [0, 1), a cone angle ≥ 0, and Adam's β in [0, 1) and
    /// ε > 0 (all finite).
    pub fn check(&self) -> Result<(), String> {
        let bad = |field: &str, rule: &str, value: &dyn std::fmt::Display| Err(format!("model.{field} must be {rule}, not {value}"));
        self.hash_config().validate().map_err(|e| format!("model: {e}"))?;
        if !(1..=4).contains(&self.sh_degree) {
            return bad("sh_degree", "1..=4 (spherical-harmonic bands of the view direction)", &self.sh_degree);
        }
        for (field, v) in [("density_width", self.density_width), ("color_width", self.color_width)] {
            if !(1..=4096).contains(&v) {
                return bad(field, "1..=4096", &v);
            }
        }
        if !(1..=16).contains(&self.color_depth) {
            return bad("color_depth", "1..=16", &self.color_depth);
        }
        if !(1..=1024).contains(&self.geo_features) {
            return bad("geo_features", "1..=1024", &self.geo_features);
        }
        if !(1..=1024).contains(&self.grid_resolution) {
            return bad("grid_resolution", "1..=1024", &self.grid_resolution);
        }
        if !(1..=1 << 20).contains(&self.steps_per_diagonal) {
            return bad("steps_per_diagonal", "1..=2^20", &self.steps_per_diagonal);
        }
        if !(1..=1 << 16).contains(&self.max_samples_per_ray) {
            return bad("max_samples_per_ray", "1..=65536", &self.max_samples_per_ray);
        }
        if self.grid_update_interval == 0 {
            return bad("grid_update_interval", "a positive number of steps", &0);
        }
        if !(self.grid_threshold.is_finite() && self.grid_threshold >= 0.0) {
            return bad("grid_threshold", "a finite number ≥ 0", &self.grid_threshold);
        }
        if !(0.0..=1.0).contains(&self.grid_decay) {
            return bad("grid_decay", "in [0, 1]", &self.grid_decay);
        }
        if !(0.0..1.0).contains(&self.train_min_transmittance) {
            return bad("train_min_transmittance", "in [0, 1)", &self.train_min_transmittance);
        }
        if let Some(a) = self.cone_angle
            && !(a.is_finite() && a >= 0.0)
        {
            return bad("cone_angle", "a finite angle ≥ 0", &a);
        }
        self.bf16_networks()?;
        check_adam("model", self.beta1, self.beta2, self.eps)?;
        if let Some(w) = self.distortion_weight
            && !(w.is_finite() && w >= 0.0)
        {
            return Err(format!("model.distortion_weight must be a finite number ≥ 0, not {w}"));
        }
        if let Some(k) = self.distortion_mixed_footprints
            && !(k.is_finite() && k > 0.0)
        {
            return Err(format!("model.distortion_mixed_footprints must be a positive number of pixel footprints, not {k}"));
        }
        Ok(())
    }

    /// Whether the networks train in bf16 ([`Self::mlp_precision`]); an unknown precision is
    /// an error naming the field. (Whether the CPU can is checked when the model is built.)
    pub fn bf16_networks(&self) -> Result<bool, String> {
        match self.mlp_precision.as_deref() {
            None | Some("fp32") => Ok(false),
            Some("bf16") => Ok(true),
            Some(other) => Err(format!("model.mlp_precision must be \"fp32\" or \"bf16\", not \"{other}\"")),
        }
    }

    pub(super) fn hash_config(&self) -> HashGridConfig {
        HashGridConfig {
            levels: self.levels,
            features_per_level: self.features_per_level,
            log2_table_size: self.log2_table_size,
            base_resolution: self.base_resolution,
            finest_resolution: self.finest_resolution,
        }
    }
    /// Width of the colour network's direction input: the SH coefficients, or 0 without view
    /// dependence.
    pub fn dir_dims(&self) -> usize {
        if self.is_view_dependent() { sh_output_dim(self.sh_degree) } else { 0 }
    }
    /// Whether the colour network sees the view direction ([`Self::view_dependent`]).
    pub fn is_view_dependent(&self) -> bool {
        self.view_dependent.unwrap_or(true)
    }
    pub(super) fn field_config(&self) -> HashFieldConfig {
        HashFieldConfig {
            encoding_dims: self.levels * self.features_per_level,
            dir_dims: self.dir_dims(),
            density_width: self.density_width,
            geo_features: self.geo_features,
            color_width: self.color_width,
            color_depth: self.color_depth,
        }
    }
}
