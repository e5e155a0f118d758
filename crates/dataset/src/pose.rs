//! Camera pose algebra for noisy poses and their refinement: the SO(3) and SE(3) exponential
//! and logarithm, the left Jacobian of SO(3), seeded pose noise, the similarity that best maps
//! one set of camera centres onto another, and rotation and translation errors.
//!
//! - **Exponential** (Rodrigues): `exp(ω) = I + A·[ω]× + B·[ω]ײ` with `θ = |ω|`,
//!   `A = sin θ / θ`, `B = (1 − cos θ) / θ²`. **Left Jacobian**: `J(ω) = I + B·[ω]× + C·[ω]ײ`,
//!   `C = (θ − sin θ) / θ³`, so that `exp(ω + δ) ≈ exp(J(ω)·δ) · exp(ω)`. Below
//!   [`SERIES_ANGLE`] the coefficients are their Taylor series (`A = 1 − θ²/6 + θ⁴/120`,
//!   `B = 1/2 − θ²/24 + θ⁴/720`, `C = 1/6 − θ²/120 + θ⁴/5040`), whose truncation error there is
//!   below f64 rounding, instead of quotients that cancel.
//!   `se3_exp(ω, v) = [exp(ω) | J(ω)·v]`.
//! - **Logarithm**: `θ = atan2(|vee(R − Rᵀ)| / 2, (tr R − 1) / 2)` (accurate at every angle,
//!   unlike `acos`); `ω = θ / (2 sin θ) · vee(R − Rᵀ)`, by series near 0; near π the axis comes
//!   from the largest column of `a aᵀ = ((R + Rᵀ)/2 − cos θ I) / (1 − cos θ)` (sign fixed by
//!   `vee(R − Rᵀ)`).
//! - **Angle between rotations**: the logarithm's `θ` of `R_aᵀ R_b`, in degrees.
//! - **Noise** ([`perturb`]): the camera turns about its centre by `N(0, σ_r)` about an axis
//!   uniform on the sphere, and its centre moves by a 3-vector of independent `N(0, σ_t/√3)`
//!   (root-mean-square length `σ_t`). Every number is a pure function of `(seed, view)`
//!   (SplitMix64 of a hash of both, Box–Muller), so noise does not depend on order or threads.
//! - **Alignment** ([`align_similarity`]): the `s, R, t` minimising `Σ |y_i − (s R x_i + t)|²`
//!   (Umeyama 1991). The rotation is found by Horn's quaternion method (the eigenvector of the
//!   largest eigenvalue of a symmetric 4x4 built from the cross-covariance, by Jacobi sweeps),
//!   then `s = Σ (R x̄_i)·ȳ_i / Σ |x̄_i|²` and `t = ȳ − s R x̄` on centred points. Fewer than 3
//!   points, or points on a line, are refused: the rotation is not determined.
//! - **Errors** ([`pose_errors`]): per view, the angle and the centre distance between the
//!   aligned estimate and the truth.

use glam::{DMat3, DMat4, DQuat, DVec3, DVec4};

/// Below this angle (radians) the exponential's, logarithm's and Jacobian's coefficients are
/// evaluated by their series.
pub const SERIES_ANGLE: f64 = 1e-4;

/// `[ω]×`, the cross-product matrix: `[ω]× v = ω × v`.
pub fn hat(w: DVec3) -> DMat3 {
    DMat3::from_cols(DVec3::new(0.0, w.z, -w.y), DVec3::new(-w.z, 0.0, w.x), DVec3::new(w.y, -w.x, 0.0))
}

/// The vector of the skew part: `vee(M) = (M₃₂ − M₂₃, M₁₃ − M₃₁, M₂₁ − M₁₂)`.
fn vee_of_difference(m: &DMat3) -> DVec3 {
    DVec3::new(m.y_axis.z - m.z_axis.y, m.z_axis.x - m.x_axis.z, m.x_axis.y - m.y_axis.x)
}

