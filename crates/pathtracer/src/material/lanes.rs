//! The BSDFs in lanes: [`SampleLane`], one BSDF as plain numbers (the union of the models'
//! parameters), and [`BsdfLanes`], eight of them as one array per number. Each model's lane
//! functions (in its file) are selected per lane with no branch on the data, so that the loops
//! over the eight lanes vectorise; a lane's result is its model's scalar verbs' bits. Eight
//! lanes that are all Lambertian compute that model alone.

// Negated comparisons (`!(x > 0.0)`) are deliberate: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::{BsdfAt, BsdfSample, SampleLane, lambert, metallic_roughness};
use crate::sampler::sample_cosine_hemisphere;
use glam::{Vec2, Vec3};

/// `(ps, sd_wo)` of the lane `x` seen from `x.wo`: what [`super::Bsdf::at`] computes and
/// [`super::BsdfAt::lane`] passes on, each model's ([`lambert::WO_TERMS`],
/// [`metallic_roughness::wo_terms_lane`]) selected with no branch on the data, so that a loop
/// over lanes vectorises.
#[inline(always)]
fn wo_terms(x: &SampleLane) -> (f32, f32) {
    let mr = metallic_roughness::wo_terms_lane(x);
    if x.diffuse { lambert::WO_TERMS } else { mr }
}

/// [`BsdfAt::evaluate_pdf`] of one lane: `(f · cos θᵢ, pdf)`. Both models are computed and
/// the lane's own selected, with no branch on the data, so that a loop over lanes vectorises
/// ([`evaluate_many`]).
#[inline(always)]
pub(super) fn evaluate_pdf_lane<const ALL_DIFFUSE: bool>(x: &SampleLane, wi: Vec3) -> (Vec3, f32) {
    let wo = x.wo;
    let below = (wo.z <= 0.0) | (wi.z <= 0.0);
    let lambert = lambert::evaluate_pdf_lane(x.rho, wi);
    // Lanes that are all Lambertian compute that model alone.
    let value = if ALL_DIFFUSE || x.diffuse { lambert } else { metallic_roughness::evaluate_pdf_lane(x, wi) };
    if below { (Vec3::ZERO, 0.0) } else { value }
}

/// [`SAMPLE_LANES`] BSDFs as one array per number ([`SampleLane`] without its `u`): what
/// [`sample_many`] and [`evaluate_many`] move their BSDFs into before the loop over the lanes
/// (and what the path loop in lanes keeps its vertices' BSDFs in).
#[derive(Default)]
pub(crate) struct BsdfLanes {
    diffuse: [bool; SAMPLE_LANES],
    rho: [[f32; SAMPLE_LANES]; 3],
    metallic: [f32; SAMPLE_LANES],
    alpha: [f32; SAMPLE_LANES],
    f0: [[f32; SAMPLE_LANES]; 3],
    f90: [f32; SAMPLE_LANES],
    wo: [[f32; SAMPLE_LANES]; 3],
    ps: [f32; SAMPLE_LANES],
    sd_wo: [f32; SAMPLE_LANES],
}

impl BsdfLanes {
    /// Lane `k` := `l`.
    #[inline(always)]
    pub(crate) fn set(&mut self, k: usize, l: &SampleLane) {
        self.diffuse[k] = l.diffuse;
        for c in 0..3 {
            self.rho[c][k] = l.rho[c];
            self.f0[c][k] = l.f0[c];
            self.wo[c][k] = l.wo[c];
        }
        (self.metallic[k], self.alpha[k], self.f90[k], self.ps[k], self.sd_wo[k]) = (l.metallic, l.alpha, l.f90, l.ps, l.sd_wo);
    }

    /// Computes lane `k`'s terms that depend on its `wo` ([`super::Bsdf::at`]'s).
    #[inline(always)]
    pub(crate) fn set_wo_terms(&mut self, k: usize) {
        (self.ps[k], self.sd_wo[k]) = wo_terms(&self.get(k, Vec2::ZERO));
    }

    /// Whether lane `k` is the Lambertian model.
    #[inline(always)]
    pub(crate) fn is_lambertian(&self, k: usize) -> bool {
        self.diffuse[k]
    }

