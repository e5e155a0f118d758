//! Camera rigs: where the train, val and test views of a dataset are placed.
//!
//! Three kinds, chosen by [`RigKind`]:
//! - [`RigKind::Sphere`]: cameras on a whole sphere around the scene's bounding sphere, looking
//!   at its centre, world +Y up (object-centric scenes floating in space).
//! - [`RigKind::Hemisphere`]: the same on the upper half (elevations 5°–85° above the bounds'
//!   centre), for objects standing on a ground, like the Blender synthetic scenes.
//! - [`RigKind::Gltf`]: forward-facing views around the scene's own glTF cameras, for scenes
//!   the cameras must stay inside (closed rooms, corridors): positions on a disc in the
//!   camera's image plane (radius [`GLTF_BASELINE`] × the median depth it sees, for parallax,
//!   at most [`GLTF_FREE_SPACE`] × the distance to the nearest wall), each looking at the
//!   point at that depth, turned by a small random yaw and pitch.
//!
//! [`RigKind::Auto`] resolves to `Gltf` when the scene has glTF cameras, else to `Hemisphere`
//! when it has a ground (see [`has_ground`]), else to `Sphere`.
//!
//! Sphere placement is a Fibonacci lattice per split (even coverage) with a per-split random
//! azimuth offset and per-view jitter inside each lattice cell, so train, val and test poses
//! differ. The radius keeps the bounding sphere inside the image for the chosen field of view
//! (see [`framing_distance`]); the hemisphere rig frames the content standing on the ground
//! rather than the whole ground (see [`framing_sphere`]). All randomness is counter-based, keyed by (seed, split, view,
//! dimension): a rig depends only on the scene and the [`RigConfig`].

use crate::PathTracerError;
use crate::geometry::{Ray, WatertightRay, intersect_triangle};
use crate::scene::Scene;
use dataset::{Camera, Intrinsics, SplitKind};
use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};

/// Horizontal field of view of the Blender synthetic scenes (radians), the default.
pub const DEFAULT_FOV_X: f64 = 0.691_111_207_008_361_8;

/// Distance margin over the tightest framing: the bounding sphere's image fills at most
/// `1 / FRAMING_MARGIN` of the half field of view (in sine).
pub const FRAMING_MARGIN: f64 = 1.05;

/// Lowest and highest camera elevation (radians) of the hemisphere rig.
const HEMISPHERE_ELEVATION: (f64, f64) = (5.0 * std::f64::consts::PI / 180.0, 85.0 * std::f64::consts::PI / 180.0);

/// Radius of the glTF rig's disc of camera positions around each glTF camera, as a fraction of
/// the median depth it sees (see `gltf_rig`): a baseline too short for the depth gives the
/// train views too little parallax to fix textureless walls (`docs/renderer.md`).
pub const GLTF_BASELINE: f64 = 0.1;

/// The disc stays within this fraction of the free distance around the glTF camera (the
/// nearest surface along 16 directions in its image plane), so no camera lands in or behind a
/// wall of a room or corridor.
pub const GLTF_FREE_SPACE: f64 = 0.5;

/// Largest rotation jitter of the glTF rig, as a fraction of the camera's vertical field of view.
const GLTF_ROTATION_JITTER: f64 = 0.04;

/// How cameras are placed around the scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RigKind {
    /// `gltf` if the scene has glTF cameras, else `hemisphere` if it has a ground, else `sphere`.
    Auto,
    /// Whole sphere around the bounds, looking at their centre.
    Sphere,
    /// Upper hemisphere around the bounds, looking at their centre.
    Hemisphere,
    /// Forward-facing views jittered around the scene's glTF cameras.
    Gltf,
    /// The frames of a camera path file (`render --camera-path`), as the train split.
    #[serde(rename = "camera-path")]
    CameraPath,
}

impl RigKind {
    /// The lowercase name (`auto`, `sphere`, `hemisphere`, `gltf`).
    pub fn name(self) -> &'static str {
        match self {
            RigKind::Auto => "auto",
            RigKind::Sphere => "sphere",
            RigKind::Hemisphere => "hemisphere",
            RigKind::Gltf => "gltf",
            RigKind::CameraPath => "camera-path",
        }
    }
}

