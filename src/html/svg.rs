//! Inline SVG figures of the report: a histogram, and a map frame that places world coordinates
//! over a raster preview. Text is left to the browser, so no font is embedded.

use std::fmt::Write as _;

use super::page::esc;

/// A histogram of `values` over `[lo, hi]` (values outside are counted in the end bins) with
/// labelled axes and vertical marks (value, label).
pub fn histogram(values: &[f64], lo: f64, hi: f64, x_label: &str, marks: &[(f64, &str)]) -> String {
    const BINS: usize = 40;
    let (w, h, left, bottom, top, right) = (560.0, 220.0, 52.0, 40.0, 12.0, 14.0);
    let span = (hi - lo).max(f64::MIN_POSITIVE);
    let mut counts = [0usize; BINS];
    for v in values.iter().filter(|v| v.is_finite()) {
        let b = (((v - lo) / span) * BINS as f64).floor();
        counts[b.clamp(0.0, (BINS - 1) as f64) as usize] += 1;
    }
    let max = counts.iter().copied().max().unwrap_or(0).max(1) as f64;
    let (pw, ph) = (w - left - right, h - top - bottom);
    let mut s = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 {w} {h}\" role=\"img\" \
         font-size=\"11\" font-family=\"sans-serif\">"
    );
    let bw = pw / BINS as f64;
    for (i, &c) in counts.iter().enumerate() {
        let bh = ph * c as f64 / max;
        let _ = write!(
            s,
            "<rect x=\"{:.2}\" y=\"{:.2}\" width=\"{:.2}\" height=\"{:.2}\" fill=\"#2c6e91\"/>",
            left + i as f64 * bw + 0.5,
            top + ph - bh,
            (bw - 1.0).max(0.5),
            bh
        );
    }
    // Axes, ticks at the ends and the middle, the count scale.
    let _ = write!(
        s,
        "<path d=\"M{left} {top} V{y0} H{x1}\" stroke=\"#333\" fill=\"none\"/>",
        y0 = top + ph,
        x1 = left + pw
    );
    for k in 0..=4 {
        let t = k as f64 / 4.0;
        let x = left + t * pw;
        let _ = write!(
            s,
            "<line x1=\"{x:.1}\" y1=\"{y:.1}\" x2=\"{x:.1}\" y2=\"{y2:.1}\" stroke=\"#333\"/>\
             <text x=\"{x:.1}\" y=\"{ty:.1}\" text-anchor=\"middle\">{}</text>",
            tick(lo + t * span, span),
            y = top + ph,
            y2 = top + ph + 4.0,
            ty = top + ph + 16.0
        );
    }
    let _ = write!(
        s,
        "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>\
         <text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">{}</text>\
         <text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">0</text>",
        left + pw / 2.0,
        h - 6.0,
        esc(x_label),
        left - 4.0,
        top + 9.0,
        max as usize,
        left - 4.0,
        top + ph
    );
    for (k, &(v, label)) in marks.iter().enumerate() {
        if !(v.is_finite() && v >= lo && v <= hi) {
            continue;
        }
        let x = left + (v - lo) / span * pw;
        let _ = write!(
            s,
            "<line x1=\"{x:.1}\" y1=\"{top}\" x2=\"{x:.1}\" y2=\"{:.1}\" stroke=\"#c0392b\" \
             stroke-dasharray=\"4 3\"/><text x=\"{:.1}\" y=\"{:.1}\" fill=\"#c0392b\">{}</text>",
            top + ph,
            x + 3.0,
            top + 10.0 + 12.0 * k as f64,
            esc(label)
        );
    }
    s.push_str("</svg>");
    s
}

/// A tick label with as many decimals as the span needs.
fn tick(v: f64, span: f64) -> String {
    let digits = if span >= 50.0 {
        0
    } else if span >= 5.0 {
        1
    } else if span >= 0.5 {
        2
    } else {
        3
    };
    format!("{v:.digits$}")
}

/// A north-up map frame: world (x east, y north) onto SVG user units of one per cell, the
/// north-west corner at (0, 0).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapFrame {
    /// x of the west edge.
    pub west: f64,
    /// y of the north edge.
    pub north: f64,
    /// Metres per unit.
    pub cell: f64,
    /// Width in units.
    pub width: f64,
    /// Height in units.
    pub height: f64,
}

