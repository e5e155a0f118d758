//! Tests of the written files: they load with the `gltf` crate (which
//! validates references), every accessor's min/max equals its data, output is
//! byte-identical across runs, the scenes meet their stated properties (depth
//! range, closed room, light levels).

use std::path::Path;

use glam::{DMat4, DVec3, Vec2, Vec3};

use crate::*;

struct Loaded {
    doc: gltf::Document,
    buffers: Vec<gltf::buffer::Data>,
    images: Vec<gltf::image::Data>,
}

fn load(path: &Path) -> Loaded {
    let (doc, buffers, images) =
        gltf::import(path).unwrap_or_else(|e| panic!("{} does not load: {e}", path.display()));
    Loaded {
        doc,
        buffers,
        images,
    }
}

/// Read every component of an accessor as f64, element by element.
fn accessor_values(l: &Loaded, acc: &gltf::Accessor) -> Vec<Vec<f64>> {
    use gltf::accessor::DataType;
    let Some(view) = acc.view() else {
        // A sparse accessor without a bufferView: zeros with the sparse values substituted.
        let sparse = acc.sparse().expect("accessor without bufferView or sparse");
        let dims = acc.dimensions().multiplicity();
        let mut out = vec![vec![0.0; dims]; acc.count()];
        let read = |view: gltf::buffer::View<'_>, offset: usize, len: usize| {
            let buf = &l.buffers[view.buffer().index()].0;
            buf[view.offset() + offset..view.offset() + offset + len].to_vec()
        };
        let idx = read(sparse.indices().view(), sparse.indices().offset(), 4 * sparse.count());
        let vals = read(sparse.values().view(), sparse.values().offset(), 4 * dims * sparse.count());
        for j in 0..sparse.count() {
            let i = u32::from_le_bytes(idx[4 * j..4 * j + 4].try_into().unwrap()) as usize;
            for k in 0..dims {
                let at = 4 * (j * dims + k);
                out[i][k] = f32::from_le_bytes(vals[at..at + 4].try_into().unwrap()) as f64;
            }
        }
        return out;
    };
    let buf = &l.buffers[view.buffer().index()].0;
    assert_eq!(
        view.offset() % 4,
        0,
        "bufferView {} not 4-byte aligned",
        view.index()
    );
    assert!(
        view.offset() + view.length() <= buf.len(),
        "bufferView {} overruns its buffer",
        view.index()
    );
    let comp = acc.data_type().size();
    let dims = acc.dimensions().multiplicity();
    let stride = view.stride().unwrap_or(comp * dims);
    let start = view.offset() + acc.offset();
    assert!(
        acc.count() == 0
            || acc.offset() + stride * (acc.count() - 1) + comp * dims <= view.length(),
        "accessor {} overruns its bufferView",
        acc.index()
    );
    (0..acc.count())
        .map(|i| {
            (0..dims)
                .map(|k| {
                    let at = start + i * stride + k * comp;
                    let b = &buf[at..at + comp];
                    match acc.data_type() {
                        DataType::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                        DataType::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                        DataType::U16 => u16::from_le_bytes([b[0], b[1]]) as f64,
                        DataType::U8 => b[0] as f64,
                        DataType::I16 => i16::from_le_bytes([b[0], b[1]]) as f64,
                        DataType::I8 => b[0] as i8 as f64,
                    }
                })
                .collect()
        })
        .collect()
}

/// Every accessor has min and max equal (exactly, after f32 rounding) to its data.
fn assert_min_max_match(l: &Loaded, what: &str) {
    for acc in l.doc.accessors() {
        let values = accessor_values(l, &acc);
        let dims = acc.dimensions().multiplicity();
        let parse = |v: Option<gltf::json::Value>, which: &str| -> Vec<f64> {
            let v = v.unwrap_or_else(|| panic!("{what}: accessor {} has no {which}", acc.index()));
            v.as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap() as f32 as f64)
                .collect()
        };
        let (lo, hi) = (parse(acc.min(), "min"), parse(acc.max(), "max"));
        assert_eq!(lo.len(), dims);
        for k in 0..dims {
            let data_lo = values.iter().map(|e| e[k]).fold(f64::INFINITY, f64::min);
            let data_hi = values
                .iter()
                .map(|e| e[k])
                .fold(f64::NEG_INFINITY, f64::max);
            assert_eq!(lo[k], data_lo, "{what}: accessor {} min[{k}]", acc.index());
            assert_eq!(hi[k], data_hi, "{what}: accessor {} max[{k}]", acc.index());
        }
    }
}