impl std::str::FromStr for RigKind {
    type Err = PathTracerError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "auto" => Ok(RigKind::Auto),
            "sphere" => Ok(RigKind::Sphere),
            "hemisphere" => Ok(RigKind::Hemisphere),
            "gltf" => Ok(RigKind::Gltf),
            _ => Err(PathTracerError::Config(format!(
                "unknown rig '{s}' (expected auto, sphere, hemisphere or gltf)"
            ))),
        }
    }
}

/// Everything a rig depends on besides the scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RigConfig {
    /// Which rig.
    pub kind: RigKind,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Horizontal field of view (radians) of the sphere rigs; the glTF rig uses the first glTF
    /// camera's `yfov` instead.
    pub fov_x: f64,
    /// Number of train, val and test views.
    pub counts: [u32; 3],
    /// Seed of the jitter.
    pub seed: u64,
}

/// The placed cameras of every split. All cameras share one set of intrinsics.
#[derive(Clone, Debug, PartialEq)]
pub struct Rig {
    /// The rig actually used (never [`RigKind::Auto`]).
    pub kind: RigKind,
    /// Shared intrinsics.
    pub intrinsics: Intrinsics,
    /// Train, val and test cameras, in [`SplitKind::ALL`] order.
    pub splits: [Vec<Camera>; 3],
}

impl Rig {
    /// The cameras of one split.
    pub fn split(&self, split: SplitKind) -> &[Camera] {
        &self.splits[split_index(split)]
    }
    /// Every camera with its split and index within the split.
    pub fn views(&self) -> impl Iterator<Item = (SplitKind, u32, &Camera)> {
        SplitKind::ALL
            .into_iter()
            .flat_map(move |s| self.split(s).iter().enumerate().map(move |(k, c)| (s, k as u32, c)))
    }
}

/// Position of `split` in [`SplitKind::ALL`] (0 train, 1 val, 2 test).
pub fn split_index(split: SplitKind) -> usize {
    match split {
        SplitKind::Train => 0,
        SplitKind::Val => 1,
        SplitKind::Test => 2,
    }
}

/// The world-space bounding sphere (centre, radius) of the scene's bounds: the box's centre
/// and half its diagonal.
pub fn bounding_sphere(scene: &Scene) -> (DVec3, f64) {
    let c = scene.origin + scene.bounds.center().as_dvec3();
    (c, 0.5 * (scene.bounds.max - scene.bounds.min).as_dvec3().length())
}

/// The sphere a sphere or hemisphere rig frames (centre, radius). For the hemisphere rig it is
/// the bounding sphere of the scene's *content*: every triangle except the ground's (the
/// up-facing triangles at the bottom of the bounds that [`has_ground`] counts), so objects
/// standing on a large ground plane fill the frame as in the Blender synthetic scenes instead
/// of shrinking to the middle of a view of the whole plane; the ground is then partly out of
/// frame, as in a real capture. Falls back to [`bounding_sphere`] when nothing stands on the
/// ground, and for the sphere rig.
pub fn framing_sphere(scene: &Scene, kind: RigKind) -> (DVec3, f64) {
    if kind != RigKind::Hemisphere {
        return bounding_sphere(scene);
    }
    let mesh = &scene.mesh;
    let mut lo = DVec3::INFINITY;
    let mut hi = DVec3::NEG_INFINITY;
    for tri in &mesh.indices {
        let p = tri.map(|i| mesh.positions.get(i as usize).copied().unwrap_or(glam::Vec3::NAN));
        if p.iter().any(|v| !v.is_finite()) || is_ground_triangle(scene, &p) {
            continue;
        }
        for v in p {
            lo = lo.min(v.as_dvec3());
            hi = hi.max(v.as_dvec3());
        }
    }
    if !(lo.cmple(hi).all()) || (hi - lo).length() <= 0.0 {
        return bounding_sphere(scene);
    }
    (scene.origin + 0.5 * (lo + hi), 0.5 * (hi - lo).length())
}

/// Whether a triangle is part of a ground (see [`has_ground`]): near the bounds' bottom and
/// facing up within ~25°.
fn is_ground_triangle(scene: &Scene, p: &[glam::Vec3; 3]) -> bool {
    let b = scene.bounds;
    let size = b.max - b.min;
    let eps = (0.01 * size.y).max(0.001 * b.diagonal());
    if p.iter().any(|v| v.y.is_nan() || v.y - b.min.y > eps) {
        return false;
    }
    let n = (p[1] - p[0]).as_dvec3().cross((p[2] - p[0]).as_dvec3());
    let len = n.length();
    len > 0.0 && n.y / len > 0.9
}

