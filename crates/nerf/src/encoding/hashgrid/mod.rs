//! Multiresolution hash encoding (Müller et al. 2022, "Instant Neural Graphics Primitives"),
//! forward and exact backward over slices, and a dense [`Adam`] for its table.
//!
//! # Formula
//! Level `l < L` has `N_l = floor(N_min · b^l)` cells per axis with
//! `b = exp((ln N_max − ln N_min) / (L − 1))` (`b = 1` when `L = 1`; the floor tolerates 1e-6
//! so that `N_{L−1} = N_max` exactly). A point `p ∈ [0, 1]³` maps to `x = p · N_l`, the cell
//! `c = min(floor(x), N_l − 1)` and the fraction `f = x − c ∈ [0, 1]` (so `p = 1` lies in the
//! last cell with `f = 1`, and vertices sit exactly at `p = k / N_l`). The level's features are
//! the trilinear interpolation of its 8 corner vertices `v = c + {0,1}³`:
//!
//! ```text
//! enc_l(p) = Σ_{corners v} Π_a (f_a if v_a = c_a + 1 else 1 − f_a) · θ_l[index_l(v)]
//! index_l(v) = v_x + v_y (N_l+1) + v_z (N_l+1)²                if (N_l+1)³ ≤ T  (dense)
//!            = (v_x · 1 ⊕ v_y · 2654435761 ⊕ v_z · 805459861) mod T   otherwise (u32 wrapping)
//! ```
//!
//! with `T = 2^log2_table_size` entries of `F` features per level. Every level owns a full
//! table of `T` entries (dense levels use the first `(N_l+1)³`).
//!
//! Points outside `[0, 1]` are clamped to it per axis; a NaN coordinate is treated as 0.
//!
//! # Worked example
//! `L = 1, F = 1, N = 2` (dense, vertices 3 per axis), `p = (0.25, 0, 0)`: `x = (0.5, 0, 0)`,
//! `c = 0`, `f = (0.5, 0, 0)`, so `enc = 0.5 θ[0] + 0.5 θ[1]` (vertex (0,0,0) and (1,0,0)).
//!
//! # Layout
//! - `params`: `[L][T][F]`, i.e. `params[(l · T + i) · F + j]`
//! - `encode` output: `[N][L · F]` row-major, `out[n · L·F + l · F + j]`
//!
//! # Determinism
//! The forward is parallel over fixed chunks of points (each output written once); the
//! backward is parallel over levels, each level summing its points in index order. Results are
//! bit-identical whatever the thread count.

use super::EncodingError;
use crate::sampling::rng;
use adam::{ADAM_ENTRIES, AdamStep, sparse_update};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

mod adam;
mod position;
#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod simd;
#[cfg(test)]
#[allow(clippy::needless_range_loop)]
mod tests;

pub use adam::{Adam, AdamConfig};

/// The spatial-hash primes of instant-ngp (the first is 1 for coherence along x).
pub const PRIMES: [u32; 3] = [1, 2_654_435_761, 805_459_861];

/// Points per rayon task in the forward.
const POINT_CHUNK: usize = 4096;

/// Hash-grid hyper-parameters (instant-ngp's NeRF defaults: 16 levels, 2 features,
/// `2^19` entries, `N_min = 16`, `N_max = 2048 · scene scale`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HashGridConfig {
    /// Number of levels `L` (≥ 1).
    pub levels: usize,
    /// Features per level `F`: 1, 2, 4 or 8.
    pub features_per_level: usize,
    /// `log2 T`, the entries per level (1 ..= 28).
    pub log2_table_size: u32,
    /// `N_min`, cells per axis of the coarsest level (≥ 1).
    pub base_resolution: u32,
    /// `N_max`, cells per axis of the finest level (≥ `N_min`).
    pub finest_resolution: u32,
}

