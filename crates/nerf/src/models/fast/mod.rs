//! The fast model (instant-ngp's recipe on the CPU): a multiresolution hash encoding
//! ([`crate::encoding::hashgrid`], sparse Adam), a tiny density network and a colour network on
//! spherical harmonics of the direction (parameters and Adam in burn, forward and backward
//! as fused Rust kernels, [`crate::mlp`]), an occupancy grid ([`crate::occupancy`]) that
//! skips empty space while marching with a constant step, and early ray termination at
//! inference (transmittance < 1e-4, [`volrend::CompositeOptions::INFERENCE`]).
//!
//! CPU-sized defaults (instant-ngp's in brackets): 16 levels × 2 features, 2^17 entries per
//! level [2^19] so that one level's table (1 MiB) stays in the core's cache, finest resolution
//! 512 over the bounding cube [2048 · scale] (enough for the 64–400 pixel images trained on a
//! CPU, and finer levels overfit the few views; `--model auto`, [`crate::auto`], derives it
//! from the cameras), 64-wide networks, a 64³ occupancy
//! grid over the scene box \[128³\] and a marching step of the cube's diagonal / 512 \[/ 1024\].
//! With `view_dependent` false the colour network gets no direction input (Lambertian scenes).
//! Training rays are compacted as in instant-ngp: a density-only pass finds where each ray
//! becomes opaque, and only the samples before it are trained on.

use super::ops::DensityActivation;
use super::base::{Model, ModelKind, NerfModel, RayGradients, RayGrads, RayOutputs, StepStats, StepTimings, TrainPreset, all_finite, expected_distance, load_adam, load_params, mse_and_grad, save_adam, save_params, squared_error_and_grad};
use crate::backend;
use crate::checkpoint::StateDict;
use crate::data::{Background, RayBatch, SceneBounds};
use crate::encoding::hashgrid::{Adam, AdamConfig, BackwardScratch, HashGrid};
use crate::encoding::sh::sh_encode;
use crate::field::{AdamSettings, HashField, MlpAdam};
use crate::kernels::{seeded_init, stream, stream_seed};
use crate::mlp::{GroupGrads, HashMlp};
use crate::occupancy::{MarchOptions, OccupancyBlocks, OccupancyGrid, OccupancyGridConfig};
use crate::sampling::{Aabb, RaySamples, SampleMode};
use crate::{supervision, volrend};
use burn::module::Module;
use rayon::prelude::*;
use std::time::Instant;

mod config;
#[cfg(test)]
mod tests;

pub use config::FastConfig;

/// The fast model's state.
#[derive(Debug)]
pub struct FastModel {
    /// Settings.
    pub config: FastConfig,
    /// Scene bounds (the hash grid covers their bounding cube, the occupancy grid their box).
    pub bounds: SceneBounds,
    /// The networks (on the training device).
    pub field: HashField,
    /// Hash tables.
    pub grid: HashGrid,
    /// Sparse Adam of the hash tables.
    pub grid_adam: Adam,
    /// burn's Adam of the networks.
    pub adam: MlpAdam,
    /// Occupancy grid over the scene box.
    pub occupancy: OccupancyGrid,
    /// The hash backward's per-thread gradient of one level ([`HashGrid::backward_adam`]).
    scratch: BackwardScratch,
    /// The occupancy grid's empty-space distances ([`OccupancyGrid::blocks`]) and the
    /// occupancy bits they were computed from: used by marching while the bits are unchanged.
    empty_space: Option<(Vec<u64>, OccupancyBlocks)>,
    /// Learning rate used by the next step (set by the trainer).
    pub lr: f64,
    /// Whether steps also return the loss's gradient with respect to the rays
    /// ([`NerfModel::set_ray_gradients`]).
    ray_gradients: RayGradients,
}

const ACT: DensityActivation = DensityActivation::TruncExp;

/// Samples evaluated per live ray and round at inference, between early-termination checks.
/// One: a trained surface stops most rays within a sample or two, so longer rounds evaluate
/// samples behind it (figures in `docs/fast-model.md`).
const INFERENCE_ROUND: usize = 1;
/// Samples per ray in the first two rounds of training's marching and compaction
/// ([`Parts::march_until_opaque`]); later rounds double. Late in training most rays turn
/// opaque within 4 to 8 samples, so doubling at once marches samples behind the surface
/// (figures in `docs/fast-model.md`).
const COMPACTION_FIRST_ROUND: usize = 4;

/// Groups of rays per thread in training's marching and compaction (more than one, so that a
/// thread whose groups finish early takes another's).
const COMPACTION_GROUPS_PER_THREAD: usize = 4;

/// One group's part of [`Parts::march_until_opaque`]: every sample it marched, in marching
/// order (round by round, so a ray's samples are spread over the rounds), and which it kept.
struct CompactionPiece {
    /// Samples kept per ray of the group (a prefix of each).
    kept: Vec<u32>,
    /// Per marched sample: its interval, its ray (index in the group), its unit-cube point,
    /// its encoding `[L·F]` and whether it is kept.
    t_start: Vec<f32>,
    t_end: Vec<f32>,
    ray_of: Vec<u32>,
    unit: Vec<[f32; 3]>,
    enc: Vec<f32>,
    keep: Vec<bool>,
    /// CPU seconds of marching (with the unit points), the hash encoding and the density pass.
    cpu_s: [f64; 3],
}

/// The kept samples of one [`CompactionPiece`], in ray order, written into its part of the
/// step's arrays (`t_start` … `enc`, which hold exactly its kept samples).
fn gather_kept(p: &CompactionPiece, dims: usize, t_start: &mut [f32], t_end: &mut [f32], unit: &mut [[f32; 3]], enc: &mut [f32]) {
    // Each ray's next slot.
    let mut at = Vec::with_capacity(p.kept.len());
    let mut n = 0usize;
    for &k in &p.kept {
        at.push(n);
        n += k as usize;
    }
    for (s, _) in p.keep.iter().enumerate().filter(|(_, k)| **k) {
        let c = p.ray_of[s] as usize;
        let j = at[c];
        at[c] += 1;
        (t_start[j], t_end[j], unit[j]) = (p.t_start[s], p.t_end[s], p.unit[s]);
        enc[j * dims..(j + 1) * dims].copy_from_slice(&p.enc[s * dims..(s + 1) * dims]);
    }
}

/// Weight below which a sample's colour is not evaluated at inference (it stays 0): a ray's
/// composited colour moves by at most the sum of the weights skipped, which is far below the
/// 1/255 of a display value (density and depth are always complete).
const COLOR_MIN_WEIGHT: f32 = 1e-5;

/// Rays per rayon task when rendering ([`FastModel::render_rays`]).
const RENDER_CHUNK: usize = 1024;

