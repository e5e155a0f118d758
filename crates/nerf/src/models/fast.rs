//! The fast model (instant-ngp's recipe on the CPU): a multiresolution hash encoding (plain
//! Rust, hand-written backward, sparse Adam), a tiny density network and a colour network on
//! spherical harmonics of the direction (burn), an occupancy grid that skips empty space, and
//! early ray termination at inference (transmittance < 1e-4).

use super::ops::{self, DensityActivation, HashGrid, HashGridSettings, OccupancyGrid, RaySamples, SparseAdam};
use super::{RayOutputs, StepStats, StepTimings, all_finite, mse_and_grad};
use crate::backend;
use crate::checkpoint::StateDict;
use crate::data::{RayBatch, SceneBounds};
use crate::field::{AdamSettings, HashField, HashFieldConfig, MlpAdam, seeded_init, tensor2, to_vec};
use burn::config::Config;
use burn::module::Module;
use burn::optim::GradientsParams;
use burn::tensor::Device;
use std::time::Instant;

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
    #[config(default = 19)]
    pub log2_table_size: u32,
    /// Coarsest grid resolution over the bounding cube.
    #[config(default = 16)]
    pub base_resolution: u32,
    /// Finest grid resolution over the bounding cube (instant-ngp: 2048 × the scene's extent in
    /// units of its unit cube; 1024 suits the 64–400 pixel images used on the CPU).
    #[config(default = 1024)]
    pub finest_resolution: u32,
    /// Spherical-harmonics degree of the direction encoding (4 → 16 coefficients).
    #[config(default = 4)]
    pub sh_degree: usize,
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
    /// Marching steps along the bounding cube's diagonal (the step size is diagonal / this).
    #[config(default = 256)]
    pub steps_per_diagonal: usize,
    /// Most samples per ray.
    #[config(default = 256)]
    pub max_samples_per_ray: usize,
    /// Steps between occupancy-grid updates (instant-ngp: 16).
    #[config(default = 16)]
    pub grid_update_interval: u64,
    /// First step at which the grid is updated (before it every cell is occupied).
    #[config(default = 256)]
    pub grid_warmup_steps: u64,
    /// A cell is occupied when σ·step_size exceeds this (nerfacc's `occ_thre`).
    #[config(default = 0.01)]
    pub grid_threshold: f32,
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
    fn hash_settings(&self) -> HashGridSettings {
        HashGridSettings {
            levels: self.levels,
            features_per_level: self.features_per_level,
            log2_table_size: self.log2_table_size,
            base_resolution: self.base_resolution,
            finest_resolution: self.finest_resolution,
        }
    }
    fn field_config(&self) -> HashFieldConfig {
        HashFieldConfig::new(self.levels * self.features_per_level, ops::sh_dims(self.sh_degree))
            .with_density_width(self.density_width)
            .with_geo_features(self.geo_features)
            .with_color_width(self.color_width)
            .with_color_depth(self.color_depth)
    }
}

/// The fast model's state.
#[derive(Debug)]
pub struct FastModel {
    /// Settings.
    pub config: FastConfig,
    /// Scene bounds (the hash grid and occupancy grid cover their bounding cube).
    pub bounds: SceneBounds,
    /// The networks (on the training device).
    pub field: HashField,
    /// Hash tables.
    pub grid: HashGrid,
    /// Adam of the hash tables.
    pub grid_adam: SparseAdam,
    /// burn's Adam of the networks.
    pub adam: MlpAdam,
    /// Occupancy grid over the bounding cube.
    pub occupancy: OccupancyGrid,
    device: Device,
    grad: Vec<f32>,
    touched: Vec<bool>,
    /// Learning rate used by the next step (set by the trainer).
    pub lr: f64,
}

const ACT: DensityActivation = DensityActivation::TruncExp;

impl FastModel {
    /// A new model with parameters keyed by `seed`.
    pub fn new(config: FastConfig, bounds: SceneBounds, seed: u64) -> Self {
        let device = backend::train_device();
        let field = seeded_init(config.field_config().init(&device), seed);
        let grid = HashGrid::new(config.hash_settings(), seed);
        let n = grid.params.len();
        let entries: usize = grid.entries.iter().sum();
        let (lo, hi) = bounds.cube();
        let occupancy = OccupancyGrid::new(config.grid_resolution, lo, hi);
        let adam = MlpAdam::new(&AdamSettings::new(config.beta1, config.beta2, config.eps));
        Self {
            grid_adam: SparseAdam::new(n, config.beta1, config.beta2, config.eps),
            config,
            bounds,
            field,
            grid,
            adam,
            occupancy,
            device,
            grad: vec![0.0; n],
            touched: vec![false; entries],
            lr: 1e-2,
        }
    }

