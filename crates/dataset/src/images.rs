//! Image files of a view: display colour (8-bit sRGB RGBA PNG, straight alpha), linear colour
//! (float32 RGBA EXR, premultiplied alpha), the ground-truth EXR (z-depth, distance, world
//! normal, alpha at the pixel-centre ray) and nerfstudio's depth `.npy` (float32 z-depth).

use crate::DatasetError;
use crate::io::{atomic_write, read};
use exr::prelude::{
    AnyChannel, AnyChannels, Blocks, Compression, Encoding, FlatSamples, Image, Layer,
    LayerAttributes, LineOrder, ReadChannels, ReadLayers, WritableImage,
};
use std::io::Cursor;
use std::path::Path;

/// An RGBA image, row-major from the top row, 4 interleaved `f32` per pixel.
///
/// # Shapes
/// `data.len() == width * height * 4`.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbaImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Interleaved RGBA samples.
    pub data: Vec<f32>,
}

impl RgbaImage {
    /// A black, fully transparent image.
    pub fn new(width: u32, height: u32) -> Self {
        Self { width, height, data: vec![0.0; width as usize * height as usize * 4] }
    }
    /// The RGBA value of pixel (column `i`, row `j`).
    pub fn pixel(&self, i: u32, j: u32) -> [f32; 4] {
        let k = (j as usize * self.width as usize + i as usize) * 4;
        [self.data[k], self.data[k + 1], self.data[k + 2], self.data[k + 3]]
    }
}

/// Ground truth at each pixel-centre ray. Misses have depth 0, distance 0, normal 0, alpha 0.
///
/// # Shapes
/// Every vector has `width * height` entries (normal: 3 per pixel, interleaved).
#[derive(Clone, Debug, PartialEq)]
pub struct GroundTruth {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// z-depth along the camera's −Z axis, scene units.
    pub depth: Vec<f32>,
    /// Euclidean distance from the camera centre along the ray, scene units.
    pub distance: Vec<f32>,
    /// World-space unit shading normal facing the camera, xyz interleaved.
    pub normal: Vec<f32>,
    /// 1 where the pixel-centre ray hits geometry, else 0.
    pub alpha: Vec<f32>,
}

/// sRGB transfer function (IEC 61966-2-1), linear → encoded, clamped to [0, 1].
pub fn linear_to_srgb(x: f32) -> f32 {
    let x = if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) };
    if x <= 0.003_130_8 { 12.92 * x } else { 1.055 * x.powf(1.0 / 2.4) - 0.055 }
}

/// sRGB transfer function, encoded → linear.
pub fn srgb_to_linear(x: f32) -> f32 {
    if x <= 0.040_45 { x / 12.92 } else { ((x + 0.055) / 1.055).powf(2.4) }
}

/// Writes an 8-bit RGBA PNG. `image` holds display values in [0, 1] (already sRGB-encoded,
/// straight alpha); they are rounded to the nearest 8-bit level.
pub fn write_png_rgba(path: &Path, image: &RgbaImage) -> Result<(), DatasetError> {
    check_len(path, image.data.len(), image.width, image.height, 4)?;
    let bytes: Vec<u8> =
        image.data.iter().map(|v| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8).collect();
    let mut out = Vec::new();
    {
        use image::ImageEncoder;
        let enc = image::codecs::png::PngEncoder::new(&mut out);
        enc.write_image(&bytes, image.width, image.height, image::ExtendedColorType::Rgba8)
            .map_err(|e| DatasetError::image(path, e))?;
    }
    atomic_write(path, &out)
}

/// Writes a single-channel 8-bit PNG: 255 where `keep`, 0 elsewhere (nerfstudio's mask
/// convention: 0 = ignore the pixel). `keep` is row-major, `width × height`.
pub fn write_png_mask(path: &Path, width: u32, height: u32, keep: &[bool]) -> Result<(), DatasetError> {
    check_len(path, keep.len(), width, height, 1)?;
    let bytes: Vec<u8> = keep.iter().map(|k| if *k { 255 } else { 0 }).collect();
    let mut out = Vec::new();
    {
        use image::ImageEncoder;
        let enc = image::codecs::png::PngEncoder::new(&mut out);
        enc.write_image(&bytes, width, height, image::ExtendedColorType::L8).map_err(|e| DatasetError::image(path, e))?;
    }
    atomic_write(path, &out)
}

/// Reads a PNG (any bit depth, grey or colour, with or without alpha) as RGBA in [0, 1]
/// (values as stored: sRGB-encoded, straight alpha; alpha 1 when the file has none).
pub fn read_png_rgba(path: &Path) -> Result<RgbaImage, DatasetError> {
    let bytes = read(path)?;
    let img = image::load_from_memory_with_format(&bytes, image::ImageFormat::Png)
        .map_err(|e| DatasetError::image(path, e))?;
    let rgba = img.to_rgba32f();
    Ok(RgbaImage { width: rgba.width(), height: rgba.height(), data: rgba.into_raw() })
}

