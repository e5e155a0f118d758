//! Reading another tool's prediction files, defensively: regular files only, read with a size
//! cap, the image size checked before the pixels are decoded, and every error one sentence
//! naming the file.
//!
//! Colour ([`read_colour`]) comes back as display (sRGB) RGBA in [0, 1] with straight alpha,
//! the space and alpha convention of the dataset's PNGs:
//! - PNG (8 or 16 bit, grey or RGB, with or without alpha) and JPEG: values as stored;
//! - EXR (channels `R`, `G`, `B`, optional `A`): linear colour with premultiplied alpha, as our
//!   datasets write it, converted as the dataset's PNG is made from its EXR
//!   (`dataset::folder::display`: `srgb(rgb / a)`, 0 where `a = 0`, clamped to [0, 1]);
//! - `.npy` / `.npy.gz` (float32 or float64, `H×W×3` or `H×W×4`): display values as stored
//!   (nerfstudio's `raw-rgb`).
//!
//! A pixel with a non-finite value stays non-finite (NaN) through every conversion, so the
//! evaluation counts it instead of seeing a clamped 0.
//!
//! Scalars ([`read_scalar`], depth and opacity): `.npy` / `.npy.gz` (`H×W` or `H×W×1`), EXR
//! (channel `depth`, `Z`, `Y` or `R`, or its only channel), or a 16-bit single-channel PNG whose
//! integer values need a stated unit.

use crate::EvalError;
use std::io::Read;
use std::path::Path;

fn invalid(path: &Path, message: impl std::fmt::Display) -> EvalError {
    EvalError::Input(format!("{}: {message}", path.display()))
}

/// Reads the whole of `path`, a regular file of at most `cap` bytes.
pub fn read_regular(path: &Path, cap: u64) -> Result<Vec<u8>, EvalError> {
    let meta = std::fs::metadata(path).map_err(|source| EvalError::Io { path: path.to_path_buf(), source })?;
    if !meta.is_file() {
        return Err(invalid(path, "is not a regular file"));
    }
    if meta.len() > cap {
        return Err(invalid(path, format!("is {} bytes, more than the {cap} a prediction of this size may take", meta.len())));
    }
    let f = std::fs::File::open(path).map_err(|source| EvalError::Io { path: path.to_path_buf(), source })?;
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    f.take(cap + 1).read_to_end(&mut bytes).map_err(|source| EvalError::Io { path: path.to_path_buf(), source })?;
    if bytes.len() as u64 > cap {
        return Err(invalid(path, format!("grew past {cap} bytes while read")));
    }
    Ok(bytes)
}

/// The most bytes a prediction file of a `width × height` view may take: 16 MiB of headroom
/// plus 64 bytes a pixel (four float64 channels twice over).
pub fn size_cap(width: u32, height: u32) -> u64 {
    (16 << 20) + 64 * u64::from(width) * u64::from(height)
}

/// A decoded colour prediction: display RGBA, straight alpha.
///
/// # Shapes
/// `rgba`: `[H * W * 4]`.
#[derive(Clone, Debug)]
pub struct ColourImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Display RGBA in [0, 1] (non-finite values kept as NaN).
    pub rgba: Vec<f32>,
    /// Whether the file carried alpha (else alpha is 1).
    pub has_alpha: bool,
}

/// A decoded scalar prediction (depth or opacity).
#[derive(Clone, Debug)]
pub struct ScalarImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Values as stored, `[H * W]`.
    pub values: Vec<f32>,
    /// Whether they are a 16-bit PNG's integers (no unit of their own).
    pub integer_png: bool,
}

/// The kinds of prediction file, by extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FileKind {
    /// `.png`
    Png,
    /// `.jpg`, `.jpeg`
    Jpeg,
    /// `.exr`
    Exr,
    /// `.npy`
    Npy,
    /// `.npy.gz`
    NpyGz,
}

