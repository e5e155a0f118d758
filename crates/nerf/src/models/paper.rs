//! The NeRF paper's model (Mildenhall et al. 2020): positional encoding (10 frequencies for
//! the position, 4 for the direction), an 8×256 ReLU MLP with the input re-injected at the
//! fifth layer, a density head (ReLU by default, softplus selectable) and a 128-wide
//! view-dependent colour branch; hierarchical sampling with 64 stratified coarse samples and
//! 128 importance samples, coarse and fine networks trained jointly on coarse + fine MSE.
//!
//! Positions are fed to γ normalised to [−1, 1] over the scene's bounding cube (the paper's
//! Blender scenes already lie in about [−1.5, 1.5]³; ours are in metres at any scale).
//! Near/far come from [`SceneBounds`] (scene facts, or the cameras plus an assumed radius).

use super::base::{Model, ModelKind, NerfModel, RayGradients, RayGrads, RayOutputs, StepStats, StepTimings, TrainPreset};
use super::base::{all_finite, check_adam, expected_distance, load_adam, load_params, mse_and_grad, save_adam, save_params};
use super::ops::{self, DensityActivation};
use crate::encoding::{frequency_encode, frequency_point_gradient};
use crate::sampling::{self, RaySamples, SampleMode};
use crate::volrend;
use crate::backend;
use crate::checkpoint::StateDict;
use crate::data::{Background, RayBatch, SceneBounds};
use crate::field::{AdamSettings, MlpAdam, NerfField, NerfFieldConfig};
use crate::kernels::{seeded_init, stream, stream_seed, tensor2, to_vec};
use burn::config::Config;
use burn::module::Module;
use burn::optim::GradientsParams;
use burn::tensor::{Device, Tensor};
use std::time::Instant;

/// Settings of the paper model.
#[derive(Config, Debug)]
pub struct PaperConfig {
    /// The network (both coarse and fine use it).
    #[config(default = "NerfFieldConfig::new()")]
    pub field: NerfFieldConfig,
    /// Stratified coarse samples per ray.
    #[config(default = 64)]
    pub coarse_samples: usize,
    /// Importance samples per ray added for the fine network.
    #[config(default = 128)]
    pub fine_samples: usize,
    /// Density activation: `relu` (the paper) or `softplus`.
    #[config(default = "DensityActivation::Relu")]
    pub density_activation: DensityActivation,
    /// Adam β₁.
    #[config(default = 0.9)]
    pub beta1: f32,
    /// Adam β₂.
    #[config(default = 0.999)]
    pub beta2: f32,
    /// Adam ε (the paper: 1e-7).
    #[config(default = 1e-7)]
    pub eps: f32,
}

impl PaperConfig {
    /// Refuses values no model can be built or trained with (each message names the field):
    /// at least one coarse sample, at most 2^16 samples of each kind, 0..=32 frequencies,
    /// network widths 1..=4096 and depth 1..=64, and Adam's β in [0, 1) and ε > 0.
    pub fn check(&self) -> Result<(), String> {
        let bad = |field: &str, rule: &str, value: usize| Err(format!("model.{field} must be {rule}, not {value}"));
        if !(1..=1 << 16).contains(&self.coarse_samples) {
            return bad("coarse_samples", "1..=65536", self.coarse_samples);
        }
        if self.fine_samples > 1 << 16 {
            return bad("fine_samples", "0..=65536", self.fine_samples);
        }
        let f = &self.field;
        for (field, v) in [("field.pos_freqs", f.pos_freqs), ("field.dir_freqs", f.dir_freqs)] {
            if v > 32 {
                return bad(field, "0..=32", v);
            }
        }
        for (field, v) in [("field.width", f.width), ("field.color_width", f.color_width)] {
            if !(1..=4096).contains(&v) {
                return bad(field, "1..=4096", v);
            }
        }
        if !(1..=64).contains(&f.depth) {
            return bad("field.depth", "1..=64", f.depth);
        }
        check_adam("model", self.beta1, self.beta2, self.eps)
    }
}