impl HashGridConfig {
    /// Checks the ranges documented on the fields.
    pub fn validate(&self) -> Result<(), EncodingError> {
        let bad = |m: &str| Err(EncodingError::InvalidConfig(m.to_string()));
        if self.levels == 0 {
            return bad("levels must be ≥ 1");
        }
        if ![1, 2, 4, 8].contains(&self.features_per_level) {
            return bad("features_per_level must be 1, 2, 4 or 8");
        }
        if !(1..=28).contains(&self.log2_table_size) {
            return bad("log2_table_size must be in 1..=28");
        }
        if self.base_resolution == 0 || self.finest_resolution < self.base_resolution {
            return bad("need 1 ≤ base_resolution ≤ finest_resolution");
        }
        if self.finest_resolution > 1 << 20 {
            return bad("finest_resolution must be ≤ 2^20");
        }
        Ok(())
    }

    /// Growth factor `b` between levels.
    pub fn growth_factor(&self) -> f64 {
        if self.levels <= 1 {
            1.0
        } else {
            (((self.finest_resolution as f64).ln() - (self.base_resolution as f64).ln()) / (self.levels - 1) as f64).exp()
        }
    }

    /// `N_l`, cells per axis of level `l`.
    pub fn resolution(&self, l: usize) -> u32 {
        let x = self.base_resolution as f64 * self.growth_factor().powi(l as i32);
        ((x + 1e-6).floor() as u32).clamp(self.base_resolution, self.finest_resolution)
    }

    /// `T`, entries per level.
    pub fn table_size(&self) -> usize {
        1 << self.log2_table_size
    }

    /// Whether level `l` is indexed densely (`(N_l + 1)³ ≤ T`).
    pub fn is_dense(&self, l: usize) -> bool {
        let v = self.resolution(l) as u64 + 1;
        v * v * v <= self.table_size() as u64
    }

    /// `L · F`, the encoding's width.
    pub fn output_dim(&self) -> usize {
        self.levels * self.features_per_level
    }

    /// `L · T · F`, the parameter count.
    pub fn n_params(&self) -> usize {
        self.levels * self.table_size() * self.features_per_level
    }
}

/// Per-level constants of the hot loops.
#[derive(Clone, Copy, Debug)]
struct Level {
    res: u32,
    res_f: f64,
    dense: bool,
    s1: u32,
    s2: u32,
    mask: u32,
}

fn levels(c: &HashGridConfig) -> Vec<Level> {
    (0..c.levels)
        .map(|l| {
            let res = c.resolution(l);
            Level {
                res,
                res_f: res as f64,
                dense: c.is_dense(l),
                s1: res + 1,
                s2: (res + 1).wrapping_mul(res + 1),
                mask: (c.table_size() - 1) as u32,
            }
        })
        .collect()
}

/// Levels whose entries take at most this many bytes stay in a core's L2 cache (512 KiB to
/// 2 MiB on the x86 machines we run on) through a level's pass, so their kernels skip software
/// prefetching.
const PREFETCH_MIN_BYTES: usize = 256 << 10;

/// Whether a level's table (the `(N + 1)³` entries a dense level uses, or all `T`) is larger
/// than [`PREFETCH_MIN_BYTES`] at `f` floats per entry. Prefetching changes no value.
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
fn worth_prefetching(lv: &Level, f: usize) -> bool {
    let entries = if lv.dense { (lv.res as usize + 1).pow(3) } else { lv.mask as usize + 1 };
    entries * f * 4 > PREFETCH_MIN_BYTES
}

#[inline(always)]
fn clamp01(v: f32) -> f32 {
    // NaN >= 0 is false → 0
    if v >= 0.0 { v.min(1.0) } else { 0.0 }
}

