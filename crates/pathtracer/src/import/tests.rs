//! Unit tests of the importer internals and of the spec corners the integration tests
//! (`tests/import.rs`) do not reach.

use glam::{DMat4, DQuat, DVec3, Vec3, Vec4};
use gltf::mesh::Mode;
use serde_json::{json, Value};

use super::graph::{assemble, rigid_pose};
use super::*;

pub(super) fn b64(bytes: &[u8]) -> String {
    const T: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in bytes.chunks(3) {
        let b = [c[0], *c.get(1).unwrap_or(&0), *c.get(2).unwrap_or(&0)];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            s.push(if k <= c.len() { T[(n >> (18 - 6 * k) & 63) as usize] as char } else { '=' });
        }
    }
    s
}

pub(super) fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// A glTF file: `body` plus one data-URI buffer holding `bin`.
pub(super) fn file(bin: &[u8], mut body: Value) -> Vec<u8> {
    body["asset"] = json!({"version": "2.0"});
    if !bin.is_empty() {
        body["buffers"] = json!([{"byteLength": bin.len(), "uri": format!("data:application/octet-stream;base64,{}", b64(bin))}]);
    }
    serde_json::to_vec(&body).unwrap()
}

pub(super) fn load(bytes: &[u8]) -> Result<Scene, PathTracerError> {
    load_gltf_from_slice(bytes, None, "unit.gltf", &ImportOptions::default())
}

/// One triangle (positions at byte 0, 36 bytes) as accessor 0, plus `extra` accessors.
fn triangle_body(extra_views: Value, extra_accessors: &[Value]) -> Value {
    let mut views = vec![json!({"buffer": 0, "byteLength": 36})];
    views.extend(extra_views.as_array().cloned().unwrap_or_default());
    let mut accessors = vec![json!({"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0,0,0], "max": [1,1,0]})];
    accessors.extend_from_slice(extra_accessors);
    json!({
        "bufferViews": views,
        "accessors": accessors,
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}]
    })
}

const TRI: [f32; 9] = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0];

#[test]
fn assemble_matches_hand_computed_lists() {
    assert_eq!(assemble(Mode::Triangles, &[0, 1, 2, 3, 4, 5, 6]), vec![[0, 1, 2], [3, 4, 5]]);
    assert_eq!(assemble(Mode::TriangleStrip, &[10, 11, 12, 13]), vec![[10, 11, 12], [11, 13, 12]]);
    assert_eq!(assemble(Mode::TriangleStrip, &[1, 2]), Vec::<[u32; 3]>::new());
    assert_eq!(assemble(Mode::TriangleFan, &[7, 8, 9, 10]), vec![[8, 9, 7], [9, 10, 7]]);
    assert!(assemble(Mode::Lines, &[0, 1, 2, 3]).is_empty());
}

