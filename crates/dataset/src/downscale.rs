//! Integer downscaling of a view, shared by the trainer (its targets) and the evaluation (its
//! ground truth), so both compare against the same pixels.
//!
//! - Colour: a box filter over whole `k × k` blocks of full-resolution pixels, with the colour
//!   **premultiplied by alpha** while averaging, so that the downscaled pixel composited onto
//!   any background equals the mean of the full-resolution pixels composited onto it:
//!   `ā = mean(a)`, `rgb = mean(a·rgb) / ā` (straight alpha out; 0 where `ā = 0`).
//! - Ground truth (depth, distance, normal, alpha) is exact at the downscaled pixel-centre ray and
//!   never averaged: block `(x, y)`'s centre ray is full-resolution pixel `(k·x + (k−1)/2,
//!   k·y + (k−1)/2)`'s centre ray when `k` is odd, so [`GroundTruth::at_downscale`] picks that
//!   pixel; for even `k` no full-resolution centre ray coincides and the caller casts the rays
//!   (or falls back to [`GroundTruth::nearest_at_downscale`], half a full-resolution pixel off).
//!
//! ```
//! use dataset::RgbaImage;
//! // A 2x2 block: two opaque red pixels, two transparent blue ones: half coverage, still red.
//! let (red, clear) = ([1.0, 0.0, 0.0, 1.0], [0.0, 0.0, 1.0, 0.0]);
//! let img = RgbaImage { width: 2, height: 2, data: [red, clear, clear, red].concat() };
//! let d = img.downscaled(2);
//! assert_eq!(d.pixel(0, 0), [1.0, 0.0, 0.0, 0.5]);
//! ```

use crate::camera::Intrinsics;
use crate::images::{GroundTruth, RgbaImage};

/// Checks an integer downscale factor against an image size: it must be at least 1, no larger
/// than either side, and divide both (so every downscaled pixel is a whole block and the
/// downscaled camera keeps the full image's field of view). `option` names the setting in the
/// message (e.g. `--downscale`).
pub fn check_downscale(option: &str, factor: u32, intr: &Intrinsics) -> Result<(), String> {
    let (w, h) = (intr.width, intr.height);
    if factor == 0 {
        return Err(format!("{option} 0: the downscale must be a positive integer factor"));
    }
    if factor > w || factor > h {
        return Err(format!("{option} {factor} is larger than the {w}x{h} image"));
    }
    if !w.is_multiple_of(factor) || !h.is_multiple_of(factor) {
        return Err(format!(
            "{option} {factor} does not divide the {w}x{h} image (factors that do: {})",
            divisors(w, h).iter().map(u32::to_string).collect::<Vec<_>>().join(", ")
        ));
    }
    Ok(())
}

/// Common divisors of `w` and `h`, ascending (at most the first 12).
fn divisors(w: u32, h: u32) -> Vec<u32> {
    (1..=w.min(h)).filter(|d| w.is_multiple_of(*d) && h.is_multiple_of(*d)).take(12).collect()
}

impl RgbaImage {
    /// The image downscaled by `factor` with an alpha-premultiplied box filter over whole
    /// blocks (see the module docs); a remainder of rows or columns that does not fill a block
    /// is dropped. Factor 0 or 1 returns a copy.
    pub fn downscaled(&self, factor: u32) -> RgbaImage {
        let k = factor.max(1) as usize;
        if k == 1 {
            return self.clone();
        }
        let (w, h) = (self.width as usize / k, self.height as usize / k);
        let mut out = RgbaImage::new(w as u32, h as u32);
        let inv = 1.0 / (k * k) as f64;
        for y in 0..h {
            for x in 0..w {
                let mut acc = [0.0f64; 4];
                for dy in 0..k {
                    for dx in 0..k {
                        let p = self.pixel((x * k + dx) as u32, (y * k + dy) as u32);
                        let a = p[3] as f64;
                        acc[0] += a * p[0] as f64;
                        acc[1] += a * p[1] as f64;
                        acc[2] += a * p[2] as f64;
                        acc[3] += a;
                    }
                }
                let a = acc[3] * inv;
                let rgb = if a > 0.0 { [0, 1, 2].map(|c| (acc[c] * inv / a) as f32) } else { [0.0; 3] };
                let o = 4 * (y * w + x);
                out.data[o..o + 3].copy_from_slice(&rgb);
                out.data[o + 3] = a as f32;
            }
        }
        out
    }
}

impl GroundTruth {
    /// The ground truth at the pixel centres of the image downscaled by an **odd** `factor`
    /// (exact: each downscaled centre ray is a full-resolution centre ray); `None` for an even
    /// factor, whose downscaled centres fall between full-resolution ones.
    pub fn at_downscale(&self, factor: u32) -> Option<GroundTruth> {
        let k = factor.max(1);
        (k % 2 == 1).then(|| self.pick(k, (k - 1) / 2))
    }

    /// The ground truth of the full-resolution pixel nearest each downscaled pixel centre
    /// (exact for odd `factor`; for even factors the value of a ray half a full-resolution pixel
    /// right of and below the downscaled centre ray: an approximation, never an average).
    pub fn nearest_at_downscale(&self, factor: u32) -> GroundTruth {
        let k = factor.max(1);
        self.pick(k, k / 2)
    }

