//! Matrix products on row-major slices through the `gemm` crate (single-threaded: the
//! callers parallelise over tiles). Unsafe code (as in [`super::bf16`] and the hash grid's
//! SIMD): `gemm`'s entry point takes raw pointers and strides, and each wrapper checks every
//! slice's length against the shape first.

use gemm::{Parallelism, gemm};

/// `c = a · b` for square `n × n` matrices through `gemm` on every rayon thread: the
/// machine's practical fp32 matmul peak, in GFLOP/s (the best of `reps` timed runs after
/// one warm-up).
pub fn gemm_peak_gflops(n: usize, reps: usize) -> f64 {
    let a: Vec<f32> = (0..n * n).map(|k| ((k * 7919) % 1000) as f32 * 1e-3 - 0.5).collect();
    let b: Vec<f32> = (0..n * n).map(|k| ((k * 104729) % 1000) as f32 * 1e-3 - 0.5).collect();
    let mut c = vec![0.0f32; n * n];
    let mut best = f64::INFINITY;
    for rep in 0..=reps {
        let t = std::time::Instant::now();
        // SAFETY: a, b and c hold n × n values each, row-major with the strides given; c is exclusive.
        unsafe {
            gemm(
                n, n, n, c.as_mut_ptr(), 1, n as isize, false, a.as_ptr(), 1, n as isize, b.as_ptr(), 1, n as isize, 0.0, 1.0,
                false, false, false, Parallelism::Rayon(0),
            )
        }
        if rep > 0 {
            best = best.min(t.elapsed().as_secs_f64());
        }
    }
    std::hint::black_box(&c);
    2.0 * (n as f64).powi(3) / best / 1e9
}

/// `c[m][n] += a[m][k] · b[k][n]`.
pub fn matmul_acc(c: &mut [f32], a: &[f32], b: &[f32], m: usize, k: usize, n: usize) {
    assert!(c.len() == m * n && a.len() == m * k && b.len() == k * n, "matmul_acc shapes");
    if m == 0 || n == 0 || k == 0 {
        return;
    }
    // SAFETY: the lengths match the shapes and strides (checked above); `c` is exclusive.
    unsafe {
        gemm(
            m, n, k, c.as_mut_ptr(), 1, n as isize, true, a.as_ptr(), 1, k as isize, b.as_ptr(), 1, n as isize, 1.0, 1.0,
            false, false, false, Parallelism::None,
        )
    }
}

/// A dense layer's forward pass: `y[m][n] = b + x[m][k] · w[k][n]`, through a ReLU when
/// `relu`. Small layers (the fast model's are 16 to 64 wide) are far from `gemm`'s sweet
/// spot, so where the CPU has FMA this runs a register-blocked kernel compiled for AVX-512
/// or AVX2 (chosen at run time): 4 rows × 2 vectors (or 8 rows × 1) of accumulators, each
/// output `b + Σᵢ x[i]·w[i]` fused-multiply-added in `i` order; columns left over (fewer
/// than a vector, e.g. the colour output's 3) are dot products in vector lanes. A row's
/// result never depends on the other rows of the call (so a pixel renders the same in any
/// batch), and for widths that are multiples of 16 not on which kernel ran. Elsewhere:
/// `gemm` (whose results do depend on the batch).
#[allow(clippy::too_many_arguments)]
pub fn dense(y: &mut [f32], x: &[f32], w: &[f32], b: &[f32], m: usize, k: usize, n: usize, relu: bool) {
    dense_strided(y, x, w, n, b, m, k, n, relu)
}

/// [`dense`] with the weights' rows `ldw ≥ n` floats apart: `w` `[k][ldw]`, of which the
/// first `n` columns are used (an input gradient needed for only the first `n` inputs of
/// a layer reads those columns of its transposed weights).
#[allow(clippy::too_many_arguments)]
pub fn dense_strided(y: &mut [f32], x: &[f32], w: &[f32], ldw: usize, b: &[f32], m: usize, k: usize, n: usize, relu: bool) {
    assert!(
        y.len() == m * n && x.len() == m * k && ldw >= n && w.len() == k * ldw && b.len() == n,
        "dense shapes"
    );
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has the features the function is compiled for (checked above).
            unsafe { blocked::dense_avx512(y, x, w, ldw, b, m, k, n, relu) };
            return;
        }
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
            // SAFETY: as above.
            unsafe { blocked::dense_avx2(y, x, w, ldw, b, m, k, n, relu) };
            return;
        }
    }
    for row in y.chunks_exact_mut(n.max(1)) {
        row.copy_from_slice(b);
    }
    if ldw == n {
        matmul_acc(y, x, w, m, k, n);
    } else {
        let wn: Vec<f32> = w.chunks_exact(ldw).flat_map(|r| r[..n].iter().copied()).collect();
        matmul_acc(y, x, &wn, m, k, n);
    }
    if relu {
        y.iter_mut().for_each(|v| *v = v.max(0.0));
    }
}

