//! Report figures as RGB images: a map of a difference grid with a diverging colour bar, and a
//! histogram. Drawn directly into pixels (text from the public-domain 8 × 8 font of `font8x8`), so
//! figures need no system font and look the same on every machine; the caller encodes them (PNG).

use image::{Rgb, RgbImage};

use crate::grid::Dem;
use crate::stats::quantile_sorted;

const WHITE: Rgb<u8> = Rgb([255, 255, 255]);
const BLACK: Rgb<u8> = Rgb([0, 0, 0]);
const NODATA: Rgb<u8> = Rgb([215, 215, 215]);
const GREY: Rgb<u8> = Rgb([120, 120, 120]);

/// Options of a difference map.
#[derive(Debug, Clone, PartialEq)]
pub struct MapOptions {
    /// Title drawn above the map.
    pub title: String,
    /// Unit of the values, for the colour bar.
    pub unit: String,
    /// Colour range ±limit; default: the 98th percentile of |value|.
    pub limit: Option<f64>,
    /// Values with |value| ≤ lod are drawn in light grey (not significant).
    pub lod: Option<f64>,
    /// Longest side of the map area in pixels.
    pub max_size: u32,
}

impl Default for MapOptions {
    fn default() -> Self {
        MapOptions {
            title: String::new(),
            unit: "m".into(),
            limit: None,
            lod: None,
            max_size: 800,
        }
    }
}

/// Blue (negative, lowering) – white – red (positive, raising), t ∈ [−1, 1].
pub fn diverging(t: f64) -> Rgb<u8> {
    let t = if t.is_finite() {
        t.clamp(-1.0, 1.0)
    } else {
        0.0
    };
    let (lo, hi) = ([33.0, 102.0, 172.0], [178.0, 24.0, 43.0]);
    let end = if t < 0.0 { lo } else { hi };
    let a = t.abs();
    Rgb([0, 1, 2].map(|k| (255.0 + a * (end[k] - 255.0)).round() as u8))
}

/// Map of a grid of differences (DoD, gridded M3C2 distances) with title and colour bar.
pub fn difference_map(dem: &Dem, options: &MapOptions) -> RgbImage {
    let (w, h) = (dem.grid.width.max(1), dem.grid.height.max(1));
    let scale = (options.max_size as f64 / w.max(h) as f64).min(8.0);
    let (mw, mh) = (
        ((w as f64 * scale).round() as u32).max(1),
        ((h as f64 * scale).round() as u32).max(1),
    );
    let limit = options.limit.unwrap_or_else(|| {
        let mut abs: Vec<f64> = dem
            .values
            .iter()
            .filter(|v| !v.is_nan())
            .map(|v| (*v as f64).abs())
            .collect();
        abs.sort_unstable_by(f64::total_cmp);
        let l = quantile_sorted(&abs, 0.98);
        if l > 0.0 { l } else { 1.0 }
    });
    let (margin, top, bar) = (20u32, 40u32, 110u32);
    let bh = mh.clamp(60, 400);
    let height = mh.max(bh + 40) + top + margin;
    let width = (mw + 2 * margin + bar).max(16 * options.title.len() as u32 + 2 * margin);
    let mut img = RgbImage::from_pixel(width, height, WHITE);
    for y in 0..mh {
        for x in 0..mw {
            let col = ((x as f64 + 0.5) / scale) as usize;
            let row = ((y as f64 + 0.5) / scale) as usize;
            let v = dem.get(col.min(w - 1), row.min(h - 1)) as f64;
            let colour = if v.is_nan() {
                NODATA
            } else if options.lod.is_some_and(|l| v.abs() <= l) {
                Rgb([240, 240, 240])
            } else {
                diverging(v / limit)
            };
            img.put_pixel(margin + x, top + y, colour);
        }
    }
    frame(&mut img, margin - 1, top - 1, mw + 2, mh + 2, BLACK);
    text(&mut img, margin, 12, &options.title, 2, BLACK);
    // Colour bar.
    let (bx, bw) = (margin + mw + 20, 20u32);
    for y in 0..bh {
        let t = 1.0 - 2.0 * (y as f64 + 0.5) / bh as f64;
        for x in 0..bw {
            img.put_pixel(bx + x, top + y, diverging(t));
        }
    }
    frame(&mut img, bx - 1, top - 1, bw + 2, bh + 2, BLACK);
    for (t, frac) in [(limit, 0.0), (0.0, 0.5), (-limit, 1.0)] {
        let y = top + ((bh - 1) as f64 * frac) as u32;
        line_h(&mut img, bx + bw, y, 4, BLACK);
        text(
            &mut img,
            bx + bw + 6,
            y.saturating_sub(4),
            &format!("{}", Short(t)),
            1,
            BLACK,
        );
    }
    text(&mut img, bx, top + bh + 8, &options.unit, 1, BLACK);
    if let Some(l) = options.lod {
        text(
            &mut img,
            bx,
            top + bh + 20,
            &format!("grey: |v|<={}", Short(l)),
            1,
            GREY,
        );
    }
    img
}

