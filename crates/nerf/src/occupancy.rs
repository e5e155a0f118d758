//! An occupancy grid over the scene box that lets ray marching skip empty space
//! (instant-ngp's density grid, nerfacc's `OccGridEstimator`, one level).
//!
//! # Update (instant-ngp / nerfacc)
//! Each cell keeps a running density `ρ_c`. An update at training step `s`:
//! 1. selects cells: all of them while `s < warmup_steps`; afterwards each cell with probability
//!    `update_fraction`, plus each occupied cell with probability `update_fraction` again
//!    (keyed by `(seed, s, cell)`);
//! 2. evaluates the density at one point per selected cell, jittered uniformly inside the cell
//!    (keyed by `(seed, s, cell, axis)`), in batches of [`UPDATE_BATCH`] points;
//! 3. sets `ρ_c ← max(decay · ρ_c, σ(x_c))` for the selected cells (others keep `ρ_c`);
//! 4. marks a cell occupied when its opacity `ρ_c · step_size` exceeds
//!    `min(threshold, mean_c(ρ_c) · step_size)` (nerfacc's rule; `threshold = 0.01` there).
//!
//! A new grid has every cell occupied (so marching works before the first update) and
//! `ρ_c = 0`.
//!
//! # Marching
//! [`OccupancyGrid::march`] clips each ray's `[near, far]` to the grid box, then steps with a
//! **constant** step `Δ`: interval `k` is `[t_k, min(t_k + Δ, t_hi)]` with
//! `t_k = t_lo + (k + u) Δ`, `u` uniform in [0, 1) keyed by `(seed, step, ray)` in
//! [`SampleMode::Random`] and `u = 0` in [`SampleMode::Deterministic`]. An interval is kept when
//! the cell holding its midpoint is occupied; from an empty cell the march jumps (DDA) to the
//! first interval whose midpoint lies past the cell's exit. At most `max_samples_per_ray`
//! intervals per ray.
//!
//! Example: unit box, everything occupied, `near = 0.2`, `far = 0.5`, `Δ = 0.1`,
//! deterministic → `[0.2, 0.3] [0.3, 0.4] [0.4, 0.5]`.

// `!(a < b)` is deliberate throughout: it is true for NaN, which must count as invalid.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use crate::sampling::{Aabb, RaySamples, SampleMode, ray_aabb, rng};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Points per call of the density closure during an update.
pub const UPDATE_BATCH: usize = 1 << 16;

/// Rays per rayon task while marching.
const MARCH_BLOCK: usize = 256;

/// Occupancy-grid settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OccupancyGridConfig {
    /// The box the grid covers (world units); nothing outside it is ever sampled.
    pub aabb: Aabb,
    /// Cells per axis (e.g. 64 or 128).
    pub resolution: u32,
    /// Decay of the running density per update (instant-ngp: 0.95).
    pub decay: f32,
    /// Updates with `step < warmup_steps` refresh every cell (nerfacc: 256).
    pub warmup_steps: u64,
    /// Fraction of cells refreshed per update afterwards (nerfacc: 0.25).
    pub update_fraction: f32,
    /// Seed of the update jitter.
    pub seed: u64,
}

/// Options of [`OccupancyGrid::march`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MarchOptions {
    /// Constant step `Δ` in world units (instant-ngp: `√3 / 1024` of the box for 1024 steps
    /// across the diagonal).
    pub step_size: f32,
    /// Cap on intervals per ray.
    pub max_samples_per_ray: usize,
    /// Jitter of the first sample.
    pub jitter: SampleMode,
    /// Cone marching (instant-ngp's `cone_angle`): where > 0, the step at distance `t` along
    /// the (unit-direction) ray is `t · cone_angle` (the pixel footprint there), at least
    /// `step_size` and at most one occupancy cell. 0: the constant step `step_size`.
    pub cone_angle: f32,
}

/// A ray's place in its march ([`OccupancyGrid::march_start`], [`OccupancyGrid::march_more`]),
/// so that rendering can march only as far as the ray stays transparent.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MarchState {
    lo: f32,
    hi: f32,
    u: f32,
    /// Next constant-step interval index.
    k: u64,
    /// Next cone-march interval start.
    t: f32,
    emitted: usize,
    done: bool,
}

impl MarchState {
    /// No interval is left to emit.
    pub fn is_done(&self) -> bool {
        self.done
    }
}

/// The empty space around each cell of an [`OccupancyGrid`] ([`OccupancyGrid::blocks`]): the
/// chessboard distance in cells from each cell to the nearest occupied one (0 for an occupied
/// cell; capped at 255, which a grid with no occupied cell gets everywhere). Every cell within
/// distance `k − 1` of a cell at distance `k` is empty, so the march leaves that whole cube of
/// `(2k − 1)³` cells at once.
#[derive(Clone, Debug)]
pub struct OccupancyBlocks {
    /// Index `x + R (y + R z)`, as the grid's cells.
    dist: Vec<u8>,
}

/// The grid: running densities and the occupancy bitfield.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OccupancyGrid {
    pub config: OccupancyGridConfig,
    /// Running density `ρ_c` per cell, index `x + R (y + R z)`.
    pub density: Vec<f32>,
    /// Occupancy bits, cell `i` at `bits[i / 64] >> (i % 64)`.
    pub bits: Vec<u64>,
}

