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
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

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

/// The forward of two-feature levels eight points at a time with AVX2 (gathers for the
/// table reads). Every lane does exactly the scalar [`corners`] / [`encode_level_scalar`]
/// arithmetic in the same order (f64 cell coordinates, no fused multiply-add), so the output is
/// bit-identical to the scalar path on any machine.
#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod simd {
    use super::{AdamStep, Level, PRIMES, scatter_point};
    use std::arch::x86_64::*;
    use std::sync::OnceLock;

    /// Whether the AVX2 kernel can run here (checked once).
    pub(super) fn avx2() -> bool {
        static HAS: OnceLock<bool> = OnceLock::new();
        *HAS.get_or_init(|| std::arch::is_x86_feature_detected!("avx2"))
    }

    /// Cell index (`c`) and fraction (`f`) of eight coordinates along one axis, as
    /// `clamp01(v) as f64 · N`, `min(floor, N − 1)`, `(x − c) as f32`.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn axis(v: __m256, res_f: __m256d, res_m1: __m256i) -> (__m256i, __m256) {
        // clamp01: NaN and negatives to +0 (maxps returns its second operand for NaN), then ≤ 1.
        // (-0.0 becomes +0.0 where the scalar path keeps -0.0: the fraction's sign only reaches
        // zero weights, whose products add nothing to the sums.)
        let v = _mm256_min_ps(_mm256_max_ps(v, _mm256_setzero_ps()), _mm256_set1_ps(1.0));
        let lo = _mm256_mul_pd(_mm256_cvtps_pd(_mm256_castps256_ps128(v)), res_f);
        let hi = _mm256_mul_pd(_mm256_cvtps_pd(_mm256_extractf128_ps::<1>(v)), res_f);
        let (ilo, ihi) = (_mm256_cvttpd_epi32(lo), _mm256_cvttpd_epi32(hi));
        let i = _mm256_min_epi32(_mm256_set_m128i(ihi, ilo), res_m1);
        let flo = _mm256_sub_pd(lo, _mm256_cvtepi32_pd(_mm256_castsi256_si128(i)));
        let fhi = _mm256_sub_pd(hi, _mm256_cvtepi32_pd(_mm256_extracti128_si256::<1>(i)));
        (i, _mm256_set_m128(_mm256_cvtpd_ps(fhi), _mm256_cvtpd_ps(flo)))
    }

    /// Encodes the first `8 · floor(n / 8)` points of `pts` at level `lv` (two features);
    /// returns how many it did.
    ///
    /// # Safety
    /// AVX2 must be available; `table` must hold the level's `T · 2` floats with every index
    /// the level can produce inside it (as the scalar path requires).
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn encode_level_f2_avx2<const DENSE: bool>(pts: &[[f32; 3]], lv: &Level, table: &[f32], out: &mut [f32], stride: usize) -> usize {
        let n8 = pts.len() / 8 * 8;
        assert!(table.len() / 2 < i32::MAX as usize / 8, "table too large for 64-bit pair gathers");
        assert!(n8 == 0 || out.len() >= (n8 - 1) * stride + 2, "output too short");
        let k = Consts::new(lv);
        let pairs = table.as_ptr() as *const f64;
        let dup_lo = _mm256_setr_epi32(0, 0, 1, 1, 2, 2, 3, 3);
        let dup_hi = _mm256_setr_epi32(4, 4, 5, 5, 6, 6, 7, 7);
        if n8 == 0 {
            return 0;
        }
        // As in the backward: the next eight points' corners one batch ahead, their entries
        // prefetched while this batch's gathers wait.
        let mut ring = [corners8::<DENSE>(&pts[..8], &k), corners8::<DENSE>(&pts[if n8 > 8 { 8 } else { 0 }..][..8], &k)];
        let on = super::worth_prefetching(lv, 2);
        prefetch_entries::<2>(on, &ring[0].0, table.as_ptr(), std::ptr::null());
        prefetch_entries::<2>(on, &ring[1].0, table.as_ptr(), std::ptr::null());
        for (b, k0) in (0..n8).step_by(8).enumerate() {
            let (idx, w) = ring[b % 2];
            if k0 + 16 < n8 {
                ring[b % 2] = corners8::<DENSE>(&pts[k0 + 16..k0 + 24], &k);
                prefetch_entries::<2>(on, &ring[b % 2].0, table.as_ptr(), std::ptr::null());
            }
            // Each corner's two features are one 64-bit gather lane (an entry's pair), four
            // points per gather: half the gathered elements of one 32-bit gather per feature.
            // Accumulators hold (feature 0, feature 1) pairs of points 0–3 and 4–7, each lane
            // summing the same products in the same corner order as the scalar path.
            let (mut lo, mut hi) = (_mm256_setzero_ps(), _mm256_setzero_ps());
            for c in 0..8 {
                // SAFETY: every index is a table entry of this level (as in the scalar path), so
                // its pair lies inside `table`.
                let (e_lo, e_hi) = unsafe {
                    (
                        _mm256_castpd_ps(_mm256_i32gather_pd::<8>(pairs, _mm256_castsi256_si128(idx[c]))),
                        _mm256_castpd_ps(_mm256_i32gather_pd::<8>(pairs, _mm256_extracti128_si256::<1>(idx[c]))),
                    )
                };
                lo = _mm256_add_ps(lo, _mm256_mul_ps(_mm256_permutevar8x32_ps(w[c], dup_lo), e_lo));
                hi = _mm256_add_ps(hi, _mm256_mul_ps(_mm256_permutevar8x32_ps(w[c], dup_hi), e_hi));
            }
            let mut r = [0f32; 16];
            // SAFETY: the array holds 16 floats.
            unsafe {
                _mm256_storeu_ps(r.as_mut_ptr(), lo);
                _mm256_storeu_ps(r.as_mut_ptr().add(8), hi);
            }
            for j in 0..8 {
                let o = (k0 + j) * stride;
                out[o..o + 2].copy_from_slice(&r[2 * j..2 * j + 2]);
            }
        }
        n8
    }

    /// One chunk of [`super::Adam::step_sparse`] for two parameters per flag: entries four at a
    /// time (eight floats), skipping groups with no touched entry; a group with one is computed
    /// in all lanes and blended into the touched entries' lanes only, then its flags cleared
    /// and its touched gradients zeroed. Lane for lane the scalar update, operation for
    /// operation (`gᵢ` finite or 0; `m = β₁m + (1−β₁)g`; `v = β₂v + ((1−β₂)g)g`;
    /// `p −= (lr·(m/c₁)) / (√(v/c₂) + ε)`; no fused multiply-add), so the same bits. Returns the
    /// number of touched entries.
    ///
    /// # Safety
    /// AVX2 must be available.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn adam_pairs_avx2(p: &mut [f32], g: &mut [f32], m: &mut [f32], v: &mut [f32], tch: &mut [bool], k: &AdamStep) -> usize {
        let n = tch.len();
        assert!(p.len() == 2 * n && g.len() == 2 * n && m.len() == 2 * n && v.len() == 2 * n, "two parameters per flag");
        let set = |x: f32| _mm256_set1_ps(x);
        let (b1, ob1, b2, ob2) = (set(k.b1), set(1.0 - k.b1), set(k.b2), set(1.0 - k.b2));
        let (eps, lr, c1, c2, zero) = (set(k.eps), set(k.lr), set(k.c1), set(k.c2), _mm256_setzero_ps());
        let n4 = n / 4 * 4;
        let mut updated = 0usize;
        for e0 in (0..n4).step_by(4) {
            let f = [tch[e0], tch[e0 + 1], tch[e0 + 2], tch[e0 + 3]];
            if f == [false; 4] {
                continue;
            }
            updated += f.iter().filter(|&&x| x).count();
            tch[e0..e0 + 4].fill(false);
            let lane = |x: bool| -(x as i32);
            let mask = _mm256_castsi256_ps(_mm256_setr_epi32(lane(f[0]), lane(f[0]), lane(f[1]), lane(f[1]), lane(f[2]), lane(f[2]), lane(f[3]), lane(f[3])));
            let i = 2 * e0;
            let (ps, gs, ms, vs) = (&mut p[i..i + 8], &mut g[i..i + 8], &mut m[i..i + 8], &mut v[i..i + 8]);
            // SAFETY: each slice holds 8 floats.
            let (pv, gv, mv, vv) = unsafe { (_mm256_loadu_ps(ps.as_ptr()), _mm256_loadu_ps(gs.as_ptr()), _mm256_loadu_ps(ms.as_ptr()), _mm256_loadu_ps(vs.as_ptr())) };
            // Finite: g − g is 0 (NaN for an infinity or NaN).
            let gi = _mm256_and_ps(_mm256_cmp_ps::<_CMP_EQ_OQ>(_mm256_sub_ps(gv, gv), zero), gv);
            let m_new = _mm256_add_ps(_mm256_mul_ps(b1, mv), _mm256_mul_ps(ob1, gi));
            let v_new = _mm256_add_ps(_mm256_mul_ps(b2, vv), _mm256_mul_ps(_mm256_mul_ps(ob2, gi), gi));
            let step = _mm256_div_ps(_mm256_mul_ps(lr, _mm256_div_ps(m_new, c1)), _mm256_add_ps(_mm256_sqrt_ps(_mm256_div_ps(v_new, c2)), eps));
            let p_new = _mm256_sub_ps(pv, step);
            // SAFETY: as the loads.
            unsafe {
                _mm256_storeu_ps(ps.as_mut_ptr(), _mm256_blendv_ps(pv, p_new, mask));
                _mm256_storeu_ps(gs.as_mut_ptr(), _mm256_blendv_ps(gv, zero, mask));
                _mm256_storeu_ps(ms.as_mut_ptr(), _mm256_blendv_ps(mv, m_new, mask));
                _mm256_storeu_ps(vs.as_mut_ptr(), _mm256_blendv_ps(vv, v_new, mask));
            }
        }
        for (e, hit) in tch.iter_mut().enumerate().skip(n4) {
            if !std::mem::take(hit) {
                continue;
            }
            updated += 1;
            for i in 2 * e..2 * e + 2 {
                k.update(std::mem::take(&mut g[i]), &mut p[i], &mut m[i], &mut v[i]);
            }
        }
        updated
    }

    /// Prefetches (into every cache level) the table entries of `F` floats of eight points'
    /// corners `idx`, and the one-byte flags at the same indices of `flags` unless it is null;
    /// nothing when `!on` (a level whose table stays in cache, see
    /// [`super::worth_prefetching`]). Flags are fetched for the corners at the cell's lower x
    /// only: the upper-x neighbour's index is the next one on dense levels and differs only in
    /// its low bits on hashed ones (x's prime is 1), so its flag shares the 64-byte line 63 times
    /// in 64.
    #[inline]
    #[target_feature(enable = "avx2")]
    #[allow(clippy::needless_range_loop)] // index loops on purpose, see below
    fn prefetch_entries<const F: usize>(on: bool, idx: &[__m256i; 8], table: *const f32, flags: *const bool) {
        if !on {
            return;
        }
        let mut lanes = [[0u32; 8]; 8];
        for c in 0..8 {
            // SAFETY: each array holds 8 lanes.
            unsafe { _mm256_storeu_si256(lanes[c].as_mut_ptr() as *mut __m256i, idx[c]) };
        }
        // Plain index loops (constant bounds, no iterator adaptors): this runs once per eight
        // points and level, and a flattening iterator's bookkeeping cost as much as the scatter.
        for c in 0..8 {
            for j in 0..8 {
                // A prefetch never faults and reads nothing into the program; `wrapping_add`
                // keeps the address computation defined whatever the index.
                _mm_prefetch::<_MM_HINT_T0>(table.wrapping_add(lanes[c][j] as usize * F) as *const i8);
            }
        }
        if !flags.is_null() {
            for c in (0..8).step_by(2) {
                for j in 0..8 {
                    _mm_prefetch::<_MM_HINT_T0>(flags.wrapping_add(lanes[c][j] as usize) as *const i8);
                }
            }
        }
    }

    /// One level's constants in registers.
    struct Consts {
        res_f: __m256d,
        res_m1: __m256i,
        s1: __m256i,
        s2: __m256i,
        primes: [__m256i; 3],
        mask: __m256i,
    }

    impl Consts {
        #[inline]
        #[target_feature(enable = "avx2")]
        fn new(lv: &Level) -> Self {
            Self {
                res_f: _mm256_set1_pd(lv.res_f),
                res_m1: _mm256_set1_epi32((lv.res - 1) as i32),
                s1: _mm256_set1_epi32(lv.s1 as i32),
                s2: _mm256_set1_epi32(lv.s2 as i32),
                primes: PRIMES.map(|p| _mm256_set1_epi32(p as i32)),
                mask: _mm256_set1_epi32(lv.mask as i32),
            }
        }
    }

    /// The 8 corners' table indices and trilinear weights of eight points (`pts[..8]`), corner
    /// `c` in register `c`, lane `j` for point `j`: lane for lane the scalar
    /// [`super::corners`].
    #[inline]
    #[target_feature(enable = "avx2")]
    fn corners8<const DENSE: bool>(pts: &[[f32; 3]], k: &Consts) -> ([__m256i; 8], [__m256; 8]) {
        let one = _mm256_set1_epi32(1);
        let onef = _mm256_set1_ps(1.0);
        let mut coord = [[0f32; 8]; 3];
        for (j, p) in pts[..8].iter().enumerate() {
            coord[0][j] = p[0];
            coord[1][j] = p[1];
            coord[2][j] = p[2];
        }
        // SAFETY: the arrays hold 8 floats each.
        let (cx, fx) = axis(unsafe { _mm256_loadu_ps(coord[0].as_ptr()) }, k.res_f, k.res_m1);
        let (cy, fy) = axis(unsafe { _mm256_loadu_ps(coord[1].as_ptr()) }, k.res_f, k.res_m1);
        let (cz, fz) = axis(unsafe { _mm256_loadu_ps(coord[2].as_ptr()) }, k.res_f, k.res_m1);
        let (cx1, cy1, cz1) = (_mm256_add_epi32(cx, one), _mm256_add_epi32(cy, one), _mm256_add_epi32(cz, one));
        let (ix, iy, iz) = if DENSE {
            ([cx, cx1], [_mm256_mullo_epi32(cy, k.s1), _mm256_mullo_epi32(cy1, k.s1)], [_mm256_mullo_epi32(cz, k.s2), _mm256_mullo_epi32(cz1, k.s2)])
        } else {
            (
                [_mm256_mullo_epi32(cx, k.primes[0]), _mm256_mullo_epi32(cx1, k.primes[0])],
                [_mm256_mullo_epi32(cy, k.primes[1]), _mm256_mullo_epi32(cy1, k.primes[1])],
                [_mm256_mullo_epi32(cz, k.primes[2]), _mm256_mullo_epi32(cz1, k.primes[2])],
            )
        };
        let wx = [_mm256_sub_ps(onef, fx), fx];
        let wy = [_mm256_sub_ps(onef, fy), fy];
        let wz = [_mm256_sub_ps(onef, fz), fz];
        let mut idx = [_mm256_setzero_si256(); 8];
        let mut w = [_mm256_setzero_ps(); 8];
        for c in 0..8 {
            let (i, j, l) = (c & 1, (c >> 1) & 1, c >> 2);
            idx[c] = if DENSE {
                _mm256_add_epi32(_mm256_add_epi32(ix[i], iy[j]), iz[l])
            } else {
                _mm256_and_si256(_mm256_xor_si256(_mm256_xor_si256(ix[i], iy[j]), iz[l]), k.mask)
            };
            w[c] = _mm256_mul_ps(_mm256_mul_ps(wx[i], wy[j]), wz[l]);
        }
        (idx, w)
    }

    /// [`super::backward_level`] for the first `8 · floor(n / 8)` points, their corners
    /// computed eight at a time; the scatter is scalar, point by point and corner by corner as
    /// in the scalar path, so the sums are bit-identical. Returns how many points it did.
    ///
    /// # Safety
    /// AVX2 must be available.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn backward_level_avx2<const F: usize, const DENSE: bool, const MARK: bool>(
        points: &[[f32; 3]],
        lv: &Level,
        d_l: &[f32],
        g: &mut [f32],
        touched: &mut [bool],
    ) -> usize {
        let n8 = points.len() / 8 * 8;
        if n8 == 0 {
            return 0;
        }
        let k = Consts::new(lv);
        let (mut idx, mut w) = ([[0u32; 8]; 8], [[0f32; 8]; 8]);
        // The corners of the next eight points are computed one batch ahead and their gradient
        // entries (and flags) prefetched, so that the scatter's read-modify-writes find them in
        // cache instead of waiting on each miss in turn. Prefetches change no value.
        let flags = if MARK { touched.as_ptr() } else { std::ptr::null() };
        let mut ring = [corners8::<DENSE>(&points[..8], &k), corners8::<DENSE>(&points[if n8 > 8 { 8 } else { 0 }..][..8], &k)];
        let on = super::worth_prefetching(lv, F);
        prefetch_entries::<F>(on, &ring[0].0, g.as_ptr(), flags);
        prefetch_entries::<F>(on, &ring[1].0, g.as_ptr(), flags);
        for (b, k0) in (0..n8).step_by(8).enumerate() {
            let (vi, vw) = ring[b % 2];
            if k0 + 16 < n8 {
                ring[b % 2] = corners8::<DENSE>(&points[k0 + 16..k0 + 24], &k);
                prefetch_entries::<F>(on, &ring[b % 2].0, g.as_ptr(), flags);
            }
            for c in 0..8 {
                // SAFETY: each array holds 8 lanes.
                unsafe {
                    _mm256_storeu_si256(idx[c].as_mut_ptr() as *mut __m256i, vi[c]);
                    _mm256_storeu_ps(w[c].as_mut_ptr(), vw[c]);
                }
            }
            for j in 0..8 {
                let d = &d_l[(k0 + j) * F..(k0 + j) * F + F];
                scatter_point::<F, MARK>(std::array::from_fn(|c| idx[c][j]), std::array::from_fn(|c| w[c][j]), d, g, touched);
            }
        }
        n8
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
const ADAM_ENTRIES: usize = 1 << 14;
const _: () = assert!(ADAM_ENTRIES <= 1 << 16, "entry indices are u16 within a chunk");

/// The sparse Adam of up to [`ADAM_ENTRIES`] entries of `group` parameters: the entries flagged
/// in `tch` are updated, their gradients zeroed and their flags cleared. Returns how many.
fn sparse_update(p: &mut [f32], g: &mut [f32], m: &mut [f32], v: &mut [f32], tch: &mut [bool], group: usize, k: &AdamStep) -> usize {
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
struct AdamStep {
    b1: f32,
    b2: f32,
    eps: f32,
    lr: f32,
    c1: f32,
    c2: f32,
}

impl AdamStep {
    fn new(config: &AdamConfig, step: u64, lr: f32) -> Self {
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
    fn update(&self, g: f32, p: &mut f32, m: &mut f32, v: &mut f32) {
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

#[cfg(test)]
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;

    fn cfg(levels: usize, f: usize, log2_t: u32, nmin: u32, nmax: u32) -> HashGridConfig {
        HashGridConfig { levels, features_per_level: f, log2_table_size: log2_t, base_resolution: nmin, finest_resolution: nmax }
    }

    fn rnd(i: u64) -> f32 {
        rng::uniform_f32(rng::key(&[4242, i]))
    }

    fn random_points(n: usize, seed: u64) -> Vec<[f32; 3]> {
        (0..n as u64).map(|i| [0, 1, 2].map(|a| rnd(seed * 1_000_003 + 3 * i + a))).collect()
    }

    /// Naive f64 reference: per point, per level, independent of the fast path's code.
    fn reference(c: &HashGridConfig, params: &[f64], p: [f32; 3]) -> Vec<f64> {
        let (t, f) = (c.table_size(), c.features_per_level);
        let b = if c.levels > 1 { (c.finest_resolution as f64 / c.base_resolution as f64).powf(1.0 / (c.levels - 1) as f64) } else { 1.0 };
        let mut out = vec![0.0; c.output_dim()];
        for l in 0..c.levels {
            let n = (c.base_resolution as f64 * b.powi(l as i32) + 1e-6).floor() as u64;
            let dense = (n + 1).pow(3) <= t as u64;
            let x: Vec<f64> = p.iter().map(|&v| (v as f64).clamp(0.0, 1.0) * n as f64).collect();
            let cell: Vec<u64> = x.iter().map(|&v| (v.floor() as u64).min(n - 1)).collect();
            for dz in 0..2u64 {
                for dy in 0..2u64 {
                    for dx in 0..2u64 {
                        let v = [cell[0] + dx, cell[1] + dy, cell[2] + dz];
                        let mut w = 1.0;
                        for a in 0..3 {
                            let fr = x[a] - cell[a] as f64;
                            w *= if [dx, dy, dz][a] == 1 { fr } else { 1.0 - fr };
                        }
                        let i = if dense {
                            (v[0] + v[1] * (n + 1) + v[2] * (n + 1) * (n + 1)) as usize
                        } else {
                            let h = v[0] ^ ((v[1] * 2_654_435_761) & 0xFFFF_FFFF) ^ ((v[2] * 805_459_861) & 0xFFFF_FFFF);
                            (h as usize) % t
                        };
                        for j in 0..f {
                            out[l * f + j] += w * params[(l * t + i) * f + j];
                        }
                    }
                }
            }
        }
        out
    }

    /// Random points in the cube plus combinations of special coordinates (±0, the cube's
    /// faces, outside it, NaN, ±inf, denormal-small, just below 1).
    fn points_with_specials() -> Vec<[f32; 3]> {
        let mut pts = random_points(1000, 9);
        let special = [0.0, -0.0, 1.0, 0.5, 0.25, 1.0 / 3.0, -0.25, 1.5, f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 1e-30, 1.0 - 1e-7];
        for (i, &a) in special.iter().enumerate() {
            for &b in &special {
                pts.push([a, b, special[(i * 7 + 3) % special.len()]]);
            }
        }
        pts
    }

    fn grid(c: HashGridConfig, seed: u64, scale: f32) -> HashGrid {
        let mut g = HashGrid::new(c, seed).unwrap();
        // larger params than the ±1e-4 init so that differences are visible
        for (i, p) in g.params.iter_mut().enumerate() {
            *p = (rnd(1_000_000_007 + i as u64) - 0.5) * scale;
        }
        g
    }

    #[test]
    fn resolutions_follow_the_paper() {
        let c = cfg(16, 2, 19, 16, 2048);
        assert_eq!(c.resolution(0), 16);
        assert_eq!(c.resolution(15), 2048);
        assert!((c.growth_factor() - 1.3819).abs() < 1e-4);
        assert_eq!(c.resolution(1), 22); // floor(16 · 1.3819)
        assert_eq!((0..16).map(|l| c.resolution(l)).collect::<Vec<_>>(), [16, 22, 30, 42, 58, 80, 111, 153, 212, 294, 406, 561, 776, 1072, 1482, 2048]);
        assert!(c.is_dense(4) && !c.is_dense(5)); // 59³ ≤ 2^19 < 81³
        assert_eq!(cfg(1, 2, 19, 16, 16).resolution(0), 16);
        assert!(cfg(1, 3, 19, 16, 16).validate().is_err());
        assert!(cfg(2, 2, 19, 32, 16).validate().is_err());
        assert!(HashGrid::new(cfg(0, 2, 19, 16, 16), 0).is_err());
    }

    #[test]
    fn init_is_small_and_seeded() {
        let g = HashGrid::new(cfg(2, 2, 10, 4, 64), 7).unwrap();
        assert!(g.params.iter().all(|v| v.abs() <= 1e-4));
        assert!(g.params.iter().any(|v| v.abs() > 5e-5));
        assert_eq!(g, HashGrid::new(cfg(2, 2, 10, 4, 64), 7).unwrap());
        assert_ne!(g, HashGrid::new(cfg(2, 2, 10, 4, 64), 8).unwrap());
    }

    #[test]
    fn worked_example() {
        let mut g = HashGrid::new(cfg(1, 1, 10, 2, 2), 0).unwrap();
        g.params[0] = 1.0;
        g.params[1] = 3.0;
        let mut out = [0.0];
        g.encode(&[[0.25, 0.0, 0.0]], &mut out);
        assert_eq!(out[0], 2.0);
    }

    #[test]
    fn forward_matches_f64_reference() {
        // dense and hashed levels, collisions (tiny tables), every feature count
        for (c, n) in [
            (cfg(8, 2, 12, 4, 300), 3000),
            (cfg(3, 1, 4, 8, 64), 500), // T = 16: heavy collisions
            (cfg(4, 4, 9, 2, 40), 500),
            (cfg(2, 8, 14, 16, 512), 500),
            (cfg(1, 2, 19, 16, 16), 100),
        ] {
            let g = grid(c.clone(), 1, 2.0);
            let p64: Vec<f64> = g.params.iter().map(|&v| v as f64).collect();
            let mut pts = random_points(n, 2);
            // edges, corners, vertices, outside and NaN
            pts.extend([[0.0; 3], [1.0; 3], [0.0, 1.0, 0.5], [0.5, 0.25, 0.125], [-0.5, 1.5, 0.3], [f32::NAN, 0.2, f32::INFINITY]]);
            let mut out = vec![0.0; pts.len() * c.output_dim()];
            g.encode(&pts, &mut out);
            for (k, &p) in pts.iter().enumerate() {
                let p_clean = p.map(|v| if v.is_nan() { 0.0 } else { v });
                let r = reference(&c, &p64, p_clean);
                for (j, &rv) in r.iter().enumerate() {
                    let v = out[k * c.output_dim() + j] as f64;
                    assert!((v - rv).abs() < 2e-6, "config {c:?} point {p:?} feature {j}: {v} vs {rv}");
                }
            }
        }
    }

    /// The AVX2 kernel gives the scalar path's bits (two features, dense and hashed levels,
    /// a table of 2^19 entries and a tiny one with collisions), including points on vertices,
    /// on the box's faces, outside it, NaN, infinite and -0.0, at every offset of the 8-point
    /// blocks (so lane position cannot matter).
    #[test]
    fn simd_forward_is_bit_identical_to_scalar() {
        for c in [cfg(16, 2, 19, 16, 2048), cfg(6, 2, 4, 2, 300), cfg(4, 2, 14, 3, 17)] {
            let g = grid(c.clone(), 4, 1.0);
            let pts = points_with_specials();
            let lvs = levels(&c);
            let tf = c.table_size() * 2;
            for skip in 0..8 {
                let p = &pts[skip..];
                for (l, lv) in lvs.iter().enumerate() {
                    let table = &g.params[l * tf..(l + 1) * tf];
                    let (mut fast, mut slow) = (vec![0.0f32; p.len() * 3], vec![0.0f32; p.len() * 3]);
                    if lv.dense {
                        encode_level::<2, true>(p, lv, table, &mut fast, 3);
                        encode_level_scalar::<2, true>(p, lv, table, &mut slow, 3);
                    } else {
                        encode_level::<2, false>(p, lv, table, &mut fast, 3);
                        encode_level_scalar::<2, false>(p, lv, table, &mut slow, 3);
                    }
                    for (k, (a, b)) in fast.iter().zip(&slow).enumerate() {
                        assert_eq!(a.to_bits(), b.to_bits(), "config {c:?} level {l} point {:?} value {k}: {a} vs {b}", p[k / 3]);
                    }
                }
            }
        }
    }

    #[test]
    fn simd_backward_is_bit_identical_to_scalar() {
        fn run<const F: usize>(c: &HashGridConfig, pts: &[[f32; 3]]) {
            let lvs = levels(c);
            let t = c.table_size();
            let d: Vec<f32> = (0..pts.len() * F).map(|i| rnd(7000 + i as u64) - 0.5).collect();
            for skip in 0..8 {
                let (p, d) = (&pts[skip..], &d[skip * F..]);
                for (l, lv) in lvs.iter().enumerate() {
                    let (mut fast, mut slow) = (vec![0.0f32; t * F], vec![0.0f32; t * F]);
                    let (mut tf, mut ts) = (vec![false; t], vec![false; t]);
                    if lv.dense {
                        backward_level::<F, true, true>(p, lv, d, &mut fast, &mut tf);
                        backward_level_scalar::<F, true, true>(p, lv, d, &mut slow, &mut ts);
                    } else {
                        backward_level::<F, false, true>(p, lv, d, &mut fast, &mut tf);
                        backward_level_scalar::<F, false, true>(p, lv, d, &mut slow, &mut ts);
                    }
                    assert_eq!(tf, ts, "config {c:?} level {l}: touched entries");
                    assert!(ts.iter().any(|x| *x));
                    // Without the touched flags, the same gradient.
                    let mut unmarked = vec![0.0f32; t * F];
                    if lv.dense {
                        backward_level::<F, true, false>(p, lv, d, &mut unmarked, &mut []);
                    } else {
                        backward_level::<F, false, false>(p, lv, d, &mut unmarked, &mut []);
                    }
                    for (k, ((a, b), u)) in fast.iter().zip(&slow).zip(&unmarked).enumerate() {
                        assert_eq!(a.to_bits(), b.to_bits(), "config {c:?} F {F} level {l} gradient {k}: {a} vs {b}");
                        assert_eq!(u.to_bits(), b.to_bits(), "config {c:?} F {F} level {l} gradient {k} (no flags): {u} vs {b}");
                    }
                }
            }
        }
        let pts = points_with_specials();
        for (levels, log2_t, nmin, nmax) in [(16usize, 14u32, 16u32, 2048u32), (6, 4, 2, 300), (4, 14, 3, 17)] {
            run::<1>(&cfg(levels, 1, log2_t, nmin, nmax), &pts);
            run::<2>(&cfg(levels, 2, log2_t, nmin, nmax), &pts);
            run::<4>(&cfg(levels, 4, log2_t, nmin, nmax), &pts);
        }
    }

    /// Prefetching is skipped exactly on the levels whose used entries fit in
    /// [`PREFETCH_MIN_BYTES`]: instant-ngp's grid (16 levels, `T = 2^19`, `F = 2`, 16 to 2048)
    /// has three dense levels that small (17³, 23³ and 31³ entries of 8 bytes), then a dense
    /// level of 43³ entries (632 KiB) and hashed ones of 4 MiB.
    #[test]
    fn prefetching_is_skipped_on_levels_that_stay_in_cache() {
        let c = cfg(16, 2, 19, 16, 2048);
        let lvs = levels(&c);
        let on: Vec<bool> = lvs.iter().map(|lv| worth_prefetching(lv, 2)).collect();
        assert_eq!(&on[..4], &[false, false, false, true], "resolutions {:?}", lvs.iter().map(|l| l.res).collect::<Vec<_>>());
        assert!(on[4..].iter().all(|x| *x));
        // One feature per entry halves the bytes: 43³ · 4 B = 318 KiB still over, 31³ · 4 B under.
        assert_eq!(lvs.iter().map(|lv| worth_prefetching(lv, 1)).take(4).collect::<Vec<_>>(), [false, false, false, true]);
        // A tiny table is never worth it, however fine the level.
        let small = cfg(4, 2, 10, 16, 2048);
        assert!(levels(&small).iter().all(|lv| !worth_prefetching(lv, 2)));
    }

    #[test]
    fn vertices_are_exact() {
        // a dense level (N = 4) and a hashed one (N = 64, T = 2^10): at a vertex the encoding
        // is that vertex's entry exactly, including p = 0 and p = 1
        let c = cfg(2, 2, 10, 4, 64);
        let g = grid(c.clone(), 4, 1.0);
        let t = c.table_size();
        let entry = |l: usize, v: [u32; 3]| -> [f32; 2] {
            let n = c.resolution(l);
            let i = if c.is_dense(l) {
                (v[0] + v[1] * (n + 1) + v[2] * (n + 1) * (n + 1)) as usize
            } else {
                ((v[0] ^ v[1].wrapping_mul(PRIMES[1]) ^ v[2].wrapping_mul(PRIMES[2])) as usize) % t
            };
            [g.params[(l * t + i) * 2], g.params[(l * t + i) * 2 + 1]]
        };
        for (p, v4, v64) in [
            ([0.0, 0.0, 0.0], [0, 0, 0], [0, 0, 0]),
            ([1.0, 1.0, 1.0], [4, 4, 4], [64, 64, 64]),
            ([0.25, 0.5, 1.0], [1, 2, 4], [16, 32, 64]),
        ] {
            let mut out = [0.0; 4];
            g.encode(&[p], &mut out);
            assert_eq!(out[..2], entry(0, v4));
            assert_eq!(out[2..], entry(1, v64));
        }
    }

    #[test]
    fn continuous_across_cell_boundaries() {
        let c = cfg(4, 2, 12, 4, 32);
        let g = grid(c.clone(), 3, 1.0);
        // p = 0.25 is a vertex on every level (N = 4, 8, 16, 32)
        let pts = [[0.25, 0.5, 0.75], [0.25 - 1e-6, 0.5, 0.75], [0.25 + 1e-6, 0.5, 0.75]];
        let mut out = vec![0.0; 3 * c.output_dim()];
        g.encode(&pts, &mut out);
        let d = c.output_dim();
        for j in 0..d {
            assert!((out[j] - out[d + j]).abs() < 1e-4 && (out[j] - out[2 * d + j]).abs() < 1e-4);
        }
        // no points: nothing written, nothing accumulated
        let mut grad = vec![0.0; c.n_params()];
        g.encode(&[], &mut []);
        g.backward(&[], &[], &mut grad);
        assert!(grad.iter().all(|v| *v == 0.0));
        // clamping: outside equals the clamped point exactly
        let mut o2 = vec![0.0; 2 * d];
        g.encode(&[[-3.0, 2.0, 0.5], [0.0, 1.0, 0.5]], &mut o2);
        assert_eq!(o2[..d], o2[d..]);
    }

    #[test]
    fn backward_is_the_exact_adjoint_and_matches_finite_differences() {
        for c in [cfg(6, 2, 10, 4, 200), cfg(3, 1, 4, 8, 64), cfg(2, 4, 8, 2, 30)] {
            let g = grid(c.clone(), 5, 1.0);
            let pts = random_points(400, 6);
            let d = c.output_dim();
            let d_out: Vec<f32> = (0..pts.len() * d).map(|i| rnd(77_000_000 + i as u64) - 0.5).collect();
            let mut grad = vec![0.0; c.n_params()];
            g.backward(&pts, &d_out, &mut grad);
            // finite differences of L(θ) = Σ d_out · enc(θ) with the f64 reference
            let p64: Vec<f64> = g.params.iter().map(|&v| v as f64).collect();
            let loss = |params: &[f64]| -> f64 {
                pts.iter().enumerate().map(|(k, &p)| reference(&c, params, p).iter().enumerate().map(|(j, v)| v * d_out[k * d + j] as f64).sum::<f64>()).sum()
            };
            let touched: Vec<usize> = (0..grad.len()).filter(|&i| grad[i] != 0.0).collect();
            assert!(touched.len() > 10);
            let h = 1e-3;
            for &i in touched.iter().step_by(touched.len() / 12 + 1).chain([0usize, grad.len() - 1].iter()) {
                let (mut a, mut b) = (p64.clone(), p64.clone());
                a[i] += h;
                b[i] -= h;
                let fd = (loss(&a) - loss(&b)) / (2.0 * h);
                assert!((grad[i] as f64 - fd).abs() < 1e-4 * (1.0 + fd.abs()), "param {i}: {} vs {fd}", grad[i]);
            }
            // adjoint identity over all params: <d_out, enc(θ)> = <grad, θ>
            let mut out = vec![0.0; pts.len() * d];
            g.encode(&pts, &mut out);
            let lhs: f64 = out.iter().zip(&d_out).map(|(a, b)| *a as f64 * *b as f64).sum();
            let rhs: f64 = grad.iter().zip(&g.params).map(|(a, b)| *a as f64 * *b as f64).sum();
            assert!((lhs - rhs).abs() < 1e-4 * (1.0 + lhs.abs()), "{lhs} vs {rhs}");
            // accumulation: a second call doubles
            let mut grad2 = grad.clone();
            g.backward(&pts, &d_out, &mut grad2);
            assert!(grad2.iter().zip(&grad).all(|(a, b)| (*a - 2.0 * *b).abs() <= 1e-5 * (1.0 + b.abs())));
        }
    }

    #[test]
    fn deterministic_across_thread_counts() {
        let c = cfg(5, 2, 12, 4, 128);
        let g = grid(c.clone(), 8, 1.0);
        let pts = random_points(5000, 9);
        let d_out: Vec<f32> = (0..pts.len() * c.output_dim()).map(|i| rnd(i as u64) - 0.5).collect();
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| {
                let mut out = vec![0.0; pts.len() * c.output_dim()];
                g.encode(&pts, &mut out);
                let mut grad = vec![0.0; c.n_params()];
                g.backward(&pts, &d_out, &mut grad);
                (out, grad)
            })
        };
        assert_eq!(run(1), run(4));
    }

    #[test]
    fn adam_first_step_and_finite() {
        let mut adam = Adam::new(AdamConfig::instant_ngp(0.1), 4);
        let mut p = vec![1.0, 1.0, 1.0, 1.0];
        adam.step(&mut p, &[0.5, -2.0, 0.0, f32::NAN]);
        assert!((p[0] - 0.9).abs() < 1e-6 && (p[1] - 1.1).abs() < 1e-6);
        assert_eq!(&p[2..], &[1.0, 1.0]);
        // converges on a quadratic
        let mut adam = Adam::new(AdamConfig { lr: 0.05, beta1: 0.9, beta2: 0.999, eps: 1e-8 }, 1);
        let mut x = vec![3.0f32];
        for _ in 0..500 {
            let g = [2.0 * (x[0] - 1.0)];
            adam.step(&mut x, &g);
        }
        assert!((x[0] - 1.0).abs() < 1e-2, "{}", x[0]);
    }

    #[test]
    fn sparse_adam_updates_only_touched_entries_and_clears() {
        let c = cfg(3, 2, 8, 2, 40);
        let g = grid(c.clone(), 2, 1.0);
        let pts = random_points(50, 3);
        let d_out: Vec<f32> = (0..pts.len() * c.output_dim()).map(|i| rnd(5_000 + i as u64) - 0.5).collect();
        let mut grad = vec![0.0; c.n_params()];
        let mut touched = vec![false; c.levels * c.table_size()];
        g.backward_touched(&pts, &d_out, &mut grad, &mut touched);
        let mut plain = vec![0.0; c.n_params()];
        g.backward(&pts, &d_out, &mut plain);
        assert_eq!(grad, plain);
        // every entry with a nonzero gradient is flagged
        assert!(grad.chunks(2).zip(&touched).all(|(gr, t)| *t || gr.iter().all(|v| *v == 0.0)));
        let n_touched = touched.iter().filter(|t| **t).count();
        assert!(n_touched > 10 && n_touched < touched.len());
        // sparse on the touched entries = dense on them; untouched entries unchanged
        let (mut dense, mut sparse) = (Adam::new(AdamConfig::instant_ngp(0.01), c.n_params()), Adam::new(AdamConfig::instant_ngp(0.01), c.n_params()));
        let (mut pd, mut ps) = (g.params.clone(), g.params.clone());
        dense.step(&mut pd, &grad);
        let flags = touched.clone();
        assert_eq!(sparse.step_sparse(&mut ps, &mut grad, &mut touched, 2, 0.01), n_touched, "updated entries");
        for (e, hit) in flags.iter().enumerate() {
            for i in 2 * e..2 * e + 2 {
                assert_eq!(ps[i], if *hit { pd[i] } else { g.params[i] }, "entry {e}");
            }
        }
        assert!(grad.iter().all(|v| *v == 0.0) && touched.iter().all(|t| !*t));
    }

    /// The fused backward and sparse Adam give exactly the parameters and moments of
    /// `backward_touched` then `step_sparse`, step after step, for every feature count, with
    /// dense and hashed levels, whatever the pool (including a scratch made in a smaller pool,
    /// which grows to the larger one's threads), and an empty batch still counts as a step.
    #[test]
    fn fused_backward_and_adam_equal_the_two_calls_bit_for_bit() {
        fn run<const F: usize>() {
            let c = cfg(4, F, 9, 3, 60); // levels 0–1 dense, 2–3 hashed
            assert!(c.is_dense(0) && !c.is_dense(3));
            let mut a = grid(c.clone(), 11, 1.0);
            let mut b = a.clone();
            let (mut adam_a, mut adam_b) = (Adam::new(AdamConfig::instant_ngp(0.01), c.n_params()), Adam::new(AdamConfig::instant_ngp(0.01), c.n_params()));
            let mut grad = vec![0.0; c.n_params()];
            let mut touched = vec![false; c.levels * c.table_size()];
            let small = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
            let mut scratch = small.install(BackwardScratch::new);
            assert_eq!(scratch.slots.len(), 1);
            let pools = [1, 3].map(|t| rayon::ThreadPoolBuilder::new().num_threads(t).build().unwrap());
            for step in 0..6u64 {
                let n = if step == 2 { 0 } else { 40 + 17 * step as usize };
                let pts = random_points(n, 100 + step);
                let d_out: Vec<f32> = (0..n * c.output_dim()).map(|i| rnd(9_000 * step + i as u64) - 0.5).collect();
                a.backward_touched(&pts, &d_out, &mut grad, &mut touched);
                let want = adam_a.step_sparse(&mut a.params, &mut grad, &mut touched, F, 0.01 / (1 + step) as f32);
                let d_lvl = b.level_major(&d_out);
                let got = pools[step as usize % 2].install(|| b.backward_adam(&pts, &d_lvl, &mut adam_b, 0.01 / (1 + step) as f32, &mut scratch));
                assert_eq!(got.updated, want, "F = {F}, step {step}: entries updated");
                assert!(got.backward_seconds >= 0.0 && got.adam_seconds >= 0.0);
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&a.params), bits(&b.params), "F = {F}, step {step}: params");
                assert_eq!((bits(&adam_a.m), bits(&adam_a.v)), (bits(&adam_b.m), bits(&adam_b.v)), "F = {F}, step {step}: moments");
                assert_eq!(adam_a.step, adam_b.step);
            }
            // the scratch grew to the 3-thread pool and is left cleared: every slot all zero
            // and unflagged
            assert_eq!(scratch.slots.len(), 3);
            for slot in &scratch.slots {
                let buf = slot.lock().unwrap();
                assert!(buf.grad.iter().all(|v| *v == 0.0) && buf.touched.iter().all(|t| !*t));
            }
        }
        run::<1>();
        run::<2>();
        run::<4>();
        run::<8>();
    }

    /// On-CPU time of the calling thread in seconds (Linux `schedstat`), insensitive to other
    /// processes competing for the cores; `None` elsewhere.
    pub(crate) fn thread_cpu_seconds() -> Option<f64> {
        let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
        Some(s.split_whitespace().next()?.parse::<f64>().ok()? * 1e-9)
    }

    /// `cargo test -p nerf hashgrid_timing -- --ignored --nocapture`
    ///
    /// Prints wall time on the default pool and on-CPU time on one thread (the machine is
    /// shared, so wall times vary with load; CPU time much less, but the kernel updates it at
    /// scheduler ticks, so values below ~10 ms are coarse).
    #[test]
    #[ignore]
    fn hashgrid_timing() {
        let n = 262_144;
        let random = random_points(n, 10);
        // training-like: 1024 random chords of the cube, 256 consecutive samples each
        let ends = random_points(2048, 11);
        let rays: Vec<[f32; 3]> = (0..n)
            .map(|i| {
                let (a, b, t) = (ends[2 * (i / 256)], ends[2 * (i / 256) + 1], (i % 256) as f32 / 255.0);
                [0, 1, 2].map(|k| a[k] + t * (b[k] - a[k]))
            })
            .collect();
        for (levels, nmin, pts, kind) in [
            (1usize, 16u32, &random, "random"),
            (1, 2048, &random, "random"),
            (16, 16, &random, "random"),
            (1, 2048, &rays, "along rays"),
            (16, 16, &rays, "along rays"),
        ] {
            let c = cfg(levels, 2, 19, nmin, 2048);
            let g = HashGrid::new(c.clone(), 0).unwrap();
            let mut out = vec![0.0; n * c.output_dim()];
            let d_out = vec![1e-3f32; n * c.output_dim()];
            let mut grad = vec![0.0; c.n_params()];
            let mut wall = (f64::MAX, f64::MAX);
            for _ in 0..5 {
                let t0 = std::time::Instant::now();
                g.encode(pts, &mut out);
                let t1 = std::time::Instant::now();
                g.backward(pts, &d_out, &mut grad);
                let t2 = std::time::Instant::now();
                wall.0 = wall.0.min((t1 - t0).as_secs_f64());
                wall.1 = wall.1.min((t2 - t1).as_secs_f64());
            }
            let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
            let cpu = pool.install(|| {
                let mut cpu = (f64::MAX, f64::MAX);
                for _ in 0..5 {
                    let t0 = thread_cpu_seconds().unwrap_or(0.0);
                    g.encode(pts, &mut out);
                    let t1 = thread_cpu_seconds().unwrap_or(0.0);
                    g.backward(pts, &d_out, &mut grad);
                    let t2 = thread_cpu_seconds().unwrap_or(0.0);
                    cpu.0 = cpu.0.min(t1 - t0);
                    cpu.1 = cpu.1.min(t2 - t1);
                }
                cpu
            });
            println!(
                "hashgrid L={levels} N_min={nmin} F=2 T=2^19, {n} points {kind}: wall ({} threads) fwd {:.1} ms + bwd {:.1} ms; 1-thread CPU fwd {:.1} ms + bwd {:.1} ms",
                rayon::current_num_threads(),
                wall.0 * 1e3,
                wall.1 * 1e3,
                cpu.0 * 1e3,
                cpu.1 * 1e3
            );
        }
    }
}
#[cfg(test)]
#[allow(clippy::needless_range_loop)]
mod sparse_adam_list {
    use super::*;