/// The 8 corner entries (table indices) and trilinear weights of `p` at one level; corner `k`
/// is `c + (k & 1, (k >> 1) & 1, k >> 2)`. `DENSE` must equal `lv.dense` (a compile-time
/// switch so that the hot loops carry no per-corner branch).
#[inline(always)]
fn corners<const DENSE: bool>(p: [f32; 3], lv: &Level) -> ([u32; 8], [f32; 8]) {
    let mut c = [0u32; 3];
    let mut f = [0f32; 3];
    for a in 0..3 {
        // f64: the product of a 24-bit mantissa and N ≤ 2^20 is exact, so the fraction is
        // rounded once (f32 would lose up to 1e-4 of a cell at N = 2048)
        let x = clamp01(p[a]) as f64 * lv.res_f;
        let i = (x as u32).min(lv.res - 1);
        c[a] = i;
        f[a] = (x - i as f64) as f32;
    }
    // per-axis index terms, combined by + (dense) or ⊕ (hash)
    let (ix, iy, iz) = if DENSE {
        ([c[0], c[0] + 1], [c[1] * lv.s1, (c[1] + 1) * lv.s1], [c[2] * lv.s2, (c[2] + 1) * lv.s2])
    } else {
        (
            [c[0].wrapping_mul(PRIMES[0]), (c[0] + 1).wrapping_mul(PRIMES[0])],
            [c[1].wrapping_mul(PRIMES[1]), (c[1] + 1).wrapping_mul(PRIMES[1])],
            [c[2].wrapping_mul(PRIMES[2]), (c[2] + 1).wrapping_mul(PRIMES[2])],
        )
    };
    let wx = [1.0 - f[0], f[0]];
    let wy = [1.0 - f[1], f[1]];
    let wz = [1.0 - f[2], f[2]];
    let mut idx = [0u32; 8];
    let mut w = [0f32; 8];
    for k in 0..8 {
        let (i, j, l) = (k & 1, (k >> 1) & 1, k >> 2);
        idx[k] = if DENSE { ix[i] + iy[j] + iz[l] } else { (ix[i] ^ iy[j] ^ iz[l]) & lv.mask };
        w[k] = wx[i] * wy[j] * wz[l];
    }
    (idx, w)
}

/// A multiresolution hash encoding with its parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HashGrid {
    pub config: HashGridConfig,
    /// `[L][T][F]`, see the module doc.
    pub params: Vec<f32>,
}

impl HashGrid {
    /// A grid with parameters uniform in `±1e-4` (instant-ngp's initialisation), drawn with the
    /// counter-based RNG keyed by `(seed, index)`.
    pub fn new(config: HashGridConfig, seed: u64) -> Result<Self, EncodingError> {
        config.validate()?;
        let mut params = vec![0f32; config.n_params()];
        params.par_chunks_mut(1 << 16).enumerate().for_each(|(c, chunk)| {
            for (k, v) in chunk.iter_mut().enumerate() {
                let i = (c << 16) + k;
                *v = (2.0 * rng::uniform_f32(rng::key(&[seed, i as u64])) - 1.0) * 1e-4;
            }
        });
        Ok(Self { config, params })
    }

    /// `L · F`.
    pub fn output_dim(&self) -> usize {
        self.config.output_dim()
    }

    /// Encodes points (see the module doc for the formula).
    ///
    /// # Shapes
    /// - `points`: `[N]` in `[0, 1]³` (clamped)
    /// - `out`: `[N · L · F]`, row-major `[N][L · F]`, overwritten
    pub fn encode(&self, points: &[[f32; 3]], out: &mut [f32]) {
        self.encode_dispatch::<true>(points, out);
    }

    /// [`Self::encode`] on the calling thread only (level-outer over all `points`), for callers
    /// that are parallel over batches themselves: the same values, without a fork and join
    /// per level.
    pub fn encode_serial(&self, points: &[[f32; 3]], out: &mut [f32]) {
        self.encode_dispatch::<false>(points, out);
    }

    /// [`Self::encode_f`] for the configured features per level, in parallel or not.
    fn encode_dispatch<const PAR: bool>(&self, points: &[[f32; 3]], out: &mut [f32]) {
        match self.config.features_per_level {
            1 => self.encode_f::<1, PAR>(points, out),
            2 => self.encode_f::<2, PAR>(points, out),
            4 => self.encode_f::<4, PAR>(points, out),
            8 => self.encode_f::<8, PAR>(points, out),
            f => panic!("unsupported features_per_level {f}"),
        }
    }

    /// Accumulates the gradient of `L = Σ d_out · encode(points)` with respect to the params:
    /// `grad[l][index_l(v)][j] += w_v(p) · d_out[p][l][j]` over points and corners. Exact
    /// (the encoding is linear in the params) and deterministic.
    ///
    /// # Shapes
    /// - `points`: `[N]`, `d_out`: `[N · L · F]` (as `encode`'s `out`)
    /// - `grad`: `[L · T · F]` (as `params`), accumulated into
    pub fn backward(&self, points: &[[f32; 3]], d_out: &[f32], grad: &mut [f32]) {
        self.backward_dispatch(points, d_out, grad, None);
    }