#[cfg(target_arch = "x86_64")]
pub(super) mod blocked {
    use std::arch::x86_64::*;

    /// A kernel's register block: `RB` rows × `NV` vectors of output from row `r0`, column
    /// `c0` (its other arguments held by the implementer).
    trait Blocks {
        /// # Safety
        /// The block lies within the kernel's checked shapes; the CPU has its features.
        unsafe fn block<const RB: usize, const NV: usize>(&self, r0: usize, c0: usize);
    }

    /// The walk both kernels make over a `rows × cols` output: column blocks `NVW` vectors
    /// of `W` lanes wide where the registers allow, then 2, then 1 vector (rows in fours,
    /// in eights for one vector to keep 8 accumulators in flight, the rest one by one).
    /// Returns the first column no block covered (fewer than `W` are left).
    ///
    /// # Safety
    /// As [`Blocks::block`], for every block of the output.
    #[inline(always)]
    unsafe fn walk<B: Blocks, const W: usize, const NVW: usize>(b: &B, rows: usize, cols: usize) -> usize {
        let mut c0 = 0;
        // SAFETY (all bands): rows < `rows` and columns < `cols` (the caller's promise).
        unsafe {
            while c0 + NVW * W <= cols {
                band::<B, 4, NVW>(b, rows, c0);
                c0 += NVW * W;
            }
            while c0 + 2 * W <= cols {
                band::<B, 4, 2>(b, rows, c0);
                c0 += 2 * W;
            }
            while c0 + W <= cols {
                band::<B, 8, 1>(b, rows, c0);
                c0 += W;
            }
        }
        c0
    }

    /// One band of [`walk`]: the columns `NV` vectors wide from `c0`, rows in blocks of
    /// `RB`, then the rest one by one.
    ///
    /// # Safety
    /// As [`Blocks::block`], for every block of the band.
    #[inline(always)]
    unsafe fn band<B: Blocks, const RB: usize, const NV: usize>(b: &B, rows: usize, c0: usize) {
        let mut r0 = 0;
        // SAFETY: the caller's promise, block by block.
        unsafe {
            while r0 + RB <= rows {
                b.block::<RB, NV>(r0, c0);
                r0 += RB;
            }
            for r in r0..rows {
                b.block::<1, NV>(r, c0);
            }
        }
    }