/// Triangles of every mesh instance in world space (flat node hierarchy).
fn world_triangles(l: &Loaded) -> Vec<[DVec3; 3]> {
    let mut tris = Vec::new();
    for node in l.doc.nodes() {
        let Some(mesh) = node.mesh() else { continue };
        let m = DMat4::from_cols_array_2d(&node.transform().matrix().map(|c| c.map(|x| x as f64)));
        for prim in mesh.primitives() {
            let reader = prim.reader(|b| Some(&l.buffers[b.index()]));
            let pos: Vec<DVec3> = reader
                .read_positions()
                .unwrap()
                .map(|p| m.transform_point3(Vec3::from(p).as_dvec3()))
                .collect();
            let idx: Vec<u32> = reader.read_indices().unwrap().into_u32().collect();
            for t in idx.chunks_exact(3) {
                tris.push([pos[t[0] as usize], pos[t[1] as usize], pos[t[2] as usize]]);
            }
        }
    }
    tris
}

/// Nearest hit distance along a ray (Möller–Trumbore, both sides).
fn cast(tris: &[[DVec3; 3]], o: DVec3, d: DVec3) -> Option<f64> {
    cast_index(tris, o, d).map(|(t, _)| t)
}

/// Nearest hit distance and triangle index along a ray.
fn cast_index(tris: &[[DVec3; 3]], o: DVec3, d: DVec3) -> Option<(f64, usize)> {
    let mut best: Option<(f64, usize)> = None;
    for (k, [a, b, c]) in tris.iter().enumerate() {
        let e1 = *b - *a;
        let e2 = *c - *a;
        let p = d.cross(e2);
        let det = e1.dot(p);
        if det.abs() < 1e-14 {
            continue;
        }
        let inv = 1.0 / det;
        let s = o - *a;
        let u = s.dot(p) * inv;
        if !(0.0..=1.0).contains(&u) {
            continue;
        }
        let q = s.cross(e1);
        let v = d.dot(q) * inv;
        if v < 0.0 || u + v > 1.0 {
            continue;
        }
        let t = e2.dot(q) * inv;
        if t > 1e-9 && best.is_none_or(|b| t < b.0) {
            best = Some((t, k));
        }
    }
    best
}

/// The scene's first camera: world matrix and vertical FOV.
fn first_camera(l: &Loaded) -> (DMat4, f64) {
    let node = l
        .doc
        .nodes()
        .find(|n| n.camera().is_some())
        .expect("scene has a camera");
    let yfov = match node.camera().unwrap().projection() {
        gltf::camera::Projection::Perspective(p) => p.yfov() as f64,
        gltf::camera::Projection::Orthographic(_) => panic!("expected a perspective camera"),
    };
    let m = DMat4::from_cols_array_2d(&node.transform().matrix().map(|c| c.map(|x| x as f64)));
    (m, yfov)
}