    /// The listed sparse Adam equals a plain per-flag loop bit for bit over several steps, on a
    /// table of several chunks plus a partial one, with flags scattered at random (including
    /// each chunk's first and last entry, and some non-finite gradients), for 1, 2 and 3
    /// parameters per flag (2 runs the AVX2 kernel where the CPU has AVX2).
    #[test]
    fn sparse_adam_equals_a_per_flag_loop() {
        for group in [1usize, 2, 3] {
            let entries = (1usize << 14) * 3 + 77;
            let n = entries * group;
            let cfg = AdamConfig::instant_ngp(0.01);
            let mut adam = Adam::new(cfg.clone(), n);
            let (mut p, mut rp) = (vec![0.1f32; n], vec![0.1f32; n]);
            let (mut rm, mut rv) = (vec![0.0f32; n], vec![0.0f32; n]);
            for step in 1..=4u64 {
                let mut g = vec![0.0f32; n];
                let mut touched = vec![false; entries];
                for e in 0..entries {
                    let hit = e % (1 << 14) == 0 || e % (1 << 14) == (1 << 14) - 1 || rng::uniform_f32(rng::key(&[step, e as u64])) < 0.35;
                    if hit {
                        touched[e] = true;
                        for i in e * group..(e + 1) * group {
                            g[i] = rng::uniform_f32(rng::key(&[step, i as u64, 1])) - 0.5;
                        }
                        // Now and then a non-finite gradient (treated as 0).
                        if e % 997 == 5 {
                            g[e * group] = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY][e % 3];
                        }
                    }
                }
                let (reference_g, flags) = (g.clone(), touched.clone());
                let want = touched.iter().filter(|t| **t).count();
                assert_eq!(adam.step_sparse(&mut p, &mut g, &mut touched, group, 0.01), want);
                let t = step as i32;
                let c1 = (1.0 - (cfg.beta1 as f64).powi(t)) as f32;
                let c2 = (1.0 - (cfg.beta2 as f64).powi(t)) as f32;
                for e in (0..entries).filter(|&e| flags[e]) {
                    for i in e * group..(e + 1) * group {
                        let gi = if reference_g[i].is_finite() { reference_g[i] } else { 0.0 };
                        rm[i] = cfg.beta1 * rm[i] + (1.0 - cfg.beta1) * gi;
                        rv[i] = cfg.beta2 * rv[i] + (1.0 - cfg.beta2) * gi * gi;
                        rp[i] -= 0.01 * (rm[i] / c1) / ((rv[i] / c2).sqrt() + cfg.eps);
                    }
                }
                assert!(p.iter().zip(&rp).all(|(a, b)| a.to_bits() == b.to_bits()), "group {group} step {step}: parameters differ");
                assert!(adam.m.iter().zip(&rm).all(|(a, b)| a.to_bits() == b.to_bits()), "group {group} step {step}: first moments differ");
                assert!(adam.v.iter().zip(&rv).all(|(a, b)| a.to_bits() == b.to_bits()), "group {group} step {step}: second moments differ");
                assert!(g.iter().all(|v| *v == 0.0) && touched.iter().all(|t| !*t), "group {group} step {step}: buffers not cleared");
            }
        }
    }
}
