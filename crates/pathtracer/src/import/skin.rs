//! Skins and morph targets at the default pose (glTF 2.0 §3.7.2.2 "Morph Targets", §3.7.3
//! "Skins"): the importer bakes the pose the file shows without animation.
//!
//! - **Morph targets** come first. With weights `wₜ` (`node.weights`, else `mesh.weights`,
//!   else 0) a vertex attribute is `a = a₀ + Σₜ wₜ·Δaₜ` for POSITION, NORMAL and TANGENT (xyz;
//!   the handedness `w` is kept). Displacement accessors may be sparse. Every primitive of a
//!   mesh has the same number of targets, and a weights array has one weight per target.
//! - **Skins** then place the morphed vertex. Joint `j`'s matrix is `Jⱼ = W(jointⱼ) · IBMⱼ`,
//!   the joint node's world transform times its inverse bind matrix (identity when
//!   `inverseBindMatrices` is absent); the vertex's skin matrix is
//!   `S = Σᵢ wᵢ · J[jᵢ]` over the influences of JOINTS_0/WEIGHTS_0 and JOINTS_1/WEIGHTS_1
//!   (up to 8), with the weights divided by their sum when it is not 1. `S` takes the vertex
//!   straight to world space: the skinned mesh node's own transform is ignored. Normals go
//!   through `S`'s inverse transpose, tangents through `S`; a triangle's winding flips where
//!   the determinant of its corners' summed matrices is negative.
//!
//! Errors name the node, skin, mesh and primitive: a joint outside the scene, an inverse bind
//! matrix accessor with fewer matrices than joints, a matrix that is not finite or not
//! invertible, a joint index beyond the joint count, a weight that is negative or not finite,
//! a vertex whose weights sum to 0, targets whose count differs between primitives, a weights
//! array whose length differs from the target count.

use glam::{DMat3, DMat4};

use super::accessor::{self, AccessorData, Interpret};
use super::Importer;
use crate::error::PathTracerError;

/// One vertex transform and what normals and tangents need from it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Frame {
    /// Mesh space → world space (affine).
    pub m4: DMat4,
    /// Its linear part, for tangents.
    pub m3: DMat3,
    /// Normal matrix: the inverse transpose up to a positive factor (the cofactor matrix,
    /// negated when the determinant is negative; defined even for singular matrices).
    pub nmat: DMat3,
    /// The determinant is negative: the winding and the tangent handedness flip.
    pub flip: bool,
}

impl Frame {
    pub fn new(m4: DMat4) -> Self {
        let m3 = DMat3::from_mat4(m4);
        let flip = m3.determinant() < 0.0;
        let cof = DMat3::from_cols(m3.y_axis.cross(m3.z_axis), m3.z_axis.cross(m3.x_axis), m3.x_axis.cross(m3.y_axis));
        Self { m4, m3, nmat: if flip { -cof } else { cof }, flip }
    }
}

/// How a primitive's vertices reach world space.
pub(crate) enum Frames {
    /// Every vertex by the node's world transform.
    Rigid(Frame),
    /// One skin matrix per vertex.
    Skinned(Vec<Frame>),
}

impl Frames {
    /// Vertex `i`'s frame (the rigid frame, or the identity past the end, which cannot happen
    /// for range-checked indices).
    pub fn at(&self, i: usize) -> Frame {
        match self {
            Frames::Rigid(f) => *f,
            Frames::Skinned(v) => v.get(i).copied().unwrap_or_else(|| Frame::new(DMat4::IDENTITY)),
        }
    }

    /// Whether triangle `t`'s winding flips.
    pub fn flips(&self, t: [u32; 3]) -> bool {
        match self {
            Frames::Rigid(f) => f.flip,
            Frames::Skinned(_) => {
                let m = t.iter().fold(DMat3::ZERO, |acc, &k| acc + self.at(k as usize).m3);
                m.determinant() < 0.0
            }
        }
    }
}

/// A node's placement of its mesh: its world transform, or its skin's joint matrices.
pub(crate) enum Placement {
    Rigid(DMat4),
    /// `what` names the node and skin for messages; `joints` are `Jⱼ` in joint order.
    Skinned { what: String, joints: Vec<DMat4> },
}

