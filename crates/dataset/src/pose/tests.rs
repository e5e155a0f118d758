use super::*;

/// `exp([ω]×)` by its power series in f64, the reference for moderate angles.
fn exp_series(w: DVec3) -> DMat3 {
    let k = hat(w);
    let (mut term, mut sum) = (DMat3::IDENTITY, DMat3::IDENTITY);
    for n in 1..60 {
        term = term * k * (1.0 / n as f64);
        sum += term;
    }
    sum
}

fn max_abs(m: DMat3) -> f64 {
    m.to_cols_array().iter().fold(0.0, |a, x| a.max(x.abs()))
}

const ANGLES: [f64; 7] = [0.0, 1e-8, 1e-4, 0.1, 1.0, 3.0, std::f64::consts::PI - 1e-6];

fn axis() -> DVec3 {
    DVec3::new(0.3, -0.5, 0.81).normalize()
}

#[test]
fn exponential_matches_its_power_series_and_is_a_rotation() {
    for theta in ANGLES {
        let w = axis() * theta;
        let r = so3_exp(w);
        assert!(max_abs(r - exp_series(w)) < 1e-14, "θ {theta}: {}", max_abs(r - exp_series(w)));
        assert!(max_abs(r.transpose() * r - DMat3::IDENTITY) < 1e-15, "θ {theta}");
        assert!((r.determinant() - 1.0).abs() < 1e-15);
    }
}

#[test]
fn logarithm_inverts_the_exponential_at_every_angle() {
    for theta in ANGLES {
        for a in [axis(), DVec3::X, DVec3::new(-0.2, 0.1, -0.97).normalize()] {
            let w = a * theta;
            let back = so3_log(&so3_exp(w));
            // Relative accuracy at small angles, absolute near π (where the axis is recovered
            // from a rank-1 matrix).
            let tol = if theta > 3.0 { 1e-9 } else { 1e-15 * theta.max(1e-300) + 1e-22 };
            assert!((back - w).length() <= tol.max(1e-15 * theta), "θ {theta}: {back} against {w}");
        }
    }
    assert!((rotation_angle_deg(&DMat3::IDENTITY, &so3_exp(axis() * 1e-9)) - 1e-9f64.to_degrees()).abs() < 1e-22);
}

/// `exp(ω + h e_i) exp(ω)ᵀ ≈ exp(h J(ω) e_i)`: the left Jacobian against central differences.
#[test]
fn left_jacobian_matches_finite_differences() {
    let h = 1e-6;
    for theta in ANGLES {
        let w = axis() * theta;
        let j = so3_left_jacobian(w);
        for (i, e) in [DVec3::X, DVec3::Y, DVec3::Z].into_iter().enumerate() {
            let d = (so3_exp(w + e * h) - so3_exp(w - e * h)) * (1.0 / (2.0 * h)) * so3_exp(w).transpose();
            let fd = DVec3::new(d.y_axis.z, d.z_axis.x, d.x_axis.y);
            let err = (fd - j.col(i)).length();
            assert!(err < 1e-8, "θ {theta}, column {i}: {fd} against {}", j.col(i));
        }
    }
    // se3_exp's translation is J v.
    let t = se3_exp(axis() * 0.7, DVec3::new(1.0, 2.0, 3.0));
    assert!((t.w_axis.truncate() - so3_left_jacobian(axis() * 0.7) * DVec3::new(1.0, 2.0, 3.0)).length() < 1e-15);
}

fn pose(k: u64) -> DMat4 {
    let a = k as f64;
    let r = so3_exp(DVec3::new(0.3 * a, -0.2, 0.1 * a.sin()));
    DMat4::from_cols(r.x_axis.extend(0.0), r.y_axis.extend(0.0), r.z_axis.extend(0.0), DVec3::new(a.cos() * 3.0, 1.0 + 0.1 * a, a.sin() * 3.0).extend(1.0))
}

