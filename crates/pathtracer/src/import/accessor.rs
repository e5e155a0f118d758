//! A bounds-checked glTF accessor reader: every component type, normalisation per the spec
//! (section 3.11, "Animations"/"Meshes": `f = max(c / 127, -1)` for i8, `c / 255` for u8,
//! `max(c / 32767, -1)` for i16, `c / 65535` for u16), interleaved buffer views
//! (`byteStride`), accessors without a buffer view (zeros) and sparse substitution.
//! Every offset and length from the file is checked before it is used; nothing here can
//! panic or read out of bounds on hostile data.

use gltf::json::accessor::{ComponentType, Type};
use gltf::json::validation::Checked;
use gltf::json::Root;

/// Decoded accessor contents as `f64`, `count × dims` values, element-major.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct AccessorData {
    /// Components per element (1 for SCALAR, 2–4 for VEC2–VEC4).
    pub dims: usize,
    /// Element-major values.
    pub values: Vec<f64>,
}

impl AccessorData {
    /// Number of elements.
    pub fn len(&self) -> usize {
        self.values.len().checked_div(self.dims).unwrap_or(0)
    }
    /// Element `i` (zero-padded past `dims`, so callers can read a fixed width).
    pub fn get<const N: usize>(&self, i: usize) -> [f64; N] {
        let mut out = [0.0; N];
        let start = i.saturating_mul(self.dims);
        for (k, o) in out.iter_mut().enumerate().take(self.dims) {
            *o = self.values.get(start + k).copied().unwrap_or(0.0);
        }
        out
    }
}

fn component_size(ct: ComponentType) -> usize {
    match ct {
        ComponentType::I8 | ComponentType::U8 => 1,
        ComponentType::I16 | ComponentType::U16 => 2,
        ComponentType::U32 | ComponentType::F32 => 4,
    }
}

fn component_name(ct: ComponentType) -> &'static str {
    match ct {
        ComponentType::I8 => "BYTE",
        ComponentType::U8 => "UNSIGNED_BYTE",
        ComponentType::I16 => "SHORT",
        ComponentType::U16 => "UNSIGNED_SHORT",
        ComponentType::U32 => "UNSIGNED_INT",
        ComponentType::F32 => "FLOAT",
    }
}

/// Reads one component from exactly `component_size(ct)` bytes, normalising integer types
/// when `normalized` (glTF 2.0 spec, "Animation samplers / mesh attributes" formulas).
fn decode_component(b: &[u8], ct: ComponentType, normalized: bool) -> f64 {
    let b0 = b.first().copied().unwrap_or(0);
    let b1 = b.get(1).copied().unwrap_or(0);
    let b2 = b.get(2).copied().unwrap_or(0);
    let b3 = b.get(3).copied().unwrap_or(0);
    match ct {
        ComponentType::I8 => {
            let c = f64::from(b0 as i8);
            if normalized { (c / 127.0).max(-1.0) } else { c }
        }
        ComponentType::U8 => {
            let c = f64::from(b0);
            if normalized { c / 255.0 } else { c }
        }
        ComponentType::I16 => {
            let c = f64::from(i16::from_le_bytes([b0, b1]));
            if normalized { (c / 32767.0).max(-1.0) } else { c }
        }
        ComponentType::U16 => {
            let c = f64::from(u16::from_le_bytes([b0, b1]));
            if normalized { c / 65535.0 } else { c }
        }
        ComponentType::U32 => {
            let c = f64::from(u32::from_le_bytes([b0, b1, b2, b3]));
            if normalized { c / f64::from(u32::MAX) } else { c }
        }
        ComponentType::F32 => f64::from(f32::from_le_bytes([b0, b1, b2, b3])),
    }
}