    /// [`Self::backward`] that also sets `touched[l · T + i] = true` for every table entry a
    /// point's corner reached (with a nonzero weight or not), for [`Adam::step_sparse`].
    ///
    /// # Shapes
    /// As [`Self::backward`]; `touched`: `[L · T]` (one flag per entry, not per float).
    pub fn backward_touched(&self, points: &[[f32; 3]], d_out: &[f32], grad: &mut [f32], touched: &mut [bool]) {
        assert_eq!(touched.len(), self.config.levels * self.config.table_size(), "touched must hold L · T flags");
        self.backward_dispatch(points, d_out, grad, Some(touched));
    }

    /// [`Self::backward_touched`] followed by [`Adam::step_sparse`] on the table, fused per
    /// level: each level's gradient is summed into a per-thread scratch table and the level's
    /// touched entries are updated (and the scratch cleared) straight away, while the gradient
    /// is still in cache. The same sums in the same order and the same elementwise updates, so
    /// `params` and the moments are bit-identical to the two calls in turn; the difference is
    /// that no gradient the size of the whole table is written, left to go cold, and read back
    /// (and the table's gradient needs `threads` levels' memory instead of `L`).
    ///
    /// The encoding's gradient comes level-major, `d_lvl[(l · N + k) · F + j]` (as
    /// [`crate::mlp::HashMlp::train_groups_blocked`] with `block = F` writes it, or
    /// [`Self::level_major`] makes it from the row-major `d_out` of [`Self::backward`]), so that
    /// each level's task streams its own contiguous slice.
    ///
    /// # Shapes
    /// `points`: `[N]`; `d_lvl`: `[L][N][F]`; `adam` holds `L · T · F` moments.
    pub fn backward_adam(&mut self, points: &[[f32; 3]], d_lvl: &[f32], adam: &mut Adam, lr: f32, scratch: &mut BackwardScratch) -> BackwardAdamStats {
        scratch.fit(rayon::current_num_threads());
        match self.config.features_per_level {
            1 => self.backward_adam_f::<1>(points, d_lvl, adam, lr, scratch),
            2 => self.backward_adam_f::<2>(points, d_lvl, adam, lr, scratch),
            4 => self.backward_adam_f::<4>(points, d_lvl, adam, lr, scratch),
            8 => self.backward_adam_f::<8>(points, d_lvl, adam, lr, scratch),
            f => panic!("unsupported features_per_level {f}"),
        }
    }

    /// The row-major encoding gradient `d_out` (`[N][L · F]`) copied level-major
    /// (`[L][N][F]`), the layout [`Self::backward_adam`] reads.
    pub fn level_major(&self, d_out: &[f32]) -> Vec<f32> {
        let n = d_out.len() / self.output_dim().max(1);
        assert_eq!(d_out.len(), n * self.output_dim(), "d_out must hold N · L · F floats");
        match self.config.features_per_level {
            1 => level_major::<1>(d_out, n, self.config.levels),
            2 => level_major::<2>(d_out, n, self.config.levels),
            4 => level_major::<4>(d_out, n, self.config.levels),
            8 => level_major::<8>(d_out, n, self.config.levels),
            f => panic!("unsupported features_per_level {f}"),
        }
    }

