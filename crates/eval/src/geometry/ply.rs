//! PLY bodies: the header (elements, scalar and list properties of any PLY type), then the
//! elements in order through one [`Body`] for ascii (one element per line, tokens) and
//! binary (either byte order). Elements other than `vertex` and `face` are walked past; those
//! after the last needed one are not read. Messages name the element, its number and where
//! (line or byte); the caller adds the file.

use super::{MAX_VERTICES, Raw};

/// The most header bytes looked through for `end_header`.
const MAX_HEADER_BYTES: usize = 1 << 20;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    fn is_float(self) -> bool {
        matches!(self, Self::F32 | Self::F64)
    }

    /// The range of an integer type.
    fn range(self) -> (i64, i64) {
        match self {
            Self::I8 => (i8::MIN.into(), i8::MAX.into()),
            Self::U8 => (0, u8::MAX.into()),
            Self::I16 => (i16::MIN.into(), i16::MAX.into()),
            Self::U16 => (0, u16::MAX.into()),
            Self::I32 => (i32::MIN.into(), i32::MAX.into()),
            _ => (0, u32::MAX.into()),
        }
    }
}

#[derive(Debug)]
enum Property {
    Scalar(Scalar, String),
    /// Count type, item type, name.
    List(Scalar, Scalar, String),
}

impl Property {
    fn name(&self) -> &str {
        match self {
            Self::Scalar(_, n) | Self::List(_, _, n) => n,
        }
    }

    /// The fewest bytes it takes in a binary body.
    fn min_bytes(&self) -> usize {
        match self {
            Self::Scalar(t, _) | Self::List(t, _, _) => t.size(),
        }
    }
}

#[derive(Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Encoding {
    Ascii,
    Little,
    Big,
}

/// The encoding, the elements and where the body starts.
fn header(bytes: &[u8]) -> Result<(Encoding, Vec<Element>, usize), String> {
    let (mut pos, mut line_no) = (0usize, 0usize);
    let (mut encoding, mut elements) = (None, Vec::<Element>::new());
    loop {
        if pos >= bytes.len() || pos > MAX_HEADER_BYTES {
            return Err(format!("the header has no `end_header` line (looked through {} bytes)", pos.min(bytes.len())));
        }
        let end = bytes[pos..].iter().position(|&b| b == b'\n').map_or(bytes.len(), |k| pos + k);
        let raw = &bytes[pos..end];
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        line_no += 1;
        pos = end + 1;
        let line = std::str::from_utf8(raw).map_err(|_| format!("header line {line_no} is not text (not UTF-8)"))?;
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            ["ply"] if line_no == 1 => {}
            _ if line_no == 1 => return Err("not a PLY file: its first line is not `ply`".into()),
            ["format", f, version] => {
                encoding = Some(match *f {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::Little,
                    "binary_big_endian" => Encoding::Big,
                    _ => return Err(format!("header line {line_no}: unknown format `{f}`")),
                });
                if !version.starts_with('1') {
                    return Err(format!("header line {line_no}: PLY version {version}, not 1.x"));
                }
            }
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["element", name, count] => {
                let count = count.parse::<usize>().map_err(|_| format!("header line {line_no}: element count `{count}` is not a whole number"))?;
                if elements.iter().any(|e| e.name == *name) {
                    return Err(format!("header line {line_no}: a second `{name}` element"));
                }
                elements.push(Element { name: name.to_string(), count, props: Vec::new() });
            }
            ["property", "list", c, i, name] => {
                let ty = |s: &str| Scalar::parse(s).ok_or_else(|| format!("header line {line_no}: unknown type `{s}`"));
                let (c, i) = (ty(c)?, ty(i)?);
                if c.is_float() {
                    return Err(format!("header line {line_no}: list `{name}` has a floating-point count type"));
                }
                last(&mut elements, line_no)?.props.push(Property::List(c, i, name.to_string()));
            }
            ["property", t, name] => {
                let t = Scalar::parse(t).ok_or_else(|| format!("header line {line_no}: unknown type `{t}`"))?;
                last(&mut elements, line_no)?.props.push(Property::Scalar(t, name.to_string()));
            }
            ["end_header"] => break,
            _ => return Err(format!("header line {line_no}: `{line}` is not a PLY header line")),
        }
    }
    let encoding = encoding.ok_or("the header has no `format` line")?;
    Ok((encoding, elements, pos.min(bytes.len())))
}

