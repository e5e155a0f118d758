//! Per-view image grids: ground truth | NeRF | colour error (top row) and ground-truth depth |
//! NeRF depth | depth error (bottom row, when the NeRF rendered depth), each panel labelled,
//! heatmaps with a colour bar and units.
//!
//! Colour maps: viridis for depth (shared range: the ground-truth foreground depth range),
//! inferno for the colour error `mean_c |pred − gt|`, blue-white-red for the signed depth
//! error `pred − gt` with a range symmetric about 0 set to the 99th percentile of `|error|`
//! over foreground pixels (larger errors saturate). Pixels outside the foreground (ground-truth
//! alpha below 0.5, or NeRF opacity below 0.5 for the NeRF depth) are grey.

use std::path::Path;

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::colormap::Colormap;
use crate::error::{EvalError, MetricError};
use crate::evaluate::ViewInput;
use crate::io::write_png_atomic;
use crate::metrics::FOREGROUND_ALPHA;
use crate::plot::{FONT, ensure_font, plot_err};

const GREY: [u8; 3] = [128, 128, 128];
const GAP: usize = 24;
const TITLE_H: usize = 30;
const BAR_H: usize = 14;
const BAR_AREA_H: usize = 62;
const HEADER_H: usize = 40;

/// A heatmap's value range and legend, for its colour bar.
struct Bar {
    map: Colormap,
    lo: f64,
    hi: f64,
    label: String,
}

/// One panel: an RGB image of the panel size, its title, and optionally a colour bar.
struct Panel {
    title: String,
    rgb: Vec<u8>,
    bar: Option<Bar>,
}

/// Safe file-name stem for a view: ASCII letters, digits, `-`, `_` and `.` kept, others `_`.
pub fn grid_file_name(view: &str) -> String {
    let stem: String = view
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '_' || c == '.' { c } else { '_' })
        .collect();
    format!("grid_{stem}.png")
}

/// Panel side: images are scaled (nearest neighbour) so the longer side is between 256 and 512.
fn panel_size(w: usize, h: usize) -> (usize, usize) {
    let long = w.max(h) as f64;
    let scale = if long < 256.0 { (256.0 / long).ceil() } else if long > 512.0 { 512.0 / long } else { 1.0 };
    (((w as f64 * scale).round() as usize).max(1), ((h as f64 * scale).round() as usize).max(1))
}

/// Resample a per-pixel colour function to the panel size: nearest neighbour when enlarging,
/// the mean colour of the covered source pixels (box filter) when shrinking.
fn resample(w: usize, h: usize, pw: usize, ph: usize, f: impl Fn(usize) -> [u8; 3]) -> Vec<u8> {
    let mut out = Vec::with_capacity(pw * ph * 3);
    for py in 0..ph {
        let (y0, y1) = ((py * h / ph).min(h - 1), ((py + 1) * h).div_ceil(ph).clamp(1, h));
        for px in 0..pw {
            let (x0, x1) = ((px * w / pw).min(w - 1), ((px + 1) * w).div_ceil(pw).clamp(1, w));
            if pw >= w && ph >= h {
                out.extend_from_slice(&f(y0 * w + x0));
                continue;
            }
            let mut acc = [0u32; 3];
            let mut n = 0u32;
            for y in y0..y1.max(y0 + 1) {
                for x in x0..x1.max(x0 + 1) {
                    let c = f(y * w + x);
                    for k in 0..3 {
                        acc[k] += u32::from(c[k]);
                    }
                    n += 1;
                }
            }
            out.extend(acc.iter().map(|&a| ((a + n / 2) / n) as u8));
        }
    }
    out
}

fn to_u8(v: f32) -> u8 {
    (f64::from(v).clamp(0.0, 1.0) * 255.0).round() as u8
}

fn percentile(mut v: Vec<f64>, q: f64) -> Option<f64> {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let i = ((v.len() - 1) as f64 * q).round() as usize;
    Some(v[i])
}

fn fmt_value(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if a >= 100.0 {
        format!("{v:.0}")
    } else if a >= 1.0 {
        format!("{v:.2}")
    } else if a >= 0.01 {
        format!("{v:.3}")
    } else {
        format!("{v:.1e}")
    }
}

fn check(v: &ViewInput<'_>, what: &'static str, got: usize, expected: usize) -> Result<(), EvalError> {
    if got == expected {
        Ok(())
    } else {
        Err(EvalError::Metric { view: v.name.to_string(), source: MetricError::Length { what, expected, got } })
    }
}