impl ModelKind for FastConfig {
    fn name(&self) -> &'static str {
        "fast"
    }

    fn check(&self) -> Result<(), String> {
        FastConfig::check(self)
    }

    /// [`FastModel::new`] checks the settings and bounds itself.
    fn init(&self, bounds: &SceneBounds, seed: u64) -> Result<Model, String> {
        Ok(Box::new(FastModel::new(self.clone(), bounds.clone(), seed)?))
    }

    /// Batched by samples, 2^15 per step (instant-ngp: 2^18 on a GPU; on 2 CPU cores more,
    /// smaller steps learn faster in minutes; the first step 256 rays), Adam 1e-2 → 1e-3 over
    /// 5k steps (CPU runs are short), and a random background behind transparent pixels
    /// (instant-ngp; without it the few-view CPU runs learn translucent objects).
    fn preset(&self) -> TrainPreset {
        TrainPreset { batch_rays: 256, batch_samples: Some(1 << 15), lr_init: 1e-2, lr_final: 1e-3, lr_decay_steps: 5_000, background: Background::Random }
    }

    /// The distortion loss, when on, leaves out mixed pixels of this many footprints.
    fn mixed_pixel_footprints(&self) -> Option<f64> {
        self.distortion_weight.filter(|w| *w > 0.0).and(self.distortion_mixed_footprints).map(|k| k as f64)
    }
}

impl FastModel {
    /// A new model with parameters keyed by `seed`.
    pub fn new(config: FastConfig, bounds: SceneBounds, seed: u64) -> Result<Self, String> {
        config.check()?;
        bounds.check()?;
        let device = backend::train_device();
        let field = seeded_init(config.field_config().init(&device), seed);
        let hash = config.hash_config();
        let grid = HashGrid::new(hash.clone(), stream_seed(seed, stream::INIT)).map_err(|e| e.to_string())?;
        let n = grid.params.len();
        let occupancy = OccupancyGrid::new(OccupancyGridConfig {
            aabb: Aabb { min: bounds.aabb_min, max: bounds.aabb_max },
            resolution: config.grid_resolution as u32,
            decay: config.grid_decay,
            warmup_steps: config.grid_warmup_steps,
            update_fraction: 0.25,
            seed: stream_seed(seed, stream::OCCUPANCY),
        });
        // The networks must have the fused kernels' shape (`mlp()` relies on it from here on).
        HashMlp::from_field(&field)?;
        if config.bf16_networks()? {
            HashMlp::bf16_supported()?;
        }
        let adam = MlpAdam::new(&AdamSettings::new(config.beta1, config.beta2, config.eps));
        let grid_adam = Adam::new(AdamConfig { lr: 1e-2, beta1: config.beta1, beta2: config.beta2, eps: config.eps }, n);
        Ok(Self {
            grid_adam,
            config,
            bounds,
            field,
            grid,
            adam,
            occupancy,
            scratch: BackwardScratch::new(),
            empty_space: None,
            lr: 1e-2,
            ray_gradients: RayGradients::Off,
        })
    }

    /// Marching step size: the bounding cube's diagonal / `steps_per_diagonal`.
    pub fn step_size(&self) -> f32 {
        self.parts().step_size()
    }

    /// The networks' current weights as plain vectors for the fused kernels ([`crate::mlp`]).
    fn mlp(&self) -> HashMlp {
        HashMlp::from_field(&self.field).expect("the fast model's networks have the fused kernels' shape (checked in new)")
    }

    /// The parts rendering and sampling read, shared across threads.
    fn parts(&self) -> Parts<'_> {
        let empty = self.empty_space.as_ref().filter(|(bits, _)| *bits == self.occupancy.bits).map(|e| &e.1);
        Parts { config: &self.config, bounds: &self.bounds, grid: &self.grid, occupancy: &self.occupancy, empty }
    }

    /// Recomputes the occupancy grid's empty-space distances if its bits changed since (a
    /// 32 KiB comparison for a 64³ grid).
    fn refresh_empty_space(&mut self) {
        if self.empty_space.as_ref().is_none_or(|(bits, _)| *bits != self.occupancy.bits) {
            self.empty_space = Some((self.occupancy.bits.clone(), self.occupancy.blocks()));
        }
    }

    fn march(&self, origins: &[[f32; 3]], dirs: &[[f32; 3]], jitter: SampleMode) -> RaySamples {
        self.parts().march(origins, dirs, jitter)
    }

    fn unit_points(&self, samples: &RaySamples, idx: Option<&[usize]>, origins: &[[f32; 3]], dirs: &[[f32; 3]]) -> Vec<[f32; 3]> {
        self.parts().unit_points(samples, idx, origins, dirs)
    }

    fn hash_encode(&self, unit: &[[f32; 3]]) -> Vec<f32> {
        self.parts().hash_encode(unit)
    }

    /// The loss's gradient with respect to each ray's origin and direction, through the
    /// sample points `x = o + t·d` (`t` the interval's midpoint, held fixed) and the hash
    /// encoding ([`HashGrid::point_gradient`]; `unit = (x − centre) / 2h + ½`). The view
    /// direction's own input (the colour network's spherical harmonics) is not
    /// differentiated: see [`crate::camera_opt`]. Each ray sums its samples in order.
    fn ray_gradients_of(&self, samples: &RaySamples, unit: &[[f32; 3]], d_enc: &[f32]) -> RayGrads {
        let g_unit = self.grid.point_gradient(unit, d_enc);
        let inv = 1.0 / (2.0 * self.bounds.half_extent().max(f32::MIN_POSITIVE));
        let n_rays = samples.n_rays();
        let (d_origins, d_dirs): (Vec<[f32; 3]>, Vec<[f32; 3]>) = (0..n_rays)
            .into_par_iter()
            .with_min_len(64)
            .map(|r| {
                let (mut go, mut gd) = ([0f32; 3], [0f32; 3]);
                for s in samples.offsets[r] as usize..samples.offsets[r + 1] as usize {
                    let t = 0.5 * (samples.t_start[s] + samples.t_end[s]);
                    for a in 0..3 {
                        let gx = g_unit[s][a] * inv;
                        go[a] += gx;
                        gd[a] += t * gx;
                    }
                }
                (go, gd)
            })
            .unzip();
        RayGrads { d_origins, d_dirs }
    }

    /// The normal term's rays and points ([`crate::supervision`]): per ray of `batch` with a
    /// depth and a normal target, its index and the unit-cube points one finest cell either
    /// side of its target surface point along each axis; rays whose points leave the unit cube
    /// are left out. Empty without the term.
    fn normal_points(&self, batch: &RayBatch) -> Vec<(usize, [[f32; 3]; 6])> {
        let Some(sup) = batch.supervision.as_ref().filter(|s| s.normal_weight > 0.0 && !s.normal.is_empty()) else { return Vec::new() };
        let h = 1.0 / self.config.finest_resolution.max(1) as f32;
        (0..batch.origins.len())
            .filter_map(|r| {
                let d = sup.depth[r];
                if !(d.is_finite() && d > 0.0 && sup.normal[r][0].is_finite()) {
                    return None;
                }
                let (o, dir) = (batch.origins[r], batch.dirs[r]);
                let c = self.bounds.to_unit([o[0] + d * dir[0], o[1] + d * dir[1], o[2] + d * dir[2]]);
                let pts: [[f32; 3]; 6] = std::array::from_fn(|i| {
                    let mut p = c;
                    p[i / 2] += if i % 2 == 0 { h } else { -h };
                    p
                });
                pts.iter().flatten().all(|x| (0.0..=1.0).contains(x)).then_some((r, pts))
            })
            .collect()
    }

    /// Updates the occupancy grid on update steps, with the networks' weights `mlp`.
    fn maybe_update_occupancy(&mut self, step: u64, mlp: &HashMlp) {
        let interval = self.config.grid_update_interval.max(1);
        if step == 0 || !step.is_multiple_of(interval) {
            return;
        }
        let dt = self.step_size();
        let (grid, bounds) = (&self.grid, &self.bounds);
        let thr = self.config.grid_threshold;
        self.occupancy.update(step, dt, thr, &mut |pts| density_at(grid, mlp, bounds, pts));
    }

    /// The same model without view dependence, for a run whose test found the scene's colour
    /// constant across views ([`crate::auto`]): the colour network's direction inputs are
    /// dropped and what it learned otherwise is kept. Its first layer sees `[geometry, SH]`;
    /// the SH band-0 input is the constant Y₀₀ for every direction, so its weights times Y₀₀
    /// fold into the bias, and bands ≥ 1 (which integrate to zero over the sphere) go, so the
    /// first layer computes its mean over all directions. Hash tables, density network, the
    /// rest of the colour network, the occupancy grid and all optimiser moments carry over
    /// (the first layer's moments for the rows it keeps). Already without view dependence:
    /// an unchanged copy.
    pub fn without_view_dependence(&self) -> Result<Self, String> {
        let c = &self.config;
        let mut cfg = c.clone();
        cfg.view_dependent = Some(false);
        let mut out = Self::new(cfg, self.bounds.clone(), 0)?;
        let mut s = self.state();
        if c.is_view_dependent() {
            // Parameter tensors in visiting order: the density network's, then the colour
            // network's first layer (weight [geo + dir, width] row-major, then bias).
            let wi = crate::kernels::param_vectors(&self.field.density).len();
            let (geo, width) = (c.geo_features, c.color_width);
            let y00 = crate::encoding::sh::sh_encode([0.0, 0.0, 1.0])[0];
            let key = |k: usize| format!("field.{k}");
            let w = s.arrays.get(&key(wi)).cloned().ok_or("the colour network has no first layer")?;
            let b = s.arrays.get(&key(wi + 1)).cloned().ok_or("the colour network's first layer has no bias")?;
            if w.len() != (geo + c.dir_dims()) * width || b.len() != width {
                return Err(format!("the colour network's first layer has {} weights, not ({geo} + {}) × {width}", w.len(), c.dir_dims()));
            }
            let band0 = &w[geo * width..(geo + 1) * width];
            let bias: Vec<f32> = b.iter().zip(band0).map(|(b, w0)| b + y00 * w0).collect();
            s.arrays.insert(key(wi), w[..geo * width].to_vec());
            s.arrays.insert(key(wi + 1), bias);
            for m in ["m1", "m2"] {
                if let Some(v) = s.arrays.get_mut(&format!("field_adam.{wi}.{m}")) {
                    v.truncate(geo * width);
                }
            }
        }
        out.load_state(&s)?;
        out.lr = self.lr;
        Ok(out)
    }

}


