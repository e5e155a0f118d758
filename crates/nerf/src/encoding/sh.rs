//! Real spherical harmonics of a unit direction up to degree 4 (16 outputs), exactly the basis
//! and ordering of tiny-cuda-nn's `SphericalHarmonics` encoding (instant-ngp's view direction
//! encoding).
//!
//! tiny-cuda-nn takes directions mapped to `[0, 1]³` and undoes it with `x = 2u − 1`; here the
//! input is the unit direction itself. Degree `d` (1..=4) gives `d²` outputs, ordered by band
//! `ℓ = 0..d` then `m = −ℓ..ℓ`:
//!
//! ```text
//! Y0  = 0.28209479                       (1 / (2 √π))
//! Y1  = −0.48860251 y   Y2 = 0.48860251 z   Y3 = −0.48860251 x
//! Y4  = 1.09254843 xy   Y5 = −1.09254843 yz  Y6 = 0.94617470 z² − 0.31539157
//! Y7  = −1.09254843 xz  Y8 = 0.54627422 (x² − y²)
//! Y9  = 0.59004359 y (y² − 3x²)            Y10 = 2.89061144 xyz
//! Y11 = 0.45704580 y (1 − 5z²)             Y12 = 0.37317633 z (5z² − 3)
//! Y13 = 0.45704580 x (1 − 5z²)             Y14 = 1.44530572 z (x² − y²)
//! Y15 = 0.59004359 x (3y² − x²)
//! ```
//!
//! They are orthonormal over the unit sphere: `∫ Y_i Y_j dω = δ_ij`.
//! Example: `d = (0, 0, 1)` → `Y0 = 0.282095, Y2 = 0.488603, Y6 = 0.630783, Y12 = 0.746353`,
//! all others 0.

/// Number of outputs for a degree (`degree²`).
pub const fn sh_output_dim(degree: usize) -> usize {
    degree * degree
}

/// The 16 degree-4 harmonics of a unit direction (callers wanting degree `d < 4` take the
/// first `d²`). The direction is used as given (normalise it first).
pub fn sh_encode(d: [f32; 3]) -> [f32; 16] {
    let [x, y, z] = d;
    let (x2, y2, z2) = (x * x, y * y, z * z);
    let (xy, yz, xz) = (x * y, y * z, x * z);
    [
        0.282_094_8,
        -0.488_602_52 * y,
        0.488_602_52 * z,
        -0.488_602_52 * x,
        1.092_548_4 * xy,
        -1.092_548_4 * yz,
        0.946_174_7 * z2 - 0.315_391_57,
        -1.092_548_4 * xz,
        0.546_274_2 * (x2 - y2),
        0.590_043_6 * y * (-3.0 * x2 + y2),
        2.890_611_4 * xy * z,
        0.457_045_8 * y * (1.0 - 5.0 * z2),
        0.373_176_33 * z * (5.0 * z2 - 3.0),
        0.457_045_8 * x * (1.0 - 5.0 * z2),
        1.445_305_7 * z * (x2 - y2),
        0.590_043_6 * x * (-x2 + 3.0 * y2),
    ]
}

/// Encodes a batch of directions at `degree` (1..=4).
///
/// # Shapes
/// `dirs`: `[N]` → `out`: `[N · degree²]`, row-major
pub fn sh_encode_batch(dirs: &[[f32; 3]], degree: usize, out: &mut [f32]) {
    assert!((1..=4).contains(&degree), "spherical-harmonics degree must be 1..=4");
    let k = sh_output_dim(degree);
    assert_eq!(out.len(), dirs.len() * k);
    for (d, o) in dirs.iter().zip(out.chunks_exact_mut(k)) {
        o.copy_from_slice(&sh_encode(*d)[..k]);
    }
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;

    #[test]
    fn orthonormal_over_the_sphere() {
        // midpoint rule in z = cos θ (the integrands are polynomials of degree ≤ 8 in z times
        // trigonometric polynomials in φ, for which the uniform φ rule is exact)
        let (nz, nphi) = (400, 64);
        let mut gram = [[0.0f64; 16]; 16];
        let dw = (2.0 / nz as f64) * (2.0 * std::f64::consts::PI / nphi as f64);
        for i in 0..nz {
            let z = -1.0 + (i as f64 + 0.5) * 2.0 / nz as f64;
            let r = (1.0 - z * z).sqrt();
            for j in 0..nphi {
                let phi = 2.0 * std::f64::consts::PI * j as f64 / nphi as f64;
                let y = sh_encode([(r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32]);
                for a in 0..16 {
                    for b in 0..16 {
                        gram[a][b] += y[a] as f64 * y[b] as f64 * dw;
                    }
                }
            }
        }
        for a in 0..16 {
            for b in 0..16 {
                let want = if a == b { 1.0 } else { 0.0 };
                assert!((gram[a][b] - want).abs() < 2e-4, "<Y{a}, Y{b}> = {}", gram[a][b]);
            }
        }
    }

    #[test]
    fn worked_example_and_batch() {
        let y = sh_encode([0.0, 0.0, 1.0]);
        for (i, v) in [(0, 0.282095), (2, 0.488603), (6, 0.630783), (12, 0.746353)] {
            assert!((y[i] - v).abs() < 1e-6, "Y{i} = {}", y[i]);
        }
        assert_eq!(y.iter().filter(|v| **v != 0.0).count(), 4);
        let mut out = vec![0.0; 2 * 9];
        sh_encode_batch(&[[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], 3, &mut out);
        assert_eq!(out[9..], y[..9]);
        assert!((out[3] + 0.488603).abs() < 1e-6);
    }
}