    /// One kernel per vector width: `$rb` rows × `$nv` vectors of `$w` lanes of columns.
    macro_rules! kernels {
        ($name:ident, $feat:literal, $w:literal, $nvw:literal, $vt:ty, $load:ident, $store:ident, $set1:ident, $fma:ident, $max:ident, $zero:ident) => {
            /// See [`super::dense_strided`]; the caller checked the shapes and the CPU's features.
            #[target_feature(enable = $feat)]
            #[allow(clippy::too_many_arguments)]
            pub unsafe fn $name(y: &mut [f32], x: &[f32], w: &[f32], ldw: usize, b: &[f32], m: usize, k: usize, n: usize, relu: bool) {
                /// `RB` rows × `NV` vectors from row `r0`, column `c0`.
                #[inline(always)]
                #[allow(clippy::too_many_arguments)]
                unsafe fn block<const RB: usize, const NV: usize>(y: *mut f32, x: *const f32, w: *const f32, ldw: usize, b: *const f32, r0: usize, c0: usize, k: usize, n: usize, relu: bool) {
                    unsafe {
                        let mut acc = [[$zero(); NV]; RB];
                        for a in acc.iter_mut() {
                            for (v, av) in a.iter_mut().enumerate() {
                                *av = $load(b.add(c0 + v * $w));
                            }
                        }
                        for i in 0..k {
                            let mut wv = [$zero(); NV];
                            for (v, wvv) in wv.iter_mut().enumerate() {
                                *wvv = $load(w.add(i * ldw + c0 + v * $w));
                            }
                            for (r, a) in acc.iter_mut().enumerate() {
                                let xv = $set1(*x.add((r0 + r) * k + i));
                                for v in 0..NV {
                                    a[v] = $fma(xv, wv[v], a[v]);
                                }
                            }
                        }
                        for (r, a) in acc.iter().enumerate() {
                            for (v, av) in a.iter().enumerate() {
                                let o = if relu { $max(*av, $zero()) } else { *av };
                                $store(y.add((r0 + r) * n + c0 + v * $w), o);
                            }
                        }
                    }
                }
                /// The forward's blocks ([`block`] with the call's arguments).
                struct Fwd {
                    y: *mut f32,
                    x: *const f32,
                    w: *const f32,
                    ldw: usize,
                    b: *const f32,
                    k: usize,
                    n: usize,
                    relu: bool,
                }
                impl Blocks for Fwd {
                    #[inline(always)]
                    unsafe fn block<const RB: usize, const NV: usize>(&self, r0: usize, c0: usize) {
                        // SAFETY: as the trait's.
                        unsafe { block::<RB, NV>(self.y, self.x, self.w, self.ldw, self.b, r0, c0, self.k, self.n, self.relu) }
                    }
                }
                let fwd = Fwd { y: y.as_mut_ptr(), x: x.as_ptr(), w: w.as_ptr(), ldw, b: b.as_ptr(), k, n, relu };
                // `$nvw` vectors wide where the registers allow (AVX-512: 4 rows × 4 vectors,
                // 16 FMAs per 4 weight loads and 4 broadcasts, FMA-bound rather than
                // load-bound as 4 × 2 is).
                // SAFETY: the blocks cover rows < m and columns < n, within the checked lengths.
                let c0 = unsafe { walk::<Fwd, $w, $nvw>(&fwd, m, n) };
                // The last columns (fewer than a vector, e.g. the colour output's 3): each a
                // dot product of the row with the column (transposed once), `$w` lanes of
                // partial sums added pairwise, then to the bias, then the leftover inputs.
                if c0 < n {
                    let wt: Vec<f32> = (c0..n).flat_map(|c| (0..k).map(move |i| w[i * ldw + c])).collect();
                    for r in 0..m {
                        let xr = &x[r * k..(r + 1) * k];
                        for (ci, c) in (c0..n).enumerate() {
                            let wc = &wt[ci * k..(ci + 1) * k];
                            let mut i = 0;
                            let mut lanes = [0.0f32; $w];
                            // SAFETY: i + $w <= k, within both rows.
                            unsafe {
                                let mut acc = $zero();
                                while i + $w <= k {
                                    acc = $fma($load(xr.as_ptr().add(i)), $load(wc.as_ptr().add(i)), acc);
                                    i += $w;
                                }
                                $store(lanes.as_mut_ptr(), acc);
                            }
                            // The lanes summed pairwise: a fixed order per row, 4
                            // additions deep instead of 16.
                            let mut a = b[c] + super::pairwise_sum(&mut lanes);
                            for j in i..k {
                                a = xr[j].mul_add(wc[j], a);
                            }
                            y[r * n + c] = if relu { a.max(0.0) } else { a };
                        }
                    }
                }
            }
        };
    }

    kernels!(dense_avx512, "avx512f,fma", 16, 4, __m512, _mm512_loadu_ps, _mm512_storeu_ps, _mm512_set1_ps, _mm512_fmadd_ps, _mm512_max_ps, _mm512_setzero_ps);
    kernels!(dense_avx2, "avx2,fma", 8, 2, __m256, _mm256_loadu_ps, _mm256_storeu_ps, _mm256_set1_ps, _mm256_fmadd_ps, _mm256_max_ps, _mm256_setzero_ps);

    /// Samples per pass of the weight-gradient kernels: a pass's rows of `a` and `b` (at
    /// most 64 wide) stay in L1 while every block of `c` reads them.
    const TN_CHUNK: usize = 64;