/// The bytes of buffer view `view` (bounds-checked against the loaded buffer) and its stride.
pub(crate) fn view_bytes<'b>(
    root: &Root,
    buffers: &'b [Vec<u8>],
    view: usize,
) -> Result<(&'b [u8], Option<usize>), String> {
    let v = root.buffer_views.get(view).ok_or_else(|| format!("bufferView {view} does not exist"))?;
    let buffer_index = v.buffer.value();
    let data = buffers.get(buffer_index).ok_or_else(|| format!("bufferView {view}: buffer {buffer_index} does not exist"))?;
    let offset = v.byte_offset.map_or(0, |o| o.0);
    let length = v.byte_length.0;
    let end = offset.checked_add(length).filter(|&e| e <= data.len() as u64).ok_or_else(|| {
        format!(
            "bufferView {view} (byteOffset {offset}, byteLength {length}) is out of range of buffer {buffer_index} ({} bytes)",
            data.len()
        )
    })?;
    // Both fit in the buffer's length, hence in usize.
    let bytes = data.get(offset as usize..end as usize).ok_or_else(|| format!("bufferView {view} out of range"))?;
    Ok((bytes, v.byte_stride.map(|s| s.0).filter(|&s| s != 0)))
}

/// Checks that `count` elements of `elem_size` bytes, `stride` apart from `offset`, lie in
/// `bytes`.
fn check_range(bytes: &[u8], offset: u64, stride: usize, elem_size: usize, count: usize, what: &str) -> Result<(), String> {
    if count == 0 {
        return Ok(());
    }
    let last_end = (count as u64 - 1)
        .checked_mul(stride as u64)
        .and_then(|x| x.checked_add(offset))
        .and_then(|x| x.checked_add(elem_size as u64));
    match last_end {
        Some(end) if end <= bytes.len() as u64 => Ok(()),
        _ => Err(format!(
            "{what}: {count} elements of {elem_size} bytes (stride {stride}) from byteOffset {offset} overrun its bufferView ({} bytes)",
            bytes.len()
        )),
    }
}

/// Reads `count` tightly or stride-packed elements of `elem_size` bytes starting at `offset`
/// of `bytes`, calling `f(element_index, element_bytes)`.
fn for_each_element(
    bytes: &[u8],
    offset: u64,
    stride: usize,
    elem_size: usize,
    count: usize,
    what: &str,
    mut f: impl FnMut(usize, &[u8]),
) -> Result<(), String> {
    check_range(bytes, offset, stride, elem_size, count, what)?;
    for i in 0..count {
        let start = offset as usize + i * stride;
        let e = bytes.get(start..start + elem_size).ok_or_else(|| format!("{what}: element {i} out of range"))?;
        f(i, e);
    }
    Ok(())
}

/// How to interpret an accessor's integers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Interpret {
    /// As the accessor says (`normalized` flag honoured).
    Attribute,
    /// Raw unsigned integers (indices): only UNSIGNED_BYTE/SHORT/INT SCALAR allowed.
    Indices,
    /// 4×4 matrices (a skin's inverse bind matrices): only FLOAT MAT4 allowed, read as 16
    /// column-major values per element.
    Matrix4,
}

