//! The node hierarchy: transforms in `f64`, primitives baked into world-space triangles,
//! cameras and punctual lights placed by their nodes, and the final [`Scene`].

use std::f64::consts::{FRAC_PI_2, PI};
use std::rc::Rc;

use glam::{DMat4, DQuat, DVec3, DVec4, Vec2, Vec3, Vec4};
use gltf::camera::Projection;
use gltf::khr_lights_punctual::Kind;
use gltf::mesh::Mode;
use gltf::Semantic;
use serde_json::Value;

use super::accessor::{self, AccessorData, Interpret};
use super::skin::{Frame, Frames, Placement};
use super::{name_suffix, Importer, WorldLight};
use crate::error::PathTracerError;
use crate::scene::{Aabb, Light, Material, Mesh, Scene, SceneCamera};

/// Triangles of a primitive from its (already range-checked) vertex index list, per the glTF
/// spec's formulas: TRIANGLES `(v₃ᵢ, v₃ᵢ₊₁, v₃ᵢ₊₂)`; TRIANGLE_STRIP
/// `pᵢ = (vᵢ, v_{i+(1+i%2)}, v_{i+(2−i%2)})`; TRIANGLE_FAN `pᵢ = (vᵢ₊₁, vᵢ₊₂, v₀)`.
/// Other modes give no triangles.
pub(crate) fn assemble(mode: Mode, idx: &[u32]) -> Vec<[u32; 3]> {
    let n = idx.len();
    let at = |i: usize| idx.get(i).copied().unwrap_or(0);
    match mode {
        Mode::Triangles => idx.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        Mode::TriangleStrip => {
            (0..n.saturating_sub(2)).map(|i| [at(i), at(i + 1 + i % 2), at(i + 2 - i % 2)]).collect()
        }
        Mode::TriangleFan => (0..n.saturating_sub(2)).map(|i| [at(i + 1), at(i + 2), at(0)]).collect(),
        Mode::Points | Mode::Lines | Mode::LineLoop | Mode::LineStrip => Vec::new(),
    }
}

/// Reads `N` numbers from a JSON array of exactly `N` numbers.
fn f64_array<const N: usize>(v: Option<&Value>) -> Option<[f64; N]> {
    let a = v?.as_array()?;
    if a.len() != N {
        return None;
    }
    let mut out = [0.0; N];
    for (o, x) in out.iter_mut().zip(a) {
        *o = x.as_f64()?;
    }
    Some(out)
}

/// The rigid part of a camera's world transform: −Z (view) and +Y (up) kept, scale and shear
/// removed by Gram–Schmidt, a right-handed basis rebuilt. `None` if degenerate.
pub(crate) fn rigid_pose(world: &DMat4) -> Option<DMat4> {
    let z = world.z_axis.truncate().try_normalize()?;
    let y_raw = world.y_axis.truncate();
    let y = (y_raw - z * y_raw.dot(z)).try_normalize()?;
    let x = y.cross(z);
    Some(DMat4::from_cols(x.extend(0.0), y.extend(0.0), z.extend(0.0), world.w_axis))
}

