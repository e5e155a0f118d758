//! The NeRF paper's positional encoding, as in the official code (`get_embedder` in
//! `run_nerf_helpers.py`):
//!
//! ```text
//! γ(p) = (p, sin(2⁰ p), cos(2⁰ p), sin(2¹ p), cos(2¹ p), …, sin(2^{L−1} p), cos(2^{L−1} p))
//! ```
//!
//! applied to every coordinate, each term a 3-vector, so `3 + 3 · 2 · L` outputs. The official
//! code has **no π** in the frequencies (the paper's equation writes `sin(2^k π p)`); we follow
//! the code, so inputs are expected in roughly `[−π, π]` or a few scene units (the paper's
//! Blender scenes live in `[−1.5, 1.5]³`). `L = 10` for positions, `L = 4` for directions.
//!
//! Example: `p = (0.5, 0, 0)`, `L = 1` → `(0.5, 0, 0, sin 0.5, 0, 0, cos 0.5, 1, 1)`
//! `= (0.5, 0, 0, 0.479426, 0, 0, 0.877583, 1, 1)`.

/// `3 + 6 · n_frequencies`.
pub const fn frequency_output_dim(n_frequencies: usize) -> usize {
    3 + 6 * n_frequencies
}

/// Encodes points with `n_frequencies` octaves (see the module doc for the order).
///
/// # Shapes
/// `points`: `[N]` → `out`: `[N · (3 + 6 L)]`, row-major
pub fn frequency_encode(points: &[[f32; 3]], n_frequencies: usize, out: &mut [f32]) {
    let k = frequency_output_dim(n_frequencies);
    assert_eq!(out.len(), points.len() * k, "out must hold N · (3 + 6 L) floats");
    for (p, o) in points.iter().zip(out.chunks_exact_mut(k)) {
        o[..3].copy_from_slice(p);
        for f in 0..n_frequencies {
            let scale = (1u64 << f) as f32;
            for a in 0..3 {
                let (s, c) = (scale * p[a]).sin_cos();
                o[3 + 6 * f + a] = s;
                o[3 + 6 * f + 3 + a] = c;
            }
        }
    }
}

/// The gradient with respect to each point of `L = Σ d_out · γ(p)`:
/// `∂L/∂p_a = d[a] + Σ_f 2^f (d_sin[f][a] cos(2^f p_a) − d_cos[f][a] sin(2^f p_a))`.
///
/// # Shapes
/// `points`: `[N]`, `d_out`: `[N · (3 + 6 L)]` as [`frequency_encode`]'s `out`; returns `[N]`.
pub fn frequency_point_gradient(points: &[[f32; 3]], n_frequencies: usize, d_out: &[f32]) -> Vec<[f32; 3]> {
    let k = frequency_output_dim(n_frequencies);
    assert_eq!(d_out.len(), points.len() * k, "d_out must hold N · (3 + 6 L) floats");
    points
        .iter()
        .zip(d_out.chunks_exact(k))
        .map(|(p, d)| {
            std::array::from_fn(|a| {
                let mut g = d[a];
                for f in 0..n_frequencies {
                    let scale = (1u64 << f) as f32;
                    let (s, c) = (scale * p[a]).sin_cos();
                    g += scale * (d[3 + 6 * f + a] * c - d[6 + 6 * f + a] * s);
                }
                g
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn point_gradient_matches_finite_differences() {
        let pts = [[0.3f32, -1.2, 2.0], [0.01, 0.7, -0.4]];
        let n = 6;
        let k = frequency_output_dim(n);
        let d: Vec<f32> = (0..pts.len() * k).map(|i| ((i * 37 % 11) as f32 - 5.0) * 0.1).collect();
        let g = frequency_point_gradient(&pts, n, &d);
        let loss = |q: [f64; 3], j: usize| -> f64 {
            let mut o = vec![0.0; k];
            // f64 reference of the encoding.
            for a in 0..3 {
                o[a] = q[a];
                for f in 0..n {
                    let x = 2f64.powi(f as i32) * q[a];
                    o[3 + 6 * f + a] = x.sin();
                    o[6 + 6 * f + a] = x.cos();
                }
            }
            o.iter().zip(&d[j * k..(j + 1) * k]).map(|(a, b)| a * *b as f64).sum()
        };
        for (j, p) in pts.iter().enumerate() {
            for a in 0..3 {
                let h = 1e-6;
                let (mut lo, mut hi) = (p.map(|v| v as f64), p.map(|v| v as f64));
                lo[a] -= h;
                hi[a] += h;
                let fd = (loss(hi, j) - loss(lo, j)) / (2.0 * h);
                assert!((g[j][a] as f64 - fd).abs() < 1e-3 * (1.0 + fd.abs()), "point {j} axis {a}: {} vs {fd}", g[j][a]);
            }
        }
    }

    #[test]
    fn matches_the_official_layout() {
        let mut out = vec![0.0; frequency_output_dim(1)];
        frequency_encode(&[[0.5, 0.0, 0.0]], 1, &mut out);
        let want = [0.5, 0.0, 0.0, 0.5f32.sin(), 0.0, 0.0, 0.5f32.cos(), 1.0, 1.0];
        assert_eq!(out, want);
        let p = [0.3f32, -1.2, 2.0];
        let mut out = vec![0.0; frequency_output_dim(10)];
        frequency_encode(&[p], 10, &mut out);
        for f in 0..10 {
            for a in 0..3 {
                let x = 2f64.powi(f as i32) * p[a] as f64;
                assert!((out[3 + 6 * f + a] as f64 - x.sin()).abs() < 2e-4);
                assert!((out[6 + 6 * f + a] as f64 - x.cos()).abs() < 2e-4);
            }
        }
    }
}
