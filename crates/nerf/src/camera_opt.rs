//! Camera refinement: one SE(3) correction per training view, learned with the field from the
//! loss's gradient with respect to the view's rays (nerfacto's camera optimiser, BARF).
//!
//! # Parameterisation
//! View `v` with camera-to-world pose `[R | c]` is trained on `[exp(ω_v) R | c + s·τ_v]`: the
//! camera turns about its own centre by the rotation vector `ω_v` (radians) and its centre
//! moves by `τ_v` in units of the scene size `s` ([`crate::poses::scene_size`]), so one
//! learning rate suits every scene. A ray `(o, d)` of the view becomes
//! `(o + s·τ_v, exp(ω_v)·d)`. Both start at 0 (the poses as given).
//!
//! # Gradient
//! The model gives `g_o = ∂L/∂o` and `g_d = ∂L/∂d` per ray ([`crate::models::RayGrads`]);
//! with `exp(ω + δ) ≈ exp(J(ω)·δ)·exp(ω)` (`J` the left Jacobian, [`dataset::pose`]),
//! `δd' = (J δ) × d'`, so per view
//!
//! ```text
//! ∂L/∂ω = J(ω)ᵀ Σ_rays d' × g_d          ∂L/∂τ = s · Σ_rays g_o
//! ```
//!
//! The rays' gradients flow through the sample points `o + t·d`; the colour network's view
//! direction input is not differentiated (the points carry the pose: at 1° a point 1 m away
//! moves 17 mm, while the view-dependent colour of most surfaces changes little).
//!
//! # Optimiser
//! Adam per view on `(ω, τ)` (β = 0.9, 0.999, ε = 1e-15 as nerfacto), with its own step count.
//! A step's batch holds few rays of any one view (a batch of 4096 rays over 100 views gives
//! each about 40), so one step's per-view gradient is mostly noise, and Adam, which divides
//! by the gradient's running RMS, turns noise into steps of the learning rate's size: a
//! random walk away from the right pose. Each view therefore sums its rays' gradients over
//! steps and takes one Adam step with their mean once `rays_per_update` rays have been
//! summed (0 or 1: every step with rays of the view, as nerfacto does with its large batches). The learning rate ramps linearly from 0 over
//! `warmup_steps` (the field first needs coarse geometry for the gradient to point anywhere)
//! and follows the field's decay (`lr_camera · lr_field(step) / lr_field(0)`). After every
//! update `|ω|` is clamped to `max_rotation_deg` and `|τ|` to `max_translation_rel`, so one
//! view whose pose is wrong beyond repair cannot run away (its correction stops at the bound).
//!
//! State is f32 (parameters and moments), so a checkpoint restores it exactly.
//!
//! # Held-out views
//! [`optimise_view`] refines one view's pose with the model frozen (the protocol of BARF-style
//! evaluations, `eval --test-pose-opt N`): the same correction and gradient, Adam at the
//! constant rate [`TEST_POSE_LR`], on random pixels of that view.

use crate::checkpoint::StateDict;
use crate::data::{RayBatch, TrainData};
use crate::models::{NerfModel, RayGradients, RayGrads};
use dataset::pose::{so3_exp, so3_left_jacobian};
use glam::{DMat3, DMat4, DVec3};
use serde::{Deserialize, Serialize};

/// Camera refinement settings (`config.json`'s `camera_opt`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraOptConfig {
    /// Adam learning rate of `ω` (radians) and `τ` (scene sizes) at the start of the decay.
    pub lr: f64,
    /// Steps over which the learning rate ramps up from 0.
    pub warmup_steps: u64,
    /// Largest correction angle, degrees.
    pub max_rotation_deg: f64,
    /// Largest centre correction, as a fraction of the scene size.
    pub max_translation_rel: f64,
    /// Rays whose gradients a view sums before its Adam step (module doc); configs written
    /// without the field update every step.
    #[serde(default)]
    pub rays_per_update: u32,
}

impl Default for CameraOptConfig {
    fn default() -> Self {
        Self { lr: 2e-4, warmup_steps: 500, max_rotation_deg: 15.0, max_translation_rel: 0.2, rays_per_update: 0 }
    }
}