#[test]
fn every_scene_loads_with_exact_accessor_bounds() {
    let dir = tempfile::tempdir().unwrap();
    let written = write_all(dir.path()).unwrap();
    let mut total = 0u64;
    for f in &written {
        total += std::fs::metadata(f).unwrap().len();
    }
    assert!(total < 5_000_000, "scenes take {total} bytes");
    for name in scene_names() {
        let l = load(&dir.path().join(format!("{name}.gltf")));
        assert_min_max_match(&l, name);
        assert_eq!(l.doc.scenes().count(), 1);
        // Each primitive is a triangle list with normals and UVs.
        for mesh in l.doc.meshes() {
            for prim in mesh.primitives() {
                assert_eq!(prim.mode(), gltf::mesh::Mode::Triangles);
                assert!(prim.get(&gltf::Semantic::Normals).is_some());
                assert!(prim.get(&gltf::Semantic::TexCoords(0)).is_some());
                // glTF requires unit normals and unit tangents with w = ±1.
                let reader = prim.reader(|b| Some(&l.buffers[b.index()]));
                for n in reader.read_normals().unwrap() {
                    assert!(
                        (Vec3::from(n).length() - 1.0).abs() < 1e-5,
                        "{name}: normal {n:?}"
                    );
                }
                for t in reader.read_tangents().into_iter().flatten() {
                    assert!(
                        (Vec3::new(t[0], t[1], t[2]).length() - 1.0).abs() < 1e-5
                            && t[3].abs() == 1.0
                    );
                }
            }
        }
        assert_eq!(l.images.len(), l.doc.images().count());
        // Lights declare their extension.
        let has_lights = l.doc.lights().is_some_and(|mut ls| ls.next().is_some());
        assert_eq!(
            has_lights,
            l.doc.extensions_used().any(|e| e == "KHR_lights_punctual"),
            "{name}"
        );
    }
    let readme = std::fs::read_to_string(dir.path().join("README.md")).unwrap();
    for name in scene_names() {
        assert!(
            readme.contains(&format!("- `{name}`:")),
            "README lacks {name}"
        );
    }
}

#[test]
fn output_is_byte_identical_across_runs() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let fa = write_all(a.path()).unwrap();
    let fb = write_all(b.path()).unwrap();
    assert_eq!(fa.len(), fb.len());
    for (x, y) in fa.iter().zip(&fb) {
        assert_eq!(x.file_name(), y.file_name());
        assert!(
            std::fs::read(x).unwrap() == std::fs::read(y).unwrap(),
            "{} differs",
            x.display()
        );
    }
}

#[test]
fn deep_scene_depth_range_is_at_least_20_to_1() {
    let dir = tempfile::tempdir().unwrap();
    write_scene("deep", dir.path()).unwrap();
    let l = load(&dir.path().join("deep.gltf"));
    let tris = world_triangles(&l);
    let (cam, yfov) = first_camera(&l);
    let origin = cam.transform_point3(DVec3::ZERO);
    let forward = cam.transform_vector3(DVec3::NEG_Z).normalize();
    let n = 96;
    let tan = (yfov / 2.0).tan();
    let (mut near, mut far) = (f64::INFINITY, 0.0f64);
    for j in 0..n {
        for i in 0..n {
            // Square image, pixel centres.
            let x = ((i as f64 + 0.5) / n as f64 * 2.0 - 1.0) * tan;
            let y = (1.0 - (j as f64 + 0.5) / n as f64 * 2.0) * tan;
            let d = cam.transform_vector3(DVec3::new(x, y, -1.0)).normalize();
            if let Some(t) = cast(&tris, origin, d) {
                let z = t * d.dot(forward);
                near = near.min(z);
                far = far.max(z);
            }
        }
    }
    assert!(near < 0.7, "nearest visible depth {near}");
    assert!(far > 15.0, "farthest visible depth {far}");
    assert!(far / near >= 20.0, "depth range {near}..{far}");
}

#[test]
fn cornell_room_is_closed_around_its_camera() {
    let dir = tempfile::tempdir().unwrap();
    write_scene("cornell", dir.path()).unwrap();
    let l = load(&dir.path().join("cornell.gltf"));
    let tris = world_triangles(&l);
    let (cam, _) = first_camera(&l);
    let origin = cam.transform_point3(DVec3::ZERO);
    // Fibonacci sphere of directions: every one must hit a wall within the room's diagonal.
    let n = 600;
    for k in 0..n {
        let z = 1.0 - 2.0 * (k as f64 + 0.5) / n as f64;
        let phi = k as f64 * std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let r = (1.0 - z * z).sqrt();
        let d = DVec3::new(r * phi.cos(), r * phi.sin(), z);
        let (t, k) =
            cast_index(&tris, origin, d).unwrap_or_else(|| panic!("ray {d} escapes the room"));
        assert!(t < 5.0);
        // Walls and boxes face the camera: the geometric (winding) normal opposes the ray.
        let [a, b, c] = tris[k];
        assert!(
            (b - a).cross(c - a).dot(d) < 0.0,
            "ray {d} hits a back face"
        );
    }
    let emissive = l
        .doc
        .materials()
        .find(|m| m.emissive_strength().is_some())
        .expect("emissive material");
    assert!(emissive.emissive_strength().unwrap() > 1.0);
}