impl NerfModel for FastModel {
    /// One training step.
    fn train_step(&mut self, batch: &RayBatch, step: u64, seed: u64) -> StepStats {
        let mut tm = StepTimings::default();
        let t0 = Instant::now();
        // The networks' weights, read once for the step (they change only in its Adam step);
        // in bf16 where configured (the sweep's products; the density-only passes stay fp32).
        let mlp = self.mlp();
        let mlp = if self.config.bf16_networks().unwrap_or(false) { mlp.with_bf16().expect("bf16 support checked in new") } else { mlp };
        if self.ray_gradients != RayGradients::Only {
            self.maybe_update_occupancy(step, &mlp);
        }
        self.refresh_empty_space();
        tm.phases.occupancy = t0.elapsed().as_secs_f64();
        tm.optimizer += tm.phases.occupancy;

        let dims = self.grid.output_dim();
        let jitter = SampleMode::Random { seed: stream_seed(seed, stream::MARCH), step };
        // Compaction (instant-ngp, nerfacc): a density-only pass without gradients finds where
        // each ray's transmittance falls below `train_min_transmittance`; only the samples
        // before that are trained on. Marching, encoding and that pass go in rounds along the
        // rays ([`Parts::march_until_opaque`]), so samples behind that point are mostly never
        // marched or encoded.
        let (samples, mut unit, mut enc, n_marched) = if self.config.train_min_transmittance > 0.0 {
            let tau_stop = -self.config.train_min_transmittance.ln();
            self.parts().march_until_opaque(&mlp, &batch.origins, &batch.dirs, jitter, tau_stop, &mut tm)
        } else {
            let t0 = Instant::now();
            let marched = self.march(&batch.origins, &batch.dirs, jitter);
            let unit = self.unit_points(&marched, None, &batch.origins, &batch.dirs);
            tm.phases.march = t0.elapsed().as_secs_f64();
            let t1 = Instant::now();
            let enc = self.hash_encode(&unit);
            tm.phases.hash_forward = t1.elapsed().as_secs_f64();
            tm.encoding += t0.elapsed().as_secs_f64();
            let n = marched.len();
            (marched, unit, enc, n)
        };
        let t0 = Instant::now();
        let n = samples.len();
        let mut sh = self.parts().sh_for(&samples.ray_index, &batch.dirs);
        tm.phases.gather += t0.elapsed().as_secs_f64();
        tm.encoding += t0.elapsed().as_secs_f64();
        if n == 0 {
            // Nothing to learn from: every ray missed the occupied cells.
            let (mse, _) = mse_and_grad(&batch.background, &batch.target);
            return StepStats { loss: mse, mse, samples: 0, marched: n_marched, encoded: n_marched, skipped_nonfinite: false, timings: tm, ..Default::default() };
        }

        // Networks, compositing, loss and backward in one sweep over groups of whole rays
        // ([`HashMlp::train_groups_blocked`]): each group stays in cache from the networks'
        // forward to their backward, and leaves its encoding gradient level-major (blocks of
        // `F` columns), as the hash backward reads it. (Its time is counted as MLP time;
        // rendering is inside it.)
        let t0 = Instant::now();
        let groups = ray_groups(&samples.offsets, crate::mlp::TILE);
        let mut sample_ranges: Vec<std::ops::Range<usize>> = groups.iter().map(|g| g.1.clone()).collect();
        // The normal term's six points per ray ([`crate::supervision`]) follow the samples, in
        // groups of whole rays; their encoding gradient joins the samples' in the hash backward.
        let normal_rays = self.normal_points(batch);
        let per_group = (crate::mlp::TILE / 6).max(1);
        if !normal_rays.is_empty() {
            let t1 = Instant::now();
            let points: Vec<[f32; 3]> = normal_rays.iter().flat_map(|r| r.1).collect();
            enc.extend(self.hash_encode(&points));
            unit.extend(points);
            let rays_of: Vec<u32> = normal_rays.iter().flat_map(|r| [r.0 as u32; 6]).collect();
            sh.extend(self.parts().sh_for(&rays_of, &batch.dirs));
            for c in 0..normal_rays.len().div_ceil(per_group) {
                let (a, b) = (c * per_group, ((c + 1) * per_group).min(normal_rays.len()));
                sample_ranges.push(n + 6 * a..n + 6 * b);
            }
            tm.phases.hash_forward += t1.elapsed().as_secs_f64();
            tm.encoding += t1.elapsed().as_secs_f64();
        }
        let n_rays = samples.n_rays();
        let norm = (3 * n_rays).max(1) as f32;
        let lambda = self.config.distortion_weight.filter(|l| *l > 0.0 && l.is_finite());
        let scale = 1.0 / (self.bounds.far - self.bounds.near).max(1e-6);
        // CPU nanoseconds of the groups' compositing, loss and compositing backward.
        let composite_ns = std::sync::atomic::AtomicU64::new(0);
        let (d_enc, grads, parts) = mlp.train_groups_blocked(&enc, &sh, &sample_ranges, self.config.features_per_level, |gi, raw, rgb| {
            let tc = Instant::now();
            if gi >= groups.len() {
                let sup = batch.supervision.as_ref().expect("normal points come from supervision");
                let lw = sup.normal_weight as f64 / n_rays.max(1) as f64;
                let first = (gi - groups.len()) * per_group;
                let mut d_raw = vec![0.0; raw.len()];
                let mut value = 0.0;
                for (k, (raw6, d6)) in raw.chunks_exact(6).zip(d_raw.chunks_exact_mut(6)).enumerate() {
                    let sigma: [f32; 6] = std::array::from_fn(|i| ACT.forward(raw6[i]));
                    if let Some((l, ds)) = supervision::normal_loss_and_grads(&sigma, sup.normal[normal_rays[first + k].0], lw) {
                        value += l;
                        for i in 0..6 {
                            d6[i] = ACT.backward(raw6[i], ds[i]);
                        }
                    }
                }
                return GroupGrads { d_raw, d_rgb: vec![[0.0; 3]; rgb.len()], value: (0.0, 0.0, value) };
            }
            let (rays, smp) = (groups[gi].0.clone(), groups[gi].1.clone());
            let base = samples.offsets[rays.start];
            let o: Vec<u32> = samples.offsets[rays.start..=rays.end].iter().map(|v| v - base).collect();
            let (ts, te) = (&samples.t_start[smp.clone()], &samples.t_end[smp]);
            let (bg, target) = (&batch.background[rays.clone()], &batch.target[rays.clone()]);
            let sigma: Vec<f32> = raw.iter().map(|x| ACT.forward(*x)).collect();
            let inputs = volrend::CompositeInputs { offsets: &o, sigma: &sigma, rgb, t_start: ts, t_end: te, background: bg };
            let comp = volrend::composite_forward(&inputs);
            // Squared error summed over the group; the gradient of the batch's mean.
            let (sq, d_out) = squared_error_and_grad(&comp.rgb, target, norm);
            let (dist, d_weights) = match lambda {
                Some(l) => {
                    // Mixed pixels' rays ([`RayBatch::mixed`]) are left out of the loss.
                    let d_loss: Vec<f32> = rays.clone().map(|r| if batch.mixed.get(r).copied().unwrap_or(false) { 0.0 } else { l / n_rays.max(1) as f32 }).collect();
                    let (per_ray, dw) = volrend::distortion(&o, &comp.weights, ts, te, scale, &d_loss);
                    (per_ray.iter().zip(&d_loss).filter(|(_, d)| **d > 0.0).map(|(&v, _)| v as f64).sum::<f64>(), Some(dw))
                }
                None => (0.0, None),
            };
            let zeros = vec![0.0; rays.len()];
            let g = match &batch.supervision {
                None => volrend::composite_backward(&inputs, &comp, &volrend::OutputGrads { d_rgb: &d_out, d_opacity: &zeros, d_distance: &zeros, d_weights: d_weights.as_deref() }),
                Some(sup) => {
                    // The depth and empty-space terms ([`crate::supervision`]) through the same backward.
                    let mut sg = supervision::loss_and_grads(sup, rays.start, n_rays, &o, ts, te, &comp);
                    if let Some(dw) = &d_weights {
                        sg.d_weights.iter_mut().zip(dw).for_each(|(a, b)| *a += b);
                    }
                    let g = volrend::composite_backward(&inputs, &comp, &volrend::OutputGrads { d_rgb: &d_out, d_opacity: &sg.d_opacity, d_distance: &sg.d_distance, d_weights: Some(&sg.d_weights) });
                    let d_raw = g.d_sigma.iter().zip(raw).map(|(g, x)| ACT.backward(*x, *g)).collect();
                    composite_ns.fetch_add(tc.elapsed().as_nanos() as u64, std::sync::atomic::Ordering::Relaxed);
                    return GroupGrads { d_raw, d_rgb: g.d_rgb, value: (sq, dist, sg.loss) };
                }
            };
            let d_raw = g.d_sigma.iter().zip(raw).map(|(g, x)| ACT.backward(*x, *g)).collect();
            composite_ns.fetch_add(tc.elapsed().as_nanos() as u64, std::sync::atomic::Ordering::Relaxed);
            GroupGrads { d_raw, d_rgb: g.d_rgb, value: (sq, dist, 0.0) }
        });
        tm.phases.composite_cpu = composite_ns.into_inner() as f64 * 1e-9;
        let mse = (parts.iter().map(|p| p.0).sum::<f64>() / norm as f64) as f32;
        let loss = match lambda {
            Some(l) => mse + l * (parts.iter().map(|p| p.1).sum::<f64>() / n_rays.max(1) as f64) as f32,
            None => mse,
        };
        let loss = if batch.supervision.is_some() { loss + parts.iter().map(|p| p.2).sum::<f64>() as f32 } else { loss };
        tm.phases.mlp_sweep = t0.elapsed().as_secs_f64();
        tm.mlp += tm.phases.mlp_sweep;
        let stats = |skipped, tm, touched| StepStats { loss, mse, samples: n, marched: n_marched, encoded: n_marched, touched, skipped_nonfinite: skipped, timings: tm, ray_grads: None };
        if !loss.is_finite() || d_enc.len() != unit.len() * dims || !d_enc.par_chunks(1 << 16).all(all_finite) || !grads.is_finite() {
            return stats(true, tm, 0);
        }
        // The rays' gradients, from the tables before this step's update (through the
        // samples; the normal term's points are left out).
        let t0 = Instant::now();
        let ray_grads = (self.ray_gradients != RayGradients::Off).then(|| self.ray_gradients_of(&samples, &unit[..n], &d_enc[..n * dims]));
        // (Counted with the hash backward: it is the encoding's gradient for the points.)
        tm.phases.hash_backward += t0.elapsed().as_secs_f64();
        tm.encoding += t0.elapsed().as_secs_f64();
        if self.ray_gradients == RayGradients::Only {
            return StepStats { ray_grads, ..stats(false, tm, 0) };
        }
        let mut gp = grads.into_params(&self.field);

        // The hash tables' backward and their sparse Adam, fused per level (independent of the
        // networks' Adam, which follows).
        let hb = self.grid.backward_adam(&unit, &d_enc, &mut self.grid_adam, self.lr as f32, &mut self.scratch);
        tm.phases.hash_backward += hb.backward_seconds;
        tm.encoding += hb.backward_seconds;
        tm.phases.adam_hash = hb.adam_seconds;
        tm.optimizer += hb.adam_seconds;
        let touched = hb.updated;

        let t0 = Instant::now();
        self.field = self.adam.step(self.lr, self.field.clone(), &mut gp);
        tm.phases.adam_mlp = t0.elapsed().as_secs_f64();
        tm.optimizer += t0.elapsed().as_secs_f64();
        StepStats { ray_grads, ..stats(false, tm, touched) }
    }

