//! The transmissive dielectric against closed forms (Fresnel at normal incidence, its symmetry
//! across the interface, total internal reflection, the smooth interface's straight and bent
//! rays), its energy (white furnace: `R + T = 1` for smooth interfaces, `≤ 1` for rough ones
//! and with a tint), and its verbs' consistency over the whole sphere (sample ∝ pdf by χ²,
//! `∫ pdf` = the probability that `sample` succeeds, weight = f/pdf, the sampled albedo =
//! the integral of `evaluate`).

use super::*;
use crate::sampler::Sampler;
use std::f32::consts::PI;

fn dir(theta_deg: f32, phi: f32) -> Vec3 {
    let t = theta_deg.to_radians();
    Vec3::new(t.sin() * phi.cos(), t.sin() * phi.sin(), t.cos())
}

fn glass(ior: f32, roughness: f32, tint: Vec3, thin: bool, inside: bool) -> Bsdf {
    let base = MetallicRoughness::new(tint, 0.0, roughness, 1.0);
    let mut t = Transmissive::new(base, roughness, ior, 1.0, thin);
    t.glass.inside = inside;
    Bsdf::Transmissive(t)
}

/// The energy a sample carries: its weight, times `η²` for a ray refracted into the other
/// medium (the radiance weight's `1/η²` is the beam's compression, not a loss).
fn energy(b: &Bsdf, wo: Vec3, s: &BsdfSample) -> f64 {
    let Bsdf::Transmissive(t) = b else { unreachable!() };
    let eta = t.glass.eta();
    let scale = if s.wi.z < 0.0 && !t.glass.thin { eta * eta } else { 1.0 };
    let _ = wo;
    (s.weight.x * scale) as f64
}

/// Mean and standard error of [`energy`] over `n` samples.
fn furnace(b: &Bsdf, wo: Vec3, n: u64, seed: u64) -> (f64, f64) {
    let (mut s1, mut s2) = (0.0f64, 0.0f64);
    for k in 0..n {
        let v = b.sample(wo, Sampler::new(seed, 0, k, 0).next_2d()).map_or(0.0, |s| energy(b, wo, &s));
        s1 += v;
        s2 += v * v;
    }
    let m = s1 / n as f64;
    (m, ((s2 / n as f64 - m * m).max(0.0) / n as f64).sqrt())
}

#[test]
fn fresnel_is_f0_at_normal_incidence_symmetric_across_the_interface_and_total_beyond_the_critical_angle() {
    let (f, ct) = fresnel_dielectric(1.0, 1.5);
    assert!((f - 0.04).abs() < 1e-6 && (ct - 1.0).abs() < 1e-6, "{f} {ct}");
    assert!((fresnel_dielectric(1.0, 1.0 / 1.5).0 - 0.04).abs() < 1e-6);
    // The same interface from the other side: F(θ_i, η) = F(θ_t, 1/η).
    for c in [0.9f32, 0.6, 0.3, 0.1] {
        let (f1, ct) = fresnel_dielectric(c, 1.5);
        let (f2, back) = fresnel_dielectric(ct, 1.0 / 1.5);
        assert!((f1 - f2).abs() < 1e-5 && (back - c).abs() < 1e-5, "{c}: {f1} vs {f2}, {back}");
    }
    // Inside glass beyond the critical angle (sin θ_c = 1/1.5): total internal reflection.
    let c_crit = (1.0f32 - 1.0 / 2.25).sqrt();
    assert_eq!(fresnel_dielectric(c_crit - 0.01, 1.0 / 1.5).0, 1.0);
    assert!(fresnel_dielectric(c_crit + 0.01, 1.0 / 1.5).0 < 1.0);
}

#[test]
fn smooth_interface_reflects_mirrors_and_refracts_by_snell() {
    let b = glass(1.5, 0.0, Vec3::new(0.9, 0.8, 0.7), false, false);
    // Normal incidence: straight through with weight tint/η², or back with weight 1.
    let t = b.sample(Vec3::Z, Vec2::new(0.5, 0.5)).unwrap();
    assert!((t.wi - -Vec3::Z).length() < 1e-6 && (t.weight - Vec3::new(0.9, 0.8, 0.7) / 2.25).abs().max_element() < 1e-6);
    assert!(t.pdf.is_infinite());
    let r = b.sample(Vec3::Z, Vec2::new(0.01, 0.5)).unwrap();
    assert!((r.wi - Vec3::Z).length() < 1e-6 && r.weight == Vec3::ONE);
    // Snell: sin θ_t = sin θ_i / η, on the other side of the normal.
    let wo = dir(50.0, 0.4);
    let t = b.sample(wo, Vec2::new(0.9, 0.5)).unwrap();
    let sin_t = (t.wi.x * t.wi.x + t.wi.y * t.wi.y).sqrt();
    assert!((sin_t - 50f32.to_radians().sin() / 1.5).abs() < 1e-5 && t.wi.z < 0.0, "{:?}", t.wi);
    assert!((t.wi.x * wo.y - t.wi.y * wo.x).abs() < 1e-6 && t.wi.x * wo.x < 0.0, "in the plane of incidence, opposite side");
    // A thin wall passes rays straight.
    let thin = glass(1.5, 0.0, Vec3::ONE, true, false);
    assert!((thin.sample(wo, Vec2::new(0.9, 0.5)).unwrap().wi - -wo).length() < 1e-6);
    // Delta lobes: no value anywhere, pdf 0.
    assert_eq!(b.evaluate(wo, t.wi), Vec3::ZERO);
    assert_eq!(b.pdf(wo, t.wi), 0.0);
}

