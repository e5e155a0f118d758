//! Mixed-precision (bf16 × bf16 → fp32) products for the fast model's training sweep, on CPUs
//! with AVX512-BF16 (`vdpbf16ps`: 32 multiply-adds per instruction where fp32 FMA does 16;
//! measured 2.0x the fp32 kernel's rate on a Zen 4 core at the networks' 64-wide layers).
//!
//! What is rounded: each product's two inputs (activations or gradients, and weights) are
//! rounded to bf16 (8 significant bits, round to nearest even); the products are exact in fp32
//! and are summed in fp32. Weights, biases, their gradients' sums over samples, and every
//! activation and gradient kept between layers stay fp32 (fp32 master weights, as in
//! mixed-precision training generally). So a layer's output differs from the fp32 one's by
//! about 2⁻⁸ of the sum of its terms' magnitudes, which the module's tests check against an f64
//! reference.
//!
//! Layouts (`u16` = bf16 bits):
//! - row-major inputs `[t][kp]`, `kp` = the input width rounded up to even (zero-padded): the
//!   forward product and the input gradient read two consecutive inputs of a row at once;
//! - packed weights `[kp / 2][np][2]`, `np` = the output width rounded up to 16 (zero-padded):
//!   element `(i, j)` of the pair-row `i` holds `w[2i][j], w[2i + 1][j]`;
//! - sample-paired ("VNNI") `[tp / 2][kq][2]`, `tp` = samples rounded up to even, `kq` = width
//!   rounded up to 16: element `(p, j)` holds `x[2p][j], x[2p + 1][j]`, for the weight gradient
//!   `Σₛ x[s][r] · g[s][j]`, whose sum runs over samples.

// Pointer arithmetic on checked lengths throughout; each public function checks its shapes.
#![allow(clippy::too_many_arguments)]

/// `x` rounded to bf16 (round to nearest even; NaN stays NaN), as its bit pattern.
pub fn to_bf16(x: f32) -> u16 {
    let b = x.to_bits();
    if x.is_nan() {
        return ((b >> 16) | 0x40) as u16;
    }
    let round = 0x7fff + ((b >> 16) & 1);
    (b.wrapping_add(round) >> 16) as u16
}

/// The fp32 value of bf16 bits.
pub fn from_bf16(h: u16) -> f32 {
    f32::from_bits((h as u32) << 16)
}

/// `n` rounded up to a multiple of `m`.
pub fn round_up(n: usize, m: usize) -> usize {
    n.div_ceil(m) * m
}

/// A layer's weights `w` `[k][n]` (row-major) packed for [`dense`]: `[round_up(k, 2) / 2]
/// [round_up(n, 16)][2]`, zero-padded.
pub fn pack_weights(w: &[f32], k: usize, n: usize) -> Vec<u16> {
    assert_eq!(w.len(), k * n, "pack_weights shapes");
    let (kp, np) = (round_up(k, 2), round_up(n, 16));
    let mut out = vec![0u16; kp * np];
    for i in 0..k {
        for j in 0..n {
            out[((i / 2) * np + j) * 2 + i % 2] = to_bf16(w[i * n + j]);
        }
    }
    out
}

/// Whether this CPU runs the bf16 kernels (x86-64 with AVX-512 F/BW and BF16).
pub fn available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512bw")
            && std::arch::is_x86_feature_detected!("avx512vl")
            && std::arch::is_x86_feature_detected!("avx512bf16")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

fn require() {
    assert!(available(), "the bf16 kernels need a CPU with AVX512-BF16 (callers check `available()` first)");
}

/// `src` `[t][k]` into row-major bf16 `dst` `[t][round_up(k, 2)]` (resized; every element
/// written, the padding with zero).
pub fn rows(src: &[f32], t: usize, k: usize, dst: &mut Vec<u16>) {
    assert_eq!(src.len(), t * k, "rows shapes");
    require();
    let kp = round_up(k, 2);
    dst.resize(t * kp, 0);
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has the kernel's features (`require`); the lengths are as checked.
    unsafe {
        x86::rows(src.as_ptr(), t, k, dst.as_mut_ptr(), kp)
    }
}

/// `src` `[t][k]` into sample-paired bf16 `dst` `[round_up(t, 2) / 2][round_up(k, 16)][2]`
/// (resized; every element written, the padding with zero).
pub fn paired(src: &[f32], t: usize, k: usize, dst: &mut Vec<u16>) {
    assert_eq!(src.len(), t * k, "paired shapes");
    require();
    let (tp, kq) = (round_up(t, 2), round_up(k, 16));
    dst.resize(tp * kq, 0);
    #[cfg(target_arch = "x86_64")]
    // SAFETY: as `rows`.
    unsafe {
        x86::paired(src.as_ptr(), t, k, dst.as_mut_ptr(), kq)
    }
}

