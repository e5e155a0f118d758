//! The forward of two-feature levels eight points at a time with AVX2 (gathers for the
//! table reads). Every lane does exactly the scalar [`super::corners`] / [`super::encode_level_scalar`]
//! arithmetic in the same order (f64 cell coordinates, no fused multiply-add), so the output is
//! bit-identical to the scalar path on any machine.

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
