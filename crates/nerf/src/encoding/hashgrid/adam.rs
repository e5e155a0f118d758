//! The Adam optimiser of the hash tables: dense ([`Adam::step`]) and sparse over the entries a
//! step touched ([`Adam::step_sparse`], and fused with the backward in
//! [`super::HashGrid::backward_adam`]).

#[cfg(target_arch = "x86_64")]
use super::simd;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Adam hyper-parameters (Kingma & Ba). instant-ngp trains its table with
/// `lr = 1e-2, beta1 = 0.9, beta2 = 0.99, eps = 1e-15`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AdamConfig {
    pub lr: f32,
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
}

impl AdamConfig {
    /// instant-ngp's settings with the given learning rate.
    pub fn instant_ngp(lr: f32) -> Self {
        Self { lr, beta1: 0.9, beta2: 0.99, eps: 1e-15 }
    }
}

/// Table entries per task of the sparse Adam (indices within a chunk fit in `u16`).
pub(super) const ADAM_ENTRIES: usize = 1 << 14;
const _: () = assert!(ADAM_ENTRIES <= 1 << 16, "entry indices are u16 within a chunk");

/// The sparse Adam of up to [`ADAM_ENTRIES`] entries of `group` parameters: the entries flagged
/// in `tch` are updated, their gradients zeroed and their flags cleared. Returns how many.
pub(super) fn sparse_update(p: &mut [f32], g: &mut [f32], m: &mut [f32], v: &mut [f32], tch: &mut [bool], group: usize, k: &AdamStep) -> usize {
    // Two parameters per flag (the hash grid's two features) with AVX2: every group of four
    // entries that has a touched one is updated eight lanes at once, the results kept only in
    // the touched entries' lanes (the same operations in the same order as below, so the same
    // bits).
    #[cfg(target_arch = "x86_64")]
    if group == 2 && simd::avx2() {
        // SAFETY: AVX2 is present (checked at run time).
        #[allow(unsafe_code)]
        return unsafe { simd::adam_pairs_avx2(p, g, m, v, tch, k) };
    }
    // The touched entries' indices first, without a branch per flag (about a third of the
    // flags are set, scattered, so a branch on each mispredicts often), then the updates in
    // index order.
    let mut list = [0u16; ADAM_ENTRIES];
    let mut updated = 0;
    for (e, hit) in tch.iter().enumerate() {
        list[updated] = e as u16;
        updated += *hit as usize;
    }
    tch.fill(false);
    for &e in &list[..updated] {
        let e = e as usize;
        for i in e * group..(e + 1) * group {
            k.update(std::mem::take(&mut g[i]), &mut p[i], &mut m[i], &mut v[i]);
        }
    }
    updated
}

/// The numbers of one Adam step: the configuration's betas and epsilon, the learning rate and
/// the bias corrections `c₁ = 1 − β₁ᵗ`, `c₂ = 1 − β₂ᵗ` (computed in `f64`) at step `t`.
pub(super) struct AdamStep {
    pub(super) b1: f32,
    pub(super) b2: f32,
    pub(super) eps: f32,
    pub(super) lr: f32,
    pub(super) c1: f32,
    pub(super) c2: f32,
}

impl AdamStep {
    pub(super) fn new(config: &AdamConfig, step: u64, lr: f32) -> Self {
        let AdamConfig { beta1: b1, beta2: b2, eps, .. } = *config;
        let t = step.min(i32::MAX as u64) as i32;
        let c1 = (1.0 - (b1 as f64).powi(t)) as f32;
        let c2 = (1.0 - (b2 as f64).powi(t)) as f32;
        Self { b1, b2, eps, lr, c1, c2 }
    }

    /// One parameter's update with gradient `g` (a NaN or infinite one counts as 0):
    /// `m = β₁m + (1−β₁)g`, `v = β₂v + ((1−β₂)g)g`, `p −= (lr·(m/c₁)) / (√(v/c₂) + ε)`, in
    /// this order and without fused operations (the AVX2 kernel repeats it lane for lane).
    #[inline(always)]
    pub(super) fn update(&self, g: f32, p: &mut f32, m: &mut f32, v: &mut f32) {
        let g = if g.is_finite() { g } else { 0.0 };
        *m = self.b1 * *m + (1.0 - self.b1) * g;
        *v = self.b2 * *v + (1.0 - self.b2) * g * g;
        *p -= self.lr * (*m / self.c1) / ((*v / self.c2).sqrt() + self.eps);
    }
}