#[test]
fn white_furnace_smooth_conserves_energy_rough_loses_at_most_what_ggx_loses() {
    for &theta in &[0.0f32, 30.0, 60.0, 85.0] {
        let wo = dir(theta, 0.3);
        for (thin, inside) in [(false, false), (false, true), (true, false)] {
            // Smooth and white: R + T = 1 exactly per sample's expectation.
            let (m, se) = furnace(&glass(1.5, 0.0, Vec3::ONE, thin, inside), wo, 20_000, 3);
            assert!((m - 1.0).abs() < 1e-6 + 4.0 * se, "θ {theta} thin {thin} inside {inside}: {m} ± {se}");
            // Tinted: at most 1 (1 under total internal reflection), at least the tint.
            let (mt, _) = furnace(&glass(1.5, 0.0, Vec3::splat(0.5), thin, inside), wo, 20_000, 3);
            assert!(mt <= m + 1e-6 && mt >= 0.5 - 1e-6, "{mt}");
            for &r in &[0.1f32, 0.3, 0.6, 1.0] {
                let (m, se) = furnace(&glass(1.5, r, Vec3::ONE, thin, inside), wo, 40_000, 5);
                assert!(m <= 1.0 + 4.0 * se + 1e-4, "θ {theta} r {r} thin {thin} inside {inside}: {m} ± {se}");
                // A nearly smooth interface loses almost nothing away from grazing angles.
                if r <= 0.1 && theta <= 60.0 {
                    assert!(m > 0.97, "θ {theta} r {r} thin {thin} inside {inside}: {m} ± {se}");
                }
            }
        }
    }
}

/// `∫ pdf` over a (cos θ, φ) cell of the whole sphere by the midpoint rule, and the same of
/// `evaluate` (red channel).
fn cell(b: &Bsdf, wo: Vec3, z0: f32, z1: f32, p0: f32, p1: f32, sub: u32) -> (f64, f64) {
    let (mut sp, mut sf) = (0.0f64, 0.0f64);
    for i in 0..sub {
        for j in 0..sub {
            let z = z0 + (z1 - z0) * (i as f32 + 0.5) / sub as f32;
            let phi = p0 + (p1 - p0) * (j as f32 + 0.5) / sub as f32;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let (f, p) = b.evaluate_pdf(wo, Vec3::new(r * phi.cos(), r * phi.sin(), z));
            sp += p as f64;
            sf += f.x as f64;
        }
    }
    let area = ((z1 - z0) * (p1 - p0)) as f64 / (sub * sub) as f64;
    (sp * area, sf * area)
}

/// Rough configurations: (ior, roughness, thin, inside, θ_o).
const ROUGH: [(f32, f32, bool, bool, f32); 5] = [(1.5, 0.5, false, false, 30.0), (1.5, 0.7, false, true, 20.0), (1.33, 0.4, false, false, 70.0), (1.5, 0.5, true, false, 45.0), (2.0, 0.9, false, true, 60.0)];

#[test]
fn rough_interface_samples_follow_its_pdf_and_its_albedo_is_the_integral_of_evaluate() {
    let (nz, np, n) = (32usize, 32usize, 200_000u64);
    for (k, &(ior, r, thin, inside, theta)) in ROUGH.iter().enumerate() {
        let b = glass(ior, r, Vec3::ONE, thin, inside);
        let wo = dir(theta, 0.8);
        let mut counts = vec![0u64; nz * np];
        let (mut ok, mut albedo) = (0u64, 0.0f64);
        for p in 0..n {
            let Some(s) = b.sample(wo, Sampler::new(60 + k as u64, 0, p, 0).next_2d()) else { continue };
            ok += 1;
            albedo += s.weight.x as f64;
            // weight = f/pdf and pdf() agrees with the sample's.
            let (f, pdf) = b.evaluate_pdf(wo, s.wi);
            assert!((pdf - s.pdf).abs() <= 1e-3 * s.pdf, "config {k}: pdf {pdf} vs {}", s.pdf);
            assert!((s.weight * s.pdf - f).abs().max_element() <= 1e-3 * f.max_element() + 1e-9);
            let zi = (((s.wi.z + 1.0) * 0.5 * nz as f32) as usize).min(nz - 1);
            let phi = s.wi.y.atan2(s.wi.x).rem_euclid(2.0 * PI);
            let pj = ((phi / (2.0 * PI) * np as f32) as usize).min(np - 1);
            counts[zi * np + pj] += 1;
        }
        let (mut cells, mut total_pdf, mut total_f) = (Vec::with_capacity(nz * np), 0.0f64, 0.0f64);
        for i in 0..nz {
            for j in 0..np {
                let (z0, z1) = (-1.0 + 2.0 * i as f32 / nz as f32, -1.0 + 2.0 * (i + 1) as f32 / nz as f32);
                let (p0, p1) = (2.0 * PI * j as f32 / np as f32, 2.0 * PI * (j + 1) as f32 / np as f32);
                let (cp, cf) = cell(&b, wo, z0, z1, p0, p1, 12);
                total_pdf += cp;
                total_f += cf;
                cells.push((n as f64 * cp, counts[i * np + j] as f64));
            }
        }
        let (chi2, dof, z) = super::tests::pooled_chi_square(cells);
        assert!(dof > 20 && z < 4.0, "config {k}: χ² = {chi2:.1} with {dof} cells, z = {z:.2}");
        let p_ok = ok as f64 / n as f64;
        assert!((total_pdf - p_ok).abs() < 0.01, "config {k}: ∫pdf = {total_pdf}, P(Some) = {p_ok}");
        let albedo = albedo / n as f64;
        assert!((total_f - albedo).abs() < 0.01 * albedo.max(0.1), "config {k}: ∫f = {total_f}, sampled {albedo}");
    }
}