/// Distance from a sphere of `radius` at which it stays inside the image of `intr` when the
/// camera looks at its centre: the sphere's silhouette is a cone of half-angle
/// `asin(radius / d)`, which must not exceed the smaller half field of view `θ`, so
/// `d = FRAMING_MARGIN · radius / sin θ`.
pub fn framing_distance(radius: f64, intr: &Intrinsics) -> f64 {
    let half = 0.5 * intr.camera_angle_x().min(intr.camera_angle_y());
    FRAMING_MARGIN * radius / half.sin()
}

/// Whether the scene stands on a ground: up-facing triangles (geometric normal within ~25° of
/// +Y) lying within 1% of the bounds' height (or 0.1% of the diagonal, if larger) of the bounds'
/// bottom cover at least half of the bounds' horizontal (XZ) area. A floating closed object's
/// bottom faces point down and do not count.
pub fn has_ground(scene: &Scene) -> bool {
    let b = scene.bounds;
    if b.is_empty() {
        return false;
    }
    let size = b.max - b.min;
    let footprint = size.x as f64 * size.z as f64;
    if footprint <= 0.0 {
        return false;
    }
    let mesh = &scene.mesh;
    let mut covered = 0.0f64;
    for tri in &mesh.indices {
        let p = tri.map(|i| mesh.positions.get(i as usize).copied().unwrap_or(glam::Vec3::INFINITY));
        if is_ground_triangle(scene, &p) {
            covered += 0.5 * (p[1] - p[0]).as_dvec3().cross((p[2] - p[0]).as_dvec3()).y;
        }
    }
    covered >= 0.5 * footprint
}

/// The rig kind `kind` resolves to for `scene` (see the module documentation).
pub fn resolve_kind(scene: &Scene, kind: RigKind) -> RigKind {
    match kind {
        RigKind::Auto if !scene.cameras.is_empty() => RigKind::Gltf,
        RigKind::Auto if has_ground(scene) => RigKind::Hemisphere,
        RigKind::Auto => RigKind::Sphere,
        k => k,
    }
}

/// Places every camera of every split.
///
/// Errors: a scene without geometry, impossible image size / field of view / view counts, or
/// the `gltf` rig on a scene without glTF cameras.
pub fn build_rig(scene: &Scene, cfg: &RigConfig) -> Result<Rig, PathTracerError> {
    if cfg.width == 0 || cfg.height == 0 {
        return Err(PathTracerError::Config(format!("resolution {}x{} is empty", cfg.width, cfg.height)));
    }
    if cfg.counts[0] == 0 {
        return Err(PathTracerError::Config("at least one train view is needed".into()));
    }
    if let Some(&n) = cfg.counts.iter().find(|&&n| n >= 1 << 24) {
        return Err(PathTracerError::Config(format!("{n} views in one split is too many (limit 16777215)")));
    }
    if scene.bounds.is_empty() || !scene.bounds.diagonal().is_finite() || scene.bounds.diagonal() <= 0.0 {
        return Err(PathTracerError::Config(format!(
            "scene '{}' has no geometry of nonzero size to place cameras around",
            scene.name
        )));
    }
    let kind = resolve_kind(scene, cfg.kind);
    let (intrinsics, splits) = match kind {
        RigKind::CameraPath => return Err(PathTracerError::Config("the camera-path rig is placed by a camera path file (render --camera-path)".into())),
        RigKind::Gltf => gltf_rig(scene, cfg)?,
        _ => {
            if !(cfg.fov_x.is_finite() && cfg.fov_x > 0.0 && cfg.fov_x < std::f64::consts::PI) {
                return Err(PathTracerError::Config(format!(
                    "field of view {} rad is not in (0, pi)",
                    cfg.fov_x
                )));
            }
            let intr = Intrinsics::from_fov_x(cfg.width, cfg.height, cfg.fov_x);
            (intr, sphere_rig(scene, cfg, &intr, kind == RigKind::Hemisphere)?)
        }
    };
    Ok(Rig { kind, intrinsics, splits })
}

fn camera(intr: &Intrinsics, c2w: glam::DMat4) -> Result<Camera, PathTracerError> {
    Camera::new(*intr, c2w).map_err(|m| PathTracerError::Config(format!("rig produced an invalid camera: {m}")))
}

