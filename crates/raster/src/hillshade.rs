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
    let k = width.max(height).div_ceil(max_side.max(1)).max(1);
    let (w, h) = (width.div_ceil(k), height.div_ceil(k));
    let colours = channels - 1;
    let mut out = vec![0u8; w * h * channels];
    let mut sum = vec![0u64; channels];
    for r in 0..h {
        for c in 0..w {
            sum.iter_mut().for_each(|s| *s = 0);
            let mut n = 0u64;
            for y in r * k..((r + 1) * k).min(height) {
                for x in c * k..((c + 1) * k).min(width) {
                    let px = &data[(y * width + x) * channels..(y * width + x + 1) * channels];
                    let a = px[colours] as u64;
                    for b in 0..colours {
                        sum[b] += a * px[b] as u64;
                    }
                    sum[colours] += a;
                    n += 1;
                }
            }
            let o = &mut out[(r * w + c) * channels..(r * w + c + 1) * channels];
            for b in 0..colours {
                if let Some(v) = (sum[b] + sum[colours] / 2).checked_div(sum[colours]) {
                    o[b] = v as u8;
                }
            }
            o[colours] = (sum[colours] / n.max(1)) as u8;
        }
    }
    (w, h, out)
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
}