    fn backward_adam_f<const F: usize>(&mut self, points: &[[f32; 3]], d_lvl: &[f32], adam: &mut Adam, lr: f32, scratch: &BackwardScratch) -> BackwardAdamStats {
        use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
        let start = std::time::Instant::now();
        let n = points.len();
        assert_eq!(d_lvl.len(), n * self.output_dim(), "d_lvl must hold L · N · F floats");
        assert!(adam.m.len() == self.params.len() && adam.v.len() == self.params.len(), "Adam: length mismatch");
        adam.step += 1;
        let k = AdamStep::new(&adam.config, adam.step, lr);
        if n == 0 {
            return BackwardAdamStats::default();
        }
        let lvs = levels(&self.config);
        let t = self.config.table_size();
        let (scatter_ns, adam_ns) = (AtomicU64::new(0), AtomicU64::new(0));
        let slots = &scratch.slots;
        let updated = self
            .params
            .par_chunks_mut(t * F)
            .zip(adam.m.par_chunks_mut(t * F))
            .zip(adam.v.par_chunks_mut(t * F))
            .zip(d_lvl.par_chunks(n * F))
            .zip(lvs.par_iter())
            .with_max_len(1)
            .map(|((((p, m), v), d_l), lv)| {
                let t0 = std::time::Instant::now();
                // A task runs on one thread and makes no nested rayon call, and there is a
                // slot per thread of the pool ([`BackwardScratch::fit`]), so its thread's slot
                // is free; the lock makes that safe in every case.
                let slot = &slots[rayon::current_thread_index().unwrap_or(0) % slots.len()];
                let mut buf = slot.lock().unwrap_or_else(|poisoned| {
                    // A panic in a level left the buffers in an unknown state: clear them.
                    let mut b = poisoned.into_inner();
                    b.grad.fill(0.0);
                    b.touched.fill(false);
                    b
                });
                let LevelBuffers { grad, touched } = &mut *buf;
                if grad.len() != t * F || touched.len() != t {
                    *grad = vec![0.0; t * F];
                    *touched = vec![false; t];
                }
                if lv.dense {
                    backward_level::<F, true, true>(points, lv, d_l, grad, touched);
                } else {
                    backward_level::<F, false, true>(points, lv, d_l, grad, touched);
                }
                let t1 = std::time::Instant::now();
                let updated = p
                    .chunks_mut(ADAM_ENTRIES * F)
                    .zip(grad.chunks_mut(ADAM_ENTRIES * F))
                    .zip(m.chunks_mut(ADAM_ENTRIES * F))
                    .zip(v.chunks_mut(ADAM_ENTRIES * F))
                    .zip(touched.chunks_mut(ADAM_ENTRIES))
                    .map(|((((p, g), m), v), tch)| sparse_update(p, g, m, v, tch, F, &k))
                    .sum::<usize>();
                scatter_ns.fetch_add((t1 - t0).as_nanos() as u64, Relaxed);
                adam_ns.fetch_add(t1.elapsed().as_nanos() as u64, Relaxed);
                updated
            })
            .sum();
        let wall = start.elapsed().as_secs_f64();
        let (s, a) = (scatter_ns.into_inner() as f64, adam_ns.into_inner() as f64);
        let share = if s + a > 0.0 { s / (s + a) } else { 1.0 };
        BackwardAdamStats { updated, backward_seconds: wall * share, adam_seconds: wall * (1.0 - share) }
    }

    fn backward_dispatch(&self, points: &[[f32; 3]], d_out: &[f32], grad: &mut [f32], touched: Option<&mut [bool]>) {
        match self.config.features_per_level {
            1 => self.backward_f::<1>(points, d_out, grad, touched),
            2 => self.backward_f::<2>(points, d_out, grad, touched),
            4 => self.backward_f::<4>(points, d_out, grad, touched),
            8 => self.backward_f::<8>(points, d_out, grad, touched),
            f => panic!("unsupported features_per_level {f}"),
        }
    }

    fn encode_f<const F: usize, const PAR: bool>(&self, points: &[[f32; 3]], out: &mut [f32]) {
        let lf = self.output_dim();
        assert_eq!(out.len(), points.len() * lf, "out must hold N · L · F floats");
        assert_eq!(self.params.len(), self.config.n_params());
        let lvs = levels(&self.config);
        let tf = self.config.table_size() * F;
        // At most POINT_CHUNK points per task, in a multiple of the threads' count of tasks of
        // equal size (three chunks of a 12k-point batch kept one of two cores idle a third of
        // the time). A point's encoding does not depend on its chunk.
        let threads = rayon::current_num_threads().max(1);
        let tasks = points.len().div_ceil(POINT_CHUNK).div_ceil(threads) * threads;
        let chunk = points.len().div_ceil(tasks.max(1)).max(1);
        // Level-outer: one level's table (≤ T·F floats) stays in cache while every point
        // reads it; rotating through all levels per point chunk thrashes the last-level cache.
        for (l, lv) in lvs.iter().enumerate() {
            let table = &self.params[l * tf..(l + 1) * tf];
            let level = |pts: &[[f32; 3]], o: &mut [f32]| {
                if lv.dense {
                    encode_level::<F, true>(pts, lv, table, &mut o[l * F..], lf);
                } else {
                    encode_level::<F, false>(pts, lv, table, &mut o[l * F..], lf);
                }
            };
            if PAR {
                points.par_chunks(chunk).zip(out.par_chunks_mut(chunk * lf)).for_each(|(pts, o)| level(pts, o));
            } else if !points.is_empty() {
                level(points, out);
            }
        }
    }