impl ModelKind for PaperConfig {
    fn name(&self) -> &'static str {
        "paper"
    }

    fn check(&self) -> Result<(), String> {
        PaperConfig::check(self)
    }

    /// The model's constructor cannot fail, so the settings and bounds are checked here.
    fn init(&self, bounds: &SceneBounds, seed: u64) -> Result<Model, String> {
        self.check()?;
        bounds.check()?;
        Ok(Box::new(PaperModel::new(self.clone(), bounds.clone(), seed)))
    }

    /// 1024 rays per step (4096 in the paper), Adam 5e-4 → 5e-5 over 200k steps.
    fn preset(&self) -> TrainPreset {
        TrainPreset { batch_rays: 1024, batch_samples: None, lr_init: 5e-4, lr_final: 5e-5, lr_decay_steps: 200_000, background: Background::White }
    }
}

/// Coarse and fine networks.
#[derive(Module, Debug)]
pub struct PaperNets {
    /// Evaluated on the stratified samples.
    pub coarse: NerfField,
    /// Evaluated on stratified + importance samples.
    pub fine: NerfField,
}

/// The paper model's state.
#[derive(Debug)]
pub struct PaperModel {
    /// Settings.
    pub config: PaperConfig,
    /// Scene bounds.
    pub bounds: SceneBounds,
    /// The networks (training device).
    pub nets: PaperNets,
    /// burn's Adam.
    pub adam: MlpAdam,
    device: Device,
    /// Learning rate of the next step (set by the trainer).
    pub lr: f64,
    /// Whether steps also return the rays' gradients ([`NerfModel::set_ray_gradients`]).
    ray_gradients: RayGradients,
}

struct Encoded {
    pos: Vec<f32>,
    dir: Vec<f32>,
}

/// Rays rendered at a time ([`NerfModel::render_rays`]).
const RENDER_CHUNK: usize = 1024;

impl PaperModel {
    /// A new model with parameters keyed by `seed`.
    pub fn new(config: PaperConfig, bounds: SceneBounds, seed: u64) -> Self {
        let device = backend::train_device();
        let nets = seeded_init(
            PaperNets { coarse: config.field.init(&device), fine: config.field.init(&device) },
            seed,
        );
        let adam = MlpAdam::new(&AdamSettings::new(config.beta1, config.beta2, config.eps));
        Self { config, bounds, nets, adam, device, lr: 5e-4, ray_gradients: RayGradients::Off }
    }

    fn encode(&self, s: &RaySamples, origins: &[[f32; 3]], dirs: &[[f32; 3]]) -> Encoded {
        let f = &self.config.field;
        let (pd, dd) = (f.pos_dims(), f.dir_dims());
        let (c, h) = (self.bounds.center(), self.bounds.half_extent());
        let pts: Vec<[f32; 3]> =
            s.positions(origins, dirs).into_iter().map(|p| [0, 1, 2].map(|i| (p[i] - c[i]) / h)).collect();
        let mut pos = vec![0.0; pts.len() * pd];
        frequency_encode(&pts, f.pos_freqs, &mut pos);
        let mut dir = vec![0.0; pts.len() * dd];
        frequency_encode(&ops::sample_dirs(&s.ray_index, dirs), f.dir_freqs, &mut dir);
        Encoded { pos, dir }
    }

    fn near_far(&self, n: usize) -> (Vec<f32>, Vec<f32>) {
        (vec![self.bounds.near; n], vec![self.bounds.far; n])
    }

    fn forward(&self, net: &NerfField, e: Encoded, n: usize, dev: &Device) -> (Tensor<2>, Tensor<2>) {
        self.forward_tracked(net, e, n, dev, false).0
    }

    /// [`Self::forward`], the position encoding tracked by autodiff when `track` (its handle
    /// returned, for the gradient with respect to the inputs).
    fn forward_tracked(&self, net: &NerfField, e: Encoded, n: usize, dev: &Device, track: bool) -> ((Tensor<2>, Tensor<2>), Option<Tensor<2>>) {
        let f = &self.config.field;
        let pos = tensor2(e.pos, n, f.pos_dims(), dev);
        let pos = if track { pos.require_grad() } else { pos };
        let handle = track.then(|| pos.clone());
        (net.forward(pos, tensor2(e.dir, n, f.dir_dims(), dev)), handle)
    }