fn last(elements: &mut [Element], line_no: usize) -> Result<&mut Element, String> {
    elements.last_mut().ok_or_else(|| format!("header line {line_no}: a property before any element"))
}

/// A body's elements, read one property value at a time.
trait Body {
    /// Moves to the next element.
    fn begin(&mut self) -> Result<(), String>;
    /// The next value (an integer type's value is whole and in its range).
    fn value(&mut self, ty: Scalar) -> Result<f64, String>;
    /// Skips `n` values.
    fn skip(&mut self, ty: Scalar, n: usize) -> Result<(), String>;
    /// Ends the element.
    fn end(&mut self) -> Result<(), String>;
    /// Where the current element is.
    fn location(&self) -> String;
    /// The most elements of at least `min_bytes` bytes that the rest of the body can hold.
    fn room(&self, min_bytes: usize) -> usize;
    /// Whether `n` more values could follow (a binary body's bytes; an ascii line's values run
    /// out on their own).
    fn fits(&self, ty: Scalar, n: usize) -> bool;
}

struct Binary<'a> {
    b: &'a [u8],
    pos: usize,
    start: usize,
    big: bool,
}

const TRUNCATED: &str = "the file ends inside it (truncated, or the header declares more than the file holds)";

impl Body for Binary<'_> {
    fn begin(&mut self) -> Result<(), String> {
        self.start = self.pos;
        Ok(())
    }

    fn value(&mut self, ty: Scalar) -> Result<f64, String> {
        let n = ty.size();
        let s = self.b.get(self.pos..self.pos + n).ok_or(TRUNCATED)?;
        self.pos += n;
        let mut a = [0u8; 8];
        a[..n].copy_from_slice(s);
        if self.big {
            a[..n].reverse();
        }
        Ok(match ty {
            Scalar::I8 => a[0] as i8 as f64,
            Scalar::U8 => a[0] as f64,
            Scalar::I16 => i16::from_le_bytes([a[0], a[1]]) as f64,
            Scalar::U16 => u16::from_le_bytes([a[0], a[1]]) as f64,
            Scalar::I32 => i32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::U32 => u32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::F32 => f32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::F64 => f64::from_le_bytes(a),
        })
    }

    fn skip(&mut self, ty: Scalar, n: usize) -> Result<(), String> {
        let end = n.checked_mul(ty.size()).and_then(|l| self.pos.checked_add(l)).filter(|&e| e <= self.b.len()).ok_or(TRUNCATED)?;
        self.pos = end;
        Ok(())
    }

    fn end(&mut self) -> Result<(), String> {
        Ok(())
    }

    fn location(&self) -> String {
        format!("byte {}", self.start)
    }

    fn room(&self, min_bytes: usize) -> usize {
        (self.b.len() - self.pos.min(self.b.len())).checked_div(min_bytes).unwrap_or(usize::MAX)
    }

    fn fits(&self, ty: Scalar, n: usize) -> bool {
        n.checked_mul(ty.size()).is_some_and(|l| l <= self.b.len() - self.pos.min(self.b.len()))
    }
}

struct Ascii<'a> {
    rest: &'a [u8],
    line_no: usize,
    tokens: std::str::SplitAsciiWhitespace<'a>,
}

impl<'a> Body for Ascii<'a> {
    fn begin(&mut self) -> Result<(), String> {
        loop {
            if self.rest.is_empty() {
                return Err("the file ends before it (the header declares more elements than the file holds)".into());
            }
            let end = self.rest.iter().position(|&b| b == b'\n').unwrap_or(self.rest.len());
            let line: &'a [u8] = &self.rest[..end];
            self.rest = &self.rest[(end + 1).min(self.rest.len())..];
            self.line_no += 1;
            let text = std::str::from_utf8(line).map_err(|_| format!("line {} is not text (not UTF-8)", self.line_no))?;
            if !text.trim().is_empty() {
                self.tokens = text.split_ascii_whitespace();
                return Ok(());
            }
        }
    }

