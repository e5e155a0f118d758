//! Charts drawn with plotters into an RGB buffer and written as PNG atomically:
//! the speed-versus-error chart of one run, the PSNR curves of several runs, and panels of
//! benchmark figures with error bars.
//!
//! Text uses DejaVu Sans, shipped in `assets/` (Bitstream Vera licence, see
//! `assets/DejaVuSans-LICENSE.txt`) and registered with plotters on first use, so no system
//! font is needed.

use std::path::Path;
use std::sync::OnceLock;

use plotters::prelude::*;
use plotters::style::FontStyle;

use crate::error::EvalError;
use crate::io::write_png_atomic;

/// DejaVu Sans, embedded.
static FONT_BYTES: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

/// The font family name the charts use.
pub(crate) const FONT: &str = "sans-serif";

/// Register the embedded font with plotters (once per process).
pub(crate) fn ensure_font(path: &Path) -> Result<(), EvalError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| plotters::style::register_font(FONT, FontStyle::Normal, FONT_BYTES).is_ok());
    if ok {
        Ok(())
    } else {
        Err(EvalError::Plot { path: path.to_path_buf(), message: "embedded font failed to load".into() })
    }
}

pub(crate) fn plot_err<E: std::fmt::Debug>(path: &Path) -> impl Fn(E) -> EvalError + '_ {
    move |e| EvalError::Plot { path: path.to_path_buf(), message: format!("{e:?}") }
}

/// Distinct line colours for runs (Tableau 10).
pub(crate) const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

/// One labelled curve of `(x, y)` points.
#[derive(Debug, Clone)]
pub struct Curve {
    /// Legend label.
    pub label: String,
    /// Points in drawing order.
    pub points: Vec<(f64, f64)>,
}

/// What [`speed_vs_error_png`] draws.
#[derive(Debug, Clone)]
pub struct SpeedVsError {
    /// Validation PSNR `(wall_s, dB)`.
    pub val_psnr: Vec<(f64, f64)>,
    /// Training-batch PSNR `(wall_s, dB)` (drawn faintly; may be empty).
    pub train_psnr: Vec<(f64, f64)>,
    /// Validation depth MAE `(wall_s, scene units)`; a second panel when not empty.
    pub val_depth_mae: Vec<(f64, f64)>,
    /// Time to reach 25 dB, seconds.
    pub t25: Option<f64>,
    /// Time to reach 30 dB, seconds.
    pub t30: Option<f64>,
    /// Title.
    pub title: String,
}

fn range_with_margin(values: impl Iterator<Item = f64>, include: &[f64]) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.chain(include.iter().copied()).filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-6);
    (lo - pad, hi + pad)
}

/// Draw PSNR curves with the 25 dB and 30 dB lines and, optionally, time markers.
fn psnr_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    curves: &[(Curve, ShapeStyle, bool)],
    markers: &[(f64, f64, String)],
    title: &str,
    x_max: f64,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let (y_lo, y_hi) = range_with_margin(curves.iter().flat_map(|(c, _, _)| c.points.iter().map(|p| p.1)), &[25.0, 30.0]);
    let mut chart = ChartBuilder::on(area)
        .caption(title, (FONT, 22))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..x_max, y_lo..y_hi)?;
    chart
        .configure_mesh()
        .x_desc("wall-clock training time (s)")
        .y_desc("PSNR (dB)")
        .label_style((FONT, 15))
        .axis_desc_style((FONT, 16))
        .light_line_style(RGBColor(246, 246, 246))
        .draw()?;
    for thr in [25.0, 30.0] {
        chart.draw_series(DashedLineSeries::new(
            vec![(0.0, thr), (x_max, thr)],
            6,
            4,
            RGBColor(150, 150, 150).stroke_width(1),
        ))?;
        chart.draw_series(std::iter::once(Text::new(
            format!("{thr:.0} dB"),
            (x_max * 0.005, thr + (y_hi - y_lo) * 0.01),
            (FONT, 13).into_font().color(&RGBColor(110, 110, 110)).pos(plotters::style::text_anchor::Pos::new(
                plotters::style::text_anchor::HPos::Left,
                plotters::style::text_anchor::VPos::Bottom,
            )),
        )))?;
    }
    let mut any_label = false;
    for (curve, style, dots) in curves {
        if curve.points.is_empty() {
            continue;
        }
        let s = chart.draw_series(LineSeries::new(curve.points.iter().copied(), *style))?;
        if !curve.label.is_empty() {
            any_label = true;
            let legend_style = *style;
            s.label(curve.label.clone())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], legend_style));
        }
        if *dots {
            chart.draw_series(curve.points.iter().map(|&p| Circle::new(p, 3, style.color.filled())))?;
        }
    }
    for (t, thr, label) in markers {
        chart.draw_series(DashedLineSeries::new(
            vec![(*t, y_lo), (*t, *thr)],
            6,
            4,
            RGBColor(200, 40, 40).stroke_width(2),
        ))?;
        chart.draw_series(std::iter::once(Circle::new((*t, *thr), 5, RGBColor(200, 40, 40).filled())))?;
        chart.draw_series(std::iter::once(Text::new(
            label.clone(),
            (*t, *thr - (y_hi - y_lo) * 0.03),
            (FONT, 14).into_font().color(&RGBColor(200, 40, 40)),
        )))?;
    }
    if any_label {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .label_font((FONT, 14))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()?;
    }
    Ok(())
}

