//! Procedural textures: checkerboards, stripes and a tangent-space normal map
//! of round bumps, as 8-bit RGB images, plus deterministic PNG encoding.
//!
//! Image coordinates follow glTF: `u = (x + 0.5) / width` to the right and
//! `v = (y + 0.5) / height` downwards (row 0 is the top row).

use std::f64::consts::PI;

use image::{ImageEncoder, RgbImage, codecs::png::PngEncoder};

use crate::SceneGenError;

/// A `size`×`size` checkerboard with `cells`×`cells` squares alternating
/// between colours `a` (the top-left square) and `b` (sRGB bytes).
pub fn checker(size: u32, cells: u32, a: [u8; 3], b: [u8; 3]) -> RgbImage {
    let cells = cells.max(1);
    RgbImage::from_fn(size, size, |x, y| {
        let cx = x * cells / size;
        let cy = y * cells / size;
        image::Rgb(if (cx + cy).is_multiple_of(2) { a } else { b })
    })
}

/// A `size`×`size` image of `count` horizontal bands (constant `v`)
/// alternating between colours `a` and `b`; on a UV sphere these are
/// latitude bands.
pub fn stripes(size: u32, count: u32, a: [u8; 3], b: [u8; 3]) -> RgbImage {
    let count = count.max(1);
    RgbImage::from_fn(size, size, |_, y| {
        image::Rgb(if (y * count / size).is_multiple_of(2) {
            a
        } else {
            b
        })
    })
}

/// Parameters of the round-bump height field behind [`bump_normal_map`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bumps {
    /// Bumps per side of the unit UV square (one bump centred in each cell).
    pub cells: u32,
    /// Bump radius as a fraction of the cell size (at most 0.5 for bumps that do not overlap).
    pub radius: f64,
    /// Bump height in UV units (the slope scale of the normal map).
    pub height: f64,
}

impl Bumps {
    /// Height `h(u, v) = height · cos²(π r / 2R)` for `r < R`, else 0, where
    /// `r` is the distance to the centre of the cell containing `(u, v)`, in
    /// cell units, and `R` is [`Bumps::radius`]. The field repeats with period
    /// `1 / cells` and is C¹.
    pub fn height_at(&self, u: f64, v: f64) -> f64 {
        let (dx, dy) = self.cell_offset(u, v);
        let r = (dx * dx + dy * dy).sqrt();
        if r >= self.radius {
            return 0.0;
        }
        let c = (PI * r / (2.0 * self.radius)).cos();
        self.height * c * c
    }

    /// Analytic gradient `(∂h/∂u, ∂h/∂v)` of [`Bumps::height_at`].
    pub fn gradient_at(&self, u: f64, v: f64) -> (f64, f64) {
        let (dx, dy) = self.cell_offset(u, v);
        let r = (dx * dx + dy * dy).sqrt();
        if r >= self.radius || r == 0.0 {
            return (0.0, 0.0);
        }
        // d/dr [cos²(k r)] = -k sin(2 k r), k = π / 2R; r is in cell units, so d/du = cells · d/dx.
        let k = PI / (2.0 * self.radius);
        let dh_dr = -self.height * k * (2.0 * k * r).sin();
        let s = dh_dr * self.cells as f64 / r;
        (s * dx, s * dy)
    }

    /// Tangent-space unit normal of the height field at `(u, v)`, in the glTF
    /// convention (+X towards increasing `u`, +Y up in the image, i.e.
    /// towards decreasing `v`, +Z out of the surface):
    /// `normalize(-∂h/∂u, ∂h/∂v, 1)`.
    pub fn normal_at(&self, u: f64, v: f64) -> [f64; 3] {
        let (gu, gv) = self.gradient_at(u, v);
        let len = (gu * gu + gv * gv + 1.0).sqrt();
        [-gu / len, gv / len, 1.0 / len]
    }

    fn cell_offset(&self, u: f64, v: f64) -> (f64, f64) {
        let n = self.cells.max(1) as f64;
        let x = u * n;
        let y = v * n;
        (x - x.floor() - 0.5, y - y.floor() - 0.5)
    }
}