#[test]
fn noise_is_a_pure_function_of_seed_and_view_with_the_stated_spread() {
    let p = pose(3);
    assert_eq!(perturb(&p, 7, 3, 0.0, 0.0), p);
    assert_eq!(perturb(&p, 7, 3, 1.0, 0.01), perturb(&p, 7, 3, 1.0, 0.01));
    assert_ne!(perturb(&p, 7, 3, 1.0, 0.01), perturb(&p, 8, 3, 1.0, 0.01));
    assert_ne!(perturb(&p, 7, 3, 1.0, 0.01), perturb(&p, 7, 4, 1.0, 0.01));
    let n = 4000;
    let (mut sq_angle, mut sq_shift) = (0.0, 0.0);
    for view in 0..n {
        let q = perturb(&p, 11, view, 2.0, 0.05);
        sq_angle += rotation_angle_deg(&DMat3::from_mat4(p), &DMat3::from_mat4(q)).powi(2);
        sq_shift += (q.w_axis - p.w_axis).truncate().length_squared();
        let r = DMat3::from_mat4(q);
        assert!(max_abs(r.transpose() * r - DMat3::IDENTITY) < 1e-14);
    }
    let (rms_angle, rms_shift) = ((sq_angle / n as f64).sqrt(), (sq_shift / n as f64).sqrt());
    assert!((rms_angle - 2.0).abs() < 0.1, "rms angle {rms_angle}°");
    assert!((rms_shift - 0.05).abs() < 0.0025, "rms shift {rms_shift}");
}

#[test]
fn alignment_recovers_a_known_similarity_and_refuses_a_line() {
    let truth = Similarity { scale: 0.37, rotation: so3_exp(DVec3::new(0.4, -1.1, 2.0)), translation: DVec3::new(1.0, -2.0, 0.5) };
    let x: Vec<DVec3> = (0..12).map(|k| pose(k).w_axis.truncate()).collect();
    let y: Vec<DVec3> = x.iter().map(|p| truth.apply(*p)).collect();
    let s = align_similarity(&x, &y).unwrap();
    assert!((s.scale - truth.scale).abs() < 1e-12, "{}", s.scale);
    assert!(max_abs(s.rotation - truth.rotation) < 1e-12);
    assert!((s.translation - truth.translation).length() < 1e-12);
    // A rotation near π about a coordinate axis (Horn's eigenvector has a small first entry).
    let flip = Similarity { scale: 2.0, rotation: so3_exp(DVec3::Z * (std::f64::consts::PI - 1e-9)), translation: DVec3::ZERO };
    let y: Vec<DVec3> = x.iter().map(|p| flip.apply(*p)).collect();
    let s = align_similarity(&x, &y).unwrap();
    assert!(max_abs(s.rotation - flip.rotation) < 1e-9 && (s.scale - 2.0).abs() < 1e-12);
    // Poses map with their centres.
    let mapped = truth.apply_pose(&pose(2));
    assert!((mapped.w_axis.truncate() - truth.apply(pose(2).w_axis.truncate())).length() < 1e-15);
    let line: Vec<DVec3> = (0..5).map(|k| DVec3::splat(k as f64)).collect();
    assert!(align_similarity(&line, &line).unwrap_err().contains("one line"));
    assert!(align_similarity(&x[..2], &x[..2]).unwrap_err().contains("at least 3"));
    assert!(align_similarity(&x, &x[..5]).is_err());
}

/// Noisy poses moved by a similarity: the alignment removes the similarity, so the errors are
/// the noise's (exactly zero without noise), and their median sits near the noise level.
#[test]
fn pose_errors_measure_the_noise_not_the_frame() {
    let truth: Vec<DMat4> = (0..40).map(pose).collect();
    let moved = Similarity { scale: 1.7, rotation: so3_exp(DVec3::new(0.2, 0.9, -0.4)), translation: DVec3::new(3.0, 0.0, -1.0) };
    let exact: Vec<DMat4> = truth.iter().map(|p| moved.apply_pose(p)).collect();
    let e = pose_errors(&exact, &truth).unwrap();
    assert!(e.rotation_deg.iter().all(|a| *a < 1e-9) && e.translation.iter().all(|d| *d < 1e-12), "{e:?}");
    let noisy: Vec<DMat4> = truth.iter().enumerate().map(|(k, p)| moved.apply_pose(&perturb(p, 5, k as u64, 1.0, 0.0))).collect();
    let e = pose_errors(&noisy, &truth).unwrap();
    let m = median(&e.rotation_deg);
    // |N(0, 1°)| has median 0.674°.
    assert!((0.4..1.0).contains(&m), "median rotation error {m}°");
    assert!(median(&e.translation) < 1e-9, "rotation noise moved no centre");
    assert_eq!(median(&[3.0, 1.0, 2.0, 10.0]), 2.5);
    assert!(median(&[]).is_nan());
}
