//! Counter-based sample generation and the warps that turn uniform numbers into directions
//! and points.
//!
//! Every number is a pure function of `(seed, view, pixel, sample, dimension)`, so images are
//! bit-identical whatever the thread count or the order in which pixels are rendered.
//!
//! The numbers are a padded, Owen-scrambled Sobol' sequence (Burley 2020, "Practical
//! Hash-based Owen Scrambling"; pbrt-v4's `PaddedSobolSampler`): the samples of one pixel are
//! the points of a 2-D Sobol' (0,2)-sequence, independently for each dimension or pair of
//! dimensions drawn ([`Sampler::next_1d`], [`Sampler::next_2d`]) with
//! - the sample index shuffled by a nested uniform (Owen) scramble keyed by `(pixel key,
//!   dimension)`: for `2^m` samples the pixel gets an aligned block of `2^m` sequence points,
//!   so each 2-D pair is a (0,m,2)-net (stratified in every elementary interval), and
//!   different dimensions are decorrelated;
//! - each coordinate Owen-scrambled with its own key: every single number is exactly uniform
//!   and different pixels are independent.
//!
//! Estimates stay unbiased; over a pixel's samples the error falls faster than with independent
//! numbers wherever the integrand is smooth in the early dimensions (pixel area, first light
//! sample, first bounce). Values are `f32` on the exact grid `m / 2²⁴`.