fn encoding() -> Encoding {
    Encoding {
        compression: Compression::ZIP16,
        blocks: Blocks::ScanLines,
        line_order: LineOrder::Increasing,
    }
}

fn write_channels(
    path: &Path,
    width: u32,
    height: u32,
    channels: Vec<(&str, Vec<f32>)>,
) -> Result<(), DatasetError> {
    let list = channels
        .into_iter()
        .map(|(name, data)| AnyChannel::new(name, FlatSamples::F32(data)))
        .collect();
    let layer = Layer::new(
        (width as usize, height as usize),
        LayerAttributes::default(),
        encoding(),
        AnyChannels::sort(list),
    );
    let mut buffer = Cursor::new(Vec::new());
    Image::from_layer(layer)
        .write()
        .non_parallel()
        .to_buffered(&mut buffer)
        .map_err(|e| DatasetError::image(path, e))?;
    atomic_write(path, &buffer.into_inner())
}

fn read_channels(
    path: &Path,
    names: &[&str],
) -> Result<(u32, u32, Vec<Vec<f32>>), DatasetError> {
    let bytes = read(path)?;
    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(Cursor::new(bytes))
        .map_err(|e| DatasetError::image(path, e))?;
    let layer = image.layer_data;
    let size = layer.size;
    let mut out = Vec::new();
    for name in names {
        let ch = layer
            .channel_data
            .list
            .iter()
            .find(|c| c.name.eq(name))
            .ok_or_else(|| DatasetError::invalid(path, format!("EXR has no channel '{name}'")))?;
        out.push(ch.sample_data.values_as_f32().collect());
    }
    Ok((size.0 as u32, size.1 as u32, out))
}

fn check_len(path: &Path, len: usize, w: u32, h: u32, c: usize) -> Result<(), DatasetError> {
    if len != w as usize * h as usize * c {
        return Err(DatasetError::invalid(
            path,
            format!("buffer of {len} values does not match {w}x{h}x{c}"),
        ));
    }
    Ok(())
}

/// Writes linear RGBA as a float32 EXR with channels R, G, B, A (RGB premultiplied by A).
pub fn write_exr_rgba(path: &Path, image: &RgbaImage) -> Result<(), DatasetError> {
    check_len(path, image.data.len(), image.width, image.height, 4)?;
    let ch = |c: usize| image.data.iter().skip(c).step_by(4).copied().collect::<Vec<_>>();
    write_channels(path, image.width, image.height, vec![
        ("R", ch(0)),
        ("G", ch(1)),
        ("B", ch(2)),
        ("A", ch(3)),
    ])
}

/// Reads an RGBA (or RGB, then A = 1) EXR into linear values.
pub fn read_exr_rgba(path: &Path) -> Result<RgbaImage, DatasetError> {
    let (w, h, rgb) = read_channels(path, &["R", "G", "B"])?;
    let alpha = read_channels(path, &["A"]).ok().map(|(_, _, mut a)| a.remove(0));
    let n = w as usize * h as usize;
    let mut data = Vec::with_capacity(n * 4);
    for k in 0..n {
        data.extend_from_slice(&[rgb[0][k], rgb[1][k], rgb[2][k]]);
        data.push(alpha.as_ref().map_or(1.0, |a| a[k]));
    }
    Ok(RgbaImage { width: w, height: h, data })
}

/// Channel names of the ground-truth EXR.
const GT_CHANNELS: [&str; 6] = ["depth", "distance", "normal.X", "normal.Y", "normal.Z", "alpha"];

/// Writes the ground-truth EXR: float32 channels `depth` (z-depth), `distance`, `normal.X`,
/// `normal.Y`, `normal.Z` (world space) and `alpha`.
pub fn write_ground_truth(path: &Path, gt: &GroundTruth) -> Result<(), DatasetError> {
    let n = gt.width as usize * gt.height as usize;
    for (len, c) in [(gt.depth.len(), 1), (gt.distance.len(), 1), (gt.alpha.len(), 1), (gt.normal.len(), 3)] {
        check_len(path, len, gt.width, gt.height, c)?;
    }
    let normal = |c: usize| (0..n).map(|k| gt.normal[3 * k + c]).collect::<Vec<_>>();
    write_channels(path, gt.width, gt.height, vec![
        (GT_CHANNELS[0], gt.depth.clone()),
        (GT_CHANNELS[1], gt.distance.clone()),
        (GT_CHANNELS[2], normal(0)),
        (GT_CHANNELS[3], normal(1)),
        (GT_CHANNELS[4], normal(2)),
        (GT_CHANNELS[5], gt.alpha.clone()),
    ])
}

/// Reads a ground-truth EXR written by [`write_ground_truth`].
pub fn read_ground_truth(path: &Path) -> Result<GroundTruth, DatasetError> {
    let (width, height, mut ch) = read_channels(path, &GT_CHANNELS)?;
    let alpha = ch.pop().unwrap_or_default();
    let (nz, ny, nx) = (ch.pop().unwrap_or_default(), ch.pop().unwrap_or_default(), ch.pop().unwrap_or_default());
    let distance = ch.pop().unwrap_or_default();
    let depth = ch.pop().unwrap_or_default();
    let normal = (0..nx.len()).flat_map(|k| [nx[k], ny[k], nz[k]]).collect();
    Ok(GroundTruth { width, height, depth, distance, normal, alpha })
}