    fn set_ray_gradients(&mut self, mode: RayGradients) -> Result<(), String> {
        self.ray_gradients = mode;
        Ok(())
    }

    fn set_lr(&mut self, lr: f64) {
        self.lr = lr;
    }

    /// Renders rays: marches the occupancy grid (no jitter), evaluates the density network in
    /// rounds of `INFERENCE_ROUND` samples per ray that is still live (transmittance ≥ 1e-4
    /// and samples left) and the colour network only for samples whose weight reaches
    /// `COLOR_MIN_WEIGHT`, then composites with [`volrend::CompositeOptions::INFERENCE`];
    /// samples never evaluated lie past the termination point and get weight 0.
    ///
    /// Rays go in chunks of `RENDER_CHUNK`, one rayon task each (a chunk's result does not
    /// depend on the others or on the thread count, so the output is bit-identical for any
    /// pool), which keeps every buffer small and both cores busy (before, 8192-ray chunks in
    /// turn, each marched in full and evaluated in rounds of 16: 5.9 s for an 800×800 view,
    /// mostly one core, much of it zeroing freshly allocated pages).
    fn render_rays(&self, origins: &[[f32; 3]], dirs: &[[f32; 3]], background: [f32; 3]) -> RayOutputs {
        self.parts().render_rays(&self.mlp(), origins, dirs, background)
    }