/// Histogram of values over ±limit (default: 99th percentile of |value|), with lines at 0 and at
/// ±lod when given.
pub fn histogram(
    values: &[f64],
    title: &str,
    unit: &str,
    limit: Option<f64>,
    lod: Option<f64>,
) -> RgbImage {
    let mut finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    finite.sort_unstable_by(f64::total_cmp);
    let limit = limit.unwrap_or_else(|| {
        let mut abs: Vec<f64> = finite.iter().map(|v| v.abs()).collect();
        abs.sort_unstable_by(f64::total_cmp);
        let l = quantile_sorted(&abs, 0.99);
        if l > 0.0 { l } else { 1.0 }
    });
    let bins = 60usize;
    let mut counts = vec![0usize; bins];
    for v in &finite {
        if v.abs() <= limit {
            let b = ((v + limit) / (2.0 * limit) * bins as f64).floor() as usize;
            counts[b.min(bins - 1)] += 1;
        }
    }
    let peak = counts.iter().copied().max().unwrap_or(0).max(1);
    let (pw, ph, left, top) = (600u32, 300u32, 70u32, 40u32);
    let mut img = RgbImage::from_pixel(pw + left + 30, ph + top + 50, WHITE);
    let title_scale = if 16 * title.len() as u32 + left <= img.width() {
        2
    } else {
        1
    };
    let title_x = left.min(img.width().saturating_sub(8 * title.len() as u32));
    text(&mut img, title_x, 12, title, title_scale, BLACK);
    let bar_w = pw / bins as u32;
    for (i, &c) in counts.iter().enumerate() {
        let bh = ((c as f64 / peak as f64) * ph as f64).round() as u32;
        let colour = Rgb([70, 110, 160]);
        for y in 0..bh {
            for x in 0..bar_w.saturating_sub(1) {
                img.put_pixel(left + i as u32 * bar_w + x, top + ph - 1 - y, colour);
            }
        }
    }
    let axis_w = bar_w * bins as u32;
    line_h(&mut img, left, top + ph, axis_w, BLACK);
    for y in top..top + ph {
        img.put_pixel(left - 1, y, BLACK);
    }
    let x_of = |v: f64| {
        left + (((v + limit) / (2.0 * limit)) * axis_w as f64)
            .round()
            .clamp(0.0, (axis_w - 1) as f64) as u32
    };
    for v in [-limit, 0.0, limit] {
        let x = x_of(v);
        for y in top + ph..top + ph + 5 {
            img.put_pixel(x, y, BLACK);
        }
        let label = format!("{}", Short(v));
        text(
            &mut img,
            x.saturating_sub(4 * label.len() as u32),
            top + ph + 9,
            &label,
            1,
            BLACK,
        );
    }
    text(
        &mut img,
        left + axis_w / 2 - 4,
        top + ph + 24,
        unit,
        1,
        BLACK,
    );
    text(&mut img, 4, top, &format!("{peak}"), 1, BLACK);
    text(&mut img, 4, top + ph - 8, "0", 1, BLACK);
    if let Some(l) = lod {
        for v in [-l, l] {
            if v.abs() < limit {
                let x = x_of(v);
                for y in (top..top + ph).step_by(4) {
                    img.put_pixel(x, y, GREY);
                    img.put_pixel(x, y + 1, GREY);
                }
            }
        }
    }
    img
}