/// `y[t][n] = b + x·w` through a ReLU when `relu`: `x` row-major bf16 `[t][kp]` ([`rows`]),
/// `w` packed `[kp / 2][np][2]` ([`pack_weights`] of a `[k][≥ n]` matrix, `np` ≥ `n` a
/// multiple of 16), `b` `[≥ n]`; `y` fp32 with rows `n` apart.
pub fn dense(y: &mut [f32], x: &[u16], kp: usize, w: &[u16], np: usize, b: &[f32], t: usize, n: usize, relu: bool) {
    assert!(
        kp.is_multiple_of(2) && np.is_multiple_of(16) && n <= np && y.len() == t * n && x.len() == t * kp && w.len() == kp * np && b.len() >= n,
        "bf16 dense shapes"
    );
    require();
    if t == 0 || n == 0 {
        return;
    }
    #[cfg(target_arch = "x86_64")]
    // SAFETY: as `rows`.
    unsafe {
        x86::dense(y.as_mut_ptr(), x.as_ptr(), kp, w.as_ptr(), np, b.as_ptr(), t, n, relu)
    }
}

/// `c[k][n] += Σₛ x[s][·]ᵀ g[s][·]` (a weight gradient): `x` and `g` sample-paired ([`paired`]
/// of `[t][k]` and `[t][n]`), `c` fp32 row-major `[k][n]`.
pub fn weight_grads_acc(c: &mut [f32], x: &[u16], g: &[u16], t: usize, k: usize, n: usize) {
    let (tp, kq, nq) = (round_up(t, 2), round_up(k, 16), round_up(n, 16));
    assert!(c.len() == k * n && x.len() == tp * kq && g.len() == tp * nq, "bf16 weight_grads_acc shapes");
    require();
    if t == 0 || n == 0 || k == 0 {
        return;
    }
    #[cfg(target_arch = "x86_64")]
    // SAFETY: as `rows`.
    unsafe {
        x86::weight_grads_acc(c.as_mut_ptr(), x.as_ptr(), kq, g.as_ptr(), nq, tp / 2, k, n)
    }
}

#[cfg(target_arch = "x86_64")]
#[allow(unsafe_op_in_unsafe_fn)]
mod x86 {
    use std::arch::x86_64::*;

    /// The mask of the first `n` (≤ 16) lanes.
    #[inline(always)]
    fn lanes(n: usize) -> __mmask16 {
        if n >= 16 { 0xffff } else { ((1u32 << n) - 1) as __mmask16 }
    }

    #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bf16")]
    pub unsafe fn rows(src: *const f32, t: usize, k: usize, dst: *mut u16, kp: usize) {
        for s in 0..t {
            // Loads of the `k` values (zeros past them), stores of all `kp` (the padding too).
            let mut c0 = 0;
            while c0 < kp {
                let v = _mm512_maskz_loadu_ps(lanes(k - c0.min(k)), src.add(s * k + c0));
                let h: __m256i = std::mem::transmute(_mm512_cvtneps_pbh(v));
                _mm256_mask_storeu_epi16(dst.add(s * kp + c0) as *mut i16, lanes(kp - c0), h);
                c0 += 16;
            }
        }
    }

    #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bf16")]
    pub unsafe fn paired(src: *const f32, t: usize, k: usize, dst: *mut u16, kq: usize) {
        // Word 2j of the result is word j of `cvtne2ps(b, a)` (a's lane j), word 2j + 1 its word
        // 16 + j (b's lane j).
        let mut idx = [0i16; 32];
        for j in 0..16 {
            idx[2 * j] = j as i16;
            idx[2 * j + 1] = 16 + j as i16;
        }
        let idx = _mm512_loadu_si512(idx.as_ptr() as *const _);
        for p in 0..t.div_ceil(2) {
            let (s0, s1) = (2 * p, 2 * p + 1);
            let mut c0 = 0;
            while c0 < k {
                let m = lanes(k - c0);
                let a = _mm512_maskz_loadu_ps(m, src.add(s0 * k + c0));
                let b = if s1 < t { _mm512_maskz_loadu_ps(m, src.add(s1 * k + c0)) } else { _mm512_setzero_ps() };
                let h: __m512i = std::mem::transmute(_mm512_cvtne2ps_pbh(b, a));
                _mm512_storeu_si512(dst.add((p * kq + c0) * 2) as *mut _, _mm512_permutexvar_epi16(idx, h));
                c0 += 16;
            }
        }
    }