#[test]
fn rigid_pose_removes_scale_and_shear() {
    let q = DQuat::from_rotation_y(0.7) * DQuat::from_rotation_x(-0.3);
    let t = DVec3::new(5.0, -2.0, 1e5);
    let shear = DMat4::from_cols_array(&[1.0, 0.0, 0.0, 0.0, 0.4, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
    let m = DMat4::from_scale_rotation_translation(DVec3::new(2.0, 3.0, 4.0), q, t) * shear;
    let r = rigid_pose(&m).unwrap();
    let expected = DMat4::from_rotation_translation(q, t);
    // The view axis (−Z) and the camera centre are preserved exactly in direction.
    assert!((r.z_axis - expected.z_axis).length() < 1e-12);
    assert!((r.w_axis - expected.w_axis).length() < 1e-9);
    assert!((r.determinant() - 1.0).abs() < 1e-12);
    let m3 = glam::DMat3::from_mat4(r);
    assert!((m3.transpose() * m3 - glam::DMat3::IDENTITY).abs().to_cols_array().iter().all(|&e| e < 1e-12));
    assert!(rigid_pose(&DMat4::from_scale(DVec3::new(1.0, 1.0, 0.0))).is_none());
}

#[test]
fn extension_policy() {
    let mut root: gltf::json::Root = gltf::json::deserialize::from_str(r#"{"asset":{"version":"2.0"},
        "extensionsUsed":["KHR_materials_ior","KHR_materials_specular","KHR_texture_transform","KHR_materials_iridescence","EXT_texture_webp","KHR_lights_punctual"],
        "extensionsRequired":["KHR_materials_ior","KHR_materials_specular","KHR_texture_transform","KHR_materials_iridescence","KHR_lights_punctual"]}"#)
    .unwrap();
    let mut w = Vec::new();
    check_extensions(&root, &mut w).unwrap();
    // Supported ones (required or not) say nothing; an ignorable required one and an unknown
    // optional one are warnings naming them.
    assert_eq!(w.len(), 2, "{w:?}");
    assert!(w[0].contains("required extension KHR_materials_iridescence only adds optional material data"), "{w:?}");
    assert!(w[1].contains("extension EXT_texture_webp is used but not supported"), "{w:?}");
    root.extensions_required.push("EXT_texture_webp".into());
    let e = check_extensions(&root, &mut w).unwrap_err();
    assert!(e.contains("required extension EXT_texture_webp is not supported"), "{e}");
    assert!(e.contains("KHR_texture_transform") && e.contains("KHR_materials_specular"), "lists the supported: {e}");
}

#[test]
fn position_accessor_out_of_range_is_an_error_not_a_panic() {
    // gltf-json's own validation would index `accessors` with this unchecked.
    let mut body = triangle_body(json!([]), &[]);
    body["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = json!(5);
    let e = load(&file(&f32_bytes(&TRI), body)).unwrap_err().to_string();
    assert!(e.contains("unit.gltf") && e.contains("accessor 5 does not exist"), "{e}");
}

#[test]
fn a_buffer_view_past_the_buffers_byte_length_is_refused() {
    // The data URI holds the triangle's 36 bytes, but the buffer declares only 24 of them.
    let mut bytes: Value = serde_json::from_slice(&file(&f32_bytes(&TRI), triangle_body(json!([]), &[]))).unwrap();
    bytes["buffers"][0]["byteLength"] = json!(24);
    let e = load(&serde_json::to_vec(&bytes).unwrap()).unwrap_err().to_string();
    assert!(e.contains("unit.gltf") && e.contains("bufferView 0") && e.contains("out of range of buffer 0 (24 bytes)"), "{e}");
    // Declared in full, the same file loads.
    bytes["buffers"][0]["byteLength"] = json!(36);
    assert_eq!(load(&serde_json::to_vec(&bytes).unwrap()).unwrap().mesh.indices.len(), 1);
}

#[test]
fn position_min_max_missing_is_only_a_warning() {
    let mut body = triangle_body(json!([]), &[]);
    body["accessors"][0].as_object_mut().unwrap().remove("min");
    body["accessors"][0].as_object_mut().unwrap().remove("max");
    let s = load(&file(&f32_bytes(&TRI), body)).unwrap();
    assert_eq!(s.mesh.indices.len(), 1);
    assert_eq!(s.warnings.len(), 2, "{:?}", s.warnings);
}

#[test]
fn other_validation_errors_name_the_json_path() {
    let mut body = triangle_body(json!([]), &[]);
    body["accessors"][0]["componentType"] = json!(5130); // DOUBLE: not glTF
    let e = load(&file(&f32_bytes(&TRI), body)).unwrap_err().to_string();
    assert!(e.contains("accessors[0].componentType"), "{e}");
}

#[test]
fn mesh_quantization_positions_and_normals() {
    // KHR_mesh_quantization: u16 positions (not normalized), i16 normalized normals.
    let mut bin: Vec<u8> = [0u16, 0, 0, 0, 2, 0, 0, 0, 0, 2, 0, 0].iter().flat_map(|x| x.to_le_bytes()).collect();
    bin.extend([0i16, 0, -32767, 0, 0, 0, -32767, 0, 0, 0, -32767, 0].iter().flat_map(|x| x.to_le_bytes()));
    let body = json!({
        "extensionsUsed": ["KHR_mesh_quantization"], "extensionsRequired": ["KHR_mesh_quantization"],
        "bufferViews": [{"buffer": 0, "byteLength": 24, "byteStride": 8}, {"buffer": 0, "byteOffset": 24, "byteLength": 24, "byteStride": 8}],
        "accessors": [
            {"bufferView": 0, "componentType": 5123, "count": 3, "type": "VEC3", "min": [0,0,0], "max": [2,2,0]},
            {"bufferView": 1, "componentType": 5122, "normalized": true, "count": 3, "type": "VEC3"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1}}]}],
        "nodes": [{"mesh": 0, "scale": [0.5, 0.5, 0.5]}]
    });
    let s = load(&file(&bin, body)).unwrap();
    let w = |k: usize| s.origin + s.mesh.positions[k].as_dvec3();
    assert!((w(1) - DVec3::new(1.0, 0.0, 0.0)).length() < 1e-7 && (w(2) - DVec3::new(0.0, 1.0, 0.0)).length() < 1e-7);
    assert_eq!(s.mesh.normals[0], Vec3::NEG_Z);
}

