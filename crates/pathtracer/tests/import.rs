//! glTF import against hand-computed ground truth: small glTF files built in the test (JSON
//! plus base64 or external or GLB buffers), the malformed corpus under `tests/data/import/`,
//! and the project's own scenes.

use std::path::{Path, PathBuf};

use glam::{DVec3, Vec3};
use pathtracer::import::{load_gltf, load_gltf_from_slice, ImportOptions};
use pathtracer::scene::{Filter, Light, Scene, Wrap};
use pathtracer::PathTracerError;
use serde_json::{json, Value};

// ---------------------------------------------------------------------------------------
// A tiny glTF writer.

fn base64(bytes: &[u8]) -> String {
    const T: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in bytes.chunks(3) {
        let b = [c[0], *c.get(1).unwrap_or(&0), *c.get(2).unwrap_or(&0)];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= c.len() {
                s.push(T[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

/// Where the builder puts its binary buffer.
enum BufferMode<'a> {
    DataUri,
    External(&'a str),
    Glb,
}

#[derive(Default)]
struct Builder {
    bin: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
    /// Extra top-level JSON members (nodes, meshes, materials, ...).
    doc: serde_json::Map<String, Value>,
}

impl Builder {
    fn view(&mut self, bytes: &[u8], stride: Option<usize>) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let mut v = json!({"buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len()});
        if let Some(s) = stride {
            v["byteStride"] = json!(s);
        }
        self.bin.extend_from_slice(bytes);
        self.views.push(v);
        self.views.len() - 1
    }
    fn accessor(&mut self, a: Value) -> usize {
        self.accessors.push(a);
        self.accessors.len() - 1
    }
    fn f32s<const N: usize>(&mut self, data: &[[f32; N]], ty: &str) -> usize {
        let bytes: Vec<u8> = data.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
        let view = self.view(&bytes, None);
        let mut a = json!({"bufferView": view, "componentType": 5126, "count": data.len(), "type": ty});
        if N == 3 {
            let mut lo = [f32::INFINITY; N];
            let mut hi = [f32::NEG_INFINITY; N];
            for e in data {
                for k in 0..N {
                    lo[k] = lo[k].min(e[k]);
                    hi[k] = hi[k].max(e[k]);
                }
            }
            a["min"] = json!(lo.to_vec());
            a["max"] = json!(hi.to_vec());
        }
        self.accessor(a)
    }
    fn positions(&mut self, p: &[[f32; 3]]) -> usize {
        self.f32s(p, "VEC3")
    }
    fn indices_u16(&mut self, idx: &[u16]) -> usize {
        let bytes: Vec<u8> = idx.iter().flat_map(|x| x.to_le_bytes()).collect();
        let view = self.view(&bytes, None);
        self.accessor(json!({"bufferView": view, "componentType": 5123, "count": idx.len(), "type": "SCALAR"}))
    }
    fn set(&mut self, key: &str, v: Value) {
        self.doc.insert(key.to_string(), v);
    }
    fn json(&self, mode: &BufferMode<'_>) -> Value {
        let mut doc = self.doc.clone();
        doc.insert("asset".into(), json!({"version": "2.0"}));
        let mut buffer = json!({"byteLength": self.bin.len()});
        match mode {
            BufferMode::DataUri => buffer["uri"] = json!(format!("data:application/octet-stream;base64,{}", base64(&self.bin))),
            BufferMode::External(uri) => buffer["uri"] = json!(uri),
            BufferMode::Glb => {}
        }
        if !self.bin.is_empty() {
            doc.insert("buffers".into(), json!([buffer]));
            doc.insert("bufferViews".into(), json!(self.views));
            doc.insert("accessors".into(), json!(self.accessors));
        }
        Value::Object(doc)
    }
    fn glb(&self) -> Vec<u8> {
        let mut j = serde_json::to_vec(&self.json(&BufferMode::Glb)).unwrap();
        while !j.len().is_multiple_of(4) {
            j.push(b' ');
        }
        let mut b = self.bin.clone();
        while !b.len().is_multiple_of(4) {
            b.push(0);
        }
        let mut out = b"glTF".to_vec();
        out.extend_from_slice(&2u32.to_le_bytes());
        out.extend_from_slice(&((12 + 8 + j.len() + 8 + b.len()) as u32).to_le_bytes());
        out.extend_from_slice(&(j.len() as u32).to_le_bytes());
        out.extend_from_slice(b"JSON");
        out.extend_from_slice(&j);
        out.extend_from_slice(&(b.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&b);
        out
    }
    fn load(&self) -> Result<Scene, PathTracerError> {
        let bytes = serde_json::to_vec(&self.json(&BufferMode::DataUri)).unwrap();
        load_gltf_from_slice(&bytes, None, "test.gltf", &ImportOptions::default())
    }
}

/// One-mesh scene: `prim` is the primitive JSON, the single node has `node` members.
fn one_node(b: &mut Builder, prim: Value, node: Value) {
    let mut n = node;
    n["mesh"] = json!(0);
    b.set("meshes", json!([{"primitives": [prim]}]));
    b.set("nodes", json!([n]));
    b.set("scenes", json!([{"nodes": [0]}]));
}

fn world(scene: &Scene, i: usize) -> DVec3 {
    scene.origin + scene.mesh.positions[i].as_dvec3()
}

fn close(a: DVec3, b: DVec3, tol: f64) -> bool {
    (a - b).length() <= tol
}

fn tmp_dir(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("import-tests").join(name);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

const TRI: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];

// ---------------------------------------------------------------------------------------
// Geometry and transforms.

#[test]
fn hierarchy_trs_matrix_and_negative_scale() {
    let mut b = Builder::default();
    let pos = b.positions(&TRI);
    let nrm = b.f32s(&[[0.0, 0.0, 1.0]; 3], "VEC3");
    let idx = b.indices_u16(&[0, 1, 2]);
    b.set("meshes", json!([{"primitives": [{"attributes": {"POSITION": pos, "NORMAL": nrm}, "indices": idx}]}]));
    let h = std::f64::consts::FRAC_1_SQRT_2;
    b.set(
        "nodes",
        json!([
            // A: T(10,0,0) · R_y(90°) · S(2), parent of B.
            {"translation": [10, 0, 0], "rotation": [0, h, 0, h], "scale": [2, 2, 2], "children": [1]},
            // B: matrix T(0,1,0), column-major.
            {"matrix": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,1,0,1], "mesh": 0},
            // C: mirror in X, moved to z = 5.
            {"translation": [0, 0, 5], "scale": [-1, 1, 1], "mesh": 0}
        ]),
    );
    b.set("scenes", json!([{"nodes": [0, 2]}]));
    let s = b.load().unwrap();
    assert_eq!(s.mesh.indices.len(), 2);
    // One mesh under two nodes (B and C) is two objects, numbered in traversal order, each
    // owning its own triangle: the label files give them two IDs.
    let placed: Vec<(usize, usize, u32, u32)> = s.objects.iter().map(|o| (o.node, o.mesh, o.first_triangle, o.triangles)).collect();
    assert_eq!(placed, vec![(1, 0, 0, 1), (2, 0, 1, 1)]);
    assert_eq!((s.object_of(0), s.object_of(1), s.object_of(2)), (Some(0), Some(1), None));
    // Hand-computed: R_y(90°) maps (x, y, z) → (z, y, −x).
    let expected_b = [DVec3::new(10.0, 2.0, 0.0), DVec3::new(10.0, 2.0, -2.0), DVec3::new(10.0, 4.0, 0.0)];
    let expected_c = [DVec3::new(0.0, 0.0, 5.0), DVec3::new(-1.0, 0.0, 5.0), DVec3::new(0.0, 1.0, 5.0)];
    for (k, e) in expected_b.iter().chain(&expected_c).enumerate() {
        assert!(close(world(&s, k), *e, 1e-5), "vertex {k}: {} vs {e}", world(&s, k));
    }
    assert!((s.mesh.normals[0] - Vec3::X).length() < 1e-6, "R_y(90°) takes +Z to +X");
    assert!((s.mesh.normals[3] - Vec3::Z).length() < 1e-6, "a mirror in X keeps +Z");
    // Node C mirrors: its winding must be flipped so the geometric normal agrees with the
    // normal attribute on every triangle.
    assert_eq!(s.mesh.indices[1], [3, 5, 4]);
    for t in &s.mesh.indices {
        let p = |k: u32| s.mesh.positions[k as usize];
        let g = (p(t[1]) - p(t[0])).cross(p(t[2]) - p(t[0]));
        assert!(g.dot(s.mesh.normals[t[0] as usize]) > 0.0, "triangle {t:?} winding disagrees with its normal");
    }
    // Origin is the bounds' centre; bounds hold every vertex.
    let lo = DVec3::new(-1.0, 0.0, -2.0);
    let hi = DVec3::new(10.0, 4.0, 5.0);
    assert!(close(s.origin, 0.5 * (lo + hi), 1e-9));
    assert!(close(s.bounds.min.as_dvec3() + s.origin, lo, 1e-5) && close(s.bounds.max.as_dvec3() + s.origin, hi, 1e-5));
}

#[test]
fn strip_and_fan_follow_the_spec_formulas() {
    let verts: Vec<[f32; 3]> = (0..5).map(|i| [i as f32, (i % 2) as f32, 0.0]).collect();
    for (mode, indexed, expected) in [
        // TRIANGLE_STRIP: p_i = (v_i, v_{i+1+i%2}, v_{i+2-i%2})
        (5, false, vec![[0, 1, 2], [1, 3, 2], [2, 3, 4]]),
        // TRIANGLE_FAN: p_i = (v_{i+1}, v_{i+2}, v_0), here through indices 4,3,2,1,0.
        (6, true, vec![[3, 2, 4], [2, 1, 4], [1, 0, 4]]),
    ] {
        let mut b = Builder::default();
        let pos = b.positions(&verts);
        let nrm = b.f32s(&[[0.0, 0.0, 1.0]; 5], "VEC3");
        let mut prim = json!({"attributes": {"POSITION": pos, "NORMAL": nrm}, "mode": mode});
        if indexed {
            prim["indices"] = json!(b.indices_u16(&[4, 3, 2, 1, 0]));
        }
        one_node(&mut b, prim, json!({}));
        let s = b.load().unwrap();
        assert_eq!(s.mesh.indices, expected, "mode {mode}");
        assert_eq!(s.mesh.material, vec![0; 3]);
        assert_eq!(s.materials.len(), 1, "the default material is appended");
    }
}

#[test]
fn points_and_lines_are_skipped_with_a_warning() {
    let mut b = Builder::default();
    let pos = b.positions(&TRI);
    b.set("meshes", json!([{"primitives": [{"attributes": {"POSITION": pos}, "mode": 0}, {"attributes": {"POSITION": pos}, "mode": 1}, {"attributes": {"POSITION": pos}}]}]));
    b.set("nodes", json!([{"mesh": 0}]));
    let s = b.load().unwrap();
    assert_eq!(s.mesh.indices.len(), 1);
    assert_eq!(s.warnings.iter().filter(|w| w.contains("not a surface")).count(), 2, "{:?}", s.warnings);
}

#[test]
fn index_component_types_and_normalized_attributes() {
    let mut results = Vec::new();
    for (ct, bytes) in [(5121u32, vec![0u8, 1, 2, 0]), (5123, [0u16, 1, 2].iter().flat_map(|x| x.to_le_bytes()).collect()), (5125, [0u32, 1, 2].iter().flat_map(|x| x.to_le_bytes()).collect())] {
        let mut b = Builder::default();
        let pos = b.positions(&TRI);
        let iv = b.view(&bytes, None);
        let idx = b.accessor(json!({"bufferView": iv, "componentType": ct, "count": 3, "type": "SCALAR"}));
        // TEXCOORD_0 as normalized u8 (255, 51): (1.0, 0.2); TEXCOORD_1 normalized u16.
        let uv_view = b.view(&[255, 51, 0, 255, 0, 0], None);
        let uv0 = b.accessor(json!({"bufferView": uv_view, "componentType": 5121, "normalized": true, "count": 3, "type": "VEC2"}));
        let uv1_bytes: Vec<u8> = [65535u16, 0, 0, 65535, 0, 0].iter().flat_map(|x| x.to_le_bytes()).collect();
        let uv1_view = b.view(&uv1_bytes, None);
        let uv1 = b.accessor(json!({"bufferView": uv1_view, "componentType": 5123, "normalized": true, "count": 3, "type": "VEC2"}));
        // COLOR_0 as normalized u8 VEC3 (alpha becomes 1); NORMAL as normalized i8.
        let col_view = b.view(&[255, 0, 51, 0, 255, 0, 0, 0, 255], None);
        let col = b.accessor(json!({"bufferView": col_view, "componentType": 5121, "normalized": true, "count": 3, "type": "VEC3"}));
        let n_view = b.view(&[0, 0, 127, 0, 0, 0, 127, 0, 0, 0, 127, 0], Some(4));
        let nrm = b.accessor(json!({"bufferView": n_view, "componentType": 5120, "normalized": true, "count": 3, "type": "VEC3"}));
        one_node(
            &mut b,
            json!({"attributes": {"POSITION": pos, "NORMAL": nrm, "TEXCOORD_0": uv0, "TEXCOORD_1": uv1, "COLOR_0": col}, "indices": idx}),
            json!({}),
        );
        let s = b.load().unwrap();
        assert_eq!(s.mesh.indices, vec![[0, 1, 2]], "component type {ct}");
        assert!((s.mesh.uv0[0] - glam::Vec2::new(1.0, 0.2)).length() < 1e-7);
        assert_eq!(s.mesh.uv1[1], glam::Vec2::new(0.0, 1.0));
        assert!((s.mesh.colors[0] - glam::Vec4::new(1.0, 0.0, 0.2, 1.0)).length() < 1e-7);
        assert_eq!(s.mesh.normals[2], Vec3::Z);
        results.push(s.mesh.positions);
    }
    assert!(results.windows(2).all(|w| w[0] == w[1]));
}

#[test]
fn sparse_accessor_replaces_elements() {
    let mut b = Builder::default();
    let pos = b.positions(&TRI);
    let idx_view = b.view(&[2u8, 0, 0, 0], None);
    let val_bytes: Vec<u8> = [0.0f32, 3.0, 0.0].iter().flat_map(|x| x.to_le_bytes()).collect();
    let val_view = b.view(&val_bytes, None);
    b.accessors[pos]["sparse"] = json!({"count": 1, "indices": {"bufferView": idx_view, "componentType": 5121}, "values": {"bufferView": val_view}});
    b.accessors[pos]["max"] = json!([1.0, 3.0, 0.0]);
    one_node(&mut b, json!({"attributes": {"POSITION": pos}}), json!({}));
    let s = b.load().unwrap();
    // Flat normals: three unshared vertices in triangle order.
    assert!(close(world(&s, 2), DVec3::new(0.0, 3.0, 0.0), 1e-6));
    assert!(close(world(&s, 1), DVec3::new(1.0, 0.0, 0.0), 1e-6));
}

#[test]
fn interleaved_buffer_view() {
    let mut b = Builder::default();
    // position (12 bytes) + normal (12 bytes), stride 24.
    let mut bytes = Vec::new();
    for p in TRI {
        bytes.extend(p.iter().flat_map(|x| x.to_le_bytes()));
        bytes.extend([0.0f32, 0.0, -1.0].iter().flat_map(|x| x.to_le_bytes()));
    }
    let v = b.view(&bytes, Some(24));
    let pos = b.accessor(json!({"bufferView": v, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0,0,0], "max": [1,1,0]}));
    let nrm = b.accessor(json!({"bufferView": v, "byteOffset": 12, "componentType": 5126, "count": 3, "type": "VEC3"}));
    one_node(&mut b, json!({"attributes": {"POSITION": pos, "NORMAL": nrm}}), json!({}));
    let s = b.load().unwrap();
    for (k, p) in TRI.iter().enumerate() {
        assert!(close(world(&s, k), DVec3::from(p.map(f64::from)), 1e-7));
        assert_eq!(s.mesh.normals[k], Vec3::NEG_Z);
    }
}

#[test]
fn missing_normals_become_flat_face_normals() {
    let mut b = Builder::default();
    // A quad folded along its diagonal: two triangles with different planes, shared vertices.
    let pos = b.positions(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 1.0]]);
    let idx = b.indices_u16(&[0, 1, 2, 1, 3, 2]);
    one_node(&mut b, json!({"attributes": {"POSITION": pos}, "indices": idx}), json!({}));
    let s = b.load().unwrap();
    assert_eq!(s.mesh.positions.len(), 6, "flat shading unshares vertices");
    let expect = [Vec3::Z, Vec3::new(-1.0, -1.0, 1.0).normalize()];
    for (t, tri) in s.mesh.indices.iter().enumerate() {
        for &k in tri {
            assert!((s.mesh.normals[k as usize] - expect[t]).length() < 1e-6, "triangle {t}");
        }
    }
}

#[test]
fn far_from_origin_keeps_f32_precision() {
    let mut b = Builder::default();
    // A 1 mm triangle, 100 km away, placed by the node so the f64 path matters.
    let pos = b.positions(&[[0.0, 0.0, 0.0], [0.001, 0.0, 0.0], [0.0, 0.001, 0.0]]);
    one_node(&mut b, json!({"attributes": {"POSITION": pos}}), json!({"translation": [100000.125, 100000.0, -100000.0]}));
    let s = b.load().unwrap();
    let e = DVec3::new(100000.125, 100000.0, -100000.0);
    assert!(close(s.origin, e + DVec3::new(0.0005, 0.0005, 0.0), 1e-9));
    // Relative to the origin, the vertices are resolved to ~1e-10 m, not f32's 8 mm at 1e5.
    assert!(close(world(&s, 1), e + DVec3::new(0.001, 0.0, 0.0), 1e-9));
    assert!(s.bounds.diagonal() < 0.0015);
}

// ---------------------------------------------------------------------------------------
// Buffers: GLB, external files, data URIs.

fn triangle_builder() -> Builder {
    let mut b = Builder::default();
    let pos = b.positions(&TRI);
    let idx = b.indices_u16(&[0, 1, 2]);
    one_node(&mut b, json!({"attributes": {"POSITION": pos}, "indices": idx}), json!({}));
    b
}

#[test]
fn glb_external_and_data_uri_buffers_agree() {
    let b = triangle_builder();
    let dir = tmp_dir("buffers");
    let glb = dir.join("tri.glb");
    std::fs::write(&glb, b.glb()).unwrap();
    std::fs::write(dir.join("my buffer.bin"), &b.bin).unwrap();
    let ext = dir.join("tri_external.gltf");
    std::fs::write(&ext, serde_json::to_vec(&b.json(&BufferMode::External("my%20buffer.bin"))).unwrap()).unwrap();
    let data = dir.join("tri_data.gltf");
    std::fs::write(&data, serde_json::to_vec(&b.json(&BufferMode::DataUri)).unwrap()).unwrap();
    let opts = ImportOptions::default();
    let scenes: Vec<Scene> = [&glb, &ext, &data].iter().map(|p| load_gltf(p, &opts).unwrap()).collect();
    for s in &scenes {
        assert_eq!(s.mesh.indices.len(), 1);
        for (&k, p) in s.mesh.indices[0].iter().zip(&TRI) {
            let w = s.origin + s.mesh.positions[k as usize].as_dvec3();
            assert!(close(w, DVec3::from(p.map(f64::from)), 1e-7));
        }
    }
    assert!(scenes[0].name.ends_with("tri.glb"));
    // The committed GLB fixture too.
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/import/valid_triangle.glb");
    assert_eq!(load_gltf(&fixture, &opts).unwrap().mesh.indices.len(), 1);
}

#[test]
fn byte_budget_is_enforced() {
    let b = triangle_builder();
    let bytes = serde_json::to_vec(&b.json(&BufferMode::DataUri)).unwrap();
    let opts = ImportOptions { max_buffer_bytes: 10, ..ImportOptions::default() };
    let e = load_gltf_from_slice(&bytes, None, "budget.gltf", &opts).unwrap_err().to_string();
    assert!(e.contains("budget.gltf") && e.contains("limit"), "{e}");
    let opts = ImportOptions { max_triangles: 0, ..ImportOptions::default() };
    let e = load_gltf_from_slice(&bytes, None, "budget.gltf", &opts).unwrap_err().to_string();
    assert!(e.contains("limit"), "{e}");
}

// ---------------------------------------------------------------------------------------
// Lights, cameras, materials.

#[test]
fn punctual_lights_units_and_directions() {
    let mut b = triangle_builder();
    let h = std::f64::consts::FRAC_1_SQRT_2;
    b.set("extensionsUsed", json!(["KHR_lights_punctual"]));
    b.set(
        "extensions",
        json!({"KHR_lights_punctual": {"lights": [
            {"type": "point", "color": [1.0, 0.5, 0.25], "intensity": 100.0, "range": 20.0},
            {"type": "spot", "intensity": 50.0, "spot": {"innerConeAngle": 0.2, "outerConeAngle": 0.4}},
            {"type": "directional", "color": [1.0, 1.0, 0.5], "intensity": 3.0}
        ]}}),
    );
    // R_x(−90°) turns the node's −Z into world −Y (pointing down).
    let down = json!([-h, 0, 0, h]);
    b.doc["nodes"].as_array_mut().unwrap().extend([
        json!({"translation": [1, 2, 3], "extensions": {"KHR_lights_punctual": {"light": 0}}}),
        json!({"translation": [0, 4, 0], "rotation": down, "extensions": {"KHR_lights_punctual": {"light": 1}}}),
        json!({"rotation": down, "scale": [5, 5, 5], "extensions": {"KHR_lights_punctual": {"light": 2}}}),
    ]);
    b.doc["scenes"] = json!([{"nodes": [0, 1, 2, 3]}]);
    let s = b.load().unwrap();
    assert_eq!(s.lights.len(), 3);
    let local = |p: DVec3| (p - s.origin).as_vec3();
    match s.lights[0] {
        Light::Point { position, intensity, range } => {
            assert!((position - local(DVec3::new(1.0, 2.0, 3.0))).length() < 1e-6);
            assert_eq!(intensity, Vec3::new(100.0, 50.0, 25.0), "colour × candela");
            assert_eq!(range, Some(20.0));
        }
        other => panic!("expected a point light, got {other:?}"),
    }
    match s.lights[1] {
        Light::Spot { position, direction, intensity, inner_cone_angle, outer_cone_angle, range } => {
            assert!((position - local(DVec3::new(0.0, 4.0, 0.0))).length() < 1e-6);
            assert!((direction - Vec3::NEG_Y).length() < 1e-6, "{direction}");
            assert_eq!(intensity, Vec3::splat(50.0), "white by default");
            assert_eq!((inner_cone_angle, outer_cone_angle, range), (0.2, 0.4, None));
        }
        other => panic!("expected a spot light, got {other:?}"),
    }
    match s.lights[2] {
        Light::Directional { direction, illuminance } => {
            assert!((direction - Vec3::NEG_Y).length() < 1e-6, "unit despite the node's scale: {direction}");
            assert_eq!(illuminance, Vec3::new(3.0, 3.0, 1.5), "colour × lux");
        }
        other => panic!("expected a directional light, got {other:?}"),
    }
}

#[test]
fn perspective_camera_pose_is_rigid_world_c2w() {
    let mut b = triangle_builder();
    let h = std::f64::consts::FRAC_1_SQRT_2;
    b.set("cameras", json!([
        {"type": "perspective", "name": "cam", "perspective": {"yfov": 0.8, "znear": 0.05, "aspectRatio": 1.5}},
        {"type": "orthographic", "orthographic": {"xmag": 1, "ymag": 1, "znear": 0.1, "zfar": 10}}
    ]));
    // Parent translates by 1e5 in x and scales by 3; child rotates 90° about Y and moves back.
    b.doc["nodes"].as_array_mut().unwrap().extend([
        json!({"translation": [100000, 0, 0], "scale": [3, 3, 3], "children": [2]}),
        json!({"translation": [0, 1, 2], "rotation": [0, h, 0, h], "camera": 0}),
        json!({"camera": 1}),
    ]);
    b.doc["scenes"] = json!([{"nodes": [0, 1, 3]}]);
    let s = b.load().unwrap();
    assert_eq!(s.cameras.len(), 1, "orthographic skipped");
    assert!(s.warnings.iter().any(|w| w.contains("orthographic")));
    let c = &s.cameras[0];
    assert_eq!(c.name.as_deref(), Some("cam"));
    assert!((c.yfov - 0.8).abs() < 1e-7 && c.aspect_ratio.is_some() && c.zfar.is_none());
    // Camera centre: 1e5 + 3·(0, 1, 2), true world coordinates.
    assert!(close(c.c2w.w_axis.truncate(), DVec3::new(100000.0, 3.0, 6.0), 1e-9));
    // Rotation R_y(90°): camera +X → world −Z, +Y → +Y, +Z (backwards) → +X; scale removed.
    assert!(close(c.c2w.x_axis.truncate(), DVec3::NEG_Z, 1e-12));
    assert!(close(c.c2w.y_axis.truncate(), DVec3::Y, 1e-12));
    assert!(close(c.c2w.z_axis.truncate(), DVec3::X, 1e-12));
    assert!((c.c2w.determinant() - 1.0).abs() < 1e-12);
}

fn png_data_uri(px: [u8; 4]) -> String {
    let img = image::RgbaImage::from_pixel(2, 2, image::Rgba(px));
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    format!("data:image/png;base64,{}", base64(&out.into_inner()))
}

#[test]
fn materials_emissive_strength_and_srgb_textures() {
    let mut b = triangle_builder();
    b.set("extensionsUsed", json!(["KHR_materials_emissive_strength", "EXT_texture_webp"]));
    b.set("images", json!([{"uri": png_data_uri([188, 64, 255, 128])}]));
    b.set("samplers", json!([{"magFilter": 9728, "wrapS": 33071, "wrapT": 33648}]));
    b.set("textures", json!([{"source": 0, "sampler": 0}, {"source": 0}]));
    b.set(
        "materials",
        json!([{
            "name": "glow",
            "pbrMetallicRoughness": {
                "baseColorFactor": [0.5, 0.5, 0.5, 1.0],
                "baseColorTexture": {"index": 0, "texCoord": 1},
                "metallicFactor": 0.25, "roughnessFactor": 0.75,
                "metallicRoughnessTexture": {"index": 1}
            },
            "normalTexture": {"index": 1, "scale": 0.5},
            "occlusionTexture": {"index": 1, "strength": 0.3},
            "emissiveFactor": [1.0, 0.5, 0.0],
            "emissiveTexture": {"index": 0},
            "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 10.0}},
            "alphaMode": "MASK", "alphaCutoff": 0.3, "doubleSided": true
        }]),
    );
    b.doc["meshes"][0]["primitives"][0]["material"] = json!(0);
    let s = b.load().unwrap();
    assert!(s.warnings.iter().any(|w| w.contains("EXT_texture_webp")), "{:?}", s.warnings);
    assert_eq!(s.materials.len(), 1, "no default material needed");
    let m = &s.materials[0];
    assert_eq!(m.emissive, Vec3::new(10.0, 5.0, 0.0));
    assert_eq!((m.metallic_factor, m.roughness_factor, m.double_sided), (0.25, 0.75, true));
    assert_eq!(m.alpha_mode, pathtracer::scene::AlphaMode::Mask { cutoff: 0.3 });
    let base = m.base_color_texture.unwrap();
    assert_eq!((base.tex_coord, base.wrap_s, base.wrap_t, base.filter), (1, Wrap::ClampToEdge, Wrap::MirroredRepeat, Filter::Nearest));
    let mr = m.metallic_roughness_texture.unwrap();
    assert_eq!((mr.wrap_s, mr.filter), (Wrap::Repeat, Filter::Linear), "default sampler");
    assert_eq!(m.normal_texture.unwrap().1, 0.5);
    assert_eq!(m.occlusion_texture.unwrap().1, 0.3);
    // One image, two colour spaces: decoded once as sRGB (base colour, emissive) and once as
    // linear data (metallic-roughness, normal, occlusion).
    assert_eq!(s.textures.len(), 2);
    assert_eq!(m.emissive_texture.unwrap().texture, base.texture);
    let srgb = s.textures[base.texture as usize].texels[0];
    let data = s.textures[mr.texture as usize].texels[0];
    // sRGB 188/255 → linear 0.50289; 64/255 → 0.05127.
    assert!((srgb.x - 0.502_886).abs() < 1e-5 && (srgb.y - 0.051_269).abs() < 1e-5 && (srgb.z - 1.0).abs() < 1e-6);
    assert!((srgb.w - 128.0 / 255.0).abs() < 1e-6, "alpha is linear");
    assert!((data.x - 188.0 / 255.0).abs() < 1e-6);
}

// ---------------------------------------------------------------------------------------
// Malformed files: each gives an error naming the file and the problem, never a panic.

#[test]
fn malformed_corpus_gives_clear_errors() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/import");
    let cases = [
        ("truncated.gltf", "invalid glTF JSON"),
        ("truncated.glb", "truncated GLB"),
        ("accessor_offset_out_of_range.gltf", "overrun"),
        ("index_out_of_range.gltf", "index 7"),
        ("missing_buffer.gltf", "does_not_exist.bin"),
        ("missing_image.gltf", "no_such_texture.png"),
        ("nan_positions.gltf", "not finite"),
        ("unsupported_required_extension.gltf", "KHR_draco_mesh_compression"),
        ("empty_scene.gltf", "scene has no triangles"),
        ("camera_zero_yfov.gltf", "yfov"),
        ("node_cycle.gltf", "reached twice"),
    ];
    for (file, problem) in cases {
        let err = load_gltf(&dir.join(file), &ImportOptions::default()).expect_err(file).to_string();
        assert!(err.contains(file), "{file}: message does not name the file: {err}");
        assert!(err.contains(problem), "{file}: message does not name the problem '{problem}': {err}");
    }
    assert!(load_gltf(&dir.join("valid_triangle.gltf"), &ImportOptions::default()).is_ok());
    let err = load_gltf(&dir.join("no_such_file.gltf"), &ImportOptions::default()).unwrap_err().to_string();
    assert!(err.contains("no_such_file.gltf"), "{err}");
}

#[test]
fn nan_error_names_the_mesh_and_primitive() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/import");
    let err = load_gltf(&dir.join("nan_positions.gltf"), &ImportOptions::default()).unwrap_err().to_string();
    assert!(err.contains("mesh 0 ('tri') primitive 0") && err.contains("vertex 1"), "{err}");
}

#[test]
fn every_prefix_of_a_valid_file_fails_cleanly() {
    // Truncation anywhere (JSON or GLB) is an error, never a panic.
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/import");
    for file in ["valid_triangle.gltf", "valid_triangle.glb"] {
        let bytes = std::fs::read(dir.join(file)).unwrap();
        for n in (0..bytes.len().saturating_sub(2)).step_by(7) {
            assert!(load_gltf_from_slice(&bytes[..n], None, file, &ImportOptions::default()).is_err(), "{file}[..{n}]");
        }
    }
}

// ---------------------------------------------------------------------------------------
// The project's scenes.

#[test]
fn project_scenes_import() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .map(|rd| rd.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    files.retain(|p| matches!(p.extension().and_then(|e| e.to_str()), Some("gltf" | "glb")));
    files.sort();
    assert!(!files.is_empty(), "no scenes in {}", dir.display());
    for f in &files {
        let s = load_gltf(f, &ImportOptions::default()).unwrap_or_else(|e| panic!("{e}"));
        assert!(!s.mesh.indices.is_empty(), "{}", f.display());
        assert!(s.mesh.material.iter().all(|&m| (m as usize) < s.materials.len()));
        assert!(s.mesh.indices.iter().flatten().all(|&k| (k as usize) < s.mesh.positions.len()));
        assert!(!s.bounds.is_empty());
        assert!(s.warnings.is_empty(), "{}: our own scenes import without warnings: {:?}", f.display(), s.warnings);
    }
}

// ---------------------------------------------------------------------------------------
// Structural mutation: every field of a feature-rich file set to hostile values or removed.

fn rich_file() -> Value {
    let mut b = Builder::default();
    let pos = b.positions(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]]);
    let nrm = b.f32s(&[[0.0, 0.0, 1.0]; 4], "VEC3");
    let tan = b.f32s(&[[1.0, 0.0, 0.0, 1.0]; 4], "VEC4");
    let uv = b.f32s(&[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]], "VEC2");
    let col = b.f32s(&[[1.0, 0.5, 0.25, 1.0]; 4], "VEC4");
    let idx = b.indices_u16(&[0, 1, 2, 2, 1, 3]);
    let sp_i = b.view(&[1u8, 0, 0, 0], None);
    let sp_v = b.view(&f32_bytes_test(&[0.5, 0.5]), None);
    b.accessors[uv]["sparse"] = json!({"count": 1, "indices": {"bufferView": sp_i, "componentType": 5121}, "values": {"bufferView": sp_v}});
    b.set("extensionsUsed", json!(["KHR_lights_punctual", "KHR_materials_emissive_strength"]));
    b.set("meshes", json!([{"name": "quad", "primitives": [{"attributes": {"POSITION": pos, "NORMAL": nrm, "TANGENT": tan, "TEXCOORD_0": uv, "COLOR_0": col}, "indices": idx, "material": 0, "mode": 4}]}]));
    b.set("images", json!([{"uri": png_data_uri([10, 20, 30, 255])}]));
    b.set("samplers", json!([{"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 33071}]));
    b.set("textures", json!([{"source": 0, "sampler": 0}]));
    b.set("materials", json!([{"pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1], "baseColorTexture": {"index": 0, "texCoord": 0}, "metallicFactor": 0.5, "roughnessFactor": 0.5},
        "emissiveFactor": [0.1, 0.1, 0.1], "alphaMode": "MASK", "alphaCutoff": 0.5,
        "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 2.0}}}]));
    b.set("cameras", json!([{"type": "perspective", "perspective": {"yfov": 0.7, "znear": 0.1, "zfar": 100, "aspectRatio": 1.0}}]));
    b.set("extensions", json!({"KHR_lights_punctual": {"lights": [{"type": "spot", "intensity": 5, "range": 9, "spot": {"innerConeAngle": 0.1, "outerConeAngle": 0.5}}]}}));
    b.set("nodes", json!([
        {"children": [1, 2], "translation": [1, 2, 3], "rotation": [0, 0, 0, 1], "scale": [1, 2, 1]},
        {"mesh": 0, "matrix": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]},
        {"camera": 0, "children": [3]},
        {"extensions": {"KHR_lights_punctual": {"light": 0}}}
    ]));
    b.set("scenes", json!([{"nodes": [0]}]));
    b.set("scene", json!(0));
    b.json(&BufferMode::DataUri)
}

fn f32_bytes_test(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// Every JSON pointer to a leaf or container below `v` (skipping the long data URIs).
fn pointers(v: &Value, at: String, out: &mut Vec<String>) {
    match v {
        Value::Object(m) => {
            for (k, c) in m {
                pointers(c, format!("{at}/{k}"), out);
            }
        }
        Value::Array(a) => {
            for (i, c) in a.iter().enumerate() {
                pointers(c, format!("{at}/{i}"), out);
            }
        }
        _ => {}
    }
    if !at.is_empty() {
        out.push(at);
    }
}

#[test]
fn hostile_mutations_never_panic() {
    let base = rich_file();
    let opts = ImportOptions::default();
    let ok = load_gltf_from_slice(&serde_json::to_vec(&base).unwrap(), None, "fuzz.gltf", &opts).unwrap();
    assert_eq!((ok.mesh.indices.len(), ok.cameras.len(), ok.lights.len(), ok.textures.len()), (2, 1, 1, 1));
    let mut ptrs = Vec::new();
    pointers(&base, String::new(), &mut ptrs);
    let variants = [json!(-1), json!(0), json!(3), json!(1e10), json!(4294967296u64), json!(0.5), json!("x"), json!([]), json!({})];
    let (mut errors, mut loads) = (0, 0);
    for p in &ptrs {
        let mut docs = Vec::new();
        for v in &variants {
            let mut d = base.clone();
            *d.pointer_mut(p).unwrap() = v.clone();
            docs.push(d);
        }
        // Removal of the member or element.
        let (parent, last) = p.rsplit_once('/').unwrap();
        let mut d = base.clone();
        match d.pointer_mut(if parent.is_empty() { "" } else { parent }).unwrap() {
            Value::Object(m) => {
                m.remove(last);
            }
            Value::Array(a) => {
                a.remove(last.parse::<usize>().unwrap());
            }
            _ => unreachable!(),
        }
        docs.push(d);
        for d in docs {
            loads += 1;
            match load_gltf_from_slice(&serde_json::to_vec(&d).unwrap(), None, "fuzz.gltf", &opts) {
                Err(e) => {
                    errors += 1;
                    assert!(e.to_string().starts_with("fuzz.gltf: "), "{p}: {e}");
                }
                Ok(s) => {
                    let m = &s.mesh;
                    assert!(m.indices.iter().flatten().all(|&k| (k as usize) < m.positions.len()), "{p}");
                    assert!(m.material.iter().all(|&k| (k as usize) < s.materials.len()), "{p}");
                    assert_eq!(m.normals.len(), m.positions.len());
                    assert!(m.normals.iter().all(|n| n.is_finite() && (n.length() - 1.0).abs() < 1e-3), "{p}");
                    assert!(m.positions.iter().all(|q| q.is_finite()), "{p}");
                    for mat in &s.materials {
                        for t in [mat.base_color_texture, mat.emissive_texture, mat.metallic_roughness_texture].into_iter().flatten() {
                            assert!((t.texture as usize) < s.textures.len(), "{p}");
                        }
                    }
                }
            }
        }
    }
    assert!(errors > 0 && errors < loads, "{errors} errors in {loads} loads");
}

#[test]
fn byte_flips_in_glb_never_panic() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/import");
    let glb = std::fs::read(dir.join("valid_triangle.glb")).unwrap();
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let (mut errors, mut oks) = (0, 0);
    for _ in 0..3000 {
        let mut bytes = glb.clone();
        for _ in 0..1 + next() % 3 {
            let at = (next() % bytes.len() as u64) as usize;
            bytes[at] = next() as u8;
        }
        match load_gltf_from_slice(&bytes, None, "flip.glb", &ImportOptions::default()) {
            Ok(s) => {
                oks += 1;
                assert!(s.mesh.indices.iter().flatten().all(|&k| (k as usize) < s.mesh.positions.len()));
            }
            Err(e) => {
                errors += 1;
                assert!(e.to_string().starts_with("flip.glb: "), "{e}");
            }
        }
    }
    assert!(errors > 0 && oks > 0, "{errors} errors, {oks} successes");
}

/// A `.glb` file without the GLB magic is refused as such, naming the file and what it starts
/// with, instead of being read as JSON (whose parser then spoke of an unexpected value); a
/// valid one loads whatever the case of its extension.
#[test]
fn a_glb_without_the_magic_is_refused_as_not_binary_gltf() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/import");
    let glb = std::fs::read(dir.join("valid_triangle.glb")).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let mut bad = glb.clone();
    bad[..4].copy_from_slice(b"gLTF");
    let path = tmp.path().join("bad.glb");
    std::fs::write(&path, &bad).unwrap();
    let e = load_gltf(&path, &ImportOptions::default()).unwrap_err().to_string();
    assert!(e.contains("bad.glb") && e.contains("not a binary glTF") && e.contains("'gLTF'"), "{e}");
    let upper = tmp.path().join("fine.GLB");
    std::fs::write(&upper, &glb).unwrap();
    assert!(load_gltf(&upper, &ImportOptions::default()).is_ok());
}

/// An image file that is not a decodable PNG is named in the error by its URI (the file to
/// open), not only by its glTF index.
#[test]
fn a_corrupt_texture_file_is_named_by_its_uri() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/import");
    let tmp = tempfile::tempdir().unwrap();
    std::fs::copy(dir.join("missing_image.gltf"), tmp.path().join("scene.gltf")).unwrap();
    let mut png = vec![0x89, b'P', b'N', b'G', 0x0d, 0x0a, 0x1a, 0x0a];
    png.extend_from_slice(b"garbage, not chunks");
    std::fs::write(tmp.path().join("no_such_texture.png"), &png).unwrap();
    let e = load_gltf(&tmp.path().join("scene.gltf"), &ImportOptions::default()).unwrap_err().to_string();
    assert!(e.contains("scene.gltf") && e.contains("image 0 ('no_such_texture.png')") && e.contains("cannot decode"), "{e}");
}

// ---------------------------------------------------------------------------------------
// External files: inside the scene's folder, regular files, within the byte budget.

/// A fresh folder `name` holding `scene/` (where the scene goes) and, beside it, `outside.bin`:
/// the triangle's buffer followed by a marker that no error message may quote.
fn confinement_dir(name: &str, b: &Builder) -> (PathBuf, PathBuf) {
    let dir = tmp_dir(name);
    std::fs::remove_dir_all(&dir).unwrap();
    std::fs::create_dir_all(dir.join("scene/sub")).unwrap();
    let mut outside = b.bin.clone();
    outside.extend_from_slice(SECRET);
    std::fs::write(dir.join("outside.bin"), outside).unwrap();
    (dir.clone(), dir.join("scene"))
}

const SECRET: &[u8] = b"root:x:0:0:SECRET-OUTSIDE-BYTES";

/// Writes `scene_dir/tri.gltf` with its buffer at `uri`.
fn external_scene(b: &Builder, scene_dir: &Path, uri: &str) -> PathBuf {
    let path = scene_dir.join("tri.gltf");
    std::fs::write(&path, serde_json::to_vec(&b.json(&BufferMode::External(uri))).unwrap()).unwrap();
    path
}

fn allow_outside() -> ImportOptions {
    ImportOptions { allow_outside: true, ..ImportOptions::default() }
}

/// Asserts `e` refuses `uri` as leading outside the scene's folder, naming the scene and the
/// URI, without a byte of the outside file.
fn assert_refused_outside(e: &str, uri: &str) {
    assert!(e.contains("tri.gltf") && e.contains(&format!("'{uri}'")) && e.contains("outside the scene's folder") && e.contains("--allow-outside"), "{uri}: {e}");
    assert!(!e.contains("root:") && !e.contains("SECRET"), "{uri}: the error quotes the outside file: {e}");
}

/// Buffer URIs leading outside the scene's folder (`../`, percent-encoded `%2e%2e`, an absolute
/// path, a symbolic link or a linked folder) are refused by the import and by the scene hash of
/// `render_config.json`; `allow_outside` admits them (and they load).
#[test]
fn external_files_outside_the_scene_folder_are_refused_unless_allowed() {
    use pathtracer::dataset_folder::SceneSource;
    let b = triangle_builder();
    let (dir, scene_dir) = confinement_dir("confined", &b);
    let absolute = dir.join("outside.bin").to_string_lossy().into_owned();
    let mut uris = vec!["../outside.bin".to_string(), "%2e%2e/outside.bin".into(), "%2E%2E%2Foutside.bin".into(), "sub/../../outside.bin".into(), absolute];
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(dir.join("outside.bin"), scene_dir.join("link.bin")).unwrap();
        std::os::unix::fs::symlink(&dir, scene_dir.join("up")).unwrap();
        uris.extend(["link.bin".to_string(), "up/outside.bin".into(), "up/scene/../outside.bin".into()]);
    }
    for uri in &uris {
        let path = external_scene(&b, &scene_dir, uri);
        let e = load_gltf(&path, &ImportOptions::default()).unwrap_err().to_string();
        assert_refused_outside(&e, uri);
        assert!(e.contains("buffer 0"), "{e}");
        let e = SceneSource::from_scene(&path).unwrap_err().to_string();
        assert_refused_outside(&e, uri);
        let scene = load_gltf(&path, &allow_outside()).unwrap_or_else(|e| panic!("{uri} with allow_outside: {e}"));
        assert_eq!(scene.mesh.indices.len(), 1);
        assert!(SceneSource::from_scene_with(&path, &allow_outside()).is_ok());
    }
    // An image URI outside is refused the same way (named by its URI), before it is decoded.
    let image = scene_dir.join("img.gltf");
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/import/missing_image.gltf")).unwrap();
    std::fs::write(&image, text.replace("no_such_texture.png", "../outside.bin")).unwrap();
    let e = load_gltf(&image, &ImportOptions::default()).unwrap_err().to_string();
    assert!(e.contains("image 0 ('../outside.bin')") && e.contains("outside the scene's folder") && !e.contains("SECRET"), "{e}");
    // Inside by a detour, and a missing file inside: loaded, and reported as missing.
    std::fs::write(scene_dir.join("tri.bin"), &b.bin).unwrap();
    assert!(load_gltf(&external_scene(&b, &scene_dir, "../scene/sub/../tri.bin"), &ImportOptions::default()).is_ok());
    let e = load_gltf(&external_scene(&b, &scene_dir, "missing.bin"), &ImportOptions::default()).unwrap_err().to_string();
    assert!(e.contains("cannot read") && e.contains("missing.bin"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Runs `f` in a thread and fails the test if it has not returned within five seconds (a
/// read of a device or a FIFO that blocks would otherwise hang the suite).
fn promptly<T: Send + 'static>(what: &str, f: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || tx.send(f()));
    rx.recv_timeout(std::time::Duration::from_secs(5)).unwrap_or_else(|_| panic!("{what} did not return within 5 s"))
}

/// Only regular files are read: a URI naming `/dev/zero` or `/dev/urandom` (even with
/// `allow_outside`), a FIFO or a folder, and a scene file that is a FIFO, are refused at once,
/// by the import and by the scene hash.
#[cfg(unix)]
#[test]
fn devices_fifos_and_folders_are_refused_before_reading() {
    use pathtracer::dataset_folder::SceneSource;
    let b = triangle_builder();
    let (dir, scene_dir) = confinement_dir("regular", &b);
    assert!(std::process::Command::new("mkfifo").arg(scene_dir.join("pipe.bin")).status().unwrap().success());
    for (uri, kind) in [("/dev/zero", "device"), ("/dev/urandom", "device"), ("pipe.bin", "FIFO"), ("sub", "folder")] {
        let path = external_scene(&b, &scene_dir, uri);
        let p = path.clone();
        let e = promptly(uri, move || load_gltf(&p, &allow_outside()).unwrap_err().to_string());
        assert!(e.contains("tri.gltf") && e.contains("not a regular file") && e.contains(kind), "{uri}: {e}");
        let p = path.clone();
        let e = promptly(uri, move || SceneSource::from_scene_with(&p, &allow_outside()).unwrap_err().to_string());
        assert!(e.contains("not a regular file"), "{uri}: {e}");
    }
    let fifo = scene_dir.join("scene.gltf");
    assert!(std::process::Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let f = fifo.clone();
    let e = promptly("a FIFO scene file", move || load_gltf(&f, &ImportOptions::default()).unwrap_err().to_string());
    assert!(e.contains("scene.gltf") && e.contains("FIFO"), "{e}");
    let e = promptly("hashing a FIFO scene file", move || SceneSource::from_scene(&fifo).unwrap_err().to_string());
    assert!(e.contains("FIFO"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// An external file larger than what is left of the byte budget is refused by the import and
/// by the scene hash, naming the limit.
#[test]
fn an_external_file_beyond_the_byte_budget_is_refused() {
    use pathtracer::dataset_folder::SceneSource;
    let b = triangle_builder();
    let (dir, scene_dir) = confinement_dir("budget", &b);
    std::fs::write(scene_dir.join("tri.bin"), vec![0u8; 4096]).unwrap();
    let path = external_scene(&b, &scene_dir, "tri.bin");
    let scene_len = std::fs::metadata(&path).unwrap().len();
    let small = ImportOptions { max_buffer_bytes: scene_len + 1000, ..ImportOptions::default() };
    let e = load_gltf(&path, &small).unwrap_err().to_string();
    assert!(e.contains("buffer 0") && e.contains("4096 bytes") && e.contains("limit"), "{e}");
    let e = SceneSource::from_scene_with(&path, &small).unwrap_err().to_string();
    assert!(e.contains("tri.bin") && e.contains("limit"), "{e}");
    assert!(SceneSource::from_scene_with(&path, &ImportOptions { max_buffer_bytes: scene_len + 4096, ..small }).is_ok());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The committed `skinned` and `morphed` scenes import at the default pose scenegen computes
/// independently (in `f32`, from its own joint and morph data): every vertex of the posed
/// meshes is found among the imported positions, and that pose is far from the bind pose.
#[test]
fn skinned_and_morphed_scenes_import_at_their_default_pose() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    for (name, meshes) in [("skinned", &["tube"][..]), ("morphed", &["blob_mesh_weights", "blob_node_weights"][..])] {
        let b = scenegen::build_scene(name).unwrap();
        let s = load_gltf(&dir.join(format!("{name}.gltf")), &ImportOptions::default()).unwrap();
        assert!(s.warnings.is_empty(), "{name}: {:?}", s.warnings);
        let imported: Vec<DVec3> = (0..s.mesh.positions.len()).map(|i| world(&s, i)).collect();
        let gltf = gltf::Gltf::open(dir.join(format!("{name}.gltf"))).unwrap();
        for mesh_name in meshes {
            let node = gltf.nodes().find(|n| n.name() == Some(mesh_name)).unwrap();
            let posed = b.world_positions(scenegen::NodeId(node.index())).unwrap();
            let mut moved = 0.0f64;
            for p in &posed {
                let p = p.as_dvec3();
                let nearest = imported.iter().map(|q| (*q - p).length()).fold(f64::INFINITY, f64::min);
                assert!(nearest < 2e-6, "{name}/{mesh_name}: posed vertex {p} is {nearest} m from every imported vertex");
            }
            // The unposed mesh under the node's own transform: the pose moves it by decimetres.
            let node_m = glam::DMat4::from_cols_array_2d(&node.transform().matrix().map(|c| c.map(f64::from)));
            let mesh = node.mesh().unwrap();
            let prim = mesh.primitives().next().unwrap();
            let buffers: Vec<Vec<u8>> = vec![std::fs::read(dir.join(format!("{name}.bin"))).unwrap()];
            let reader = prim.reader(|b| buffers.get(b.index()).map(Vec::as_slice));
            for (p, q) in reader.read_positions().unwrap().zip(&posed) {
                moved = moved.max((node_m.transform_point3(Vec3::from(p).as_dvec3()) - q.as_dvec3()).length());
            }
            assert!(moved > 0.1, "{name}/{mesh_name}: the default pose moves vertices by only {moved} m");
        }
    }
}