/// `(A, B, C)` of the module docs at angle `θ`.
fn coefficients(theta: f64) -> (f64, f64, f64) {
    let t2 = theta * theta;
    if theta < SERIES_ANGLE {
        (1.0 - t2 / 6.0 + t2 * t2 / 120.0, 0.5 - t2 / 24.0 + t2 * t2 / 720.0, 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0)
    } else {
        let (s, c) = theta.sin_cos();
        (s / theta, (1.0 - c) / t2, (theta - s) / (t2 * theta))
    }
}

/// The rotation `exp([ω]×)`.
pub fn so3_exp(w: DVec3) -> DMat3 {
    let (a, b, _) = coefficients(w.length());
    let k = hat(w);
    DMat3::IDENTITY + k * a + k * k * b
}

/// The left Jacobian `J(ω)` of SO(3).
pub fn so3_left_jacobian(w: DVec3) -> DMat3 {
    let (_, b, c) = coefficients(w.length());
    let k = hat(w);
    DMat3::IDENTITY + k * b + k * k * c
}

/// The rigid transform `[exp(ω) | J(ω)·v]`.
pub fn se3_exp(w: DVec3, v: DVec3) -> DMat4 {
    let r = so3_exp(w);
    DMat4::from_cols(r.x_axis.extend(0.0), r.y_axis.extend(0.0), r.z_axis.extend(0.0), (so3_left_jacobian(w) * v).extend(1.0))
}

/// The rotation vector `ω` with `exp(ω) = r`, `|ω| ≤ π`, of a rotation matrix `r`.
pub fn so3_log(r: &DMat3) -> DVec3 {
    let skew = vee_of_difference(r);
    let sin = 0.5 * skew.length();
    let cos = 0.5 * (r.x_axis.x + r.y_axis.y + r.z_axis.z - 1.0);
    let theta = sin.atan2(cos);
    if theta < SERIES_ANGLE {
        return skew * (0.5 * (1.0 + theta * theta / 6.0));
    }
    if theta < std::f64::consts::PI - 1e-3 {
        return skew * (theta / (2.0 * sin));
    }
    // Near π: the symmetric part is cos θ I + (1 − cos θ) a aᵀ, so a aᵀ is known; its largest
    // column is the best-conditioned multiple of a.
    let s = ((*r + r.transpose()) * 0.5 - DMat3::IDENTITY * cos) * (1.0 / (1.0 - cos));
    let cols = [s.x_axis, s.y_axis, s.z_axis];
    let k = (0..3).max_by(|&i, &j| cols[i][i].total_cmp(&cols[j][j])).unwrap_or(0);
    let mut axis = (cols[k] / cols[k][k].max(f64::MIN_POSITIVE).sqrt()).normalize_or(DVec3::X);
    if axis.dot(skew) < 0.0 {
        axis = -axis;
    }
    axis * theta
}

/// The angle of the rotation taking `a` to `b` (of `aᵀ b`), degrees.
pub fn rotation_angle_deg(a: &DMat3, b: &DMat3) -> f64 {
    let m = a.transpose() * *b;
    let sin = 0.5 * vee_of_difference(&m).length();
    let cos = 0.5 * (m.x_axis.x + m.y_axis.y + m.z_axis.z - 1.0);
    sin.atan2(cos).to_degrees()
}

/// SplitMix64 of `x`.
fn mix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// Uniform numbers in (0, 1) and standard normals drawn for one `(seed, view)`.
struct Draws(u64, u64);

impl Draws {
    fn uniform(&mut self) -> f64 {
        self.1 += 1;
        let bits = mix(self.0 ^ mix(self.1)) >> 11;
        (bits as f64 + 0.5) / (1u64 << 53) as f64
    }

