//! A smooth camera path through keyframe poses: uniform Catmull-Rom on the camera centres and
//! on the rotations' unit quaternions (signs aligned to the previous key, renormalised), so
//! position and orientation are C¹ and the path passes through every keyframe.
//!
//! With `K` keyframes and `n` frames per segment, frame `i · n` **is** keyframe `i` (its matrix
//! copied, bit for bit); an open path has `(K − 1) · n + 1` frames, a cycle `K · n` (its last
//! segment returns to the first key). The end tangents of an open path repeat the end keys.

use glam::{DMat3, DMat4, DQuat, DVec3, DVec4};

/// The interpolated poses through `keys` (camera-to-world, rigid), `per_segment` frames from
/// one key to the next (at least 1); `cycle` closes the path.
pub fn interpolate_poses(keys: &[DMat4], per_segment: u32, cycle: bool) -> Vec<DMat4> {
    let n = per_segment.max(1);
    let k = keys.len();
    if k < 2 {
        return keys.to_vec();
    }
    let pos: Vec<DVec3> = keys.iter().map(|m| m.w_axis.truncate()).collect();
    let mut rot: Vec<DQuat> = keys.iter().map(|m| DQuat::from_mat3(&DMat3::from_mat4(*m)).normalize()).collect();
    for i in 1..k {
        if rot[i].dot(rot[i - 1]) < 0.0 {
            rot[i] = -rot[i];
        }
    }
    let segments = if cycle { k } else { k - 1 };
    // The key at index `i` (wrapped for a cycle, clamped otherwise) with its quaternion's sign
    // aligned to `reference`.
    let at = |i: isize| -> usize { if cycle { i.rem_euclid(k as isize) as usize } else { i.clamp(0, k as isize - 1) as usize } };
    let mut out = Vec::with_capacity(segments * n as usize + 1);
    for s in 0..segments {
        let idx = [s as isize - 1, s as isize, s as isize + 1, s as isize + 2].map(at);
        let p = idx.map(|i| pos[i]);
        let mut q = idx.map(|i| rot[i]);
        for j in [0, 2, 3] {
            if q[j].dot(q[1]) < 0.0 {
                q[j] = -q[j];
            }
        }
        for f in 0..n {
            if f == 0 {
                out.push(keys[idx[1]]);
                continue;
            }
            let t = f as f64 / n as f64;
            let w = catmull_rom_weights(t);
            let c = w[0] * p[0] + w[1] * p[1] + w[2] * p[2] + w[3] * p[3];
            let qv = w[0] * DVec4::from(q[0]) + w[1] * DVec4::from(q[1]) + w[2] * DVec4::from(q[2]) + w[3] * DVec4::from(q[3]);
            let r = DMat3::from_quat(DQuat::from_vec4(qv).normalize());
            out.push(DMat4::from_cols(r.x_axis.extend(0.0), r.y_axis.extend(0.0), r.z_axis.extend(0.0), c.extend(1.0)));
        }
    }
    if !cycle {
        out.push(keys[k - 1]);
    }
    out
}

/// Uniform Catmull-Rom basis weights of the four control points at `t` in [0, 1] (the curve
/// runs from the second point at `t = 0` to the third at `t = 1`).
fn catmull_rom_weights(t: f64) -> [f64; 4] {
    let (t2, t3) = (t * t, t * t * t);
    [0.5 * (-t3 + 2.0 * t2 - t), 0.5 * (3.0 * t3 - 5.0 * t2 + 2.0), 0.5 * (-3.0 * t3 + 4.0 * t2 + t), 0.5 * (t3 - t2)]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Camera;

    fn keys() -> Vec<DMat4> {
        [DVec3::new(3.0, 1.0, 0.0), DVec3::new(0.0, 1.5, 3.0), DVec3::new(-3.0, 0.5, 0.0), DVec3::new(0.0, 2.0, -3.0)]
            .iter()
            .map(|&eye| Camera::look_at(eye, DVec3::ZERO, DVec3::Y))
            .collect()
    }

    #[test]
    fn the_path_passes_through_every_keyframe_exactly() {
        let keys = keys();
        for cycle in [false, true] {
            let path = interpolate_poses(&keys, 5, cycle);
            assert_eq!(path.len(), if cycle { 20 } else { 16 });
            for (i, key) in keys.iter().enumerate() {
                assert_eq!(path[i * 5], *key, "keyframe {i} (cycle {cycle})");
            }
        }
    }

    #[test]
    fn between_keys_the_poses_are_rigid_and_move_smoothly() {
        let keys = keys();
        let path = interpolate_poses(&keys, 8, true);
        for (i, m) in path.iter().enumerate() {
            Camera::new(crate::Intrinsics::from_fov_x(8, 8, 0.7), *m).unwrap_or_else(|e| panic!("frame {i}: {e}"));
        }
        // No step is far longer than the mean step: no jumps, also across keyframes.
        let steps: Vec<f64> = (0..path.len()).map(|i| (path[(i + 1) % path.len()].w_axis - path[i].w_axis).length()).collect();
        let mean = steps.iter().sum::<f64>() / steps.len() as f64;
        assert!(steps.iter().all(|s| *s < 2.0 * mean && *s > 0.2 * mean), "{steps:?}");
        // Midway between two keys the camera lies between them, off the chord (a curve).
        let mid = path[4].w_axis.truncate();
        assert!(mid.x > 0.0 && mid.z > 0.0 && mid.length() > (keys[0].w_axis.truncate() + keys[1].w_axis.truncate()).length() / 2.0);
    }

    #[test]
    fn one_key_is_a_path_of_one_frame() {
        let keys = keys();
        assert_eq!(interpolate_poses(&keys[..1], 10, false), vec![keys[0]]);
    }
}
