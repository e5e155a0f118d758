use super::*;
use crate::mesh_eval::{ReferenceInfo, compare_with_reference};
use crate::mesh_metrics::sample_surface;
use dataset::{Camera, Intrinsics};
use glam::DVec3;
use std::path::PathBuf;

/// A fresh folder for one test.
fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("eval-geometry-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The unit cube's corners and its six faces as quads, counter-clockwise from outside.
fn cube_quads() -> (Vec<[f32; 3]>, Vec<Vec<u32>>) {
    let p = (0..8).map(|c| [(c & 1) as f32, ((c >> 1) & 1) as f32, ((c >> 2) & 1) as f32]).collect();
    let q = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
    (p, q.iter().map(|f| f.to_vec()).collect())
}

fn fan(faces: &[Vec<u32>]) -> Vec<[u32; 3]> {
    faces.iter().flat_map(|f| (1..f.len() - 1).map(move |k| [f[0], f[k], f[k + 1]])).collect()
}

/// Three cameras on a ring above the unit cube, looking at its centre.
fn cameras() -> Vec<Camera> {
    let centre = DVec3::splat(0.5);
    [0.3f64, 2.4, 4.4]
        .iter()
        .map(|a| {
            let eye = centre + DVec3::new(4.0 * a.cos(), 2.5, 4.0 * a.sin());
            Camera::new(Intrinsics::from_fov_y(48, 48, 35f64.to_radians()), Camera::look_at(eye, centre, DVec3::Y)).unwrap()
        })
        .collect()
}

/// The reference of `scene` seen by `cameras`, built as `scene_reference` builds a dataset's.
fn reference_of(scene: &TriMesh, cameras: Vec<Camera>, diagonal: f64) -> SceneReference {
    let (mesh, fraction) = visible_part(scene, &cameras).unwrap();
    let info = ReferenceInfo {
        scene: "test".into(),
        triangles: scene.triangles.len(),
        visible_triangles: mesh.triangles.len(),
        visible_area_fraction: fraction,
        visible_area: mesh.area(),
        cameras: cameras.len(),
        rays: 0,
    };
    SceneReference { mesh, info, diagonal, cameras, labels: vec![] }
}

fn cube_reference() -> SceneReference {
    let (p, q) = cube_quads();
    reference_of(&TriMesh::new(p, fan(&q)), cameras(), 3f64.sqrt())
}

fn ply_ascii(p: &[[f32; 3]], faces: &[Vec<u32>], normals: Option<&[[f32; 3]]>) -> String {
    let mut s = format!("ply\nformat ascii 1.0\ncomment test\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n", p.len());
    if normals.is_some() {
        s.push_str("property float nx\nproperty float ny\nproperty float nz\n");
    }
    if !faces.is_empty() {
        s.push_str(&format!("element face {}\nproperty list uchar int vertex_indices\n", faces.len()));
    }
    s.push_str("end_header\n");
    for (k, v) in p.iter().enumerate() {
        s.push_str(&format!("{} {} {}", v[0], v[1], v[2]));
        if let Some(n) = normals {
            s.push_str(&format!(" {} {} {}", n[k][0], n[k][1], n[k][2]));
        }
        s.push('\n');
    }
    for f in faces {
        s.push_str(&format!("{} {}\n", f.len(), f.iter().map(|i| i.to_string()).collect::<Vec<_>>().join(" ")));
    }
    s
}

/// A binary PLY with `double` coordinates, an extra `uchar` property, an `int` corner count
/// and `uint` indices, and a trailing element that is not read.
fn ply_binary(p: &[[f32; 3]], faces: &[Vec<u32>], big: bool) -> Vec<u8> {
    let order = if big { "binary_big_endian" } else { "binary_little_endian" };
    let mut out = format!(
        "ply\r\nformat {order} 1.0\r\nelement vertex {}\r\nproperty double x\r\nproperty double y\r\nproperty double z\r\nproperty uchar quality\r\nelement face {}\r\nproperty list int uint vertex_index\r\nelement edge 1\r\nproperty int vertex1\r\nproperty int vertex2\r\nend_header\r\n",
        p.len(),
        faces.len()
    )
    .into_bytes();
    let put = |b: &mut Vec<u8>, le: &[u8]| {
        let mut v = le.to_vec();
        if big {
            v.reverse();
        }
        b.extend(v);
    };
    for v in p {
        for c in v {
            put(&mut out, &(*c as f64).to_le_bytes());
        }
        out.push(7);
    }
    for f in faces {
        put(&mut out, &(f.len() as i32).to_le_bytes());
        for i in f {
            put(&mut out, &i.to_le_bytes());
        }
    }
    out
}

/// An OBJ using every corner form and negative indices.
fn obj(p: &[[f32; 3]], faces: &[Vec<u32>]) -> String {
    let mut s = String::from("# test\nmtllib none.mtl\no cube\n");
    for v in p {
        s.push_str(&format!("v {} {} {}\n", v[0], v[1], v[2]));
    }
    s.push_str("vt 0 0\nvn 0 0 1\ns off\n");
    for (k, f) in faces.iter().enumerate() {
        let corners: Vec<String> = f
            .iter()
            .map(|&i| match k % 4 {
                0 => format!("{}", i + 1),
                1 => format!("{}/1", i + 1),
                2 => format!("{}//1", i as i64 - p.len() as i64),
                _ => format!("{}/1/1", i + 1),
            })
            .collect();
        s.push_str(&format!("f {}\r\n", corners.join(" ")));
    }
    s
}

fn assert_exact(b: &MeshBlock) {
    let m = &b.metrics;
    assert!(m.chamfer_l1 < 1e-6 && m.accuracy < 1e-6 && m.completeness < 1e-6, "{m:?}");
    for f in &m.f_scores {
        assert_eq!(f.f_score, 1.0, "{f:?}");
    }
}

#[test]
fn the_scenes_own_triangles_in_every_format_score_zero() {
    let dir = temp_dir("formats");
    let reference = cube_reference();
    let (p, q) = cube_quads();
    let files: [(&str, Vec<u8>, &str); 5] = [
        ("a.ply", ply_ascii(&p, &q, None).into_bytes(), "PLY ascii"),
        ("le.ply", ply_binary(&p, &q, false), "PLY binary_little_endian"),
        ("be.ply", ply_binary(&p, &q, true), "PLY binary_big_endian"),
        ("ours.ply", TriMesh::new(p.clone(), fan(&q)).to_ply(), "PLY binary_little_endian"),
        ("c.OBJ", obj(&p, &q).into_bytes(), "OBJ"),
    ];
    let ours = compare_with_reference(&TriMesh::new(p.clone(), fan(&q)), &reference, 3000).unwrap();
    for (name, bytes, format) in files {
        let path = dir.join(name);
        std::fs::write(&path, bytes).unwrap();
        let g = read_geometry(&path).unwrap();
        assert_eq!(g.input.format, format, "{name}");
        assert_eq!((g.input.kind, g.input.vertices, g.input.triangles), (GeometryKind::Mesh, 8, 12), "{name}");
        assert_eq!(g.input.polygons, if name == "ours.ply" { 0 } else { 6 }, "{name}");
        let b = score_geometry(&g, &reference, 3000).unwrap();
        assert_exact(&b);
        assert_eq!(b.metrics.normal_consistency, Some(1.0));
        // The same code as our mesh's: identical numbers.
        assert_eq!((&b.metrics, b.predicted_visible_area_fraction), (&ours.0, ours.1), "{name}");
        assert_eq!((b.level.as_ref(), b.resolution, b.input.as_ref().map(|i| i.file.as_str())), (None, None, Some(path.to_str().unwrap())));
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_real_scenes_triangles_score_zero() {
    use pathtracer::accel::AccelParams;
    let path = test_support_scene("cornell.gltf");
    let scene = pathtracer::import::load_gltf(&path, &pathtracer::import::ImportOptions::default()).unwrap();
    let (lo, hi) = (scene.bounds.min.as_dvec3() + scene.origin, scene.bounds.max.as_dvec3() + scene.origin);
    let renderer = pathtracer::render::Renderer::new(scene, &AccelParams::fast_build()).unwrap();
    let centre = 0.5 * (lo + hi);
    // From the scene's own camera, as its datasets' cameras see it.
    let eye = renderer.scene().cameras[0].c2w.w_axis.truncate();
    let camera = Camera::new(Intrinsics::from_fov_y(40, 40, 40f64.to_radians()), Camera::look_at(eye, centre, DVec3::Y)).unwrap();
    let r = pathtracer::reference::visible_surface(&renderer, &[camera]);
    let all = TriMesh::new(r.positions.iter().map(|p| p.to_array()).collect(), r.triangles.clone());
    let visible = TriMesh::new(all.positions.clone(), r.visible_mesh());
    let info = ReferenceInfo { scene: "cornell".into(), triangles: 0, visible_triangles: 0, visible_area_fraction: 0.0, visible_area: 0.0, cameras: 1, rays: 0 };
    let reference = SceneReference { mesh: visible, info, diagonal: (hi - lo).length(), cameras: vec![camera], labels: vec![] };
    let dir = temp_dir("cornell");
    let file = dir.join("cornell.ply");
    let faces: Vec<Vec<u32>> = all.triangles.iter().map(|t| t.to_vec()).collect();
    std::fs::write(&file, ply_binary(&all.positions, &faces, true)).unwrap();
    let b = score_geometry(&read_geometry(&file).unwrap(), &reference, 3000).unwrap();
    assert_exact(&b);
    std::fs::remove_dir_all(&dir).unwrap();
}

fn test_support_scene(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scenes").join(name)
}

/// The row-major 4x4 of `p ↦ linear·p + t`.
fn rows(linear: DMat3, t: DVec3) -> [[f64; 4]; 4] {
    let r = |i: usize| {
        let row = linear.row(i);
        [row.x, row.y, row.z, t[i]]
    };
    [r(0), r(1), r(2), [0.0, 0.0, 0.0, 1.0]]
}

/// Rotation about a tilted axis by 0.7 rad, scale 2.5, translation (40, -10, 70): out of the
/// test cameras' view.
fn similarity() -> [[f64; 4]; 4] {
    rows(DMat3::from_axis_angle(DVec3::new(1.0, 2.0, -0.5).normalize(), 0.7) * 2.5, DVec3::new(40.0, -10.0, 70.0))
}

fn inverse(m: &[[f64; 4]; 4]) -> [[f64; 4]; 4] {
    let a = Affine::new(m).unwrap();
    let li = a.linear.inverse();
    rows(li, -(li * a.translation))
}

#[test]
fn a_mesh_moved_by_a_similarity_scores_zero_after_the_inverse() {
    let dir = temp_dir("similarity");
    let reference = cube_reference();
    let (p, q) = cube_quads();
    let mut g = read_geometry(&{
        let f = dir.join("cube.obj");
        std::fs::write(&f, obj(&p, &q)).unwrap();
        f
    })
    .unwrap();
    let s = similarity();
    transform(&mut g, &s).unwrap();
    let Shape::Mesh(moved) = &g.shape else { panic!("a mesh") };
    // The tool's frame: far from the scene, so nothing is seen and the error says why.
    let file = dir.join("moved.ply");
    std::fs::write(&file, ply_binary(&moved.positions, &q, false)).unwrap();
    let mut g = read_geometry(&file).unwrap();
    let e = score_geometry(&g, &reference, 1000).unwrap_err().to_string();
    assert!(e.contains("moved.ply") && e.contains("none of the mesh's 12 triangles is seen") && e.contains("dataset's frame"), "{e}");
    // Back with the inverse, given as text the way `--to-dataset` takes it, and as a JSON file.
    let inv = inverse(&s);
    let text = inv.iter().flatten().map(|v| format!("{v:e}")).collect::<Vec<_>>().join(", ");
    let parsed = parse_matrix(&text).unwrap();
    assert_eq!(parsed, inv);
    let json = dir.join("to_dataset.json");
    std::fs::write(&json, serde_json::to_string(&inv).unwrap()).unwrap();
    assert_eq!(parse_matrix(json.to_str().unwrap()).unwrap(), inv);
    transform(&mut g, &parsed).unwrap();
    assert_eq!(g.input.to_dataset, Some(inv));
    let b = score_geometry(&g, &reference, 3000).unwrap();
    let m = &b.metrics;
    assert!(m.chamfer_l1 < 1e-6, "{m:?}");
    assert!(m.f_scores.iter().all(|f| f.f_score == 1.0), "{m:?}");
    assert!((m.normal_consistency.unwrap() - 1.0).abs() < 1e-9);
    // Two transforms compose: S then S⁻¹ records the identity.
    let mut twice = read_geometry(&dir.join("cube.obj")).unwrap();
    transform(&mut twice, &s).unwrap();
    transform(&mut twice, &inv).unwrap();
    let id = twice.input.to_dataset.unwrap();
    for (r, row) in id.iter().enumerate() {
        for (c, v) in row.iter().enumerate() {
            assert!((v - f64::from(u8::from(r == c))).abs() < 1e-12, "{id:?}");
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_point_cloud_on_the_surface_scores_near_zero_and_normals_only_when_given() {
    let dir = temp_dir("points");
    let reference = cube_reference();
    let s = sample_surface(&reference.mesh, 40_000, 11).unwrap();
    let points: Vec<[f32; 3]> = s.points.iter().map(|p| p.to_array()).collect();
    let normals: Vec<[f32; 3]> = s.normals.iter().map(|n| (-*n).as_vec3().to_array()).collect();
    let bare = dir.join("bare.ply");
    std::fs::write(&bare, ply_ascii(&points, &[], None)).unwrap();
    let g = read_geometry(&bare).unwrap();
    assert_eq!((g.input.kind, g.input.vertices, g.input.normals), (GeometryKind::PointCloud, 40_000, false));
    let b = score_geometry(&g, &reference, 10_000).unwrap();
    let m = &b.metrics;
    assert!(m.accuracy < 1e-6, "{m:?}");
    // Completeness: the mean distance to the nearest of 40 000 points on 3 m², about
    // 0.5 / √(40 000 / 3) ≈ 0.004 m.
    assert!(m.completeness < 0.006 && m.chamfer_l1 < 0.003, "{m:?}");
    assert_eq!(m.f_scores[2].f_score, 1.0);
    assert_eq!(m.normal_consistency, None);
    assert_eq!((m.predicted_area, m.predicted_triangles, b.predicted_visible_area_fraction), (0.0, 0, 1.0));
    let input = b.input.as_ref().unwrap();
    assert_eq!(input.measured_points, Some(10_000));
    assert!(input.notes.iter().any(|n| n.contains("Normal consistency is absent: the points carry no normals")), "{:?}", input.notes);
    let json = serde_json::to_value(&b).unwrap();
    assert_eq!(json["input"]["kind"], "point cloud");
    assert!(json["metrics"].get("normal_consistency").is_none());
    assert!(crate::report::mesh_section(&b).contains("| normal consistency | absent |"));
    // With normals (flipped: the metric is unsigned), as PLY and as OBJ `vn` one per `v`.
    let with = dir.join("normals.ply");
    std::fs::write(&with, ply_ascii(&points, &[], Some(&normals))).unwrap();
    let mut text = String::new();
    for (p, n) in points.iter().zip(&normals).take(5000) {
        text.push_str(&format!("v {} {} {}\nvn {} {} {}\n", p[0], p[1], p[2], n[0], n[1], n[2]));
    }
    let obj_file = dir.join("points.obj");
    std::fs::write(&obj_file, text).unwrap();
    for file in [with, obj_file] {
        let g = read_geometry(&file).unwrap();
        assert!(g.input.normals && g.input.kind == GeometryKind::PointCloud, "{:?}", g.input);
        let m = score_geometry(&g, &reference, 10_000).unwrap().metrics;
        assert!(m.accuracy < 1e-6);
        // Near the cube's edges the nearest point may lie on the other face.
        assert!(m.normal_consistency.unwrap() > 0.97, "{m:?}");
    }
    // Zero normals (as splat exports write) are not normals.
    let zeros = dir.join("zeros.ply");
    std::fs::write(&zeros, ply_ascii(&points[..100], &[], Some(&vec![[0.0; 3]; 100]))).unwrap();
    let g = read_geometry(&zeros).unwrap();
    assert!(!g.input.normals && g.input.notes.iter().any(|n| n.contains("100 of 100 points have a zero")), "{:?}", g.input.notes);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn non_finite_vertices_are_dropped_and_counted() {
    let dir = temp_dir("nan");
    let (mut p, q) = cube_quads();
    p.push([f32::NAN, 0.0, 0.0]);
    let mut q2 = q.clone();
    q2.push(vec![0, 1, 8]);
    let file = dir.join("nan.ply");
    std::fs::write(&file, ply_ascii(&p, &q2, None)).unwrap();
    let g = read_geometry(&file).unwrap();
    assert_eq!((g.input.vertices, g.input.dropped_vertices, g.input.triangles, g.input.dropped_triangles), (8, 1, 12, 1));
    assert!(g.input.notes.iter().any(|n| n.contains("1 of 9 vertices")), "{:?}", g.input.notes);
    assert_exact(&score_geometry(&g, &cube_reference(), 2000).unwrap());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The error reading `bytes` as `name`, which must name the file and contain every `want`.
fn refused(dir: &Path, name: &str, bytes: &[u8], want: &[&str]) {
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    let e = read_geometry(&path).unwrap_err().to_string();
    assert!(e.contains(name), "{e}");
    for w in want {
        assert!(e.contains(w), "{name}: {e:?} lacks {w:?}");
    }
}

#[test]
fn malformed_files_are_clear_errors() {
    let dir = temp_dir("malformed");
    let (p, q) = cube_quads();
    let good = ply_binary(&p, &q, false);
    let start = std::time::Instant::now();
    refused(&dir, "truncated.ply", &good[..good.len() - 30], &["face 4 (byte", "truncated"]);
    let mut bad_index = q.clone();
    bad_index[3][2] = 8;
    refused(&dir, "index.ply", ply_ascii(&p, &bad_index, None).as_bytes(), &["face 3 (line 22)", "vertex 8, out of range", "8 vertices"]);
    let lying = String::from_utf8_lossy(&good).replace("element vertex 8", "element vertex 40000000").into_bytes();
    refused(&dir, "lying.ply", &lying, &["declares 40000000 `vertex` elements", "at most 13 of them"]);
    let huge = String::from_utf8_lossy(&good).replace("element vertex 8", "element vertex 800000000").into_bytes();
    refused(&dir, "huge.ply", &huge, &["declares 800000000 vertices, more than the 50000000"]);
    let lying = ply_ascii(&p, &q, None).replace("element face 6", "element face 7");
    refused(&dir, "lying_ascii.ply", lying.as_bytes(), &["declares 7 `face` elements", "at most 6"]);
    let mut latin = b"ply\nformat ascii 1.0\ncomment caf\xe9\nelement vertex 0\nend_header\n".to_vec();
    refused(&dir, "latin.ply", &latin, &["header line 3 is not text"]);
    latin.truncate(4);
    refused(&dir, "short.ply", &latin, &["no `end_header`"]);
    refused(&dir, "notply.ply", b"solid x\n", &["not a PLY file"]);
    refused(&dir, "mesh.stl", b"solid x\n", &["not a geometry file this reads"]);
    refused(&dir, "partial.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nend_header\n0 0 0 1\n", &["some but not all of nx, ny, nz"]);
    refused(&dir, "intx.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty int x\nproperty float y\nproperty float z\nend_header\n0 0 0\n", &["`x` must be a float or double"]);
    refused(&dir, "extra.ply", ply_ascii(&p, &q, None).replace("0 0 0\n", "0 0 0 5\n").as_bytes(), &["vertex 0 (line 11)", "more values"]);
    refused(&dir, "word.ply", ply_ascii(&p, &q, None).replace("1 1 1\n", "1 one 1\n").as_bytes(), &["vertex 7 (line 18)", "`one` is not a number"]);
    refused(&dir, "two.ply", ply_ascii(&p, &[vec![0, 1]], None).as_bytes(), &["face 0", "2 corners"]);
    refused(&dir, "strips.ply", b"ply\nformat ascii 1.0\nelement vertex 0\nelement tristrips 0\nend_header\n", &["triangle strips"]);
    refused(&dir, "empty.ply", b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n", &["no vertices"]);
    refused(&dir, "forward.obj", b"v 0 0 0\nv 1 0 0\nf 1 2 3\nv 0 1 0\n", &["line 3", "vertex 3", "2 vertices are defined above"]);
    refused(&dir, "zero.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", &["line 4", "vertex 0"]);
    refused(&dir, "neg.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n", &["line 4", "vertex -4"]);
    refused(&dir, "short.obj", b"v 0 0 0\nv 1 0\n", &["line 2", "2 numbers"]);
    refused(&dir, "latin.obj", b"# caf\xe9 is a comment\nv 0 0 0\ng caf\xe9\n", &["line 3 is not text"]);
    refused(&dir, "nanonly.obj", b"v nan 0 0\n", &["none of its 1 vertices"]);
    // Not regular files: refused at once, never opened.
    let e = read_geometry(&dir).unwrap_err().to_string();
    assert!(e.contains("not a regular file (a folder)"), "{e}");
    #[cfg(unix)]
    {
        let e = read_geometry(Path::new("/dev/zero")).unwrap_err().to_string();
        assert!(e.contains("/dev/zero: not a regular file (a device)"), "{e}");
        let fifo = dir.join("fifo.ply");
        if std::process::Command::new("mkfifo").arg(&fifo).status().is_ok_and(|s| s.success()) {
            let e = read_geometry(&fifo).unwrap_err().to_string();
            assert!(e.contains("fifo.ply: not a regular file (a FIFO)"), "{e}");
        }
    }
    let e = read_geometry(&dir.join("missing.ply")).unwrap_err().to_string();
    assert!(e.contains("missing.ply"), "{e}");
    assert!(start.elapsed().as_secs_f64() < 5.0, "{:?}", start.elapsed());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_transforms_are_refused_and_leave_the_geometry() {
    let dir = temp_dir("transforms");
    let (p, q) = cube_quads();
    let file = dir.join("cube.ply");
    std::fs::write(&file, ply_ascii(&p, &q, None)).unwrap();
    let mut g = read_geometry(&file).unwrap();
    let before = g.clone();
    let mut m = similarity();
    m[3] = [0.0, 0.0, 0.5, 1.0];
    assert!(transform(&mut g, &m).unwrap_err().to_string().contains("not affine"));
    let mut m = similarity();
    m[1][2] = f64::NAN;
    assert!(transform(&mut g, &m).unwrap_err().to_string().contains("non-finite"));
    let mut m = similarity();
    m[2] = [0.0, 0.0, 0.0, 4.0];
    assert!(transform(&mut g, &m).unwrap_err().to_string().contains("singular"));
    let mut m = similarity();
    m[0][3] = 1e39;
    assert!(transform(&mut g, &m).unwrap_err().to_string().contains("out of range"));
    assert_eq!(g, before);
    // Normals go through the inverse transpose: a plane's normal stays normal to it under a shear.
    let plane = dir.join("plane.ply");
    let pts = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]];
    std::fs::write(&plane, ply_ascii(&pts, &[], Some(&[[0.0, 0.0, 2.0]; 4]))).unwrap();
    let mut g = read_geometry(&plane).unwrap();
    let shear = DMat3::from_cols(DVec3::X, DVec3::new(2.0, 1.0, 0.0), DVec3::Z);
    transform(&mut g, &rows(DMat3::from_rotation_x(0.4) * shear, DVec3::ONE)).unwrap();
    let Shape::Points { points, normals: Some(normals) } = &g.shape else { panic!("points with normals") };
    let n = Vec3::from(normals[0]);
    assert!((n.length() - 1.0).abs() < 1e-6);
    for k in 1..4 {
        let edge = Vec3::from(points[k]) - Vec3::from(points[0]);
        assert!(n.dot(edge).abs() < 1e-6, "{n} · {edge}");
    }
    // Matrices as text.
    assert_eq!(parse_matrix("[[1,0,0,0],[0,1,0,0],[0,0,1,0]]").unwrap()[3], [0.0, 0.0, 0.0, 1.0]);
    assert!(parse_matrix("1 0 0 0 0 1 0 0 0 0 1 0 0 0").unwrap_err().contains("14 numbers"));
    assert!(parse_matrix("1 0 0 0 0 1 0 0 0 0 0 0 0 0 0 1").unwrap_err().contains("singular"));
    assert!(parse_matrix("1 0 0 0 0 1 0 0 0 0 1 0 0 0 nan 1").unwrap_err().contains("not a finite number"));
    let e = parse_matrix(dir.join("nope.json").to_str().unwrap()).unwrap_err();
    assert!(e.contains("neither 16 numbers nor a file") && e.contains("nope.json"), "{e}");
    let words = dir.join("words.json");
    std::fs::write(&words, r#"{"transform": [[1, 0, 0, 0]]}"#).unwrap();
    assert!(parse_matrix(words.to_str().unwrap()).unwrap_err().contains("words.json: not a list of numbers"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn our_mesh_blocks_json_is_unchanged() {
    // Our runs' `mesh` block keeps its keys, their order and its report text: the fields for
    // another tool's geometry are absent from it.
    let reference = cube_reference();
    let (p, q) = cube_quads();
    let (metrics, fraction) = compare_with_reference(&TriMesh::new(p, fan(&q)), &reference, 500).unwrap();
    let level = crate::mesh_extract::LevelChoice { level: 3.0, source: "data".into(), reason: "r".into(), candidates: Vec::new(), rays: 1, views: 1 };
    let b = MeshBlock {
        metrics,
        predicted_visible_area_fraction: fraction,
        reference: reference.info.clone(),
        resolution: Some(64),
        level: Some(level),
        mesh_file: Some("mesh.ply".into()),
        picture: None,
        input: None,
    };
    let text = serde_json::to_string(&b).unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let keys: Vec<&str> = v.as_object().unwrap().keys().map(String::as_str).collect();
    assert_eq!(keys, ["level", "mesh_file", "metrics", "picture", "predicted_visible_area_fraction", "reference", "resolution"]);
    let order: Vec<usize> = ["\"metrics\"", "\"predicted_visible_area_fraction\"", "\"reference\"", "\"resolution\":64", "\"level\"", "\"mesh_file\"", "\"picture\":null"]
        .iter()
        .map(|k| text.find(k).unwrap_or_else(|| panic!("{k} in {text}")))
        .collect();
    assert!(order.is_sorted(), "{text}");
    assert!(text.contains("\"normal_consistency\":1.0,"), "{text}");
    assert_eq!(serde_json::from_str::<MeshBlock>(&text).unwrap(), b);
    let section = crate::report::mesh_section(&b);
    assert!(section.contains("The mesh extracted at density level 3.000 /m (data) on a grid of 64 cells along the box's longest side, against the scene's triangles"), "{section}");
    assert!(section.contains("| normal consistency | 1.000 |\n\nLevel: r.\n"), "{section}");
}