fn sphere_rig(
    scene: &Scene,
    cfg: &RigConfig,
    intr: &Intrinsics,
    upper: bool,
) -> Result<[Vec<Camera>; 3], PathTracerError> {
    let (centre, radius) = framing_sphere(scene, if upper { RigKind::Hemisphere } else { RigKind::Sphere });
    let dist = framing_distance(radius, intr);
    // Band of y = sin(elevation) covered; uniform in y is uniform in area on a sphere band.
    let (y_lo, y_hi) =
        if upper { (HEMISPHERE_ELEVATION.0.sin(), HEMISPHERE_ELEVATION.1.sin()) } else { (-1.0, 1.0) };
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let mut out: [Vec<Camera>; 3] = Default::default();
    for split in SplitKind::ALL {
        let s = split_index(split) as u64;
        let n = cfg.counts[s as usize];
        let offset = std::f64::consts::TAU * uniform(cfg.seed, s, u32::MAX as u64, 0);
        for k in 0..n {
            let key = k as u64;
            // Jitter within the lattice cell: ±40% of the cell height in y, ±40% of the
            // golden-angle step in azimuth, so cells never swap.
            let t = (k as f64 + 0.5 + 0.8 * (uniform(cfg.seed, s, key, 0) - 0.5)) / n as f64;
            let y = y_lo + (y_hi - y_lo) * (1.0 - t);
            let phi = offset + k as f64 * golden + 0.4 * golden * (uniform(cfg.seed, s, key, 1) - 0.5);
            let r = (1.0 - y * y).max(0.0).sqrt();
            let dir = DVec3::new(r * phi.cos(), y, r * phi.sin());
            let eye = centre + dist * dir;
            out[s as usize].push(camera(intr, Camera::look_at(eye, centre, DVec3::Y))?);
        }
    }
    Ok(out)
}

/// Median z-depth, along the camera's viewing axis, of the scene's vertices in front of
/// `cam` (world space); the distance to the bounds' centre when none is in front.
fn median_depth(scene: &Scene, c2w: &glam::DMat4, znear: f64) -> f64 {
    let eye = c2w.w_axis.truncate();
    let fwd = -c2w.z_axis.truncate().normalize();
    let mut depths: Vec<f64> = scene
        .mesh
        .positions
        .iter()
        .map(|p| (p.as_dvec3() + scene.origin - eye).dot(fwd))
        .filter(|d| d.is_finite() && *d > znear.max(0.0))
        .collect();
    if depths.is_empty() {
        return (bounding_sphere(scene).0 - eye).length().max(1e-3);
    }
    let mid = depths.len() / 2;
    let (_, m, _) = depths.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    *m
}

fn gltf_rig(scene: &Scene, cfg: &RigConfig) -> Result<(Intrinsics, [Vec<Camera>; 3]), PathTracerError> {
    let Some(first) = scene.cameras.first() else {
        return Err(PathTracerError::Config(format!(
            "rig 'gltf' needs glTF cameras, but scene '{}' has none (use --rig auto, sphere or hemisphere)",
            scene.name
        )));
    };
    if !(first.yfov.is_finite() && first.yfov > 0.0 && first.yfov < std::f64::consts::PI) {
        return Err(PathTracerError::Config(format!("glTF camera yfov {} is not in (0, pi)", first.yfov)));
    }
    let intr = Intrinsics::from_fov_y(cfg.width, cfg.height, first.yfov);
    let max_angle = GLTF_ROTATION_JITTER * first.yfov;
    let anchors: Vec<(glam::DMat4, f64, f64)> = scene
        .cameras
        .iter()
        .map(|c| {
            let m = orthonormalise(&c.c2w);
            let depth = median_depth(scene, &c.c2w, c.znear);
            (m, depth, gltf_jitter_radius(scene, &m, depth))
        })
        .collect();
    let mut out: [Vec<Camera>; 3] = Default::default();
    for split in SplitKind::ALL {
        let s = split_index(split) as u64;
        for k in 0..cfg.counts[s as usize] {
            let key = k as u64;
            let (c2w, depth, jitter_radius) = anchors[k as usize % anchors.len()];
            let (right, up, back) = (c2w.x_axis.truncate(), c2w.y_axis.truncate(), c2w.z_axis.truncate());
            let eye0 = c2w.w_axis.truncate();
            let target = eye0 - back * depth;
            // Uniform point in a disc in the camera's image plane.
            let rho = jitter_radius * uniform(cfg.seed, s, key, 0).sqrt();
            let ang = std::f64::consts::TAU * uniform(cfg.seed, s, key, 1);
            let eye = eye0 + rho * (ang.cos() * right + ang.sin() * up);
            // Look at the target, then turn by small yaw and pitch angles.
            let look = Camera::look_at(eye, target, up);
            let yaw = max_angle * (2.0 * uniform(cfg.seed, s, key, 2) - 1.0);
            let pitch = max_angle * (2.0 * uniform(cfg.seed, s, key, 3) - 1.0);
            let rot = DMat3::from_cols(look.x_axis.truncate(), look.y_axis.truncate(), look.z_axis.truncate())
                * DMat3::from_rotation_y(yaw)
                * DMat3::from_rotation_x(pitch);
            let m = glam::DMat4::from_cols(
                rot.x_axis.extend(0.0),
                rot.y_axis.extend(0.0),
                rot.z_axis.extend(0.0),
                eye.extend(1.0),
            );
            out[s as usize].push(camera(&intr, m)?);
        }
    }
    Ok((intr, out))
}