    fn normal(&mut self) -> f64 {
        let (u, v) = (self.uniform(), self.uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// The camera-to-world `pose` with seeded noise (see the module docs): rotation about its
/// centre with standard deviation `rotation_deg` degrees, centre moved with root-mean-square
/// length `translation` (scene units). Zero noise returns `pose` bit for bit.
pub fn perturb(pose: &DMat4, seed: u64, view: u64, rotation_deg: f64, translation: f64) -> DMat4 {
    let mut d = Draws(mix(seed ^ 0x504F_5345) ^ mix(view.wrapping_mul(0xD1B5_4A32_D192_ED03)), 0);
    let z = d.uniform() * 2.0 - 1.0;
    let phi = std::f64::consts::TAU * d.uniform();
    let r = (1.0 - z * z).max(0.0).sqrt();
    let axis = DVec3::new(r * phi.cos(), r * phi.sin(), z);
    let angle = d.normal() * rotation_deg.to_radians();
    let sigma = translation / 3f64.sqrt();
    let shift = DVec3::new(d.normal(), d.normal(), d.normal()) * sigma;
    if rotation_deg == 0.0 && translation == 0.0 {
        return *pose;
    }
    let turn = so3_exp(axis * angle);
    let rot = turn * DMat3::from_mat4(*pose);
    let centre = pose.w_axis.truncate() + shift;
    DMat4::from_cols(rot.x_axis.extend(0.0), rot.y_axis.extend(0.0), rot.z_axis.extend(0.0), centre.extend(1.0))
}

/// A similarity `y = s R x + t`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Similarity {
    /// Scale.
    pub scale: f64,
    /// Rotation.
    pub rotation: DMat3,
    /// Translation.
    pub translation: DVec3,
}

impl Similarity {
    /// `s R x + t`.
    pub fn apply(&self, x: DVec3) -> DVec3 {
        self.rotation * x * self.scale + self.translation
    }

    /// A camera-to-world pose mapped by the similarity: centre mapped, orientation rotated
    /// (the scale changes no direction).
    pub fn apply_pose(&self, pose: &DMat4) -> DMat4 {
        let r = self.rotation * DMat3::from_mat4(*pose);
        let c = self.apply(pose.w_axis.truncate());
        DMat4::from_cols(r.x_axis.extend(0.0), r.y_axis.extend(0.0), r.z_axis.extend(0.0), c.extend(1.0))
    }
}

/// Eigenvector of the largest eigenvalue of a symmetric 4x4 (cyclic Jacobi sweeps).
fn top_eigenvector(mut a: [[f64; 4]; 4]) -> DVec4 {
    let mut v = [[0.0; 4]; 4];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _ in 0..64 {
        let off: f64 = (0..4).flat_map(|i| (0..4).filter(move |&j| j != i).map(move |j| (i, j))).map(|(i, j)| a[i][j] * a[i][j]).sum();
        if off < 1e-30 {
            break;
        }
        for p in 0..3 {
            for q in p + 1..4 {
                if a[p][q].abs() < 1e-300 {
                    continue;
                }
                let theta = 0.5 * (a[q][q] - a[p][p]) / a[p][q];
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..4 {
                    let (akp, akq) = (a[k][p], a[k][q]);
                    a[k][p] = c * akp - s * akq;
                    a[k][q] = s * akp + c * akq;
                }
                for k in 0..4 {
                    let (apk, aqk) = (a[p][k], a[q][k]);
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                for row in v.iter_mut() {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    let k = (0..4).max_by(|&i, &j| a[i][i].total_cmp(&a[j][j])).unwrap_or(0);
    DVec4::new(v[0][k], v[1][k], v[2][k], v[3][k])
}

/// The similarity mapping the points `x` onto `y` best in least squares (see the module
/// docs). Errors, in words, when the lengths differ, a point is not finite, or the points
/// do not determine a rotation (fewer than 3, or on one line).
pub fn align_similarity(x: &[DVec3], y: &[DVec3]) -> Result<Similarity, String> {
    if x.len() != y.len() {
        return Err(format!("{} points to align against {}", x.len(), y.len()));
    }
    if x.len() < 3 {
        return Err(format!("{} points: at least 3 not on one line are needed to fix a rotation", x.len()));
    }
    if x.iter().chain(y).any(|p| !p.is_finite()) {
        return Err("a point is not finite".into());
    }
    let n = x.len() as f64;
    let (mx, my) = (x.iter().sum::<DVec3>() / n, y.iter().sum::<DVec3>() / n);
    let spread = |ps: &[DVec3], m: DVec3| {
        let c: Vec<DVec3> = ps.iter().map(|p| *p - m).collect();
        let scale = c.iter().map(|p| p.length()).fold(0.0, f64::max);
        let on_line = scale == 0.0 || {
            let far = c.iter().copied().max_by(|a, b| a.length().total_cmp(&b.length())).unwrap_or(DVec3::X).normalize();
            c.iter().all(|p| p.cross(far).length() <= 1e-9 * scale)
        };
        (c, on_line)
    };
    let ((xc, x_line), (yc, y_line)) = (spread(x, mx), spread(y, my));
    if x_line || y_line {
        return Err("the points lie on one line (or coincide): the rotation about it is not determined".into());
    }
    // Cross-covariance S = Σ x̄ ȳᵀ, and Horn's symmetric N.
    let mut s = [[0.0f64; 3]; 3];
    for (a, b) in xc.iter().zip(&yc) {
        for i in 0..3 {
            for j in 0..3 {
                s[i][j] += a[i] * b[j];
            }
        }
    }
    let [[sxx, sxy, sxz], [syx, syy, syz], [szx, szy, szz]] = s;
    let nm = [
        [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
        [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
        [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
        [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
    ];
    let q = top_eigenvector(nm);
    let rotation = DMat3::from_quat(DQuat::from_xyzw(q.y, q.z, q.w, q.x).normalize());
    let num: f64 = xc.iter().zip(&yc).map(|(a, b)| (rotation * *a).dot(*b)).sum();
    let den: f64 = xc.iter().map(|a| a.length_squared()).sum();
    let scale = num / den;
    Ok(Similarity { scale, rotation, translation: my - rotation * mx * scale })
}

/// Per-view errors of estimated camera poses against the true ones, after the similarity that
/// maps the estimated centres onto the true best ([`align_similarity`]): a reconstruction from
/// images alone is defined up to a similarity, so that part is not an error.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseErrors {
    /// Angle between each aligned estimated orientation and the true one, degrees.
    pub rotation_deg: Vec<f64>,
    /// Distance between each aligned estimated centre and the true one, scene units.
    pub translation: Vec<f64>,
    /// The alignment applied to the estimates.
    pub alignment: Similarity,
}

/// The median of `v` (`NaN` when empty).
pub fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    match s.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => s[n / 2],
        n => 0.5 * (s[n / 2 - 1] + s[n / 2]),
    }
}

/// [`PoseErrors`] of camera-to-world `estimated` poses against `truth` (same views, same
/// order). Errors as [`align_similarity`] does.
pub fn pose_errors(estimated: &[DMat4], truth: &[DMat4]) -> Result<PoseErrors, String> {
    let centres = |ps: &[DMat4]| ps.iter().map(|p| p.w_axis.truncate()).collect::<Vec<_>>();
    let alignment = align_similarity(&centres(estimated), &centres(truth))?;
    let (mut rotation_deg, mut translation) = (Vec::new(), Vec::new());
    for (e, t) in estimated.iter().zip(truth) {
        let a = alignment.apply_pose(e);
        rotation_deg.push(rotation_angle_deg(&DMat3::from_mat4(a), &DMat3::from_mat4(*t)));
        translation.push((a.w_axis - t.w_axis).truncate().length());
    }
    Ok(PoseErrors { rotation_deg, translation, alignment })
}

#[cfg(test)]
mod tests;
