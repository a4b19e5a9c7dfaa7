//! Previews for people to look at (report pages): hillshade of a DEM — Horn's gradient, light
//! from the north-west at 45° elevation as GIS tools default to, nodata transparent — and
//! downscaling of any interleaved 8-bit raster whose last channel is alpha.

use crate::Lattice;

/// Grey level and alpha per cell (row-major, 2 bytes a cell); cells without a height, or next
/// to one, are transparent.
pub fn hillshade(height: &[f32], lattice: &Lattice) -> Vec<u8> {
    let (w, h) = (lattice.width(), lattice.height());
    let (cell_x, cell_y) = (lattice.cell_width(), lattice.cell_height());
    let azimuth = 315f64.to_radians();
    let altitude = 45f64.to_radians();
    // Direction towards the light in (east, north, up).
    let light = [
        altitude.cos() * azimuth.sin(),
        altitude.cos() * azimuth.cos(),
        altitude.sin(),
    ];
    let mut out = vec![0u8; 2 * w * h];
    let at = |c: isize, r: isize| -> f64 {
        let c = c.clamp(0, w as isize - 1) as usize;
        let r = r.clamp(0, h as isize - 1) as usize;
        height[r * w + c] as f64
    };
    for r in 0..h as isize {
        for c in 0..w as isize {
            let z = |dc: isize, dr: isize| at(c + dc, r + dr);
            let dzdx = ((z(1, -1) + 2.0 * z(1, 0) + z(1, 1))
                - (z(-1, -1) + 2.0 * z(-1, 0) + z(-1, 1)))
                / (8.0 * cell_x);
            // Rows grow southward, so north is −row.
            let dzdy = ((z(-1, -1) + 2.0 * z(0, -1) + z(1, -1))
                - (z(-1, 1) + 2.0 * z(0, 1) + z(1, 1)))
                / (8.0 * cell_y);
            let i = (r as usize * w + c as usize) * 2;
            if !(dzdx.is_finite() && dzdy.is_finite() && z(0, 0).is_finite()) {
                continue;
            }
            let norm = (dzdx * dzdx + dzdy * dzdy + 1.0).sqrt();
            let shade = (-dzdx * light[0] - dzdy * light[1] + light[2]) / norm;
            out[i] = (shade.clamp(0.0, 1.0) * 255.0).round() as u8;
            out[i + 1] = 255;
        }
    }
    out
}

/// Box-downscales an interleaved 8-bit raster (last channel alpha) by the smallest integer
/// factor that brings its longer side to `max_side` or less; colours are alpha-weighted so that
/// transparent cells do not darken edges. Returns (width, height, data).
pub fn downscale(
    data: &[u8],
    channels: usize,
    width: usize,
    height: usize,
    max_side: usize,
) -> (usize, usize, Vec<u8>) {
    let mut small = Downscaler::new(channels, width, height, max_side);
    small.push_rows(data);
    small.finish()
}

/// [`downscale`] of a raster given a band of rows at a time (a preview of a mosaic larger
/// than memory): holds one output row's sums.
#[derive(Debug, Clone)]
pub struct Downscaler {
    channels: usize,
    width: usize,
    height: usize,
    k: usize,
    out_width: usize,
    /// Input rows taken so far.
    rows: usize,
    /// Per output column of the output row being summed: alpha-weighted colour sums, the
    /// alpha sum, and the cell count.
    sums: Vec<u64>,
    counts: Vec<u64>,
    out: Vec<u8>,
}

impl Downscaler {
    /// A downscaler of a `width` × `height` raster of `channels` channels (the last alpha) to
    /// a longer side of at most `max_side`.
    pub fn new(channels: usize, width: usize, height: usize, max_side: usize) -> Downscaler {
        let k = width.max(height).div_ceil(max_side.max(1)).max(1);
        let out_width = width.div_ceil(k);
        Downscaler {
            channels,
            width,
            height,
            k,
            out_width,
            rows: 0,
            sums: vec![0; out_width * channels],
            counts: vec![0; out_width],
            out: Vec::with_capacity(out_width * height.div_ceil(k) * channels),
        }
    }

    /// Takes whole rows below those already given (rows beyond the height are ignored).
    pub fn push_rows(&mut self, data: &[u8]) {
        let (ch, colours) = (self.channels, self.channels.saturating_sub(1));
        for row in data.chunks_exact(self.width * ch) {
            if self.rows == self.height {
                return;
            }
            for (x, px) in row.chunks_exact(ch).enumerate() {
                let c = x / self.k;
                let sum = &mut self.sums[c * ch..(c + 1) * ch];
                let a = px[colours] as u64;
                for b in 0..colours {
                    sum[b] += a * px[b] as u64;
                }
                sum[colours] += a;
                self.counts[c] += 1;
            }
            self.rows += 1;
            if self.rows % self.k == 0 || self.rows == self.height {
                self.emit_row();
            }
        }
    }