    /// Adds the loss's gradient with respect to the rays through one network's sample points
    /// `x = o + t·d` (`t` the midpoint, fixed; the encoded point is `(x − c) / h`): `d_pos` is
    /// the gradient with respect to the position encoding. The direction encoding is not
    /// differentiated (see [`crate::camera_opt`]).
    fn add_ray_gradients(&self, s: &RaySamples, origins: &[[f32; 3]], dirs: &[[f32; 3]], d_pos: &[f32], g: &mut RayGrads) {
        let (c, h) = (self.bounds.center(), self.bounds.half_extent());
        let pts: Vec<[f32; 3]> = s.positions(origins, dirs).into_iter().map(|p| [0, 1, 2].map(|i| (p[i] - c[i]) / h)).collect();
        let gp = frequency_point_gradient(&pts, self.config.field.pos_freqs, d_pos);
        for (k, (&r, gp)) in s.ray_index.iter().zip(&gp).enumerate() {
            let t = 0.5 * (s.t_start[k] + s.t_end[k]);
            for a in 0..3 {
                let gx = gp[a] / h;
                g.d_origins[r as usize][a] += gx;
                g.d_dirs[r as usize][a] += t * gx;
            }
        }
    }

    /// Volume rendering of one network's outputs and the gradients of its MSE (plus the batch's
    /// supervision terms, when it has any) w.r.t. the raw outputs: (composite, mse, supervision
    /// loss, ∂L/∂raw density, ∂L/∂rgb flat).
    fn render_and_grad(
        &self,
        s: &RaySamples,
        raw: &[f32],
        rgb: &[f32],
        batch: &RayBatch,
    ) -> (volrend::CompositeOutput, f32, f32, Vec<f32>, Vec<f32>) {
        let act = self.config.density_activation;
        let sigma: Vec<f32> = raw.iter().map(|x| act.forward(*x)).collect();
        let rgb3 = ops::rgb3(rgb);
        let inputs = volrend::CompositeInputs { offsets: &s.offsets, sigma: &sigma, rgb: &rgb3, t_start: &s.t_start, t_end: &s.t_end, background: &batch.background };
        let comp = volrend::composite_forward(&inputs);
        let (mse, d_out) = mse_and_grad(&comp.rgb, &batch.target);
        let zeros = vec![0.0; d_out.len()];
        let (g, extra) = match &batch.supervision {
            None => (volrend::composite_backward(&inputs, &comp, &volrend::OutputGrads { d_rgb: &d_out, d_opacity: &zeros, d_distance: &zeros, d_weights: None }), 0.0),
            Some(sup) => {
                // The depth and empty-space terms ([`crate::supervision`]) through the same backward.
                let sg = crate::supervision::loss_and_grads(sup, 0, d_out.len(), &s.offsets, &s.t_start, &s.t_end, &comp);
                let g = volrend::composite_backward(&inputs, &comp, &volrend::OutputGrads { d_rgb: &d_out, d_opacity: &sg.d_opacity, d_distance: &sg.d_distance, d_weights: Some(&sg.d_weights) });
                (g, sg.loss as f32)
            }
        };
        let d_raw = g.d_sigma.iter().zip(raw).map(|(g, x)| act.backward(*x, *g)).collect();
        (comp, mse, extra, d_raw, g.d_rgb.into_iter().flatten().collect())
    }


    /// Renders rays: coarse samples at bin centres, importance samples at fixed quantiles, the
    /// fine network's result.
    fn render_chunk(&self, origins: &[[f32; 3]], dirs: &[[f32; 3]], background: [f32; 3]) -> RayOutputs {
        let act = self.config.density_activation;
        let nets = self.nets.valid();
        let dev = backend::inference_device();
        let rays = origins.len();
        let (near, far) = self.near_far(rays);
        let bg = vec![background; rays];
        let coarse = sampling::stratified(&near, &far, self.config.coarse_samples, SampleMode::Deterministic);
        let (raw, _) = self.forward(&nets.coarse, self.encode(&coarse, origins, dirs), coarse.len(), &dev);
        let sig: Vec<f32> = to_vec(raw).iter().map(|x| act.forward(*x)).collect();
        let zeros = vec![[0.0; 3]; coarse.len()];
        let comp_c = volrend::composite_forward(&volrend::CompositeInputs { offsets: &coarse.offsets, sigma: &sig, rgb: &zeros, t_start: &coarse.t_start, t_end: &coarse.t_end, background: &bg });
        let fine = sampling::sample_pdf(&coarse, &comp_c.weights, self.config.fine_samples, SampleMode::Deterministic);
        let (raw, rgb) = self.forward(&nets.fine, self.encode(&fine, origins, dirs), fine.len(), &dev);
        let sig: Vec<f32> = to_vec(raw).iter().map(|x| act.forward(*x)).collect();
        let rgb = ops::rgb3(&to_vec(rgb));
        let comp = volrend::composite_forward(&volrend::CompositeInputs { offsets: &fine.offsets, sigma: &sig, rgb: &rgb, t_start: &fine.t_start, t_end: &fine.t_end, background: &bg });
        let distance = comp.distance.iter().zip(&comp.opacity).map(|(d, o)| expected_distance(*d, *o)).collect();
        let t = sig.iter().zip(fine.t_start.iter().zip(&fine.t_end)).map(|(s, (a, b))| volrend::termination_distance(*s, *a, *b)).collect();
        RayOutputs { rgb: comp.rgb, opacity: comp.opacity, distance, t, offsets: fine.offsets, w: comp.weights }
    }
}


