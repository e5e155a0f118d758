//! What a render or a ground truth looks like on the page: 8-bit RGB pixels (colour as is,
//! depth through viridis, opacity in grey, error through inferno) and their PNG encoding.

use eval::colormap::Colormap;
use image::ImageEncoder;

/// The mean absolute colour error (display values in [0, 1]) drawn at the top of the heat map's
/// scale: errors at or above it are the brightest colour.
pub const ERROR_SCALE: f32 = 0.25;

/// A display value in [0, 1] as a byte.
pub fn byte(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// Display colour `[N * 3]` in [0, 1] as bytes.
pub fn colour(rgb: &[f32]) -> Vec<u8> {
    rgb.iter().map(|&v| byte(v)).collect()
}

/// Z-depth `[N]` through viridis over `[lo, hi]` (near = dark), faded to black by `opacity`
/// (a pixel that sees nothing is black); without opacity (ground truth), depth 0 is black.
pub fn depth(depth: &[f32], opacity: Option<&[f32]>, lo: f64, hi: f64) -> Vec<u8> {
    depth
        .iter()
        .enumerate()
        .flat_map(|(p, &d)| {
            let a = match opacity {
                Some(o) => o[p].clamp(0.0, 1.0),
                None => f32::from(d > 0.0),
            };
            Colormap::Viridis.map(d as f64, lo, hi).map(|c| (c as f32 * a).round() as u8)
        })
        .collect()
}

/// Opacity `[N]` in grey.
pub fn opacity(opacity: &[f32]) -> Vec<u8> {
    opacity.iter().flat_map(|&a| [byte(a); 3]).collect()
}

/// The per-pixel mean absolute difference of two colour images `[N * 3]` through inferno over
/// `[0, ERROR_SCALE]`.
pub fn error_heat(a: &[f32], b: &[f32]) -> Vec<u8> {
    a.chunks_exact(3)
        .zip(b.chunks_exact(3))
        .flat_map(|(x, y)| {
            let e = (0..3).map(|c| (x[c] - y[c]).abs()).sum::<f32>() / 3.0;
            Colormap::Inferno.map(e as f64, 0.0, ERROR_SCALE as f64)
        })
        .collect()
}

/// `width`×`height` RGB bytes as a PNG (fast compression: the page asks for many frames).
pub fn png(width: u32, height: u32, rgb: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(rgb.len() / 2);
    let enc = image::codecs::png::PngEncoder::new_with_quality(&mut out, image::codecs::png::CompressionType::Fast, image::codecs::png::FilterType::Sub);
    enc.write_image(rgb, width, height, image::ExtendedColorType::Rgb8).expect("an in-memory PNG of a checked size encodes");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_round_trips_and_maps_are_sized() {
        let rgb: Vec<u8> = (0..2 * 3 * 3).map(|v| v as u8 * 10).collect();
        let img = image::load_from_memory(&png(3, 2, &rgb)).unwrap().to_rgb8();
        assert_eq!((img.width(), img.height()), (3, 2));
        assert_eq!(img.into_raw(), rgb);
        assert_eq!(depth(&[0.0, 1.0], None, 0.0, 2.0)[..3], [0, 0, 0]);
        assert_ne!(depth(&[0.0, 1.0], None, 0.0, 2.0)[3..], [0, 0, 0]);
        assert_eq!(error_heat(&[0.0; 3], &[0.0; 3]), Colormap::Inferno.at(0.0));
        assert_eq!(error_heat(&[1.0; 3], &[0.0; 3]), Colormap::Inferno.at(1.0));
    }
}