    /// One weight-gradient kernel per vector width: `c[k][n] += a[m][k]ᵀ · b[m][n]` and the
    /// bias gradient `cb[n] += Σₛ b[s][n]`, blocks of `RB` rows × `NV` vectors of `c` held in
    /// registers over a pass of samples. Every element is `c + a[0][r]·b[0][j] +
    /// a[1][r]·b[1][j] + …`, fused-multiply-added in sample order (and `cb + b[0][j] +
    /// b[1][j] + …` added in sample order) whichever block, pass or kernel computes it, so
    /// both widths give the same bits.
    macro_rules! tn_kernels {
        ($name:ident, $feat:literal, $w:literal, $nvw:literal, $vt:ty, $load:ident, $store:ident, $set1:ident, $fma:ident, $add:ident, $zero:ident) => {
            /// See [`super::weight_grads_acc`]; the caller checked the shapes and the CPU's features.
            #[target_feature(enable = $feat)]
            #[allow(clippy::too_many_arguments)]
            pub unsafe fn $name(c: &mut [f32], cb: &mut [f32], a: &[f32], b: &[f32], m: usize, k: usize, n: usize) {
                /// Rows `r0..r0 + RB`, vectors of columns from `c0`, samples `s0..s1`; with
                /// `BIAS`, also the columns' sums of `b` into `cb` (from the loads of `b`
                /// the block makes anyway).
                #[inline(always)]
                #[allow(clippy::too_many_arguments)]
                unsafe fn block<const RB: usize, const NV: usize, const BIAS: bool>(c: *mut f32, cb: *mut f32, a: *const f32, b: *const f32, r0: usize, c0: usize, s0: usize, s1: usize, k: usize, n: usize) {
                    unsafe {
                        let mut acc = [[$zero(); NV]; RB];
                        for (r, row) in acc.iter_mut().enumerate() {
                            for (v, av) in row.iter_mut().enumerate() {
                                *av = $load(c.add((r0 + r) * n + c0 + v * $w));
                            }
                        }
                        let mut bacc = [$zero(); NV];
                        if BIAS {
                            for (v, av) in bacc.iter_mut().enumerate() {
                                *av = $load(cb.add(c0 + v * $w));
                            }
                        }
                        for s in s0..s1 {
                            let mut bv = [$zero(); NV];
                            for (v, bvv) in bv.iter_mut().enumerate() {
                                *bvv = $load(b.add(s * n + c0 + v * $w));
                            }
                            if BIAS {
                                for v in 0..NV {
                                    bacc[v] = $add(bacc[v], bv[v]);
                                }
                            }
                            for (r, row) in acc.iter_mut().enumerate() {
                                let av = $set1(*a.add(s * k + r0 + r));
                                for v in 0..NV {
                                    row[v] = $fma(av, bv[v], row[v]);
                                }
                            }
                        }
                        for (r, row) in acc.iter().enumerate() {
                            for (v, av) in row.iter().enumerate() {
                                $store(c.add((r0 + r) * n + c0 + v * $w), *av);
                            }
                        }
                        if BIAS {
                            for (v, av) in bacc.iter().enumerate() {
                                $store(cb.add(c0 + v * $w), *av);
                            }
                        }
                    }
                }
                /// [`block`], summing the bias for the first block of rows of a column block.
                #[inline(always)]
                #[allow(clippy::too_many_arguments)]
                unsafe fn blk<const RB: usize, const NV: usize>(c: *mut f32, cb: *mut f32, a: *const f32, b: *const f32, r0: usize, c0: usize, s0: usize, s1: usize, k: usize, n: usize) {
                    unsafe {
                        if r0 == 0 {
                            block::<RB, NV, true>(c, cb, a, b, r0, c0, s0, s1, k, n)
                        } else {
                            block::<RB, NV, false>(c, cb, a, b, r0, c0, s0, s1, k, n)
                        }
                    }
                }
                /// The blocks of one pass of samples `s0..s1` ([`blk`] with the call's arguments).
                struct Pass {
                    c: *mut f32,
                    cb: *mut f32,
                    a: *const f32,
                    b: *const f32,
                    s0: usize,
                    s1: usize,
                    k: usize,
                    n: usize,
                }
                impl Blocks for Pass {
                    #[inline(always)]
                    unsafe fn block<const RB: usize, const NV: usize>(&self, r0: usize, c0: usize) {
                        // SAFETY: as the trait's.
                        unsafe { blk::<RB, NV>(self.c, self.cb, self.a, self.b, r0, c0, self.s0, self.s1, self.k, self.n) }
                    }
                }
                let (cp, cbp, ap, bp) = (c.as_mut_ptr(), cb.as_mut_ptr(), a.as_ptr(), b.as_ptr());
                let mut s0 = 0;
                while s0 < m {
                    let s1 = (s0 + TN_CHUNK).min(m);
                    let pass = Pass { c: cp, cb: cbp, a: ap, b: bp, s0, s1, k, n };
                    // SAFETY (all blocks): rows < k, columns < n and samples < m, within the
                    // checked lengths.
                    unsafe {
                        let c0 = walk::<Pass, $w, $nvw>(&pass, k, n);
                        // The last columns (fewer than a vector, e.g. the colour output's 3):
                        // vectors over `$w` rows of `c` (a row of `a` is contiguous there),
                        // the remaining rows one by one; the same sums in the same order.
                        for j in c0..n {
                            for s in s0..s1 {
                                *cbp.add(j) += *bp.add(s * n + j);
                            }
                            let mut r0 = 0;
                            while r0 + $w <= k {
                                let mut lanes = [0.0f32; $w];
                                for (l, v) in lanes.iter_mut().enumerate() {
                                    *v = *cp.add((r0 + l) * n + j);
                                }
                                let mut acc = $load(lanes.as_ptr());
                                for s in s0..s1 {
                                    acc = $fma($load(ap.add(s * k + r0)), $set1(*bp.add(s * n + j)), acc);
                                }
                                $store(lanes.as_mut_ptr(), acc);
                                for (l, v) in lanes.iter().enumerate() {
                                    *cp.add((r0 + l) * n + j) = *v;
                                }
                                r0 += $w;
                            }
                            for r in r0..k {
                                let mut v = *cp.add(r * n + j);
                                for s in s0..s1 {
                                    v = (*ap.add(s * k + r)).mul_add(*bp.add(s * n + j), v);
                                }
                                *cp.add(r * n + j) = v;
                            }
                        }
                    }
                    s0 = s1;
                }
            }
        };
    }