    /// `RB` rows × `NV` vectors of [`dense`]'s output from row `r0`, column `c0`.
    #[inline(always)]
    unsafe fn dense_block<const RB: usize, const NV: usize>(y: *mut f32, x: *const u16, kp: usize, w: *const u16, np: usize, b: *const f32, r0: usize, c0: usize, n: usize, relu: bool) {
        let mut acc = [[_mm512_setzero_ps(); NV]; RB];
        for a in acc.iter_mut() {
            for (v, av) in a.iter_mut().enumerate() {
                *av = _mm512_maskz_loadu_ps(lanes(n - (c0 + 16 * v).min(n)), b.add(c0 + 16 * v));
            }
        }
        for i in 0..kp / 2 {
            let mut wv = [_mm512_setzero_si512(); NV];
            for (v, wvv) in wv.iter_mut().enumerate() {
                *wvv = _mm512_loadu_si512(w.add((i * np + c0 + 16 * v) * 2) as *const _);
            }
            for (r, a) in acc.iter_mut().enumerate() {
                let xv = _mm512_set1_epi32((x.add((r0 + r) * kp + 2 * i) as *const i32).read_unaligned());
                for v in 0..NV {
                    a[v] = _mm512_dpbf16_ps(a[v], std::mem::transmute::<__m512i, __m512bh>(xv), std::mem::transmute::<__m512i, __m512bh>(wv[v]));
                }
            }
        }
        for (r, a) in acc.iter().enumerate() {
            for (v, av) in a.iter().enumerate() {
                let o = if relu { _mm512_max_ps(*av, _mm512_setzero_ps()) } else { *av };
                let c = c0 + 16 * v;
                _mm512_mask_storeu_ps(y.add((r0 + r) * n + c), lanes(n - c.min(n)), o);
            }
        }
    }

    #[inline(always)]
    unsafe fn dense_band<const RB: usize, const NV: usize>(y: *mut f32, x: *const u16, kp: usize, w: *const u16, np: usize, b: *const f32, t: usize, c0: usize, n: usize, relu: bool) {
        let mut r0 = 0;
        while r0 + RB <= t {
            dense_block::<RB, NV>(y, x, kp, w, np, b, r0, c0, n, relu);
            r0 += RB;
        }
        for r in r0..t {
            dense_block::<1, NV>(y, x, kp, w, np, b, r, c0, n, relu);
        }
    }

    #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bf16")]
    pub unsafe fn dense(y: *mut f32, x: *const u16, kp: usize, w: *const u16, np: usize, b: *const f32, t: usize, n: usize, relu: bool) {
        let mut c0 = 0;
        while c0 < n {
            // Vectors of 16 columns still to do (the last one possibly partial).
            match (n - c0).div_ceil(16) {
                1 => dense_band::<8, 1>(y, x, kp, w, np, b, t, c0, n, relu),
                2 => dense_band::<4, 2>(y, x, kp, w, np, b, t, c0, n, relu),
                3 => dense_band::<4, 3>(y, x, kp, w, np, b, t, c0, n, relu),
                _ => dense_band::<4, 4>(y, x, kp, w, np, b, t, c0, n, relu),
            }
            c0 += 64;
        }
    }

    /// Sample pairs per pass of the weight-gradient kernel: a pass's `x` and `g` (at most 64
    /// wide: 8 KiB each) stay in L1 while every block of `c` reads them.
    const PAIRS: usize = 32;

    #[inline(always)]
    unsafe fn grad_block<const RB: usize, const NV: usize>(c: *mut f32, x: *const u16, kq: usize, g: *const u16, nq: usize, p0: usize, p1: usize, r0: usize, c0: usize, n: usize) {
        let mut acc = [[_mm512_setzero_ps(); NV]; RB];
        for (r, a) in acc.iter_mut().enumerate() {
            for (v, av) in a.iter_mut().enumerate() {
                let col = c0 + 16 * v;
                *av = _mm512_maskz_loadu_ps(lanes(n - col.min(n)), c.add((r0 + r) * n + col));
            }
        }
        for p in p0..p1 {
            let mut gv = [_mm512_setzero_si512(); NV];
            for (v, gvv) in gv.iter_mut().enumerate() {
                *gvv = _mm512_loadu_si512(g.add((p * nq + c0 + 16 * v) * 2) as *const _);
            }
            for (r, a) in acc.iter_mut().enumerate() {
                let xv = _mm512_set1_epi32((x.add((p * kq + r0 + r) * 2) as *const i32).read_unaligned());
                for v in 0..NV {
                    a[v] = _mm512_dpbf16_ps(a[v], std::mem::transmute::<__m512i, __m512bh>(xv), std::mem::transmute::<__m512i, __m512bh>(gv[v]));
                }
            }
        }
        for (r, a) in acc.iter().enumerate() {
            for (v, av) in a.iter().enumerate() {
                let col = c0 + 16 * v;
                _mm512_mask_storeu_ps(c.add((r0 + r) * n + col), lanes(n - col.min(n)), *av);
            }
        }
    }