/// Radius of the disc of camera positions around the glTF camera `c2w` (orthonormal) that
/// sees a median depth `depth`: [`GLTF_BASELINE`] × `depth`, at most [`GLTF_FREE_SPACE`] × the
/// distance to the nearest surface along 16 directions in the camera's image plane.
pub fn gltf_jitter_radius(scene: &Scene, c2w: &glam::DMat4, depth: f64) -> f64 {
    let eye = c2w.w_axis.truncate() - scene.origin;
    let (right, up) = (c2w.x_axis.truncate(), c2w.y_axis.truncate());
    let free = (0..16)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / 16.0;
            nearest_hit(scene, eye, a.cos() * right + a.sin() * up)
        })
        .fold(f64::INFINITY, f64::min);
    (GLTF_BASELINE * depth).min(GLTF_FREE_SPACE * free).max(0.0)
}

/// Distance from `o` (scene-local) along the unit direction `d` to the nearest triangle, either
/// side (the renderer's watertight test, [`intersect_triangle`], over every triangle);
/// infinity when none.
fn nearest_hit(scene: &Scene, o: DVec3, d: DVec3) -> f64 {
    let Some(ray) = WatertightRay::new(&Ray::new(o.as_vec3(), d.as_vec3())) else { return f64::INFINITY };
    let m = &scene.mesh;
    m.indices
        .iter()
        .filter_map(|idx| {
            let [a, b, c] = idx.map(|i| m.positions.get(i as usize).copied());
            intersect_triangle(&ray, [a?, b?, c?], f32::INFINITY)
        })
        .map(|h| h.t as f64)
        .fold(f64::INFINITY, f64::min)
}

/// Re-orthonormalises the rotation part of a camera-to-world matrix (Gram-Schmidt on the
/// viewing axis, then up).
fn orthonormalise(m: &glam::DMat4) -> glam::DMat4 {
    let back = m.z_axis.truncate().normalize_or(DVec3::Z);
    let up0 = m.y_axis.truncate();
    let mut right = up0.cross(back);
    if right.length_squared() < 1e-18 {
        right = back.any_orthonormal_vector();
    }
    let right = right.normalize();
    let up = back.cross(right);
    glam::DMat4::from_cols(right.extend(0.0), up.extend(0.0), back.extend(0.0), m.w_axis.truncate().extend(1.0))
}