/// Width and height of the speed-versus-error picture (a second panel doubles the height).
const CHART_W: u32 = 1000;
const CHART_H: u32 = 520;

/// Draw `speed_vs_error.png`: validation PSNR against wall-clock training time with the times
/// to 25 dB and 30 dB marked, and validation depth MAE on a second panel when present.
pub fn speed_vs_error_png(path: &Path, data: &SpeedVsError) -> Result<(), EvalError> {
    ensure_font(path)?;
    let err = plot_err(path);
    let panels = if data.val_depth_mae.is_empty() { 1 } else { 2 };
    let (w, h) = (CHART_W, CHART_H * panels);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(&err)?;
        let areas = root.split_evenly((panels as usize, 1));
        let x_max = data
            .val_psnr
            .iter()
            .chain(&data.train_psnr)
            .chain(&data.val_depth_mae)
            .map(|p| p.0)
            .fold(1e-3, f64::max)
            * 1.02;
        let mut curves = vec![(
            Curve { label: "validation PSNR".into(), points: data.val_psnr.clone() },
            PALETTE[0].stroke_width(2),
            true,
        )];
        if !data.train_psnr.is_empty() {
            curves.push((
                Curve { label: "training-batch PSNR".into(), points: data.train_psnr.clone() },
                RGBColor(170, 170, 170).stroke_width(1),
                false,
            ));
        }
        let mut markers = Vec::new();
        for (t, thr) in [(data.t25, 25.0), (data.t30, 30.0)] {
            if let Some(t) = t {
                markers.push((t, thr, format!(" {thr:.0} dB at {t:.1} s")));
            }
        }
        let reached = |t: Option<f64>| t.map_or("never".to_string(), |t| format!("{t:.1} s"));
        let title = format!("{}: time to 25 dB {}, to 30 dB {}", data.title, reached(data.t25), reached(data.t30));
        psnr_panel(&areas[0], &curves, &markers, &title, x_max).map_err(&err)?;
        if data.val_psnr.is_empty() {
            areas[0]
                .draw(&Text::new(
                    "no validation evaluations in metrics.jsonl",
                    (300, (CHART_H / 2) as i32),
                    (FONT, 20).into_font().color(&RED),
                ))
                .map_err(&err)?;
        }
        if panels == 2 {
            let (lo, hi) = range_with_margin(data.val_depth_mae.iter().map(|p| p.1), &[0.0]);
            let mut chart = ChartBuilder::on(&areas[1])
                .caption("validation depth error", (FONT, 22))
                .margin(12)
                .x_label_area_size(45)
                .y_label_area_size(60)
                .build_cartesian_2d(0.0..x_max, lo.max(0.0)..hi)
                .map_err(&err)?;
            chart
                .configure_mesh()
                .x_desc("wall-clock training time (s)")
                .y_desc("depth MAE (scene units, m)")
                .label_style((FONT, 15))
                .axis_desc_style((FONT, 16))
                .light_line_style(RGBColor(246, 246, 246))
                .draw()
                .map_err(&err)?;
            chart
                .draw_series(LineSeries::new(data.val_depth_mae.iter().copied(), PALETTE[1].stroke_width(2)))
                .map_err(&err)?;
            chart
                .draw_series(data.val_depth_mae.iter().map(|&p| Circle::new(p, 3, PALETTE[1].filled())))
                .map_err(&err)?;
        }
        root.present().map_err(&err)?;
    }
    write_png_atomic(path, w, h, buf)
}

