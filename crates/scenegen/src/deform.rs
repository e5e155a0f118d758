//! Skins and morph targets for [`crate::SceneBuilder`]: the data a skinned or morphed mesh
//! carries, its checks, and the default pose it shows (glTF 2.0 §3.7.2.2, §3.7.3).
//!
//! - A [`Skin`] names its joint nodes, one inverse bind matrix per joint, and per vertex up to
//!   four `(joint, weight)` influences (JOINTS_0 as UNSIGNED_BYTE, WEIGHTS_0 as FLOAT).
//!   The posed vertex is `Σᵢ wᵢ · W(jointᵢ) · IBMᵢ · p` with the weights divided by their sum;
//!   the mesh node's own transform does not apply.
//! - A [`MorphTarget`] holds per-vertex POSITION (and optionally NORMAL) displacements; the
//!   default weights go into `mesh.weights`, a node may override them. A target without normal
//!   displacements and with fewer than half its vertices displaced is written as a sparse
//!   accessor.

use glam::{Mat4, Vec3};

use crate::SceneGenError;
use crate::mesh::Mesh;

/// A skin: joints (node indices from [`crate::SceneBuilder::add_joint`]), their inverse bind
/// matrices and the per-vertex influences.
#[derive(Clone, Debug, PartialEq)]
pub struct Skin {
    /// Joint nodes in joint-index order.
    pub joints: Vec<crate::NodeId>,
    /// One inverse bind matrix per joint: the inverse of the joint's world transform in the
    /// pose the mesh was modelled in.
    pub inverse_bind_matrices: Vec<Mat4>,
    /// Per vertex, four joint indices into `joints`.
    pub vertex_joints: Vec<[u8; 4]>,
    /// Per vertex, the four matching weights (finite, non-negative, not all zero).
    pub vertex_weights: Vec<[f32; 4]>,
}

/// One morph target: per-vertex displacements.
#[derive(Clone, Debug, PartialEq)]
pub struct MorphTarget {
    /// POSITION displacement per vertex.
    pub positions: Vec<Vec3>,
    /// NORMAL displacement per vertex, if any.
    pub normals: Option<Vec<Vec3>>,
}

impl MorphTarget {
    /// The vertices it displaces, when it is better written sparse (no normal displacements
    /// and fewer than half the vertices displaced).
    pub(crate) fn sparse_indices(&self) -> Option<Vec<u32>> {
        if self.normals.is_some() {
            return None;
        }
        let moved: Vec<u32> = (0..self.positions.len() as u32).filter(|&i| self.positions[i as usize] != Vec3::ZERO).collect();
        (moved.len() * 2 < self.positions.len()).then_some(moved)
    }
}

/// Checks a skin against its mesh (`joint_count` nodes exist is the caller's check).
pub(crate) fn check_skin(name: &str, mesh: &Mesh, skin: &Skin) -> Result<(), SceneGenError> {
    let bad = |reason: String| SceneGenError::InvalidMesh { name: name.to_string(), reason };
    let n = mesh.positions.len();
    if skin.joints.is_empty() || skin.inverse_bind_matrices.len() != skin.joints.len() {
        return Err(bad(format!("a skin needs joints and one inverse bind matrix per joint ({} joints, {} matrices)", skin.joints.len(), skin.inverse_bind_matrices.len())));
    }
    if skin.vertex_joints.len() != n || skin.vertex_weights.len() != n {
        return Err(bad(format!("{n} vertices but {} joint and {} weight entries", skin.vertex_joints.len(), skin.vertex_weights.len())));
    }
    if skin.inverse_bind_matrices.iter().any(|m| !m.is_finite() || m.determinant() == 0.0) {
        return Err(bad("inverse bind matrices must be finite and invertible".into()));
    }
    for (i, (j, w)) in skin.vertex_joints.iter().zip(&skin.vertex_weights).enumerate() {
        if j.iter().any(|&j| usize::from(j) >= skin.joints.len()) {
            return Err(bad(format!("vertex {i}: joint index beyond the {} joints", skin.joints.len())));
        }
        if w.iter().any(|w| !w.is_finite() || *w < 0.0) || w.iter().sum::<f32>() <= 0.0 {
            return Err(bad(format!("vertex {i}: weights must be finite, non-negative and not all zero")));
        }
    }
    Ok(())
}

/// Checks morph targets and their default weights against the mesh.
pub(crate) fn check_morph(name: &str, mesh: &Mesh, targets: &[MorphTarget], weights: &[f32]) -> Result<(), SceneGenError> {
    let bad = |reason: String| SceneGenError::InvalidMesh { name: name.to_string(), reason };
    if targets.is_empty() || weights.len() != targets.len() {
        return Err(bad(format!("{} morph targets with {} weights (need at least one, one weight each)", targets.len(), weights.len())));
    }
    let n = mesh.positions.len();
    for (t, target) in targets.iter().enumerate() {
        let lens_ok = target.positions.len() == n && target.normals.as_ref().is_none_or(|v| v.len() == n);
        let finite = target.positions.iter().chain(target.normals.iter().flatten()).all(|v| v.is_finite());
        if !lens_ok || !finite {
            return Err(bad(format!("morph target {t}: needs {n} finite displacements")));
        }
    }
    if weights.iter().any(|w| !w.is_finite()) {
        return Err(bad("morph weights must be finite".into()));
    }
    Ok(())
}

/// Positions after the morph targets at `weights`.
pub(crate) fn morphed_positions(mesh: &Mesh, targets: &[MorphTarget], weights: &[f32]) -> Vec<Vec3> {
    let mut out = mesh.positions.clone();
    for (target, &w) in targets.iter().zip(weights) {
        for (p, d) in out.iter_mut().zip(&target.positions) {
            *p += w * *d;
        }
    }
    out
}

/// World positions of skinned `positions` given each joint's world matrix.
pub(crate) fn skinned_positions(positions: &[Vec3], skin: &Skin, joint_world: &[Mat4]) -> Vec<Vec3> {
    let joints: Vec<Mat4> = joint_world.iter().zip(&skin.inverse_bind_matrices).map(|(w, ibm)| *w * *ibm).collect();
    positions
        .iter()
        .enumerate()
        .map(|(i, &p)| {
            let (js, ws) = (skin.vertex_joints[i], skin.vertex_weights[i]);
            let sum: f32 = ws.iter().sum();
            js.iter().zip(ws).fold(Vec3::ZERO, |acc, (&j, w)| acc + (w / sum) * joints[usize::from(j)].transform_point3(p))
        })
        .collect()
}