impl CameraOptConfig {
    /// Refuses settings no run can use, naming the field.
    pub fn check(&self) -> Result<(), String> {
        if !(self.lr.is_finite() && self.lr > 0.0) {
            return Err(format!("camera_opt.lr must be a positive number, not {}", self.lr));
        }
        if !(self.max_rotation_deg.is_finite() && self.max_rotation_deg > 0.0 && self.max_rotation_deg <= 90.0) {
            return Err(format!("camera_opt.max_rotation_deg must be in (0, 90], not {}", self.max_rotation_deg));
        }
        if !(self.max_translation_rel.is_finite() && self.max_translation_rel > 0.0 && self.max_translation_rel <= 1.0) {
            return Err(format!("camera_opt.max_translation_rel must be in (0, 1], not {}", self.max_translation_rel));
        }
        Ok(())
    }
}

/// `--camera-opt off|se3`.
pub fn parse_mode(s: &str) -> Result<Option<CameraOptConfig>, String> {
    match s {
        "off" => Ok(None),
        "se3" => Ok(Some(CameraOptConfig::default())),
        other => Err(format!("'{other}' is not a camera refinement (off or se3)")),
    }
}

const BETA1: f64 = 0.9;
const BETA2: f64 = 0.999;
const EPS: f64 = 1e-15;

/// The corrections of every training view and their optimiser state.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraOpt {
    /// Settings.
    pub config: CameraOptConfig,
    /// The scene size `s` translations are relative to.
    pub scene_size: f64,
    /// Per view: `[ω, τ]`.
    pub params: Vec<[f32; 6]>,
    m: Vec<[f32; 6]>,
    v: Vec<[f32; 6]>,
    steps: Vec<u32>,
    /// Per view: the summed gradient not yet applied, and its ray count.
    acc: Vec<[f32; 6]>,
    acc_rays: Vec<u32>,
}

impl CameraOpt {
    /// Zero corrections for `views` views.
    pub fn new(config: CameraOptConfig, views: usize, scene_size: f64) -> Self {
        Self { config, scene_size, params: vec![[0.0; 6]; views], m: vec![[0.0; 6]; views], v: vec![[0.0; 6]; views], steps: vec![0; views], acc: vec![[0.0; 6]; views], acc_rays: vec![0; views] }
    }