#[test]
fn zero_normals_are_repaired_and_degenerate_triangles_kept() {
    // Vertex 0's normal is zero: replaced by the face normal. Triangle 1 is degenerate
    // (repeats a vertex) and is kept.
    let mut bin = f32_bytes(&TRI);
    bin.extend(f32_bytes(&[0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0]));
    bin.extend([0u16, 1, 2, 0, 0, 1].iter().flat_map(|x| x.to_le_bytes()));
    let mut body = triangle_body(
        json!([{"buffer": 0, "byteOffset": 36, "byteLength": 36}, {"buffer": 0, "byteOffset": 72, "byteLength": 12}]),
        &[json!({"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC3"}),
          json!({"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"})],
    );
    body["meshes"][0]["primitives"][0]["attributes"]["NORMAL"] = json!(1);
    body["meshes"][0]["primitives"][0]["indices"] = json!(2);
    let s = load(&file(&bin, body)).unwrap();
    assert_eq!(s.mesh.indices, vec![[0, 1, 2], [0, 0, 1]]);
    assert_eq!(s.mesh.normals[0], Vec3::Z);
    assert!(s.mesh.normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-6));
}

#[test]
fn tangents_follow_the_transform_and_flip_handedness_when_mirrored() {
    let mut bin = f32_bytes(&TRI);
    bin.extend(f32_bytes(&[1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0]));
    let mut body = triangle_body(
        json!([{"buffer": 0, "byteOffset": 36, "byteLength": 48}]),
        &[json!({"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC4"})],
    );
    body["meshes"][0]["primitives"][0]["attributes"]["TANGENT"] = json!(1);
    body["nodes"] = json!([{"mesh": 0}, {"mesh": 0, "scale": [-3, 1, 1]}]);
    body["scenes"] = json!([{"nodes": [0, 1]}]);
    let s = load(&file(&bin, body)).unwrap();
    // Flat normals unshare the vertices: 3 per triangle, node 0 then node 1.
    assert_eq!(s.mesh.tangents[0], Vec4::new(1.0, 0.0, 0.0, 1.0));
    assert_eq!(s.mesh.tangents[3], Vec4::new(-1.0, 0.0, 0.0, -1.0));
    // Mirrored triangle: flat normal from the flipped winding still faces +Z.
    assert!((s.mesh.normals[3] - Vec3::Z).length() < 1e-6);
}

#[test]
fn glb_with_embedded_image_and_missing_bin_chunk() {
    let mut png = std::io::Cursor::new(Vec::new());
    image::RgbaImage::from_pixel(3, 2, image::Rgba([255, 0, 0, 255])).write_to(&mut png, image::ImageFormat::Png).unwrap();
    let png = png.into_inner();
    let mut bin = f32_bytes(&TRI);
    bin.extend_from_slice(&png);
    let mut body = triangle_body(json!([{"buffer": 0, "byteOffset": 36, "byteLength": png.len()}]), &[]);
    body["asset"] = json!({"version": "2.0"});
    body["buffers"] = json!([{"byteLength": bin.len()}]);
    body["images"] = json!([{"bufferView": 1, "mimeType": "image/png"}]);
    body["textures"] = json!([{"source": 0}]);
    body["materials"] = json!([{"emissiveTexture": {"index": 0}, "emissiveFactor": [1, 1, 1]}]);
    body["meshes"][0]["primitives"][0]["material"] = json!(0);
    let glb = |json: &Value, bin: Option<&[u8]>| {
        let mut j = serde_json::to_vec(json).unwrap();
        while !j.len().is_multiple_of(4) {
            j.push(b' ');
        }
        let mut out = b"glTF".to_vec();
        out.extend(2u32.to_le_bytes());
        out.extend(0u32.to_le_bytes());
        out.extend((j.len() as u32).to_le_bytes());
        out.extend(b"JSON");
        out.extend(&j);
        if let Some(b) = bin {
            let mut b = b.to_vec();
            while !b.len().is_multiple_of(4) {
                b.push(0);
            }
            out.extend((b.len() as u32).to_le_bytes());
            out.extend(b"BIN\0");
            out.extend(&b);
        }
        let n = out.len() as u32;
        out[8..12].copy_from_slice(&n.to_le_bytes());
        out
    };
    let s = load(&glb(&body, Some(&bin))).unwrap();
    assert_eq!((s.textures[0].width, s.textures[0].height), (3, 2));
    assert!((s.textures[0].texels[5] - Vec4::new(1.0, 0.0, 0.0, 1.0)).length() < 1e-6);
    assert!(s.materials[0].is_emissive());
    let e = load(&glb(&body, None)).unwrap_err().to_string();
    assert!(e.contains("buffer 0") && e.contains("binary chunk"), "{e}");
    // The texel budget.
    let opts = ImportOptions { max_texture_texels: 5, ..ImportOptions::default() };
    let e = load_gltf_from_slice(&glb(&body, Some(&bin)), None, "unit.glb", &opts).unwrap_err().to_string();
    assert!(e.contains("image 0") && e.contains("budget"), "{e}");
}