    /// Lane `k`, with the numbers `u`.
    #[inline(always)]
    pub(crate) fn get(&self, k: usize, u: Vec2) -> SampleLane {
        let v3 = |a: &[[f32; SAMPLE_LANES]; 3]| Vec3::new(a[0][k], a[1][k], a[2][k]);
        SampleLane {
            diffuse: self.diffuse[k],
            rho: v3(&self.rho),
            metallic: self.metallic[k],
            alpha: self.alpha[k],
            f0: v3(&self.f0),
            f90: self.f90[k],
            wo: v3(&self.wo),
            ps: self.ps[k],
            sd_wo: self.sd_wo[k],
            u,
        }
    }
}

/// `values[k] = bsdfs(k).evaluate_pdf(wi[k])` for every `k` (the same bits), eight
/// (`SAMPLE_LANES`) at a time: the inputs transposed into one array per number, one vectorised
/// loop over the lanes (`evaluate_pdf_lane`), the results transposed back.
///
/// # Panics
/// If `values` and `wi` differ in length.
#[inline(always)]
pub fn evaluate_many<'a>(bsdfs: impl Fn(usize) -> &'a BsdfAt, wi: &[Vec3], values: &mut [(Vec3, f32)]) {
    const L: usize = SAMPLE_LANES;
    let n = wi.len();
    assert!(values.len() == n, "evaluate_many: slices of different lengths");
    for start in (0..n).step_by(L) {
        let m = (n - start).min(L);
        // Unused lanes hold zeros; their results are dropped.
        let mut x = BsdfLanes::default();
        let mut x_wi = [[0.0f32; L]; 3];
        for (k, w) in wi[start..start + m].iter().enumerate() {
            x.set(k, &bsdfs(start + k).lane(Vec2::ZERO));
            (x_wi[0][k], x_wi[1][k], x_wi[2][k]) = (w.x, w.y, w.z);
        }
        let (mut f, mut pdf) = ([[0.0f32; L]; 3], [0.0f32; L]);
        evaluate_lanes(&x, x.diffuse[..m].iter().all(|&d| d), &x_wi, &mut f, &mut pdf);
        for k in 0..m {
            let b = bsdfs(start + k);
            values[start + k] = if b.is_scalar_only() { b.evaluate_pdf(wi[start + k]) } else { (Vec3::new(f[0][k], f[1][k], f[2][k]), pdf[k]) };
        }
    }
}

/// `(f[k], pdf[k]) = x.get(k).evaluate_pdf(wi[k])` for the eight lanes ([`evaluate_pdf_lane`]):
/// one loop over the lanes, computing only the Lambertian model where `all_diffuse` (every lane
/// that matters is Lambertian).
#[inline(always)]
pub(crate) fn evaluate_lanes(x: &BsdfLanes, all_diffuse: bool, wi: &[[f32; SAMPLE_LANES]; 3], f: &mut [[f32; SAMPLE_LANES]; 3], pdf: &mut [f32; SAMPLE_LANES]) {
    // `k` indexes the lanes, the inner dimension of every array: the loop over it is what
    // vectorises.
    #[allow(clippy::needless_range_loop)]
    #[inline(always)]
    fn lanes<const ALL_DIFFUSE: bool>(x: &BsdfLanes, wi: &[[f32; SAMPLE_LANES]; 3], f: &mut [[f32; SAMPLE_LANES]; 3], pdf: &mut [f32; SAMPLE_LANES]) {
        for k in 0..SAMPLE_LANES {
            let (v, p) = evaluate_pdf_lane::<ALL_DIFFUSE>(&x.get(k, Vec2::ZERO), Vec3::new(wi[0][k], wi[1][k], wi[2][k]));
            for c in 0..3 {
                f[c][k] = v[c];
            }
            pdf[k] = p;
        }
    }
    if all_diffuse {
        lanes::<true>(x, wi, f, pdf);
    } else {
        lanes::<false>(x, wi, f, pdf);
    }
}

/// The BSDF sample of one lane: `(wi, weight, pdf, valid)`. Both models are computed and the
/// lane's own selected, with no branch on the data, so that a loop over lanes vectorises
/// ([`sample_many`]); each model's values are the operations its sampling describes. A lane
/// draws one cosine-weighted direction, the Lambertian model's or the metallic-roughness
/// model's diffuse lobe's ([`metallic_roughness::diffuse_lobe_numbers`]).
#[inline(always)]
pub(super) fn sample_lane<const ALL_DIFFUSE: bool>(x: SampleLane) -> (Vec3, Vec3, f32, bool) {
    if ALL_DIFFUSE {
        // The Lambertian model alone (for lanes that are all Lambertian).
        return lambert::sample_lane(x.rho, x.wo, sample_cosine_hemisphere(x.u));
    }
    let u_d = if x.diffuse { x.u } else { metallic_roughness::diffuse_lobe_numbers(x.u, x.ps) };
    let wi_d = sample_cosine_hemisphere(u_d);
    let mr = metallic_roughness::sample_lane(&x, wi_d);
    let lambert = lambert::sample_lane(x.rho, x.wo, wi_d);
    if x.diffuse { lambert } else { mr }
}