    fn rotation(&self, view: usize) -> DMat3 {
        let p = &self.params[view];
        so3_exp(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64))
    }

    fn shift(&self, view: usize) -> DVec3 {
        let p = &self.params[view];
        DVec3::new(p[3] as f64, p[4] as f64, p[5] as f64) * self.scene_size
    }

    /// View `view`'s corrected camera-to-world pose.
    pub fn corrected_pose(&self, view: usize, pose: &DMat4) -> DMat4 {
        let r = self.rotation(view) * DMat3::from_mat4(*pose);
        let c = pose.w_axis.truncate() + self.shift(view);
        DMat4::from_cols(r.x_axis.extend(0.0), r.y_axis.extend(0.0), r.z_axis.extend(0.0), c.extend(1.0))
    }

    /// Applies each ray's view correction to `batch` (the view is `id >> 32`).
    pub fn apply(&self, batch: &mut RayBatch) {
        let per_view: Vec<(DMat3, DVec3)> = (0..self.params.len()).map(|v| (self.rotation(v), self.shift(v))).collect();
        for ((o, d), id) in batch.origins.iter_mut().zip(batch.dirs.iter_mut()).zip(&batch.ids) {
            let Some((r, t)) = per_view.get((id >> 32) as usize) else { continue };
            let dn = *r * DVec3::new(d[0] as f64, d[1] as f64, d[2] as f64);
            *d = [dn.x as f32, dn.y as f32, dn.z as f32];
            *o = [(o[0] as f64 + t.x) as f32, (o[1] as f64 + t.y) as f32, (o[2] as f64 + t.z) as f32];
        }
    }

    /// Per view with rays in the batch: `∂L/∂(ω, τ)` (module doc), from the corrected batch
    /// and its rays' gradients; summed in batch order.
    pub fn gradients(&self, batch: &RayBatch, g: &RayGrads) -> Vec<Option<[f64; 6]>> {
        self.gradients_and_rays(batch, g).into_iter().map(|e| e.map(|(g, _)| g)).collect()
    }

    /// [`Self::gradients`] with each view's ray count.
    pub fn gradients_and_rays(&self, batch: &RayBatch, g: &RayGrads) -> Vec<Option<([f64; 6], u32)>> {
        let mut acc: Vec<Option<([f64; 3], [f64; 3], u32)>> = vec![None; self.params.len()];
        for (k, id) in batch.ids.iter().enumerate() {
            let Some(slot) = acc.get_mut((id >> 32) as usize) else { continue };
            let (go, gd, d) = (g.d_origins[k], g.d_dirs[k], batch.dirs[k]);
            let (d, gd) = (DVec3::new(d[0] as f64, d[1] as f64, d[2] as f64), DVec3::new(gd[0] as f64, gd[1] as f64, gd[2] as f64));
            let cross = d.cross(gd);
            let e = slot.get_or_insert(([0.0; 3], [0.0; 3], 0));
            for a in 0..3 {
                e.0[a] += cross[a];
                e.1[a] += go[a] as f64;
            }
            e.2 += 1;
        }
        acc.iter()
            .enumerate()
            .map(|(v, e)| {
                e.map(|(rot, org, n)| {
                    let p = &self.params[v];
                    let j = so3_left_jacobian(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64));
                    let gw = j.transpose() * DVec3::from(rot);
                    ([gw.x, gw.y, gw.z, org[0] * self.scene_size, org[1] * self.scene_size, org[2] * self.scene_size], n)
                })
            })
            .collect()
    }

    /// Adds a step's per-view gradients and ray counts ([`Self::gradients_and_rays`]) to the
    /// views' sums; views whose sum holds `rays_per_update` rays take their Adam step with the
    /// mean, and their sums restart. Non-finite gradients are dropped.
    pub fn accumulate_and_step(&mut self, grads: &[Option<([f64; 6], u32)>], lr: f64) {
        if self.config.rays_per_update <= 1 {
            let sums: Vec<Option<[f64; 6]>> = grads.iter().map(|g| g.map(|(g, _)| g)).collect();
            return self.step(&sums, lr);
        }
        let need = self.config.rays_per_update;
        let mut ready: Vec<Option<[f64; 6]>> = vec![None; self.params.len()];
        for (v, g) in grads.iter().enumerate() {
            let Some((g, n)) = g.filter(|(g, _)| g.iter().all(|x| x.is_finite())) else { continue };
            for k in 0..6 {
                self.acc[v][k] += g[k] as f32;
            }
            self.acc_rays[v] += n;
            if self.acc_rays[v] >= need {
                let inv = 1.0 / self.acc_rays[v] as f64;
                ready[v] = Some(self.acc[v].map(|x| x as f64 * inv));
                self.acc[v] = [0.0; 6];
                self.acc_rays[v] = 0;
            }
        }
        self.step(&ready, lr);
    }

    /// The learning rate at `step`, given the field's decay factor `lr_field(step) / lr_field(0)`.
    pub fn lr(&self, step: u64, decay: f64) -> f64 {
        let ramp = if self.config.warmup_steps == 0 { 1.0 } else { (step as f64 / self.config.warmup_steps as f64).min(1.0) };
        self.config.lr * ramp * decay
    }

    /// One Adam step of every view with a gradient, then the bounds (module doc). Views
    /// without rays in the batch, and gradients that are not finite, change nothing.
    pub fn step(&mut self, grads: &[Option<[f64; 6]>], lr: f64) {
        let max_w = self.config.max_rotation_deg.to_radians();
        let max_t = self.config.max_translation_rel;
        for (v, g) in grads.iter().enumerate() {
            let Some(g) = g.filter(|g| g.iter().all(|x| x.is_finite())) else { continue };
            self.steps[v] += 1;
            let n = self.steps[v] as i32;
            let (c1, c2) = (1.0 - BETA1.powi(n), 1.0 - BETA2.powi(n));
            let mut p = self.params[v].map(|x| x as f64);
            for k in 0..6 {
                let m = BETA1 * self.m[v][k] as f64 + (1.0 - BETA1) * g[k];
                let s = BETA2 * self.v[v][k] as f64 + (1.0 - BETA2) * g[k] * g[k];
                self.m[v][k] = m as f32;
                self.v[v][k] = s as f32;
                p[k] -= lr * (m / c1) / ((s / c2).sqrt() + EPS);
            }
            for (range, max) in [(0..3, max_w), (3..6, max_t)] {
                let len = p[range.clone()].iter().map(|x| x * x).sum::<f64>().sqrt();
                if len > max {
                    p[range].iter_mut().for_each(|x| *x *= max / len);
                }
            }
            self.params[v] = p.map(|x| x as f32);
        }
    }

    /// Adds the state to a checkpoint (`camera_opt.*` arrays).
    pub fn save(&self, s: &mut StateDict) {
        let flat = |x: &[[f32; 6]]| x.iter().flatten().copied().collect::<Vec<f32>>();
        s.arrays.insert("camera_opt.params".into(), flat(&self.params));
        s.arrays.insert("camera_opt.m".into(), flat(&self.m));
        s.arrays.insert("camera_opt.v".into(), flat(&self.v));
        s.arrays.insert("camera_opt.steps".into(), self.steps.iter().map(|&n| n as f32).collect());
        if self.config.rays_per_update > 1 {
            s.arrays.insert("camera_opt.acc".into(), flat(&self.acc));
            s.arrays.insert("camera_opt.acc_rays".into(), self.acc_rays.iter().map(|&n| n as f32).collect());
        }
    }

    /// Restores [`Self::save`]'s state (refused when the view count differs).
    pub fn load(&mut self, s: &StateDict) -> Result<(), String> {
        let n = self.params.len();
        let get = |k: &str, len: usize| -> Result<&Vec<f32>, String> {
            let a = s.arrays.get(k).ok_or_else(|| format!("the checkpoint has no {k} (it was written without camera refinement)"))?;
            if a.len() != len {
                return Err(format!("{k} holds {} values, {len} expected for {n} training views", a.len()));
            }
            Ok(a)
        };
        let rows = |a: &Vec<f32>| a.chunks_exact(6).map(|c| std::array::from_fn(|k| c[k])).collect::<Vec<[f32; 6]>>();
        self.params = rows(get("camera_opt.params", 6 * n)?);
        self.m = rows(get("camera_opt.m", 6 * n)?);
        self.v = rows(get("camera_opt.v", 6 * n)?);
        self.steps = get("camera_opt.steps", n)?.iter().map(|&x| x as u32).collect();
        if self.config.rays_per_update > 1 {
            self.acc = rows(get("camera_opt.acc", 6 * n)?);
            self.acc_rays = get("camera_opt.acc_rays", n)?.iter().map(|&x| x as u32).collect();
        }
        Ok(())
    }
}

