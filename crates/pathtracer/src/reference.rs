//! The reference surface for geometry metrics: the scene's own triangles in world space (the
//! positions the renders used: the importer's node transforms applied, plus the scene's
//! origin offset), restricted to those that some camera sees.
//!
//! A triangle counts as visible when the pixel-centre ray of at least one pixel of at least
//! one of the given cameras hits it first (the same closest-hit rules as the ground truth:
//! back faces of single-sided materials and alpha-masked-out texels are not hit). Hidden
//! interiors and the undersides of objects resting on the ground are left out, so a
//! reconstruction is not asked to recover surface that no view constrains. A triangle is kept
//! or dropped whole: a large triangle that is only partly visible counts entirely.
//!
//! ```no_run
//! use pathtracer::ground_truth::{SceneLookup, scene_of_dataset};
//! use pathtracer::reference::visible_surface;
//! let dataset = dataset::Dataset::load(std::path::Path::new("out/tabletop")).unwrap();
//! let cameras: Vec<dataset::Camera> = dataset.train.iter().chain(&dataset.test).map(|f| f.camera).collect();
//! if let SceneLookup::Found { renderer, .. } = scene_of_dataset(&dataset.root, None, &Default::default()).unwrap() {
//!     let r = visible_surface(&renderer, &cameras);
//!     println!("{} of {} triangles visible, {:.1} % of the area", r.visible_triangles(), r.triangles.len(), 100.0 * r.visible_area_fraction);
//! }
//! ```

use crate::render::Renderer;
use dataset::Camera;
use glam::Vec3;
use rayon::prelude::*;

/// The scene's triangles in world space and which of them the cameras see.
///
/// # Shapes
/// `positions`: one per vertex; `triangles`, `visible`: one per triangle.
#[derive(Clone, Debug)]
pub struct ReferenceSurface {
    /// World-space vertex positions (`f32`, the scene's origin added back).
    pub positions: Vec<Vec3>,
    /// Every triangle of the scene (vertex indices into `positions`).
    pub triangles: Vec<[u32; 3]>,
    /// Whether a camera ray hits the triangle first.
    pub visible: Vec<bool>,
    /// Area of the visible triangles over the area of all triangles.
    pub visible_area_fraction: f64,
    /// Total area of all triangles, m².
    pub total_area: f64,
    /// Pixel-centre rays cast.
    pub rays: u64,
    /// Rays that hit a triangle.
    pub hits: u64,
}

impl ReferenceSurface {
    /// Number of visible triangles.
    pub fn visible_triangles(&self) -> usize {
        self.visible.iter().filter(|v| **v).count()
    }

    /// The visible triangles only.
    pub fn visible_mesh(&self) -> Vec<[u32; 3]> {
        self.triangles.iter().zip(&self.visible).filter(|(_, v)| **v).map(|(t, _)| *t).collect()
    }
}