    tn_kernels!(tn_acc_avx512, "avx512f,fma", 16, 4, __m512, _mm512_loadu_ps, _mm512_storeu_ps, _mm512_set1_ps, _mm512_fmadd_ps, _mm512_add_ps, _mm512_setzero_ps);
    tn_kernels!(tn_acc_avx2, "avx2,fma", 8, 2, __m256, _mm256_loadu_ps, _mm256_storeu_ps, _mm256_set1_ps, _mm256_fmadd_ps, _mm256_add_ps, _mm256_setzero_ps);
}

/// The sum of `lanes` (a power of two of them) pairwise: halves added, then quarters, …,
/// in place; a fixed order, `log₂` additions deep.
#[inline(always)]
pub(super) fn pairwise_sum(lanes: &mut [f32]) -> f32 {
    debug_assert!(lanes.len().is_power_of_two());
    let mut width = lanes.len();
    while width > 1 {
        width /= 2;
        for l in 0..width {
            lanes[l] += lanes[l + width];
        }
    }
    lanes[0]
}

/// `Σᵢ a[i]·b[i]` in 16 lanes (lane `l` sums the products `i ≡ l (mod 16)` in order, the
/// remainder into lane 0), then the lanes pairwise: a fixed order, vectorised (a plain
/// sequential sum is one 64-deep chain of dependent additions per row), the same bits on
/// every path (no fused multiply-add).
pub fn dot(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len(), "dot lengths");
    #[inline(always)]
    fn plain(a: &[f32], b: &[f32]) -> f32 {
        let mut lanes = [0.0f32; 16];
        let (ca, cb) = (a.chunks_exact(16), b.chunks_exact(16));
        let (ra, rb) = (ca.remainder(), cb.remainder());
        for (x, y) in ca.zip(cb) {
            for l in 0..16 {
                lanes[l] += x[l] * y[l];
            }
        }
        for (x, y) in ra.iter().zip(rb) {
            lanes[0] += x * y;
        }
        pairwise_sum(&mut lanes)
    }
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        /// `plain` compiled for AVX2: the same operations lane for lane.
        #[target_feature(enable = "avx2")]
        fn wide(a: &[f32], b: &[f32]) -> f32 {
            plain(a, b)
        }
        // SAFETY: the CPU has AVX2 (checked above).
        return unsafe { wide(a, b) };
    }
    plain(a, b)
}