    #[inline(always)]
    unsafe fn grad_band<const RB: usize, const NV: usize>(c: *mut f32, x: *const u16, kq: usize, g: *const u16, nq: usize, p0: usize, p1: usize, k: usize, c0: usize, n: usize) {
        let mut r0 = 0;
        while r0 + RB <= k {
            grad_block::<RB, NV>(c, x, kq, g, nq, p0, p1, r0, c0, n);
            r0 += RB;
        }
        for r in r0..k {
            grad_block::<1, NV>(c, x, kq, g, nq, p0, p1, r, c0, n);
        }
    }

    #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bf16")]
    pub unsafe fn weight_grads_acc(c: *mut f32, x: *const u16, kq: usize, g: *const u16, nq: usize, pairs: usize, k: usize, n: usize) {
        let mut p0 = 0;
        while p0 < pairs {
            let p1 = (p0 + PAIRS).min(pairs);
            let mut c0 = 0;
            while c0 < n {
                match (n - c0).div_ceil(16) {
                    1 => grad_band::<8, 1>(c, x, kq, g, nq, p0, p1, k, c0, n),
                    2 => grad_band::<4, 2>(c, x, kq, g, nq, p0, p1, k, c0, n),
                    3 => grad_band::<4, 3>(c, x, kq, g, nq, p0, p1, k, c0, n),
                    _ => grad_band::<4, 4>(c, x, kq, g, nq, p0, p1, k, c0, n),
                }
                c0 += 64;
            }
            p0 = p1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic values in about [-1, 1] with varied magnitudes.
    fn values(n: usize, seed: u64) -> Vec<f32> {
        let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        (0..n)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                let u = (s >> 40) as f32 / (1u64 << 24) as f32;
                (u - 0.5) * 2.0 * if s & 3 == 0 { 1e-3 } else { 1.0 }
            })
            .collect()
    }

    fn rounded(v: &[f32]) -> Vec<f64> {
        v.iter().map(|&x| from_bf16(to_bf16(x)) as f64).collect()
    }

    #[test]
    fn rounding_to_bf16_is_to_nearest_even() {
        assert_eq!(to_bf16(1.0), 0x3f80);
        // 1 + 2⁻⁸ is halfway between 1 and 1 + 2⁻⁷: to even (1).
        assert_eq!(from_bf16(to_bf16(1.0 + 1.0 / 256.0)), 1.0);
        // 1 + 3·2⁻⁸ is halfway between 1 + 2⁻⁷ and 1 + 2⁻⁶: to even (1 + 2⁻⁶).
        assert_eq!(from_bf16(to_bf16(1.0 + 3.0 / 256.0)), 1.0 + 1.0 / 64.0);
        assert_eq!(from_bf16(to_bf16(-2.5)), -2.5);
        assert!(from_bf16(to_bf16(f32::NAN)).is_nan());
        assert_eq!(from_bf16(to_bf16(f32::INFINITY)), f32::INFINITY);
        for x in values(1000, 3) {
            let r = from_bf16(to_bf16(x));
            assert!((r - x).abs() <= x.abs() * (1.0 / 256.0), "{x} → {r}");
        }
    }

    /// `start + Σ a·b` over `terms` in f64, and `|start| + Σ |a·b|` (the scale of its rounding).
    fn reference(start: f32, terms: impl Iterator<Item = (f64, f64)>) -> (f64, f64) {
        terms.fold((start as f64, (start as f64).abs()), |(sum, mag), (a, b)| (sum + a * b, mag + (a * b).abs()))
    }

    /// Every product's inputs rounded to bf16, summed in f64: what the kernels compute, up to
    /// fp32 summation error, which is bounded by `k · 2⁻²³` (plus slack) of the sum of the
    /// terms' magnitudes.
    fn close(got: f32, want: f64, mag: f64, terms: usize, what: &str) {
        let tol = mag * (terms as f64 + 4.0) * f32::EPSILON as f64 + 1e-30;
        assert!(((got as f64) - want).abs() <= tol, "{what}: {got} vs {want} (tolerance {tol:e})");
    }