/// Writes a little-endian float32 `.npy` array of shape (`height`, `width`) (nerfstudio reads
/// depth from `.npy` files in scene units times `depth_unit_scale_factor`).
pub fn write_npy_f32(path: &Path, width: u32, height: u32, values: &[f32]) -> Result<(), DatasetError> {
    check_len(path, values.len(), width, height, 1)?;
    let mut out = npy_f32_prefix(width, height);
    out.reserve(values.len() * 4);
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
    atomic_write(path, &out)
}

/// The bytes before the values of the `.npy` file [`write_npy_f32`] writes for a (`height`,
/// `width`) array: magic, version, header length and the header, padded to 64 bytes.
fn npy_f32_prefix(width: u32, height: u32) -> Vec<u8> {
    npy_f32_header(&[height as usize, width as usize])
}

/// The bytes before the values of a little-endian float32 C-order `.npy` file of `shape`:
/// magic, version 1.0, header length and the header dictionary, padded to 64 bytes.
pub(crate) fn npy_f32_header(shape: &[usize]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(usize::to_string).collect();
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({}), }}", dims.join(", "));
    // Magic (6) + version (2) + header length (2) + header + '\n' is padded to 64 bytes.
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len());
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    out
}

/// Checks that `path` is the whole `.npy` file [`write_npy_f32`] writes for a (`height`,
/// `width`) array: the same header and exactly `width · height` float32 values after it.
pub fn check_npy_f32(path: &Path, width: u32, height: u32) -> Result<(), DatasetError> {
    let bytes = read(path)?;
    let prefix = npy_f32_prefix(width, height);
    let want = prefix.len() + width as usize * height as usize * 4;
    if !bytes.starts_with(&prefix) || bytes.len() != want {
        return Err(DatasetError::invalid(
            path,
            format!("not a whole {height}x{width} float32 .npy array ({} bytes, {want} expected)", bytes.len()),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(name: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("dataset-images-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d.join(name)
    }

    #[test]
    fn srgb_round_trip() {
        for k in 0..=100 {
            let x = k as f32 / 100.0;
            assert!((srgb_to_linear(linear_to_srgb(x)) - x).abs() < 1e-5);
        }
        assert_eq!(linear_to_srgb(f32::NAN), 0.0);
    }

    #[test]
    fn exr_round_trip_is_exact() {
        let mut img = RgbaImage::new(5, 3);
        for (k, v) in img.data.iter_mut().enumerate() {
            *v = k as f32 * 0.37 - 1.5;
        }
        let p = tmp("a.exr");
        write_exr_rgba(&p, &img).unwrap();
        assert_eq!(read_exr_rgba(&p).unwrap(), img);
        let gt = GroundTruth {
            width: 2,
            height: 2,
            depth: vec![1.0, 2.0, 0.0, 4.5],
            distance: vec![1.1, 2.2, 0.0, 4.6],
            normal: (0..12).map(|k| k as f32 / 12.0).collect(),
            alpha: vec![1.0, 1.0, 0.0, 1.0],
        };
        let p = tmp("gt.exr");
        write_ground_truth(&p, &gt).unwrap();
        assert_eq!(read_ground_truth(&p).unwrap(), gt);
    }

    #[test]
    fn png_round_trip_quantises_to_8_bits() {
        let mut img = RgbaImage::new(4, 2);
        for (k, v) in img.data.iter_mut().enumerate() {
            *v = k as f32 / 31.0;
        }
        let p = tmp("a.png");
        write_png_rgba(&p, &img).unwrap();
        let back = read_png_rgba(&p).unwrap();
        assert_eq!((back.width, back.height), (4, 2));
        for (a, b) in back.data.iter().zip(&img.data) {
            assert!((a - b).abs() <= 0.5 / 255.0 + 1e-6);
        }
    }

    #[test]
    fn npy_header_is_aligned() {
        let p = tmp("d.npy");
        write_npy_f32(&p, 3, 2, &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        assert_eq!((10 + hlen) % 64, 0);
        assert_eq!(bytes.len(), 10 + hlen + 24);
        assert_eq!(f32::from_le_bytes(bytes[bytes.len() - 4..].try_into().unwrap()), 6.0);
    }

    #[test]
    fn corrupt_files_name_the_file() {
        let p = tmp("bad.exr");
        std::fs::write(&p, b"not an exr").unwrap();
        let e = read_exr_rgba(&p).unwrap_err().to_string();
        assert!(e.contains("bad.exr"), "{e}");
        let p = tmp("bad.png");
        std::fs::write(&p, b"not a png").unwrap();
        assert!(read_png_rgba(&p).unwrap_err().to_string().contains("bad.png"));
    }
}