#[test]
fn jpeg_textures_decode() {
    let mut jpg = std::io::Cursor::new(Vec::new());
    image::RgbImage::from_pixel(8, 8, image::Rgb([188, 188, 188])).write_to(&mut jpg, image::ImageFormat::Jpeg).unwrap();
    let t = super::textures::decode(&jpg.into_inner(), true, 1000).unwrap();
    assert_eq!((t.width, t.height), (8, 8));
    // A flat grey block survives JPEG within a code value: linear ≈ 0.5029.
    assert!((t.texels[0].x - 0.502_886).abs() < 0.01, "{}", t.texels[0]);
}

#[test]
fn hostile_counts_are_capped_before_allocating() {
    // A sparse accessor with no buffer view claims 10^12 zero-filled elements.
    let mut body = triangle_body(json!([{"buffer": 0, "byteLength": 4}]), &[]);
    body["accessors"][0] = json!({"componentType": 5126, "count": 1_000_000_000_000u64, "type": "VEC3", "min": [0,0,0], "max": [0,0,0],
        "sparse": {"count": 1, "indices": {"bufferView": 1, "componentType": 5125}, "values": {"bufferView": 1}}});
    let e = load(&file(&f32_bytes(&TRI), body)).unwrap_err().to_string();
    assert!(e.contains("exceeds the import limit"), "{e}");
}

#[test]
fn scene_selection_follows_the_spec() {
    let two_nodes = |scenes: Value, scene: Option<usize>| {
        let mut body = triangle_body(json!([]), &[]);
        body["nodes"] = json!([{"mesh": 0}, {"mesh": 0, "translation": [0, 0, 7]}]);
        body["scenes"] = scenes;
        if let Some(s) = scene {
            body["scene"] = json!(s);
        }
        file(&f32_bytes(&TRI), body)
    };
    let count = |bytes: &[u8], opts: &ImportOptions| load_gltf_from_slice(bytes, None, "s.gltf", opts).map(|s| s.mesh.indices.len());
    let d = ImportOptions::default();
    let scenes = json!([{"nodes": [0]}, {"nodes": [0, 1]}]);
    assert_eq!(count(&two_nodes(scenes.clone(), None), &d).unwrap(), 1, "scene 0 without `scene`");
    assert_eq!(count(&two_nodes(scenes.clone(), Some(1)), &d).unwrap(), 2, "the default scene");
    assert_eq!(count(&two_nodes(scenes.clone(), None), &ImportOptions { scene: Some(1), ..d.clone() }).unwrap(), 2);
    assert_eq!(count(&two_nodes(json!([]), None), &d).unwrap(), 2, "no scenes: all root nodes");
    let e = count(&two_nodes(scenes, None), &ImportOptions { scene: Some(5), ..d.clone() }).unwrap_err().to_string();
    assert!(e.contains("scene 5 does not exist"), "{e}");
    let e = count(&two_nodes(json!([{"nodes": [1, 1]}]), None), &d).unwrap_err().to_string();
    assert!(e.contains("node 1 is reached twice"), "{e}");
}

#[test]
fn default_material_is_appended_last() {
    let mut body = triangle_body(json!([]), &[]);
    body["materials"] = json!([{"name": "red", "pbrMetallicRoughness": {"baseColorFactor": [1, 0, 0, 1]}}]);
    body["meshes"] = json!([{"primitives": [{"attributes": {"POSITION": 0}}, {"attributes": {"POSITION": 0}, "material": 0}]}]);
    let s = load(&file(&f32_bytes(&TRI), body)).unwrap();
    assert_eq!(s.mesh.material, vec![1, 0]);
    assert_eq!(s.materials.len(), 2);
    assert_eq!(s.materials[0].name.as_deref(), Some("red"));
    assert_eq!(s.materials[1].base_color_factor, Vec4::ONE);
    assert_eq!((s.materials[1].metallic_factor, s.materials[1].double_sided), (1.0, false));
}

