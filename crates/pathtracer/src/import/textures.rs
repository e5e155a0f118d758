//! Image decoding (PNG, JPEG) into [`Texture`]s, with sRGB → linear conversion for colour
//! textures and a cap on the texels a file may make us allocate.

use std::io::Cursor;

use glam::Vec4;
use image::{ImageFormat, ImageReader, Limits};

use crate::scene::Texture;

/// sRGB electro-optical transfer function (IEC 61966-2-1): encoded value in [0, 1] → linear.
pub(crate) fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
}

/// Decodes an encoded PNG or JPEG image. `srgb`: convert RGB from sRGB to linear (alpha is
/// always linear). `max_texels`: the most texels this image may have.
pub(crate) fn decode(bytes: &[u8], srgb: bool, max_texels: u64) -> Result<Texture, String> {
    let reader = || -> Result<ImageReader<Cursor<&[u8]>>, String> {
        let r = ImageReader::new(Cursor::new(bytes))
            .with_guessed_format()
            .map_err(|e| format!("cannot read image: {e}"))?;
        match r.format() {
            Some(ImageFormat::Png | ImageFormat::Jpeg) => Ok(r),
            Some(other) => Err(format!("unsupported image format {other:?} (PNG and JPEG are supported)")),
            None => Err("unrecognised image data (PNG and JPEG are supported)".to_string()),
        }
    };
    let (width, height) = reader()?.into_dimensions().map_err(|e| format!("cannot decode image header: {e}"))?;
    let texels = u64::from(width) * u64::from(height);
    if texels == 0 {
        return Err(format!("image has zero size ({width}×{height})"));
    }
    if texels > max_texels {
        return Err(format!(
            "image of {width}×{height} texels exceeds the remaining texture budget of {max_texels} texels"
        ));
    }
    let mut r = reader()?;
    let mut limits = Limits::default();
    // Decoded 16-bit RGBA plus the f32 conversion: generous but bounded.
    limits.max_alloc = Some(texels.saturating_mul(32).max(1 << 20));
    r.limits(limits);
    let img = r.decode().map_err(|e| format!("cannot decode image: {e}"))?;
    let rgba = img.to_rgba32f();
    let texels: Vec<Vec4> = rgba
        .pixels()
        .map(|p| {
            let [r, g, b, a] = p.0;
            if srgb {
                Vec4::new(srgb_to_linear(r), srgb_to_linear(g), srgb_to_linear(b), a)
            } else {
                Vec4::new(r, g, b, a)
            }
        })
        .collect();
    Ok(Texture { width, height, texels })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn png(w: u32, h: u32, px: &[[u8; 4]]) -> Vec<u8> {
        let mut img = image::RgbaImage::new(w, h);
        for (p, v) in img.pixels_mut().zip(px) {
            p.0 = *v;
        }
        let mut out = Cursor::new(Vec::new());
        img.write_to(&mut out, ImageFormat::Png).unwrap();
        out.into_inner()
    }

    #[test]
    fn srgb_curve_known_values() {
        assert_eq!(srgb_to_linear(0.0), 0.0);
        assert!((srgb_to_linear(1.0) - 1.0).abs() < 1e-6);
        // 188/255 is the sRGB encoding of linear ~0.5029.
        assert!((srgb_to_linear(188.0 / 255.0) - 0.502_886).abs() < 1e-5);
        assert!((srgb_to_linear(0.04) - 0.04 / 12.92).abs() < 1e-9);
    }

    #[test]
    fn decodes_png_rows_top_first_with_colour_space() {
        let bytes = png(2, 1, &[[188, 0, 255, 128], [255, 255, 255, 255]]);
        let t = decode(&bytes, true, 100).unwrap();
        assert_eq!((t.width, t.height), (2, 1));
        assert!((t.texels[0].x - 0.502_886).abs() < 1e-5);
        assert!((t.texels[0].w - 128.0 / 255.0).abs() < 1e-6, "alpha stays linear");
        let d = decode(&bytes, false, 100).unwrap();
        assert!((d.texels[0].x - 188.0 / 255.0).abs() < 1e-6);
    }

    #[test]
    fn rejects_garbage_oversize_and_truncation() {
        assert!(decode(b"not an image at all", true, 100).is_err());
        let bytes = png(4, 4, &[[1, 2, 3, 4]; 16]);
        assert!(decode(&bytes, true, 15).unwrap_err().contains("budget"));
        for n in [8, 20, bytes.len() / 2] {
            assert!(decode(&bytes[..n], true, 100).is_err(), "truncated to {n}");
        }
    }
}