impl FileKind {
    /// The extension it is named by (`png`, `jpg`, `exr`, `npy`, `npy.gz`).
    pub fn extension(self) -> &'static str {
        match self {
            FileKind::Png => "png",
            FileKind::Jpeg => "jpg",
            FileKind::Exr => "exr",
            FileKind::Npy => "npy",
            FileKind::NpyGz => "npy.gz",
        }
    }

    /// The kind of a file name (case-insensitive extension), and the name without it.
    pub fn of(name: &str) -> Option<(FileKind, &str)> {
        let lower = name.to_ascii_lowercase();
        for (ext, kind) in [(".npy.gz", FileKind::NpyGz), (".npy", FileKind::Npy), (".png", FileKind::Png), (".jpg", FileKind::Jpeg), (".jpeg", FileKind::Jpeg), (".exr", FileKind::Exr)] {
            if lower.ends_with(ext) && name.len() > ext.len() {
                return Some((kind, &name[..name.len() - ext.len()]));
            }
        }
        None
    }
}

fn kind_of(path: &Path) -> Result<FileKind, EvalError> {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    FileKind::of(&name).map(|k| k.0).ok_or_else(|| invalid(path, "has no extension a prediction is read from (.png, .jpg, .exr, .npy, .npy.gz)"))
}

/// The size a prediction must have: the view at the evaluated resolution, and the dataset's
/// full resolution (to say which `--downscale` a mis-sized file would match).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Expected {
    /// Width and height at the evaluated resolution.
    pub size: (u32, u32),
    /// Width and height of the dataset's images.
    pub full: (u32, u32),
}

fn check_size(path: &Path, got: (u32, u32), want: Expected) -> Result<(), EvalError> {
    if got == want.size {
        return Ok(());
    }
    let (w, h) = want.size;
    let factor = (got.0 > 0 && got.1 > 0 && want.full.0.is_multiple_of(got.0) && want.full.1.is_multiple_of(got.1) && want.full.0 / got.0 == want.full.1 / got.1).then(|| want.full.0 / got.0);
    let hint = match factor {
        Some(1) => " (the dataset's full resolution: leave out --downscale)".to_string(),
        Some(f) => format!(" (1/{f} of the dataset's resolution: give --downscale {f})"),
        None => String::new(),
    };
    Err(invalid(path, format!("is {}x{}, the view is {w}x{h} at the resolution scored{hint}", got.0, got.1)))
}

/// Reads a colour prediction of the size `want` (see the module docs).
pub fn read_colour(path: &Path, want: Expected) -> Result<ColourImage, EvalError> {
    let kind = kind_of(path)?;
    let bytes = read_regular(path, size_cap(want.size.0, want.size.1))?;
    match kind {
        FileKind::Png | FileKind::Jpeg => {
            let format = if kind == FileKind::Png { image::ImageFormat::Png } else { image::ImageFormat::Jpeg };
            let dims = image::ImageReader::with_format(std::io::Cursor::new(&bytes), format).into_dimensions().map_err(|e| invalid(path, format!("unreadable image ({e})")))?;
            check_size(path, dims, want)?;
            let img = image::load_from_memory_with_format(&bytes, format).map_err(|e| invalid(path, format!("unreadable image ({e})")))?;
            let has_alpha = img.color().has_alpha();
            let rgba = img.to_rgba32f();
            Ok(ColourImage { width: rgba.width(), height: rgba.height(), rgba: rgba.into_raw(), has_alpha })
        }
        FileKind::Exr => {
            let (size, mut channels) = read_exr(path, &bytes, want)?;
            let mut take = |name: &str| channels.iter().position(|(n, _)| n == name).map(|k| channels.swap_remove(k).1);
            let (Some(r), Some(g), Some(b)) = (take("R"), take("G"), take("B")) else {
                return Err(invalid(path, "EXR colour needs channels R, G and B"));
            };
            let a = take("A");
            let n = (size.0 * size.1) as usize;
            let mut rgba = Vec::with_capacity(4 * n);
            for k in 0..n {
                let alpha = a.as_ref().map_or(1.0, |a| a[k]);
                let px = [r[k], g[k], b[k], alpha];
                if px.iter().any(|v| !v.is_finite()) {
                    rgba.extend([f32::NAN; 4]);
                    continue;
                }
                let alpha = alpha.clamp(0.0, 1.0);
                for v in &px[..3] {
                    rgba.push(if alpha > 0.0 { dataset::linear_to_srgb(v / alpha) } else { 0.0 });
                }
                rgba.push(alpha);
            }
            Ok(ColourImage { width: size.0, height: size.1, rgba, has_alpha: a.is_some() })
        }
        FileKind::Npy | FileKind::NpyGz => {
            let arr = parse_npy(path, &inflate(path, kind, bytes, want)?)?;
            let (h, w, c) = match arr.shape[..] {
                [h, w, c] if c == 3 || c == 4 => (h, w, c),
                _ => return Err(invalid(path, format!("colour .npy must be H x W x 3 or 4, not {:?}", arr.shape))),
            };
            check_size(path, (w as u32, h as u32), want)?;
            let rgba = if c == 4 { arr.values } else { arr.values.chunks_exact(3).flat_map(|p| [p[0], p[1], p[2], 1.0]).collect() };
            Ok(ColourImage { width: w as u32, height: h as u32, rgba, has_alpha: c == 4 })
        }
    }
}