/// A body with one triangle, two 2×1 PNG images (image 0: texels (255,128,0,51), (0,0,0,0);
/// image 1: (188,188,188,255) twice) as textures 0 and 1, and `materials`.
fn materials_body(materials: Value) -> Vec<u8> {
    let png = |px: [[u8; 4]; 2]| {
        let mut img = image::RgbaImage::new(2, 1);
        img.put_pixel(0, 0, image::Rgba(px[0]));
        img.put_pixel(1, 0, image::Rgba(px[1]));
        let mut out = std::io::Cursor::new(Vec::new());
        img.write_to(&mut out, image::ImageFormat::Png).unwrap();
        format!("data:image/png;base64,{}", b64(&out.into_inner()))
    };
    let mut body = triangle_body(json!([]), &[]);
    body["images"] = json!([{"uri": png([[255, 128, 0, 51], [0, 0, 0, 0]])}, {"uri": png([[188, 188, 188, 255]; 2])}]);
    body["textures"] = json!([{"source": 0}, {"source": 1}]);
    body["materials"] = materials;
    file(&f32_bytes(&TRI), body)
}

#[test]
fn reads_khr_materials_specular_ior_and_texture_transform() {
    let bytes = materials_body(json!([
        {"name": "full",
         "pbrMetallicRoughness": {"baseColorTexture": {"index": 1, "extensions": {"KHR_texture_transform": {"offset": [0.5, 0.25], "rotation": 1.5, "scale": [2, 3], "texCoord": 1}}}},
         "emissiveTexture": {"index": 1, "texCoord": 1, "extensions": {"KHR_texture_transform": {"rotation": -0.5}}},
         "extensions": {
            "KHR_materials_specular": {"specularFactor": 0.25, "specularColorFactor": [0.5, 1.5, 2],
                "specularTexture": {"index": 0, "extensions": {"KHR_texture_transform": {"scale": [4, 4], "texCoord": 1}}},
                "specularColorTexture": {"index": 1, "texCoord": 1}},
            "KHR_materials_ior": {"ior": 1.33}}},
        {"name": "defaults", "extensions": {"KHR_materials_specular": {}, "KHR_materials_ior": {}}},
        {"name": "ior zero", "extensions": {"KHR_materials_ior": {"ior": 0}}},
        {"name": "plain"}
    ]));
    let s = load(&bytes).unwrap();
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    let m = &s.materials[0];
    assert_eq!((m.specular_factor, m.specular_color_factor, m.ior), (0.25, Vec3::new(0.5, 1.5, 2.0), 1.33));
    let base = m.base_color_texture.unwrap();
    assert_eq!(base.tex_coord, 1, "texCoord override");
    let t = base.transform.unwrap();
    assert_eq!((t.offset, t.rotation, t.scale), (glam::Vec2::new(0.5, 0.25), 1.5, glam::Vec2::new(2.0, 3.0)));
    let e = m.emissive_texture.unwrap();
    assert_eq!((e.tex_coord, e.transform.unwrap().rotation, e.transform.unwrap().scale), (1, -0.5, glam::Vec2::ONE));
    let spec = m.specular_texture.unwrap();
    assert_eq!((spec.tex_coord, spec.transform.unwrap().scale), (1, glam::Vec2::splat(4.0)));
    let col = m.specular_color_texture.unwrap();
    assert_eq!((col.tex_coord, col.transform), (1, None));
    // specularTexture is data (A kept as stored); specularColorTexture is sRGB → linear.
    let st = &s.textures[spec.texture as usize];
    assert!((st.texels[0].w - 0.2).abs() < 1e-6 && (st.texels[0].y - 128.0 / 255.0).abs() < 1e-6);
    assert!((s.textures[col.texture as usize].texels[0].x - 0.502_886).abs() < 1e-5);
    assert_eq!(col.texture, base.texture, "both colour reads of image 1 share one decoded texture");
    // Defaults: every field of both extensions, and plain glTF.
    for m in [&s.materials[1], &s.materials[3]] {
        assert_eq!((m.specular_factor, m.specular_color_factor, m.ior), (1.0, Vec3::ONE, 1.5), "{:?}", m.name);
        assert!(m.specular_texture.is_none() && m.specular_color_texture.is_none());
    }
    assert_eq!(s.materials[2].ior, 0.0);
    assert!(s.materials[3].base_color_texture.is_none());
}