impl Importer<'_> {
    /// The root nodes of the scene chosen by [`super::ImportOptions::scene`] or the spec.
    fn root_nodes(&self) -> Result<Vec<usize>, PathTracerError> {
        let doc = &self.doc;
        let scene = match self.options.scene {
            Some(i) => Some(doc.scenes().nth(i).ok_or_else(|| {
                self.error(format!("scene {i} does not exist (the file has {} scenes)", doc.as_json().scenes.len()))
            })?),
            None => doc.default_scene().or_else(|| doc.scenes().next()),
        };
        Ok(match scene {
            Some(scene) => scene.nodes().map(|n| n.index()).collect(),
            None => {
                let nodes = &doc.as_json().nodes;
                let mut has_parent = vec![false; nodes.len()];
                for node in nodes {
                    for child in node.children.iter().flatten() {
                        if let Some(flag) = has_parent.get_mut(child.value()) {
                            *flag = true;
                        }
                    }
                }
                (0..nodes.len()).filter(|&i| !has_parent.get(i).copied().unwrap_or(true)).collect()
            }
        })
    }

    /// A node's local transform in `f64`, read from the raw JSON so no precision is lost to
    /// the gltf crate's `f32` (falling back to those values if the raw JSON is unavailable).
    fn node_local(&self, node: &gltf::Node<'_>) -> Result<DMat4, PathTracerError> {
        let raw = self.raw.get("nodes").and_then(|n| n.get(node.index()));
        let what = || format!("node {}{}", node.index(), name_suffix(node.name()));
        let (t, r, s) = match raw {
            Some(raw) => {
                if let Some(matrix) = raw.get("matrix") {
                    // glTF 2.0 §5.25: a node has either a matrix or TRS properties, never both
                    // (which would win is undefined), and a matrix is 16 numbers.
                    let trs: Vec<&str> = ["translation", "rotation", "scale"].into_iter().filter(|k| raw.get(*k).is_some()).collect();
                    if !trs.is_empty() {
                        return Err(self.error(format!("{}: has both a matrix and {} (glTF allows one or the other)", what(), trs.join(", "))));
                    }
                    let Some(m) = f64_array::<16>(Some(matrix)) else {
                        return Err(self.error(format!("{}: matrix must be 16 numbers", what())));
                    };
                    return Ok(DMat4::from_cols_array(&m));
                }
                (
                    f64_array::<3>(raw.get("translation")).unwrap_or([0.0; 3]),
                    f64_array::<4>(raw.get("rotation")).unwrap_or([0.0, 0.0, 0.0, 1.0]),
                    f64_array::<3>(raw.get("scale")).unwrap_or([1.0; 3]),
                )
            }
            None => match node.transform() {
                gltf::scene::Transform::Matrix { matrix } => {
                    return Ok(DMat4::from_cols_array_2d(&matrix.map(|c| c.map(f64::from))));
                }
                gltf::scene::Transform::Decomposed { translation, rotation, scale } => {
                    (translation.map(f64::from), rotation.map(f64::from), scale.map(f64::from))
                }
            },
        };
        let q = DQuat::from_array(r);
        let len = q.length();
        if !(len.is_finite() && len > 0.0) {
            return Err(self.error(format!("{}: rotation {r:?} is not a valid quaternion", what())));
        }
        Ok(DMat4::from_scale_rotation_translation(DVec3::from(s), q / len, DVec3::from(t)))
    }

    /// Walks the scene's node trees depth-first, computing every node's world transform, then
    /// bakes meshes (placed rigidly or by their skins), cameras and lights in that order.
    pub(super) fn traverse(&mut self) -> Result<(), PathTracerError> {
        let doc = Rc::clone(&self.doc);
        let nodes: Vec<gltf::Node<'_>> = doc.nodes().collect();
        let mut world_of: Vec<Option<DMat4>> = vec![None; nodes.len()];
        let mut order = Vec::new();
        let mut stack: Vec<(usize, DMat4)> = self.root_nodes()?.into_iter().rev().map(|r| (r, DMat4::IDENTITY)).collect();
        while let Some((index, parent)) = stack.pop() {
            let node = nodes.get(index).ok_or_else(|| self.error(format!("node {index} does not exist")))?;
            let what = format!("node {index}{}", name_suffix(node.name()));
            match world_of.get(index) {
                Some(None) => {}
                _ => {
                    return Err(self.error(format!(
                        "{what} is reached twice: the node hierarchy must be a set of disjoint trees (a cycle, two parents, or a root listed twice)"
                    )));
                }
            }
            let world = parent * self.node_local(node)?;
            if !world.is_finite() {
                return Err(self.error(format!("{what}: world transform is not finite")));
            }
            world_of[index] = Some(world);
            order.push(index);
            for child in node.children().collect::<Vec<_>>().into_iter().rev() {
                stack.push((child.index(), world));
            }
        }
        for index in order {
            let (Some(node), Some(Some(world))) = (nodes.get(index), world_of.get(index).copied()) else { continue };
            let what = format!("node {index}{}", name_suffix(node.name()));
            if let Some(mesh) = node.mesh() {
                let weights = self.morph_weights(node, &mesh)?;
                let placement = match node.skin() {
                    Some(skin) => self.joint_matrices(node, &skin, &world_of)?,
                    None => Placement::Rigid(world),
                };
                let first = self.geometry.indices.len();
                for prim in mesh.primitives() {
                    self.add_primitive(&mesh, &prim, &placement, &weights)?;
                }
                let triangles = self.geometry.indices.len() - first;
                if triangles > 0 {
                    self.objects.push(crate::scene::SceneObject {
                        node: index,
                        name: node.name().map(str::to_string),
                        mesh: mesh.index(),
                        mesh_name: mesh.name().map(str::to_string),
                        first_triangle: first as u32,
                        triangles: triangles as u32,
                    });
                }
            }
            if let Some(camera) = node.camera() {
                self.add_camera(node, &camera, &world)?;
            }
            if let Some(light) = node.light() {
                self.add_light(&what, &light, &world)?;
            }
        }
        Ok(())
    }

    fn read_attribute(
        &self,
        prim: &gltf::Primitive<'_>,
        semantic: Semantic,
        allowed_dims: &[usize],
        what: &str,
    ) -> Result<Option<AccessorData>, PathTracerError> {
        let Some(acc) = prim.get(&semantic) else { return Ok(None) };
        let budget = self.options.max_vertices.saturating_sub(self.geometry.positions.len());
        let data = accessor::read(self.doc.as_json(), &self.buffers, acc.index(), Interpret::Attribute, budget)
            .map_err(|e| self.error(format!("{what} {}: {e}", semantic.to_string())))?;
        if !allowed_dims.contains(&data.dims) {
            return Err(self.error(format!("{what} {}: {} components per element, expected {allowed_dims:?}", semantic.to_string(), data.dims)));
        }
        Ok(Some(data))
    }

    // Long by design: one glTF primitive is read attribute by attribute (mode, indices,
    // positions, normals, tangents, UVs, colours, material), each with its own validation
    // message naming the JSON path; the steps share the primitive's counts and transforms.
    /// Bakes one primitive into world-space triangles: morphed by `weights`, then placed.
    fn add_primitive(
        &mut self,
        mesh: &gltf::Mesh<'_>,
        prim: &gltf::Primitive<'_>,
        placement: &Placement,
        weights: &[f64],
    ) -> Result<(), PathTracerError> {
        let what = format!("mesh {}{} primitive {}", mesh.index(), name_suffix(mesh.name()), prim.index());
        let mode = prim.mode();
        if !matches!(mode, Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
            self.warn(format!("{what}: mode {mode:?} is not a surface; skipped"));
            return Ok(());
        }
        let mut positions = self
            .read_attribute(prim, Semantic::Positions, &[3], &what)?
            .ok_or_else(|| self.error(format!("{what}: no POSITION attribute")))?;
        let n = positions.len();
        if let Some(i) = positions.values.iter().position(|v| !v.is_finite()) {
            return Err(self.error(format!("{what}: POSITION of vertex {} is not finite (NaN or infinite)", i / 3)));
        }
        let mut normals = self.read_attribute(prim, Semantic::Normals, &[3], &what)?;
        let mut tangents = self.read_attribute(prim, Semantic::Tangents, &[4], &what)?;
        let uv0 = self.read_attribute(prim, Semantic::TexCoords(0), &[2], &what)?;
        let uv1 = self.read_attribute(prim, Semantic::TexCoords(1), &[2], &what)?;
        let colors = self.read_attribute(prim, Semantic::Colors(0), &[3, 4], &what)?;
        for (name, attr) in [("NORMAL", &normals), ("TANGENT", &tangents), ("TEXCOORD_0", &uv0), ("TEXCOORD_1", &uv1), ("COLOR_0", &colors)] {
            if let Some(a) = attr
                && a.len() != n
            {
                return Err(self.error(format!("{what}: {name} has {} elements but POSITION has {n}", a.len())));
            }
        }

        let index_list: Vec<u32> = match prim.indices() {
            Some(acc) => {
                let budget = self.options.max_triangles.saturating_mul(3).saturating_add(2);
                let data = accessor::read(self.doc.as_json(), &self.buffers, acc.index(), Interpret::Indices, budget)
                    .map_err(|e| self.error(format!("{what} indices: {e}")))?;
                let mut list = Vec::with_capacity(data.values.len());
                for (k, &v) in data.values.iter().enumerate() {
                    if v >= n as f64 {
                        return Err(self.error(format!(
                            "{what}: index {v} at position {k} is out of range (the primitive has {n} vertices)"
                        )));
                    }
                    list.push(v as u32);
                }
                list
            }
            None => {
                let n32 = u32::try_from(n).map_err(|_| self.error(format!("{what}: too many vertices")))?;
                (0..n32).collect()
            }
        };
        if mode == Mode::Triangles && !index_list.len().is_multiple_of(3) {
            self.warn(format!("{what}: {} indices is not a multiple of 3; the last {} ignored", index_list.len(), index_list.len() % 3));
        }
        let triangles = assemble(mode, &index_list);
        if self.geometry.indices.len().saturating_add(triangles.len()) > self.options.max_triangles {
            return Err(self.error(format!("{what}: the scene exceeds the import limit of {} triangles", self.options.max_triangles)));
        }

        self.apply_morph(prim, &what, weights, &mut positions, normals.as_mut(), tangents.as_mut())?;
        if let Some(i) = positions.values.iter().position(|v| !v.is_finite()) {
            return Err(self.error(format!("{what}: the morphed POSITION of vertex {} is not finite", i / 3)));
        }
        let frames = match placement {
            Placement::Rigid(world) => Frames::Rigid(Frame::new(*world)),
            Placement::Skinned { what: skin_what, joints } => Frames::Skinned(self.skin_frames(prim, &what, skin_what, joints, n)?),
        };

        let material = match prim.material().index() {
            Some(i) => u32::try_from(i).map_err(|_| self.error("too many materials"))?,
            None => {
                self.uses_default_material = true;
                u32::try_from(self.doc.as_json().materials.len()).map_err(|_| self.error("too many materials"))?
            }
        };

        // Per-vertex attributes in world space.
        let wpos: Vec<DVec3> = (0..n).map(|i| frames.at(i).m4.transform_point3(DVec3::from(positions.get::<3>(i)))).collect();
        if wpos.iter().any(|p| !p.is_finite()) {
            return Err(self.error(format!("{what}: a world-space position overflows to infinity")));
        }
        let vnormal = |i: usize| -> Option<Vec3> {
            let nrm = frames.at(i).nmat * DVec3::from(normals.as_ref()?.get::<3>(i));
            nrm.try_normalize().map(|v| v.as_vec3())
        };
        let vtangent = |i: usize| -> Vec4 {
            let Some(t) = &tangents else { return Vec4::ZERO };
            let [x, y, z, w] = t.get::<4>(i);
            let frame = frames.at(i);
            let dir = (frame.m3 * DVec3::new(x, y, z)).try_normalize().unwrap_or(DVec3::ZERO);
            let sign = if w < 0.0 { -1.0 } else { 1.0 } * if frame.flip { -1.0 } else { 1.0 };
            DVec4::new(dir.x, dir.y, dir.z, sign).as_vec4()
        };
        let uv = |a: &Option<AccessorData>, i: usize| -> Vec2 {
            a.as_ref().map_or(Vec2::ZERO, |a| {
                let v = DVec3::new(a.get::<2>(i)[0], a.get::<2>(i)[1], 0.0).as_vec3();
                if v.is_finite() { Vec2::new(v.x, v.y) } else { Vec2::ZERO }
            })
        };
        let color = |i: usize| -> Vec4 {
            colors.as_ref().map_or(Vec4::ONE, |c| {
                let [r, g, b, a] = c.get::<4>(i);
                let v = DVec4::new(r, g, b, if c.dims == 3 { 1.0 } else { a }).as_vec4();
                if v.is_finite() { v } else { Vec4::ONE }
            })
        };
        let face_normal = |t: [u32; 3]| -> DVec3 {
            let p = |k: u32| wpos.get(k as usize).copied().unwrap_or(DVec3::ZERO);
            (p(t[1]) - p(t[0])).cross(p(t[2]) - p(t[0]))
        };
        let oriented: Vec<[u32; 3]> = triangles.iter().map(|&[a, b, c]| if frames.flips([a, b, c]) { [a, c, b] } else { [a, b, c] }).collect();

        let new_vertices = if normals.is_some() { n } else { oriented.len() * 3 };
        let total = self.geometry.positions.len().saturating_add(new_vertices);
        if total > self.options.max_vertices || total > u32::MAX as usize {
            return Err(self.error(format!("{what}: the scene exceeds the import limit of {} vertices", self.options.max_vertices)));
        }
        let base = self.geometry.positions.len() as u32;
        let g = &mut self.geometry;
        if normals.is_some() {
            // Shared vertices with the given normals; a zero or non-finite normal is replaced
            // by the area-weighted normal of the triangles using the vertex.
            let mut bad: Vec<Option<DVec3>> = Vec::new();
            for i in 0..n {
                g.positions.push(wpos[i]);
                match vnormal(i) {
                    Some(nrm) if nrm.is_finite() => g.normals.push(nrm),
                    _ => {
                        if bad.is_empty() {
                            bad = vec![None; n];
                        }
                        bad[i] = Some(DVec3::ZERO);
                        g.normals.push(Vec3::Z);
                    }
                }
                g.tangents.push(vtangent(i));
                g.uv0.push(uv(&uv0, i));
                g.uv1.push(uv(&uv1, i));
                g.colors.push(color(i));
            }
            for &t in &oriented {
                g.indices.push([base + t[0], base + t[1], base + t[2]]);
                g.material.push(material);
                if !bad.is_empty() {
                    let fnrm = face_normal(t);
                    for k in t {
                        if let Some(Some(acc)) = bad.get_mut(k as usize) {
                            *acc += fnrm;
                        }
                    }
                }
            }
            for (i, acc) in bad.iter().enumerate() {
                if let (Some(acc), Some(slot)) = (acc, g.normals.get_mut(base as usize + i)) {
                    *slot = acc.try_normalize().map_or(Vec3::Z, |v| v.as_vec3());
                }
            }
        } else {
            // Flat normals (glTF spec: required when NORMAL is absent): three unshared
            // vertices per triangle with the face's geometric normal.
            for (j, &t) in oriented.iter().enumerate() {
                let fnrm = face_normal(t).try_normalize().map_or(Vec3::Z, |v| v.as_vec3());
                for &k in &t {
                    let i = k as usize;
                    g.positions.push(wpos.get(i).copied().unwrap_or(DVec3::ZERO));
                    g.normals.push(fnrm);
                    g.tangents.push(vtangent(i));
                    g.uv0.push(uv(&uv0, i));
                    g.uv1.push(uv(&uv1, i));
                    g.colors.push(color(i));
                }
                let v = base + 3 * j as u32;
                g.indices.push([v, v + 1, v + 2]);
                g.material.push(material);
            }
        }
        Ok(())
    }

    fn add_camera(&mut self, node: &gltf::Node<'_>, camera: &gltf::Camera<'_>, world: &DMat4) -> Result<(), PathTracerError> {
        let what = format!("camera {}{} on node {}", camera.index(), name_suffix(camera.name()), node.index());
        let p = match camera.projection() {
            Projection::Perspective(p) => p,
            Projection::Orthographic(_) => {
                self.warn(format!("{what}: orthographic cameras are not supported; skipped"));
                return Ok(());
            }
        };
        let yfov = f64::from(p.yfov());
        if !(yfov.is_finite() && yfov > 0.0 && yfov < PI) {
            return Err(self.error(format!("{what}: yfov {yfov} must be finite and in (0, π) radians")));
        }
        let znear = f64::from(p.znear());
        if !(znear.is_finite() && znear > 0.0) {
            return Err(self.error(format!("{what}: znear {znear} must be finite and positive")));
        }
        let zfar = match p.zfar().map(f64::from) {
            Some(z) if z.is_nan() || z <= znear => return Err(self.error(format!("{what}: zfar {z} must exceed znear {znear}"))),
            Some(z) if z.is_finite() => Some(z),
            _ => None,
        };
        let aspect_ratio = match p.aspect_ratio().map(f64::from) {
            Some(a) if a.is_finite() && a > 0.0 => Some(a),
            Some(a) => {
                self.warn(format!("{what}: aspectRatio {a} ignored (must be positive)"));
                None
            }
            None => None,
        };
        let c2w = rigid_pose(world).ok_or_else(|| self.error(format!("{what}: the node's transform is degenerate")))?;
        self.cameras.push(SceneCamera {
            name: node.name().or(camera.name()).map(str::to_string),
            c2w,
            yfov,
            aspect_ratio,
            znear,
            zfar,
        });
        Ok(())
    }

    fn add_light(&mut self, what: &str, light: &gltf::khr_lights_punctual::Light<'_>, world: &DMat4) -> Result<(), PathTracerError> {
        let what = format!("light {}{} on {what}", light.index(), name_suffix(light.name()));
        let color = Vec3::from(light.color());
        let intensity = light.intensity();
        if !(intensity.is_finite() && intensity >= 0.0 && color.is_finite() && color.min_element() >= 0.0) {
            return Err(self.error(format!("{what}: color {color} × intensity {intensity} must be finite and non-negative")));
        }
        let range = match light.range() {
            Some(r) if r.is_finite() && r > 0.0 => Some(r),
            Some(r) => {
                self.warn(format!("{what}: range {r} ignored (must be positive)"));
                None
            }
            None => None,
        };
        let mut kind = light.kind();
        if let Kind::Spot { inner_cone_angle, outer_cone_angle } = kind {
            let outer = if outer_cone_angle.is_finite() { outer_cone_angle.clamp(0.0, FRAC_PI_2 as f32) } else { FRAC_PI_2 as f32 / 2.0 };
            let inner = if inner_cone_angle.is_finite() { inner_cone_angle.clamp(0.0, outer) } else { 0.0 };
            if (inner, outer) != (inner_cone_angle, outer_cone_angle) {
                self.warn(format!(
                    "{what}: cone angles ({inner_cone_angle}, {outer_cone_angle}) outside 0 ≤ inner ≤ outer ≤ π/2; clamped to ({inner}, {outer})"
                ));
            }
            kind = Kind::Spot { inner_cone_angle: inner, outer_cone_angle: outer };
        }
        let direction = world.transform_vector3(DVec3::NEG_Z).try_normalize();
        let direction = match (&kind, direction) {
            (_, Some(d)) => d,
            (Kind::Point, None) => DVec3::NEG_Z,
            (_, None) => return Err(self.error(format!("{what}: the node's transform is degenerate (no direction)"))),
        };
        self.lights.push(WorldLight {
            kind,
            color_intensity: color * intensity,
            range,
            position: world.transform_point3(DVec3::ZERO),
            direction,
        });
        Ok(())
    }

    /// Moves everything into the local frame around the bounds' centre and builds the scene.
    pub(super) fn finish(mut self, name: &str) -> Result<Scene, PathTracerError> {
        let g = std::mem::take(&mut self.geometry);
        if g.indices.is_empty() {
            return Err(self.error("scene has no triangles"));
        }
        let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        for t in &g.indices {
            for &k in t {
                let p = g.positions.get(k as usize).copied().unwrap_or(DVec3::ZERO);
                lo = lo.min(p);
                hi = hi.max(p);
            }
        }
        let origin = 0.5 * (lo + hi);
        let positions: Vec<Vec3> = g.positions.iter().map(|&p| (p - origin).as_vec3()).collect();
        let mut bounds = Aabb::EMPTY;
        for t in &g.indices {
            for &k in t {
                bounds = bounds.union_point(positions.get(k as usize).copied().unwrap_or(Vec3::ZERO));
            }
        }
        if self.uses_default_material {
            self.materials.push(Material::gltf_default());
        }
        let local = |p: DVec3| (p - origin).as_vec3();
        let lights = self
            .lights
            .iter()
            .map(|l| match l.kind {
                Kind::Point => Light::Point { position: local(l.position), intensity: l.color_intensity, range: l.range },
                Kind::Spot { inner_cone_angle, outer_cone_angle } => Light::Spot {
                    position: local(l.position),
                    direction: l.direction.as_vec3(),
                    intensity: l.color_intensity,
                    inner_cone_angle,
                    outer_cone_angle,
                    range: l.range,
                },
                Kind::Directional => Light::Directional { direction: l.direction.as_vec3(), illuminance: l.color_intensity },
            })
            .collect();
        Ok(Scene {
            name: name.to_string(),
            origin,
            mesh: Mesh {
                positions,
                normals: g.normals,
                tangents: g.tangents,
                uv0: g.uv0,
                uv1: g.uv1,
                colors: g.colors,
                indices: g.indices,
                material: g.material,
            },
            materials: self.materials,
            textures: self.textures,
            lights,
            cameras: self.cameras,
            bounds,
            warnings: self.warnings,
            objects: self.objects,
        })
    }
}