/// Dense Adam over a flat `f32` parameter vector: every entry is updated every step (as
/// instant-ngp does for its hash table), so entries no point touched this step still move with
/// their momentum. Parallel over fixed chunks, elementwise, hence deterministic.
///
/// ```text
/// t += 1;  m = β1 m + (1 − β1) g;  v = β2 v + (1 − β2) g²
/// p -= lr · (m / (1 − β1^t)) / (sqrt(v / (1 − β2^t)) + eps)
/// ```
///
/// A NaN or infinite gradient entry is treated as 0. Example: first step with `g = 0.5`,
/// `lr = 0.1`: `m̂ = 0.5`, `v̂ = 0.25`, `p -= 0.1 · 0.5 / 0.5 = 0.1`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Adam {
    pub config: AdamConfig,
    /// Steps taken.
    pub step: u64,
    pub m: Vec<f32>,
    pub v: Vec<f32>,
}

impl Adam {
    /// Zero moments for `n_params` parameters.
    pub fn new(config: AdamConfig, n_params: usize) -> Self {
        Self { config, step: 0, m: vec![0.0; n_params], v: vec![0.0; n_params] }
    }

    /// One update of `params` with `grads` at the configured learning rate.
    pub fn step(&mut self, params: &mut [f32], grads: &[f32]) {
        let lr = self.config.lr;
        self.step_with_lr(params, grads, lr);
    }

    /// One update with an explicit learning rate (for schedules).
    pub fn step_with_lr(&mut self, params: &mut [f32], grads: &[f32], lr: f32) {
        assert!(params.len() == self.m.len() && grads.len() == self.m.len(), "Adam: length mismatch");
        self.step += 1;
        let k = AdamStep::new(&self.config, self.step, lr);
        const CHUNK: usize = 1 << 14;
        params
            .par_chunks_mut(CHUNK)
            .zip(grads.par_chunks(CHUNK))
            .zip(self.m.par_chunks_mut(CHUNK))
            .zip(self.v.par_chunks_mut(CHUNK))
            .for_each(|(((p, g), m), v)| {
                for i in 0..p.len() {
                    k.update(g[i], &mut p[i], &mut m[i], &mut v[i]);
                }
            });
    }

    /// Sparse (lazy) Adam: the update above applied only to the entries flagged in `touched`
    /// (groups of `group` consecutive parameters share one flag: the `F` features of a hash
    /// table entry, as [`HashGrid::backward_touched`] marks them); untouched entries keep their
    /// values and moments. The step counter, and so the bias correction, is global. Afterwards
    /// the touched entries' gradients are reset to 0 and their flags to `false`, so the buffers
    /// are ready for the next step's backward without a full clear (on a CPU the table is far
    /// larger than what one batch touches).
    ///
    /// Example: with every flag set this is exactly [`Self::step_with_lr`] (then clears `grads`).
    ///
    /// # Shapes
    /// `params`, `grads`: `[n]`; `touched`: `[n / group]`. Returns how many entries it updated.
    pub fn step_sparse(&mut self, params: &mut [f32], grads: &mut [f32], touched: &mut [bool], group: usize, lr: f32) -> usize {
        assert!(params.len() == self.m.len() && grads.len() == self.m.len(), "Adam: length mismatch");
        assert_eq!(touched.len() * group, params.len(), "one flag per group of parameters");
        self.step += 1;
        let k = AdamStep::new(&self.config, self.step, lr);
        let chunk = ADAM_ENTRIES * group;
        params
            .par_chunks_mut(chunk)
            .zip(grads.par_chunks_mut(chunk))
            .zip(self.m.par_chunks_mut(chunk))
            .zip(self.v.par_chunks_mut(chunk))
            .zip(touched.par_chunks_mut(ADAM_ENTRIES))
            .map(|((((p, g), m), v), tch)| sparse_update(p, g, m, v, tch, group, &k))
            .sum()
    }
}