/// The renderer's scene as a [`ReferenceSurface`], visibility from every pixel-centre ray of
/// `cameras` (parallel over cameras and rows; the result does not depend on the thread count).
pub fn visible_surface(renderer: &Renderer, cameras: &[Camera]) -> ReferenceSurface {
    let scene = renderer.scene();
    let mesh = &scene.mesh;
    let positions: Vec<Vec3> = mesh.positions.iter().map(|p| (p.as_dvec3() + scene.origin).as_vec3()).collect();
    let rows: Vec<(&Camera, u32)> = cameras.iter().flat_map(|c| (0..c.intrinsics.height).map(move |j| (c, j))).collect();
    let hits: Vec<(u64, Vec<u32>)> = rows
        .par_iter()
        .map(|(camera, j)| {
            let mut prims: Vec<u32> =
                (0..camera.intrinsics.width).filter_map(|i| renderer.trace_primary(&camera.pixel_center_ray(i, *j)).map(|h| h.hit.prim)).collect();
            let n = prims.len() as u64;
            prims.sort_unstable();
            prims.dedup();
            (n, prims)
        })
        .collect();
    let mut visible = vec![false; mesh.indices.len()];
    let mut hit_count = 0;
    for (n, prims) in &hits {
        hit_count += n;
        for &p in prims {
            if let Some(v) = visible.get_mut(p as usize) {
                *v = true;
            }
        }
    }
    let area = |t: &[u32; 3]| {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize].as_dvec3());
        0.5 * (b - a).cross(c - a).length()
    };
    let total_area: f64 = mesh.indices.iter().map(area).sum();
    let visible_area: f64 = mesh.indices.iter().zip(&visible).filter(|(_, v)| **v).map(|(t, _)| area(t)).sum();
    ReferenceSurface {
        positions,
        triangles: mesh.indices.clone(),
        visible,
        visible_area_fraction: if total_area > 0.0 { visible_area / total_area } else { 0.0 },
        total_area,
        rays: cameras.iter().map(|c| c.intrinsics.width as u64 * c.intrinsics.height as u64).sum(),
        hits: hit_count,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::AccelParams;
    use crate::scene::{Aabb, Material, Mesh, Scene};
    use dataset::Intrinsics;
    use glam::{DVec3, Vec2, Vec4};

    /// A 4 m ground square at y = 0 and a unit cube standing on it, centred on the origin, and
    /// a scene origin offset so that world = local + (10, 0, 0).
    fn scene() -> Scene {
        let mut mesh = Mesh::default();
        let mut quad = |c: [Vec3; 4]| {
            let base = mesh.positions.len() as u32;
            let n = (c[1] - c[0]).cross(c[2] - c[0]).normalize();
            for p in c {
                mesh.positions.push(p);
                mesh.normals.push(n);
                mesh.tangents.push(Vec4::ZERO);
                mesh.uv0.push(Vec2::ZERO);
                mesh.uv1.push(Vec2::ZERO);
                mesh.colors.push(Vec4::ONE);
            }
            mesh.indices.push([base, base + 1, base + 2]);
            mesh.indices.push([base, base + 2, base + 3]);
            mesh.material.extend([0, 0]);
        };
        let v = Vec3::new;
        quad([v(-2.0, 0.0, -2.0), v(-2.0, 0.0, 2.0), v(2.0, 0.0, 2.0), v(2.0, 0.0, -2.0)]); // ground, up
        let (a, b) = (-0.5, 0.5);
        quad([v(a, 1.0, a), v(a, 1.0, b), v(b, 1.0, b), v(b, 1.0, a)]); // top, +y
        quad([v(a, 0.0, a), v(b, 0.0, a), v(b, 0.0, b), v(a, 0.0, b)]); // bottom, -y
        quad([v(a, 0.0, b), v(b, 0.0, b), v(b, 1.0, b), v(a, 1.0, b)]); // front, +z
        quad([v(a, 0.0, a), v(a, 1.0, a), v(b, 1.0, a), v(b, 0.0, a)]); // back, -z
        quad([v(b, 0.0, a), v(b, 1.0, a), v(b, 1.0, b), v(b, 0.0, b)]); // +x
        quad([v(a, 0.0, a), v(a, 0.0, b), v(a, 1.0, b), v(a, 1.0, a)]); // -x
        let bounds = mesh.positions.iter().fold(Aabb::EMPTY, |b, &p| b.union_point(p));
        Scene {
            name: "test".into(),
            origin: DVec3::new(10.0, 0.0, 0.0),
            mesh,
            materials: vec![Material::gltf_default()],
            textures: Vec::new(),
            lights: Vec::new(),
            cameras: Vec::new(),
            bounds,
            warnings: Vec::new(),
            objects: vec![],
        }
    }

    #[test]
    fn visible_triangles_are_those_a_camera_ray_hits() {
        let renderer = Renderer::new(scene(), &AccelParams::fast_build()).unwrap();
        let eye = DVec3::new(10.0, 5.0, 3.0);
        let camera = Camera::new(Intrinsics::from_fov_y(96, 96, 70f64.to_radians()), Camera::look_at(eye, DVec3::new(10.0, 0.0, 0.0), DVec3::Y)).unwrap();
        let r = visible_surface(&renderer, &[camera]);
        // Ground, top and front seen; bottom (under the cube), back and the sides (edge-on or
        // facing away) not.
        assert_eq!(r.visible, [true, true, true, true, false, false, true, true, false, false, false, false, false, false]);
        assert!((r.total_area - 22.0).abs() < 1e-9);
        assert!((r.visible_area_fraction - 18.0 / 22.0).abs() < 1e-9);
        // World positions carry the scene origin.
        assert_eq!(r.positions[0], Vec3::new(8.0, 0.0, -2.0));
        assert_eq!(r.rays, 96 * 96);
        assert!(r.hits > 0 && r.hits <= r.rays);
        assert_eq!(r.visible_mesh().len(), 6);
    }
}