/// Irradiance at `p` with normal `n` from the scene's punctual lights, ignoring shadows.
fn punctual_irradiance(l: &Loaded, p: DVec3, n: DVec3) -> f64 {
    use gltf::khr_lights_punctual::Kind;
    let mut e = 0.0;
    for node in l.doc.nodes() {
        let Some(light) = node.light() else { continue };
        let m = DMat4::from_cols_array_2d(&node.transform().matrix().map(|c| c.map(|x| x as f64)));
        let pos = m.transform_point3(DVec3::ZERO);
        let axis = m.transform_vector3(DVec3::NEG_Z).normalize();
        let i = light.intensity() as f64;
        match light.kind() {
            Kind::Directional => e += i * n.dot(-axis).max(0.0),
            Kind::Point => {
                let to = pos - p;
                e += i / to.length_squared() * n.dot(to.normalize()).max(0.0);
            }
            Kind::Spot {
                inner_cone_angle,
                outer_cone_angle,
            } => {
                let to = pos - p;
                let cos = (-to.normalize()).dot(axis);
                let (ci, co) = (
                    (inner_cone_angle as f64).cos(),
                    (outer_cone_angle as f64).cos(),
                );
                let falloff = ((cos - co) / (ci - co)).clamp(0.0, 1.0);
                e += i * falloff / to.length_squared() * n.dot(to.normalize()).max(0.0);
            }
        }
    }
    e
}

#[test]
fn light_levels_give_mid_grey_radiance() {
    let dir = tempfile::tempdir().unwrap();
    // Ground points near each scene's centre; radiance of albedo 0.5 = 0.5 · E / π.
    for (name, p) in [
        ("tabletop", DVec3::new(0.0, 0.0, 0.6)),
        ("thin", DVec3::new(0.0, 0.0, 0.0)),
        ("deep", DVec3::new(0.0, 0.0, -4.0)),
        ("materials", DVec3::new(0.0, 0.0, 0.4)),
    ] {
        write_scene(name, dir.path()).unwrap();
        let l = load(&dir.path().join(format!("{name}.gltf")));
        let radiance = 0.5 * punctual_irradiance(&l, p, DVec3::Y) / std::f64::consts::PI;
        assert!(
            (0.2..=0.8).contains(&radiance),
            "{name}: radiance {radiance}"
        );
    }
    // Cornell: direct irradiance at the floor centre below the emissive quad,
    // E = ∫ L cosθ cosθ' / r² dA by the midpoint rule.
    write_scene("cornell", dir.path()).unwrap();
    let l = load(&dir.path().join("cornell.gltf"));
    let mat = l
        .doc
        .materials()
        .find(|m| m.emissive_strength().is_some())
        .unwrap();
    let radiance_l = mat.emissive_strength().unwrap() as f64
        * mat.emissive_factor().iter().map(|&c| c as f64).sum::<f64>()
        / 3.0;
    let tris = world_triangles(&l);
    let light_y = tris
        .iter()
        .flat_map(|t| t.iter())
        .map(|v| v.y)
        .filter(|y| *y < 1.999)
        .fold(0.0, f64::max);
    let (w, d, k) = (0.5, 0.4, 50);
    let mut e = 0.0;
    for i in 0..k {
        for j in 0..k {
            let q = DVec3::new(
                -w / 2.0 + w * (i as f64 + 0.5) / k as f64,
                light_y,
                -d / 2.0 + d * (j as f64 + 0.5) / k as f64,
            );
            let r2 = q.length_squared();
            let cos = light_y / r2.sqrt();
            e += radiance_l * cos * cos / r2 * (w * d) / (k * k) as f64;
        }
    }
    let radiance = 0.5 * e / std::f64::consts::PI;
    assert!(
        (0.15..=0.8).contains(&radiance),
        "cornell direct radiance {radiance}"
    );
}