    fn value(&mut self, ty: Scalar) -> Result<f64, String> {
        let t = self.tokens.next().ok_or("its line has fewer values than the header's properties")?;
        if ty.is_float() {
            return t.parse::<f64>().map_err(|_| format!("`{t}` is not a number"));
        }
        let v = t.parse::<i64>().map_err(|_| format!("`{t}` is not a whole number"))?;
        let (lo, hi) = ty.range();
        if v < lo || v > hi {
            return Err(format!("{v} is out of the range of its type ({lo} to {hi})"));
        }
        Ok(v as f64)
    }

    fn skip(&mut self, ty: Scalar, n: usize) -> Result<(), String> {
        for _ in 0..n {
            self.value(ty)?;
        }
        Ok(())
    }

    fn end(&mut self) -> Result<(), String> {
        match self.tokens.next() {
            Some(t) => Err(format!("its line has more values than the header's properties (`{t}` and after)")),
            None => Ok(()),
        }
    }

    fn location(&self) -> String {
        format!("line {}", self.line_no)
    }

    fn room(&self, _min_bytes: usize) -> usize {
        self.rest.iter().filter(|&&b| b == b'\n').count() + usize::from(!self.rest.ends_with(b"\n"))
    }

    fn fits(&self, _ty: Scalar, _n: usize) -> bool {
        true
    }
}

/// What a property of the vertex or face element is used for.
#[derive(Clone, Copy, PartialEq)]
enum Role {
    Skip,
    /// Coordinate (0..3) or normal component (3..6).
    Vertex(usize),
    Corners,
}

fn vertex_roles(e: &Element) -> Result<(Vec<Role>, bool), String> {
    const NAMES: [&str; 6] = ["x", "y", "z", "nx", "ny", "nz"];
    let mut roles = vec![Role::Skip; e.props.len()];
    let mut found = [false; 6];
    for (k, p) in e.props.iter().enumerate() {
        if let Some(j) = NAMES.iter().position(|n| *n == p.name()) {
            match p {
                Property::Scalar(t, _) if t.is_float() => {}
                _ => return Err(format!("vertex property `{}` must be a float or double", p.name())),
            }
            roles[k] = Role::Vertex(j);
            found[j] = true;
        }
    }
    if !found[..3].iter().all(|f| *f) {
        return Err("the vertex element lacks one of x, y, z".into());
    }
    let normals = found[3..].iter().filter(|f| **f).count();
    if normals != 0 && normals != 3 {
        return Err("the vertex element has some but not all of nx, ny, nz".into());
    }
    Ok((roles, normals == 3))
}

fn face_roles(e: &Element) -> Result<Vec<Role>, String> {
    let mut roles = vec![Role::Skip; e.props.len()];
    let mut found = false;
    for (k, p) in e.props.iter().enumerate() {
        if matches!(p.name(), "vertex_indices" | "vertex_index") {
            match p {
                Property::List(_, i, _) if !i.is_float() => {}
                _ => return Err(format!("face property `{}` must be a list of integers", p.name())),
            }
            if found {
                return Err("the face element has two vertex index lists".into());
            }
            roles[k] = Role::Corners;
            found = true;
        }
    }
    if !found {
        return Err("the face element has no `vertex_indices` (or `vertex_index`) list".into());
    }
    Ok(roles)
}