    /// Marching step size.
    pub fn step_size(&self) -> f32 {
        2.0 * self.bounds.half_extent() * 3f32.sqrt() / self.config.steps_per_diagonal as f32
    }

    fn encode(&self, samples: &RaySamples, origins: &[[f32; 3]], dirs: &[[f32; 3]]) -> (Vec<[f32; 3]>, Vec<f32>, Vec<f32>) {
        let unit: Vec<[f32; 3]> = samples.points(origins, dirs).into_iter().map(|p| self.bounds.to_unit(p)).collect();
        let mut enc = vec![0.0; unit.len() * self.grid.output_dims()];
        self.grid.encode(&unit, &mut enc);
        let shd = ops::sh_dims(self.config.sh_degree);
        let mut sh = vec![0.0; unit.len() * shd];
        for (s, d) in samples.sample_dirs(dirs).iter().enumerate() {
            ops::sh_encode(*d, self.config.sh_degree, &mut sh[s * shd..(s + 1) * shd]);
        }
        (unit, enc, sh)
    }

    fn maybe_update_occupancy(&mut self, step: u64, seed: u64) {
        let c = &self.config;
        if step == 0 || step < c.grid_warmup_steps || step % c.grid_update_interval.max(1) != 0 {
            return;
        }
        let pts = self.occupancy.update_points(seed, step);
        let sigma = self.density(&pts);
        let dt = self.step_size();
        self.occupancy.update(&sigma, dt, self.config.grid_threshold);
    }

    /// Density at world points (inference).
    pub fn density(&self, points: &[[f32; 3]]) -> Vec<f32> {
        let net = self.field.valid();
        let dev = backend::inference_device();
        let dims = self.grid.output_dims();
        let mut out = Vec::with_capacity(points.len());
        for chunk in points.chunks(65536) {
            let unit: Vec<[f32; 3]> = chunk.iter().map(|p| self.bounds.to_unit(*p)).collect();
            let mut enc = vec![0.0; unit.len() * dims];
            self.grid.encode(&unit, &mut enc);
            let geo = net.density.forward(tensor2(enc, unit.len(), dims, &dev));
            let [n, _] = geo.dims();
            let raw = to_vec(geo.slice([0..n, 0..1]));
            out.extend(raw.into_iter().map(|x| ACT.forward(x)));
        }
        out
    }