#[test]
fn builder_writes_valid_glb_and_gltf() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = SceneBuilder::new("tiny");
    let tex = s
        .add_texture("check", texture::checker(16, 2, [0, 0, 0], [255, 255, 255]))
        .unwrap();
    let mat = s
        .add_material(Material::diffuse("m", [0.5; 3]).with_texture(tex))
        .unwrap();
    s.add_mesh(
        "floor",
        Mesh::quad(Vec2::ONE, 1.0),
        mat,
        Transform::IDENTITY,
    )
    .unwrap();
    s.add_mesh(
        "ball",
        Mesh::uv_sphere(0.2, 8, 4)
            .with_tangents()
            .with_colors(|p, _| p.abs()),
        mat,
        Transform::from_translation(Vec3::Y),
    )
    .unwrap();
    s.add_light(
        "bulb",
        Light::Point {
            color: [1.0; 3],
            intensity: 2.0,
        },
        Transform::from_translation(Vec3::Y * 2.0),
    )
    .unwrap();
    let glb = s.write(&dir.path().join("tiny.glb")).unwrap().remove(0);
    assert_eq!(glb.extension().unwrap(), "glb");
    let gltf_files = s.write_gltf(&dir.path().join("sub/tiny.gltf")).unwrap();
    assert_eq!(gltf_files.len(), 3);
    for path in [glb, gltf_files[0].clone()] {
        let l = load(&path);
        assert_min_max_match(&l, "tiny");
        assert_eq!(l.images.len(), 1);
        assert_eq!((l.images[0].width, l.images[0].height), (16, 16));
        let prim = l.doc.meshes().nth(1).unwrap().primitives().next().unwrap();
        assert!(prim.get(&gltf::Semantic::Tangents).is_some());
        assert!(prim.get(&gltf::Semantic::Colors(0)).is_some());
        // The light sits 2 m up: irradiance 2 / 2² = 0.5 at the origin.
        assert!((punctual_irradiance(&l, DVec3::ZERO, DVec3::Y) - 0.5).abs() < 1e-6);
    }
}

#[test]
fn look_at_points_minus_z_at_the_target() {
    let eye = Vec3::new(1.0, 2.0, 3.0);
    let target = Vec3::new(-2.0, 0.5, -1.0);
    let t = Transform::look_at(eye, target, Vec3::Y);
    let fwd = t.rotation * Vec3::NEG_Z;
    assert!((fwd - (target - eye).normalize()).length() < 1e-6);
    let up = t.rotation * Vec3::Y;
    assert!(up.y > 0.0 && up.dot(fwd).abs() < 1e-6);
    // Straight down still gives a valid rotation.
    let down = Transform::look_at(Vec3::Y, Vec3::ZERO, Vec3::Y);
    assert!(((down.rotation * Vec3::NEG_Z) - Vec3::NEG_Y).length() < 1e-6);
}

#[test]
fn errors_name_the_problem() {
    let err = write_scene("nope", Path::new("/tmp")).unwrap_err();
    assert!(matches!(err, SceneGenError::UnknownScene { .. }));
    assert!(err.to_string().contains("cornell"));

    let mut s = SceneBuilder::new("bad");
    assert!(matches!(
        s.add_texture("a b", texture::checker(4, 2, [0; 3], [9; 3])),
        Err(SceneGenError::InvalidName { .. })
    ));
    let spot = Light::Spot {
        color: [1.0; 3],
        intensity: 1.0,
        inner_cone_angle: 0.5,
        outer_cone_angle: 0.4,
    };
    assert!(matches!(
        s.add_light("s", spot, Transform::IDENTITY),
        Err(SceneGenError::InvalidLight { .. })
    ));
    assert!(matches!(
        s.add_material(Material::diffuse("x", [2.0, 0.0, 0.0])),
        Err(SceneGenError::InvalidMaterial { .. })
    ));
    assert!(matches!(
        s.add_instance("i", GeometryId(3), MaterialId(0), Transform::IDENTITY),
        Err(SceneGenError::InvalidMesh { .. })
    ));

    // Writing below a regular file fails with an I/O error naming the path.
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("plain");
    std::fs::write(&file, b"x").unwrap();
    let m = s.add_material(Material::diffuse("m", [0.5; 3])).unwrap();
    s.add_mesh("q", Mesh::quad(Vec2::ONE, 1.0), m, Transform::IDENTITY)
        .unwrap();
    let err = s.write_gltf(&file.join("bad.gltf")).unwrap_err();
    assert!(matches!(err, SceneGenError::Io { .. }), "{err}");
    assert!(err.to_string().contains("plain"));
}