/// Reads a PLY file's vertices and faces.
pub(super) fn parse(bytes: &[u8]) -> Result<Raw, String> {
    let (encoding, elements, start) = header(bytes)?;
    if let Some(e) = elements.iter().find(|e| e.name == "tristrips") {
        return Err(format!("the `{}` element (triangle strips) is not read; write faces instead", e.name));
    }
    let vi = elements.iter().position(|e| e.name == "vertex").ok_or("the header declares no `vertex` element")?;
    let fi = elements.iter().position(|e| e.name == "face");
    let nv = elements[vi].count;
    if nv > MAX_VERTICES {
        return Err(format!("the header declares {nv} vertices, more than the {MAX_VERTICES} a geometry file may hold"));
    }
    let (vroles, has_normals) = vertex_roles(&elements[vi])?;
    let froles = fi.map(|f| face_roles(&elements[f])).transpose()?;
    let format = match encoding {
        Encoding::Ascii => "PLY ascii",
        Encoding::Little => "PLY binary_little_endian",
        Encoding::Big => "PLY binary_big_endian",
    };
    let body = &bytes[start..];
    let mut reader: Box<dyn Body + '_> = match encoding {
        Encoding::Ascii => Box::new(Ascii { rest: body, line_no: bytes[..start].iter().filter(|&&b| b == b'\n').count(), tokens: "".split_ascii_whitespace() }),
        e => Box::new(Binary { b: body, pos: 0, start: 0, big: e == Encoding::Big }),
    };
    let mut raw = Raw::new(format);
    let mut normals = Vec::new();
    let mut corners: Vec<u32> = Vec::new();
    let last = fi.map_or(vi, |f| f.max(vi));
    for (ei, el) in elements.iter().enumerate().take(last + 1) {
        let min = el.props.iter().map(Property::min_bytes).sum::<usize>();
        let room = reader.room(min);
        if el.count > room {
            return Err(format!(
                "the header declares {} `{}` elements, but the rest of the file holds at most {room} of them",
                el.count, el.name
            ));
        }
        let roles: &[Role] = if ei == vi {
            &vroles
        } else if Some(ei) == fi {
            froles.as_deref().unwrap_or(&[])
        } else {
            &[]
        };
        if ei == vi {
            raw.positions.reserve_exact(el.count);
            if has_normals {
                normals.reserve_exact(el.count);
            }
        }
        for k in 0..el.count {
            let at = |reader: &dyn Body, m: String| format!("{} {k} ({}): {m}", el.name, reader.location());
            reader.begin().map_err(|m| format!("{} {k}: {m}", el.name))?;
            let mut v = [0f64; 6];
            for (j, p) in el.props.iter().enumerate() {
                let role = roles.get(j).copied().unwrap_or(Role::Skip);
                match (p, role) {
                    (Property::Scalar(t, _), Role::Vertex(c)) => v[c] = reader.value(*t).map_err(|m| at(&*reader, m))?,
                    (Property::Scalar(t, _), _) => reader.skip(*t, 1).map_err(|m| at(&*reader, m))?,
                    (Property::List(c, i, _), role) => {
                        let n = reader.value(*c).map_err(|m| at(&*reader, m))?;
                        if n < 0.0 {
                            return Err(at(&*reader, format!("list `{}` has a negative length {n}", p.name())));
                        }
                        let n = n as usize;
                        if role != Role::Corners {
                            reader.skip(*i, n).map_err(|m| at(&*reader, m))?;
                            continue;
                        }
                        if !reader.fits(*i, n) {
                            return Err(at(&*reader, format!("it has {n} corners, more than the rest of the file holds")));
                        }
                        corners.clear();
                        for c in 0..n {
                            let x = reader.value(*i).map_err(|m| at(&*reader, m))?;
                            if !(x >= 0.0 && x < nv as f64) {
                                return Err(at(&*reader, format!("corner {c} is vertex {x}, out of range (the file has {nv} vertices)")));
                            }
                            corners.push(x as u32);
                        }
                    }
                }
            }
            reader.end().map_err(|m| at(&*reader, m))?;
            if ei == vi {
                raw.positions.push([v[0] as f32, v[1] as f32, v[2] as f32]);
                if has_normals {
                    normals.push([v[3] as f32, v[4] as f32, v[5] as f32]);
                }
            } else if Some(ei) == fi {
                raw.push_face(&corners).map_err(|m| at(&*reader, m))?;
            }
        }
    }
    raw.normals = has_normals.then_some(normals);
    Ok(raw)
}
