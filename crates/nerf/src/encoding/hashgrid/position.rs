//! The encoding's gradient with respect to its input points, which camera refinement needs
//! (a pose moves every sample point of its rays).
//!
//! Within a cell the level's features are trilinear in the point, so with
//! `x = p · N_l`, `f = x − c` and corner weights `w_v = Π_a (f_a or 1 − f_a)`:
//!
//! ```text
//! ∂L/∂p_a = Σ_l N_l Σ_corners v ∂w_v/∂f_a · (d_l · θ_l[index_l(v)])
//! ∂w_v/∂f_a = ±Π_{b≠a} (f_b or 1 − f_b)     (+ where v_a = c_a + 1, − otherwise)
//! ```
//!
//! for `L = Σ_l d_l · enc_l(p)`. The encoding is continuous across cell faces but its
//! derivative is not; at a face the cell the forward chose (`c = min(floor(x), N − 1)`) gives
//! the one-sided derivative. An axis clamped to `[0, 1]` (or NaN, treated as 0) has derivative
//! 0. Each point's gradient is summed over levels in order in f64, so results do not depend on
//! the thread count.

use super::{HashGrid, Level, POINT_CHUNK, clamp01, corners, levels};
use rayon::prelude::*;

impl HashGrid {
    /// The gradient of `L = Σ_p Σ_l d_l(p) · enc_l(p)` with respect to each point `p` (see the
    /// module doc), with the encoding's gradient level-major as [`Self::backward_adam`] reads
    /// it.
    ///
    /// # Shapes
    /// `points`: `[N]`; `d_lvl`: `[L][N][F]`; returns `[N]`.
    pub fn point_gradient(&self, points: &[[f32; 3]], d_lvl: &[f32]) -> Vec<[f32; 3]> {
        match self.config.features_per_level {
            1 => self.point_gradient_f::<1>(points, d_lvl),
            2 => self.point_gradient_f::<2>(points, d_lvl),
            4 => self.point_gradient_f::<4>(points, d_lvl),
            8 => self.point_gradient_f::<8>(points, d_lvl),
            f => panic!("unsupported features_per_level {f}"),
        }
    }

    fn point_gradient_f<const F: usize>(
        &self,
        points: &[[f32; 3]],
        d_lvl: &[f32],
    ) -> Vec<[f32; 3]> {
        let n = points.len();
        assert_eq!(
            d_lvl.len(),
            n * self.output_dim(),
            "d_lvl must hold L · N · F floats"
        );
        let lvs = levels(&self.config);
        let tf = self.config.table_size() * F;
        let mut out = vec![[0f32; 3]; n];
        out.par_chunks_mut(POINT_CHUNK)
            .enumerate()
            .for_each(|(chunk, o)| {
                for (k, g) in o.iter_mut().enumerate() {
                    let i = chunk * POINT_CHUNK + k;
                    let mut acc = [0f64; 3];
                    for (l, lv) in lvs.iter().enumerate() {
                        let d = &d_lvl[(l * n + i) * F..(l * n + i + 1) * F];
                        if d.iter().all(|v| *v == 0.0) {
                            continue;
                        }
                        let table = &self.params[l * tf..(l + 1) * tf];
                        let dl = if lv.dense {
                            level_gradient::<F, true>(points[i], lv, table, d)
                        } else {
                            level_gradient::<F, false>(points[i], lv, table, d)
                        };
                        for a in 0..3 {
                            acc[a] += dl[a];
                        }
                    }
                    *g = acc.map(|v| v as f32);
                }
            });
        out
    }
}

/// One level's `∂(d · enc_l(p))/∂p`.
#[inline(always)]
fn level_gradient<const F: usize, const DENSE: bool>(
    p: [f32; 3],
    lv: &Level,
    table: &[f32],
    d: &[f32],
) -> [f64; 3] {
    let (idx, _) = corners::<DENSE>(p, lv);
    let mut f = [0f64; 3];
    let mut inside = [false; 3];
    for a in 0..3 {
        // The fraction exactly as `corners` computes it.
        let x = clamp01(p[a]) as f64 * lv.res_f;
        let c = (x as u32).min(lv.res - 1);
        f[a] = (x - c as f64) as f32 as f64;
        inside[a] = (0.0..=1.0).contains(&p[a]);
    }
    let w = |a: usize, bit: usize| if bit == 1 { f[a] } else { 1.0 - f[a] };
    let mut g = [0f64; 3];
    for (c, &e) in idx.iter().enumerate() {
        let bits = [c & 1, (c >> 1) & 1, c >> 2];
        let s: f64 = (0..F)
            .map(|j| d[j] as f64 * table[e as usize * F + j] as f64)
            .sum();
        for a in 0..3 {
            let sign = if bits[a] == 1 { 1.0 } else { -1.0 };
            let others: f64 = (0..3).filter(|b| *b != a).map(|b| w(b, bits[b])).product();
            g[a] += sign * others * s;
        }
    }
    std::array::from_fn(|a| if inside[a] { g[a] * lv.res_f } else { 0.0 })
}