/// `S = Σ wᵢ J[jᵢ]` for one vertex's `(joint, weight)` influences, weights normalised to sum
/// 1; the message says what is wrong with the influences.
pub(crate) fn skin_matrix(influences: &[(f64, f64)], joints: &[DMat4]) -> Result<DMat4, String> {
    let mut sum = 0.0;
    for &(j, w) in influences {
        if !(j >= 0.0 && j.fract() == 0.0 && j < joints.len() as f64) {
            return Err(format!("joint index {j} is out of range (the skin has {} joints)", joints.len()));
        }
        if !(w.is_finite() && w >= 0.0) {
            return Err(format!("weight {w} must be finite and non-negative"));
        }
        sum += w;
    }
    if sum <= 0.0 {
        return Err("weights sum to 0 (no joint influences it)".to_string());
    }
    let mut m = DMat4::ZERO;
    for &(j, w) in influences {
        if w == 0.0 {
            continue;
        }
        let w = if sum == 1.0 { w } else { w / sum };
        m += joints[j as usize] * w;
    }
    Ok(m)
}

/// Reads a JSON array of numbers in full `f64` precision.
fn f64_list(v: Option<&serde_json::Value>) -> Option<Vec<f64>> {
    v?.as_array()?.iter().map(serde_json::Value::as_f64).collect()
}