#[test]
fn malformed_extension_values_name_the_file_material_and_field() {
    let cases = [
        (json!({"KHR_materials_specular": {"specularFactor": "high"}}), "KHR_materials_specular.specularFactor"),
        (json!({"KHR_materials_specular": {"specularFactor": 1.5}}), "KHR_materials_specular.specularFactor"),
        (json!({"KHR_materials_specular": {"specularColorFactor": [1, 1]}}), "KHR_materials_specular.specularColorFactor"),
        (json!({"KHR_materials_specular": {"specularColorFactor": [1, -1, 1]}}), "KHR_materials_specular.specularColorFactor"),
        (json!({"KHR_materials_specular": {"specularTexture": {"index": 9}}}), "KHR_materials_specular.specularTexture.index: texture 9 does not exist"),
        (json!({"KHR_materials_specular": {"specularColorTexture": {"texCoord": 0}}}), "KHR_materials_specular.specularColorTexture.index"),
        (json!({"KHR_materials_specular": 3}), "KHR_materials_specular must be an object"),
        (json!({"KHR_materials_ior": {"ior": 0.5}}), "KHR_materials_ior.ior must be a finite number ≥ 1 or exactly 0"),
        (json!({"KHR_materials_ior": {"ior": -2}}), "KHR_materials_ior.ior"),
        (json!({"KHR_materials_specular": {"specularTexture": {"index": 0, "extensions": {"KHR_texture_transform": {"offset": [0, "x"]}}}}}),
            "KHR_materials_specular.specularTexture.extensions.KHR_texture_transform: offset must be two finite numbers"),
    ];
    for (ext, expect) in cases {
        let e = load(&materials_body(json!([{"name": "m"}, {"name": "bad", "extensions": ext}]))).unwrap_err().to_string();
        assert!(e.contains("unit.gltf") && e.contains("material 1 ('bad')") && e.contains(expect), "{e}");
    }
    let transform_cases = [
        (json!({"rotation": "1"}), "rotation must be a finite number"),
        (json!({"scale": [1, 2, 3]}), "scale must be two finite numbers"),
        (json!({"texCoord": -1}), "texCoord must be a non-negative integer"),
        (json!([1]), "must be an object"),
    ];
    for (t, expect) in transform_cases {
        let body = materials_body(json!([{"normalTexture": {"index": 0, "extensions": {"KHR_texture_transform": t}}}]));
        let e = load(&body).unwrap_err().to_string();
        assert!(e.contains("material 0: normalTexture.extensions.KHR_texture_transform: ") && e.contains(expect), "{e}");
    }
}

#[test]
fn transmission_and_volume_are_read_and_their_bad_values_name_the_material() {
    let body = materials_body(json!([
        {"name": "glass", "extensions": {
            "KHR_materials_transmission": {"transmissionFactor": 0.75, "transmissionTexture": {"index": 0}},
            "KHR_materials_volume": {"thicknessFactor": 0.2, "attenuationColor": [0.5, 0.25, 1], "attenuationDistance": 2}}},
        {"name": "thin", "extensions": {"KHR_materials_transmission": {"transmissionFactor": 1}, "KHR_materials_volume": {}}},
        {"name": "hinted", "extensions": {"KHR_materials_transmission": {"transmissionFactor": 1},
            "KHR_materials_volume": {"thicknessFactor": 1, "thicknessTexture": {"index": 0}}}},
        {"name": "plain"}
    ]));
    let s = load(&body).unwrap();
    let g = &s.materials[0];
    assert!(g.transmits() && g.transmission_factor == 0.75 && g.transmission_texture.is_some());
    let v = g.volume.unwrap();
    assert_eq!((v.attenuation_color, v.attenuation_distance), (Vec3::new(0.5, 0.25, 1.0), 2.0));
    assert!((v.transmittance(2.0) - Vec3::new(0.5, 0.25, 1.0)).abs().max_element() < 1e-6, "c^(d/dist) at d = dist");
    assert!(s.materials[1].transmits() && s.materials[1].volume.is_none(), "thickness 0 is thin-walled");
    let h = s.materials[2].volume.unwrap();
    assert_eq!((h.attenuation_color, h.attenuation_distance), (Vec3::ONE, f32::INFINITY));
    assert_eq!(h.transmittance(5.0), Vec3::ONE);
    assert!(s.warnings.len() == 1 && s.warnings[0].contains("material 2 ('hinted'): KHR_materials_volume.thicknessTexture is not read"), "{:?}", s.warnings);
    assert!(!s.materials[3].transmits() && s.materials[3].volume.is_none());
    let cases = [
        (json!({"KHR_materials_transmission": {"transmissionFactor": 1}, "KHR_materials_ior": {"ior": 0}}), "ior 0 is below 1, which a transmissive material"),
        (json!({"KHR_materials_transmission": {"transmissionFactor": 2}}), "KHR_materials_transmission.transmissionFactor must be a number in [0, 1]"),
        (json!({"KHR_materials_transmission": []}), "KHR_materials_transmission must be an object"),
        (json!({"KHR_materials_volume": {"thicknessFactor": 1, "attenuationDistance": 0}}), "KHR_materials_volume.attenuationDistance must be a finite number > 0"),
        (json!({"KHR_materials_volume": {"attenuationDistance": -1}}), "KHR_materials_volume.attenuationDistance"),
        (json!({"KHR_materials_volume": {"thicknessFactor": -1}}), "KHR_materials_volume.thicknessFactor must be a finite number ≥ 0"),
        (json!({"KHR_materials_volume": {"attenuationColor": [2, 0, 0]}}), "KHR_materials_volume.attenuationColor must be three numbers in [0, 1]"),
    ];
    for (ext, expect) in cases {
        let e = load(&materials_body(json!([{"name": "m"}, {"name": "bad", "extensions": ext}]))).unwrap_err().to_string();
        assert!(e.contains("unit.gltf") && e.contains("material 1 ('bad')") && e.contains(expect), "{e}");
    }
}