    fn backward_f<const F: usize>(&self, points: &[[f32; 3]], d_out: &[f32], grad: &mut [f32], touched: Option<&mut [bool]>) {
        let lf = self.output_dim();
        assert_eq!(d_out.len(), points.len() * lf, "d_out must hold N · L · F floats");
        assert_eq!(grad.len(), self.config.n_params(), "grad must have the params' shape");
        let lvs = levels(&self.config);
        let tf = self.config.table_size() * F;
        let n = points.len();
        if n == 0 {
            return;
        }
        let d_lvl = level_major::<F>(d_out, n, self.config.levels);
        let t = self.config.table_size();
        match touched {
            None => grad.par_chunks_mut(tf).zip(d_lvl.par_chunks(n * F)).zip(lvs.par_iter()).with_max_len(1).for_each(
                |((g, d_l), lv)| {
                    if lv.dense {
                        backward_level::<F, true, false>(points, lv, d_l, g, &mut []);
                    } else {
                        backward_level::<F, false, false>(points, lv, d_l, g, &mut []);
                    }
                },
            ),
            Some(touched) => grad
                .par_chunks_mut(tf)
                .zip(touched.par_chunks_mut(t))
                .zip(d_lvl.par_chunks(n * F))
                .zip(lvs.par_iter())
                .with_max_len(1)
                .for_each(|(((g, tl), d_l), lv)| {
                    if lv.dense {
                        backward_level::<F, true, true>(points, lv, d_l, g, tl);
                    } else {
                        backward_level::<F, false, true>(points, lv, d_l, g, tl);
                    }
                }),
        }
    }
}

/// `d_out` (`[N][L · F]`) copied level-major (`[L][N][F]`), so that each level's backward task
/// streams its own contiguous slice instead of one cache line per point; filled in parallel over
/// fixed point chunks.
fn level_major<const F: usize>(d_out: &[f32], n: usize, levels: usize) -> Vec<f32> {
    let lf = levels * F;
    let mut d_lvl = vec![0f32; d_out.len()];
    if levels > 1 && n > 0 {
        let mut per_chunk: Vec<Vec<&mut [f32]>> = (0..n.div_ceil(POINT_CHUNK)).map(|_| Vec::new()).collect();
        for lvl in d_lvl.chunks_mut(n * F) {
            for (c, piece) in lvl.chunks_mut(POINT_CHUNK * F).enumerate() {
                per_chunk[c].push(piece);
            }
        }
        per_chunk.into_par_iter().enumerate().for_each(|(c, mut pieces)| {
            let rows = &d_out[c * POINT_CHUNK * lf..((c + 1) * POINT_CHUNK).min(n) * lf];
            crate::kernels::scatter_blocks::<F>(rows, &mut pieces);
        });
    } else {
        d_lvl.copy_from_slice(d_out);
    }
    d_lvl
}

/// One level's table gradient and touched flags, all zero (false) between uses.
#[derive(Debug, Default)]
struct LevelBuffers {
    grad: Vec<f32>,
    touched: Vec<bool>,
}

/// Working memory of [`HashGrid::backward_adam`]: one level's table gradient and touched
/// flags per worker thread (a few MiB in all, instead of a gradient the size of the whole
/// table), reused from step to step so that it stays in cache.
#[derive(Debug)]
pub struct BackwardScratch {
    slots: Vec<std::sync::Mutex<LevelBuffers>>,
}

impl BackwardScratch {
    /// Scratch for the current rayon pool's threads (buffers are sized on first use; a call
    /// from a larger pool adds slots).
    pub fn new() -> Self {
        let mut s = Self { slots: Vec::new() };
        s.fit(rayon::current_num_threads());
        s
    }

    /// At least one slot per thread of a pool of `threads`.
    fn fit(&mut self, threads: usize) {
        while self.slots.len() < threads.max(1) {
            self.slots.push(Default::default());
        }
    }
}