impl OccupancyGrid {
    /// A grid with every cell occupied and zero running density.
    ///
    /// # Panics
    /// If `resolution` is 0 or above 1024, or the box is empty.
    pub fn new(config: OccupancyGridConfig) -> Self {
        assert!((1..=1024).contains(&config.resolution), "resolution must be 1..=1024");
        assert!((0..3).all(|a| config.aabb.max[a] > config.aabb.min[a]), "empty box");
        let n = (config.resolution as usize).pow(3);
        let mut g = Self { config, density: vec![0.0; n], bits: vec![0; n.div_ceil(64)] };
        g.mark_all(true);
        g
    }

    /// Number of cells `R³`.
    pub fn n_cells(&self) -> usize {
        self.density.len()
    }

    /// Sets every cell occupied (`true`) or empty.
    pub fn mark_all(&mut self, occupied: bool) {
        let n = self.n_cells();
        for (w, word) in self.bits.iter_mut().enumerate() {
            *word = if occupied { u64::MAX } else { 0 };
            if occupied && (w + 1) * 64 > n {
                *word = (1u64 << (n - w * 64)) - 1;
            }
        }
    }

    /// Sets one cell's bit.
    pub fn set_occupied(&mut self, cell: [u32; 3], occupied: bool) {
        let i = self.cell_index(cell);
        if occupied {
            self.bits[i / 64] |= 1 << (i % 64);
        } else {
            self.bits[i / 64] &= !(1 << (i % 64));
        }
    }

    /// Linear index `x + R (y + R z)`.
    #[inline]
    pub fn cell_index(&self, c: [u32; 3]) -> usize {
        let r = self.config.resolution as usize;
        c[0] as usize + r * (c[1] as usize + r * c[2] as usize)
    }

    #[inline]
    fn bit(&self, i: usize) -> bool {
        (self.bits[i / 64] >> (i % 64)) & 1 == 1
    }

    /// Whether a cell is occupied.
    pub fn is_occupied(&self, c: [u32; 3]) -> bool {
        self.bit(self.cell_index(c))
    }

    /// The cell holding a world point, `None` outside the box (or NaN).
    #[inline]
    pub fn cell_of(&self, p: [f32; 3]) -> Option<[u32; 3]> {
        let (b, r) = (&self.config.aabb, self.config.resolution);
        let mut c = [0u32; 3];
        for a in 0..3 {
            let u = (p[a] - b.min[a]) / (b.max[a] - b.min[a]);
            if !(0.0..=1.0).contains(&u) {
                return None;
            }
            c[a] = ((u * r as f32) as u32).min(r - 1);
        }
        Some(c)
    }

    /// Fraction of occupied cells.
    pub fn occupied_fraction(&self) -> f32 {
        let n: u32 = self.bits.iter().map(|w| w.count_ones()).sum();
        n as f32 / self.n_cells() as f32
    }

    /// One update (see the module doc). `density_fn` maps world points to densities (≥ 0;
    /// NaN and negatives count as 0) and must return one value per point.
    pub fn update(
        &mut self,
        step: u64,
        step_size: f32,
        threshold: f32,
        density_fn: &mut dyn FnMut(&[[f32; 3]]) -> Vec<f32>,
    ) {
        let cfg = &self.config;
        let r = cfg.resolution;
        let all = step < cfg.warmup_steps;
        // Selection and jitter are keyed per cell, so computing them in parallel gives the
        // same cells and points for any thread count (rayon keeps the order).
        // The keys are `(seed, step, cell, draw)`, their shared prefixes hashed once.
        let step_key = rng::key(&[cfg.seed, step]);
        let selected: Vec<u32> = (0..self.n_cells() as u32)
            .into_par_iter()
            .filter(|&i| {
                if all {
                    return true;
                }
                let cell_key = rng::extend(step_key, &[i as u64]);
                rng::uniform_f32(rng::extend(cell_key, &[0])) < cfg.update_fraction
                    || (self.bit(i as usize) && rng::uniform_f32(rng::extend(cell_key, &[1])) < cfg.update_fraction)
            })
            .collect();
        let size: [f32; 3] = [0, 1, 2].map(|a| (cfg.aabb.max[a] - cfg.aabb.min[a]) / r as f32);
        for batch in selected.chunks(UPDATE_BATCH) {
            let pts: Vec<[f32; 3]> = batch
                .par_iter()
                .map(|&i| {
                    let c = [i % r, (i / r) % r, i / (r * r)];
                    let cell_key = rng::extend(step_key, &[i as u64]);
                    [0, 1, 2].map(|a| {
                        let u = rng::uniform_f32(rng::extend(cell_key, &[2 + a as u64]));
                        cfg.aabb.min[a] + (c[a] as f32 + u) * size[a]
                    })
                })
                .collect();
            let sigma = density_fn(&pts);
            assert_eq!(sigma.len(), pts.len(), "density_fn must return one density per point");
            for (&i, &s) in batch.iter().zip(&sigma) {
                let s = if s > 0.0 { s.min(f32::MAX) } else { 0.0 };
                let d = &mut self.density[i as usize];
                *d = (*d * cfg.decay).max(s);
            }
        }
        let mean = self.density.iter().map(|&d| d as f64).sum::<f64>() / self.n_cells() as f64;
        let thr = (threshold as f64).min(mean * step_size as f64);
        for (w, chunk) in self.bits.iter_mut().zip(self.density.chunks(64)) {
            *w = 0;
            for (b, &d) in chunk.iter().enumerate() {
                if d as f64 * step_size as f64 > thr {
                    *w |= 1 << b;
                }
            }
        }
    }

