//! Colour maps for heatmaps: sequential (viridis, inferno) and diverging (blue-white-red).
//!
//! Each map is a table of anchor colours at evenly spaced positions in `[0, 1]` (sampled from
//! matplotlib's maps), interpolated linearly in sRGB.

/// A colour map.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Colormap {
    /// Perceptually uniform sequential map, dark blue → yellow (depth).
    Viridis,
    /// Perceptually uniform sequential map, black → yellow-white (colour error).
    Inferno,
    /// Diverging map, blue (negative) → white (zero) → red (positive) (signed depth error,
    /// used with a range symmetric about 0).
    BlueWhiteRed,
}

const VIRIDIS: [[u8; 3]; 9] = [
    [68, 1, 84],
    [71, 45, 123],
    [59, 82, 139],
    [44, 114, 142],
    [33, 145, 140],
    [40, 174, 128],
    [94, 201, 98],
    [173, 220, 48],
    [253, 231, 37],
];

const INFERNO: [[u8; 3]; 9] = [
    [0, 0, 4],
    [31, 12, 72],
    [85, 15, 109],
    [136, 34, 106],
    [186, 54, 85],
    [227, 89, 51],
    [249, 140, 10],
    [249, 201, 50],
    [252, 255, 164],
];

const BLUE_WHITE_RED: [[u8; 3]; 5] =
    [[5, 48, 97], [67, 147, 195], [247, 247, 247], [214, 96, 77], [103, 0, 31]];

impl Colormap {
    fn anchors(self) -> &'static [[u8; 3]] {
        match self {
            Colormap::Viridis => &VIRIDIS,
            Colormap::Inferno => &INFERNO,
            Colormap::BlueWhiteRed => &BLUE_WHITE_RED,
        }
    }

    /// Colour at position `s` in `[0, 1]` (clamped; NaN maps to the low end).
    pub fn at(self, s: f64) -> [u8; 3] {
        let a = self.anchors();
        let s = if s.is_nan() { 0.0 } else { s.clamp(0.0, 1.0) };
        let x = s * (a.len() - 1) as f64;
        let i = (x.floor() as usize).min(a.len() - 2);
        let f = x - i as f64;
        let mut out = [0u8; 3];
        for c in 0..3 {
            let v = f64::from(a[i][c]) * (1.0 - f) + f64::from(a[i + 1][c]) * f;
            out[c] = v.round() as u8;
        }
        out
    }

    /// Colour of `value` on the range `[lo, hi]` (a degenerate range maps to the middle).
    pub fn map(self, value: f64, lo: f64, hi: f64) -> [u8; 3] {
        if hi > lo {
            self.at((value - lo) / (hi - lo))
        } else {
            self.at(0.5)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn luminance(c: [u8; 3]) -> f64 {
        0.2126 * f64::from(c[0]) + 0.7152 * f64::from(c[1]) + 0.0722 * f64::from(c[2])
    }

    #[test]
    fn endpoints_and_interpolation() {
        assert_eq!(Colormap::Viridis.at(0.0), [68, 1, 84]);
        assert_eq!(Colormap::Viridis.at(1.0), [253, 231, 37]);
        assert_eq!(Colormap::Viridis.at(2.0), [253, 231, 37]);
        assert_eq!(Colormap::Inferno.at(-1.0), [0, 0, 4]);
        // halfway between anchors 0 and 1 of the diverging map (positions 0 and 0.25)
        assert_eq!(Colormap::BlueWhiteRed.at(0.125), [36, 98, 146]);
        assert_eq!(Colormap::BlueWhiteRed.map(0.0, -2.0, 2.0), [247, 247, 247]);
        assert_eq!(Colormap::Viridis.map(3.0, 1.0, 1.0), Colormap::Viridis.at(0.5));
    }

    #[test]
    fn sequential_maps_brighten_monotonically() {
        for map in [Colormap::Viridis, Colormap::Inferno] {
            let lum: Vec<f64> = (0..=100).map(|i| luminance(map.at(i as f64 / 100.0))).collect();
            assert!(lum.windows(2).all(|w| w[1] >= w[0] - 0.5), "{map:?}");
        }
    }

    #[test]
    fn diverging_map_is_lightest_at_zero_and_symmetric_in_lightness() {
        let m = Colormap::BlueWhiteRed;
        let mid = luminance(m.at(0.5));
        for i in 0..50 {
            let s = i as f64 / 100.0;
            assert!(luminance(m.at(s)) < mid);
            assert!(luminance(m.at(1.0 - s)) < mid);
        }
        let neg = m.at(0.1);
        let pos = m.at(0.9);
        assert!(neg[2] > neg[0] && pos[0] > pos[2]); // blue below zero, red above
    }
}