    /// Density at world points (inference).
    fn density(&self, points: &[[f32; 3]]) -> Vec<f32> {
        let mlp = self.mlp();
        points.chunks(65536).flat_map(|c| density_at(&self.grid, &mlp, &self.bounds, c)).collect()
    }

    /// Density and display colour at world points, each seen along its unit direction
    /// (inference; what a sample at that point of a ray with that direction evaluates to).
    ///
    /// # Shapes
    /// `points`, `dirs`: n; returns n densities and n colours.
    fn query(&self, points: &[[f32; 3]], dirs: &[[f32; 3]]) -> (Vec<f32>, Vec<[f32; 3]>) {
        let mlp = self.mlp();
        let shd = self.config.dir_dims();
        let (mut sigma, mut rgb) = (Vec::with_capacity(points.len()), Vec::with_capacity(points.len()));
        for (p, d) in points.chunks(65536).zip(dirs.chunks(65536)) {
            let unit: Vec<[f32; 3]> = p.iter().map(|p| self.bounds.to_unit(*p)).collect();
            let enc = self.hash_encode(&unit);
            let sh: Vec<f32> = if shd == 0 { Vec::new() } else { d.iter().flat_map(|d| sh_encode(*d)[..shd].to_vec()).collect() };
            let (raw, c) = mlp.forward(&enc, &sh);
            sigma.extend(raw.into_iter().map(|x| ACT.forward(x)));
            rgb.extend(c);
        }
        (sigma, rgb)
    }

    fn bounds(&self) -> &SceneBounds {
        &self.bounds
    }

    /// A cell is empty when its running density (the decayed maximum of the densities sampled
    /// in it) times the marching step is at most the grid threshold.
    fn occupancy(&self) -> Option<(&OccupancyGrid, f32)> {
        Some((&self.occupancy, self.config.grid_threshold / self.step_size()))
    }

    /// Trainable parameters: hash tables plus networks.
    fn parameters(&self) -> usize {
        self.grid.params.len() + self.field.num_params()
    }

    /// The full state for a checkpoint.
    fn state(&self) -> StateDict {
        let mut s = StateDict::default();
        save_params(&mut s, "field", &self.field);
        save_adam(&mut s, "field_adam", &self.adam);
        s.arrays.insert("grid.params".into(), self.grid.params.clone());
        s.arrays.insert("grid_adam.m".into(), self.grid_adam.m.clone());
        s.arrays.insert("grid_adam.v".into(), self.grid_adam.v.clone());
        s.scalars.insert("grid_adam.step".into(), self.grid_adam.step as f64);
        s.arrays.insert("occupancy.density".into(), self.occupancy.density.clone());
        let occupied = (0..self.occupancy.n_cells()).map(|i| ((self.occupancy.bits[i / 64] >> (i % 64)) & 1) as f32).collect();
        s.arrays.insert("occupancy.occupied".into(), occupied);
        s
    }

    /// Restores [`Self::state`].
    fn load_state(&mut self, s: &StateDict) -> Result<(), String> {
        self.field = load_params(s, "field", self.field.clone())?;
        let n = crate::kernels::param_vectors(&self.field).len();
        load_adam(s, "field_adam", &mut self.adam, n);
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
        self.grid_adam.step = s.count("grid_adam.step")?;
        let cells = self.occupancy.n_cells();
        self.occupancy.density = get("occupancy.density", cells)?;
        let occupied = get("occupancy.occupied", cells)?;
        self.occupancy.bits.iter_mut().for_each(|w| *w = 0);
        for (i, v) in occupied.iter().enumerate() {
            if *v > 0.5 {
                self.occupancy.bits[i / 64] |= 1 << (i % 64);
            }
        }
        self.refresh_empty_space();
        Ok(())
    }

    /// Forward multiply-adds per sample in the networks.
    fn macs_per_sample(&self) -> f64 {
        let c = &self.config;
        let enc = (c.levels * c.features_per_level) as f64;
        let dens = enc * c.density_width as f64 + c.density_width as f64 * c.geo_features as f64;
        let cin = (c.geo_features + c.dir_dims()) as f64;
        let col = cin * c.color_width as f64
            + (c.color_depth.saturating_sub(1)) as f64 * (c.color_width * c.color_width) as f64
            + c.color_width as f64 * 3.0;
        dens + col
    }
}

/// Points per rayon task of [`density_at`]: their encodings (128 KiB at 16 levels × 2
/// features) stay in the core's cache from the hash lookups to the density network.
const DENSITY_CHUNK: usize = 1024;

/// σ at world points: hash encoding, the density network's first output, [`ACT`]. Chunks of
/// [`DENSITY_CHUNK`] points go through both on one thread each ([`HashGrid::encode_serial`],
/// [`HashMlp::raw_density_serial`]: the values of the parallel kernels, which do not depend
/// on how points are split), so no pass writes every point's encoding out of cache.
fn density_at(grid: &HashGrid, mlp: &HashMlp, bounds: &SceneBounds, points: &[[f32; 3]]) -> Vec<f32> {
    let dims = grid.output_dim();
    let mut sigma = vec![0.0; points.len()];
    sigma.par_chunks_mut(DENSITY_CHUNK).zip(points.par_chunks(DENSITY_CHUNK)).for_each(|(sigma, points)| {
        let unit: Vec<[f32; 3]> = points.iter().map(|p| bounds.to_unit(*p)).collect();
        let mut enc = vec![0.0; unit.len() * dims];
        grid.encode_serial(&unit, &mut enc);
        let mut raw = Vec::with_capacity(unit.len());
        mlp.raw_density_serial(&enc, &mut raw);
        sigma.iter_mut().zip(raw).for_each(|(s, x)| *s = ACT.forward(x));
    });
    sigma
}

