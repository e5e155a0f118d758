//! The encoding side of the glTF writer (`SceneBuilder` uses it): [`BinWriter`] packs the
//! buffer, its bufferViews and accessors (4-byte aligned, exact `min`/`max`), [`jf`] writes an
//! f32 as its shortest round-trip decimal, and [`canonical_json`] prints a document with sorted
//! keys, so that identical scenes give identical bytes.

use serde_json::{Map, Value, json};

/// A JSON number holding the f32 `x` in its shortest round-trip decimal form.
pub(crate) fn jf(x: f32) -> Value {
    // Display for f32 prints the shortest decimal that parses back to the same f32.
    let shortest: f64 = format!("{x}").parse().unwrap_or(x as f64);
    serde_json::Number::from_f64(shortest).map_or(Value::Null, Value::Number)
}

/// A JSON array of [`jf`] numbers.
pub(crate) fn jf_slice(xs: &[f32]) -> Value {
    Value::Array(xs.iter().map(|&x| jf(x)).collect())
}

/// Accumulates the binary buffer, its bufferViews and accessors.
#[derive(Default)]
pub(crate) struct BinWriter {
    pub(crate) data: Vec<u8>,
    pub(crate) views: Vec<Value>,
    pub(crate) accessors: Vec<Value>,
}

const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_BYTE: u32 = 5121;
const UNSIGNED_SHORT: u32 = 5123;
const UNSIGNED_INT: u32 = 5125;

impl BinWriter {
    /// Append bytes as a new bufferView starting on a 4-byte boundary.
    pub(crate) fn view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        while !self.data.len().is_multiple_of(4) {
            self.data.push(0);
        }
        let mut v = Map::new();
        v.insert("buffer".into(), json!(0));
        v.insert("byteOffset".into(), json!(self.data.len()));
        v.insert("byteLength".into(), json!(bytes.len()));
        if let Some(t) = target {
            v.insert("target".into(), json!(t));
        }
        self.data.extend_from_slice(bytes);
        // The buffer itself ends on a 4-byte boundary (needed by GLB chunks).
        while !self.data.len().is_multiple_of(4) {
            self.data.push(0);
        }
        self.views.push(Value::Object(v));
        self.views.len() - 1
    }

    /// A float vertex attribute with `dims` components per element.
    pub(crate) fn floats(&mut self, values: &[f32], dims: usize) -> usize {
        let bytes: Vec<u8> = values.iter().flat_map(|x| x.to_le_bytes()).collect();
        let view = self.view(&bytes, Some(ARRAY_BUFFER));
        let mut lo = vec![f32::INFINITY; dims];
        let mut hi = vec![f32::NEG_INFINITY; dims];
        for chunk in values.chunks_exact(dims) {
            for (k, &x) in chunk.iter().enumerate() {
                lo[k] = lo[k].min(x);
                hi[k] = hi[k].max(x);
            }
        }
        let ty = match dims {
            2 => "VEC2",
            3 => "VEC3",
            _ => "VEC4",
        };
        self.accessors.push(json!({
            "bufferView": view,
            "componentType": FLOAT,
            "count": values.len() / dims,
            "type": ty,
            "min": jf_slice(&lo),
            "max": jf_slice(&hi),
        }));
        self.accessors.len() - 1
    }

    /// Triangle indices as u16 when every vertex index fits, else u32.
    /// Per-vertex joint indices (JOINTS_0): UNSIGNED_BYTE VEC4.
    pub(crate) fn joints(&mut self, joints: &[[u8; 4]]) -> usize {
        let bytes: Vec<u8> = joints.iter().flatten().copied().collect();
        let view = self.view(&bytes, Some(ARRAY_BUFFER));
        let lo: Vec<u8> = (0..4).map(|k| joints.iter().map(|j| j[k]).min().unwrap_or(0)).collect();
        let hi: Vec<u8> = (0..4).map(|k| joints.iter().map(|j| j[k]).max().unwrap_or(0)).collect();
        self.accessors.push(json!({
            "bufferView": view,
            "componentType": UNSIGNED_BYTE,
            "count": joints.len(),
            "type": "VEC4",
            "min": lo,
            "max": hi,
        }));
        self.accessors.len() - 1
    }

    /// Column-major 4×4 matrices (a skin's inverse bind matrices): FLOAT MAT4.
    pub(crate) fn matrices(&mut self, matrices: &[[f32; 16]]) -> usize {
        let bytes: Vec<u8> = matrices.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
        let view = self.view(&bytes, None);
        let lo: Vec<f32> = (0..16).map(|k| matrices.iter().map(|m| m[k]).fold(f32::INFINITY, f32::min)).collect();
        let hi: Vec<f32> = (0..16).map(|k| matrices.iter().map(|m| m[k]).fold(f32::NEG_INFINITY, f32::max)).collect();
        self.accessors.push(json!({
            "bufferView": view,
            "componentType": FLOAT,
            "count": matrices.len(),
            "type": "MAT4",
            "min": jf_slice(&lo),
            "max": jf_slice(&hi),
        }));
        self.accessors.len() - 1
    }

    /// A sparse FLOAT VEC3 accessor of `count` elements, zero except at the strictly
    /// increasing `indices`, where it holds `values` (no dense bufferView), with `min`/`max`
    /// over all `count` elements (zeros included).
    pub(crate) fn sparse_vec3(&mut self, count: usize, indices: &[u32], values: &[[f32; 3]]) -> usize {
        let ibytes: Vec<u8> = indices.iter().flat_map(|i| i.to_le_bytes()).collect();
        let vbytes: Vec<u8> = values.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
        let iview = self.view(&ibytes, None);
        let vview = self.view(&vbytes, None);
        let mut lo = [if indices.len() < count { 0.0f32 } else { f32::INFINITY }; 3];
        let mut hi = [if indices.len() < count { 0.0f32 } else { f32::NEG_INFINITY }; 3];
        for v in values {
            for k in 0..3 {
                lo[k] = lo[k].min(v[k]);
                hi[k] = hi[k].max(v[k]);
            }
        }
        self.accessors.push(json!({
            "componentType": FLOAT,
            "count": count,
            "type": "VEC3",
            "min": jf_slice(&lo),
            "max": jf_slice(&hi),
            "sparse": {
                "count": indices.len(),
                "indices": { "bufferView": iview, "componentType": UNSIGNED_INT },
                "values": { "bufferView": vview },
            },
        }));
        self.accessors.len() - 1
    }

    pub(crate) fn indices(&mut self, indices: &[u32], vertex_count: usize) -> usize {
        let (bytes, component): (Vec<u8>, u32) = if vertex_count <= u16::MAX as usize {
            (
                indices
                    .iter()
                    .flat_map(|&i| (i as u16).to_le_bytes())
                    .collect(),
                UNSIGNED_SHORT,
            )
        } else {
            (
                indices.iter().flat_map(|&i| i.to_le_bytes()).collect(),
                UNSIGNED_INT,
            )
        };
        let view = self.view(&bytes, Some(ELEMENT_ARRAY_BUFFER));
        let lo = indices.iter().copied().min().unwrap_or(0);
        let hi = indices.iter().copied().max().unwrap_or(0);
        self.accessors.push(json!({
            "bufferView": view,
            "componentType": component,
            "count": indices.len(),
            "type": "SCALAR",
            "min": [lo],
            "max": [hi],
        }));
        self.accessors.len() - 1
    }
}

