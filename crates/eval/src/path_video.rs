//! The frames of a camera-path video, in the layout the user picks:
//! - [`Layout::Nerf`]: the NeRF's colour alone;
//! - [`Layout::SideBySide`]: NeRF | ground truth | colour error | depth error, each panel under
//!   a label strip naming it.
//!
//! The colour error is `mean_c |NeRF − GT|` in display units through inferno on a fixed
//! [0, [`COLOUR_ERROR_MAX`]] (larger saturates); the depth error is the signed
//! `NeRF − GT` z-depth through blue-white-red on ±`depth_range` metres, grey where the
//! pixel-centre ray misses the scene. The ranges are fixed for the whole video, so a colour
//! means the same error in every frame.

use crate::EvalError;
use crate::colormap::Colormap;
use crate::metrics::FOREGROUND_ALPHA;
use crate::plot::{FONT, ensure_font};
use plotters::prelude::*;
use std::path::Path;

/// Height of the label strip above each side-by-side panel, pixels.
pub const LABEL_H: u32 = 16;

/// The colour error at which the heat map saturates (display units).
pub const COLOUR_ERROR_MAX: f64 = 0.25;

/// Which panels a frame holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// The NeRF's colour alone.
    Nerf,
    /// NeRF | ground truth | colour error | depth error, labelled.
    SideBySide,
}

impl std::str::FromStr for Layout {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "nerf" => Ok(Layout::Nerf),
            "side-by-side" => Ok(Layout::SideBySide),
            _ => Err(format!("unknown layout '{s}' (nerf or side-by-side)")),
        }
    }
}

/// What one frame shows; every image is `width × height`, row 0 at the top.
#[derive(Clone, Copy, Debug)]
pub struct FrameImages<'a> {
    /// Width of one panel, pixels.
    pub width: u32,
    /// Height of one panel.
    pub height: u32,
    /// The NeRF's display colour in [0, 1], `[H * W * 3]`.
    pub nerf_rgb: &'a [f32],
    /// The NeRF's z-depth, `[H * W]`.
    pub nerf_depth: &'a [f32],
    /// The ground truth's display colour composited on the same background, `[H * W * 3]`.
    pub gt_rgb: &'a [f32],
    /// Exact z-depth, `[H * W]`.
    pub gt_depth: &'a [f32],
    /// Exact alpha (1 where the pixel-centre ray hits), `[H * W]`.
    pub gt_alpha: &'a [f32],
}

/// The frame size of `layout` for panels of `width × height`.
pub fn frame_size(layout: Layout, width: u32, height: u32) -> (u32, u32) {
    match layout {
        Layout::Nerf => (width, height),
        Layout::SideBySide => (4 * width, height + LABEL_H),
    }
}