#[test]
fn partial_transmission_mixes_the_interface_with_the_opaque_brdf() {
    // Transmission 0.5, metallic 0.2: the interface's weight is 0.4, the BRDF's metallic 0.2/0.6.
    let base = MetallicRoughness::new(Vec3::splat(0.8), 0.2, 0.4, 1.0);
    let t = Transmissive::new(base, 0.4, 1.5, 0.5, false);
    assert!((t.weight - 0.4).abs() < 1e-6 && (t.base.metallic - 0.2 / 0.6).abs() < 1e-6);
    let b = Bsdf::Transmissive(t);
    let wo = dir(35.0, 0.2);
    for p in 0..4000 {
        let Some(s) = b.sample(wo, Sampler::new(9, 0, p, 0).next_2d()) else { continue };
        let (f, pdf) = b.evaluate_pdf(wo, s.wi);
        assert!((pdf - s.pdf).abs() <= 1e-3 * s.pdf);
        assert!((s.weight * s.pdf - f).abs().max_element() <= 1e-3 * f.max_element() + 1e-9);
    }
    // Smooth interface with an opaque part: the BRDF's samples carry its value alone.
    let smooth = Bsdf::Transmissive(Transmissive::new(MetallicRoughness::new(Vec3::splat(0.8), 0.0, 0.0, 1.0), 0.0, 1.5, 0.5, true));
    let (m, se) = {
        let (mut s1, mut s2) = (0.0f64, 0.0f64);
        let n = 40_000u64;
        for k in 0..n {
            let v = smooth.sample(wo, Sampler::new(4, 0, k, 0).next_2d()).map_or(0.0, |s| s.weight.x as f64);
            s1 += v;
            s2 += v * v;
        }
        let m = s1 / n as f64;
        (m, ((s2 / n as f64 - m * m) / n as f64).sqrt())
    };
    assert!(m <= 1.0 + 4.0 * se && m > 0.5, "{m} ± {se}");
}

#[test]
fn the_lane_loops_hand_transmissive_bsdfs_to_their_scalar_verbs() {
    let bsdfs: Vec<BsdfAt> = (0..11)
        .map(|k| {
            let wo = dir(10.0 + 7.0 * k as f32, k as f32);
            match k % 3 {
                0 => glass(1.5, 0.3, Vec3::ONE, false, k % 2 == 0).at(wo),
                1 => Bsdf::Diffuse { albedo: Vec3::splat(0.5) }.at(wo),
                _ => glass(1.5, 0.0, Vec3::splat(0.7), true, false).at(wo),
            }
        })
        .collect();
    let u: Vec<Vec2> = (0..11).map(|k| Sampler::new(2, 0, k, 0).next_2d()).collect();
    let mut out = vec![None; 11];
    sample_many(|k| &bsdfs[k], &u, &mut out);
    let wi: Vec<Vec3> = (0..11).map(|k| dir(120.0 - 9.0 * k as f32, 0.5 * k as f32)).collect();
    let mut values = vec![(Vec3::ZERO, 0.0); 11];
    evaluate_many(|k| &bsdfs[k], &wi, &mut values);
    for k in 0..11 {
        assert_eq!(out[k], bsdfs[k].sample(u[k]), "sample {k}");
        assert_eq!(values[k], bsdfs[k].evaluate_pdf(wi[k]), "evaluate {k}");
    }
}

#[test]
fn a_transmissive_material_is_view_dependent_at_any_roughness() {
    let mut m = crate::scene::Material::gltf_default();
    (m.metallic_factor, m.roughness_factor) = (0.0, 1.0);
    assert!(!is_view_dependent(&m));
    m.transmission_factor = 0.5;
    assert!(is_view_dependent(&m));
}