    fn pick(&self, k: u32, offset: u32) -> GroundTruth {
        let (w, h) = ((self.width / k) as usize, (self.height / k) as usize);
        let mut out = GroundTruth {
            width: w as u32,
            height: h as u32,
            depth: vec![0.0; w * h],
            distance: vec![0.0; w * h],
            normal: vec![0.0; 3 * w * h],
            alpha: vec![0.0; w * h],
        };
        let sw = self.width as usize;
        for y in 0..h {
            for x in 0..w {
                let sx = (x * k as usize + offset as usize).min(sw - 1);
                let sy = (y * k as usize + offset as usize).min(self.height as usize - 1);
                let (s, d) = (sy * sw + sx, y * w + x);
                out.depth[d] = self.depth[s];
                out.distance[d] = self.distance[s];
                out.alpha[d] = self.alpha[s];
                out.normal[3 * d..3 * d + 3].copy_from_slice(&self.normal[3 * s..3 * s + 3]);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Camera, Intrinsics};
    use glam::DVec3;

    fn img(w: u32, h: u32, f: impl Fn(u32, u32) -> [f32; 4]) -> RgbaImage {
        let mut out = RgbaImage::new(w, h);
        for j in 0..h {
            for i in 0..w {
                let k = 4 * (j * w + i) as usize;
                out.data[k..k + 4].copy_from_slice(&f(i, j));
            }
        }
        out
    }

    /// Composited onto any background, the downscaled pixel equals the mean of the composited
    /// full-resolution pixels (the premultiplied box filter's defining property), which the
    /// straight-alpha average misses at silhouettes.
    #[test]
    fn downscaled_colour_composites_like_the_mean() {
        let full = img(6, 4, |i, j| {
            let a = [0.0, 1.0, 0.25, 0.6][((i + 2 * j) % 4) as usize];
            [0.1 * i as f32, 0.9 - 0.1 * j as f32, 0.5, a]
        });
        for k in [1u32, 2] {
            let d = full.downscaled(k);
            assert_eq!((d.width, d.height), (6 / k, 4 / k));
            for bg in [[0.0f32; 3], [1.0; 3], [0.3, 0.7, 0.2]] {
                for y in 0..d.height {
                    for x in 0..d.width {
                        let p = d.pixel(x, y);
                        let mut mean = [0.0f64; 3];
                        for dy in 0..k {
                            for dx in 0..k {
                                let q = full.pixel(x * k + dx, y * k + dy);
                                for c in 0..3 {
                                    mean[c] += (q[3] * q[c] + (1.0 - q[3]) * bg[c]) as f64 / (k * k) as f64;
                                }
                            }
                        }
                        for c in 0..3 {
                            let got = p[3] * p[c] + (1.0 - p[3]) * bg[c];
                            assert!((got as f64 - mean[c]).abs() < 1e-6, "k {k} ({x},{y}) c {c}: {got} vs {}", mean[c]);
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn a_transparent_block_stays_transparent_black() {
        let d = img(2, 2, |_, _| [0.4, 0.5, 0.6, 0.0]).downscaled(2);
        assert_eq!(d.pixel(0, 0), [0.0; 4]);
    }

    /// For odd factors the picked full-resolution pixel's centre ray is the downscaled camera's
    /// centre ray (same origin and direction), so depth read there is exact.
    #[test]
    fn odd_factor_ground_truth_is_at_the_downscaled_centre_ray() {
        let intr = Intrinsics { width: 15, height: 9, fl_x: 13.0, fl_y: 11.0, cx: 7.1, cy: 4.4 };
        let cam = Camera::new(intr, Camera::look_at(DVec3::new(1.0, 2.0, 3.0), DVec3::ZERO, DVec3::Y)).unwrap();
        for k in [1u32, 3] {
            let small = cam.downscaled(k);
            let off = (k - 1) / 2;
            for y in 0..small.intrinsics.height {
                for x in 0..small.intrinsics.width {
                    let a = small.pixel_center_ray(x, y);
                    let b = cam.pixel_center_ray(x * k + off, y * k + off);
                    assert!((a.direction - b.direction).length() < 1e-12, "k {k} ({x},{y})");
                }
            }
        }
        let n = 15 * 9;
        let gt = GroundTruth {
            width: 15,
            height: 9,
            depth: (0..n).map(|v| v as f32).collect(),
            distance: (0..n).map(|v| 2.0 * v as f32).collect(),
            normal: (0..3 * n).map(|v| v as f32).collect(),
            alpha: (0..n).map(|v| (v % 2) as f32).collect(),
        };
        let d = gt.at_downscale(3).unwrap();
        assert_eq!((d.width, d.height), (5, 3));
        // Block (1, 2) → full pixel (4, 7) = index 7 · 15 + 4 = 109.
        assert_eq!(d.depth[2 * 5 + 1], 109.0);
        assert_eq!(d.distance[2 * 5 + 1], 218.0);
        assert_eq!(d.normal[3 * (2 * 5 + 1)..3 * (2 * 5 + 1) + 3], [327.0, 328.0, 329.0]);
        assert_eq!(d.alpha[2 * 5 + 1], 1.0);
        assert!(gt.at_downscale(2).is_none());
        assert_eq!(gt.at_downscale(1).unwrap(), gt);
        assert_eq!(gt.nearest_at_downscale(2).depth[0], 16.0);
    }

    #[test]
    fn downscale_factors_are_checked() {
        let intr = Intrinsics { width: 800, height: 600, fl_x: 1.0, fl_y: 1.0, cx: 400.0, cy: 300.0 };
        assert!(check_downscale("--downscale", 1, &intr).is_ok());
        assert!(check_downscale("--downscale", 8, &intr).is_ok());
        let e = check_downscale("--downscale", 0, &intr).unwrap_err();
        assert!(e.contains("--downscale 0"), "{e}");
        let e = check_downscale("--downscale", 3, &intr).unwrap_err();
        assert!(e.contains("does not divide the 800x600 image") && e.contains("1, 2, 4, 5"), "{e}");
        let e = check_downscale("--downscale", 601, &intr).unwrap_err();
        assert!(e.contains("larger than the 800x600 image"), "{e}");
    }
}