fn build_panels(v: &ViewInput<'_>, pw: usize, ph: usize) -> Result<Vec<Panel>, EvalError> {
    let (w, h) = (v.width, v.height);
    let n = w * h;
    check(v, "pred_rgb", v.pred_rgb.len(), n * 3)?;
    check(v, "gt_rgb", v.gt_rgb.len(), n * 3)?;
    for (what, a) in [("gt_alpha", v.gt_alpha), ("gt_depth", v.gt_depth), ("pred_depth", v.pred_depth), ("pred_opacity", v.pred_opacity)] {
        if let Some(a) = a {
            check(v, what, a.len(), n)?;
        }
    }
    let rgb = |img: &[f32]| resample(w, h, pw, ph, |i| [to_u8(img[3 * i]), to_u8(img[3 * i + 1]), to_u8(img[3 * i + 2])]);
    let err: Vec<f64> = (0..n)
        .map(|i| (0..3).map(|c| (f64::from(v.pred_rgb[3 * i + c]) - f64::from(v.gt_rgb[3 * i + c])).abs()).sum::<f64>() / 3.0)
        .collect();
    let err_max = err.iter().copied().filter(|e| e.is_finite()).fold(0.0, f64::max).max(1e-3);
    let mut panels = vec![
        Panel { title: "ground truth".into(), rgb: rgb(v.gt_rgb), bar: None },
        Panel { title: "NeRF".into(), rgb: rgb(v.pred_rgb), bar: None },
        Panel {
            title: "colour error".into(),
            rgb: resample(w, h, pw, ph, |i| Colormap::Inferno.map(err[i], 0.0, err_max)),
            bar: Some(Bar {
                map: Colormap::Inferno,
                lo: 0.0,
                hi: err_max,
                label: "mean |NeRF − GT| over RGB (display units, 0–1)".into(),
            }),
        },
    ];
    let Some(pred_depth) = v.pred_depth else {
        return Ok(panels);
    };
    // Where the prediction sees a surface: opacity at least 0.5, or without an opacity a
    // positive finite depth.
    let seen = |i: usize| match v.pred_opacity {
        Some(o) => o[i] >= 0.5,
        None => pred_depth[i] > 0.0 && pred_depth[i].is_finite(),
    };
    // Foreground: gt alpha if given, else gt depth > 0.
    let fg: Option<Vec<bool>> = match (v.gt_alpha, v.gt_depth) {
        (Some(a), Some(g)) => Some((0..n).map(|i| a[i] >= FOREGROUND_ALPHA && g[i] > 0.0).collect()),
        (None, Some(g)) => Some(g.iter().map(|&z| z > 0.0).collect()),
        _ => None,
    };
    let range_src: Vec<f64> = match (&fg, v.gt_depth) {
        (Some(fg), Some(g)) => (0..n).filter(|&i| fg[i]).map(|i| f64::from(g[i])).collect(),
        _ => (0..n).filter(|&i| seen(i)).map(|i| f64::from(pred_depth[i])).collect(),
    };
    let lo = percentile(range_src.clone(), 0.0).unwrap_or(0.0);
    let hi = percentile(range_src, 1.0).unwrap_or(1.0);
    let depth_bar = || Bar { map: Colormap::Viridis, lo, hi, label: "z-depth (scene units, m)".into() };
    let missing = |title: &str| Panel { title: format!("{title} (no ground truth)"), rgb: vec![200; pw * ph * 3], bar: None };
    match (v.gt_depth, &fg) {
        (Some(g), Some(fg)) => panels.push(Panel {
            title: "ground-truth depth".into(),
            rgb: resample(w, h, pw, ph, |i| if fg[i] { Colormap::Viridis.map(f64::from(g[i]), lo, hi) } else { GREY }),
            bar: Some(depth_bar()),
        }),
        _ => panels.push(missing("depth")),
    }
    panels.push(Panel {
        title: "NeRF depth".into(),
        rgb: resample(w, h, pw, ph, |i| {
            if seen(i) { Colormap::Viridis.map(f64::from(pred_depth[i]), lo, hi) } else { GREY }
        }),
        bar: Some(depth_bar()),
    });
    match (v.gt_depth, &fg) {
        (Some(g), Some(fg)) => {
            let e: Vec<f64> = (0..n).map(|i| f64::from(pred_depth[i]) - f64::from(g[i])).collect();
            let r = percentile((0..n).filter(|&i| fg[i]).map(|i| e[i].abs()).collect(), 0.99)
                .unwrap_or(0.0)
                .max(1e-6);
            panels.push(Panel {
                title: "depth error".into(),
                rgb: resample(w, h, pw, ph, |i| if fg[i] { Colormap::BlueWhiteRed.map(e[i], -r, r) } else { GREY }),
                bar: Some(Bar {
                    map: Colormap::BlueWhiteRed,
                    lo: -r,
                    hi: r,
                    label: "NeRF − GT z-depth (m), ±99th pct |error|".into(),
                }),
            });
        }
        _ => panels.push(missing("depth error")),
    }
    Ok(panels)
}