    /// One output row from the sums, which start again at zero.
    fn emit_row(&mut self) {
        let (ch, colours) = (self.channels, self.channels.saturating_sub(1));
        let start = self.out.len();
        self.out.resize(start + self.out_width * ch, 0);
        let row = &mut self.out[start..];
        for (c, (px, sum)) in row
            .chunks_exact_mut(ch)
            .zip(self.sums.chunks_exact(ch))
            .enumerate()
        {
            for b in 0..colours {
                if let Some(v) = (sum[b] + sum[colours] / 2).checked_div(sum[colours]) {
                    px[b] = v as u8;
                }
            }
            px[colours] = (sum[colours] / self.counts[c].max(1)) as u8;
        }
        self.sums.iter_mut().for_each(|s| *s = 0);
        self.counts.iter_mut().for_each(|n| *n = 0);
    }

    /// The downscaled raster: (width, height, data), with the rows given so far.
    pub fn finish(self) -> (usize, usize, Vec<u8>) {
        let rows = self.out.len() / (self.out_width * self.channels).max(1);
        (self.out_width, rows, self.out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slopes_facing_the_light_are_brighter_and_nodata_is_transparent() {
        let l = Lattice::new(0.0, 10.0, 1.0, 10, 10).unwrap();
        // Rising towards the east: the slope faces west, towards a north-west light.
        let east_up: Vec<f32> = (0..100).map(|i| (i % 10) as f32).collect();
        let west_up: Vec<f32> = (0..100).map(|i| (9 - i % 10) as f32).collect();
        let flat = vec![1.0f32; 100];
        let a = hillshade(&east_up, &l)[2 * 55];
        let b = hillshade(&west_up, &l)[2 * 55];
        let f = hillshade(&flat, &l)[2 * 55];
        assert!(b < f && f < a, "{a} {f} {b}");
        assert_eq!(f, (45f64.to_radians().sin() * 255.0).round() as u8);
        let mut holed = flat.clone();
        holed[55] = f32::NAN;
        let s = hillshade(&holed, &l);
        assert_eq!(s[2 * 55 + 1], 0);
        assert_eq!(s[2 * 56 + 1], 0);
        assert_eq!(s[2 * 58 + 1], 255);
    }

    #[test]
    fn downscaling_weights_colours_by_alpha() {
        // 4 × 2 grey + alpha: the left 2 × 2 block has one transparent black cell.
        let data = [
            100, 255, 0, 0, 50, 255, 50, 255, //
            100, 255, 100, 255, 50, 255, 50, 255,
        ];
        let (w, h, out) = downscale(&data, 2, 4, 2, 2);
        assert_eq!((w, h), (2, 1));
        assert_eq!(out, vec![100, 191, 50, 255]);
    }

    #[test]
    fn downscaling_by_bands_of_rows_gives_the_whole_raster_s_preview() {
        // 23 × 17 RGBA to at most 5 on a side: blocks of 5 × 5, the last ones partial.
        let (w, h) = (23, 17);
        let data: Vec<u8> = (0..w * h * 4)
            .map(|i| {
                if i % 4 == 3 {
                    (i * 13 % 256) as u8
                } else {
                    (i * 7 % 251) as u8
                }
            })
            .collect();
        let (sw, sh, whole) = downscale(&data, 4, w, h, 5);
        assert_eq!((sw, sh), (5, 4));
        // The first output cell, by hand: alpha-weighted colour and mean alpha of 5 × 5 cells.
        let (mut red, mut alpha) = (0u64, 0u64);
        for y in 0..5 {
            for x in 0..5 {
                let px = &data[(y * w + x) * 4..(y * w + x + 1) * 4];
                red += px[3] as u64 * px[0] as u64;
                alpha += px[3] as u64;
            }
        }
        assert_eq!(whole[0] as u64, (red + alpha / 2) / alpha);
        assert_eq!(whole[3] as u64, alpha / 25);
        for band in [1, 4, 7, 17] {
            let mut small = Downscaler::new(4, w, h, 5);
            for rows in data.chunks(band * w * 4) {
                small.push_rows(rows);
            }
            assert_eq!(
                small.finish(),
                (sw, sh, whole.clone()),
                "bands of {band} rows"
            );
        }
    }
}