/// Reads a scalar prediction of the size `want` (see the module docs).
pub fn read_scalar(path: &Path, want: Expected) -> Result<ScalarImage, EvalError> {
    let kind = kind_of(path)?;
    let bytes = read_regular(path, size_cap(want.size.0, want.size.1))?;
    match kind {
        FileKind::Png => {
            let dims = image::ImageReader::with_format(std::io::Cursor::new(&bytes), image::ImageFormat::Png).into_dimensions().map_err(|e| invalid(path, format!("unreadable image ({e})")))?;
            check_size(path, dims, want)?;
            let img = image::load_from_memory_with_format(&bytes, image::ImageFormat::Png).map_err(|e| invalid(path, format!("unreadable image ({e})")))?;
            match img {
                image::DynamicImage::ImageLuma16(g) => Ok(ScalarImage { width: g.width(), height: g.height(), values: g.into_raw().into_iter().map(f32::from).collect(), integer_png: true }),
                other => Err(invalid(path, format!("a depth or opacity PNG must be 16-bit single-channel, not {:?} (an 8-bit or colour PNG is a picture, e.g. ns-render's colour-mapped depth)", other.color()))),
            }
        }
        FileKind::Jpeg => Err(invalid(path, "a JPEG holds a picture, not depth or opacity values")),
        FileKind::Exr => {
            let (size, channels) = read_exr(path, &bytes, want)?;
            let pick = ["depth", "Z", "Y", "R"].iter().find_map(|n| channels.iter().position(|(c, _)| c == n)).or((channels.len() == 1).then_some(0));
            let Some(k) = pick else {
                let names: Vec<&str> = channels.iter().map(|(n, _)| n.as_str()).collect();
                return Err(invalid(path, format!("no depth channel: it has {names:?}, expected one of depth, Z, Y, R or a single channel")));
            };
            let values = channels.into_iter().nth(k).map(|c| c.1).unwrap_or_default();
            Ok(ScalarImage { width: size.0, height: size.1, values, integer_png: false })
        }
        FileKind::Npy | FileKind::NpyGz => {
            let arr = parse_npy(path, &inflate(path, kind, bytes, want)?)?;
            let (h, w) = match arr.shape[..] {
                [h, w] | [h, w, 1] => (h, w),
                _ => return Err(invalid(path, format!("depth or opacity .npy must be H x W or H x W x 1, not {:?}", arr.shape))),
            };
            check_size(path, (w as u32, h as u32), want)?;
            Ok(ScalarImage { width: w as u32, height: h as u32, values: arr.values, integer_png: false })
        }
    }
}