    /// One training step.
    pub fn train_step(&mut self, batch: &RayBatch, step: u64, seed: u64) -> StepStats {
        let mut tm = StepTimings::default();
        let t0 = Instant::now();
        self.maybe_update_occupancy(step, seed);
        tm.optimizer += t0.elapsed().as_secs_f64();

        let t0 = Instant::now();
        let samples = self.occupancy.march(
            &batch.origins,
            &batch.dirs,
            self.step_size(),
            self.config.max_samples_per_ray,
            Some((seed, step)),
            &batch.ids,
        );
        let n = samples.len();
        let (unit, enc, sh) = self.encode(&samples, &batch.origins, &batch.dirs);
        tm.encoding += t0.elapsed().as_secs_f64();
        if n == 0 {
            // Nothing to learn from: every ray missed the occupied cells.
            let (mse, _) = mse_and_grad(&batch.background, &batch.target);
            return StepStats { loss: mse, mse, samples: 0, skipped_nonfinite: false, timings: tm };
        }

        let t0 = Instant::now();
        let dims = self.grid.output_dims();
        let shd = ops::sh_dims(self.config.sh_degree);
        let enc_t = tensor2(enc, n, dims, &self.device).require_grad();
        let sh_t = tensor2(sh, n, shd, &self.device);
        let (raw_t, rgb_t) = self.field.forward(enc_t.clone(), sh_t);
        let raw = to_vec(raw_t.clone());
        let rgb_flat = to_vec(rgb_t.clone());
        tm.mlp += t0.elapsed().as_secs_f64();

        let t0 = Instant::now();
        let rgb: Vec<[f32; 3]> = rgb_flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let sigma: Vec<f32> = raw.iter().map(|x| ACT.forward(*x)).collect();
        let comp = ops::composite_forward(&samples, &sigma, &rgb, &batch.background);
        let (mse, d_out) = mse_and_grad(&comp.rgb, &batch.target);
        let (d_sigma, d_rgb) = ops::composite_backward(&samples, &sigma, &rgb, &batch.background, &comp.weights, &d_out);
        let d_raw: Vec<f32> = d_sigma.iter().zip(&raw).map(|(g, x)| g * ACT.derivative(*x)).collect();
        let d_rgb_flat: Vec<f32> = d_rgb.iter().flatten().copied().collect();
        tm.render += t0.elapsed().as_secs_f64();
        let stats = |skipped, tm| StepStats { loss: mse, mse, samples: n, skipped_nonfinite: skipped, timings: tm };
        if !mse.is_finite() || !all_finite(&d_raw) || !all_finite(&d_rgb_flat) {
            return stats(true, tm);
        }

        let t0 = Instant::now();
        let surrogate = (raw_t * tensor2(d_raw, n, 1, &self.device)).sum()
            + (rgb_t * tensor2(d_rgb_flat, n, 3, &self.device)).sum();
        let grads = surrogate.backward();
        let d_enc = enc_t.grad(&grads).map(to_vec).unwrap_or_default();
        let mut gp = GradientsParams::from_grads(grads, &self.field);
        tm.mlp += t0.elapsed().as_secs_f64();
        if d_enc.len() != n * dims || !all_finite(&d_enc) {
            return stats(true, tm);
        }

        let t0 = Instant::now();
        self.grad.fill(0.0);
        self.touched.fill(false);
        self.grid.backward(&unit, &d_enc, &mut self.grad, &mut self.touched);
        tm.encoding += t0.elapsed().as_secs_f64();

        let t0 = Instant::now();
        self.field = self.adam.step(self.lr, self.field.clone(), &mut gp);
        let f = self.config.features_per_level;
        self.grid_adam.step(self.lr as f32, &mut self.grid.params, &self.grad, &self.touched, f);
        tm.optimizer += t0.elapsed().as_secs_f64();
        stats(false, tm)
    }

    /// Renders rays: marches the occupancy grid, then evaluates samples in rounds of 32 per
    /// live ray, compositing front to back and stopping a ray once its transmittance drops
    /// below 1e-4.
    pub fn render_rays(&self, origins: &[[f32; 3]], dirs: &[[f32; 3]], background: [f32; 3]) -> RayOutputs {
        let ids: Vec<u64> = (0..origins.len() as u64).collect();
        let samples = self.occupancy.march(origins, dirs, self.step_size(), usize::MAX / 2, None, &ids);
        let net = self.field.valid();
        let dev = backend::inference_device();
        let rays = origins.len();
        let mut trans = vec![1.0f32; rays];
        let mut acc_rgb = vec![[0.0f32; 3]; rays];
        let mut acc_d = vec![0.0f32; rays];
        let mut next: Vec<usize> = (0..rays).map(|r| samples.offsets[r] as usize).collect();
        let mut weights = vec![f32::NAN; samples.len()];
        const ROUND: usize = 32;
        loop {
            let live: Vec<usize> =
                (0..rays).filter(|&r| trans[r] >= 1e-4 && next[r] < samples.offsets[r + 1] as usize).collect();
            if live.is_empty() {
                break;
            }
            let mut sub = RaySamples { offsets: vec![0], ..Default::default() };
            for &r in &live {
                let end = (next[r] + ROUND).min(samples.offsets[r + 1] as usize);
                for s in next[r]..end {
                    sub.t.push(samples.t[s]);
                    sub.t_start.push(samples.t_start[s]);
                    sub.t_end.push(samples.t_end[s]);
                }
                sub.offsets.push(sub.t.len() as u32);
            }
            let o: Vec<[f32; 3]> = live.iter().map(|&r| origins[r]).collect();
            let d: Vec<[f32; 3]> = live.iter().map(|&r| dirs[r]).collect();
            let (_, enc, sh) = self.encode(&sub, &o, &d);
            let n = sub.len();
            let (raw_t, rgb_t) = net.forward(
                tensor2(enc, n, self.grid.output_dims(), &dev),
                tensor2(sh, n, ops::sh_dims(self.config.sh_degree), &dev),
            );
            let raw = to_vec(raw_t);
            let rgb = to_vec(rgb_t);
            for (k, &r) in live.iter().enumerate() {
                for (j, s) in sub.range(k).enumerate() {
                    if trans[r] < 1e-4 {
                        break;
                    }
                    let sigma = ACT.forward(raw[s]);
                    let alpha = 1.0 - (-sigma * (sub.t_end[s] - sub.t_start[s])).exp();
                    let w = trans[r] * alpha;
                    for c in 0..3 {
                        acc_rgb[r][c] += w * rgb[3 * s + c];
                    }
                    acc_d[r] += w * sub.t[s];
                    trans[r] *= 1.0 - alpha;
                    weights[next[r] + j] = w;
                }
                next[r] = (next[r] + sub.range(k).len()).min(samples.offsets[r + 1] as usize);
            }
        }
        let mut out = RayOutputs { offsets: vec![0], ..Default::default() };
        for r in 0..rays {
            let o = 1.0 - trans[r];
            out.rgb.push([0, 1, 2].map(|c| acc_rgb[r][c] + trans[r] * background[c]));
            out.opacity.push(o);
            out.distance.push(if o > 1e-6 { acc_d[r] / o } else { 0.0 });
            for s in samples.range(r) {
                if weights[s].is_finite() {
                    out.t.push(samples.t[s]);
                    out.w.push(weights[s]);
                }
            }
            out.offsets.push(out.t.len() as u32);
        }
        out
    }

