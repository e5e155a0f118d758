//! OBJ text: `v x y z` (up to four more numbers, a weight or a colour, ignored), `vn`, and `f`
//! with corners `v`, `v/vt`, `v//vn` or `v/vt/vn`, an index counted from 1, or from the end
//! of the vertices so far when negative; a corner must name a vertex defined above it. `#`
//! starts a comment; every other statement (`vt`, `g`, `o`, `s`, `usemtl`, `l`, …) carries
//! nothing scored and is passed over. Messages name the line; the caller adds the file.

use super::{MAX_VERTICES, Raw};

fn floats<'a>(w: impl Iterator<Item = &'a str>, line_no: usize) -> Result<Vec<f64>, String> {
    w.map(|t| t.parse::<f64>().map_err(|_| format!("line {line_no}: `{t}` is not a number"))).collect()
}

/// Reads an OBJ file's vertices, normals and faces.
pub(super) fn parse(bytes: &[u8]) -> Result<Raw, String> {
    let mut raw = Raw::new("OBJ");
    let mut normals: Vec<[f32; 3]> = Vec::new();
    let mut corners: Vec<u32> = Vec::new();
    for (k, line) in bytes.split(|&b| b == b'\n').enumerate() {
        let line_no = k + 1;
        let line = line.strip_suffix(b"\r").unwrap_or(line);
        let start = line.iter().position(|b| !b.is_ascii_whitespace()).unwrap_or(line.len());
        if start == line.len() || line[start] == b'#' {
            continue;
        }
        let text = std::str::from_utf8(line).map_err(|_| format!("line {line_no} is not text (not UTF-8)"))?;
        let text = text.split('#').next().unwrap_or("");
        let mut w = text.split_ascii_whitespace();
        match w.next() {
            Some("v") => {
                let v = floats(w, line_no)?;
                if !(3..=7).contains(&v.len()) {
                    return Err(format!("line {line_no}: a vertex has {} numbers, not 3 (to 7)", v.len()));
                }
                if raw.positions.len() == MAX_VERTICES {
                    return Err(format!("line {line_no}: more than {MAX_VERTICES} vertices, the most a geometry file may hold"));
                }
                raw.positions.push([v[0] as f32, v[1] as f32, v[2] as f32]);
            }
            Some("vn") => {
                let v = floats(w, line_no)?;
                if v.len() != 3 {
                    return Err(format!("line {line_no}: a normal has {} numbers, not 3", v.len()));
                }
                if normals.len() == MAX_VERTICES {
                    return Err(format!("line {line_no}: more than {MAX_VERTICES} normals"));
                }
                normals.push([v[0] as f32, v[1] as f32, v[2] as f32]);
            }
            Some("f") => {
                corners.clear();
                let nv = raw.positions.len();
                for (c, t) in w.enumerate() {
                    let first = t.split('/').next().unwrap_or("");
                    let i = first.parse::<i64>().map_err(|_| format!("line {line_no}: corner {c} `{t}` does not start with a vertex index"))?;
                    let index = if i > 0 { i - 1 } else { nv as i64 + i };
                    if i == 0 || index < 0 || index >= nv as i64 {
                        return Err(format!("line {line_no}: corner {c} names vertex {i}, but {nv} vertices are defined above it"));
                    }
                    corners.push(index as u32);
                }
                raw.push_face(&corners).map_err(|m| format!("line {line_no}: face: {m}"))?;
            }
            _ => {}
        }
    }
    if raw.faces == 0 && !normals.is_empty() {
        if normals.len() == raw.positions.len() {
            raw.normals = Some(normals);
        } else {
            raw.notes.push(format!("The {} normals (`vn`) are not used: a point cloud needs one per vertex, and it has {} vertices.", normals.len(), raw.positions.len()));
        }
    }
    Ok(raw)
}