use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// The SplitMix64 output function applied to `z + φ₆₄` (a bijective 64-bit mixer).
#[inline]
pub fn splitmix64(z: u64) -> u64 {
    let mut z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Laine–Karras-style permutation with Burley's constants: bit `k` of the output depends only
/// on bits `≤ k` of the input and on `seed` (applied to bit-reversed values it is an Owen
/// scramble).
#[inline]
fn laine_karras(mut x: u32, seed: u32) -> u32 {
    x = x.wrapping_add(seed);
    x ^= x.wrapping_mul(0x6c50_b47c);
    x ^= x.wrapping_mul(0xb82f_1e52);
    x ^= x.wrapping_mul(0xc7af_e638);
    x ^= x.wrapping_mul(0x8d22_f6e6);
    x
}

/// Nested uniform (Owen) scramble of a 32-bit fixed-point number `x / 2³²`: a random
/// permutation of each dyadic interval's two halves, chosen by `seed` and the higher bits.
#[inline]
pub fn owen_scramble(x: u32, seed: u32) -> u32 {
    laine_karras(x.reverse_bits(), seed).reverse_bits()
}

/// Generator matrix columns of the second Sobol' dimension (the first is the bit-reversed
/// index, van der Corput): `v₀ = 2³¹`, `vₖ = vₖ₋₁ ⊕ (vₖ₋₁ ≫ 1)` (Pascal's triangle mod 2).
const fn sobol_dim1_columns() -> [u32; 32] {
    let mut v = [0u32; 32];
    v[0] = 1 << 31;
    let mut k = 1;
    while k < 32 {
        v[k] = v[k - 1] ^ (v[k - 1] >> 1);
        k += 1;
    }
    v
}

/// The second Sobol' dimension, bit-reversed, by bytes of the index: entry `[b][x]` is the
/// XOR of the reversed columns `8b + i` for the set bits `i` of `x` (the matrix is linear over
/// GF(2), so four lookups give any index).
static SOBOL_DIM1_REVERSED: [[u32; 256]; 4] = {
    let v = sobol_dim1_columns();
    let mut t = [[0u32; 256]; 4];
    let mut b = 0;
    while b < 4 {
        let mut x = 0;
        while x < 256 {
            let mut acc = 0u32;
            let mut i = 0;
            while i < 8 {
                if (x >> i) & 1 != 0 {
                    acc ^= v[8 * b + i].reverse_bits();
                }
                i += 1;
            }
            t[b][x] = acc;
            x += 1;
        }
        b += 1;
    }
    t
};

/// The second Sobol' dimension of point `index`, bit-reversed (32-bit fixed point after
/// reversal).
#[inline]
fn sobol_dim1_reversed(index: u32) -> u32 {
    let t = &SOBOL_DIM1_REVERSED;
    t[0][(index & 0xff) as usize] ^ t[1][((index >> 8) & 0xff) as usize] ^ t[2][((index >> 16) & 0xff) as usize] ^ t[3][(index >> 24) as usize]
}

/// 32-bit fixed point `x / 2³²` to an `f32` in `[0, 1)` on the grid `m / 2²⁴`.
#[inline]
fn to_unit(x: u32) -> f32 {
    (x >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// Dimension `dim`'s scramble keys (index shuffle, x, y) and its shuffled Sobol' index
/// `owen_scramble(sample, key)`, for the sampler of key `key` and bit-reversed sample index
/// `sample_reversed`.
#[inline(always)]
fn keys(key: u64, sample_reversed: u32, dim: u32) -> (u32, u32, u32) {
    let h = splitmix64(key ^ (dim as u64).wrapping_mul(0xD1B5_4A32_D192_ED03));
    let ky = ((h ^ (h >> 31)).wrapping_mul(0xD6E8_FEB8_6659_FD93) >> 32) as u32;
    let index = laine_karras(sample_reversed, h as u32).reverse_bits();
    (index, (h >> 32) as u32, ky)
}

/// [`Sampler::u32_at`] of the sampler `(key, sample_reversed)`.
#[inline(always)]
fn u32_at(key: u64, sample_reversed: u32, dim: u32) -> u32 {
    let (index, kx, _) = keys(key, sample_reversed, dim);
    // owen_scramble(index.reverse_bits(), kx), without the double reversal.
    laine_karras(index, kx).reverse_bits()
}

/// [`Sampler::get_2d`] of the sampler `(key, sample_reversed)`.
#[inline(always)]
fn get_2d(key: u64, sample_reversed: u32, dim: u32) -> (f32, f32) {
    let (index, kx, ky) = keys(key, sample_reversed, dim);
    let x = laine_karras(index, kx).reverse_bits();
    let y = laine_karras(sobol_dim1_reversed(index), ky).reverse_bits();
    (to_unit(x), to_unit(y))
}

/// Eight samplers' numbers at once, each lane exactly what its [`Sampler`] returns: the
/// lanes' keys and sample indices in arrays, so that the hashing of a dimension is one loop
/// over the lanes that the compiler vectorises.
#[derive(Clone, Copy, Debug, Default)]
pub struct SamplerLanes {
    key: [u64; 8],
    sample_reversed: [u32; 8],
}

impl SamplerLanes {
    /// Lane `k` := `sampler`.
    #[inline(always)]
    pub fn set(&mut self, k: usize, sampler: &Sampler) {
        self.key[k] = sampler.key;
        self.sample_reversed[k] = sampler.sample_reversed;
    }

    /// `Sampler::get_1d(dim[k])` of every lane.
    #[allow(clippy::needless_range_loop)]
    #[inline(always)]
    pub fn get_1d(&self, dim: &[u32; 8]) -> [f32; 8] {
        let mut out = [0.0; 8];
        for k in 0..8 {
            out[k] = to_unit(u32_at(self.key[k], self.sample_reversed[k], dim[k]));
        }
        out
    }

    /// `Sampler::get_2d(dim[k])` of every lane, as the arrays of x and y.
    #[allow(clippy::needless_range_loop)]
    #[inline(always)]
    pub fn get_2d(&self, dim: &[u32; 8]) -> [[f32; 8]; 2] {
        let mut out = [[0.0; 8]; 2];
        for k in 0..8 {
            (out[0][k], out[1][k]) = get_2d(self.key[k], self.sample_reversed[k], dim[k]);
        }
        out
    }
}

/// The numbers of one sample of one pixel of one view: dimension `k` is a pure function of
/// `(seed, view, pixel, sample, k)` (see the module docs). Consumers draw dimensions in a
/// fixed order ([`Sampler::next_1d`], [`Sampler::next_2d`]).
#[derive(Clone, Debug)]
pub struct Sampler {
    /// Key of `(seed, view, pixel)`.
    key: u64,
    /// Sample index within the pixel, bit-reversed.
    sample_reversed: u32,
    dimension: u32,
}

impl Sampler {
    /// The numbers of sample `sample` of `(seed, view, pixel)`, starting at dimension 0.
    /// Samples of one pixel are stratified against each other; different keys are
    /// independent.
    pub fn new(seed: u64, view: u32, pixel: u64, sample: u32) -> Self {
        let mut h = splitmix64(seed);
        h = splitmix64(h ^ (view as u64).wrapping_mul(0xA24B_AED4_963E_E407));
        h = splitmix64(h ^ pixel.wrapping_mul(0x9FB2_1C65_1E98_DF25));
        Self { key: h, sample_reversed: sample.reverse_bits(), dimension: 0 }
    }

    /// The same pixel's sample `sample`, from dimension 0: equal to `Sampler::new(seed, view,
    /// pixel, sample)` for the `(seed, view, pixel)` of `self`, without hashing them again
    /// (a pixel's samples share the key).
    #[inline]
    pub fn with_sample(&self, sample: u32) -> Self {
        Self { key: self.key, sample_reversed: sample.reverse_bits(), dimension: 0 }
    }

    /// Dimension `dim` as 32-bit fixed point (one coordinate of its own shuffled, scrambled
    /// sequence: the van der Corput point of the shuffled index, Owen-scrambled), whatever
    /// has been drawn.
    #[inline]
    fn u32_at(&self, dim: u32) -> u32 {
        u32_at(self.key, self.sample_reversed, dim)
    }

    /// Dimension `dim` as an `f32` in `[0, 1)`: what [`Sampler::next_1d`] returns when it is
    /// the next dimension.
    #[inline]
    pub fn get_1d(&self, dim: u32) -> f32 {
        to_unit(self.u32_at(dim))
    }

    /// Dimensions `dim` and `dim + 1` as one 2-D point: what [`Sampler::next_2d`] returns
    /// when `dim` is the next dimension.
    #[inline]
    pub fn get_2d(&self, dim: u32) -> Vec2 {
        let (x, y) = get_2d(self.key, self.sample_reversed, dim);
        Vec2::new(x, y)
    }

    /// Reserves the next `n` dimensions without computing them and returns the first: a
    /// consumer with a fixed dimension budget computes only those it uses
    /// ([`Sampler::get_1d`], [`Sampler::get_2d`]), and every later draw is unchanged.
    #[inline]
    pub fn skip(&mut self, n: u32) -> u32 {
        let d = self.dimension;
        self.dimension = self.dimension.wrapping_add(n);
        d
    }

    /// The next dimension as 32-bit fixed point (`Sampler::u32_at` of the next dimension).
    #[inline]
    pub fn next_u32(&mut self) -> u32 {
        let d = self.skip(1);
        self.u32_at(d)
    }

    /// The next dimension as an `f32` in `[0, 1)` (multiples of 2⁻²⁴).
    #[inline]
    pub fn next_1d(&mut self) -> f32 {
        to_unit(self.next_u32())
    }

    /// The next two dimensions, one 2-D point of the pixel's shuffled, scrambled Sobol'
    /// (0,2)-sequence.
    #[inline]
    pub fn next_2d(&mut self) -> Vec2 {
        let d = self.skip(2);
        self.get_2d(d)
    }

    /// How many dimensions have been drawn.
    pub fn dimension(&self) -> u32 {
        self.dimension
    }
}

/// Cosine-weighted direction on the +z hemisphere (Malley's method, concentric disk):
/// pdf `cos θ / π` per steradian.
#[inline(always)]
pub fn sample_cosine_hemisphere(u: Vec2) -> Vec3 {
    let d = sample_concentric_disk(u);
    let z = (1.0 - d.length_squared()).max(0.0).sqrt();
    Vec3::new(d.x, d.y, z)
}

/// Uniform point on the unit disk (Shirley–Chiu concentric map).
#[inline(always)]
pub fn sample_concentric_disk(u: Vec2) -> Vec2 {
    let o = 2.0 * u - Vec2::ONE;
    if o.x == 0.0 && o.y == 0.0 {
        return Vec2::ZERO;
    }
    let (r, theta) = if o.x.abs() > o.y.abs() {
        (o.x, PI / 4.0 * (o.y / o.x))
    } else {
        (o.y, PI / 2.0 - PI / 4.0 * (o.x / o.y))
    };
    let (sin, cos) = sin_cos(theta);
    r * Vec2::new(cos, sin)
}

/// `(sin x, cos x)` for `|x| ≤ 64` (the warps' angles lie in `[−π, 2π]`), within 2 ulps of
/// the exact values (test `sin_cos_is_within_two_ulps`), with only `+ − ×`, a conversion to
/// an integer and selects: unlike `f32::sin_cos` (a libm call) it vectorises when called in
/// a loop over lanes ([`crate::material::sample_many`]), with the same bits per lane as a
/// call on one value. The quadrant `q = round(2x/π)` is removed in three parts of `π/2`
/// (Cody–Waite), then Cephes' `sinf` / `cosf` polynomials on `[−π/4, π/4]`.
#[inline(always)]
pub fn sin_cos(x: f32) -> (f32, f32) {
    // `+ 64.5` keeps the operand of the truncation positive for |x| ≤ 64, so it rounds
    // `2x/π` to the nearest integer.
    let q = (x * std::f32::consts::FRAC_2_PI + 64.5) as i32 - 64;
    let qf = q as f32;
    let r = ((x - qf * 1.570_312_5) - qf * 4.837_513e-4) - qf * 7.549_79e-8;
    let z = r * r;
    let s = r + r * z * (-1.666_665_5e-1 + z * (8.332_161e-3 + z * -1.951_529_6e-4));
    let c = 1.0 - 0.5 * z + z * z * (4.166_664_6e-2 + z * (-1.388_731_6e-3 + z * 2.443_315_7e-5));
    let (sin, cos) = if q & 1 == 0 { (s, c) } else { (c, -s) };
    let sin = if q & 2 == 0 { sin } else { -sin };
    let cos = if q & 2 == 0 { cos } else { -cos };
    (sin, cos)
}

/// Uniform direction on the unit sphere: pdf `1 / 4π`.
pub fn sample_uniform_sphere(u: Vec2) -> Vec3 {
    let z = 1.0 - 2.0 * u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Uniformly distributed barycentrics on a triangle (`b₀ = 1 − √u₀`, `b₁ = √u₀ (1 − u₁)`,
/// `b₂ = √u₀ u₁`); area pdf `1 / area`.
pub fn sample_uniform_triangle(u: Vec2) -> [f32; 3] {
    let su = u.x.sqrt();
    let b1 = su * (1.0 - u.y);
    let b2 = su * u.y;
    [1.0 - b1 - b2, b1, b2]
}

/// Veach's power heuristic with β = 2: `f² / (f² + g²)` (0 when both are 0).
#[inline]
pub fn power_heuristic(f: f32, g: f32) -> f32 {
    let (f2, g2) = (f * f, g * g);
    if f2 + g2 == 0.0 || !(f2 + g2).is_finite() {
        if f.is_infinite() { 1.0 } else { 0.0 }
    } else {
        f2 / (f2 + g2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sin_cos_is_within_two_ulps() {
        // Every angle the warps use ([−π, 2π]) and beyond, on a fine grid and at the quadrant
        // boundaries, against f64.
        let mut worst = 0.0f64;
        let n = 2_000_000;
        for k in 0..=n {
            let x = -7.0f32 + 14.0 * k as f32 / n as f32;
            let (s, c) = sin_cos(x);
            let (es, ec) = (x as f64).sin_cos();
            // Error in ulps of the larger of the value and 2⁻²⁴ (absolute near zeros).
            let ulps = |got: f32, want: f64| (got as f64 - want).abs() / (want.abs().max(1.0 / 16_777_216.0) * f32::EPSILON as f64);
            worst = worst.max(ulps(s, es)).max(ulps(c, ec));
        }
        assert!(worst <= 2.0, "worst error {worst} ulps");
        for x in [0.0f32, -0.0, std::f32::consts::FRAC_PI_4, std::f32::consts::FRAC_PI_2, std::f32::consts::PI, 2.0 * std::f32::consts::PI, -std::f32::consts::PI] {
            let (s, c) = sin_cos(x);
            assert!((s as f64 - (x as f64).sin()).abs() < 2e-7 && (c as f64 - (x as f64).cos()).abs() < 2e-7, "{x}: {s} {c}");
        }
    }

    #[test]
    fn sampler_lanes_draw_each_lanes_numbers() {
        // Eight different pixels, samples and dimensions per call: every lane is exactly its
        // own sampler's number.
        for round in 0..200u32 {
            let samplers: Vec<Sampler> = (0..8u32).map(|k| Sampler::new(round as u64 * 31 + 5, k, (round * 977 + k * 13) as u64, round * 7 + k * 3)).collect();
            let mut lanes = SamplerLanes::default();
            for (k, s) in samplers.iter().enumerate() {
                lanes.set(k, s);
            }
            let dims: [u32; 8] = std::array::from_fn(|k| (round + 11 * k as u32) % 97);
            let (one, two) = (lanes.get_1d(&dims), lanes.get_2d(&dims));
            for (k, s) in samplers.iter().enumerate() {
                assert_eq!(one[k].to_bits(), s.get_1d(dims[k]).to_bits());
                let p = s.get_2d(dims[k]);
                assert_eq!((two[0][k].to_bits(), two[1][k].to_bits()), (p.x.to_bits(), p.y.to_bits()));
            }
        }
    }

    #[test]
    fn with_sample_is_new_with_that_sample() {
        for (seed, view, pixel) in [(0u64, 0u32, 0u64), (7, 3, 12345), (u64::MAX, u32::MAX, u64::MAX)] {
            let base = Sampler::new(seed, view, pixel, 99);
            for s in [0u32, 1, 5, 1 << 20, u32::MAX] {
                let (mut a, mut b) = (base.with_sample(s), Sampler::new(seed, view, pixel, s));
                for _ in 0..4 {
                    assert_eq!(a.next_2d().to_array().map(f32::to_bits), b.next_2d().to_array().map(f32::to_bits));
                    assert_eq!(a.next_u32(), b.next_u32());
                }
            }
        }
    }

    #[test]
    fn reserved_dimensions_are_the_numbers_drawn_in_order() {
        // A vertex's budget (1, 2, 2, 2, 1 dimensions) drawn in order, then reserved with
        // `skip` and read back out of order or not at all: the same numbers, and the draw
        // after the budget is the same too.
        for (seed, pixel, sample) in [(0u64, 0u64, 0u32), (7, 12345, 9), (u64::MAX, u64::MAX, u32::MAX)] {
            let mut a = Sampler::new(seed, 2, pixel, sample);
            let mut b = a.clone();
            for _ in 0..3 {
                let drawn = (a.next_1d(), a.next_2d(), a.next_2d(), a.next_2d(), a.next_1d());
                let d = b.skip(8);
                assert_eq!(b.get_2d(d + 5).to_array().map(f32::to_bits), drawn.3.to_array().map(f32::to_bits));
                assert_eq!(b.get_1d(d + 7).to_bits(), drawn.4.to_bits());
                assert_eq!(b.get_1d(d).to_bits(), drawn.0.to_bits());
                assert_eq!(b.get_2d(d + 1).to_array().map(f32::to_bits), drawn.1.to_array().map(f32::to_bits));
                assert_eq!(b.get_2d(d + 3).to_array().map(f32::to_bits), drawn.2.to_array().map(f32::to_bits));
                assert_eq!(a.dimension(), b.dimension());
            }
            assert_eq!(a.next_u32(), b.next_u32());
        }
    }

    #[test]
    fn streams_are_pure_functions_of_the_key() {
        let mut a = Sampler::new(7, 3, 12345, 9);
        let mut b = Sampler::new(7, 3, 12345, 9);
        let xa: Vec<u32> = (0..16).map(|_| a.next_u32()).collect();
        let xb: Vec<u32> = (0..16).map(|_| b.next_u32()).collect();
        assert_eq!(xa, xb);
        // Changing any key component changes the stream.
        for mut s in [Sampler::new(8, 3, 12345, 9), Sampler::new(7, 4, 12345, 9), Sampler::new(7, 3, 12346, 9), Sampler::new(7, 3, 12345, 10)] {
            assert_ne!(s.next_u32(), xa[0]);
        }
    }

    #[test]
    fn uniform_moments_match_closed_form() {
        // Mean 1/2 and variance 1/12 within 5σ of their estimators over 200k draws.
        let n = 200_000;
        let mut sum = 0.0f64;
        let mut sum2 = 0.0f64;
        let mut corr = 0.0f64;
        for p in 0..n {
            let mut s = Sampler::new(1, 0, p as u64, 0);
            let x = s.next_1d() as f64;
            let y = s.next_1d() as f64;
            assert!((0.0..1.0).contains(&x));
            sum += x;
            sum2 += x * x;
            corr += (x - 0.5) * (y - 0.5);
        }
        let nf = n as f64;
        let mean = sum / nf;
        let var = sum2 / nf - mean * mean;
        assert!((mean - 0.5).abs() < 5.0 * (1.0f64 / 12.0 / nf).sqrt());
        assert!((var - 1.0 / 12.0).abs() < 5.0 * (1.0f64 / 180.0 / nf).sqrt());
        // Consecutive dimensions uncorrelated: E[(x-½)(y-½)] = 0, σ = 1/12/√n.
        assert!((corr / nf).abs() < 5.0 / 12.0 / nf.sqrt());
    }

    /// Every elementary interval of volume 2⁻ᵐ of the unit square holds exactly one of the
    /// points: the (0,m,2)-net property.
    fn is_net(points: &[Vec2], m: u32) -> bool {
        (0..=m).all(|a| {
            let (nx, ny) = (1usize << a, 1usize << (m - a));
            let mut count = vec![0u32; nx * ny];
            for p in points {
                let (i, j) = ((p.x * nx as f32) as usize, (p.y * ny as f32) as usize);
                count[j * nx + i] += 1;
            }
            count.iter().all(|&c| c == 1)
        })
    }

    #[test]
    fn sobol_table_matches_the_generator_matrix() {
        let v = sobol_dim1_columns();
        for index in [0u32, 1, 2, 3, 255, 256, 0x1234_5678, u32::MAX, 0x8000_0001] {
            let direct = (0..32).filter(|k| (index >> k) & 1 != 0).fold(0u32, |acc, k| acc ^ v[k]);
            assert_eq!(sobol_dim1_reversed(index), direct.reverse_bits(), "{index:#x}");
        }
        // The first points of the second dimension in natural (not Gray-code) index order.
        let firsts: Vec<f64> = (0..8).map(|i| sobol_dim1_reversed(i).reverse_bits() as f64 / 2f64.powi(32)).collect();
        assert_eq!(firsts, [0.0, 0.5, 0.75, 0.25, 0.625, 0.125, 0.375, 0.875]);
    }

    #[test]
    fn a_pixels_samples_are_stratified_in_every_dimension() {
        for (pixel, m) in [(0u64, 6u32), (12345, 8), (99, 4)] {
            let n = 1u32 << m;
            let mut samplers: Vec<Sampler> = (0..n).map(|s| Sampler::new(3, 1, pixel, s)).collect();
            for draw in 0..6 {
                if draw % 3 == 2 {
                    let xs: Vec<f32> = samplers.iter_mut().map(|s| s.next_1d()).collect();
                    let mut cells = vec![0u32; n as usize];
                    xs.iter().for_each(|x| cells[(x * n as f32) as usize] += 1);
                    assert!(cells.iter().all(|&c| c == 1), "1-D draw {draw}, pixel {pixel}: not one point per 1/{n}");
                } else {
                    let ps: Vec<Vec2> = samplers.iter_mut().map(|s| s.next_2d()).collect();
                    assert!(is_net(&ps, m), "2-D draw {draw}, pixel {pixel}: not a (0,{m},2)-net");
                }
            }
        }
    }

    #[test]
    fn stratified_estimates_beat_independent_ones_without_bias() {
        // ∫∫ exp(x + y) = (e − 1)², from 64 samples per pixel over 2000 pixels: the mean over
        // pixels is unbiased (within 5 of its standard errors) and the per-pixel error is far
        // below the independent-sampling error σ/√64.
        let exact = (std::f64::consts::E - 1.0).powi(2);
        let f = |p: Vec2| ((p.x + p.y) as f64).exp();
        let (pixels, spp) = (2000u64, 64u32);
        let mut errs = Vec::new();
        for pixel in 0..pixels {
            let mut sum = 0.0;
            for s in 0..spp {
                let mut sm = Sampler::new(5, 0, pixel, s);
                sm.next_1d();
                sum += f(sm.next_2d());
            }
            errs.push(sum / spp as f64 - exact);
        }
        let n = errs.len() as f64;
        let mean = errs.iter().sum::<f64>() / n;
        let rmse = (errs.iter().map(|e| e * e).sum::<f64>() / n).sqrt();
        // Variance of exp(x + y) under independent uniform sampling: ((e²−1)/2)² − (e−1)⁴.
        let sigma_mc = ((((std::f64::consts::E.powi(2) - 1.0) / 2.0).powi(2) - exact * exact) / spp as f64).sqrt();
        assert!(mean.abs() < 5.0 * rmse / n.sqrt(), "bias {mean} (rmse {rmse})");
        assert!(rmse < 0.2 * sigma_mc, "rmse {rmse} vs independent {sigma_mc}");
    }

    #[test]
    fn cosine_hemisphere_has_expected_mean_cosine() {
        // E[cos θ] under pdf cos θ/π is 2/3.
        let n = 100_000;
        let mut sum = 0.0f64;
        for p in 0..n {
            let mut s = Sampler::new(2, 0, p, 0);
            let w = sample_cosine_hemisphere(s.next_2d());
            assert!((w.length() - 1.0).abs() < 1e-5 && w.z >= 0.0);
            sum += w.z as f64;
        }
        let mean = sum / n as f64;
        let sigma = ((0.5 - 4.0 / 9.0) / n as f64).sqrt();
        assert!((mean - 2.0 / 3.0).abs() < 5.0 * sigma, "{mean}");
    }

    #[test]
    fn triangle_and_sphere_samples_are_valid() {
        for p in 0..1000 {
            let mut s = Sampler::new(3, 0, p, 0);
            let b = sample_uniform_triangle(s.next_2d());
            assert!(b.iter().all(|&x| x >= 0.0) && (b.iter().sum::<f32>() - 1.0).abs() < 1e-6);
            let w = sample_uniform_sphere(s.next_2d());
            assert!((w.length() - 1.0).abs() < 1e-5);
        }
        assert!((power_heuristic(1.0, 1.0) - 0.5).abs() < 1e-7);
        assert_eq!(power_heuristic(0.0, 0.0), 0.0);
    }
}
