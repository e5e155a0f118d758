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

#[cfg(test)]
mod tests {
    use super::*;

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