impl NerfModel for PaperModel {
    /// One training step.
    fn train_step(&mut self, batch: &RayBatch, step: u64, seed: u64) -> StepStats {
        let mut tm = StepTimings::default();
        let rays = batch.origins.len();
        let (near, far) = self.near_far(rays);

        let t0 = Instant::now();
        let strat = SampleMode::Random { seed: stream_seed(seed, stream::STRATIFIED), step };
        let coarse = sampling::stratified(&near, &far, self.config.coarse_samples, strat);
        let ec = self.encode(&coarse, &batch.origins, &batch.dirs);
        tm.encoding += t0.elapsed().as_secs_f64();

        let t0 = Instant::now();
        let nc = coarse.len();
        let track = self.ray_gradients != RayGradients::Off;
        let ((raw_c_t, rgb_c_t), pos_c) = self.forward_tracked(&self.nets.coarse, ec, nc, &self.device, track);
        let raw_c = to_vec(raw_c_t.clone());
        let rgb_c = to_vec(rgb_c_t.clone());
        tm.mlp += t0.elapsed().as_secs_f64();

        let t0 = Instant::now();
        let (comp_c, mse_c, sup_c, draw_c, drgb_c) = self.render_and_grad(&coarse, &raw_c, &rgb_c, batch);
        tm.render += t0.elapsed().as_secs_f64();

        let t0 = Instant::now();
        let pdf = SampleMode::Random { seed: stream_seed(seed, stream::PDF), step };
        let fine = sampling::sample_pdf(&coarse, &comp_c.weights, self.config.fine_samples, pdf);
        let ef = self.encode(&fine, &batch.origins, &batch.dirs);
        tm.encoding += t0.elapsed().as_secs_f64();

        let t0 = Instant::now();
        let nf = fine.len();
        let ((raw_f_t, rgb_f_t), pos_f) = self.forward_tracked(&self.nets.fine, ef, nf, &self.device, track);
        let raw_f = to_vec(raw_f_t.clone());
        let rgb_f = to_vec(rgb_f_t.clone());
        tm.mlp += t0.elapsed().as_secs_f64();

        let t0 = Instant::now();
        let (_, mse_f, sup_f, draw_f, drgb_f) = self.render_and_grad(&fine, &raw_f, &rgb_f, batch);
        tm.render += t0.elapsed().as_secs_f64();
        let loss = mse_c + mse_f;
        let loss = if batch.supervision.is_some() { loss + sup_c + sup_f } else { loss };
        let stats = |skipped, tm| StepStats { loss, mse: mse_f, samples: nc + nf, marched: nc + nf, encoded: nc + nf, skipped_nonfinite: skipped, timings: tm, ..Default::default() };
        if !loss.is_finite() || ![&draw_c, &draw_f, &drgb_c, &drgb_f].iter().all(|v| all_finite(v)) {
            return stats(true, tm);
        }

        let t0 = Instant::now();
        let d = &self.device;
        let surrogate = (raw_c_t * tensor2(draw_c, nc, 1, d)).sum()
            + (rgb_c_t * tensor2(drgb_c, nc, 3, d)).sum()
            + (raw_f_t * tensor2(draw_f, nf, 1, d)).sum()
            + (rgb_f_t * tensor2(drgb_f, nf, 3, d)).sum();
        let grads = surrogate.backward();
        let mut ray_grads = None;
        if let (Some(pc), Some(pf)) = (&pos_c, &pos_f) {
            let mut g = RayGrads { d_origins: vec![[0.0; 3]; rays], d_dirs: vec![[0.0; 3]; rays] };
            for (s, p) in [(&coarse, pc), (&fine, pf)] {
                if let Some(d) = p.grad(&grads) {
                    self.add_ray_gradients(s, &batch.origins, &batch.dirs, &to_vec(d), &mut g);
                }
            }
            ray_grads = Some(g);
        }
        if self.ray_gradients == RayGradients::Only {
            tm.mlp += t0.elapsed().as_secs_f64();
            return StepStats { ray_grads, ..stats(false, tm) };
        }
        let mut gp = GradientsParams::from_grads(grads, &self.nets);
        tm.mlp += t0.elapsed().as_secs_f64();

        let t0 = Instant::now();
        self.nets = self.adam.step(self.lr, self.nets.clone(), &mut gp);
        tm.optimizer += t0.elapsed().as_secs_f64();
        StepStats { ray_grads, ..stats(false, tm) }
    }