/// SplitMix64 finaliser.
fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Counter-based uniform number in [0, 1) keyed by (seed, split, view, dimension).
fn uniform(seed: u64, split: u64, view: u64, dim: u64) -> f64 {
    let mut h = mix(seed ^ 0x5249_475f_5345_4544); // "RIG_SEED"
    for v in [split, view, dim] {
        h = mix(h ^ v.wrapping_add(0x9e37_79b9_7f4a_7c15));
    }
    (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Aabb, Material, Mesh, SceneCamera};
    use glam::Vec3;

    /// A scene with a unit cube centred at (2, 1, -3) world, plus optionally an up-facing
    /// ground quad under it.
    fn scene(ground: bool, cameras: Vec<SceneCamera>) -> Scene {
        let origin = DVec3::new(2.0, 1.0, -3.0);
        let mut positions = Vec::new();
        let mut indices = Vec::new();
        for &(x, y, z) in &[(-0.5, -0.5, -0.5), (0.5, -0.5, -0.5), (0.5, 0.5, -0.5), (-0.5, 0.5, -0.5)] {
            positions.push(Vec3::new(x, y, z));
        }
        for &(x, y, z) in &[(-0.5, -0.5, 0.5), (0.5, -0.5, 0.5), (0.5, 0.5, 0.5), (-0.5, 0.5, 0.5)] {
            positions.push(Vec3::new(x, y, z));
        }
        // Cube faces, outward (counter-clockwise seen from outside); bottom face points down.
        let faces = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [3, 7, 6, 2], [0, 4, 7, 3], [1, 2, 6, 5]];
        for f in faces {
            indices.push([f[0], f[1], f[2]]);
            indices.push([f[0], f[2], f[3]]);
        }
        if ground {
            let b = positions.len() as u32;
            for &(x, z) in &[(-2.0, -2.0), (-2.0, 2.0), (2.0, 2.0), (2.0, -2.0)] {
                positions.push(Vec3::new(x, -0.5, z));
            }
            // Counter-clockwise seen from above: normal +Y.
            indices.push([b, b + 1, b + 2]);
            indices.push([b, b + 2, b + 3]);
        }
        let bounds = positions.iter().fold(Aabb::EMPTY, |a, p| a.union_point(*p));
        let n = positions.len();
        Scene {
            name: "test".into(),
            origin,
            mesh: Mesh {
                normals: vec![Vec3::Y; n],
                tangents: vec![glam::Vec4::ZERO; n],
                uv0: vec![glam::Vec2::ZERO; n],
                uv1: vec![glam::Vec2::ZERO; n],
                colors: vec![glam::Vec4::ONE; n],
                material: vec![0; indices.len()],
                positions,
                indices,
            },
            materials: vec![Material::gltf_default()],
            textures: vec![],
            lights: vec![],
            cameras,
            bounds,
            warnings: vec![],
            objects: vec![],
        }
    }

    fn cfg(kind: RigKind) -> RigConfig {
        RigConfig { kind, width: 40, height: 30, fov_x: DEFAULT_FOV_X, counts: [20, 5, 7], seed: 7 }
    }

    /// Projects `p` (world) with `cam`; returns pixel coordinates if in front.
    fn project(cam: &Camera, p: DVec3) -> Option<(f64, f64)> {
        let q = cam.c2w.inverse().transform_point3(p);
        if q.z >= 0.0 {
            return None;
        }
        let k = cam.intrinsics;
        Some((k.cx + k.fl_x * q.x / -q.z, k.cy - k.fl_y * q.y / -q.z))
    }

    #[test]
    fn sphere_rigs_keep_the_bounding_sphere_in_frame() {
        for (kind, ground) in [(RigKind::Sphere, false), (RigKind::Hemisphere, true)] {
            let s = scene(ground, vec![]);
            let rig = build_rig(&s, &cfg(kind)).unwrap();
            assert_eq!(rig.kind, kind);
            let (c, r) = framing_sphere(&s, kind);
            for (_, _, cam) in rig.views() {
                // The silhouette of the sphere: sample its points tangent to the viewing cone,
                // i.e. every point of the sphere; all must project inside the image.
                for i in 0..40 {
                    for j in 0..20 {
                        let th = std::f64::consts::PI * (j as f64 + 0.5) / 20.0;
                        let ph = std::f64::consts::TAU * i as f64 / 40.0;
                        let p = c + r * DVec3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin());
                        let (x, y) = project(cam, p).expect("sphere point behind the camera");
                        assert!((0.0..=40.0).contains(&x) && (0.0..=30.0).contains(&y), "{kind:?}: ({x}, {y}) out of frame");
                    }
                }
                // Looking at the centre, with world +Y up (no roll), above the centre for the hemisphere.
                let ray = cam.pixel_ray(20.0, 15.0);
                assert!((ray.direction - (c - cam.origin()).normalize()).length() < 1e-9);
                assert!(cam.c2w.x_axis.y.abs() < 1e-9);
                if kind == RigKind::Hemisphere {
                    assert!(cam.origin().y > c.y);
                }
            }
            // The tight framing: not much farther than needed (the sphere spans > 80% of the
            // smaller half field of view).
            let cam = &rig.split(SplitKind::Train)[0];
            let d = (cam.origin() - c).length();
            let half = 0.5 * cam.intrinsics.camera_angle_y();
            assert!((r / d).asin() > 0.8 * half);
        }
    }

    #[test]
    fn hemisphere_frames_the_content_not_the_ground() {
        // The unit cube on a 4 m ground: the hemisphere rig frames the cube's bounding sphere
        // (centre = the cube's centre, radius = half its diagonal); the sphere rig the whole box.
        let s = scene(true, vec![]);
        let (c, r) = framing_sphere(&s, RigKind::Hemisphere);
        assert!((c - s.origin - s.bounds.center().as_dvec3() - DVec3::new(0.0, 0.0, 0.0)).length() < 1e-6);
        assert!((r - 3f64.sqrt() / 2.0).abs() < 1e-6, "radius {r}");
        let (_, r_all) = framing_sphere(&s, RigKind::Sphere);
        assert!((r_all - bounding_sphere(&s).1).abs() < 1e-12 && r_all > 2.0 * r);
        // Without a ground there is nothing to leave out.
        let s = scene(false, vec![]);
        assert_eq!(framing_sphere(&s, RigKind::Hemisphere), bounding_sphere(&s));
    }

    #[test]
    fn poses_are_rigid_distinct_and_deterministic() {
        let anchor = SceneCamera {
            name: Some("cam".into()),
            c2w: Camera::look_at(DVec3::new(2.0, 1.2, 0.0), DVec3::new(2.0, 1.0, -3.0), DVec3::Y),
            yfov: 0.8,
            aspect_ratio: None,
            znear: 0.01,
            zfar: None,
        };
        for kind in [RigKind::Sphere, RigKind::Hemisphere, RigKind::Gltf] {
            let s = scene(true, vec![anchor.clone()]);
            let a = build_rig(&s, &cfg(kind)).unwrap();
            let b = build_rig(&s, &cfg(kind)).unwrap();
            assert_eq!(a, b, "{kind:?} not deterministic");
            let other = build_rig(&s, &RigConfig { seed: 8, ..cfg(kind) }).unwrap();
            assert_ne!(a, other, "{kind:?} ignores the seed");
            let all: Vec<&Camera> = a.views().map(|(_, _, c)| c).collect();
            assert_eq!(all.len(), 32);
            for (i, x) in all.iter().enumerate() {
                // Camera::new validated rigidity; check again at a tight tolerance.
                let r = glam::DMat3::from_mat4(x.c2w);
                assert!((r.transpose() * r - glam::DMat3::IDENTITY).abs().to_cols_array().iter().all(|d| *d < 1e-9));
                assert!((r.determinant() - 1.0).abs() < 1e-9);
                for y in &all[i + 1..] {
                    let d = (x.c2w - y.c2w).abs().to_cols_array().into_iter().fold(0.0, f64::max);
                    assert!(d > 1e-6, "{kind:?}: duplicate pose");
                }
            }
        }
    }

    #[test]
    fn gltf_rig_keeps_its_cameras_in_the_free_space_of_a_corridor() {
        // A square corridor along −z, 0.3 wide and tall, 10 long, camera in its axis: the
        // baseline rule (0.1 × median depth, several metres) would put cameras in the walls; the
        // free-space bound keeps them within half the 0.15 to the walls.
        let (h, len) = (0.15f32, 10.0f32);
        let mut positions = Vec::new();
        let mut indices = Vec::new();
        let corners = [Vec3::new(-h, -h, 0.0), Vec3::new(h, -h, 0.0), Vec3::new(h, h, 0.0), Vec3::new(-h, h, 0.0)];
        for k in 0..4 {
            let (a, b) = (corners[k], corners[(k + 1) % 4]);
            let base = positions.len() as u32;
            positions.extend([a, b, b - Vec3::Z * len, a - Vec3::Z * len]);
            indices.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]]);
        }
        let mut s = scene(false, vec![]);
        let n = positions.len();
        s.mesh = Mesh { normals: vec![Vec3::Y; n], tangents: vec![glam::Vec4::ZERO; n], uv0: vec![glam::Vec2::ZERO; n], uv1: vec![glam::Vec2::ZERO; n], colors: vec![glam::Vec4::ONE; n], material: vec![0; indices.len()], positions, indices };
        s.bounds = s.mesh.positions.iter().fold(Aabb::EMPTY, |a, p| a.union_point(*p));
        let eye = DVec3::new(0.0, 0.0, -0.5) + s.origin;
        s.cameras = vec![SceneCamera { name: None, c2w: Camera::look_at(eye, eye - DVec3::Z, DVec3::Y), yfov: 0.8, aspect_ratio: None, znear: 0.01, zfar: None }];
        let radius = gltf_jitter_radius(&s, &orthonormalise(&s.cameras[0].c2w), median_depth(&s, &s.cameras[0].c2w, 0.01));
        assert!((radius - GLTF_FREE_SPACE * h as f64).abs() < 1e-6, "{radius}");
        let rig = build_rig(&s, &cfg(RigKind::Gltf)).unwrap();
        for (_, _, cam) in rig.views() {
            let p = cam.origin() - s.origin;
            assert!(p.x.abs() < h as f64 && p.y.abs() < h as f64, "camera at {p} left the corridor");
        }
    }

    #[test]
    fn gltf_rig_stays_near_its_camera_and_looks_along_it() {
        let eye = DVec3::new(2.0, 1.2, 0.0);
        let anchor = SceneCamera {
            name: None,
            c2w: Camera::look_at(eye, DVec3::new(2.0, 1.0, -3.0), DVec3::Y),
            yfov: 0.8,
            aspect_ratio: None,
            znear: 0.01,
            zfar: None,
        };
        let s = scene(false, vec![anchor.clone()]);
        let rig = build_rig(&s, &cfg(RigKind::Auto)).unwrap();
        assert_eq!(rig.kind, RigKind::Gltf);
        assert!((rig.intrinsics.camera_angle_y() - 0.8).abs() < 1e-12);
        let depth = median_depth(&s, &anchor.c2w, anchor.znear);
        let radius = gltf_jitter_radius(&s, &orthonormalise(&anchor.c2w), depth);
        assert!((radius - GLTF_BASELINE * depth).abs() < 1e-12, "open space: the baseline rule, {radius}");
        let axis = -anchor.c2w.z_axis.truncate();
        let mut widest = 0.0f64;
        for (_, _, cam) in rig.views() {
            widest = widest.max((cam.origin() - eye).length());
            assert!((cam.origin() - eye).length() <= radius + 1e-12);
            let fwd = -cam.c2w.z_axis.truncate();
            assert!(fwd.angle_between(axis) < 0.15, "view turned {} rad", fwd.angle_between(axis));
        }
        assert!(widest > 0.5 * radius, "the views spread over the disc: {widest} of {radius}");
        // Explicitly asking for the glTF rig without cameras is an error naming the scene.
        let e = build_rig(&scene(false, vec![]), &cfg(RigKind::Gltf)).unwrap_err().to_string();
        assert!(e.contains("'test'") && e.contains("no"), "{e}");
    }

    #[test]
    fn auto_rule_and_ground_detection() {
        // A floating cube: its bottom face points down, so no ground.
        assert!(!has_ground(&scene(false, vec![])));
        assert!(has_ground(&scene(true, vec![])));
        assert_eq!(resolve_kind(&scene(false, vec![]), RigKind::Auto), RigKind::Sphere);
        assert_eq!(resolve_kind(&scene(true, vec![]), RigKind::Auto), RigKind::Hemisphere);
        assert_eq!(resolve_kind(&scene(true, vec![]), RigKind::Sphere), RigKind::Sphere);
        assert_eq!("Hemisphere".parse::<RigKind>().unwrap(), RigKind::Hemisphere);
        assert!("cube".parse::<RigKind>().is_err());
    }

    #[test]
    fn impossible_configs_are_errors() {
        let s = scene(false, vec![]);
        for bad in [
            RigConfig { width: 0, ..cfg(RigKind::Sphere) },
            RigConfig { counts: [0, 1, 1], ..cfg(RigKind::Sphere) },
            RigConfig { fov_x: 0.0, ..cfg(RigKind::Sphere) },
            RigConfig { fov_x: f64::NAN, ..cfg(RigKind::Sphere) },
        ] {
            assert!(matches!(build_rig(&s, &bad), Err(PathTracerError::Config(_))));
        }
        let mut empty = s.clone();
        empty.bounds = Aabb::EMPTY;
        assert!(build_rig(&empty, &cfg(RigKind::Sphere)).is_err());
        // Rig placement ignores the world offset only through the origin: shifting the scene
        // shifts every camera.
        let mut moved = s.clone();
        moved.origin += DVec3::new(10.0, 0.0, 0.0);
        let a = build_rig(&s, &cfg(RigKind::Sphere)).unwrap();
        let b = build_rig(&moved, &cfg(RigKind::Sphere)).unwrap();
        let d = b.splits[0][0].origin() - a.splits[0][0].origin();
        assert!((d - DVec3::new(10.0, 0.0, 0.0)).length() < 1e-9);
    }
}