fn to_u8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// The frame as 8-bit RGB, `[frame_h * frame_w * 3]` ([`frame_size`]).
pub fn compose(layout: Layout, f: &FrameImages<'_>, depth_range: f64, path_for_errors: &Path) -> Result<Vec<u8>, EvalError> {
    let (w, h) = (f.width as usize, f.height as usize);
    let n = w * h;
    if f.nerf_rgb.len() != 3 * n || f.nerf_depth.len() != n {
        return Err(EvalError::Input(format!("{}: NeRF frame does not match {w}x{h}", path_for_errors.display())));
    }
    if layout == Layout::Nerf {
        return Ok(f.nerf_rgb.iter().map(|v| to_u8(*v)).collect());
    }
    if f.gt_rgb.len() != 3 * n || f.gt_depth.len() != n || f.gt_alpha.len() != n {
        return Err(EvalError::Input(format!("{}: ground-truth frame does not match {w}x{h}", path_for_errors.display())));
    }
    let (fw, fh) = frame_size(layout, f.width, f.height);
    let (fw, fh) = (fw as usize, fh as usize);
    let mut out = vec![255u8; fw * fh * 3];
    let range = depth_range.max(1e-12);
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            let nerf = [0, 1, 2].map(|c| f.nerf_rgb[3 * p + c]);
            let gt = [0, 1, 2].map(|c| f.gt_rgb[3 * p + c]);
            let err = (0..3).map(|c| (nerf[c] - gt[c]).abs() as f64).sum::<f64>() / 3.0;
            let depth = if f.gt_alpha[p] >= FOREGROUND_ALPHA {
                Colormap::BlueWhiteRed.map((f.nerf_depth[p] - f.gt_depth[p]) as f64, -range, range)
            } else {
                [128, 128, 128]
            };
            let panels = [nerf.map(to_u8), gt.map(to_u8), Colormap::Inferno.map(err, 0.0, COLOUR_ERROR_MAX), depth];
            for (i, rgb) in panels.iter().enumerate() {
                let q = 3 * ((y + LABEL_H as usize) * fw + i * w + x);
                out[q..q + 3].copy_from_slice(rgb);
            }
        }
    }
    ensure_font(path_for_errors)?;
    {
        let root = BitMapBackend::with_buffer(&mut out, (fw as u32, fh as u32)).into_drawing_area();
        let style = (FONT, 12).into_font().color(&BLACK);
        let depth_label = format!("depth error ±{depth_range:.2} m");
        let labels: [&str; 4] = ["NeRF", "ground truth", "colour error", &depth_label];
        for (i, label) in labels.iter().enumerate() {
            root.draw(&Text::new(label.to_string(), ((i * w) as i32 + 2, 1), style.clone()))
                .map_err(|e| EvalError::Plot { path: path_for_errors.into(), message: format!("{e:?}") })?;
        }
        root.present().map_err(|e| EvalError::Plot { path: path_for_errors.into(), message: format!("{e:?}") })?;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn side_by_side_places_the_four_panels_under_their_labels() {
        let (w, h) = (16u32, 12u32);
        let n = (w * h) as usize;
        let nerf = vec![0.5f32; 3 * n];
        let mut gt = vec![0.5f32; 3 * n];
        gt[0] = 0.0; // one pixel of colour error
        let depth = vec![2.0f32; n];
        let mut alpha = vec![1.0f32; n];
        alpha[n - 1] = 0.0;
        let f = FrameImages { width: w, height: h, nerf_rgb: &nerf, nerf_depth: &depth, gt_rgb: &gt, gt_depth: &depth, gt_alpha: &alpha };
        let p = Path::new("v.mp4");
        let img = compose(Layout::SideBySide, &f, 0.1, p).unwrap();
        let (fw, fh) = frame_size(Layout::SideBySide, w, h);
        assert_eq!(img.len(), (fw * fh * 3) as usize);
        let px = |x: u32, y: u32| { let q = 3 * (y * fw + x) as usize; [img[q], img[q + 1], img[q + 2]] };
        let top = LABEL_H;
        assert_eq!(px(5, top + 5), [128, 128, 128], "NeRF grey 0.5");
        assert_eq!(px(w + 5, top + 5), [128, 128, 128], "ground truth");
        assert_eq!(px(2 * w + 5, top + 5), Colormap::Inferno.map(0.0, 0.0, COLOUR_ERROR_MAX), "no colour error");
        assert_ne!(px(2 * w, top), px(2 * w + 5, top + 5), "the error pixel is hotter");
        assert_eq!(px(3 * w + 5, top + 5), Colormap::BlueWhiteRed.map(0.0, -0.1, 0.1), "no depth error");
        assert_eq!(px(4 * w - 1, fh - 1), [128, 128, 128], "a miss is grey");
        // The label strip holds text (dark pixels) over white.
        assert!((0..fw).any(|x| (0..LABEL_H).any(|y| px(x, y)[0] < 100)));
        assert_eq!(compose(Layout::Nerf, &f, 0.1, p).unwrap().len(), 3 * n);
    }
}