/// Consecutive rays grouped so that each group holds about `target` samples: a group closes
/// once it reaches `target` (a ray is never split; one longer than `target` is a group of its
/// own). Returns each group's rays and samples. Depends only on `offsets`, never on threads.
fn ray_groups(offsets: &[u32], target: usize) -> Vec<(std::ops::Range<usize>, std::ops::Range<usize>)> {
    let mut out = Vec::new();
    let n_rays = offsets.len().saturating_sub(1);
    let mut r0 = 0;
    for r in 0..n_rays {
        if (offsets[r + 1] - offsets[r0]) as usize >= target || r + 1 == n_rays {
            out.push((r0..r + 1, offsets[r0] as usize..offsets[r + 1] as usize));
            r0 = r + 1;
        }
    }
    out
}

/// The samples of each ray up to (and including) the one at which the optical depth
/// `Σ σ_j δ_j` before it still is ≤ `tau_stop` (transmittance ≥ e^−tau_stop): a prefix of
/// every ray. Returns the kept samples and their indices in `s`.
// The sample index `i` addresses three parallel arrays and is also what is kept.
#[cfg(test)]
#[allow(clippy::needless_range_loop)]
fn keep_until_opaque(s: &RaySamples, sigma: &[f32], tau_stop: f32) -> (RaySamples, Vec<usize>) {
    let mut out = RaySamples::with_rays(s.n_rays());
    let mut idx = Vec::with_capacity(s.len());
    for r in 0..s.n_rays() {
        let mut tau = 0.0f32;
        for i in s.offsets[r] as usize..s.offsets[r + 1] as usize {
            if tau > tau_stop {
                break;
            }
            out.push(s.t_start[i], s.t_end[i]);
            idx.push(i);
            tau += sigma[i] * (s.t_end[i] - s.t_start[i]);
        }
        out.end_ray();
    }
    (out, idx)
}


/// The parts of a [`FastModel`] that sampling and rendering read (no burn tensors, so they are
/// shared by the rayon tasks of [`FastModel::render_rays`]).
struct Parts<'a> {
    config: &'a FastConfig,
    bounds: &'a SceneBounds,
    grid: &'a HashGrid,
    occupancy: &'a OccupancyGrid,
    /// The occupancy grid's [`OccupancyGrid::blocks`], when computed for its current bits.
    empty: Option<&'a OccupancyBlocks>,
}