/// Pretty JSON with object keys sorted and arrays of scalars on one line,
/// independent of serde_json's map ordering features.
pub(crate) fn canonical_json(v: &Value) -> String {
    fn scalar(v: &Value) -> String {
        // Scalars serialise infallibly.
        serde_json::to_string(v).unwrap_or_default()
    }
    fn go(v: &Value, indent: usize, out: &mut String) {
        let pad = "  ".repeat(indent + 1);
        match v {
            Value::Object(map) => {
                if map.is_empty() {
                    out.push_str("{}");
                    return;
                }
                let mut keys: Vec<&String> = map.keys().collect();
                keys.sort();
                out.push_str("{\n");
                for (i, k) in keys.iter().enumerate() {
                    out.push_str(&pad);
                    out.push_str(&scalar(&Value::String((*k).clone())));
                    out.push_str(": ");
                    go(&map[*k], indent + 1, out);
                    out.push_str(if i + 1 < keys.len() { ",\n" } else { "\n" });
                }
                out.push_str(&"  ".repeat(indent));
                out.push('}');
            }
            Value::Array(items) => {
                if items.iter().all(|x| !x.is_object() && !x.is_array()) {
                    out.push('[');
                    let parts: Vec<String> = items.iter().map(scalar).collect();
                    out.push_str(&parts.join(", "));
                    out.push(']');
                    return;
                }
                out.push_str("[\n");
                for (i, item) in items.iter().enumerate() {
                    out.push_str(&pad);
                    go(item, indent + 1, out);
                    out.push_str(if i + 1 < items.len() { ",\n" } else { "\n" });
                }
                out.push_str(&"  ".repeat(indent));
                out.push(']');
            }
            other => out.push_str(&scalar(other)),
        }
    }
    let mut out = String::new();
    go(v, 0, &mut out);
    out.push('\n');
    out
}
