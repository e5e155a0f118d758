//! The clearcoat and sheen layers: the limits that must be the base exactly (no coat, no
//! sheen), energy (white furnace ≤ 1 over white Lambert, white metal, black bases), the sheen
//! albedo table against a direct integral, and the verbs' consistency (sample ∝ pdf by χ²,
//! `∫ pdf` = the probability that `sample` succeeds, weight = f/pdf).

use super::*;
use crate::sampler::Sampler;
use std::f32::consts::PI;

fn dir(theta_deg: f32, phi: f32) -> Vec3 {
    let t = theta_deg.to_radians();
    Vec3::new(t.sin() * phi.cos(), t.sin() * phi.sin(), t.cos())
}

/// A white Lambert base (metallic 0, specular 0), a white metal, a black dielectric (only its
/// 4 % specular layer) and a glTF dielectric.
fn bases() -> [(&'static str, MetallicRoughness); 4] {
    [
        ("white lambert", MetallicRoughness::new(Vec3::ONE, 0.0, 0.5, 0.0)),
        ("white metal", MetallicRoughness::new(Vec3::ONE, 1.0, 0.3, 1.0)),
        ("black", MetallicRoughness::new(Vec3::ZERO, 0.0, 0.5, 0.0)),
        ("plastic", MetallicRoughness::new(Vec3::new(0.8, 0.3, 0.2), 0.0, 0.4, 1.0)),
    ]
}

/// `∫ f cos` over the hemisphere by the midpoint rule in (cos θ, φ), red channel (the
/// white furnace), `n × 4n` cells.
fn albedo_integral(b: &Bsdf, wo: Vec3, n: usize) -> f64 {
    let mut sum = 0.0f64;
    for i in 0..n {
        let z = (i as f32 + 0.5) / n as f32;
        let r = (1.0 - z * z).sqrt();
        for j in 0..4 * n {
            let phi = 2.0 * PI * (j as f32 + 0.5) / (4 * n) as f32;
            sum += b.evaluate(wo, Vec3::new(r * phi.cos(), r * phi.sin(), z)).x as f64;
        }
    }
    sum * 2.0 * std::f64::consts::PI / (4 * n * n) as f64
}

/// Mean and standard error of the sampled weight (red) over `n` samples.
fn furnace(b: &Bsdf, wo: Vec3, n: u64, seed: u64) -> (f64, f64) {
    let (mut s1, mut s2) = (0.0f64, 0.0f64);
    for k in 0..n {
        let v = b.sample(wo, Sampler::new(seed, 0, k, 0).next_2d()).map_or(0.0, |s| s.weight.x as f64);
        s1 += v;
        s2 += v * v;
    }
    let m = s1 / n as f64;
    (m, ((s2 / n as f64 - m * m).max(0.0) / n as f64).sqrt())
}

#[test]
fn no_coat_and_no_sheen_is_the_base_exactly() {
    for (name, base) in bases() {
        let l = Bsdf::Layered(Layered::new(base, 0.0, 0.3, Vec3::ZERO, 0.5));
        let m = Bsdf::MetallicRoughness(base);
        for k in 0..200 {
            let wo = dir(2.0 + 0.43 * k as f32, 0.37 * k as f32);
            let wi = dir(89.0 - 0.41 * k as f32, 1.3 + 0.71 * k as f32);
            assert_eq!(l.evaluate(wo, wi), m.evaluate(wo, wi), "{name} {k}: evaluate");
            assert_eq!(l.pdf(wo, wi), m.pdf(wo, wi), "{name} {k}: pdf");
        }
    }
    // And a material without the extensions resolves to the BSDF it always did.
    let attr = SurfaceAttributes { uv: [Vec2::ZERO; 2], color: glam::Vec4::ONE };
    let mut mat = crate::scene::Material::gltf_default();
    mat.metallic_factor = 0.0;
    assert!(matches!(resolve(&mat, &[], &attr).bsdf, Bsdf::MetallicRoughness(_)));
    mat.sheen = Some(crate::scene::Sheen { color_factor: Vec3::ONE, color_texture: None, roughness_factor: 0.5, roughness_texture: None });
    let Bsdf::Layered(l) = resolve(&mat, &[], &attr).bsdf else { panic!("sheen gives a layered BSDF") };
    assert_eq!((l.clearcoat, l.sheen, l.sheen_roughness), (0.0, Vec3::ONE, 0.5));
}

#[test]
fn sheen_albedo_table_matches_a_direct_integral() {
    // Off the table's nodes, in both directions: the interpolated value against a fine
    // midpoint integral of the lobe.
    let mut worst = 0.0f64;
    for r in [0.07f32, 0.1, 0.23, 0.5, 0.77, 1.0] {
        for mu in [0.02f32, 0.1, 0.3, 0.55, 0.8, 0.97] {
            let direct = sheen_albedo_integral(mu as f64, r, 400);
            let table = sheen_albedo(mu, r) as f64;
            assert!(direct > 0.0 && direct < 3.0, "r {r} μ {mu}: E = {direct}");
            worst = worst.max((table - direct).abs());
            assert!((table - direct).abs() < 0.01 + 0.02 * direct, "r {r} μ {mu}: table {table} vs integral {direct}");
        }
    }
    eprintln!("worst |table − integral| = {worst:.4}");
    // The lobe's albedo grows towards grazing views (the sheen's back-scattering), and the
    // fitted Λ lets it exceed 1 there at low roughness (what the layering divides out).
    assert!(sheen_albedo(0.1, 0.5) > sheen_albedo(0.9, 0.5));
    assert!(sheen_albedo(0.02, 0.07) > 1.5 && sheen_albedo(0.5, 0.07) < 0.01);
}

#[test]
fn white_furnace_is_at_most_one_for_coat_and_sheen_over_every_base() {
    for (name, base) in bases() {
        for (c, cr, s, sr) in [(1.0, 0.0, 0.0, 0.5), (1.0, 0.5, 0.0, 0.5), (0.5, 0.2, 0.0, 0.5), (1.0, 0.6, 0.0, 0.5), (0.0, 0.0, 1.0, 0.3), (0.0, 0.0, 1.0, 1.0), (0.0, 0.0, 1.0, 0.07), (1.0, 0.1, 1.0, 0.6)] {
            let b = Bsdf::Layered(Layered::new(base, c, cr, Vec3::splat(s), sr));
            for theta in [0.0f32, 30.0, 60.0, 80.0, 88.0] {
                let wo = dir(theta, 0.4);
                let (m, se) = furnace(&b, wo, 20_000, 17);
                assert!(m <= 1.0 + 4.0 * se + 1e-3, "{name} c {c} cr {cr} s {s} sr {sr} θ {theta}: sampled albedo {m} ± {se}");
                // A smooth coat's lobe is too narrow for a quadrature: the sampled mean stands.
                if (cr >= 0.5 || c == 0.0) && theta <= 80.0 {
                    let a = albedo_integral(&b, wo, 128);
                    assert!(a <= 1.0 + 2e-3, "{name} c {c} cr {cr} s {s} sr {sr} θ {theta}: ∫ f cos = {a}");
                    assert!((a - m).abs() <= 4.0 * se + 0.02 * a.max(0.05), "{name} c {c} s {s} θ {theta}: ∫ {a} vs sampled {m} ± {se}");
                }
            }
        }
    }
    // Closed forms: a full smooth coat over a black base reflects Fc(θ) (the GGX lobe without
    // Fresnel reflects ~1 when nearly smooth); a sheen over a black base reflects max(S) E.
    let black = MetallicRoughness::new(Vec3::ZERO, 0.0, 0.5, 0.0);
    for theta in [0.0f32, 45.0, 75.0] {
        let wo = dir(theta, 0.0);
        let coat = Bsdf::Layered(Layered::new(black, 1.0, 0.05, Vec3::ZERO, 0.0));
        let fc = 0.04 + 0.96 * (1.0 - wo.z as f64).powi(5);
        let (m, se) = furnace(&coat, wo, 20_000, 3);
        assert!((m - fc).abs() < 4.0 * se + 0.01 * fc, "θ {theta}: coat over black {m} ± {se}, Fc = {fc}");
        let sheen = Bsdf::Layered(Layered::new(black, 0.0, 0.0, Vec3::splat(0.6), 0.4));
        let a = albedo_integral(&sheen, wo, 128);
        let e = 0.6 * (sheen_albedo(wo.z, 0.4) as f64).min(1.0);
        assert!((a - e).abs() < 0.01 * e + 2e-3, "θ {theta}: sheen over black ∫ = {a}, max(S) E = {e}");
    }
    // A white sheen over a white Lambert conserves what the Lambert did (= 1) up to E's error.
    let lambert = MetallicRoughness::new(Vec3::ONE, 0.0, 0.5, 0.0);
    let sheen = Bsdf::Layered(Layered::new(lambert, 0.0, 0.0, Vec3::ONE, 0.5));
    for theta in [10.0f32, 50.0, 80.0] {
        let a = albedo_integral(&sheen, dir(theta, 0.0), 128);
        assert!((a - 1.0).abs() < 0.01, "θ {theta}: white sheen over white Lambert ∫ = {a}");
    }
}

#[test]
fn sampled_directions_follow_the_pdf_and_weights_are_f_over_pdf() {
    let plastic = MetallicRoughness::new(Vec3::new(0.8, 0.3, 0.2), 0.0, 0.6, 1.0);
    let metal = MetallicRoughness::new(Vec3::splat(0.9), 1.0, 0.5, 1.0);
    let mut tilted = Layered::new(plastic, 1.0, 0.3, Vec3::new(0.2, 0.5, 0.9), 0.4);
    tilted.coat_normal = dir(20.0, 2.0);
    let configs = [
        (Layered::new(plastic, 1.0, 0.4, Vec3::ZERO, 0.0), 40.0),
        (Layered::new(metal, 0.7, 0.3, Vec3::splat(0.8), 0.5), 65.0),
        (Layered::new(plastic, 0.0, 0.0, Vec3::new(1.0, 0.5, 0.2), 0.3), 20.0),
        (tilted, 50.0),
    ];
    let (nz, np, n) = (16usize, 32usize, 100_000u64);
    for (k, &(l, theta)) in configs.iter().enumerate() {
        let b = Bsdf::Layered(l);
        let wo = dir(theta, 0.3);
        let mut counts = vec![0u64; nz * np];
        let mut ok = 0u64;
        for p in 0..n {
            let Some(s) = b.sample(wo, Sampler::new(90 + k as u64, 0, p, 0).next_2d()) else { continue };
            ok += 1;
            let (f, pdf) = b.evaluate_pdf(wo, s.wi);
            assert!((pdf - s.pdf).abs() <= 1e-4 * s.pdf, "config {k}: pdf {pdf} vs {}", s.pdf);
            assert!((s.weight * s.pdf - f).abs().max_element() <= 1e-4 * f.max_element() + 1e-9);
            let zi = ((s.wi.z * nz as f32) as usize).min(nz - 1);
            let phi = s.wi.y.atan2(s.wi.x).rem_euclid(2.0 * PI);
            counts[zi * np + ((phi / (2.0 * PI) * np as f32) as usize).min(np - 1)] += 1;
        }
        let (mut cells, mut total) = (Vec::with_capacity(nz * np), 0.0f64);
        for i in 0..nz {
            for j in 0..np {
                let (z0, z1) = (i as f32 / nz as f32, (i + 1) as f32 / nz as f32);
                let (p0, p1) = (2.0 * PI * j as f32 / np as f32, 2.0 * PI * (j + 1) as f32 / np as f32);
                let cp = super::tests::cell_integral(&b, wo, z0, z1, p0, p1, 12);
                total += cp;
                cells.push((n as f64 * cp, counts[i * np + j] as f64));
            }
        }
        let (chi2, dof, z) = super::tests::pooled_chi_square(cells);
        assert!(dof > 20 && z < 4.0, "config {k}: χ² = {chi2:.1} with {dof} cells, z = {z:.2}");
        let p_ok = ok as f64 / n as f64;
        assert!((total - p_ok).abs() < 0.01, "config {k}: ∫pdf = {total}, P(Some) = {p_ok}");
    }
}

#[test]
fn the_lane_loops_hand_layered_bsdfs_to_their_scalar_verbs() {
    let base = MetallicRoughness::new(Vec3::splat(0.6), 0.0, 0.5, 1.0);
    let bsdfs: Vec<BsdfAt> = (0..11)
        .map(|k| {
            let wo = dir(10.0 + 7.0 * k as f32, k as f32);
            match k % 3 {
                0 => Bsdf::Layered(Layered::new(base, 1.0, 0.2, Vec3::splat(0.5), 0.4)).at(wo),
                1 => Bsdf::Diffuse { albedo: Vec3::splat(0.5) }.at(wo),
                _ => Bsdf::MetallicRoughness(base).at(wo),
            }
        })
        .collect();
    let u: Vec<Vec2> = (0..11).map(|k| Sampler::new(2, 0, k, 0).next_2d()).collect();
    let mut out = vec![None; 11];
    sample_many(|k| &bsdfs[k], &u, &mut out);
    let wi: Vec<Vec3> = (0..11).map(|k| dir(80.0 - 7.0 * k as f32, 0.5 * k as f32)).collect();
    let mut values = vec![(Vec3::ZERO, 0.0); 11];
    evaluate_many(|k| &bsdfs[k], &wi, &mut values);
    for k in 0..11 {
        assert_eq!(out[k], bsdfs[k].sample(u[k]), "sample {k}");
        assert_eq!(values[k], bsdfs[k].evaluate_pdf(wi[k]), "evaluate {k}");
    }
}
