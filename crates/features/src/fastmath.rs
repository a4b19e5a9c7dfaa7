//! Polynomial atan2 for the gradient loops, where `f32::atan2` would dominate the descriptor time.

use std::f32::consts::{FRAC_PI_2, PI, TAU};

/// atan2(y, x) in [0, 2π), absolute error below 2e-5 rad (minimax polynomial of atan on [0, 1]).
#[inline]
pub(crate) fn atan2_positive(y: f32, x: f32) -> f32 {
    let ax = x.abs();
    let ay = y.abs();
    let (num, den, swapped) = if ay > ax {
        (ax, ay, true)
    } else {
        (ay, ax, false)
    };
    let z = if den > 0.0 { num / den } else { 0.0 };
    let z2 = z * z;
    let mut a = z
        * (0.999_866
            + z2 * (-0.330_299_5 + z2 * (0.180_141 + z2 * (-0.085_133 + z2 * 0.020_835_1))));
    if swapped {
        a = FRAC_PI_2 - a;
    }
    if x < 0.0 {
        a = PI - a;
    }
    if y < 0.0 {
        a = TAU - a;
    }
    if a >= TAU { a - TAU } else { a }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_std_atan2_on_the_circle() {
        let mut worst = 0.0f32;
        for i in 0..100_000 {
            let t = i as f32 * TAU / 100_000.0;
            for r in [1e-3f32, 1.0, 250.0] {
                let (y, x) = (r * t.sin(), r * t.cos());
                let exact = y.atan2(x).rem_euclid(TAU);
                let mut d = (atan2_positive(y, x) - exact).abs();
                d = d.min(TAU - d);
                worst = worst.max(d);
            }
        }
        assert!(worst < 2e-5, "worst error {worst}");
        assert_eq!(atan2_positive(0.0, 0.0), 0.0);
    }
}
