//! **Stopping.** Stop when the val PSNR's least-squares trend over the last two fifths of the
//! time budget gains < 0.1 dB per fifth even one standard error above its estimate
//! ([`plateau_trend`], [`plateau_reached`]), validating every twentieth of the budget.

use super::*;

/// Stop training when the validation PSNR has gained less than `min_gain_db` over the last
/// `window_s` seconds of training time.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PlateauStop {
    /// Window, training seconds.
    pub window_s: f64,
    /// Least gain over the window, dB.
    pub min_gain_db: f64,
    /// How the gain is measured. `Some(k)`: the least-squares trend of the val PSNR over the
    /// last [`PLATEAU_FIT_WINDOWS`] windows, plus `k` standard errors of that trend
    /// ([`plateau_trend`]). `None` (and configs written before the trend rule): the best val PSNR
    /// now against the best at or before `now − window_s`, which one lucky validation before
    /// the window or one dip inside it could end while the run still gained about 1 dB per
    /// window (measured: tabletop, stopped at 66 s at 31.5 dB where the same config reaches
    /// 33.0 dB at 120 s).
    #[serde(default)]
    pub trend_sigmas: Option<f64>,
}

/// The plateau trend is fitted over this many windows (the window measures the gain; a longer
/// fit averages the validation noise down).
pub const PLATEAU_FIT_WINDOWS: f64 = 2.0;

/// The trend rule fits at least this many validations (more when its span holds more).
pub const PLATEAU_MIN_POINTS: usize = 5;

/// The val PSNR's trend over the last [`PLATEAU_FIT_WINDOWS`] × `window_s` of `history`
/// ((training seconds, val PSNR) points, non-finite PSNRs skipped), as (gain per window, its
/// standard error), both dB: the least-squares slope times the window, and the slope's standard
/// error (from the fit's residuals, n − 2 degrees of freedom) times the window. When the span
/// holds fewer than [`PLATEAU_MIN_POINTS`] validations (a step longer than the validation
/// interval, e.g. on a loaded machine), the last that many are fitted instead. `None` until a
/// full fitting span has passed and that many validations exist.
///
/// Example: window 10 s, points every 5 s over [0, 20] s at 20, 20.5, 21, 21.5, 22 dB: slope
/// 0.1 dB/s, gain 1.0 dB per window, standard error 0 (the points lie on the line).
pub fn plateau_trend(history: &[(f64, f64)], window_s: f64) -> Option<(f64, f64)> {
    let &(now, _) = history.last()?;
    let span = PLATEAU_FIT_WINDOWS * window_s;
    if now < span - 1e-9 {
        return None;
    }
    let finite: Vec<(f64, f64)> = history.iter().copied().filter(|p| p.1.is_finite()).collect();
    let in_span = finite.iter().filter(|p| p.0 >= now - span - 1e-9).count();
    if finite.len() < PLATEAU_MIN_POINTS {
        return None;
    }
    let pts = &finite[finite.len() - in_span.max(PLATEAU_MIN_POINTS)..];
    let n = pts.len() as f64;
    let (tm, pm) = (pts.iter().map(|p| p.0).sum::<f64>() / n, pts.iter().map(|p| p.1).sum::<f64>() / n);
    let sxx: f64 = pts.iter().map(|p| (p.0 - tm).powi(2)).sum();
    if sxx <= 0.0 {
        return None;
    }
    let slope = pts.iter().map(|p| (p.0 - tm) * (p.1 - pm)).sum::<f64>() / sxx;
    let residual = pts.iter().map(|p| (p.1 - pm - slope * (p.0 - tm)).powi(2)).sum::<f64>() / (n - 2.0);
    Some((slope * window_s, (residual / sxx).sqrt() * window_s))
}

/// Whether training has plateaued, with `history` the (training seconds, val PSNR) points so
/// far.
///
/// With `rule.trend_sigmas = Some(k)` (what `auto` writes): the val PSNR's trend
/// ([`plateau_trend`]) gains less than `min_gain_db` per window even at `k` standard errors
/// above its estimate. The validations of a hash-grid model swing by 0.2–0.6 dB from one to the
/// next (2-minute runs on the standard datasets), so a trend that is merely estimated below
/// the threshold is not enough: the rule stops when the gain is below it with confidence.
/// Example: gain 0.03 ± 0.05 dB per window, k = 1, threshold 0.1: 0.08 < 0.1 → plateaued;
/// gain 0.03 ± 0.5: 0.53 → not yet.
///
/// With `None`: the best PSNR now exceeds the best at or before `now − window_s` by less than
/// `min_gain_db`, false until a point at least `window_s` old exists. Example: points (0 s,
/// 20 dB), (10 s, 25), (20 s, 25.05), window 10 s, gain 0.1 dB: at 20 s the best before 10 s is
/// 25, the best now 25.05: gained 0.05 < 0.1 → plateaued.
pub fn plateau_reached(history: &[(f64, f64)], rule: &PlateauStop) -> bool {
    if let Some(k) = rule.trend_sigmas {
        return plateau_trend(history, rule.window_s).is_some_and(|(gain, se)| gain + k * se < rule.min_gain_db);
    }
    let Some(&(now, _)) = history.last() else { return false };
    let cutoff = now - rule.window_s;
    if cutoff < 0.0 {
        return false;
    }
    let best = |pts: &mut dyn Iterator<Item = &(f64, f64)>| pts.map(|p| p.1).filter(|v| v.is_finite()).fold(f64::NEG_INFINITY, f64::max);
    let before = best(&mut history.iter().filter(|p| p.0 <= cutoff + 1e-9));
    let all = best(&mut history.iter());
    before.is_finite() && all - before < rule.min_gain_db
}