/// The bytes of a `.npy`: as read, or gunzipped (at most [`size_cap`] bytes) for `.npy.gz`.
fn inflate(path: &Path, kind: FileKind, bytes: Vec<u8>, want: Expected) -> Result<Vec<u8>, EvalError> {
    if kind != FileKind::NpyGz {
        return Ok(bytes);
    }
    let cap = size_cap(want.size.0, want.size.1);
    let mut out = Vec::new();
    flate2::read::GzDecoder::new(&bytes[..])
        .take(cap + 1)
        .read_to_end(&mut out)
        .map_err(|e| invalid(path, format!("not a gzip stream ({e})")))?;
    if out.len() as u64 > cap {
        return Err(invalid(path, format!("unpacks to more than the {cap} bytes a prediction of this size may take")));
    }
    Ok(out)
}

/// Named channels of an image, each `[H * W]`.
type Channels = Vec<(String, Vec<f32>)>;

/// An EXR's first layer: its size (checked against `want` before the pixels are decoded) and
/// every channel as `f32`.
fn read_exr(path: &Path, bytes: &[u8], want: Expected) -> Result<((u32, u32), Channels), EvalError> {
    let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(bytes), false).map_err(|e| invalid(path, format!("unreadable EXR ({e})")))?;
    let header = meta.headers.first().ok_or_else(|| invalid(path, "EXR without a layer"))?;
    check_size(path, (header.layer_size.0 as u32, header.layer_size.1 as u32), want)?;
    use exr::prelude::{ReadChannels, ReadLayers};
    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(bytes))
        .map_err(|e| invalid(path, format!("unreadable EXR ({e})")))?;
    let layer = image.layer_data;
    let size = (layer.size.0 as u32, layer.size.1 as u32);
    check_size(path, size, want)?;
    let channels = layer.channel_data.list.into_iter().map(|c| (c.name.to_string(), c.sample_data.values_as_f32().collect())).collect();
    Ok((size, channels))
}

/// A parsed `.npy` array, converted to `f32`.
#[derive(Clone, Debug, PartialEq)]
pub struct NpyArray {
    /// The shape, C order.
    pub shape: Vec<usize>,
    /// The values, C order.
    pub values: Vec<f32>,
}

/// Parses a `.npy` file (format versions 1 to 3) holding a C-order float32 or float64 array of
/// either byte order.
pub fn parse_npy(path: &Path, bytes: &[u8]) -> Result<NpyArray, EvalError> {
    let bad = |m: &str| invalid(path, format!("not a .npy array we read: {m}"));
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(bad("no .npy magic"));
    }
    let (len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize, 12),
        v => return Err(bad(&format!("format version {v}"))),
    };
    let header = bytes.get(start..start + len).ok_or_else(|| bad("header runs past the end"))?;
    let header = std::str::from_utf8(header).map_err(|_| bad("header is not text"))?;
    let value_of = |key: &str| -> Option<&str> {
        let at = header.find(&format!("'{key}'")).or_else(|| header.find(&format!("\"{key}\"")))?;
        let rest = &header[at + key.len() + 2..];
        Some(rest.trim_start().strip_prefix(':')?.trim_start())
    };
    let descr = value_of("descr").and_then(|v| v.get(1..).and_then(|v| v.split(['\'', '"']).next())).ok_or_else(|| bad("no 'descr'"))?;
    if value_of("fortran_order").is_some_and(|v| v.starts_with("True")) {
        return Err(bad("Fortran order"));
    }
    let shape_text = value_of("shape").and_then(|v| v.strip_prefix('(')).and_then(|v| v.split(')').next()).ok_or_else(|| bad("no 'shape'"))?;
    let shape: Vec<usize> = shape_text
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse::<usize>().map_err(|_| bad(&format!("shape ({shape_text})"))))
        .collect::<Result<_, _>>()?;
    let (little, size) = match descr.as_bytes() {
        [o, b'f', b'4'] if b"<=|".contains(o) => (true, 4),
        [b'>', b'f', b'4'] => (false, 4),
        [o, b'f', b'8'] if b"<=|".contains(o) => (true, 8),
        [b'>', b'f', b'8'] => (false, 8),
        _ => return Err(bad(&format!("dtype '{descr}' (float32 or float64 expected)"))),
    };
    let count = shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d)).ok_or_else(|| bad("shape too large"))?;
    let data = &bytes[start + len..];
    if Some(data.len()) != count.checked_mul(size) {
        return Err(bad(&format!("{} bytes of data, the shape {shape:?} needs {}", data.len(), count.saturating_mul(size))));
    }
    let values = match (size, little) {
        (4, true) => data.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect(),
        (4, false) => data.chunks_exact(4).map(|c| f32::from_be_bytes([c[0], c[1], c[2], c[3]])).collect(),
        (_, true) => data.chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])) as f32).collect(),
        (_, false) => data.chunks_exact(8).map(|c| f64::from_be_bytes(c.try_into().unwrap_or([0; 8])) as f32).collect(),
    };
    Ok(NpyArray { shape, values })
}