/// Reads accessor `index` into `f64`s. `max_elements` caps the allocation.
pub(crate) fn read(
    root: &Root,
    buffers: &[Vec<u8>],
    index: usize,
    interpret: Interpret,
    max_elements: usize,
) -> Result<AccessorData, String> {
    let what = format!("accessor {index}");
    let acc = root.accessors.get(index).ok_or_else(|| format!("{what} does not exist"))?;
    let Checked::Valid(ct) = acc.component_type else {
        return Err(format!("{what}: invalid componentType"));
    };
    let ct = ct.0;
    let Checked::Valid(ty) = acc.type_ else {
        return Err(format!("{what}: invalid type"));
    };
    let dims = match ty {
        Type::Scalar => 1,
        Type::Vec2 => 2,
        Type::Vec3 => 3,
        Type::Vec4 => 4,
        Type::Mat4 if interpret == Interpret::Matrix4 => 16,
        Type::Mat2 | Type::Mat3 if interpret == Interpret::Matrix4 => 0,
        Type::Mat2 | Type::Mat3 | Type::Mat4 => {
            return Err(format!("{what}: matrix accessors are not valid vertex data"));
        }
    };
    if interpret == Interpret::Matrix4 && (dims != 16 || ct != ComponentType::F32) {
        return Err(format!("{what}: inverse bind matrices must be FLOAT MAT4, found {ty:?} {}", component_name(ct)));
    }
    let normalized = match interpret {
        Interpret::Attribute | Interpret::Matrix4 => acc.normalized,
        Interpret::Indices => {
            if dims != 1 || !matches!(ct, ComponentType::U8 | ComponentType::U16 | ComponentType::U32) {
                return Err(format!(
                    "{what}: indices must be SCALAR UNSIGNED_BYTE/SHORT/INT, found {ty:?} {}",
                    component_name(ct)
                ));
            }
            false
        }
    };
    let count = usize::try_from(acc.count.0).unwrap_or(usize::MAX);
    if count > max_elements {
        return Err(format!("{what}: count {count} exceeds the import limit of {max_elements} elements"));
    }
    let csize = component_size(ct);
    let elem_size = csize * dims;
    // Check the dense data fits its view before allocating anything.
    let dense = match acc.buffer_view {
        Some(view) => {
            let (bytes, stride) = view_bytes(root, buffers, view.value()).map_err(|e| format!("{what}: {e}"))?;
            let stride = stride.unwrap_or(elem_size);
            if stride < elem_size {
                return Err(format!("{what}: byteStride {stride} is smaller than the element size {elem_size}"));
            }
            let offset = acc.byte_offset.map_or(0, |o| o.0);
            check_range(bytes, offset, stride, elem_size, count, &what)?;
            Some((bytes, stride, offset))
        }
        None => None,
    };
    let mut values = vec![0.0f64; count * dims];
    if let Some((bytes, stride, offset)) = dense {
        for_each_element(bytes, offset, stride, elem_size, count, &what, |i, e| {
            for k in 0..dims {
                values[i * dims + k] = decode_component(&e[k * csize..(k + 1) * csize], ct, normalized);
            }
        })?;
    }
    if let Some(sparse) = &acc.sparse {
        let what = format!("{what} (sparse)");
        let scount = usize::try_from(sparse.count.0).unwrap_or(usize::MAX);
        if scount > count {
            return Err(format!("{what}: sparse count {scount} exceeds the accessor count {count}"));
        }
        let Checked::Valid(ict) = sparse.indices.component_type else {
            return Err(format!("{what}: invalid indices componentType"));
        };
        let ict = ict.0;
        if !matches!(ict, ComponentType::U8 | ComponentType::U16 | ComponentType::U32) {
            return Err(format!("{what}: sparse indices must be unsigned, found {}", component_name(ict)));
        }
        let isize = component_size(ict);
        let (ibytes, _) = view_bytes(root, buffers, sparse.indices.buffer_view.value()).map_err(|e| format!("{what} indices: {e}"))?;
        let mut targets = Vec::new();
        for_each_element(ibytes, sparse.indices.byte_offset.0, isize, isize, scount, &format!("{what} indices"), |_, e| {
            targets.push(decode_component(e, ict, false) as usize);
        })?;
        if let Some(bad) = targets.iter().find(|&&t| t >= count) {
            return Err(format!("{what}: sparse index {bad} is out of range (count {count})"));
        }
        let (vbytes, _) = view_bytes(root, buffers, sparse.values.buffer_view.value()).map_err(|e| format!("{what} values: {e}"))?;
        for_each_element(vbytes, sparse.values.byte_offset.0, elem_size, elem_size, scount, &format!("{what} values"), |j, e| {
            let target = targets.get(j).copied().unwrap_or(0);
            for k in 0..dims {
                values[target * dims + k] = decode_component(&e[k * csize..(k + 1) * csize], ct, normalized);
            }
        })?;
    }
    Ok(AccessorData { dims, values })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn root(json: &str) -> Root {
        gltf::json::deserialize::from_str(json).unwrap()
    }

    #[test]
    fn normalisation_formulas() {
        assert_eq!(decode_component(&[127], ComponentType::I8, true), 1.0);
        assert_eq!(decode_component(&[0x80], ComponentType::I8, true), -1.0); // -128 clamps
        assert_eq!(decode_component(&[0x81], ComponentType::I8, true), -1.0); // -127
        assert_eq!(decode_component(&[255], ComponentType::U8, true), 1.0);
        assert_eq!(decode_component(&[51], ComponentType::U8, true), 0.2);
        assert_eq!(decode_component(&0x7fffi16.to_le_bytes(), ComponentType::I16, true), 1.0);
        assert_eq!(decode_component(&i16::MIN.to_le_bytes(), ComponentType::I16, true), -1.0);
        assert_eq!(decode_component(&65535u16.to_le_bytes(), ComponentType::U16, true), 1.0);
        assert_eq!(decode_component(&200u8.to_le_bytes(), ComponentType::U8, false), 200.0);
        assert_eq!(decode_component(&1.5f32.to_le_bytes(), ComponentType::F32, true), 1.5);
    }

    #[test]
    fn interleaved_and_sparse() {
        // Buffer: 3 interleaved vertices (vec2 f32 + u16 normalized scalar + 2 pad = 12 bytes),
        // then sparse indices (u8: 2) and values (vec2 f32: (9, 9)).
        let mut buf = Vec::new();
        for (x, y, c) in [(1.0f32, 2.0f32, 0u16), (3.0, 4.0, 65535), (5.0, 6.0, 0)] {
            buf.extend_from_slice(&x.to_le_bytes());
            buf.extend_from_slice(&y.to_le_bytes());
            buf.extend_from_slice(&c.to_le_bytes());
            buf.extend_from_slice(&[0, 0]);
        }
        buf.extend_from_slice(&[2, 0, 0, 0]);
        buf.extend_from_slice(&9.0f32.to_le_bytes());
        buf.extend_from_slice(&9.0f32.to_le_bytes());
        let json = r#"{"asset":{"version":"2.0"},
          "buffers":[{"byteLength":48}],
          "bufferViews":[{"buffer":0,"byteLength":36,"byteStride":12},
                         {"buffer":0,"byteOffset":36,"byteLength":4},
                         {"buffer":0,"byteOffset":40,"byteLength":8}],
          "accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC2"},
                       {"bufferView":0,"byteOffset":8,"componentType":5123,"normalized":true,"count":3,"type":"SCALAR"},
                       {"bufferView":0,"componentType":5126,"count":3,"type":"VEC2",
                        "sparse":{"count":1,"indices":{"bufferView":1,"componentType":5121},
                                  "values":{"bufferView":2}}},
                       {"componentType":5126,"count":2,"type":"VEC2",
                        "sparse":{"count":1,"indices":{"bufferView":1,"componentType":5121},
                                  "values":{"bufferView":2}}},
                       {"bufferView":0,"byteOffset":4,"componentType":5126,"count":3,"type":"VEC3"}]}"#;
        let r = root(json);
        let bufs = vec![buf];
        let a = read(&r, &bufs, 0, Interpret::Attribute, 100).unwrap();
        assert_eq!(a.values, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        let c = read(&r, &bufs, 1, Interpret::Attribute, 100).unwrap();
        assert_eq!(c.values, vec![0.0, 1.0, 0.0]);
        let s = read(&r, &bufs, 2, Interpret::Attribute, 100).unwrap();
        assert_eq!(s.values, vec![1.0, 2.0, 3.0, 4.0, 9.0, 9.0]);
        // Sparse without a buffer view: zeros, index 2 out of range for count 2.
        assert!(read(&r, &bufs, 3, Interpret::Attribute, 100).unwrap_err().contains("out of range"));
        // A VEC3 at offset 4 with stride 12: last element ends at 4 + 24 + 12 = 40 > 36.
        assert!(read(&r, &bufs, 4, Interpret::Attribute, 100).unwrap_err().contains("overrun"));
        // The allocation cap.
        assert!(read(&r, &bufs, 0, Interpret::Attribute, 2).unwrap_err().contains("limit"));
        // Float data are not indices.
        assert!(read(&r, &bufs, 0, Interpret::Indices, 100).is_err());
        assert_eq!(read(&r, &bufs, 1, Interpret::Indices, 100).unwrap().values, vec![0.0, 65535.0, 0.0]);
        // Missing accessor.
        assert!(read(&r, &bufs, 99, Interpret::Attribute, 100).is_err());
    }
}