#[test]
fn committed_scenes_are_up_to_date() {
    // scenes/ at the workspace root must be exactly what the code writes;
    // regenerate with `cargo run -p scenegen --example gen -- scenes`.
    let committed = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let dir = tempfile::tempdir().unwrap();
    for fresh in write_all(dir.path()).unwrap() {
        let name = fresh.file_name().unwrap();
        let old = std::fs::read(committed.join(name)).unwrap_or_else(|e| {
            panic!(
                "scenes/{} missing ({e}); regenerate the scenes",
                name.to_string_lossy()
            )
        });
        assert!(
            old == std::fs::read(&fresh).unwrap(),
            "scenes/{} is stale; regenerate the scenes",
            name.to_string_lossy()
        );
    }
}

#[test]
fn bad_skins_and_morph_targets_are_refused_and_sparse_targets_chosen() {
    let mut s = SceneBuilder::new("rigs");
    let m = s.add_material(Material::diffuse("m", [0.5; 3])).unwrap();
    let j = s.add_joint("j", Transform::IDENTITY, None).unwrap();
    let mesh = Mesh::cuboid(Vec3::splat(0.1));
    let n = mesh.positions.len();
    let skin = |joint: u8, w: f32| Skin {
        joints: vec![j],
        inverse_bind_matrices: vec![glam::Mat4::IDENTITY],
        vertex_joints: vec![[joint, 0, 0, 0]; n],
        vertex_weights: vec![[w, 0.0, 0.0, 0.0]; n],
    };
    let e = s.add_skinned_mesh("a", mesh.clone(), m, skin(1, 1.0)).unwrap_err().to_string();
    assert!(e.contains("vertex 0: joint index beyond the 1 joints"), "{e}");
    let e = s.add_skinned_mesh("a", mesh.clone(), m, skin(0, -1.0)).unwrap_err().to_string();
    assert!(e.contains("weights must be finite, non-negative"), "{e}");
    s.add_skinned_mesh("a", mesh.clone(), m, skin(0, 1.0)).unwrap();

    let short = MorphTarget { positions: vec![Vec3::ZERO; n - 1], normals: None };
    let e = s.add_morphed_geometry("b", mesh.clone(), vec![short], vec![1.0]).unwrap_err().to_string();
    assert!(e.contains(&format!("morph target 0: needs {n} finite displacements")), "{e}");
    let mut one = MorphTarget { positions: vec![Vec3::ZERO; n], normals: None };
    one.positions[3] = Vec3::X;
    assert_eq!(one.sparse_indices(), Some(vec![3]));
    let e = s.add_morphed_geometry("b", mesh.clone(), vec![one.clone()], vec![1.0, 2.0]).unwrap_err().to_string();
    assert!(e.contains("1 morph targets with 2 weights"), "{e}");
    let g = s.add_morphed_geometry("b", mesh, vec![one], vec![0.5]).unwrap();
    let node = s.add_instance("b", g, m, Transform::IDENTITY).unwrap();
    assert!(s.set_morph_weights(node, vec![1.0, 1.0]).is_err());
    s.set_morph_weights(node, vec![1.0]).unwrap();
    // The node's weight (1) displaces vertex 3 by the full delta.
    let posed = s.world_positions(node).unwrap();
    assert_eq!(posed[3], Mesh::cuboid(Vec3::splat(0.1)).positions[3] + Vec3::X);
}