/// Draw `grid_<view>.png` for one view (see the module documentation for the layout and
/// colour maps); `header` is written above the panels (e.g. the view's metrics).
pub fn view_grid_png(path: &Path, v: &ViewInput<'_>, header: &str) -> Result<(), EvalError> {
    ensure_font(path)?;
    if v.width == 0 || v.height == 0 {
        return Err(EvalError::Metric { view: v.name.to_string(), source: MetricError::Empty("grid") });
    }
    let (pw, ph) = panel_size(v.width, v.height);
    let panels = build_panels(v, pw, ph)?;
    let rows = panels.len().div_ceil(3);
    let cell_h = TITLE_H + ph + BAR_AREA_H;
    let (cw, ch) = (GAP + 3 * (pw + GAP), HEADER_H + rows * cell_h + GAP / 2);
    let mut buf = vec![255u8; cw * ch * 3];
    let origin = |k: usize| (GAP + (k % 3) * (pw + GAP), HEADER_H + (k / 3) * cell_h);
    // Pixel content: images and colour bars.
    for (k, p) in panels.iter().enumerate() {
        let (x0, y0) = origin(k);
        for y in 0..ph {
            let dst = ((y0 + TITLE_H + y) * cw + x0) * 3;
            buf[dst..dst + pw * 3].copy_from_slice(&p.rgb[y * pw * 3..(y + 1) * pw * 3]);
        }
        if let Some(bar) = &p.bar {
            let by = y0 + TITLE_H + ph + 6;
            for y in by..by + BAR_H {
                for x in 0..pw {
                    let c = bar.map.at(x as f64 / (pw - 1).max(1) as f64);
                    let dst = (y * cw + x0 + x) * 3;
                    buf[dst..dst + 3].copy_from_slice(&c);
                }
            }
        }
    }
    // Text and frames.
    let err = plot_err(path);
    {
        let root = BitMapBackend::with_buffer(&mut buf, (cw as u32, ch as u32)).into_drawing_area();
        let text = |size: u32, h: HPos| (FONT, size).into_font().color(&BLACK).pos(Pos::new(h, VPos::Top));
        root.draw(&Text::new(header.to_string(), (GAP as i32, 10), text(20, HPos::Left))).map_err(&err)?;
        for (k, p) in panels.iter().enumerate() {
            let (x0, y0) = origin(k);
            let (x0, y0, pwi, phi) = (x0 as i32, y0 as i32, pw as i32, ph as i32);
            root.draw(&Text::new(p.title.clone(), (x0 + pwi / 2, y0 + 6), text(17, HPos::Center))).map_err(&err)?;
            let top = y0 + TITLE_H as i32;
            root.draw(&Rectangle::new([(x0 - 1, top - 1), (x0 + pwi, top + phi)], BLACK.stroke_width(1)))
                .map_err(&err)?;
            if let Some(bar) = &p.bar {
                let by = top + phi + 6;
                root.draw(&Rectangle::new([(x0 - 1, by - 1), (x0 + pwi, by + BAR_H as i32)], BLACK.stroke_width(1)))
                    .map_err(&err)?;
                for (f, anchor) in [(0.0, HPos::Left), (0.5, HPos::Center), (1.0, HPos::Right)] {
                    let x = x0 + (f * f64::from(pwi - 1)) as i32;
                    root.draw(&PathElement::new(vec![(x, by + BAR_H as i32), (x, by + BAR_H as i32 + 4)], BLACK))
                        .map_err(&err)?;
                    let value = bar.lo + f * (bar.hi - bar.lo);
                    root.draw(&Text::new(fmt_value(value), (x, by + BAR_H as i32 + 5), text(13, anchor)))
                        .map_err(&err)?;
                }
                root.draw(&Text::new(bar.label.clone(), (x0 + pwi / 2, by + BAR_H as i32 + 23), text(13, HPos::Center)))
                    .map_err(&err)?;
            }
        }
        root.present().map_err(&err)?;
    }
    write_png_atomic(path, cw as u32, ch as u32, buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_names_are_sanitised() {
        assert_eq!(grid_file_name("r_0"), "grid_r_0.png");
        assert_eq!(grid_file_name("test/r 1"), "grid_test_r_1.png");
    }

    #[test]
    fn panel_sizes_stay_in_range() {
        assert_eq!(panel_size(16, 12), (256, 192));
        assert_eq!(panel_size(300, 200), (300, 200));
        assert_eq!(panel_size(800, 800), (512, 512));
    }

    #[test]
    fn resample_enlarges_by_copying_and_shrinks_by_averaging() {
        // 2x1 source: black, white
        let src = [[0u8, 0, 0], [255, 255, 255]];
        let big = resample(2, 1, 4, 2, |i| src[i]);
        assert_eq!(&big[..12], &[0, 0, 0, 0, 0, 0, 255, 255, 255, 255, 255, 255]);
        assert_eq!(&big[12..], &big[..12]);
        // 4x4 checkerboard of 0 / 200 shrunk to 2x2: every output is the mean, 100
        let small = resample(4, 4, 2, 2, |i| if (i % 4 + i / 4) % 2 == 0 { [0; 3] } else { [200; 3] });
        assert!(small.iter().all(|&v| v == 100), "{small:?}");
    }

    #[test]
    fn percentile_and_formatting() {
        let v: Vec<f64> = (0..101).map(f64::from).collect();
        assert_eq!(percentile(v.clone(), 0.99), Some(99.0));
        assert_eq!(percentile(v, 0.0), Some(0.0));
        assert_eq!(percentile(vec![f64::NAN], 0.5), None);
        assert_eq!(fmt_value(0.0), "0");
        assert_eq!(fmt_value(2.5), "2.50");
        assert_eq!(fmt_value(-0.0123), "-0.012");
    }
}