    /// Marches rays through the occupied cells (see the module doc); `blocks` as in
    /// [`Self::march_more`].
    ///
    /// # Shapes
    /// `origins`, `dirs`, `near`, `far`: `[n_rays]` → `RaySamples`
    pub fn march(
        &self,
        origins: &[[f32; 3]],
        dirs: &[[f32; 3]],
        near: &[f32],
        far: &[f32],
        options: &MarchOptions,
        blocks: Option<&OccupancyBlocks>,
    ) -> RaySamples {
        let n_rays = origins.len();
        assert!(dirs.len() == n_rays && near.len() == n_rays && far.len() == n_rays, "per-ray lengths differ");
        assert!(options.step_size > 0.0, "step_size must be > 0");
        let blocks: Vec<(Vec<u32>, Vec<f32>, Vec<f32>)> = (0..n_rays.div_ceil(MARCH_BLOCK))
            .into_par_iter()
            .map(|b| {
                let (mut counts, mut ts, mut te) = (Vec::new(), Vec::new(), Vec::new());
                for r in b * MARCH_BLOCK..((b + 1) * MARCH_BLOCK).min(n_rays) {
                    let before = ts.len();
                    self.march_ray(r, origins[r], dirs[r], near[r], far[r], options, blocks, &mut ts, &mut te);
                    counts.push((ts.len() - before) as u32);
                }
                (counts, ts, te)
            })
            .collect();
        let mut out = RaySamples::with_rays(n_rays);
        let total: usize = blocks.iter().map(|b| b.1.len()).sum();
        out.t_start.reserve(total);
        out.t_end.reserve(total);
        out.ray_index.reserve(total);
        let mut r = 0u32;
        let mut end = 0u32;
        for (counts, ts, te) in blocks {
            out.t_start.extend_from_slice(&ts);
            out.t_end.extend_from_slice(&te);
            for c in counts {
                out.ray_index.extend(std::iter::repeat_n(r, c as usize));
                end += c;
                out.offsets.push(end);
                r += 1;
            }
        }
        out
    }

    #[allow(clippy::too_many_arguments)]
    fn march_ray(
        &self,
        r: usize,
        o: [f32; 3],
        d: [f32; 3],
        near: f32,
        far: f32,
        opt: &MarchOptions,
        blocks: Option<&OccupancyBlocks>,
        ts: &mut Vec<f32>,
        te: &mut Vec<f32>,
    ) {
        let mut state = self.march_start(r, o, d, near, far, opt);
        self.march_more(&mut state, o, d, opt, blocks, usize::MAX, ts, te);
    }

    /// Where ray `r` (`o + t d`) starts its march, for [`Self::march_more`]: its clipped
    /// `[near, far]` and its jitter. `march_start` then `march_more` with no limit emits
    /// exactly the intervals [`Self::march`] gives the ray; resumed in pieces, the same
    /// intervals in the same order.
    pub fn march_start(&self, r: usize, o: [f32; 3], d: [f32; 3], near: f32, far: f32, opt: &MarchOptions) -> MarchState {
        let done = MarchState { lo: 0.0, hi: 0.0, u: 0.0, k: 0, t: 0.0, emitted: 0, done: true };
        if !(near.is_finite() && far.is_finite() && far > near) {
            return done;
        }
        let Some((t_in, t_out)) = ray_aabb(o, d, &self.config.aabb) else { return done };
        let (lo, hi) = (near.max(t_in), far.min(t_out));
        if !(hi > lo) {
            return done;
        }
        let u = match opt.jitter {
            SampleMode::Deterministic => 0.0,
            SampleMode::Random { seed, step } => rng::uniform_f32(rng::key(&[seed, step, r as u64])),
        };
        let t = if opt.cone_angle > 0.0 { lo + u * self.cone_step(opt, lo) } else { 0.0 };
        MarchState { lo, hi, u, k: 0, t, emitted: 0, done: false }
    }

    /// Emits the ray's next intervals (at most `limit` of them, and none past
    /// `max_samples_per_ray` in all) into `ts`/`te`; returns how many. `state` moves on, and is
    /// marked done when the ray has left the box or reached its cap. With `blocks` (this
    /// grid's [`Self::blocks`]) the march leaves the whole empty cube of cells around an empty
    /// cell at once where it would otherwise visit them one by one: with constant steps the
    /// same intervals but for rounding where a midpoint lies on the cube's face; a cone march
    /// resumes `u · step` past the cube's exit instead of the cell's.
    #[allow(clippy::too_many_arguments)]
    pub fn march_more(
        &self,
        state: &mut MarchState,
        o: [f32; 3],
        d: [f32; 3],
        opt: &MarchOptions,
        blocks: Option<&OccupancyBlocks>,
        limit: usize,
        ts: &mut Vec<f32>,
        te: &mut Vec<f32>,
    ) -> usize {
        if state.done {
            return 0;
        }
        let size = self.cell_size();
        let (lo, hi, u) = (state.lo, state.hi, state.u);
        let mut now = 0;
        if opt.cone_angle > 0.0 {
            // Cone marching: contiguous intervals of length `clamp(t · cone_angle, step_size,
            // one cell)` from `lo + u · step(lo)`; an interval whose midpoint lies in an empty
            // cell is dropped and the walk resumes `u · step` past that cell's exit (the same
            // jitter `u` as the first interval).
            let mut t = state.t;
            loop {
                if !(state.emitted < opt.max_samples_per_ray && t < hi) {
                    state.done = true;
                    break;
                }
                if now >= limit {
                    break;
                }
                let t1 = (t + self.cone_step(opt, t)).min(hi);
                let tm = 0.5 * (t + t1);
                let p = [o[0] + tm * d[0], o[1] + tm * d[1], o[2] + tm * d[2]];
                let c = self.cell_clamped(p);
                if self.is_occupied(c) {
                    ts.push(t);
                    te.push(t1);
                    state.emitted += 1;
                    now += 1;
                    t = t1;
                    continue;
                }
                let t_exit = self.empty_exit(o, d, c, size, blocks);
                if !(t_exit < hi) {
                    state.done = true;
                    break;
                }
                // Always advance (rounding can put the exit at or before t).
                t = (t_exit + u * self.cone_step(opt, t_exit)).max(t1);
            }
            state.t = t;
            return now;
        }
        let dt = opt.step_size;
        let mut k = state.k;
        loop {
            if state.emitted >= opt.max_samples_per_ray {
                state.done = true;
                break;
            }
            let t0 = lo + (k as f32 + u) * dt;
            if !(t0 < hi) {
                state.done = true;
                break;
            }
            if now >= limit {
                break;
            }
            let t1 = (t0 + dt).min(hi);
            let tm = 0.5 * (t0 + t1);
            let p = [o[0] + tm * d[0], o[1] + tm * d[1], o[2] + tm * d[2]];
            let c = self.cell_clamped(p);
            if self.is_occupied(c) {
                ts.push(t0);
                te.push(t1);
                state.emitted += 1;
                now += 1;
                k += 1;
                continue;
            }
            // DDA skip: the first interval whose midpoint lies past this cell's exit (or the
            // exit of the largest empty block holding it)
            let t_exit = self.empty_exit(o, d, c, size, blocks);
            if !(t_exit < hi) {
                state.done = true;
                break;
            }
            let k_next = ((t_exit - lo) / dt - u - 0.5).floor() + 1.0;
            k = if k_next > k as f32 { (k_next as u64).max(k + 1) } else { k + 1 };
        }
        state.k = k;
        now
    }