/// Adam's learning rate for a held-out view's pose ([`optimise_view`]).
pub const TEST_POSE_LR: f64 = 1e-3;
/// Rays per step of [`optimise_view`].
pub const TEST_POSE_RAYS: usize = 1024;

/// The correction of the single view of `data` after `steps` steps with `model` frozen
/// (module doc); `model` is left unchanged and asked for no ray gradients afterwards.
pub fn optimise_view(model: &mut dyn NerfModel, data: &TrainData, scene_size: f64, steps: u64, seed: u64) -> Result<CameraOpt, String> {
    model.set_ray_gradients(RayGradients::Only)?;
    let config = CameraOptConfig { lr: TEST_POSE_LR, warmup_steps: 0, ..CameraOptConfig::default() };
    let mut opt = CameraOpt::new(config, 1, scene_size);
    for step in 0..steps {
        let mut b = data.batch(seed, step, TEST_POSE_RAYS);
        opt.apply(&mut b);
        if let Some(g) = model.train_step(&b, step, seed).ray_grads {
            let grads = opt.gradients(&b, &g);
            opt.step(&grads, TEST_POSE_LR);
        }
    }
    model.set_ray_gradients(RayGradients::Off)?;
    Ok(opt)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn batch(dirs: Vec<[f32; 3]>, views: &[u64]) -> RayBatch {
        let n = dirs.len();
        RayBatch {
            origins: vec![[1.0, 2.0, 3.0]; n],
            dirs,
            target: vec![[0.0; 3]; n],
            background: vec![[0.0; 3]; n],
            ids: views.iter().enumerate().map(|(k, v)| (v << 32) | k as u64).collect(),
            mixed: Vec::new(),
            supervision: None,
        }
    }

    /// `∂L/∂(ω, τ)` against central differences of a loss of the corrected rays
    /// `L = Σ a·o' + b·d'` (whose ray gradients are `a` and `b`), at rotation angles from 0 to
    /// near π, where the left Jacobian's series and closed form take over.
    #[test]
    fn gradients_match_finite_differences_at_every_angle() {
        let dirs: Vec<[f32; 3]> = vec![[0.6, 0.0, -0.8], [0.0, 1.0, 0.0], [-0.48, 0.6, 0.64]];
        let (a, b) = ([0.3f64, -1.1, 0.7], [0.9f64, 0.4, -0.2]);
        for angle in [0.0, 1e-8, 1e-4, 0.1, std::f64::consts::PI - 1e-6] {
            let axis = DVec3::new(1.0, -2.0, 0.5).normalize();
            let w = axis * angle;
            let mut opt = CameraOpt::new(CameraOptConfig::default(), 2, 2.5);
            opt.params[1] = [w.x as f32, w.y as f32, w.z as f32, 0.01, -0.02, 0.03];
            let loss = |p: [f64; 6]| -> f64 {
                let r = so3_exp(DVec3::new(p[0], p[1], p[2]));
                dirs.iter()
                    .map(|d| {
                        let d = r * DVec3::new(d[0] as f64, d[1] as f64, d[2] as f64);
                        let o = DVec3::new(1.0, 2.0, 3.0) + DVec3::new(p[3], p[4], p[5]) * 2.5;
                        (0..3).map(|k| a[k] * o[k] + b[k] * d[k]).sum::<f64>()
                    })
                    .sum()
            };
            let mut bt = batch(dirs.clone(), &[1, 1, 1]);
            opt.apply(&mut bt);
            let n = dirs.len();
            let g = RayGrads { d_origins: vec![a.map(|x| x as f32); n], d_dirs: vec![b.map(|x| x as f32); n] };
            let grads = opt.gradients(&bt, &g);
            assert!(grads[0].is_none(), "view 0 has no rays");
            let got = grads[1].unwrap();
            let p0 = opt.params[1].map(|x| x as f64);
            for k in 0..6 {
                let h = 1e-6;
                let (mut lo, mut hi) = (p0, p0);
                lo[k] -= h;
                hi[k] += h;
                let fd = (loss(hi) - loss(lo)) / (2.0 * h);
                assert!((got[k] - fd).abs() < 1e-5 * (1.0 + fd.abs()), "angle {angle}, parameter {k}: {} vs {fd}", got[k]);
            }
        }
    }

    /// Corrected rays are the rays of the corrected pose.
    #[test]
    fn corrected_rays_come_from_the_corrected_pose() {
        let mut opt = CameraOpt::new(CameraOptConfig::default(), 1, 4.0);
        opt.params[0] = [0.1, -0.2, 0.05, 0.01, 0.0, -0.02];
        let pose = DMat4::from_translation(DVec3::new(1.0, 2.0, 3.0)) * DMat4::from_rotation_y(0.3);
        let fixed = opt.corrected_pose(0, &pose);
        let cam_dir = DVec3::new(0.1, 0.2, -1.0).normalize();
        let world = DMat3::from_mat4(pose) * cam_dir;
        let mut b = batch(vec![[world.x as f32, world.y as f32, world.z as f32]], &[0]);
        opt.apply(&mut b);
        let want_d = DMat3::from_mat4(fixed) * cam_dir;
        let want_o = fixed.w_axis.truncate();
        for k in 0..3 {
            assert!((b.dirs[0][k] as f64 - want_d[k]).abs() < 1e-6);
            assert!((b.origins[0][k] as f64 - want_o[k]).abs() < 1e-6);
        }
    }

    /// A gradient that keeps pushing one way is stopped at the bounds; views without a
    /// gradient and non-finite gradients change nothing; state survives a checkpoint.
    #[test]
    fn corrections_stay_bounded_and_round_trip() {
        let cfg = CameraOptConfig { lr: 0.05, warmup_steps: 0, max_rotation_deg: 15.0, max_translation_rel: 0.2, rays_per_update: 0 };
        let mut opt = CameraOpt::new(cfg, 3, 1.0);
        for _ in 0..2000 {
            opt.step(&[Some([-1.0, 0.0, 0.0, 0.0, -3.0, 0.0]), None, Some([f64::NAN; 6])], 0.05);
        }
        let p = opt.params[0];
        let rot = (p[0] as f64).hypot(p[1] as f64).hypot(p[2] as f64).to_degrees();
        assert!((rot - 15.0).abs() < 1e-3, "rotation stopped at {rot}°");
        assert!((p[4] - 0.2).abs() < 1e-6, "translation stopped at {}", p[4]);
        assert_eq!(opt.params[1], [0.0; 6]);
        assert_eq!(opt.params[2], [0.0; 6]);
        let mut s = StateDict::default();
        opt.save(&mut s);
        let mut back = CameraOpt::new(cfg, 3, 1.0);
        back.load(&s).unwrap();
        assert_eq!(back, opt);
        let e = CameraOpt::new(cfg, 4, 1.0).load(&s).unwrap_err();
        assert!(e.contains("4 training views"), "{e}");
    }

    /// With `rays_per_update` a view waits until its summed gradients cover that many rays,
    /// then steps once with their mean (as one Adam step given the mean directly); the sums
    /// survive a checkpoint; with 0 every step applies its sums as [`CameraOpt::step`] does.
    #[test]
    fn views_accumulate_their_rays_before_stepping() {
        let cfg = CameraOptConfig { lr: 0.01, warmup_steps: 0, rays_per_update: 10, ..Default::default() };
        let mut opt = CameraOpt::new(cfg, 2, 1.0);
        let g = [0.5, -0.25, 0.125, 1.0, 2.0, -3.0];
        for _ in 0..2 {
            opt.accumulate_and_step(&[Some((g, 4)), Some((g, 30))], 0.01);
        }
        assert_eq!(opt.params[0], [0.0; 6], "8 rays of 10: no step yet");
        assert_ne!(opt.params[1], [0.0; 6]);
        let mut s = StateDict::default();
        opt.save(&mut s);
        let mut back = CameraOpt::new(cfg, 2, 1.0);
        back.load(&s).unwrap();
        assert_eq!(back, opt, "the sums survive a checkpoint");
        back.accumulate_and_step(&[Some((g, 4)), None], 0.01);
        let mut direct = CameraOpt::new(cfg, 1, 1.0);
        direct.step(&[Some(g.map(|x| x * 3.0 / 12.0))], 0.01);
        for k in 0..6 {
            assert!((back.params[0][k] - direct.params[0][k]).abs() < 1e-7, "{:?} vs {:?}", back.params[0], direct.params[0]);
        }
        let every = CameraOptConfig { rays_per_update: 0, ..cfg };
        let (mut a, mut b) = (CameraOpt::new(every, 1, 1.0), CameraOpt::new(every, 1, 1.0));
        for k in 0..5 {
            let gk = g.map(|x| x * (k as f64 - 1.7));
            a.accumulate_and_step(&[Some((gk, 3))], 0.01);
            b.step(&[Some(gk)], 0.01);
        }
        assert_eq!(a, b);
    }

    #[test]
    fn bad_settings_are_refused_naming_the_field() {
        assert!(parse_mode("se3").unwrap().is_some() && parse_mode("off").unwrap().is_none());
        assert!(parse_mode("so3").unwrap_err().contains("off or se3"));
        for (c, says) in [
            (CameraOptConfig { lr: -1.0, ..Default::default() }, "camera_opt.lr"),
            (CameraOptConfig { max_rotation_deg: f64::NAN, ..Default::default() }, "max_rotation_deg"),
            (CameraOptConfig { max_translation_rel: 2.0, ..Default::default() }, "max_translation_rel"),
        ] {
            assert!(c.check().unwrap_err().contains(says));
        }
    }
}