/// Lanes of [`sample_many`]: eight, the `f32` lanes of an AVX2 register.
const SAMPLE_LANES: usize = 8;

/// `out[k] = bsdfs(k).sample(u[k])` for every `k < u.len()` (the same bits), the samples
/// drawn eight (`SAMPLE_LANES`) at a time: the inputs transposed into one array per number,
/// one vectorised loop over the lanes (`sample_lane`), the results transposed back. The
/// BSDFs are read where they lie (as in [`evaluate_many`]), not gathered into a slice first.
///
/// # Panics
/// If the slices differ in length.
#[inline(always)]
pub fn sample_many<'a>(bsdfs: impl Fn(usize) -> &'a BsdfAt, u: &[Vec2], out: &mut [Option<BsdfSample>]) {
    const L: usize = SAMPLE_LANES;
    let n = u.len();
    assert!(out.len() == n, "sample_many: slices of different lengths");
    for start in (0..n).step_by(L) {
        let m = (n - start).min(L);
        // Unused lanes hold zeros; their results are dropped.
        let mut x = BsdfLanes::default();
        let mut x_u = [[0.0f32; L]; 2];
        for (k, &uk) in u[start..start + m].iter().enumerate() {
            x.set(k, &bsdfs(start + k).lane(uk));
            (x_u[0][k], x_u[1][k]) = (uk.x, uk.y);
        }
        let mut y = SampledLanes::default();
        sample_lanes(&x, x.diffuse[..m].iter().all(|&d| d), &x_u, &mut y);
        for k in 0..m {
            if bsdfs(start + k).is_scalar_only() {
                out[start + k] = bsdfs(start + k).sample(u[start + k]);
                continue;
            }
            out[start + k] = y.ok[k].then(|| BsdfSample {
                wi: Vec3::new(y.wi[0][k], y.wi[1][k], y.wi[2][k]),
                weight: Vec3::new(y.weight[0][k], y.weight[1][k], y.weight[2][k]),
                pdf: y.pdf[k],
            });
        }
    }
}

/// Eight BSDF samples as one array per number ([`sample_lanes`]): the direction (local frame),
/// the weight, the density and whether the sample is valid.
#[derive(Default)]
pub(crate) struct SampledLanes {
    pub(crate) wi: [[f32; SAMPLE_LANES]; 3],
    pub(crate) weight: [[f32; SAMPLE_LANES]; 3],
    pub(crate) pdf: [f32; SAMPLE_LANES],
    pub(crate) ok: [bool; SAMPLE_LANES],
}

/// The eight lanes' BSDF samples with the numbers `u` ([`sample_lane`]): one loop over the
/// lanes, computing only the Lambertian model where `all_diffuse` (every lane that matters is
/// Lambertian).
#[inline(always)]
pub(crate) fn sample_lanes(x: &BsdfLanes, all_diffuse: bool, u: &[[f32; SAMPLE_LANES]; 2], y: &mut SampledLanes) {
    // `k` indexes the lanes, the inner dimension of every array: the loop over it is what
    // vectorises.
    #[allow(clippy::needless_range_loop)]
    #[inline(always)]
    fn lanes<const ALL_DIFFUSE: bool>(x: &BsdfLanes, u: &[[f32; SAMPLE_LANES]; 2], y: &mut SampledLanes) {
        for k in 0..SAMPLE_LANES {
            let (wi, weight, pdf, ok) = sample_lane::<ALL_DIFFUSE>(x.get(k, Vec2::new(u[0][k], u[1][k])));
            for c in 0..3 {
                y.wi[c][k] = wi[c];
                y.weight[c][k] = weight[c];
            }
            y.pdf[k] = pdf;
            y.ok[k] = ok;
        }
    }
    if all_diffuse {
        lanes::<true>(x, u, y);
    } else {
        lanes::<false>(x, u, y);
    }
}