    /// Where the ray leaves empty cell `c`: with `blocks`, the exit of the empty cube of cells
    /// around `c` that its distance to the nearest occupied cell gives (clipped to the grid),
    /// else of the cell.
    #[inline]
    fn empty_exit(&self, o: [f32; 3], d: [f32; 3], c: [u32; 3], size: [f32; 3], blocks: Option<&OccupancyBlocks>) -> f32 {
        if let Some(bl) = blocks {
            let radius = (bl.dist[self.cell_index(c)] as u32).saturating_sub(1);
            if radius > 0 {
                let r = self.config.resolution;
                let mut t_exit = f32::INFINITY;
                for a in 0..3 {
                    if d[a] != 0.0 {
                        let cell = if d[a] > 0.0 { (c[a] + radius + 1).min(r) } else { c[a].saturating_sub(radius) };
                        let plane = self.config.aabb.min[a] + cell as f32 * size[a];
                        t_exit = t_exit.min((plane - o[a]) / d[a]);
                    }
                }
                return t_exit;
            }
        }
        self.cell_exit(o, d, c, size)
    }

    /// The grid's empty space as each cell's chessboard distance to the nearest occupied cell
    /// ([`OccupancyBlocks`]), for [`Self::march_more`] to skip empty space fast: two raster
    /// passes over the 26-neighbourhood (Rosenfeld and Pfaltz's chamfer algorithm, exact for
    /// the chessboard metric). Stale once the grid changes.
    pub fn blocks(&self) -> OccupancyBlocks {
        let r = self.config.resolution as usize;
        // Rows along x (one per (y, z), raster order `y + R z`), each with one cell of 255 at
        // both ends so that a row's x − 1 and x + 1 neighbours are plain slices; 255 neither
        // lowers a distance (255 + 1 saturates) nor stands for an occupied cell, as a
        // neighbour outside the grid is skipped.
        let w = r + 2;
        let mut g = vec![u8::MAX; w * r * r];
        for (k, row) in g.chunks_exact_mut(w).enumerate() {
            for x in 0..r {
                if self.bit(x + r * k) {
                    row[x + 1] = 0;
                }
            }
        }
        let mut m = vec![0u8; r];
        for k in 0..r * r {
            chamfer_row(&mut g, &mut m, r, k, false);
        }
        for k in (0..r * r).rev() {
            chamfer_row(&mut g, &mut m, r, k, true);
        }
        OccupancyBlocks { dist: g.chunks_exact(w).flat_map(|row| row[1..=r].iter().copied()).collect() }
    }

    /// One cell's size per axis (world units).
    fn cell_size(&self) -> [f32; 3] {
        [0, 1, 2].map(|a| (self.config.aabb.max[a] - self.config.aabb.min[a]) / self.config.resolution as f32)
    }

    /// The cone march's step at distance `t`: `clamp(t · cone_angle, step_size, one cell)`.
    #[inline]
    fn cone_step(&self, opt: &MarchOptions, t: f32) -> f32 {
        let size = self.cell_size();
        let max_step = size[0].min(size[1]).min(size[2]).max(opt.step_size);
        (t * opt.cone_angle).clamp(opt.step_size, max_step)
    }

    /// The cell holding `p`; a point just outside the box (a midpoint of an interval clipped
    /// to it, off by rounding) counts in the nearest cell.
    #[inline]
    fn cell_clamped(&self, p: [f32; 3]) -> [u32; 3] {
        self.cell_of(p).unwrap_or_else(|| {
            let b = &self.config.aabb;
            let q = [0, 1, 2].map(|a| p[a].clamp(b.min[a], b.max[a]));
            self.cell_of(q).unwrap_or([0; 3])
        })
    }