impl Default for BackwardScratch {
    fn default() -> Self {
        Self::new()
    }
}

/// What [`HashGrid::backward_adam`] did: the entries it updated, and its wall time split into
/// the backward (each level's scatter) and the Adam updates, in proportion to the CPU time each
/// part of the fused level tasks took.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BackwardAdamStats {
    pub updated: usize,
    pub backward_seconds: f64,
    pub adam_seconds: f64,
}

/// One level of the forward: `out[k · stride + j] = enc_l(pts[k])[j]`.
#[inline(always)]
fn encode_level<const F: usize, const DENSE: bool>(pts: &[[f32; 3]], lv: &Level, table: &[f32], mut out: &mut [f32], stride: usize) {
    #[cfg(target_arch = "x86_64")]
    let pts = if F == 2 && simd::avx2() {
        // SAFETY: AVX2 is present (checked at run time).
        #[allow(unsafe_code)]
        let done = unsafe { simd::encode_level_f2_avx2::<DENSE>(pts, lv, table, out, stride) };
        // (`out` may end right after the last point's features, short of a whole stride)
        let from = (done * stride).min(out.len());
        out = &mut out[from..];
        &pts[done..]
    } else {
        pts
    };
    encode_level_scalar::<F, DENSE>(pts, lv, table, out, stride);
}

/// [`encode_level`] one point at a time (the reference the SIMD kernel reproduces bit for bit).
#[inline(always)]
fn encode_level_scalar<const F: usize, const DENSE: bool>(pts: &[[f32; 3]], lv: &Level, table: &[f32], out: &mut [f32], stride: usize) {
    for (k, &p) in pts.iter().enumerate() {
        let (idx, w) = corners::<DENSE>(p, lv);
        let mut acc = [0f32; F];
        for c in 0..8 {
            let e = &table[idx[c] as usize * F..idx[c] as usize * F + F];
            for j in 0..F {
                acc[j] += w[c] * e[j];
            }
        }
        out[k * stride..k * stride + F].copy_from_slice(&acc);
    }
}


/// One level of the backward, points in index order: `g[index(v)] += w_v(p) · d` (and, when
/// `MARK`, `touched[index(v)] = true`).
#[inline(always)]
fn backward_level<const F: usize, const DENSE: bool, const MARK: bool>(
    points: &[[f32; 3]],
    lv: &Level,
    d_l: &[f32],
    g: &mut [f32],
    touched: &mut [bool],
) {
    #[cfg(target_arch = "x86_64")]
    let (points, d_l) = if simd::avx2() {
        // SAFETY: AVX2 is present (checked at run time).
        #[allow(unsafe_code)]
        let done = unsafe { simd::backward_level_avx2::<F, DENSE, MARK>(points, lv, d_l, g, touched) };
        (&points[done..], &d_l[done * F..])
    } else {
        (points, d_l)
    };
    backward_level_scalar::<F, DENSE, MARK>(points, lv, d_l, g, touched);
}

/// [`backward_level`] one point at a time (the reference the SIMD kernel reproduces bit for
/// bit).
#[inline(always)]
fn backward_level_scalar<const F: usize, const DENSE: bool, const MARK: bool>(
    points: &[[f32; 3]],
    lv: &Level,
    d_l: &[f32],
    g: &mut [f32],
    touched: &mut [bool],
) {
    for (&p, d) in points.iter().zip(d_l.chunks_exact(F)) {
        let (idx, w) = corners::<DENSE>(p, lv);
        scatter_point::<F, MARK>(idx, w, d, g, touched);
    }
}

/// One point's share of a level's backward: `g[idx[c]] += w[c] · d` corner by corner, in
/// corner order (and, when `MARK`, `touched[idx[c]] = true`). Shared by the scalar and SIMD
/// paths so that their sums are the same operations in the same order.
#[inline(always)]
fn scatter_point<const F: usize, const MARK: bool>(idx: [u32; 8], w: [f32; 8], d: &[f32], g: &mut [f32], touched: &mut [bool]) {
    for c in 0..8 {
        let i = idx[c] as usize;
        if MARK {
            touched[i] = true;
        }
        let e = &mut g[i * F..i * F + F];
        for j in 0..F {
            e[j] += w[c] * d[j];
        }
    }
}