/// `c[n] += Σₛ b[s][n]` (a bias gradient), each column summed in sample order (the
/// fallback's; the kernels sum it inside [`weight_grads_acc`]).
pub fn col_sums_acc(c: &mut [f32], b: &[f32]) {
    assert!(!c.is_empty() && b.len().is_multiple_of(c.len()), "col_sums_acc shapes");
    #[inline(always)]
    fn plain(c: &mut [f32], b: &[f32]) {
        for row in b.chunks_exact(c.len()) {
            c.iter_mut().zip(row).for_each(|(a, x)| *a += x);
        }
    }
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        /// `plain` compiled for AVX2: the same additions in the same order.
        #[target_feature(enable = "avx2")]
        fn wide(c: &mut [f32], b: &[f32]) {
            plain(c, b)
        }
        // SAFETY: the CPU has AVX2 (checked above).
        unsafe { wide(c, b) };
        return;
    }
    plain(c, b)
}

/// A gradient through a ReLU whose output was `y`: `d[i] = 0` where `y[i] ≤ 0` (the ReLU
/// passed exactly where its output is positive).
pub fn relu_mask(d: &mut [f32], y: &[f32]) {
    assert_eq!(d.len(), y.len(), "relu_mask shapes");
    // A select rather than a branch: the pattern is data-dependent.
    #[inline(always)]
    fn plain(d: &mut [f32], y: &[f32]) {
        d.iter_mut().zip(y).for_each(|(g, y)| *g = if *y > 0.0 { *g } else { 0.0 });
    }
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        /// 8 lanes at a time with explicit AND and full stores: from `plain`, LLVM makes
        /// masked stores of zeros (`vmaskmovps`), which AMD's cores run slowly (5 % of a
        /// training step's CPU time on a Zen 4). The AND keeps `g`'s bits or gives +0.0, as
        /// the select does.
        #[target_feature(enable = "avx2")]
        fn wide(d: &mut [f32], y: &[f32]) {
            use std::arch::x86_64::*;
            let (dc, yc) = (d.chunks_exact_mut(8), y.chunks_exact(8));
            let n8 = yc.len() * 8;
            for (g, y) in dc.zip(yc) {
                // SAFETY: each chunk holds 8 floats.
                unsafe {
                    let keep = _mm256_cmp_ps::<_CMP_GT_OQ>(_mm256_loadu_ps(y.as_ptr()), _mm256_setzero_ps());
                    _mm256_storeu_ps(g.as_mut_ptr(), _mm256_and_ps(_mm256_loadu_ps(g.as_ptr()), keep));
                }
            }
            plain(&mut d[n8..], &y[n8..]);
        }
        // SAFETY: the CPU has AVX2 (checked above).
        unsafe { wide(d, y) };
        return;
    }
    plain(d, y)
}

/// `c[k][n] += a[m][k]ᵀ · b[m][n]` (a weight gradient: inputs transposed times output
/// gradients) and `cb[n] += Σₛ b[s][n]` (the bias gradient). Where the CPU has FMA,
/// register-blocked kernels for AVX-512 or AVX2 (chosen at run time, the same bits from
/// either) that need no packing, which at the networks' sizes (`m` = 512 samples, 16 to 64
/// wide) costs `gemm` about as much as the products, and that sum the bias from the same
/// loads; elsewhere `gemm` and [`col_sums_acc`].
pub fn weight_grads_acc(c: &mut [f32], cb: &mut [f32], a: &[f32], b: &[f32], m: usize, k: usize, n: usize) {
    assert!(c.len() == k * n && cb.len() == n && a.len() == m * k && b.len() == m * n, "weight_grads_acc shapes");
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        col_sums_acc(cb, b);
        return;
    }
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has the features the function is compiled for (checked above).
            unsafe { blocked::tn_acc_avx512(c, cb, a, b, m, k, n) };
            return;
        }
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
            // SAFETY: as above.
            unsafe { blocked::tn_acc_avx2(c, cb, a, b, m, k, n) };
            return;
        }
    }
    col_sums_acc(cb, b);
    // SAFETY: as above; aᵀ is `a` read with row stride 1 and column stride k.
    unsafe {
        gemm(
            k, n, m, c.as_mut_ptr(), 1, n as isize, true, a.as_ptr(), k as isize, 1, b.as_ptr(), 1, n as isize, 1.0, 1.0,
            false, false, false, Parallelism::None,
        )
    }
}