#[test]
fn clearcoat_and_sheen_are_read_and_their_bad_values_name_the_material() {
    let body = materials_body(json!([
        {"name": "coated", "extensions": {"KHR_materials_clearcoat": {
            "clearcoatFactor": 0.75, "clearcoatTexture": {"index": 0},
            "clearcoatRoughnessFactor": 0.25, "clearcoatRoughnessTexture": {"index": 0, "extensions": {"KHR_texture_transform": {"scale": [2, 2]}}},
            "clearcoatNormalTexture": {"index": 0, "scale": 0.5}}}},
        {"name": "velvet", "extensions": {"KHR_materials_sheen": {
            "sheenColorFactor": [0.5, 0.25, 1], "sheenColorTexture": {"index": 0},
            "sheenRoughnessFactor": 0.3, "sheenRoughnessTexture": {"index": 0}}}},
        {"name": "off", "extensions": {"KHR_materials_clearcoat": {"clearcoatRoughnessFactor": 0.5}, "KHR_materials_sheen": {"sheenRoughnessFactor": 1}}},
        {"name": "plain"}
    ]));
    let s = load(&body).unwrap();
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    let c = s.materials[0].clearcoat.unwrap();
    assert_eq!((c.factor, c.roughness_factor), (0.75, 0.25));
    assert!(c.texture.is_some() && c.roughness_texture.unwrap().transform.is_some());
    assert_eq!(c.normal_texture.map(|(_, k)| k), Some(0.5));
    let h = s.materials[1].sheen.unwrap();
    assert_eq!((h.color_factor, h.roughness_factor), (Vec3::new(0.5, 0.25, 1.0), 0.3));
    assert!(h.color_texture.is_some() && h.roughness_texture.is_some());
    // The sheen colour texture is sRGB, the roughness one data: two decodings of the image.
    assert_ne!(h.color_texture.unwrap().texture, h.roughness_texture.unwrap().texture);
    // A zero clearcoat factor or a black sheen colour (the defaults) disables the layer.
    assert!(s.materials[2].clearcoat.is_none() && s.materials[2].sheen.is_none());
    assert!(s.materials[3].clearcoat.is_none() && s.materials[3].sheen.is_none());
    let cases = [
        (json!({"KHR_materials_clearcoat": {"clearcoatFactor": 1.5}}), "KHR_materials_clearcoat.clearcoatFactor must be a number in [0, 1]"),
        (json!({"KHR_materials_clearcoat": {"clearcoatFactor": 1, "clearcoatRoughnessFactor": -0.1}}), "KHR_materials_clearcoat.clearcoatRoughnessFactor must be a number in [0, 1]"),
        (json!({"KHR_materials_clearcoat": {"clearcoatFactor": "1"}}), "KHR_materials_clearcoat.clearcoatFactor"),
        (json!({"KHR_materials_clearcoat": {"clearcoatFactor": 1, "clearcoatNormalTexture": {"index": 0, "scale": "x"}}}), "KHR_materials_clearcoat.clearcoatNormalTexture.scale must be a finite number"),
        (json!({"KHR_materials_clearcoat": {"clearcoatFactor": 1, "clearcoatTexture": {"index": 9}}}), "KHR_materials_clearcoat.clearcoatTexture.index: texture 9 does not exist"),
        (json!({"KHR_materials_clearcoat": 1}), "KHR_materials_clearcoat must be an object"),
        (json!({"KHR_materials_sheen": {"sheenColorFactor": [1, 2, 0]}}), "KHR_materials_sheen.sheenColorFactor must be three numbers in [0, 1]"),
        (json!({"KHR_materials_sheen": {"sheenColorFactor": [1, 1]}}), "KHR_materials_sheen.sheenColorFactor must be three numbers in [0, 1]"),
        (json!({"KHR_materials_sheen": {"sheenColorFactor": [1, 1, 1], "sheenRoughnessFactor": 2}}), "KHR_materials_sheen.sheenRoughnessFactor must be a number in [0, 1]"),
        (json!({"KHR_materials_sheen": {"sheenColorFactor": [1, 1, 1], "sheenRoughnessTexture": 3}}), "KHR_materials_sheen.sheenRoughnessTexture must be a textureInfo object"),
    ];
    for (ext, expect) in cases {
        let e = load(&materials_body(json!([{"name": "m"}, {"name": "bad", "extensions": ext}]))).unwrap_err().to_string();
        assert!(e.contains("unit.gltf") && e.contains("material 1 ('bad')") && e.contains(expect), "{e}");
    }
}