    #[test]
    fn the_bf16_product_sums_the_rounded_products_exactly_in_fp32() {
        if !available() {
            eprintln!("skipped: this CPU has no AVX512-BF16");
            return;
        }
        for &(t, k, n) in &[(1, 1, 1), (7, 3, 5), (33, 32, 64), (64, 64, 16), (13, 64, 3), (9, 17, 70), (512, 32, 64), (5, 64, 64)] {
            let x = values(t * k, (t * 31 + k) as u64);
            let w = values(k * n, (k * 17 + n) as u64);
            let b = values(n, 99);
            let (kp, np) = (round_up(k, 2), round_up(n, 16));
            let mut xb = Vec::new();
            rows(&x, t, k, &mut xb);
            let wp = pack_weights(&w, k, n);
            let (xr, wr) = (rounded(&x), rounded(&w));
            // All `n` columns, with and without the ReLU, and the first `n − 2` only (an input
            // gradient needed for the first columns reads the same packed weights).
            let widths = if n > 2 { vec![(n, false), (n, true), (n - 2, false)] } else { vec![(n, false), (n, true)] };
            for (m, relu) in widths {
                let mut y = vec![f32::NAN; t * m];
                dense(&mut y, &xb, kp, &wp, np, &b, t, m, relu);
                for s in 0..t {
                    for j in 0..m {
                        let (sum, mag) = reference(b[j], (0..k).map(|i| (xr[s * k + i], wr[i * n + j])));
                        let want = if relu { sum.max(0.0) } else { sum };
                        close(y[s * m + j], want, mag, k, &format!("dense {t}x{k}x{n} (first {m} columns, relu {relu}) at ({s}, {j})"));
                    }
                }
            }
        }
    }

    #[test]
    fn the_bf16_weight_gradient_sums_the_rounded_products_over_samples() {
        if !available() {
            eprintln!("skipped: this CPU has no AVX512-BF16");
            return;
        }
        for &(t, k, n) in &[(1, 1, 1), (7, 3, 5), (33, 32, 64), (64, 64, 16), (13, 64, 3), (9, 17, 70), (512, 64, 64), (129, 16, 64)] {
            let x = values(t * k, (t * 7 + k) as u64);
            let g = values(t * n, (t * 5 + n) as u64);
            let c0 = values(k * n, 5);
            let (mut xv, mut gv) = (Vec::new(), Vec::new());
            paired(&x, t, k, &mut xv);
            paired(&g, t, n, &mut gv);
            let mut c = c0.clone();
            weight_grads_acc(&mut c, &xv, &gv, t, k, n);
            let (xr, gr) = (rounded(&x), rounded(&g));
            for r in 0..k {
                for j in 0..n {
                    let (sum, mag) = reference(c0[r * n + j], (0..t).map(|s| (xr[s * k + r], gr[s * n + j])));
                    close(c[r * n + j], sum, mag, t, &format!("weight gradient {t}x{k}x{n} at ({r}, {j})"));
                }
            }
        }
    }

    #[test]
    fn the_conversions_round_each_value_and_zero_the_padding() {
        if !available() {
            eprintln!("skipped: this CPU has no AVX512-BF16");
            return;
        }
        let (t, k) = (5, 19);
        let x = values(t * k, 11);
        // Stale values in the buffers must not survive (they are reused between tiles).
        let mut r = vec![0xffffu16; 3 * t * k];
        rows(&x, t, k, &mut r);
        assert_eq!(r.len(), t * round_up(k, 2));
        let kp = round_up(k, 2);
        for s in 0..t {
            for i in 0..kp {
                let want = if i < k { to_bf16(x[s * k + i]) } else { 0 };
                assert_eq!(r[s * kp + i], want, "rows ({s}, {i})");
            }
        }
        let mut p = vec![0xffffu16; 7];
        paired(&x, t, k, &mut p);
        assert_eq!(p.len(), round_up(t, 2) * round_up(k, 16));
        let mut p2 = vec![0xffffu16; 4 * t * k];
        paired(&x, t, k, &mut p2);
        assert_eq!(p, p2);
        let kq = round_up(k, 16);
        for pi in 0..t.div_ceil(2) {
            for j in 0..kq {
                for h in 0..2 {
                    let s = 2 * pi + h;
                    let want = if s < t && j < k { to_bf16(x[s * k + j]) } else { 0 };
                    assert_eq!(p[(pi * kq + j) * 2 + h], want, "paired ({s}, {j})");
                }
            }
        }
    }
}