/// The bytes of a little-endian float32 `.npy` of `shape` (for tests and fixtures).
pub fn npy_bytes(shape: &[usize], values: &[f32]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(usize::to_string).collect();
    let dims = if dims.len() == 1 { format!("{},", dims[0]) } else { dims.join(", ") };
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({dims}), }}");
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn npy_round_trip_and_refusals() {
        let p = Path::new("x.npy");
        let a = parse_npy(p, &npy_bytes(&[2, 3, 1], &[1.0, 2.0, 3.0, 4.0, f32::NAN, 6.0])).unwrap();
        assert_eq!(a.shape, vec![2, 3, 1]);
        assert_eq!(a.values[3], 4.0);
        assert!(a.values[4].is_nan());
        // float64, big-endian, version 2
        let mut b = b"\x93NUMPY\x02\x00".to_vec();
        let h = "{'descr': '>f8', 'fortran_order': False, 'shape': (2,), }\n";
        b.extend_from_slice(&(h.len() as u32).to_le_bytes());
        b.extend_from_slice(h.as_bytes());
        b.extend_from_slice(&1.5f64.to_be_bytes());
        b.extend_from_slice(&(-2.0f64).to_be_bytes());
        assert_eq!(parse_npy(p, &b).unwrap().values, vec![1.5, -2.0]);
        let mut short = npy_bytes(&[2, 2], &[0.0; 4]);
        short.pop();
        let e = parse_npy(p, &short).unwrap_err().to_string();
        assert!(e.starts_with("x.npy: ") && e.contains("bytes of data"), "{e}");
        let e = parse_npy(p, b"\x93NUMPY\x01\x00\x10\x00{'descr': '<i4'}").unwrap_err().to_string();
        assert!(e.contains("'<i4'") || e.contains("shape"), "{e}");
        assert!(parse_npy(p, b"PK\x03\x04 a zip").unwrap_err().to_string().contains("magic"));
    }

    #[test]
    fn file_kinds_by_extension() {
        assert_eq!(FileKind::of("r_0.npy.gz"), Some((FileKind::NpyGz, "r_0")));
        assert_eq!(FileKind::of("r_0_depth.NPY"), Some((FileKind::Npy, "r_0_depth")));
        assert_eq!(FileKind::of("r_0.jpeg"), Some((FileKind::Jpeg, "r_0")));
        assert_eq!(FileKind::of("notes.txt"), None);
        assert_eq!(FileKind::of(".png"), None);
    }

    #[test]
    fn reads_are_capped_and_regular_files_only() {
        let tmp = tempfile::tempdir().unwrap();
        let f = tmp.path().join("big.png");
        std::fs::write(&f, vec![0u8; 100]).unwrap();
        assert!(read_regular(&f, 100).is_ok());
        let e = read_regular(&f, 99).unwrap_err().to_string();
        assert!(e.contains("big.png") && e.contains("100 bytes"), "{e}");
        let e = read_regular(tmp.path(), 1000).unwrap_err().to_string();
        assert!(e.contains("not a regular file"), "{e}");
        // A gzip bomb is cut off at the cap.
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
        std::io::Write::write_all(&mut gz, &vec![0u8; 40 << 20]).unwrap();
        let e = inflate(Path::new("b.npy.gz"), FileKind::NpyGz, gz.finish().unwrap(), Expected { size: (4, 4), full: (4, 4) }).unwrap_err().to_string();
        assert!(e.contains("unpacks to more than"), "{e}");
    }
}