    fn set_ray_gradients(&mut self, mode: RayGradients) -> Result<(), String> {
        self.ray_gradients = mode;
        Ok(())
    }

    fn set_lr(&mut self, lr: f64) {
        self.lr = lr;
    }

    /// Renders chunks of [`RENDER_CHUNK`] rays one after another.
    fn render_rays(&self, origins: &[[f32; 3]], dirs: &[[f32; 3]], background: [f32; 3]) -> RayOutputs {
        let mut out = RayOutputs::default();
        for (o, d) in origins.chunks(RENDER_CHUNK).zip(dirs.chunks(RENDER_CHUNK)) {
            out.append(self.render_chunk(o, d, background));
        }
        if out.offsets.is_empty() {
            out.offsets.push(0);
        }
        out
    }

    /// The fine network's density.
    fn density(&self, points: &[[f32; 3]]) -> Vec<f32> {
        self.query(points, &vec![[0.0, 0.0, -1.0]; points.len()]).0
    }

    /// Density and display colour of the fine network at world points, each seen along its
    /// unit direction (inference).
    ///
    /// # Shapes
    /// `points`, `dirs`: n; returns n densities and n colours.
    fn query(&self, points: &[[f32; 3]], dirs: &[[f32; 3]]) -> (Vec<f32>, Vec<[f32; 3]>) {
        let act = self.config.density_activation;
        let nets = self.nets.valid();
        let dev = backend::inference_device();
        let f = &self.config.field;
        let (c, h) = (self.bounds.center(), self.bounds.half_extent());
        let (mut sigma, mut rgb) = (Vec::with_capacity(points.len()), Vec::with_capacity(points.len()));
        for (p, d) in points.chunks(65536).zip(dirs.chunks(65536)) {
            let pts: Vec<[f32; 3]> = p.iter().map(|p| [0, 1, 2].map(|i| (p[i] - c[i]) / h)).collect();
            let mut pos = vec![0.0; pts.len() * f.pos_dims()];
            frequency_encode(&pts, f.pos_freqs, &mut pos);
            let mut dir = vec![0.0; pts.len() * f.dir_dims()];
            frequency_encode(d, f.dir_freqs, &mut dir);
            let (raw, col) = self.forward(&nets.fine, Encoded { pos, dir }, pts.len(), &dev);
            sigma.extend(to_vec(raw).iter().map(|x| act.forward(*x)));
            rgb.extend(ops::rgb3(&to_vec(col)));
        }
        (sigma, rgb)
    }

    fn bounds(&self) -> &SceneBounds {
        &self.bounds
    }

    /// Trainable parameters (coarse + fine).
    fn parameters(&self) -> usize {
        self.nets.num_params()
    }

    /// The full state for a checkpoint.
    fn state(&self) -> StateDict {
        let mut s = StateDict::default();
        save_params(&mut s, "nets", &self.nets);
        save_adam(&mut s, "nets_adam", &self.adam);
        s
    }

    /// Restores [`Self::state`].
    fn load_state(&mut self, s: &StateDict) -> Result<(), String> {
        self.nets = load_params(s, "nets", self.nets.clone())?;
        let n = crate::kernels::param_vectors(&self.nets).len();
        load_adam(s, "nets_adam", &mut self.adam, n);
        Ok(())
    }

