//! Four-quadrant targets (black and white quadrants alternating, as GCP targets are painted)
//! located to a fraction of a pixel in an RGBA image: the X-corner response, which a blurred or
//! resampled target keeps, rather than a template, which would need the target's size and
//! orientation.

/// Where the centre of a four-quadrant target (black and white quadrants alternating, the
/// targets `synth` paints) lies in an RGBA raster, searched within `search` cells of `near`.
/// Positions are in cells with the pixel convention of docs/design.md (the centre of cell (i, j) is
/// (i + 0.5, j + 0.5)); `radius` is the target's radius in cells.
///
/// The score of a candidate centre is the X-corner response on rings inside the disc: opposite
/// points agree (|I(c + d) − I(c − d)| small), points a quarter turn apart differ
/// (|I(c + d) − I(c + d⊥)| large). The best cell centre is
/// refined on a 0.05-cell grid. `None` when the window leaves the raster or touches transparent cells.
pub fn locate_target(
    rgba: &[u8],
    width: usize,
    height: usize,
    near: (f64, f64),
    radius: f64,
    search: f64,
) -> Option<(f64, f64)> {
    let grey = |x: f64, y: f64| -> Option<f64> {
        // Bilinear between cell centres.
        let (fx, fy) = (x - 0.5, y - 0.5);
        let (x0, y0) = (fx.floor(), fy.floor());
        if x0 < 0.0 || y0 < 0.0 || x0 + 1.0 >= width as f64 || y0 + 1.0 >= height as f64 {
            return None;
        }
        let (tx, ty) = (fx - x0, fy - y0);
        let mut v = 0.0;
        for (dx, dy, w) in [
            (0, 0, (1.0 - tx) * (1.0 - ty)),
            (1, 0, tx * (1.0 - ty)),
            (0, 1, (1.0 - tx) * ty),
            (1, 1, tx * ty),
        ] {
            let i = 4 * ((y0 as usize + dy) * width + x0 as usize + dx);
            if rgba[i + 3] == 0 {
                return None;
            }
            v += w * (rgba[i] as f64 + rgba[i + 1] as f64 + rgba[i + 2] as f64) / 3.0;
        }
        Some(v)
    };
    let score = |cx: f64, cy: f64| -> Option<f64> {
        let mut s = 0.0;
        for ring in [0.35, 0.55, 0.75] {
            let r = ring * radius;
            for k in 0..16 {
                let a = k as f64 * std::f64::consts::PI / 8.0;
                let (dx, dy) = (r * a.cos(), r * a.sin());
                let p = grey(cx + dx, cy + dy)?;
                let opposite = grey(cx - dx, cy - dy)?;
                let quarter = grey(cx - dy, cy + dx)?;
                s += (p - quarter).abs() - (p - opposite).abs();
            }
        }
        Some(s)
    };
    let reach = search.ceil() as i64;
    let (c0, r0) = (near.0.floor() as i64, near.1.floor() as i64);
    let mut best: Option<(f64, i64, i64)> = None;
    for r in r0 - reach..=r0 + reach {
        for c in c0 - reach..=c0 + reach {
            let (x, y) = (c as f64 + 0.5, r as f64 + 0.5);
            if (x - near.0).hypot(y - near.1) > search {
                continue;
            }
            let s = score(x, y)?;
            if best.is_none_or(|b| s > b.0) {
                best = Some((s, c, r));
            }
        }
    }
    // Sub-cell: the best of a 0.05-cell grid around the best cell centre (the response is a
    // cone, which a parabola would bias).
    let (_, c, r) = best?;
    let mut fine = (f64::NEG_INFINITY, c as f64 + 0.5, r as f64 + 0.5);
    for j in -12..=12 {
        for i in -12..=12 {
            let (x, y) = (
                c as f64 + 0.5 + i as f64 * 0.05,
                r as f64 + 0.5 + j as f64 * 0.05,
            );
            let s = score(x, y)?;
            if s > fine.0 {
                fine = (s, x, y);
            }
        }
    }
    Some((fine.1, fine.2))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_four_quadrant_target_is_found_to_a_sixth_of_a_cell() {
        let (w, h) = (60usize, 50usize);
        let (cx, cy, radius) = (27.3, 21.8, 9.0);
        let angle: f64 = 0.4;
        let mut rgba = vec![0u8; w * h * 4];
        for r in 0..h {
            for c in 0..w {
                // Area-averaged over 4 × 4 sub-samples, as a rendered image is.
                let mut v = 0.0;
                for s in 0..16 {
                    let x = c as f64 + (s % 4) as f64 / 4.0 + 0.125 - cx;
                    let y = r as f64 + (s / 4) as f64 / 4.0 + 0.125 - cy;
                    let (u, t) = (
                        x * angle.cos() + y * angle.sin(),
                        -x * angle.sin() + y * angle.cos(),
                    );
                    v += if x.hypot(y) > radius {
                        120.0
                    } else if (u > 0.0) == (t > 0.0) {
                        240.0
                    } else {
                        15.0
                    };
                }
                let i = 4 * (r * w + c);
                rgba[i..i + 3].fill((v / 16.0) as u8);
                rgba[i + 3] = 255;
            }
        }
        let (x, y) = locate_target(&rgba, w, h, (29.0, 20.0), radius, 4.0).unwrap();
        assert!((x - cx).abs() < 0.16 && (y - cy).abs() < 0.16, "{x} {y}");
        // A window that reaches transparent cells gives no answer.
        rgba[4 * (21 * w + 27) + 3] = 0;
        assert_eq!(locate_target(&rgba, w, h, (29.0, 20.0), radius, 4.0), None);
    }
}