impl Parts<'_> {
    /// Marching and compaction by rounds: marches each ray's intervals in order, a round at a
    /// time (first [`COMPACTION_FIRST_ROUND`] intervals of every ray, as many again for the
    /// rays still live, then twice as many per round), encodes them and evaluates their density, and stops a ray
    /// once the optical depth before its next sample exceeds `tau_stop`. Returns the kept
    /// samples (a prefix of every ray: exactly those [`keep_until_opaque`] keeps from a density
    /// pass over every sample [`OccupancyGrid::march`] gives, since [`OccupancyGrid::march_more`]
    /// resumed in pieces gives the same intervals and a sample's encoding and density do not
    /// depend on which others are evaluated with it), their unit-cube points, their
    /// encodings, and the number of samples marched (and encoded). Behind a ray's stopping
    /// point, samples are marched and encoded only as far as its last round reached: late in
    /// training, when rays turn opaque within a few samples of the surface, that spares half
    /// or more of them.
    ///
    /// Groups of consecutive rays (about [`COMPACTION_GROUPS_PER_THREAD`] per thread) run in
    /// parallel, each its rounds on one thread ([`HashGrid::encode_serial`],
    /// [`HashMlp::raw_density_serial`]): small rounds through the parallel kernels paid a fork
    /// and join per level and round and left a core idle on uneven splits. The result does not
    /// depend on the grouping.
    fn march_until_opaque(&self, mlp: &HashMlp, origins: &[[f32; 3]], dirs: &[[f32; 3]], jitter: SampleMode, tau_stop: f32, tm: &mut StepTimings) -> (RaySamples, Vec<[f32; 3]>, Vec<f32>, usize) {
        let t_all = Instant::now();
        let dims = self.grid.output_dim();
        let n_rays = origins.len();
        let opt = self.march_options(jitter);
        let groups = (COMPACTION_GROUPS_PER_THREAD * rayon::current_num_threads().max(1)).min(n_rays.max(1));
        let per = n_rays.div_ceil(groups).max(1);
        let ranges: Vec<std::ops::Range<usize>> = (0..n_rays).step_by(per).map(|a| a..(a + per).min(n_rays)).collect();
        let pieces: Vec<CompactionPiece> = ranges.par_iter().map(|rays| self.compact_group(mlp, rays.clone(), origins, dirs, &opt, tau_stop)).collect();
        // The groups' wall time, split over the phases in proportion to their CPU time.
        let wall = t_all.elapsed().as_secs_f64();
        let mut cpu = [0.0f64; 3];
        pieces.iter().for_each(|p| cpu.iter_mut().zip(&p.cpu_s).for_each(|(a, b)| *a += b));
        let total: f64 = cpu.iter().sum();
        let share = |x: f64| if total > 0.0 { wall * x / total } else { 0.0 };
        tm.phases.march += share(cpu[0]);
        tm.phases.hash_forward += share(cpu[1]);
        tm.phases.density_pass += share(cpu[2]);
        tm.encoding += share(cpu[0] + cpu[1]);
        tm.mlp += share(cpu[2]);

        // The kept samples in ray order: offsets and ray indices here, the rest gathered by
        // each piece straight into its part of the step's arrays, the pieces in parallel.
        let t0 = Instant::now();
        let mut kept = RaySamples::with_rays(n_rays);
        for (p, rays) in pieces.iter().zip(&ranges) {
            for (r, &k) in rays.clone().zip(&p.kept) {
                kept.ray_index.extend(std::iter::repeat_n(r as u32, k as usize));
                kept.offsets.push(kept.ray_index.len() as u32);
            }
        }
        let n_kept = kept.ray_index.len();
        kept.t_start = vec![0.0; n_kept];
        kept.t_end = vec![0.0; n_kept];
        let (mut unit, mut enc) = (vec![[0.0f32; 3]; n_kept], vec![0.0f32; n_kept * dims]);
        let marched = pieces.iter().map(|p| p.t_start.len()).sum();
        {
            // Each piece's part of every array.
            let mut parts = Vec::with_capacity(pieces.len());
            let (mut ts, mut te, mut un, mut en) = (&mut kept.t_start[..], &mut kept.t_end[..], &mut unit[..], &mut enc[..]);
            for (p, rays) in pieces.iter().zip(&ranges) {
                let k = (kept.offsets[rays.end] - kept.offsets[rays.start]) as usize;
                let (a, b) = std::mem::take(&mut ts).split_at_mut(k);
                let (c, d) = std::mem::take(&mut te).split_at_mut(k);
                let (e, f) = std::mem::take(&mut un).split_at_mut(k);
                let (g, h) = std::mem::take(&mut en).split_at_mut(k * dims);
                parts.push((p, a, c, e, g));
                (ts, te, un, en) = (b, d, f, h);
            }
            parts.into_par_iter().for_each(|(p, a, c, e, g)| gather_kept(p, dims, a, c, e, g));
        }
        let gather = t0.elapsed().as_secs_f64();
        tm.phases.gather += gather;
        tm.encoding += gather;
        (kept, unit, enc, marched)
    }

    /// [`Self::march_until_opaque`] for the rays `rays`, on the calling thread.
    fn compact_group(&self, mlp: &HashMlp, rays: std::ops::Range<usize>, origins: &[[f32; 3]], dirs: &[[f32; 3]], opt: &MarchOptions, tau_stop: f32) -> CompactionPiece {
        let dims = self.grid.output_dim();
        let r0 = rays.start;
        let (near, far) = (self.bounds.near, self.bounds.far);
        let mut state: Vec<_> = rays.clone().map(|r| self.occupancy.march_start(r, origins[r], dirs[r], near, far, opt)).collect();
        // Per ray (local index): the optical depth before its next sample, samples kept.
        let mut tau = vec![0.0f32; rays.len()];
        let mut kept = vec![0u32; rays.len()];
        let mut live: Vec<usize> = (0..rays.len()).filter(|&c| !state[c].is_done()).collect();
        // Every marched sample, in marching order: interval, ray, point, encoding, kept or not.
        // Room for the first two rounds of every ray (later rounds grow the vectors).
        let cap = 2 * COMPACTION_FIRST_ROUND * rays.len();
        let (mut ts, mut te, mut ray_of, mut keep) = (Vec::<f32>::with_capacity(cap), Vec::<f32>::with_capacity(cap), Vec::<u32>::with_capacity(cap), Vec::<bool>::with_capacity(cap));
        let (mut unit_rows, mut enc_rows, mut raw) = (Vec::<[f32; 3]>::with_capacity(cap), Vec::<f32>::with_capacity(cap * dims), Vec::new());
        let mut spans = Vec::new();
        let mut cpu_s = [0.0f64; 3];
        let mut round = COMPACTION_FIRST_ROUND;
        let mut rounds = 0usize;
        while !live.is_empty() {
            let t0 = Instant::now();
            let base = ts.len();
            spans.clear();
            for &c in &live {
                let (o, d) = (origins[r0 + c], dirs[r0 + c]);
                let b = ts.len();
                let k = self.occupancy.march_more(&mut state[c], o, d, opt, self.empty, round, &mut ts, &mut te);
                ray_of.extend(std::iter::repeat_n(c as u32, k));
                unit_rows.extend((b..b + k).map(|s| self.unit_at(o, d, ts[s], te[s])));
                spans.push((c, b, b + k));
            }
            let t1 = Instant::now();
            enc_rows.resize(ts.len() * dims, 0.0);
            self.grid.encode_serial(&unit_rows[base..], &mut enc_rows[base * dims..]);
            let t2 = Instant::now();
            mlp.raw_density_serial(&enc_rows[base * dims..], &mut raw);
            // As `keep_until_opaque`: a sample is kept unless the optical depth before it
            // exceeds `tau_stop` (a NaN depth never does).
            for &(c, b, e) in &spans {
                let mut open = true;
                for s in b..e {
                    if tau[c] > tau_stop {
                        open = false;
                    }
                    keep.push(open);
                    if open {
                        kept[c] += 1;
                        tau[c] += ACT.forward(raw[s - base]) * (te[s] - ts[s]);
                    }
                }
            }
            // A ray goes on while it has intervals left and its next sample would be kept.
            let opaque = |t: f32| t > tau_stop;
            live.retain(|&c| !state[c].is_done() && !opaque(tau[c]));
            // The second round as long as the first, then doubling (see the constant).
            rounds += 1;
            if rounds >= 2 {
                round = round.saturating_mul(2);
            }
            let t3 = Instant::now();
            cpu_s[0] += (t1 - t0).as_secs_f64();
            cpu_s[1] += (t2 - t1).as_secs_f64();
            cpu_s[2] += (t3 - t2).as_secs_f64();
        }
        CompactionPiece { kept, t_start: ts, t_end: te, ray_of, unit: unit_rows, enc: enc_rows, keep, cpu_s }
    }

    fn step_size(&self) -> f32 {
        2.0 * self.bounds.half_extent() * 3f32.sqrt() / self.config.steps_per_diagonal.max(1) as f32
    }

    fn march_options(&self, jitter: SampleMode) -> MarchOptions {
        MarchOptions {
            step_size: self.step_size(),
            max_samples_per_ray: self.config.max_samples_per_ray,
            jitter,
            cone_angle: self.config.cone_angle.unwrap_or(0.0),
        }
    }

    fn march(&self, origins: &[[f32; 3]], dirs: &[[f32; 3]], jitter: SampleMode) -> RaySamples {
        let n = origins.len();
        let (near, far) = (vec![self.bounds.near; n], vec![self.bounds.far; n]);
        self.occupancy.march(origins, dirs, &near, &far, &self.march_options(jitter), self.empty)
    }

    /// The unit-cube point of sample `s` (at its interval's midpoint).
    fn unit_point(&self, samples: &RaySamples, s: usize, origins: &[[f32; 3]], dirs: &[[f32; 3]]) -> [f32; 3] {
        let r = samples.ray_index[s] as usize;
        self.unit_at(origins[r], dirs[r], samples.t_start[s], samples.t_end[s])
    }

    /// The unit-cube point of the interval `[t0, t1]` of the ray `o + t d`, at its midpoint.
    fn unit_at(&self, o: [f32; 3], d: [f32; 3], t0: f32, t1: f32) -> [f32; 3] {
        let t = 0.5 * t0 + 0.5 * t1;
        self.bounds.to_unit([o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]])
    }

    /// Unit-cube points of samples (all, or those listed in `idx`).
    fn unit_points(&self, samples: &RaySamples, idx: Option<&[usize]>, origins: &[[f32; 3]], dirs: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let point = |s: usize| self.unit_point(samples, s, origins, dirs);
        match idx {
            Some(ix) => ix.iter().map(|&s| point(s)).collect(),
            None => (0..samples.len()).map(point).collect(),
        }
    }

    /// Hash encoding `[n][L·F]` of unit points.
    fn hash_encode(&self, unit: &[[f32; 3]]) -> Vec<f32> {
        let mut enc = vec![0.0; unit.len() * self.grid.output_dim()];
        self.grid.encode(unit, &mut enc);
        enc
    }

    /// The direction inputs (SH of each ray's direction, `[n][dir_dims]`, empty without view
    /// dependence) of the samples of rays `ray_index`.
    fn sh_for(&self, ray_index: &[u32], dirs: &[[f32; 3]]) -> Vec<f32> {
        if self.config.dir_dims() == 0 {
            return Vec::new();
        }
        let per_ray: Vec<[f32; 16]> = dirs.iter().map(|d| sh_encode(*d)).collect();
        self.sh_rows(ray_index, &per_ray)
    }

    /// The direction inputs of the samples of rays `ray_of` (`[n][dir_dims]`, empty without
    /// view dependence) from each ray's SH vector `per_ray` (computed once per ray), copied in
    /// parallel chunks.
    fn sh_rows(&self, ray_of: &[u32], per_ray: &[[f32; 16]]) -> Vec<f32> {
        let shd = self.config.dir_dims();
        if shd == 0 {
            return Vec::new();
        }
        let mut sh = vec![0.0; ray_of.len() * shd];
        const CHUNK: usize = 4096;
        sh.par_chunks_mut(CHUNK * shd).zip(ray_of.par_chunks(CHUNK)).for_each(|(out, rays)| {
            for (o, &r) in out.chunks_exact_mut(shd).zip(rays) {
                o.copy_from_slice(&per_ray[r as usize][..shd]);
            }
        });
        sh
    }

    /// [`FastModel::render_rays`] with the networks' weights `mlp`.
    fn render_rays(&self, mlp: &HashMlp, origins: &[[f32; 3]], dirs: &[[f32; 3]], background: [f32; 3]) -> RayOutputs {
        let computed;
        let blocks = match self.empty {
            Some(b) => b,
            None => {
                computed = self.occupancy.blocks();
                &computed
            }
        };
        let outs: Vec<RayOutputs> = origins
            .par_chunks(RENDER_CHUNK)
            .zip(dirs.par_chunks(RENDER_CHUNK))
            // one encoding buffer per rayon job, reused by its chunks and rounds (a fresh
            // half-megabyte buffer per round spent ~7 % of rendering in page faults)
            .map_init(Vec::new, |enc, (o, d)| self.render_chunk(mlp, blocks, enc, o, d, background))
            .collect();
        RayOutputs::concat(outs)
    }

    /// [`FastModel::render_rays`] of one chunk of rays. Each ray is marched lazily: a round
    /// marches [`INFERENCE_ROUND`] more intervals of every ray still live (transmittance above
    /// the inference threshold and not past the box), evaluates them, and stops the ray once
    /// opaque, so intervals behind a surface are never generated. The evaluated samples are
    /// those of marching each ray whole and evaluating it in rounds (the march skips the
    /// empty space of the occupancy grid, [`OccupancyGrid::blocks`]).
    // Sample indices address several parallel arrays at once.
    #[allow(clippy::needless_range_loop)]
    #[allow(clippy::too_many_arguments)]
    fn render_chunk(&self, mlp: &HashMlp, blocks: &OccupancyBlocks, enc: &mut Vec<f32>, origins: &[[f32; 3]], dirs: &[[f32; 3]], background: [f32; 3]) -> RayOutputs {
        let rays = origins.len();
        let opt = self.march_options(SampleMode::Deterministic);
        let (near, far) = (self.bounds.near, self.bounds.far);
        let mut state: Vec<_> = (0..rays).map(|r| self.occupancy.march_start(r, origins[r], dirs[r], near, far, &opt)).collect();
        let mut tau = vec![0.0f32; rays];
        let tau_stop = -volrend::CompositeOptions::INFERENCE.min_transmittance.ln();
        let gd = mlp.geometry_dims();
        let per_ray_sh: Vec<[f32; 16]> = if self.config.dir_dims() == 0 { Vec::new() } else { dirs.iter().map(|d| sh_encode(*d)).collect() };
        // Every evaluated sample in evaluation order (a ray's samples in order along it).
        let (mut e_ray, mut e_t0, mut e_t1, mut e_sigma, mut e_rgb) = (Vec::<u32>::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let (mut ts, mut te, mut live) = (Vec::new(), Vec::new(), Vec::new());
        loop {
            ts.clear();
            te.clear();
            live.clear();
            for r in 0..rays {
                if tau[r] <= tau_stop && !state[r].is_done() {
                    let b = ts.len();
                    let k = self.occupancy.march_more(&mut state[r], origins[r], dirs[r], &opt, Some(blocks), INFERENCE_ROUND, &mut ts, &mut te);
                    if k > 0 {
                        live.push((r, b, b + k));
                    }
                }
            }
            if ts.is_empty() {
                break;
            }
            let mut unit = Vec::with_capacity(ts.len());
            for &(r, b, e) in &live {
                let (o, d) = (origins[r], dirs[r]);
                unit.extend((b..e).map(|s| self.unit_at(o, d, ts[s], te[s])));
            }
            let need = unit.len() * self.grid.output_dim();
            if enc.len() < need {
                enc.resize(need, 0.0);
            }
            self.grid.encode(&unit, &mut enc[..need]);
            let geo = mlp.geometry(&enc[..need]);
            let sigma: Vec<f32> = (0..ts.len()).map(|k| ACT.forward(geo[k * gd])).collect();
            // Colour only where it can show: a sample whose weight is below COLOR_MIN_WEIGHT
            // keeps colour 0 (the composite's colour moves by less than that weight).
            let mut shade = Vec::new();
            let mut shade_ray = Vec::new();
            for &(r, b, e) in &live {
                let mut acc = tau[r];
                for s in b..e {
                    let od = sigma[s] * (te[s] - ts[s]);
                    let w = (-acc).exp() * (1.0 - (-od).exp());
                    if w >= COLOR_MIN_WEIGHT {
                        shade.push(s);
                        shade_ray.push(r as u32);
                    }
                    acc += od;
                }
                tau[r] = acc;
            }
            let mut rgb = vec![[0.0f32; 3]; ts.len()];
            if !shade.is_empty() {
                let mut geo_s = Vec::with_capacity(shade.len() * gd);
                for &k in &shade {
                    geo_s.extend_from_slice(&geo[k * gd..(k + 1) * gd]);
                }
                let sh = self.sh_rows(&shade_ray, &per_ray_sh);
                for (&k, c) in shade.iter().zip(mlp.color_of(&geo_s, &sh)) {
                    rgb[k] = c;
                }
            }
            for &(r, b, e) in &live {
                e_ray.extend(std::iter::repeat_n(r as u32, e - b));
            }
            e_t0.extend_from_slice(&ts);
            e_t1.extend_from_slice(&te);
            e_sigma.extend_from_slice(&sigma);
            e_rgb.extend_from_slice(&rgb);
        }
        // Ray order (a stable counting sort keeps each ray's samples in order along it).
        let mut offsets = vec![0u32; rays + 1];
        for &r in &e_ray {
            offsets[r as usize + 1] += 1;
        }
        for r in 0..rays {
            offsets[r + 1] += offsets[r];
        }
        let n = e_ray.len();
        let mut at: Vec<usize> = offsets[..rays].iter().map(|&o| o as usize).collect();
        let (mut t_start, mut t_end, mut sigma, mut rgb) = (vec![0.0f32; n], vec![0.0f32; n], vec![0.0f32; n], vec![[0.0f32; 3]; n]);
        for k in 0..n {
            let r = e_ray[k] as usize;
            let s = at[r];
            at[r] += 1;
            (t_start[s], t_end[s], sigma[s], rgb[s]) = (e_t0[k], e_t1[k], e_sigma[k], e_rgb[k]);
        }
        let bg = vec![background; rays];
        let comp = volrend::composite_forward_with(&volrend::CompositeInputs { offsets: &offsets, sigma: &sigma, rgb: &rgb, t_start: &t_start, t_end: &t_end, background: &bg }, volrend::CompositeOptions::INFERENCE);
        let out_t = (0..n).map(|s| volrend::termination_distance(sigma[s], t_start[s], t_end[s])).collect();
        RayOutputs {
            distance: comp.distance.iter().zip(&comp.opacity).map(|(d, o)| expected_distance(*d, *o)).collect(),
            rgb: comp.rgb,
            opacity: comp.opacity,
            t: out_t,
            w: comp.weights,
            offsets,
        }
    }
}