/// A `size`×`size` tangent-space normal map of [`Bumps`], sampled at pixel
/// centres and encoded as `rgb = round((n · 0.5 + 0.5) · 255)` (linear, as
/// glTF's `normalTexture` expects).
pub fn bump_normal_map(size: u32, bumps: &Bumps) -> RgbImage {
    RgbImage::from_fn(size, size, |x, y| {
        let u = (x as f64 + 0.5) / size as f64;
        let v = (y as f64 + 0.5) / size as f64;
        let n = bumps.normal_at(u, v);
        let enc = |c: f64| ((c * 0.5 + 0.5) * 255.0).round().clamp(0.0, 255.0) as u8;
        image::Rgb([enc(n[0]), enc(n[1]), enc(n[2])])
    })
}

/// Encode an RGB image as PNG bytes. The encoding is deterministic (same
/// pixels, same bytes). `what` names the image in errors.
pub fn encode_png(img: &RgbImage, what: &str) -> Result<Vec<u8>, SceneGenError> {
    let mut bytes = Vec::new();
    PngEncoder::new(&mut bytes)
        .write_image(
            img.as_raw(),
            img.width(),
            img.height(),
            image::ExtendedColorType::Rgb8,
        )
        .map_err(|source| SceneGenError::Image {
            what: what.to_string(),
            source,
        })?;
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checker_alternates() {
        let img = checker(64, 4, [255, 0, 0], [0, 0, 255]);
        assert_eq!(img.get_pixel(0, 0).0, [255, 0, 0]);
        assert_eq!(img.get_pixel(16, 0).0, [0, 0, 255]);
        assert_eq!(img.get_pixel(16, 16).0, [255, 0, 0]);
        assert_eq!(img.get_pixel(63, 0).0, [0, 0, 255]);
        let reds = img.pixels().filter(|p| p.0 == [255, 0, 0]).count();
        assert_eq!(reds, 64 * 64 / 2);
    }

    #[test]
    fn bump_gradient_matches_finite_differences() {
        let b = Bumps {
            cells: 4,
            radius: 0.4,
            height: 0.02,
        };
        let h = 1e-6;
        for i in 0..50 {
            for j in 0..50 {
                let u = (i as f64 + 0.37) / 50.0;
                let v = (j as f64 + 0.61) / 50.0;
                let fd_u = (b.height_at(u + h, v) - b.height_at(u - h, v)) / (2.0 * h);
                let fd_v = (b.height_at(u, v + h) - b.height_at(u, v - h)) / (2.0 * h);
                let (gu, gv) = b.gradient_at(u, v);
                assert!(
                    (gu - fd_u).abs() < 1e-5 && (gv - fd_v).abs() < 1e-5,
                    "at ({u},{v})"
                );
            }
        }
    }

    #[test]
    fn normal_map_encodes_the_height_field_normal() {
        let b = Bumps {
            cells: 4,
            radius: 0.4,
            height: 0.02,
        };
        let size = 64;
        let img = bump_normal_map(size, &b);
        let h = 1e-6;
        let mut tilted = 0;
        for (x, y, p) in img.enumerate_pixels() {
            let u = (x as f64 + 0.5) / size as f64;
            let v = (y as f64 + 0.5) / size as f64;
            // Reference normal from finite differences of the height field.
            let gu = (b.height_at(u + h, v) - b.height_at(u - h, v)) / (2.0 * h);
            let gv = (b.height_at(u, v + h) - b.height_at(u, v - h)) / (2.0 * h);
            let len = (gu * gu + gv * gv + 1.0).sqrt();
            let reference = [-gu / len, gv / len, 1.0 / len];
            for (byte, want) in p.0.iter().zip(reference) {
                let decoded = *byte as f64 / 255.0 * 2.0 - 1.0;
                assert!(
                    (decoded - want).abs() <= 1.0 / 255.0 + 1e-6,
                    "pixel ({x},{y})"
                );
            }
            if reference[2] < 0.99 {
                tilted += 1;
            }
        }
        assert!(
            tilted > (size * size / 4) as usize,
            "normal map is nearly flat"
        );
    }

    #[test]
    fn png_round_trips_and_is_deterministic() {
        let img = checker(32, 2, [10, 20, 30], [200, 100, 50]);
        let a = encode_png(&img, "t").unwrap();
        let b = encode_png(&img, "t").unwrap();
        assert_eq!(a, b);
        let back = image::load_from_memory(&a).unwrap().to_rgb8();
        assert_eq!(back, img);
    }
}
