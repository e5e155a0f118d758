//! Skins and morph targets: known answers (exact skinned and morphed positions, normals,
//! bounds and hit distance) and the bad-input errors, on tiny glTF files written here.

use glam::{DVec3, Vec3};
use serde_json::{json, Value};

use super::tests::{f32_bytes, file, load};
use crate::scene::Scene;

/// A triangle skinned by two joints. Joint A (node 1) has the world matrix
/// `A(p) = (p.z + 2, p.y + 3, −p.x + 4)` (a quarter turn about +Y and a translation); joint B
/// (node 2) is A's child translated by (0, 10, 0). Both inverse bind matrices translate by
/// (−1, 0, 0), and the mesh's positions are the unit triangle shifted by (+1, 0, 0), so the
/// joint matrices act on the unit triangle as `A` and `A · T(0, 10, 0)`. The skinned mesh node
/// (node 0) has a translation the spec says to ignore.
struct Rig {
    positions: [f32; 9],
    joints0: [[u8; 4]; 3],
    weights0: [[f32; 4]; 3],
    set1: Option<([[u8; 4]; 3], [[f32; 4]; 3])>,
    ibms: Option<Vec<[f32; 16]>>,
}

const SHIFT: [f32; 16] = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0, 0.0, 1.0];

impl Rig {
    fn new() -> Self {
        Rig {
            positions: [1.0, 0.0, 0.0, 2.0, 0.0, 0.0, 1.0, 1.0, 0.0],
            // v0 on A, v1 on B, v2 on A and B with weights 1 + 1 (normalised to ½ each).
            joints0: [[0, 0, 0, 0], [1, 0, 0, 0], [0, 1, 0, 0]],
            weights0: [[1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [1.0, 1.0, 0.0, 0.0]],
            set1: None,
            ibms: Some(vec![SHIFT, SHIFT]),
        }
    }

    /// The glTF file (body, binary).
    fn parts(&self) -> (Value, Vec<u8>) {
        let mut bin = Vec::new();
        let mut views = Vec::new();
        let mut push = |bytes: Vec<u8>| {
            views.push(json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": bytes.len()}));
            bin.extend(bytes);
            views.len() - 1
        };
        let u8s = |j: &[[u8; 4]; 3]| j.iter().flatten().copied().collect::<Vec<u8>>();
        let f32s = |w: &[[f32; 4]; 3]| f32_bytes(&w.iter().flatten().copied().collect::<Vec<f32>>());
        let pos = push(f32_bytes(&self.positions));
        let nrm = push(f32_bytes(&[0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0]));
        let j0 = push(u8s(&self.joints0));
        let w0 = push(f32s(&self.weights0));
        let mut accessors = vec![
            json!({"bufferView": pos, "componentType": 5126, "count": 3, "type": "VEC3"}),
            json!({"bufferView": nrm, "componentType": 5126, "count": 3, "type": "VEC3"}),
            json!({"bufferView": j0, "componentType": 5121, "count": 3, "type": "VEC4"}),
            json!({"bufferView": w0, "componentType": 5126, "count": 3, "type": "VEC4"}),
        ];
        let mut attributes = json!({"POSITION": 0, "NORMAL": 1, "JOINTS_0": 2, "WEIGHTS_0": 3});
        if let Some((j1, w1)) = &self.set1 {
            let j1 = push(u8s(j1));
            let w1 = push(f32s(w1));
            accessors.push(json!({"bufferView": j1, "componentType": 5121, "count": 3, "type": "VEC4"}));
            accessors.push(json!({"bufferView": w1, "componentType": 5126, "count": 3, "type": "VEC4"}));
            attributes["JOINTS_1"] = json!(accessors.len() - 2);
            attributes["WEIGHTS_1"] = json!(accessors.len() - 1);
        }
        let mut skin = json!({"name": "arm", "joints": [1, 2]});
        if let Some(ibms) = &self.ibms {
            let view = push(f32_bytes(&ibms.iter().flatten().copied().collect::<Vec<f32>>()));
            accessors.push(json!({"bufferView": view, "componentType": 5126, "count": ibms.len(), "type": "MAT4"}));
            skin["inverseBindMatrices"] = json!(accessors.len() - 1);
        }
        let body = json!({
            "bufferViews": views,
            "accessors": accessors,
            "meshes": [{"name": "blade", "primitives": [{"attributes": attributes}]}],
            "skins": [skin],
            "nodes": [
                {"name": "skinned", "mesh": 0, "skin": 0, "translation": [100.0, 0.0, 0.0]},
                {"name": "A", "matrix": [0, 0, -1, 0, 0, 1, 0, 0, 1, 0, 0, 0, 2, 3, 4, 1], "children": [2]},
                {"name": "B", "translation": [0.0, 10.0, 0.0]}
            ],
            "scenes": [{"nodes": [0, 1]}]
        });
        (body, bin)
    }

    fn load(&self) -> Result<Scene, String> {
        let (body, bin) = self.parts();
        load(&file(&bin, body)).map_err(|e| e.to_string())
    }
}

fn world(s: &Scene, k: usize) -> DVec3 {
    s.origin + s.mesh.positions[k].as_dvec3()
}

#[test]
fn a_skinned_triangle_lands_exactly_on_its_joint_transforms() {
    let s = Rig::new().load().unwrap();
    assert!(!s.warnings.iter().any(|w| w.contains("skin")), "{:?}", s.warnings);
    // A(0,0,0), A·T(0,10,0)(1,0,0), ½(A + A·T(0,10,0))(0,1,0): the node's translation ignored.
    assert_eq!(world(&s, 0), DVec3::new(2.0, 3.0, 4.0));
    assert_eq!(world(&s, 1), DVec3::new(2.0, 13.0, 3.0));
    assert_eq!(world(&s, 2), DVec3::new(2.0, 9.0, 4.0));
    assert_eq!(s.mesh.indices, vec![[0, 1, 2]]);
    // Normals through the inverse transpose: +Z turns to +X.
    assert!(s.mesh.normals.iter().all(|&n| n == Vec3::X), "{:?}", s.mesh.normals);
    // The bounds are the skinned ones.
    assert_eq!(s.origin + s.bounds.min.as_dvec3(), DVec3::new(2.0, 3.0, 3.0));
    assert_eq!(s.origin + s.bounds.max.as_dvec3(), DVec3::new(2.0, 13.0, 4.0));
    // The exact hit distance of a ray at the centroid along −X: the plane x = 2 is 8 away.
    let r = crate::render::Renderer::new(s, &crate::accel::AccelParams::fast_build()).unwrap();
    let origin = DVec3::new(10.0, 25.0 / 3.0, 11.0 / 3.0);
    let hit = r.trace_primary(&dataset::Ray { origin, direction: DVec3::NEG_X }).expect("hits the skinned triangle");
    assert!((hit.distance - 8.0).abs() < 1e-12, "distance {}", hit.distance);
    // Where the unskinned triangle would be (x = 100 + …, z = 0) nothing is hit.
    assert!(r.trace_primary(&dataset::Ray { origin: DVec3::new(101.2, 0.2, 5.0), direction: DVec3::NEG_Z }).is_none());
}

#[test]
fn skinning_without_inverse_bind_matrices_uses_the_identity() {
    let mut rig = Rig::new();
    rig.ibms = None;
    let s = rig.load().unwrap();
    // Mesh positions (1,0,0), (2,0,0), (1,1,0) go through A and A·T(0,10,0) directly.
    assert_eq!(world(&s, 0), DVec3::new(2.0, 3.0, 3.0));
    assert_eq!(world(&s, 1), DVec3::new(2.0, 13.0, 2.0));
    assert_eq!(world(&s, 2), DVec3::new(2.0, 9.0, 3.0));
}

#[test]
fn joints_1_and_weights_1_add_influences() {
    // v2's second influence moves from set 0 to set 1: the same pose.
    let mut rig = Rig::new();
    rig.weights0[2] = [1.0, 0.0, 0.0, 0.0];
    rig.set1 = Some(([[0; 4], [0; 4], [1, 0, 0, 0]], [[0.0; 4], [0.0; 4], [1.0, 0.0, 0.0, 0.0]]));
    let s = rig.load().unwrap();
    assert_eq!(world(&s, 2), DVec3::new(2.0, 9.0, 4.0));
    // Weights ¼ on A and ¾ on B over the two sets (not normalised: they sum to 1).
    rig.weights0[2] = [0.25, 0.0, 0.0, 0.0];
    rig.set1 = Some(([[0; 4], [0; 4], [1, 0, 0, 0]], [[0.0; 4], [0.0; 4], [0.75, 0.0, 0.0, 0.0]]));
    assert_eq!(world(&rig.load().unwrap(), 2), DVec3::new(2.0, 11.5, 4.0));
}

#[test]
fn skin_errors_name_the_node_and_skin() {
    let mut rig = Rig::new();
    rig.joints0[1] = [2, 0, 0, 0];
    let e = rig.load().unwrap_err();
    assert!(e.contains("unit.gltf") && e.contains("mesh 0 ('blade') primitive 0 (skinned by node 0 ('skinned') skin 0 ('arm')): vertex 1: joint index 2 is out of range (the skin has 2 joints)"), "{e}");

    let mut rig = Rig::new();
    rig.ibms = Some(vec![SHIFT]);
    let e = rig.load().unwrap_err();
    assert!(e.contains("node 0 ('skinned') skin 0 ('arm'): inverseBindMatrices holds 1 matrices but the skin has 2 joints"), "{e}");

    let mut rig = Rig::new();
    let mut flat = SHIFT;
    flat[5] = 0.0; // the y column vanishes
    rig.ibms = Some(vec![SHIFT, flat]);
    let e = rig.load().unwrap_err();
    assert!(e.contains("skin 0 ('arm'): inverse bind matrix 1 is not invertible"), "{e}");

    let mut rig = Rig::new();
    let mut nan = SHIFT;
    nan[12] = f32::NAN;
    rig.ibms = Some(vec![nan, SHIFT]);
    let e = rig.load().unwrap_err();
    assert!(e.contains("skin 0 ('arm'): inverse bind matrix 0 is not finite"), "{e}");

    let mut rig = Rig::new();
    rig.weights0[0] = [-0.5, 1.5, 0.0, 0.0];
    let e = rig.load().unwrap_err();
    assert!(e.contains("vertex 0: weight -0.5 must be finite and non-negative"), "{e}");

    let mut rig = Rig::new();
    rig.weights0[2] = [f32::INFINITY, 0.0, 0.0, 0.0];
    let e = rig.load().unwrap_err();
    assert!(e.contains("vertex 2: weight inf must be finite and non-negative"), "{e}");

    let mut rig = Rig::new();
    rig.weights0[1] = [0.0; 4];
    let e = rig.load().unwrap_err();
    assert!(e.contains("vertex 1: weights sum to 0"), "{e}");

    // A skinned mesh without JOINTS_0 / WEIGHTS_0.
    let (mut body, bin) = Rig::new().parts();
    let attrs = body["meshes"][0]["primitives"][0]["attributes"].as_object_mut().unwrap();
    attrs.remove("JOINTS_0");
    attrs.remove("WEIGHTS_0");
    let e = load(&file(&bin, body)).unwrap_err().to_string();
    assert!(e.contains("mesh 0 ('blade') primitive 0: placed by node 0 ('skinned') skin 0 ('arm') but has no JOINTS_0 / WEIGHTS_0"), "{e}");

    // A joint outside the imported scene.
    let (mut body, bin) = Rig::new().parts();
    body["nodes"].as_array_mut().unwrap().push(json!({"name": "stray"}));
    body["skins"][0]["joints"] = json!([1, 3]);
    let e = load(&file(&bin, body)).unwrap_err().to_string();
    assert!(e.contains("skin 0 ('arm'): joint 1 (node 3) is not in the imported scene"), "{e}");
}

/// A triangle (z = 0, NORMAL +Z, TANGENT +X) with two morph targets: target 0 is dense
/// (POSITION (0,0,1), (0,0,2), (0,0,3); NORMAL +X; TANGENT +Y), target 1 sparse (POSITION of
/// vertex 1 by (4, 0, 0), no bufferView).
fn morphed(mesh_weights: Option<Value>, node_weights: Option<Value>) -> (Value, Vec<u8>) {
    let mut bin = f32_bytes(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]); // 0: positions
    bin.extend(f32_bytes(&[0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0])); // 36: normals
    bin.extend(f32_bytes(&[1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0])); // 72: tangents
    bin.extend(f32_bytes(&[0.0, 0.0, 1.0, 0.0, 0.0, 2.0, 0.0, 0.0, 3.0])); // 120: Δ position
    bin.extend(f32_bytes(&[1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0])); // 156: Δ normal
    bin.extend(f32_bytes(&[0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0])); // 192: Δ tangent
    bin.extend([1u8, 0, 0, 0]); // 228: sparse index (u8) + pad
    bin.extend(f32_bytes(&[4.0, 0.0, 0.0])); // 232: sparse value
    let view = |o: usize, l: usize| json!({"buffer": 0, "byteOffset": o, "byteLength": l});
    let acc = |v: usize, t: &str, n: usize| json!({"bufferView": v, "componentType": 5126, "count": n, "type": t});
    let mut mesh = json!({"name": "face", "primitives": [{
        "attributes": {"POSITION": 0, "NORMAL": 1, "TANGENT": 2},
        "targets": [{"POSITION": 3, "NORMAL": 4, "TANGENT": 5}, {"POSITION": 6}]
    }]});
    if let Some(w) = mesh_weights {
        mesh["weights"] = w;
    }
    let mut node = json!({"name": "head", "mesh": 0});
    if let Some(w) = node_weights {
        node["weights"] = w;
    }
    let body = json!({
        "bufferViews": [view(0, 36), view(36, 36), view(72, 48), view(120, 36), view(156, 36), view(192, 36), view(228, 1), view(232, 12)],
        "accessors": [acc(0, "VEC3", 3), acc(1, "VEC3", 3), acc(2, "VEC4", 3), acc(3, "VEC3", 3), acc(4, "VEC3", 3), acc(5, "VEC3", 3),
            {"componentType": 5126, "count": 3, "type": "VEC3",
             "sparse": {"count": 1, "indices": {"bufferView": 6, "componentType": 5121}, "values": {"bufferView": 7}}}],
        "meshes": [mesh],
        "nodes": [node],
        "scenes": [{"nodes": [0]}]
    });
    (body, bin)
}

#[test]
fn morph_targets_displace_by_exactly_weight_times_delta() {
    // Zero default weights: the base mesh.
    let (body, bin) = morphed(None, None);
    let s = load(&file(&bin, body)).unwrap();
    assert_eq!([world(&s, 0), world(&s, 1), world(&s, 2)], [DVec3::ZERO, DVec3::X, DVec3::Y]);
    assert!(!s.warnings.iter().any(|w| w.contains("morph")), "{:?}", s.warnings);

    // mesh.weights [0.25, 0.5]: z by ¼·(1, 2, 3); vertex 1's x by ½·4 (the sparse target).
    let (body, bin) = morphed(Some(json!([0.25, 0.5])), None);
    let s = load(&file(&bin, body)).unwrap();
    assert_eq!(world(&s, 0), DVec3::new(0.0, 0.0, 0.25));
    assert_eq!(world(&s, 1), DVec3::new(3.0, 0.0, 0.5));
    assert_eq!(world(&s, 2), DVec3::new(0.0, 1.0, 0.75));
    // Normal (0,0,1) + ¼·(1,0,0) and tangent (1,0,0) + ¼·(0,1,0), renormalised.
    let n = Vec3::new(0.25, 0.0, 1.0).normalize();
    assert!(s.mesh.normals.iter().all(|&m| (m - n).length() < 1e-7), "{:?}", s.mesh.normals);
    let t = Vec3::new(1.0, 0.25, 0.0).normalize();
    assert!(s.mesh.tangents.iter().all(|&m| (m.truncate() - t).length() < 1e-7 && m.w == 1.0), "{:?}", s.mesh.tangents);

    // node.weights override mesh.weights.
    let (body, bin) = morphed(Some(json!([0.25, 0.5])), Some(json!([1.0, 0.0])));
    let s = load(&file(&bin, body)).unwrap();
    assert_eq!([world(&s, 0), world(&s, 1), world(&s, 2)], [DVec3::new(0.0, 0.0, 1.0), DVec3::new(1.0, 0.0, 2.0), DVec3::new(0.0, 1.0, 3.0)]);
}

#[test]
fn morph_comes_before_skin() {
    // The rig's vertex 0 displaced by (0, 0, 1) in mesh space, then skinned by A:
    // A(0, 0, 1) = (3, 3, 4). Skinning first and morphing after would give (2, 3, 5).
    let (mut body, mut bin) = Rig::new().parts();
    let offset = bin.len();
    bin.extend(f32_bytes(&[0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]));
    body["bufferViews"].as_array_mut().unwrap().push(json!({"buffer": 0, "byteOffset": offset, "byteLength": 36}));
    let view = body["bufferViews"].as_array().unwrap().len() - 1;
    body["accessors"].as_array_mut().unwrap().push(json!({"bufferView": view, "componentType": 5126, "count": 3, "type": "VEC3"}));
    let acc = body["accessors"].as_array().unwrap().len() - 1;
    body["meshes"][0]["primitives"][0]["targets"] = json!([{"POSITION": acc}]);
    body["meshes"][0]["weights"] = json!([1.0]);
    let s = load(&file(&bin, body)).unwrap();
    assert_eq!(world(&s, 0), DVec3::new(3.0, 3.0, 4.0));
    assert_eq!(world(&s, 1), DVec3::new(2.0, 13.0, 3.0));
}

#[test]
fn morph_errors_name_the_mesh_or_node() {
    let (body, bin) = morphed(Some(json!([0.25])), None);
    let e = load(&file(&bin, body)).unwrap_err().to_string();
    assert!(e.contains("unit.gltf") && e.contains("mesh 0 ('face'): weights has 1 entries but the mesh has 2 morph targets"), "{e}");

    let (body, bin) = morphed(None, Some(json!([0.25, 0.5, 1.0])));
    let e = load(&file(&bin, body)).unwrap_err().to_string();
    assert!(e.contains("node 0 ('head'): weights has 3 entries but the mesh has 2 morph targets"), "{e}");

    // A second primitive with one target where the first has two.
    let (mut body, bin) = morphed(None, None);
    let second = json!({"attributes": {"POSITION": 0}, "targets": [{"POSITION": 3}]});
    body["meshes"][0]["primitives"].as_array_mut().unwrap().push(second);
    let e = load(&file(&bin, body)).unwrap_err().to_string();
    assert!(e.contains("mesh 0 ('face'): primitive 1 has 1 morph targets but primitive 0 has 2"), "{e}");

    // A displacement accessor of the wrong length.
    let (mut body, bin) = morphed(Some(json!([1.0, 0.0])), None);
    body["accessors"][3]["count"] = json!(2);
    let e = load(&file(&bin, body)).unwrap_err().to_string();
    assert!(e.contains("mesh 0 ('face') primitive 0 morph target 0 POSITION: 2 elements of 3 components, expected 3 of 3"), "{e}");
}
