//! Quick look at a written scene without the path tracer:
//! `cargo run -p scenegen --example preview -- scenes/tabletop.gltf out.png [size]`.
//!
//! Casts one ray per pixel (brute force, no BVH) from the scene's first glTF
//! camera, or from a camera on the bounding sphere (40° FOV) when there is
//! none, and shades hits with the base-colour factor times vertex colour times
//! the direct light of the punctual lights and a dim headlight (no
//! shadows, no textures). For layout checks only.

use glam::{DMat4, DVec3, Vec3};
use gltf::khr_lights_punctual::Kind;

struct Tri {
    p: [DVec3; 3],
    colour: [DVec3; 3],
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        eprintln!("usage: preview SCENE.gltf OUT.png [SIZE]");
        std::process::exit(2);
    }
    let size: u32 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(200);
    let (doc, buffers, _) = match gltf::import(&args[1]) {
        Ok(x) => x,
        Err(e) => {
            eprintln!("error: {}: {e}", args[1]);
            std::process::exit(1);
        }
    };
    let matrix = |n: &gltf::Node| {
        DMat4::from_cols_array_2d(&n.transform().matrix().map(|c| c.map(|x| x as f64)))
    };

    let mut tris = Vec::new();
    for node in doc.nodes() {
        let Some(mesh) = node.mesh() else { continue };
        let m = matrix(&node);
        for prim in mesh.primitives() {
            let reader = prim.reader(|b| Some(&buffers[b.index()]));
            let base = prim.material().pbr_metallic_roughness().base_color_factor();
            let base = DVec3::new(base[0] as f64, base[1] as f64, base[2] as f64);
            let pos: Vec<DVec3> = reader
                .read_positions()
                .into_iter()
                .flatten()
                .map(|p| m.transform_point3(Vec3::from(p).as_dvec3()))
                .collect();
            let cols: Vec<DVec3> = match reader.read_colors(0) {
                Some(c) => c
                    .into_rgb_f32()
                    .map(|c| base * Vec3::from(c).as_dvec3())
                    .collect(),
                None => vec![base; pos.len()],
            };
            let idx: Vec<u32> = reader
                .read_indices()
                .map(|i| i.into_u32().collect())
                .unwrap_or_default();
            for t in idx.chunks_exact(3) {
                let [a, b, c] = [t[0] as usize, t[1] as usize, t[2] as usize];
                tris.push(Tri {
                    p: [pos[a], pos[b], pos[c]],
                    colour: [cols[a], cols[b], cols[c]],
                });
            }
        }
    }
    let mut lights = Vec::new();
    for node in doc.nodes() {
        if let Some(l) = node.light() {
            let m = matrix(&node);
            let directional = matches!(l.kind(), Kind::Directional);
            lights.push((
                directional,
                l.intensity() as f64,
                m.transform_point3(DVec3::ZERO),
                m.transform_vector3(DVec3::NEG_Z).normalize(),
            ));
        }
    }

    let (cam, yfov) = match doc.nodes().find(|n| n.camera().is_some()) {
        Some(n) => {
            let yfov = match n.camera().as_ref().map(|c| c.projection()) {
                Some(gltf::camera::Projection::Perspective(p)) => p.yfov() as f64,
                _ => 0.7,
            };
            (matrix(&n), yfov)
        }
        None => {
            let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
            for t in &tris {
                for p in t.p {
                    lo = lo.min(p);
                    hi = hi.max(p);
                }
            }
            let centre = (lo + hi) * 0.5;
            let radius = (hi - lo).length() * 0.5;
            let fov = 40f64.to_radians();
            let eye = centre + DVec3::new(0.6, 0.55, 0.8).normalize() * radius / (fov / 2.0).sin();
            let t = scenegen::Transform::look_at(eye.as_vec3(), centre.as_vec3(), Vec3::Y);
            (t.matrix().as_dmat4(), fov)
        }
    };
    let origin = cam.transform_point3(DVec3::ZERO);
    let tan = (yfov / 2.0).tan();
    let img = image::RgbImage::from_fn(size, size, |i, j| {
        let x = ((i as f64 + 0.5) / size as f64 * 2.0 - 1.0) * tan;
        let y = (1.0 - (j as f64 + 0.5) / size as f64 * 2.0) * tan;
        let d = cam.transform_vector3(DVec3::new(x, y, -1.0)).normalize();
        let mut best: Option<(f64, usize, f64, f64)> = None;
        for (k, t) in tris.iter().enumerate() {
            let e1 = t.p[1] - t.p[0];
            let e2 = t.p[2] - t.p[0];
            let p = d.cross(e2);
            let det = e1.dot(p);
            if det.abs() < 1e-14 {
                continue;
            }
            let s = origin - t.p[0];
            let u = s.dot(p) / det;
            let q = s.cross(e1);
            let v = d.dot(q) / det;
            let tt = e2.dot(q) / det;
            if u >= 0.0 && v >= 0.0 && u + v <= 1.0 && tt > 1e-6 && best.is_none_or(|b| tt < b.0) {
                best = Some((tt, k, u, v));
            }
        }
        let Some((tt, k, u, v)) = best else {
            return image::Rgb([40, 40, 60]);
        };
        let t = &tris[k];
        let mut n = (t.p[1] - t.p[0]).cross(t.p[2] - t.p[0]).normalize();
        if n.dot(d) > 0.0 {
            n = -n;
        }
        let hit = origin + d * tt;
        let albedo = t.colour[0] * (1.0 - u - v) + t.colour[1] * u + t.colour[2] * v;
        // A dim headlight so unlit scenes still show their shapes.
        let mut e = 0.6 * n.dot(-d).max(0.0);
        for &(kind, intensity, pos, axis) in &lights {
            e += match kind {
                true => intensity * n.dot(-axis).max(0.0),
                false => {
                    let to = pos - hit;
                    intensity / to.length_squared() * n.dot(to.normalize()).max(0.0)
                }
            };
        }
        let l = albedo * e / std::f64::consts::PI;
        let enc = |c: f64| (c.clamp(0.0, 1.0).powf(1.0 / 2.2) * 255.0).round() as u8;
        image::Rgb([enc(l.x), enc(l.y), enc(l.z)])
    });
    if let Err(e) = img.save(&args[2]) {
        eprintln!("error: {}: {e}", args[2]);
        std::process::exit(1);
    }
    println!("{}", args[2]);
}