    /// Distance along the ray `o + t d` at which it leaves cell `c` (cells of `size`).
    #[inline]
    fn cell_exit(&self, o: [f32; 3], d: [f32; 3], c: [u32; 3], size: [f32; 3]) -> f32 {
        let mut t_exit = f32::INFINITY;
        for a in 0..3 {
            if d[a] != 0.0 {
                let lo_a = self.config.aabb.min[a] + c[a] as f32 * size[a];
                let plane = if d[a] > 0.0 { lo_a + size[a] } else { lo_a };
                t_exit = t_exit.min((plane - o[a]) / d[a]);
            }
        }
        t_exit
    }

}

/// One row (`k = y + R z`, cells padded as in [`OccupancyGrid::blocks`]) of a pass of the
/// chamfer: every cell becomes the least of itself and one more than each of its 13
/// neighbours before it in the pass's order (forward: raster order; backward: its reverse).
/// Twelve of them lie in four other rows, all done earlier in the pass (forward: rows
/// (y − 1, z − 1), (y, z − 1), (y + 1, z − 1), (y − 1, z); backward: the mirror images),
/// each at x − 1, x and x + 1, taken a row at a time; the thirteenth is the cell before it in
/// its own row, a scan along the row. Minima do not depend on their order, so this is the
/// cell-by-cell algorithm's result exactly.
fn chamfer_row(g: &mut [u8], m: &mut [u8], r: usize, k: usize, backward: bool) {
    let w = r + 2;
    let (y, z) = ((k % r) as i64, (k / r) as i64);
    let sign = if backward { -1 } else { 1 };
    m.copy_from_slice(&g[k * w + 1..k * w + 1 + r]);
    for (dy, dz) in [(-1i64, -1i64), (0, -1), (1, -1), (-1, 0)] {
        let (ny, nz) = (y + sign * dy, z + sign * dz);
        if !(0..r as i64).contains(&ny) || !(0..r as i64).contains(&nz) {
            continue;
        }
        let o = (ny + r as i64 * nz) as usize * w;
        let a = &g[o..o + w];
        for ((mx, (&left, &mid)), &right) in m.iter_mut().zip(a[..r].iter().zip(&a[1..=r])).zip(&a[2..]) {
            *mx = (*mx).min(left.min(mid).min(right).saturating_add(1));
        }
    }
    let row = &mut g[k * w..(k + 1) * w];
    if backward {
        for x in (1..=r).rev() {
            row[x] = m[x - 1].min(row[x + 1].saturating_add(1));
        }
    } else {
        for x in 1..=r {
            row[x] = m[x - 1].min(row[x - 1].saturating_add(1));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(res: u32) -> OccupancyGridConfig {
        OccupancyGridConfig {
            aabb: Aabb { min: [0.0; 3], max: [1.0; 3] },
            resolution: res,
            decay: 0.95,
            warmup_steps: 256,
            update_fraction: 0.25,
            seed: 1,
        }
    }

    fn opts(step: f32, jitter: SampleMode) -> MarchOptions {
        MarchOptions { step_size: step, max_samples_per_ray: 10_000, jitter, cone_angle: 0.0 }
    }

    #[test]
    fn worked_example_everything_occupied_covers_near_far() {
        let g = OccupancyGrid::new(cfg(8));
        assert_eq!(g.occupied_fraction(), 1.0);
        let s = g.march(&[[0.5, 0.5, -1.0]], &[[0.0, 0.0, 1.0]], &[1.2], &[1.5], &opts(0.1, SampleMode::Deterministic), None);
        assert_eq!(s.len(), 3);
        for (k, (a, b)) in s.t_start.iter().zip(&s.t_end).enumerate() {
            assert!((a - (1.2 + 0.1 * k as f32)).abs() < 1e-6 && (b - (1.3 + 0.1 * k as f32)).abs() < 1e-6);
        }
        assert_eq!(*s.t_end.last().unwrap(), 1.5);
        // a diagonal ray, jittered: contiguous steps up to far
        let (o, d) = ([-0.5f32, -0.5, -0.5], [1.0f32 / 3f32.sqrt(); 3]);
        let (n, f) = (1.0f32, 2.0f32);
        let s = g.march(&[o], &[d], &[n], &[f], &opts(0.01, SampleMode::Random { seed: 3, step: 7 }), None);
        assert!(s.t_start[0] >= n && s.t_start[0] < n + 0.01);
        assert!(s.t_start[1..].iter().zip(&s.t_end).all(|(a, b)| (a - b).abs() < 1e-5));
        assert_eq!(*s.t_end.last().unwrap(), f);
        assert!((s.len() as i32 - 100).abs() <= 1);
        // the box clips: a ray from far outside starts at the box
        let s = g.march(&[[0.5, 0.5, -1.0]], &[[0.0, 0.0, 1.0]], &[0.0], &[100.0], &opts(0.25, SampleMode::Deterministic), None);
        assert_eq!((s.t_start.clone(), s.t_end.clone()), (vec![1.0, 1.25, 1.5, 1.75], vec![1.25, 1.5, 1.75, 2.0]));
    }

    #[test]
    fn one_occupied_cell() {
        let mut g = OccupancyGrid::new(cfg(8));
        g.mark_all(false);
        g.set_occupied([3, 4, 5], true); // [0.375, 0.5] × [0.5, 0.625] × [0.625, 0.75]
        assert_eq!(g.occupied_fraction(), 1.0 / 512.0);
        let origins = [[-1.0, 0.55, 0.7], [0.42, -1.0, 0.7], [-1.0, 0.3, 0.7], [-1.0, 0.55, 0.2], [0.45, 0.56, 2.0], [-0.6, -0.4, -0.3]];
        let dirs = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.6, 0.555, 0.55]];
        let hits = [true, true, false, false, true, true];
        let near = vec![0.0; 6];
        let far = vec![10.0; 6];
        for mode in [SampleMode::Deterministic, SampleMode::Random { seed: 5, step: 2 }] {
            let s = g.march(&origins, &dirs, &near, &far, &opts(0.01, mode), None);
            for r in 0..6 {
                let (a, b) = s.ray(r);
                assert_eq!(!a.is_empty(), hits[r], "ray {r}");
                for (&t0, &t1) in a.iter().zip(b) {
                    let tm = 0.5 * (t0 + t1);
                    let p = [0, 1, 2].map(|k| origins[r][k] + tm * dirs[r][k]);
                    assert_eq!(g.cell_of(p), Some([3, 4, 5]), "ray {r} sample at {p:?}");
                }
                if hits[r] {
                    // the samples cover the chord through the cell: ~ 0.125 / 0.01 of them
                    assert!(a.len() >= 10, "ray {r}: {} samples", a.len());
                }
            }
        }
    }

    #[test]
    fn cone_marching_steps_grow_with_distance_and_skip_empty_cells() {
        let g = OccupancyGrid::new(cfg(8));
        let cone = |step: f32, jitter| MarchOptions { step_size: step, max_samples_per_ray: 10_000, jitter, cone_angle: 0.01 };
        // Everything occupied, a ray along +z from z = -9 through the unit box (t 9..10):
        // steps t · 0.01 ≈ 0.09..0.1 (above the 0.001 minimum, below the 0.125 cell),
        // contiguous from near to far.
        let s = g.march(&[[0.5, 0.5, -9.0]], &[[0.0, 0.0, 1.0]], &[0.0], &[100.0], &cone(0.001, SampleMode::Deterministic), None);
        assert_eq!(s.t_start[0], 9.0);
        assert_eq!(*s.t_end.last().unwrap(), 10.0);
        assert!(s.t_start[1..].iter().zip(&s.t_end).all(|(a, b)| a == b));
        for (a, b) in s.t_start.iter().zip(&s.t_end).take(s.len() - 1) {
            assert!(((b - a) - 0.01 * a).abs() < 1e-5, "step {} at {a}", b - a);
        }
        // Close to the origin the minimum step rules; far away one cell.
        let s = g.march(&[[0.5, 0.5, 0.0]], &[[0.0, 0.0, 1.0]], &[0.0], &[100.0], &cone(0.02, SampleMode::Deterministic), None);
        assert!((s.t_end[0] - s.t_start[0] - 0.02).abs() < 1e-6);
        let s = g.march(&[[0.5, 0.5, -99.0]], &[[0.0, 0.0, 1.0]], &[0.0], &[1000.0], &cone(0.001, SampleMode::Deterministic), None);
        assert!((s.t_end[0] - s.t_start[0] - 0.125).abs() < 1e-4, "{}", s.t_end[0] - s.t_start[0]);
        // One occupied cell: every sample's midpoint lies in it, jittered or not.
        let mut g = OccupancyGrid::new(cfg(8));
        g.mark_all(false);
        g.set_occupied([3, 4, 5], true);
        for mode in [SampleMode::Deterministic, SampleMode::Random { seed: 5, step: 2 }] {
            let s = g.march(&[[-1.0, 0.55, 0.7]], &[[1.0, 0.0, 0.0]], &[0.0], &[10.0], &cone(0.001, mode), None);
            // The chord 1.375..1.5 at steps ≈ 0.014: 8 or 9 samples.
            assert!((8..=10).contains(&s.len()), "{} samples", s.len());
            for (&t0, &t1) in s.t_start.iter().zip(&s.t_end) {
                let tm = 0.5 * (t0 + t1);
                assert_eq!(g.cell_of([-1.0 + tm, 0.55, 0.7]), Some([3, 4, 5]));
            }
        }
    }

    #[test]
    fn degenerate_rays_get_no_samples() {
        let g = OccupancyGrid::new(cfg(4));
        let s = g.march(
            &[[0.5; 3], [0.5; 3], [f32::NAN, 0.5, 0.5], [2.0, 2.0, 2.0]],
            &[[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0]],
            &[0.3, f32::NAN, 0.0, 0.0],
            &[0.3, 1.0, 1.0, 1.0],
            &opts(0.01, SampleMode::Deterministic),
            None,
        );
        assert_eq!(s.offsets, vec![0, 0, 0, 0, 0]);
        // the cap
        let s = g.march(&[[0.0, 0.5, 0.5]], &[[1.0, 0.0, 0.0]], &[0.0], &[1.0], &MarchOptions { step_size: 0.001, max_samples_per_ray: 17, jitter: SampleMode::Deterministic, cone_angle: 0.0 }, None);
        assert_eq!(s.len(), 17);
    }

    /// Marching resumed a few intervals at a time (as rendering does) emits exactly the
    /// intervals of one march, for constant steps and cone marching, jittered or not, through
    /// a grid with empty cells to skip and a cap to hit; skipping whole empty cubes
    /// ([`OccupancyGrid::blocks`]) changes nothing with constant steps, and with cone marching
    /// gives the same intervals however it is resumed.
    #[test]
    fn resumed_marching_emits_exactly_the_whole_march() {
        // 32³ cells: a ball and scattered cells in the lower half, the upper half empty (whole
        // empty blocks of 4³ and 16³ cells to skip)
        let mut g = OccupancyGrid::new(cfg(32));
        for x in 0..32u32 {
            for y in 0..32u32 {
                for z in 0..32u32 {
                    let ball = [x, y, z].iter().map(|&v| (v as f32 - 10.0).powi(2)).sum::<f32>() < 25.0;
                    let scattered = (x * 7 + y * 13 + z * 5) % 37 == 0;
                    g.set_occupied([x, y, z], y < 16 && (ball || scattered));
                }
            }
        }
        let coarse = g.blocks();
        assert!(coarse.dist.iter().any(|&d| d >= 8), "the test needs wide empty regions to skip");
        let n = 64;
        let origins: Vec<[f32; 3]> = (0..n).map(|i| [-0.5 + 0.01 * i as f32, 0.3 + 0.005 * i as f32, -0.7]).collect();
        let dirs: Vec<[f32; 3]> = (0..n)
            .map(|i| {
                let a = 0.1 * i as f32;
                let v = [0.3 * a.cos(), 0.2 * a.sin(), 1.0];
                let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                v.map(|c| c / l)
            })
            .collect();
        let (near, far) = (vec![0.1; n], vec![4.0; n]);
        for cone_angle in [0.0, 0.004] {
            for jitter in [SampleMode::Deterministic, SampleMode::Random { seed: 5, step: 2 }] {
                for cap in [1024, 9] {
                    let opt = MarchOptions { step_size: 0.013, max_samples_per_ray: cap, jitter, cone_angle };
                    let whole = g.march(&origins, &dirs, &near, &far, &opt, None);
                    let resumed = |limit: usize, blocks: Option<&OccupancyBlocks>| {
                        let (mut ts, mut te, mut offsets) = (Vec::new(), Vec::new(), vec![0u32]);
                        for r in 0..n {
                            let mut st = g.march_start(r, origins[r], dirs[r], near[r], far[r], &opt);
                            while !st.is_done() {
                                let k = g.march_more(&mut st, origins[r], dirs[r], &opt, blocks, limit, &mut ts, &mut te);
                                assert!(k <= limit);
                            }
                            offsets.push(ts.len() as u32);
                        }
                        (offsets, ts, te)
                    };
                    let skipping = resumed(usize::MAX, Some(&coarse));
                    for (limit, blocks) in [(1, None), (3, None), (4, None), (4, Some(&coarse)), (1, Some(&coarse))] {
                        let (offsets, ts, te) = resumed(limit, blocks);
                        let what = format!("cone {cone_angle} {jitter:?} cap {cap} limit {limit} blocks {}", blocks.is_some());
                        // Cone marching resumes u·step past where it leaves empty space, so a
                        // skip across a whole empty cube places later intervals differently
                        // from a walk cell by cell; constant steps fix every interval's place.
                        let want = if blocks.is_some() && cone_angle > 0.0 { skipping.clone() } else { (whole.offsets.clone(), whole.t_start.clone(), whole.t_end.clone()) };
                        assert_eq!(offsets, want.0, "{what}");
                        assert_eq!(ts, want.1, "{what}");
                        assert_eq!(te, want.2, "{what}");
                    }
                    // Skipping cubes emits only intervals whose midpoints lie in occupied cells.
                    for r in 0..n {
                        for s in skipping.0[r] as usize..skipping.0[r + 1] as usize {
                            let tm = 0.5 * (skipping.1[s] + skipping.2[s]);
                            let p = [0, 1, 2].map(|a| origins[r][a] + tm * dirs[r][a]);
                            assert!(g.is_occupied(g.cell_clamped(p)), "ray {r} sample {s} at {p:?} lies in an empty cell");
                        }
                    }
                    assert!(whole.len() > n / 2, "the test rays must sample something ({})", whole.len());
                }
            }
        }
    }

    /// The empty-space distances are each cell's exact chessboard distance to the nearest
    /// occupied cell (brute force over every pair), on random grids of a few densities, an
    /// empty grid (the cap) and a full one.
    #[test]
    fn empty_space_distance_is_the_exact_chessboard_distance() {
        let r = 11u32;
        for (seed, p) in [(1u64, 0.002f32), (2, 0.01), (3, 0.05), (4, 0.3), (5, 0.0), (6, 1.0)] {
            let mut g = OccupancyGrid::new(cfg(r));
            let mut occupied = Vec::new();
            for z in 0..r {
                for y in 0..r {
                    for x in 0..r {
                        let on = rng::uniform_f32(rng::key(&[seed, (x + r * (y + r * z)) as u64])) < p;
                        g.set_occupied([x, y, z], on);
                        if on {
                            occupied.push([x, y, z]);
                        }
                    }
                }
            }
            let d = g.blocks().dist;
            for z in 0..r {
                for y in 0..r {
                    for x in 0..r {
                        let want = occupied
                            .iter()
                            .map(|o| (0..3).map(|a| o[a].abs_diff([x, y, z][a])).max().unwrap())
                            .min()
                            .map_or(255, |v| v.min(255) as u8);
                        assert_eq!(d[g.cell_index([x, y, z])], want, "seed {seed}, cell {x} {y} {z}");
                    }
                }
            }
        }
    }

    /// The cell-by-cell chamfer [`OccupancyGrid::blocks`] computed before it went a row at a
    /// time (kept as the reference it must equal exactly).
    fn blocks_cell_by_cell(g: &OccupancyGrid) -> Vec<u8> {
        let r = g.config.resolution as i64;
        let n = g.n_cells();
        let mut dist: Vec<u8> = (0..n).map(|i| if g.bit(i) { 0 } else { u8::MAX }).collect();
        let before: Vec<[i64; 3]> = (-1..=1i64)
            .flat_map(|dz| (-1..=1i64).flat_map(move |dy| (-1..=1i64).map(move |dx| [dx, dy, dz])))
            .filter(|&[dx, dy, dz]| (dz, dy, dx) < (0, 0, 0))
            .collect();
        let idx = |x: i64, y: i64, z: i64| (x + r * (y + r * z)) as usize;
        let mut pass = |cells: &mut dyn Iterator<Item = (i64, i64, i64)>, sign: i64| {
            for (x, y, z) in cells {
                let i = idx(x, y, z);
                if dist[i] == 0 {
                    continue;
                }
                let mut m = dist[i];
                for &[dx, dy, dz] in &before {
                    let (nx, ny, nz) = (x + sign * dx, y + sign * dy, z + sign * dz);
                    if (0..r).contains(&nx) && (0..r).contains(&ny) && (0..r).contains(&nz) {
                        m = m.min(dist[idx(nx, ny, nz)].saturating_add(1));
                    }
                }
                dist[i] = m;
            }
        };
        let forward = (0..r).flat_map(|z| (0..r).flat_map(move |y| (0..r).map(move |x| (x, y, z))));
        pass(&mut forward.clone(), 1);
        let backward = (0..r).rev().flat_map(|z| (0..r).rev().flat_map(move |y| (0..r).rev().map(move |x| (x, y, z))));
        pass(&mut backward.clone(), -1);
        dist
    }

    /// The row-at-a-time chamfer equals the cell-by-cell one on grids of 1 to 64 cells a side
    /// (64: the fast model's), sparse, dense, clustered (a shell, as a trained scene's surface)
    /// and empty (every distance at the 255 cap).
    #[test]
    fn row_chamfer_equals_the_cell_by_cell_one() {
        for r in [1u32, 2, 3, 7, 64] {
            for (seed, p) in [(1u64, 0.0005f32), (2, 0.02), (3, 0.5), (4, 0.0), (5, -1.0)] {
                let mut g = OccupancyGrid::new(cfg(r));
                for z in 0..r {
                    for y in 0..r {
                        for x in 0..r {
                            let on = if p < 0.0 {
                                // a spherical shell of radius 0.3 of the grid, one cell thick
                                let c = [x, y, z].map(|v| (v as f32 + 0.5) / r as f32 - 0.5);
                                ((c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt() - 0.3).abs() < 0.5 / r as f32
                            } else {
                                rng::uniform_f32(rng::key(&[seed, (x + r * (y + r * z)) as u64])) < p
                            };
                            g.set_occupied([x, y, z], on);
                        }
                    }
                }
                assert_eq!(g.blocks().dist, blocks_cell_by_cell(&g), "resolution {r}, seed {seed}");
            }
        }
    }

    #[test]
    fn update_marks_dense_regions_and_decays() {
        let mut g = OccupancyGrid::new(cfg(16));
        let ball = |p: &[[f32; 3]]| -> Vec<f32> {
            p.iter().map(|q| if q.iter().map(|v| (v - 0.5).powi(2)).sum::<f32>() < 0.04 { 1000.0 } else { 0.0 }).collect()
        };
        let step_size = 1.7e-3;
        g.update(0, step_size, 0.01, &mut |p| ball(p));
        let center = 0.5 / 16.0;
        for z in 0..16u32 {
            for y in 0..16u32 {
                for x in 0..16u32 {
                    let c = [x, y, z].map(|v| v as f32 / 16.0 + center);
                    let dist = c.iter().map(|v| (v - 0.5).powi(2)).sum::<f32>().sqrt();
                    let half_diag = 3f32.sqrt() * center;
                    if dist + half_diag < 0.2 {
                        assert!(g.is_occupied([x, y, z]), "inside cell {x},{y},{z}");
                    }
                    if dist - half_diag > 0.2 {
                        assert!(!g.is_occupied([x, y, z]), "outside cell {x},{y},{z}");
                    }
                }
            }
        }
        let frac = g.occupied_fraction();
        assert!(frac > 0.02 && frac < 0.1, "{frac}");
        // with the density gone, running densities decay by 0.95 per warm-up update
        let i = g.cell_index([8, 8, 8]);
        let before = g.density[i];
        g.update(1, step_size, 0.01, &mut |p| vec![0.0; p.len()]);
        assert_eq!(g.density[i], before * 0.95);
        // after warm-up only a subset is refreshed
        let mut calls = 0;
        g.update(1000, step_size, 0.01, &mut |p| {
            calls += p.len();
            vec![0.0; p.len()]
        });
        assert!(calls > 4096 / 8 && calls < 4096 / 2, "{calls}");
    }

    #[test]
    fn deterministic_across_thread_counts() {
        let mut g = OccupancyGrid::new(cfg(32));
        g.update(0, 0.01, 0.01, &mut |p| p.iter().map(|q| if q[0] + q[1] > 1.0 { 50.0 } else { 0.0 }).collect());
        let n = 3000;
        let origins: Vec<[f32; 3]> = (0..n).map(|i| [-0.5, (i % 50) as f32 / 50.0, (i / 50) as f32 / 60.0]).collect();
        let dirs: Vec<[f32; 3]> = (0..n).map(|i| [1.0, 0.1 * ((i % 7) as f32 - 3.0), 0.05]).collect();
        let run = |t: usize| {
            rayon::ThreadPoolBuilder::new().num_threads(t).build().unwrap().install(|| {
                g.march(&origins, &dirs, &vec![0.0; n], &vec![3.0; n], &opts(0.004, SampleMode::Random { seed: 1, step: 3 }), None)
            })
        };
        let a = run(1);
        assert!(!a.is_empty());
        assert_eq!(a, run(3));
        assert_eq!(a.ray_index.len(), a.len());
    }
}