    /// Forward multiply-adds per sample of one network.
    fn macs_per_sample(&self) -> f64 {
        let f = &self.config.field;
        let (w, pd, dd) = (f.width as f64, f.pos_dims() as f64, f.dir_dims() as f64);
        let trunk = pd * w + (f.depth as f64 - 1.0) * w * w + if f.skip > 0 && f.skip < f.depth { pd * w } else { 0.0 };
        trunk + w + w * w + (w + dd) * f.color_width as f64 + f.color_width as f64 * 3.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The origins' gradients agree with finite differences of the step's loss (no importance
    /// samples, whose positions would follow the coarse weights, and a fixed near/far, so the
    /// samples' `t` are the same for the shifted rays), and a gradient-only step leaves the
    /// networks unchanged. (The directions' gradient leaves out the direction input, which
    /// this network always reads, so differences would not match it; the fast model's test
    /// checks it on a view-independent model.)
    #[test]
    fn ray_gradients_match_finite_differences_of_the_loss() {
        let field = NerfFieldConfig::new().with_width(32).with_depth(2).with_skip(8).with_color_width(16).with_pos_freqs(4).with_dir_freqs(2);
        let cfg = PaperConfig::new().with_field(field).with_coarse_samples(24).with_fine_samples(0).with_density_activation(DensityActivation::Softplus);
        let bounds = SceneBounds { aabb_min: [-1.0; 3], aabb_max: [1.0; 3], near: 1.0, far: 4.0, source: "test".into() };
        let mut m = PaperModel::new(cfg, bounds, 4);
        let n = 64;
        let dirs: Vec<[f32; 3]> = (0..n)
            .map(|i| {
                let (a, b) = ((i % 8) as f32 * 0.05 - 0.2, (i / 8) as f32 * 0.05 - 0.2);
                let l = (a * a + b * b + 1.0f32).sqrt();
                [a / l, b / l, -1.0 / l]
            })
            .collect();
        let target: Vec<[f32; 3]> = (0..n).map(|i| if i % 3 == 0 { [0.9, 0.2, 0.1] } else { [0.1, 0.3, 0.8] }).collect();
        let batch = RayBatch { origins: vec![[0.0, 0.0, 2.5]; n], dirs, target, background: vec![[0.0; 3]; n], ids: (0..n as u64).collect(), mixed: Vec::new(), supervision: None };
        m.set_lr(5e-3);
        for step in 0..30 {
            m.train_step(&batch, step, 1);
        }
        m.set_ray_gradients(RayGradients::Only).unwrap();
        let before = format!("{:?}", m.nets.clone().into_record());
        let base = m.train_step(&batch, 500, 1);
        assert_eq!(format!("{:?}", m.nets.clone().into_record()), before, "a gradient-only step changed the networks");
        let g = base.ray_grads.expect("ray gradients were asked for");
        // Along the gradient itself (normalised): a signal without cancellations, far above
        // the f32 loss's rounding, so that a small step (the networks' ReLU kinks) can be used.
        let gmax = g.d_origins.iter().flatten().fold(0f32, |m, v| m.max(v.abs()));
        let delta: Vec<[f32; 3]> = g.d_origins.iter().map(|v| v.map(|x| x / gmax)).collect();
        for origins in [true] {
            let grads = if origins { &g.d_origins } else { &g.d_dirs };
            let predicted: f64 = grads.iter().zip(&delta).map(|(g, d)| (0..3).map(|a| g[a] as f64 * d[a] as f64).sum::<f64>()).sum();
            let h = 2e-4f32;
            let shifted = |sign: f32| {
                let mut b = batch.clone();
                let v = if origins { &mut b.origins } else { &mut b.dirs };
                v.iter_mut().zip(&delta).for_each(|(x, d)| (0..3).for_each(|a| x[a] += sign * h * d[a]));
                b
            };
            let (lp, lm) = (m.train_step(&shifted(1.0), 500, 1).loss as f64, m.train_step(&shifted(-1.0), 500, 1).loss as f64);
            let fd = (lp - lm) / (2.0 * h as f64);
            eprintln!("{}: predicted {predicted}, differences {fd}", if origins { "origins" } else { "directions" });
            assert!(predicted.abs() > 1e-5, "the gradient is too small to test: {predicted}");
            assert!((fd - predicted).abs() < 0.03 * predicted.abs(), "predicted {predicted}, differences {fd}");
        }
    }
}