/// Only glTF 2.x is read: another major version in `asset.version` or `asset.minVersion` is
/// refused, naming the field, rather than read as if it were 2.0.
#[test]
fn other_major_gltf_versions_are_refused() {
    let with_asset = |asset: Value| {
        let mut v: Value = serde_json::from_slice(&file(&f32_bytes(&TRI), triangle_body(json!([]), &[]))).unwrap();
        v["asset"] = asset;
        serde_json::to_vec(&v).unwrap()
    };
    for (asset, field) in [
        (json!({"version": "3.0"}), "asset.version is \"3.0\""),
        (json!({"version": "1.0"}), "asset.version is \"1.0\""),
        (json!({"version": "two"}), "asset.version is \"two\""),
        (json!({"version": "2.0", "minVersion": "3.0"}), "asset.minVersion is \"3.0\""),
    ] {
        let e = load(&with_asset(asset)).unwrap_err().to_string();
        assert!(e.starts_with("unit.gltf: ") && e.contains(field) && e.contains("only glTF 2.x"), "{e}");
    }
    for asset in [json!({"version": "2.0"}), json!({"version": "2.1", "minVersion": "2.0"})] {
        assert_eq!(load(&with_asset(asset)).unwrap().mesh.indices.len(), 1);
    }
}

/// A node with both a matrix and TRS properties (which one applies is undefined) is refused,
/// naming the node and the properties; a matrix alone and TRS alone load; a matrix or TRS
/// property of the wrong length is refused.
#[test]
fn a_node_with_both_matrix_and_trs_is_refused() {
    let with_node = |node: Value| {
        let mut body = triangle_body(json!([]), &[]);
        body["nodes"] = json!([node]);
        file(&f32_bytes(&TRI), body)
    };
    let m = json!([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]);
    for (extra, named) in [(json!({"scale": [2, 2, 2]}), "scale"), (json!({"translation": [0, 1, 0], "rotation": [0, 0, 0, 1]}), "translation, rotation")] {
        let mut node = json!({"mesh": 0, "matrix": m});
        for (k, v) in extra.as_object().unwrap() {
            node[k] = v.clone();
        }
        let e = load(&with_node(node)).unwrap_err().to_string();
        assert!(e.contains("node 0") && e.contains(&format!("has both a matrix and {named}")), "{e}");
    }
    assert!(load(&with_node(json!({"mesh": 0, "matrix": m}))).is_ok());
    assert!(load(&with_node(json!({"mesh": 0, "scale": [2, 2, 2]}))).is_ok());
    // A matrix or TRS property of the wrong length is refused too (by the JSON schema, before
    // our own checks), never read as the default.
    for node in [
        json!({"mesh": 0, "translation": [1, 2]}),
        json!({"mesh": 0, "rotation": [0, 0, 1]}),
        json!({"mesh": 0, "scale": [2, 2, 2, 2]}),
        json!({"mesh": 0, "matrix": [1, 0, 0, 1]}),
    ] {
        let e = load(&with_node(node.clone())).unwrap_err().to_string();
        assert!(e.starts_with("unit.gltf: invalid glTF JSON"), "{node}: {e}");
    }
}
