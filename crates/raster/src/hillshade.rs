//! Hillshade of a DEM for people to look at (report previews): Horn's gradient, light from the
//! north-west at 45° elevation as GIS tools default to, nodata transparent.

use crate::Lattice;

/// Grey level and alpha per cell (row-major, 2 bytes a cell); cells without a height, or next
/// to one, are transparent.
pub fn hillshade(height: &[f32], lattice: &Lattice) -> Vec<u8> {
    let (w, h) = (lattice.width(), lattice.height());
    let cell = lattice.cell();
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
                / (8.0 * cell);
            // Rows grow southward, so north is −row.
            let dzdy = ((z(-1, -1) + 2.0 * z(0, -1) + z(1, -1))
                - (z(-1, 1) + 2.0 * z(0, 1) + z(1, 1)))
                / (8.0 * cell);
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
}