    /// Trainable parameters: hash tables plus networks.
    pub fn parameters(&self) -> usize {
        self.grid.params.len() + self.field.num_params()
    }

    /// Forward multiply-adds per sample in the networks.
    pub fn macs_per_sample(&self) -> f64 {
        let c = &self.config;
        let enc = (c.levels * c.features_per_level) as f64;
        let dens = enc * c.density_width as f64 + c.density_width as f64 * c.geo_features as f64;
        let cin = (c.geo_features + ops::sh_dims(c.sh_degree)) as f64;
        let col = cin * c.color_width as f64
            + (c.color_depth.saturating_sub(1)) as f64 * (c.color_width * c.color_width) as f64
            + c.color_width as f64 * 3.0;
        dens + col
    }

    /// The full state for a checkpoint.
    pub fn state(&self) -> StateDict {
        let mut s = StateDict::default();
        super::save_params(&mut s, "field", &self.field);
        super::save_adam(&mut s, "field_adam", &self.adam);
        s.arrays.insert("grid.params".into(), self.grid.params.clone());
        s.arrays.insert("grid_adam.m".into(), self.grid_adam.m.clone());
        s.arrays.insert("grid_adam.v".into(), self.grid_adam.v.clone());
        s.scalars.insert("grid_adam.step".into(), self.grid_adam.step as f64);
        s.arrays.insert("occupancy.density".into(), self.occupancy.density.clone());
        s.arrays.insert(
            "occupancy.occupied".into(),
            self.occupancy.occupied.iter().map(|o| if *o { 1.0 } else { 0.0 }).collect(),
        );
        s
    }

    /// Restores [`Self::state`].
    pub fn load_state(&mut self, s: &StateDict) -> Result<(), String> {
        self.field = super::load_params(s, "field", self.field.clone())?;
        let n = crate::field::param_vectors(&self.field).len();
        super::load_adam(s, "field_adam", &mut self.adam, n);
        let get = |k: &str, len: usize| -> Result<Vec<f32>, String> {
            let v = s.arrays.get(k).ok_or_else(|| format!("checkpoint lacks {k}"))?;
            if v.len() != len {
                return Err(format!("{k}: {} values, the model needs {len} (different config?)", v.len()));
            }
            Ok(v.clone())
        };
        let n = self.grid.params.len();
        self.grid.params = get("grid.params", n)?;
        self.grid_adam.m = get("grid_adam.m", n)?;
        self.grid_adam.v = get("grid_adam.v", n)?;
        self.grid_adam.step = s.scalar("grid_adam.step")? as u64;
        let cells = self.occupancy.density.len();
        self.occupancy.density = get("occupancy.density", cells)?;
        self.occupancy.occupied = get("occupancy.occupied", cells)?.iter().map(|v| *v > 0.5).collect();
        Ok(())
    }
}