/// Numbers for labels: 3 significant digits, no trailing noise.
struct Short(f64);

impl std::fmt::Display for Short {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let v = self.0;
        if v == 0.0 {
            write!(f, "0")
        } else if v.abs() >= 100.0 || v.abs() < 0.01 {
            write!(f, "{v:.2e}")
        } else if v.abs() >= 10.0 {
            write!(f, "{v:.1}")
        } else if v.abs() >= 1.0 {
            write!(f, "{v:.2}")
        } else {
            write!(f, "{v:.3}")
        }
    }
}

fn line_h(img: &mut RgbImage, x: u32, y: u32, len: u32, c: Rgb<u8>) {
    for i in 0..len {
        if x + i < img.width() && y < img.height() {
            img.put_pixel(x + i, y, c);
        }
    }
}

fn frame(img: &mut RgbImage, x: u32, y: u32, w: u32, h: u32, c: Rgb<u8>) {
    line_h(img, x, y, w, c);
    line_h(img, x, y + h - 1, w, c);
    for j in 0..h {
        for xx in [x, x + w - 1] {
            if xx < img.width() && y + j < img.height() {
                img.put_pixel(xx, y + j, c);
            }
        }
    }
}

/// Draws ASCII text with the 8 × 8 font at an integer scale; other characters show as '?'.
pub fn text(img: &mut RgbImage, x: u32, y: u32, s: &str, scale: u32, c: Rgb<u8>) {
    for (i, ch) in s.chars().enumerate() {
        let code = if ch.is_ascii() {
            ch as usize
        } else {
            '?' as usize
        };
        let glyph = font8x8::legacy::BASIC_LEGACY[code];
        let gx = x + i as u32 * 8 * scale;
        for (row, bits) in glyph.iter().enumerate() {
            for col in 0..8u32 {
                if bits & (1 << col) == 0 {
                    continue;
                }
                for dy in 0..scale {
                    for dx in 0..scale {
                        let (px, py) = (gx + col * scale + dx, y + row as u32 * scale + dy);
                        if px < img.width() && py < img.height() {
                            img.put_pixel(px, py, c);
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Grid;
    use timesift_io::coords::Crs;
    use timesift_io::geotiff::GeoTransform;

    #[test]
    fn map_colours_follow_the_values() {
        let grid = Grid {
            transform: GeoTransform {
                origin_x: 0.0,
                origin_y: 10.0,
                pixel_width: 1.0,
                pixel_height: -1.0,
            },
            width: 3,
            height: 1,
            crs: Crs::Local,
        };
        let dem = Dem {
            grid,
            values: vec![-2.0, f32::NAN, 2.0],
        };
        let options = MapOptions {
            limit: Some(2.0),
            max_size: 24,
            ..Default::default()
        };
        let img = difference_map(&dem, &options);
        // Map cells are 8 px wide from (20, 40): lowering is blue, raising red, nodata grey.
        assert_eq!(*img.get_pixel(24, 45), diverging(-1.0));
        assert_eq!(*img.get_pixel(32, 45), NODATA);
        assert_eq!(*img.get_pixel(40, 45), diverging(1.0));
        assert!(diverging(-1.0)[2] > diverging(-1.0)[0] && diverging(1.0)[0] > diverging(1.0)[2]);
        assert_eq!(diverging(0.0), WHITE);
        let h = histogram(
            &[-1.0, 0.1, 0.2, 0.3, f64::NAN],
            "dz",
            "m",
            Some(1.5),
            Some(0.5),
        );
        assert!(h.width() > 600 && h.height() > 300);
    }
}