/// Draw `compare.png`: several runs' validation PSNR curves overlaid, legend = run name.
pub fn compare_png(path: &Path, runs: &[Curve]) -> Result<(), EvalError> {
    ensure_font(path)?;
    let err = plot_err(path);
    let (w, h) = (CHART_W, 600);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(&err)?;
        let x_max = runs.iter().flat_map(|c| &c.points).map(|p| p.0).fold(1e-3, f64::max) * 1.02;
        let curves: Vec<(Curve, ShapeStyle, bool)> = runs
            .iter()
            .enumerate()
            .map(|(i, c)| (c.clone(), PALETTE[i % PALETTE.len()].stroke_width(2), true))
            .collect();
        psnr_panel(&root, &curves, &[], "validation PSNR against training time", x_max).map_err(&err)?;
        root.present().map_err(&err)?;
    }
    write_png_atomic(path, w, h, buf)
}

/// One series of [`panels_png`]: `(x, mean, half-width of the error bar)` points.
#[derive(Debug, Clone)]
pub struct ErrorSeries {
    /// Legend label.
    pub label: String,
    /// Points in drawing order.
    pub points: Vec<(f64, f64, f64)>,
}

/// One panel of [`panels_png`].
#[derive(Debug, Clone)]
pub struct Panel {
    /// Caption.
    pub caption: String,
    /// Description of the x axis.
    pub x_desc: String,
    /// Description of the y axis.
    pub y_desc: String,
    /// Series, coloured in order.
    pub series: Vec<ErrorSeries>,
}

/// Draw panels side by side, each with its series as lines through the means and vertical
/// error bars (a benchmark's figure against a setting, e.g. pose error against noise level).
pub fn panels_png(path: &Path, panels: &[Panel]) -> Result<(), EvalError> {
    ensure_font(path)?;
    let err = plot_err(path);
    let (w, h) = (620 * panels.len().max(1) as u32, 480);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(&err)?;
        let areas = root.split_evenly((1, panels.len().max(1)));
        for (panel, area) in panels.iter().zip(&areas) {
            let pts = || panel.series.iter().flat_map(|s| &s.points);
            let (x0, x1) = range_with_margin(pts().map(|p| p.0), &[]);
            let (y0, y1) = range_with_margin(pts().flat_map(|p| [p.1 - p.2, p.1 + p.2]), &[]);
            let mut chart = ChartBuilder::on(area)
                .caption(&panel.caption, (FONT, 20))
                .margin(12)
                .x_label_area_size(45)
                .y_label_area_size(60)
                .build_cartesian_2d(x0..x1, y0..y1)
                .map_err(&err)?;
            chart
                .configure_mesh()
                .x_desc(panel.x_desc.as_str())
                .y_desc(panel.y_desc.as_str())
                .label_style((FONT, 14))
                .axis_desc_style((FONT, 15))
                .light_line_style(RGBColor(246, 246, 246))
                .draw()
                .map_err(&err)?;
            for (i, s) in panel.series.iter().enumerate() {
                let c = PALETTE[i % PALETTE.len()];
                chart
                    .draw_series(LineSeries::new(s.points.iter().map(|p| (p.0, p.1)), c.stroke_width(2)))
                    .map_err(&err)?
                    .label(s.label.as_str())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
                chart.draw_series(s.points.iter().map(|p| Circle::new((p.0, p.1), 3, c.filled()))).map_err(&err)?;
                chart
                    .draw_series(s.points.iter().filter(|p| p.2 > 0.0).map(|p| PathElement::new(vec![(p.0, p.1 - p.2), (p.0, p.1 + p.2)], c.stroke_width(1))))
                    .map_err(&err)?;
            }
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .label_font((FONT, 14))
                .draw()
                .map_err(&err)?;
        }
        root.present().map_err(&err)?;
    }
    write_png_atomic(path, w, h, buf)
}