impl MapFrame {
    /// The frame over a box, `cells` units along its longer side.
    pub fn around(min: [f64; 2], max: [f64; 2], cells: f64) -> MapFrame {
        let (dx, dy) = ((max[0] - min[0]).max(1e-6), (max[1] - min[1]).max(1e-6));
        let cell = dx.max(dy) / cells;
        MapFrame {
            west: min[0],
            north: max[1],
            cell,
            width: dx / cell,
            height: dy / cell,
        }
    }

    /// Frame units of a world position.
    pub fn at(&self, x: f64, y: f64) -> (f64, f64) {
        ((x - self.west) / self.cell, (self.north - y) / self.cell)
    }

    /// An SVG map: the background image stretched over the frame (when given), then the overlay
    /// (SVG elements in frame units), then a scale bar.
    pub fn svg(&self, background: Option<&str>, overlay: &str) -> String {
        let (w, h) = (self.width, self.height);
        let mut s = format!(
            "<svg xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 {w:.2} {h:.2}\" role=\"img\" \
             preserveAspectRatio=\"xMidYMid meet\">"
        );
        match background {
            Some(uri) => {
                let _ = write!(
                    s,
                    "<image href=\"{uri}\" x=\"0\" y=\"0\" width=\"{w:.2}\" height=\"{h:.2}\" \
                     preserveAspectRatio=\"none\"/>"
                );
            }
            None => {
                let _ = write!(
                    s,
                    "<rect x=\"0\" y=\"0\" width=\"{w:.2}\" height=\"{h:.2}\" fill=\"#eef1f3\"/>"
                );
            }
        }
        s.push_str(overlay);
        // Scale bar: a round length near a fifth of the width, bottom left.
        let metres = round_length(self.width * self.cell / 5.0);
        let len = metres / self.cell;
        let (x, y, u) = (w * 0.03, h * 0.95, w.max(h) / 400.0);
        let _ = write!(
            s,
            "<rect x=\"{:.2}\" y=\"{:.2}\" width=\"{:.2}\" height=\"{:.2}\" fill=\"#fff\" opacity=\"0.8\"/>\
             <line x1=\"{x:.2}\" y1=\"{y:.2}\" x2=\"{:.2}\" y2=\"{y:.2}\" stroke=\"#000\" stroke-width=\"{:.2}\"/>\
             <text x=\"{x:.2}\" y=\"{:.2}\" font-size=\"{:.2}\" font-family=\"sans-serif\">{} m</text>",
            x - 2.0 * u,
            y - 14.0 * u,
            len + 4.0 * u,
            18.0 * u,
            x + len,
            2.0 * u,
            y - 4.0 * u,
            10.0 * u,
            tick(metres, metres * 10.0)
        );
        s.push_str("</svg>");
        s
    }

    /// Stroke width and marker radius that read well at the frame's size.
    pub fn unit(&self) -> f64 {
        self.width.max(self.height) / 400.0
    }
}

/// 1, 2 or 5 × 10ⁿ not above `v`.
fn round_length(v: f64) -> f64 {
    if !(v.is_finite() && v > 0.0) {
        return 1.0;
    }
    let p = 10f64.powf(v.log10().floor());
    [5.0, 2.0, 1.0]
        .into_iter()
        .map(|m| m * p)
        .find(|&l| l <= v)
        .unwrap_or(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_counts_every_value_once() {
        let values: Vec<f64> = (0..1000).map(|i| i as f64 / 1000.0).collect();
        let s = histogram(&values, 0.0, 1.0, "error (px)", &[(0.5, "median")]);
        assert_eq!(s.matches("<rect").count(), 40);
        assert!(s.contains(">median<") && s.contains(">25<"), "{s}");
    }

    #[test]
    fn frames_map_corners_and_pick_round_scale_bars() {
        let f = MapFrame::around([100.0, 200.0], [300.0, 300.0], 400.0);
        assert_eq!(f.at(100.0, 300.0), (0.0, 0.0));
        let (x, y) = f.at(300.0, 200.0);
        assert!((x - 400.0).abs() < 1e-9 && (y - 200.0).abs() < 1e-9);
        assert_eq!(round_length(37.0), 20.0);
        assert_eq!(round_length(0.6), 0.5);
        assert_eq!(round_length(100.0), 100.0);
    }
}