impl Importer<'_> {
    fn read_accessor(&self, index: usize, interpret: Interpret, what: &str) -> Result<AccessorData, PathTracerError> {
        let budget = self.options.max_vertices;
        accessor::read(self.doc.as_json(), &self.buffers, index, interpret, budget).map_err(|e| self.error(format!("{what}: {e}")))
    }

    /// The morph weights of `mesh` as placed by `node`: one per target (checked equal over
    /// the primitives), from `node.weights`, else `mesh.weights`, else zeros.
    pub(crate) fn morph_weights(&self, node: &gltf::Node<'_>, mesh: &gltf::Mesh<'_>) -> Result<Vec<f64>, PathTracerError> {
        let mesh_what = format!("mesh {}{}", mesh.index(), super::name_suffix(mesh.name()));
        let mut targets = None;
        for prim in mesh.primitives() {
            let count = prim.morph_targets().len();
            match targets {
                None => targets = Some(count),
                Some(t) if t != count => {
                    return Err(self.error(format!(
                        "{mesh_what}: primitive {} has {count} morph targets but primitive 0 has {t} (every primitive of a mesh has the same targets)",
                        prim.index()
                    )));
                }
                Some(_) => {}
            }
        }
        let targets = targets.unwrap_or(0);
        let raw_node = self.raw.get("nodes").and_then(|n| n.get(node.index())).and_then(|n| n.get("weights"));
        let raw_mesh = self.raw.get("meshes").and_then(|m| m.get(mesh.index())).and_then(|m| m.get("weights"));
        let node_what = format!("node {}{}", node.index(), super::name_suffix(node.name()));
        let (weights, owner) = match (node.weights(), mesh.weights()) {
            (Some(w), _) => (f64_list(raw_node).unwrap_or_else(|| w.iter().map(|&x| f64::from(x)).collect()), node_what),
            (None, Some(w)) => (f64_list(raw_mesh).unwrap_or_else(|| w.iter().map(|&x| f64::from(x)).collect()), mesh_what),
            (None, None) => return Ok(vec![0.0; targets]),
        };
        if weights.len() != targets {
            return Err(self.error(format!("{owner}: weights has {} entries but the mesh has {targets} morph targets", weights.len())));
        }
        if let Some(w) = weights.iter().find(|w| !w.is_finite()) {
            return Err(self.error(format!("{owner}: morph weight {w} is not finite")));
        }
        Ok(weights)
    }

    /// Adds `Σₜ wₜ·Δₜ` to the primitive's positions, normals and tangents (xyz).
    pub(crate) fn apply_morph(
        &self,
        prim: &gltf::Primitive<'_>,
        what: &str,
        weights: &[f64],
        positions: &mut AccessorData,
        mut normals: Option<&mut AccessorData>,
        mut tangents: Option<&mut AccessorData>,
    ) -> Result<(), PathTracerError> {
        for (t, target) in prim.morph_targets().enumerate() {
            let w = weights.get(t).copied().unwrap_or(0.0);
            if w == 0.0 {
                continue;
            }
            let parts: [(&str, Option<gltf::Accessor<'_>>, Option<&mut AccessorData>); 3] = [
                ("POSITION", target.positions(), Some(&mut *positions)),
                ("NORMAL", target.normals(), normals.as_deref_mut()),
                ("TANGENT", target.tangents(), tangents.as_deref_mut()),
            ];
            for (name, acc, base) in parts {
                let (Some(acc), Some(base)) = (acc, base) else { continue };
                let twhat = format!("{what} morph target {t} {name}");
                let delta = self.read_accessor(acc.index(), Interpret::Attribute, &twhat)?;
                if delta.dims != 3 || delta.len() != base.len() {
                    return Err(self.error(format!(
                        "{twhat}: {} elements of {} components, expected {} of 3",
                        delta.len(),
                        delta.dims,
                        base.len()
                    )));
                }
                for i in 0..base.len() {
                    for k in 0..3 {
                        let d = delta.values[i * 3 + k];
                        if let Some(v) = base.values.get_mut(i * base.dims + k) {
                            *v += w * d;
                        }
                    }
                }
            }
        }
        Ok(())
    }

    /// Joint matrices `Jⱼ = W(jointⱼ) · IBMⱼ` of `skin` as used by `node`; `world_of` holds
    /// the world transform of every node of the imported scene.
    pub(crate) fn joint_matrices(
        &self,
        node: &gltf::Node<'_>,
        skin: &gltf::Skin<'_>,
        world_of: &[Option<DMat4>],
    ) -> Result<Placement, PathTracerError> {
        let what = format!(
            "node {}{} skin {}{}",
            node.index(),
            super::name_suffix(node.name()),
            skin.index(),
            super::name_suffix(skin.name())
        );
        let joints: Vec<usize> = skin.joints().map(|j| j.index()).collect();
        if joints.is_empty() {
            return Err(self.error(format!("{what}: has no joints")));
        }
        let ibms = match skin.inverse_bind_matrices() {
            Some(acc) => {
                let data = self.read_accessor(acc.index(), Interpret::Matrix4, &format!("{what} inverseBindMatrices"))?;
                if data.len() < joints.len() {
                    return Err(self.error(format!(
                        "{what}: inverseBindMatrices holds {} matrices but the skin has {} joints",
                        data.len(),
                        joints.len()
                    )));
                }
                Some(data)
            }
            None => None,
        };
        let mut out = Vec::with_capacity(joints.len());
        for (k, &j) in joints.iter().enumerate() {
            let world = world_of.get(j).copied().flatten().ok_or_else(|| {
                self.error(format!("{what}: joint {k} (node {j}) is not in the imported scene"))
            })?;
            let ibm = match &ibms {
                Some(d) => {
                    let m = DMat4::from_cols_slice(d.values.get(k * 16..k * 16 + 16).unwrap_or(&[0.0; 16]));
                    let m3 = DMat3::from_mat4(m);
                    let scale = m3.x_axis.length() * m3.y_axis.length() * m3.z_axis.length();
                    if !m.is_finite() {
                        return Err(self.error(format!("{what}: inverse bind matrix {k} is not finite")));
                    }
                    if !(m3.determinant().abs() > 1e-12 * scale && scale > 0.0) {
                        return Err(self.error(format!("{what}: inverse bind matrix {k} is not invertible (singular)")));
                    }
                    m
                }
                None => DMat4::IDENTITY,
            };
            let jm = world * ibm;
            if !jm.is_finite() {
                return Err(self.error(format!("{what}: joint matrix {k} is not finite")));
            }
            out.push(jm);
        }
        Ok(Placement::Skinned { what, joints: out })
    }

    /// The per-vertex skin frames of a primitive with `n` vertices from its JOINTS_k /
    /// WEIGHTS_k sets.
    pub(crate) fn skin_frames(
        &self,
        prim: &gltf::Primitive<'_>,
        what: &str,
        skin_what: &str,
        joints: &[DMat4],
        n: usize,
    ) -> Result<Vec<Frame>, PathTracerError> {
        let mut sets = Vec::new();
        for set in 0..2u32 {
            let (j, w) = (prim.get(&gltf::Semantic::Joints(set)), prim.get(&gltf::Semantic::Weights(set)));
            match (j, w) {
                (Some(j), Some(w)) => {
                    let jd = self.read_accessor(j.index(), Interpret::Attribute, &format!("{what} JOINTS_{set}"))?;
                    let wd = self.read_accessor(w.index(), Interpret::Attribute, &format!("{what} WEIGHTS_{set}"))?;
                    for (name, d) in [("JOINTS", &jd), ("WEIGHTS", &wd)] {
                        if d.dims != 4 || d.len() != n {
                            return Err(self.error(format!(
                                "{what} {name}_{set}: {} elements of {} components, expected {n} of 4",
                                d.len(),
                                d.dims
                            )));
                        }
                    }
                    sets.push((jd, wd));
                }
                (None, None) => {}
                _ => return Err(self.error(format!("{what}: JOINTS_{set} and WEIGHTS_{set} must come together"))),
            }
        }
        if sets.is_empty() {
            return Err(self.error(format!("{what}: placed by {skin_what} but has no JOINTS_0 / WEIGHTS_0")));
        }
        let mut frames = Vec::with_capacity(n);
        let mut influences = Vec::with_capacity(8);
        for i in 0..n {
            influences.clear();
            for (jd, wd) in &sets {
                let (js, ws) = (jd.get::<4>(i), wd.get::<4>(i));
                influences.extend(js.into_iter().zip(ws));
            }
            let m = skin_matrix(&influences, joints)
                .map_err(|e| self.error(format!("{what} (skinned by {skin_what}): vertex {i}: {e}")))?;
            frames.push(Frame::new(m));
        }
        Ok(frames)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    #[test]
    fn skin_matrix_blends_normalised_weights() {
        let a = DMat4::from_translation(DVec3::new(2.0, 0.0, 0.0));
        let b = DMat4::from_translation(DVec3::new(0.0, 4.0, 0.0));
        // Weights 1 and 3 sum to 4: normalised to 0.25 and 0.75.
        let m = skin_matrix(&[(0.0, 1.0), (1.0, 3.0), (0.0, 0.0)], &[a, b]).unwrap();
        assert_eq!(m.transform_point3(DVec3::ZERO), DVec3::new(0.5, 3.0, 0.0));
        assert_eq!(m, a * 0.25 + b * 0.75);
        // One full influence is the joint matrix exactly.
        assert_eq!(skin_matrix(&[(1.0, 1.0), (0.0, 0.0)], &[a, b]).unwrap(), b);
        assert!(skin_matrix(&[(2.0, 1.0)], &[a, b]).unwrap_err().contains("joint index 2 is out of range (the skin has 2 joints)"));
        assert!(skin_matrix(&[(0.0, -0.5), (1.0, 1.5)], &[a, b]).unwrap_err().contains("weight -0.5"));
        assert!(skin_matrix(&[(0.0, f64::NAN)], &[a, b]).unwrap_err().contains("NaN"));
        assert!(skin_matrix(&[(0.0, 0.0)], &[a, b]).unwrap_err().contains("sum to 0"));
    }

    #[test]
    fn frame_normal_matrix_is_the_inverse_transpose_direction() {
        let m = DMat4::from_scale(DVec3::new(2.0, 1.0, -1.0));
        let f = Frame::new(m);
        assert!(f.flip);
        let n = f.nmat * DVec3::new(1.0, 1.0, 0.0).normalize();
        let expected = DMat3::from_mat4(m).inverse().transpose() * DVec3::new(1.0, 1.0, 0.0).normalize();
        assert!((n.normalize() - expected.normalize()).length() < 1e-15);
    }
}
